"""The crash and flip probes (``benchmarks/crash_probe.py``, ``benchmarks/flip_probe.py``) build what they say:
session 23's estimator changes were decided on them, so their motions are checked against scipy's
rotations and the physics they claim (a full turn leaves the attitude where it was; the gyro reads the
range where the true rate is beyond it; the receiver and the accelerometer show one motion)."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.ingest.saturation import GYRO_FULL_SCALE_RAD_S
from tepinn_flight.model.synthetic import synthetic_record

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _rot(q_wxyz) -> Rotation:
    return Rotation.from_quat(np.asarray(q_wxyz)[..., [1, 2, 3, 0]])


@pytest.mark.parametrize("rate_dps", [2400.0, 1500.0])
def test_the_flip_probe_inserts_one_full_roll_the_gyro_reads_within_its_range(rate_dps):
    fp = _load("flip_probe")
    rec = synthetic_record(seed=4, duration_s=12.0, rate_hz=400.0)
    out, t0, t1 = fp.with_flip(rec, 5.0, rate_dps)
    d, o = rec.data, out.data
    i0 = int(np.searchsorted(d.t_s.to_numpy(), d.t_s.iloc[0] + 5.0))
    n = len(out) - len(rec)
    dt = float(np.median(np.diff(rec.t_s)))
    assert n == round(360.0 / rate_dps / dt) and t1 - t0 == pytest.approx(n * dt)
    # the truth turns once about the body's x axis, sample by sample at the true rate, and ends where it began
    q = out.q_ref_wxyz[i0 : i0 + n]  # the inserted samples: q0 turned by 1/n, 2/n, … of a turn
    q_start = rec.q_ref_wxyz[i0]
    steps = (_rot(np.vstack([q_start, q[:-1]])).inv() * _rot(q)).as_rotvec()  # body-frame increments
    np.testing.assert_allclose(steps, np.tile([2 * math.pi / n, 0.0, 0.0], (n, 1)), atol=1e-9)
    assert (_rot(q[-1]).inv() * _rot(q_start)).magnitude() < 1e-9
    # the gyro: the true rate, or the range where the rate is past it, marked as the readers mark it
    gyr = out.gyr_rad_s[i0 : i0 + n, 0]
    true_rate = 2 * math.pi / (n * dt)
    if true_rate > GYRO_FULL_SCALE_RAD_S:
        assert np.all(gyr == GYRO_FULL_SCALE_RAD_S) and out.gyr_clipped[i0 : i0 + n].all()
    else:
        np.testing.assert_allclose(gyr, true_rate, atol=0.02)
        assert not out.gyr_clipped[i0 : i0 + n].any()
    # the flight goes on as flown, shifted by the roll
    np.testing.assert_array_equal(o.iloc[i0 + n :][["gyr_x_rad_s", "acc_z_m_s2", "q_ref_w"]].to_numpy(),
                                  d.iloc[i0:][["gyr_x_rad_s", "acc_z_m_s2", "q_ref_w"]].to_numpy())  # fmt: skip
    np.testing.assert_allclose(o.t_s.iloc[i0 + n :].to_numpy() - n * dt, d.t_s.iloc[i0:].to_numpy())


def test_the_crash_probe_shows_one_motion_to_the_accelerometer_and_the_receiver():
    """After the crash the receiver's velocity reaches zero, and the accelerometer at rest reads gravity
    alone in the attitude the truth holds (the integrated true rate)."""
    from tepinn_flight.sim.simulate import simulate_record

    cp = _load("crash_probe")
    rec = simulate_record("F450", 10.0, 400.0, 5, "consumer")
    out, t0 = cp.with_crash(rec, 2400.0, 540.0)
    t = out.t_s
    rest = t > t0 + 0.85 + 0.5
    q = out.q_ref_wxyz[rest]
    g_body = _rot(q).inv().apply([0.0, 0.0, 9.81])  # gravity in body axes; the specific force at rest is −g
    np.testing.assert_allclose(out.acc_m_s2[rest], -g_body, atol=0.3)  # the probe's sensor noise
    vel = out.gnss_vel_ne_m_s
    late = t > t0 + 0.85 + 0.5
    assert np.nanmax(np.abs(vel[late])) < 0.3  # the receiver shows the vehicle stopped (noise 0.05 m/s)
    # 540° turned about y: upside down at rest
    assert (_rot(q[0]).inv() * _rot(rec.q_ref_wxyz[-1])).magnitude() == pytest.approx(math.pi, abs=0.05)
