"""A clipped gyro's missed turn read back from gravity (model/clip_turn.py, rule 25): on bodies at rest before and
after a roll past the gyro's range the fit finds the rate past the range (a closed form: the roll's angle over its
duration), in either direction; a clipping that missed nothing and one without enough unclipped time beside it are
left as read; the episodes against a naive loop; and the shipped offline estimate after a flip past the range."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.conventions import GRAVITY_M_S2
from tepinn_flight.model.clip_turn import clip_episodes, fit_clip_turns
from tepinn_flight.model.smoother import SmootherConfig

RANGE = math.radians(2000.0)


def rest_roll_rest(true_rate_dps: float, angle_deg: float, rest_s: float = 12.0, hz: float = 400.0, seed: int = 0,
                   pre_s: float | None = None, axis=(1.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)):  # fmt: skip
    """A body at rest (tilted 10° in pitch), a roll about its body ``axis`` (default x) through ``angle_deg`` at
    ``true_rate_dps`` read by a gyro clipped at ±2000 °/s per axis and then scaled per axis by ``scale`` (a log's
    calibration), at rest again. Returns (t, gyr, acc, clipped, true q_nb per sample)."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / hz
    n_roll = int(round(abs(angle_deg / true_rate_dps) * hz))
    n_pre = int(round((rest_s if pre_s is None else pre_s) * hz))
    n_post = int(round(rest_s * hz))
    w = math.radians(angle_deg) / (n_roll * dt)  # exactly the angle over the roll's samples
    r0 = Rotation.from_euler("ZYX", [0.3, math.radians(10.0), 0.0])
    steps = np.r_[np.zeros(n_pre), np.full(n_roll, w), np.zeros(n_post)]
    angle = np.r_[0.0, np.cumsum(steps * dt)[:-1]]  # the roll angle at each sample (the step integrates to the next)
    u = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    r = r0 * Rotation.from_rotvec(angle[:, None] * u)
    acc = r.inv().apply([0.0, 0.0, -GRAVITY_M_S2]) + rng.normal(0.0, 0.05, (len(angle), 3))
    gyr = steps[:, None] * u + rng.normal(0.0, 0.002, (len(angle), 3))
    gyr = np.clip(gyr, -RANGE, RANGE)
    clipped = np.any(np.abs(gyr) >= 0.98 * RANGE, 1)
    gyr = gyr * np.asarray(scale)
    t = np.arange(len(angle)) * dt
    return t, gyr, acc, clipped, r.as_quat()[:, [3, 0, 1, 2]]


@pytest.mark.parametrize("rate_dps,angle_deg", [(3000.0, 180.0), (-2600.0, -120.0), (2400.0, 360.0)])
def test_the_rate_past_the_range_is_read_back_from_gravity(rate_dps, angle_deg):
    t, gyr, acc, clipped, _ = rest_roll_rest(rate_dps, angle_deg)
    assert clipped.sum() > 0
    out, turns = fit_clip_turns(t, gyr, acc, clipped, np.zeros_like(gyr), [slice(0, len(t))], SmootherConfig())
    (c,) = turns
    true_rate = abs(angle_deg) / (clipped.sum() / 400.0)  # the roll's rate, its samples a whole number
    missed = abs(angle_deg) * (1.0 - 2000.0 / true_rate)  # what the clipped gyro left out, degrees
    excess = true_rate - 2000.0
    assert c.accepted
    # gravity before and after, as the clipped gyro carried it, lies apart by the missed turn about the body's x axis,
    # pitched 10° out of the horizontal: 2·asin(sin(δ/2)·cos 10°)
    seen = 2 * math.degrees(math.asin(abs(math.sin(math.radians(missed) / 2)) * math.cos(math.radians(10.0))))
    assert c.angle_before_deg == pytest.approx(seen, abs=0.3)
    assert c.angle_after_deg < 0.5
    assert math.degrees(c.excess_rad_s[0]) == pytest.approx(excess, abs=3.0)
    assert c.excess_rad_s[1] == c.excess_rad_s[2] == 0.0  # only the axis that clipped
    # put back on the clipped samples only, signed as the clip; every other sample as read, bit for bit
    np.testing.assert_array_equal(out[~clipped], gyr[~clipped])
    np.testing.assert_allclose(out[clipped, 0], np.sign(rate_dps) * (RANGE + c.excess_rad_s[0]))
    # the gyro as put back turns the body through the roll's angle
    assert math.degrees(np.sum(out[clipped, 0]) / 400.0) == pytest.approx(angle_deg, abs=0.5)


def test_a_clipping_that_missed_nothing_and_one_without_room_beside_it_are_left_as_read():
    # at exactly the range the gyro reads the truth: gravity agrees before and after, nothing to take
    t, gyr, acc, clipped, _ = rest_roll_rest(2000.0 / 0.99, 90.0)
    out, turns = fit_clip_turns(t, gyr, acc, clipped, np.zeros_like(gyr), [slice(0, len(t))], SmootherConfig())
    assert len(turns) == 1 and not turns[0].accepted and turns[0].angle_before_deg < 1.5
    np.testing.assert_array_equal(out, gyr)
    # 1 s of rest before the roll (< clip_turn_min_window_s): not fitted, and said why
    t, gyr, acc, clipped, _ = rest_roll_rest(3000.0, 180.0, pre_s=1.0)
    out, turns = fit_clip_turns(t, gyr, acc, clipped, np.zeros_like(gyr), [slice(0, len(t))], SmootherConfig())
    assert len(turns) == 1 and not turns[0].accepted and "without clipping on a side" in turns[0].why
    np.testing.assert_array_equal(out, gyr)
    # a run that ends at the roll: its windows stop at the run's end
    t, gyr, acc, clipped, _ = rest_roll_rest(3000.0, 180.0)
    _, turns = fit_clip_turns(t, gyr, acc, clipped, np.zeros_like(gyr), [slice(0, int(np.flatnonzero(clipped)[-1]) + 200)],
                              SmootherConfig())  # fmt: skip
    assert len(turns) == 1 and not turns[0].accepted and turns[0].why
    # the gyro's bias is taken out before the integration: a 0.5 °/s bias given as such changes nothing found
    t, gyr, acc, clipped, _ = rest_roll_rest(3000.0, 180.0)
    b = np.radians([0.5, -0.5, 0.3])
    _, (c0,) = fit_clip_turns(t, gyr, acc, clipped, np.zeros_like(gyr), [slice(0, len(t))], SmootherConfig())
    _, (c1,) = fit_clip_turns(t, gyr + b, acc, clipped, np.tile(b, (len(t), 1)), [slice(0, len(t))], SmootherConfig())
    assert math.degrees(c1.excess_rad_s[0]) == pytest.approx(math.degrees(c0.excess_rad_s[0]), abs=1.0)


def test_episodes_against_a_naive_loop():
    rng = np.random.default_rng(3)
    for _ in range(50):
        n = int(rng.integers(1, 400))
        t = np.cumsum(rng.uniform(0.005, 0.05, n))
        m = rng.random(n) < rng.uniform(0.0, 0.3)
        merge = float(rng.uniform(0.0, 0.3))
        ref, cur = [], None
        for i in range(n):  # naive: extend the open episode while the gap from its last clipped sample is ≤ merge
            if not m[i]:
                continue
            if cur is not None and t[i] - t[cur[1] - 1] <= merge:
                cur[1] = i + 1
            else:
                if cur is not None:
                    ref.append(tuple(cur))
                cur = [i, i + 1]
        if cur is not None:
            ref.append(tuple(cur))
        assert clip_episodes(t, m, merge) == ref


def test_settings_are_checked():
    from tepinn_flight.errors import ConfigError

    for bad in ({"clip_turn_window_s": 0.0}, {"clip_turn_min_window_s": 20.0}, {"clip_turn_accept_ratio": 1.5},
                {"clip_turn_max_excess": 0.0}, {"clip_turn_merge_s": -1.0}):  # fmt: skip
        with pytest.raises(ConfigError):
            SmootherConfig(**bad)


def test_the_shipped_offline_estimate_after_a_flip_past_the_range():
    # a 360° roll at 2400 °/s past a ±2000 °/s gyro in a gentle synthetic flight (benchmarks/flip_probe.py's insertion):
    # offline, the tilt over the roll and the 5 s after is near the truth, where without the fit the smoothing carries
    # the 60° the gyro missed for seconds; the causal estimate (the bridge's) is the same either way
    import importlib.util
    from pathlib import Path

    from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import estimate_anchored
    from tepinn_flight.model.synthetic import synthetic_record

    spec = importlib.util.spec_from_file_location("flip_probe", Path(__file__).parents[1] / "benchmarks" / "flip_probe.py")
    probe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(probe)
    rec, t0, t1 = probe.with_flip(synthetic_record(seed=2, duration_s=30.0, rate_hz=100.0), 14.0, 2400.0)
    model, anchor = load_model(default_model_path())[:2]
    cols = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]
    near = (rec.t_s >= t0) & (rec.t_s <= t1 + 5.0)

    def err(df):
        e = np.degrees(inclination_error_rad(error_quat_earth(df[cols].to_numpy(), rec.q_ref_wxyz)))
        return float(np.sqrt(np.mean(e[near] ** 2)))

    on = estimate_anchored(model, rec, anchor)
    off = estimate_anchored(model, rec, anchor, smoother=SmootherConfig(clip_turn=False))
    assert "missed turn read from gravity on 1 of 1 clipping" in on.attrs["smoother"]
    assert err(on) < 3.0 and err(off) > 3 * err(on)


def test_a_sample_marked_but_not_at_the_range_is_not_an_episode():
    # a DataFlash log marks an unhealthy gyro's samples clipped too: they read no range, so there is no turn to put back
    t, gyr, acc, clipped, _ = rest_roll_rest(1500.0, 90.0)  # within the range: nothing clipped
    assert not clipped.any()
    marked = np.zeros(len(t), bool)
    marked[len(t) - 2000 : len(t) - 1960] = True  # marked during the rest after the roll
    out, turns = fit_clip_turns(t, gyr, acc, marked, np.zeros_like(gyr), [slice(0, len(t))], SmootherConfig())
    assert len(turns) == 1 and not turns[0].accepted and turns[0].why == "no axis at the range"
    assert np.array_equal(out, gyr)


def test_an_axis_whose_plateau_differs_still_counts_as_clipped():
    # a roll about the body's x-y diagonal at 4000 °/s clips both axes (2828 °/s each); the log's calibration scales y by
    # 1.1, so y's plateau reads 2200 °/s where x's reads 2000: each axis's own range, both fitted
    t, gyr, acc, clipped, _ = rest_roll_rest(4000.0, 180.0, axis=(1.0, 1.0, 0.0), scale=(1.0, 1.1, 1.0))
    _, (c,) = fit_clip_turns(t, gyr, acc, clipped, np.zeros_like(gyr), [slice(0, len(t))], SmootherConfig())
    assert c.accepted and c.angle_after_deg < 1.0
    assert c.excess_rad_s[0] > 0 and c.excess_rad_s[1] > 0 and c.excess_rad_s[2] == 0.0
    # (gravity fixes the missed turn's horizontal part only: how it splits between the axes along the vertical it cannot
    # tell, so no per-axis figure is asserted; with one range for both axes, y's 2200-°/s plateau would not count and x
    # alone leaves 3.5° apart)


def test_holes_in_the_windows_are_no_turn_and_the_fit_still_holds():
    t, gyr, acc, clipped, _ = rest_roll_rest(3000.0, 180.0)
    g, a = gyr.copy(), acc.copy()
    g[1000:1010] = np.nan  # a hole before the roll, and one after it
    a[7000:7005] = np.nan
    out, (c,) = fit_clip_turns(t, g, a, clipped, np.zeros_like(g), [slice(0, len(t))], SmootherConfig())
    assert c.accepted and c.angle_after_deg < 0.5 and math.degrees(c.excess_rad_s[0]) == pytest.approx(1000.0, abs=5.0)
    assert np.isnan(out[1000:1010]).all()  # the holes stay holes
