"""The offline benchmark's long flight (``benchmarks/estimate_speed.py``'s ``tiled``): played forth and back, the
record's gyro still explains its attitude across the joins (a strapdown integration through them stays on the
copies' reference; scipy's rotations as the reference); repeated, the first join is a jump no gyro reading explains."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.record import FlightRecord, make_frame, segment_slices

RATE_HZ = 100.0


def _bench():
    spec = importlib.util.spec_from_file_location("estimate_speed", Path(__file__).parents[1] / "benchmarks" / "estimate_speed.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _flight(duration_s: float = 20.0) -> FlightRecord:
    """A record whose exact gyro (the turn over each step) carries the attitude from a level start to one 60° of yaw,
    ~25° of pitch and ~20° of roll away, with a receiver's velocity."""
    t = np.arange(0.0, duration_s, 1.0 / RATE_HZ)
    u = t / duration_s
    r = Rotation.from_euler("ZYX", np.c_[np.radians(60.0) * u, np.radians(25.0) * np.sin(np.pi * u / 2), np.radians(20.0) * u**2])
    q_nb = r.as_quat()[:, [3, 0, 1, 2]]
    dr = (r[:-1].inv() * r[1:]).as_rotvec() * RATE_HZ
    gyr = np.vstack([dr, dr[-1:]])
    acc = r.inv().apply(np.tile([0.0, 0.0, -9.81], (len(t), 1)))
    vel = np.c_[2.0 * u, -1.0 * u]
    df = make_frame(t, np.zeros(len(t), np.int32), gyr, acc, None, q_nb, None, gnss_vel_ne_m_s=vel)
    return FlightRecord(df, {"format_version": 1, "source_file": "synthetic", "source_kind": "synthetic",
                             "imu_rate_hz": RATE_HZ, "reference_source": "synthetic-truth"})  # fmt: skip


def _strapdown_error_deg(rec: FlightRecord) -> np.ndarray:
    """Angle (°) between the gyro integrated from the first reference attitude and the reference, per sample."""
    q = rec.q_ref_wxyz
    r = Rotation.from_quat(q[0, [1, 2, 3, 0]])
    dt = np.diff(rec.t_s)
    out = np.zeros(len(q))
    steps = Rotation.from_rotvec(rec.gyr_rad_s[:-1] * dt[:, None])
    for i in range(len(dt)):
        r = r * steps[i]
        out[i + 1] = np.degrees((Rotation.from_quat(q[i + 1, [1, 2, 3, 0]]).inv() * r).magnitude())
    return out


def test_played_forth_and_back_the_gyro_explains_the_attitude_across_every_join():
    bench = _bench()
    rec = _flight()
    long = bench.tiled(rec, 70.0)
    n = len(rec)
    assert len(long) == 7000 and np.all(np.diff(long.t_s) > 0)
    assert np.allclose(np.diff(long.t_s), 1.0 / RATE_HZ)
    assert [s.stop - s.start for s in segment_slices(long.segment)] == [len(long)]
    # the second copy is the first read backward: the attitude retraces, the gyro and the receiver's velocity negated
    assert np.array_equal(long.q_ref_wxyz[n : 2 * n], rec.q_ref_wxyz[::-1])
    assert np.array_equal(long.gyr_rad_s[n : 2 * n], -rec.gyr_rad_s[::-1])
    assert np.array_equal(long.acc_m_s2[n : 2 * n], rec.acc_m_s2[::-1])
    assert np.array_equal(long.gnss_vel_ne_m_s[n : 2 * n], -rec.gnss_vel_ne_m_s[::-1])
    assert np.array_equal(long.gyr_rad_s[2 * n : 3 * n], rec.gyr_rad_s)
    err = _strapdown_error_deg(long)
    assert err.max() < 0.5, err.max()  # (0.04°: the gyro's step alignment at each join), no jump


def test_repeated_the_first_join_is_a_jump_no_gyro_reading_explains():
    bench = _bench()
    rec = _flight()
    long = bench.tiled(rec, 70.0, "repeat")
    assert np.array_equal(long.gyr_rad_s[len(rec) : 2 * len(rec)], rec.gyr_rad_s)
    err = _strapdown_error_deg(long)
    assert err[: len(rec)].max() < 0.5 and err[len(rec) :].min() > 30.0
    with pytest.raises(ValueError, match="tiling"):
        bench.tiled(rec, 70.0, "mirror")
