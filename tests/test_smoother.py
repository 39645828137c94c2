"""Offline tilt smoothing (model/smoother.py): the tilt turn against scipy, the stretches and ramps
against naive references, the smoothed tilt against the vqf package's own offlineVQF on a real BROAD
trial (and nearer its optical truth), gated samples untouched, the CLI's default (on offline since
session 25; `--no-smooth` gives the causal tilt; `--smooth` for checkpoints written before)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad
from tepinn_flight.quat import gravity_body, inclination_heading_split, quat_mul, quat_normalize
from tepinn_flight.model.smoother import SmootherConfig, blend_tilt, ramp_weight, smooth, ungated_stretches


def _q(r: Rotation) -> np.ndarray:
    return r.as_quat()[:, [3, 0, 1, 2]]


def _with_down(q_nb: np.ndarray, down_b: np.ndarray) -> np.ndarray:
    """The numpy whole-array form the compiled blend replaced (session 29), the reference: ``q_nb`` turned in body
    axes by the minimal rotation that makes its down direction ``down_b`` (unit rows)."""
    d_f = gravity_body(q_nb)
    # R(q ⊗ c)ᵀ e₃ = R(c)ᵀ d_f must be down_b: c turns down_b onto d_f (half-way quaternion)
    c = np.concatenate([1.0 + np.sum(down_b * d_f, 1, keepdims=True), np.cross(down_b, d_f)], 1)
    return quat_normalize(quat_mul(q_nb, quat_normalize(c)))


def _down_in_body(q_nb: np.ndarray) -> np.ndarray:
    """NED down in body axes, by scipy: R(q)ᵀ e₃."""
    return Rotation.from_quat(q_nb[:, [1, 2, 3, 0]]).inv().apply([0.0, 0.0, 1.0])


def gentle_record(duration_s: float = 60.0, rate_hz: float = 100.0, seed: int = 0):
    """A slowly turning, gently rocking body with a small horizontal motion acceleration (0.5 m/s²):
    no gate of the shipped estimator opens on it. Returns (record, true q_nb)."""
    from tepinn_flight.conventions import GRAVITY_M_S2
    from tepinn_flight.record import FlightRecord, make_frame

    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    r = Rotation.from_euler("ZYX", np.c_[0.1 * t, np.radians(6.0) * np.sin(0.6 * t), np.radians(8.0) * np.sin(0.4 * t + 1.0)])
    a_n = np.c_[0.5 * np.sin(0.9 * t), 0.5 * np.cos(0.7 * t), np.zeros_like(t)]
    acc_b = r.inv().apply(a_n - [0.0, 0.0, GRAVITY_M_S2]) + rng.normal(0, 0.05, (len(t), 3))
    dr = (r[:-1].inv() * r[1:]).as_rotvec() * rate_hz
    gyr_b = np.vstack([dr, dr[-1:]]) + rng.normal(0, 0.002, (len(t), 3))
    q_nb = _q(r)
    df = make_frame(t, np.zeros(len(t), np.int32), gyr_b, acc_b, None, q_nb, None)
    meta = {"format_version": 1, "source_file": "synthetic", "source_kind": "synthetic", "imu_rate_hz": rate_hz,
            "reference_source": "synthetic-truth"}
    return FlightRecord(df, meta), q_nb


def test_the_tilt_turn_is_the_minimal_one_and_leaves_the_heading():
    # blend_tilt at weight 1 gives q the down direction of p (scipy's) by the minimal turn in body axes
    q = _q(Rotation.random(500, random_state=4))
    p = _q(Rotation.random(500, random_state=3))
    d = _down_in_body(p)
    out = blend_tilt(q, p, np.ones(500))
    np.testing.assert_allclose(_down_in_body(out), d, atol=1e-12)
    # the turn q⁻¹·out (body axes) is about an axis perpendicular to both downs, by their angle
    turn = (Rotation.from_quat(q[:, [1, 2, 3, 0]]).inv() * Rotation.from_quat(out[:, [1, 2, 3, 0]])).as_rotvec()
    d0 = _down_in_body(q)
    angle = np.arccos(np.clip(np.sum(d0 * d, 1), -1, 1))
    ok = angle < np.pi - 1e-3  # (antipodal downs: the axis is undefined)
    np.testing.assert_allclose(np.linalg.norm(turn, axis=1)[ok], angle[ok], atol=1e-9)
    np.testing.assert_allclose(np.sum(turn * d0, 1)[ok], 0.0, atol=1e-9)
    # in earth terms a turn about a horizontal axis: an inclination change, no heading change
    incl, head = inclination_heading_split(error_quat_earth(out[ok], q[ok]))
    np.testing.assert_allclose(np.abs(head), 0.0, atol=1e-9)
    np.testing.assert_allclose(np.abs(incl), angle[ok], atol=1e-9)


def test_blending_weights_the_two_downs():
    q = _q(Rotation.random(50, random_state=1))
    p = _q(Rotation.random(50, random_state=2))
    np.testing.assert_allclose(blend_tilt(q, p, np.zeros(50)), q, atol=1e-12)
    np.testing.assert_allclose(_down_in_body(blend_tilt(q, p, np.ones(50))), _down_in_body(p), atol=1e-12)
    half = _down_in_body(q) + _down_in_body(p)
    half /= np.linalg.norm(half, axis=1, keepdims=True)
    np.testing.assert_allclose(_down_in_body(blend_tilt(q, p, np.full(50, 0.5))), half, atol=1e-12)


def test_the_compiled_blend_is_numpys_whole_array_form():
    # blend_tilt runs compiled per row (session 29); numpy's form, the downs blended, normalised, then _with_down:
    # the same numbers to rounding (numpy sums its 3-vectors its own way)
    rng = np.random.default_rng(5)
    q = _q(Rotation.random(2000, random_state=6))
    p = _q(Rotation.random(2000, random_state=7))
    w = rng.uniform(0, 1, 2000)
    v = (1.0 - w[:, None]) * _down_in_body(q) + w[:, None] * _down_in_body(p)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    np.testing.assert_allclose(blend_tilt(q, p, w), _with_down(q, v), rtol=0, atol=1e-14)


def test_stretches_and_ramps_against_naive_references():
    rng = np.random.default_rng(0)
    for trial in range(30):
        n = 400
        t = np.cumsum(rng.uniform(0.05, 0.15, n))
        gate = (rng.random(n) < 0.03).astype(float)
        gate = np.convolve(gate, np.ones(rng.integers(1, 8)), "same")  # gated runs of a few samples
        min_s = float(rng.uniform(0.0, 8.0))
        naive, i = [], 0
        while i < n:
            if gate[i] > 0:
                i += 1
                continue
            j = i
            while j < n and gate[j] <= 0:
                j += 1
            if t[j - 1] - t[i] >= min_s:
                naive.append(slice(i, j))
            i = j
        assert ungated_stretches(t, gate, min_s) == naive
    t = np.linspace(0.0, 20.0, 201)
    w = ramp_weight(t, True, True, 5.0)
    np.testing.assert_allclose(w, np.clip(np.minimum(t, 20.0 - t) / 5.0, 0, 1), atol=1e-12)
    np.testing.assert_allclose(ramp_weight(t, False, True, 5.0), np.clip((20.0 - t) / 5.0, 0, 1), atol=1e-12)
    assert np.all(ramp_weight(t, False, False, 5.0) == 1.0)


def test_gated_samples_and_short_stretches_keep_the_causal_estimate():
    n = 6000  # 60 s at 100 Hz, two segments
    t = np.arange(n) * 0.01
    seg = np.r_[np.zeros(4000, np.int32), np.ones(2000, np.int32)]
    gate = np.zeros(n)
    gate[1000:1500] = 0.6  # 10-15 s: a gate; 0-10 s and 15-40 s ungated; segment 1 (40-60 s) 20 s long
    q = _q(Rotation.from_euler("ZYX", np.c_[0.1 * t, np.zeros(n), np.zeros(n)]))  # level, turning
    target = _q(Rotation.from_euler("ZYX", np.c_[np.zeros(n), np.full(n, 0.05), np.zeros(n)]))  # 0.05 rad pitch
    sigma = np.full(n, 0.01)
    seen = []

    def offline(sl):
        seen.append(sl)
        return target[sl]

    cfg = SmootherConfig(min_stretch_s=22.0, min_free_stretch_s=25.0, ramp_s=5.0, sigma_scale=0.5,
                         sigma_disagreement_gain=0.0)  # fmt: skip
    out, sig, done = smooth(t, q, sigma, gate, seg, cfg, offline)
    assert seen == [slice(1500, 4000)]  # 0-10 s too short, segment 1 too short; never across a segment
    keep = np.r_[0:1500, 4000:6000]
    np.testing.assert_array_equal(out[keep], q[keep])
    np.testing.assert_array_equal(sig[keep], sigma[keep])
    incl = inclination_error_rad(error_quat_earth(out, q))
    # ramps in over 5 s from the gate's edge; at the segment's own end at once (no gate follows)
    np.testing.assert_allclose(incl[2000:4000], 0.05, atol=1e-9)
    assert abs(incl[1750] - 0.025) < 2e-3  # half-way up the ramp: half the tilt
    np.testing.assert_allclose(sig[2000:4000], 0.005, rtol=1e-12)
    assert done.applied and done.n_stretches == 1 and done.n_smoothed == 2499 and done.n_gated == 500
    assert done.describe().endswith("; applied") and "1 stretch" in done.describe()
    # everything gated, or too short: said so
    _, _, none = smooth(t, q, sigma, np.ones(n), seg, cfg, offline)
    assert none.describe().endswith("none (no stretch of 22 s without a gate); not applied")
    _, _, short = smooth(t[:1000], q[:1000], sigma[:1000], gate[:1000], seg[:1000], cfg, offline)
    assert short.describe().endswith("none (no segment of 25 s); not applied") and not short.applied
    # a stretch next to no gate (segment 1: 20 s) needs only min_free_stretch_s; 0-10 s, next to the gate, still 22 s
    seen.clear()
    out, _, done = smooth(t, q, sigma, gate, seg, dataclasses.replace(cfg, min_free_stretch_s=15.0), offline)
    assert seen == [slice(1500, 4000), slice(4000, 6000)] and done.n_stretches == 2
    np.testing.assert_array_equal(out[:1500], q[:1500])
    np.testing.assert_allclose(inclination_error_rad(error_quat_earth(out[4000:], q[4000:])), 0.05, atol=1e-9)  # no ramp


def _run_marking_stand_in(t: np.ndarray):
    """A stand-in offline filter that pitches each run it is given by its own first and last samples' times,
    so the tilt says which run a sample came from → (tilt_of(a, b), offline(slice), the runs it saw)."""
    seen = []

    def tilt_of(a, b):
        return 1e-4 * (1.0 + t[a] + (t[b - 1] - t[a]) / 10.0)

    def offline(sl):
        seen.append((sl.start, sl.stop))
        pitch = np.full(sl.stop - sl.start, tilt_of(sl.start, sl.stop))
        return _q(Rotation.from_euler("ZYX", np.c_[np.zeros_like(pitch), pitch, np.zeros_like(pitch)]))

    return tilt_of, offline, seen


def test_before_a_stretchs_last_clipped_gyro_sample_no_backward_pass_has_crossed_a_clip():
    # 100 s at 100 Hz, no gate; the gyro clips at 30-30.5 s and 60-60.5 s. The stand-in offline filter tilts each
    # run it is given by its own first and last samples' times, so the tilt says which run a sample came from
    n = 10000
    t = np.arange(n) * 0.01
    seg = np.zeros(n, np.int32)
    gate = np.zeros(n)
    clipped = np.zeros(n, bool)
    clipped[3000:3050] = clipped[6000:6050] = True
    q = _q(Rotation.from_euler("ZYX", np.c_[0.1 * t, np.zeros(n), np.zeros(n)]))
    sigma = np.full(n, 0.01)
    tilt_of, offline, seen = _run_marking_stand_in(t)

    cfg = SmootherConfig(min_stretch_s=20.0, ramp_s=5.0, sigma_scale=0.5)
    out, sig, done = smooth(t, q, sigma, gate, seg, cfg, offline, gyr_clipped=clipped)
    # the whole stretch, then the runs cut at the clips up to the last one: 0-30 s, 30.5-60 s
    assert seen == [(0, n), (0, 3000), (3050, 6000)]
    incl = inclination_error_rad(error_quat_earth(out, q))
    np.testing.assert_allclose(incl[:2500], tilt_of(0, 3000), rtol=0, atol=1e-9)  # before the first clip: the first cut run
    np.testing.assert_allclose(incl[3550:5500], tilt_of(3050, 6000), rtol=0, atol=1e-9)  # between the clips: the second
    np.testing.assert_allclose(incl[3000:3050], 0.0, atol=1e-12)  # the clip itself: in no cut run, causal
    assert incl[2750] == pytest.approx((t[2999] - t[2750]) / 5.0 * tilt_of(0, 3000), rel=1e-3)  # ramping out toward the clip
    # after the last clip: the whole stretch's run (its backward pass starts after every clip)
    np.testing.assert_allclose(incl[6050:], tilt_of(0, n), rtol=0, atol=1e-9)
    np.testing.assert_allclose(sig[6050:], 0.005, rtol=1e-12)
    # not smoothed: both clips' samples (before the last one) and the cut runs' zero-weight ends (3)
    assert done.applied and done.n_smoothed == n - 100 - 3
    # without clipping, the whole stretch as before; the cut runs never made
    seen.clear()
    out2, _, _ = smooth(t, q, sigma, gate, seg, cfg, offline)
    assert seen == [(0, n)]
    np.testing.assert_allclose(inclination_error_rad(error_quat_earth(out2, q)), tilt_of(0, n), rtol=0, atol=1e-9)


def test_from_a_relevelling_after_the_last_clip_no_forward_pass_has_crossed_it():
    # 100 s at 100 Hz, no gate; the gyro clips at 30-30.5 s and the causal estimator re-levels at rest from
    # 31 s (sample 3100) on. The stand-in offline filter tilts each run by its first and last samples' times
    n = 10000
    t = np.arange(n) * 0.01
    seg, gate, sigma = np.zeros(n, np.int32), np.zeros(n), np.full(n, 0.01)
    clipped = np.zeros(n, bool)
    clipped[3000:3050] = True
    q = _q(Rotation.from_euler("ZYX", np.c_[0.1 * t, np.zeros(n), np.zeros(n)]))
    tilt_of, offline, seen = _run_marking_stand_in(t)

    cfg = SmootherConfig(min_stretch_s=20.0, min_free_stretch_s=20.0, ramp_s=5.0, sigma_scale=0.5)
    out, sig, done = smooth(t, q, sigma, gate, seg, cfg, offline, gyr_clipped=clipped, relevel=[3100])
    # the whole stretch, the cut run before the clip, the run from the re-levelling to the end
    assert seen == [(0, n), (0, 3000), (3100, n)]
    incl = inclination_error_rad(error_quat_earth(out, q))
    np.testing.assert_allclose(incl[:2500], tilt_of(0, 3000), rtol=0, atol=1e-9)
    np.testing.assert_allclose(incl[3050:3100], tilt_of(0, n), rtol=0, atol=1e-9)  # clip to re-levelling: the whole one
    assert incl[3100] == pytest.approx(0.0, abs=1e-12)  # the re-levelled sample: the causal tilt, the ramp's start
    assert incl[3350] == pytest.approx(2.5 / 5.0 * tilt_of(3100, n), rel=1e-3)  # ramping in from it
    np.testing.assert_allclose(incl[3600:], tilt_of(3100, n), rtol=0, atol=1e-9)  # then the run of its own
    np.testing.assert_allclose(sig[3600:], 0.005, rtol=1e-12)
    # a re-levelling too near the end for a run of its own (< 20 s): the causal tilt and σ from it on
    seen.clear()
    out, sig, _ = smooth(t, q, sigma, gate, seg, cfg, offline, gyr_clipped=clipped, relevel=[8500])
    assert seen == [(0, n), (0, 3000)]
    incl = inclination_error_rad(error_quat_earth(out, q))
    np.testing.assert_allclose(incl[3050:8500], tilt_of(0, n), rtol=0, atol=1e-9)
    np.testing.assert_allclose(incl[8500:], 0.0, atol=1e-12)
    np.testing.assert_array_equal(sig[8500:], sigma[8500:])
    # a re-levelling before the last clip ends the cut runs there too
    seen.clear()
    clipped2 = clipped.copy()
    clipped2[6000:6050] = True
    smooth(t, q, sigma, gate, seg, cfg, offline, gyr_clipped=clipped2, relevel=[3100])
    assert seen == [(0, n), (0, 3000), (3101, 6000)]  # not (3050, 6000): the re-levelled sample is a cut (3050-3100: too short)


def test_after_a_crash_past_the_gyro_range_the_shipped_estimate_keeps_the_relevelled_tilt():
    # a simulated F450 flight ending in a 540° tumble at 2400 °/s (past ±2000 °/s), an impact and 6 s upside down
    # (benchmarks/crash_probe.py): at rest from the re-levelling on, the smoothed estimate is as near the truth as the causal one,
    # within 1° of the truth, where a forward pass across the tumble had left 17° (session 26; since rule 15 the
    # 5.5 s from the re-levelling are smoothed on their own: a run starting at rest)
    import importlib.util
    from pathlib import Path

    from tepinn_flight.evaluation.estimators import TepinnEstimator
    from tepinn_flight.model.checkpoint import default_model_path
    from tepinn_flight.sim.simulate import simulate_record

    spec = importlib.util.spec_from_file_location("crash_probe", Path(__file__).parents[1] / "benchmarks" / "crash_probe.py")
    probe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(probe)
    rec, t0 = probe.with_crash(simulate_record("F450", 40.0, 200.0, 101, "consumer"), 2400.0, 540.0)
    tp = TepinnEstimator.from_checkpoint(default_model_path(), "tepinn")
    cols = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]
    sm, ca = tp.estimate(rec), tp.unsmoothed().estimate(rec)
    assert sm.attrs["rest_relevel"].endswith("applied")
    rest = rec.t_s > t0 + 2.0
    e_sm = np.degrees(inclination_error_rad(error_quat_earth(sm[cols].to_numpy(), rec.q_ref_wxyz)))[rest]
    assert e_sm.max() < 1.0
    e_ca = np.degrees(inclination_error_rad(error_quat_earth(ca[cols].to_numpy(), rec.q_ref_wxyz)))[rest]
    assert e_ca.max() < 1.0


def test_the_disagreement_rms_against_a_naive_loop():
    # the centred RMS over W s of the tilt angle between two attitude series, within each segment, against a
    # sample-by-sample loop on scipy's rotations (uneven sampling, two segments, a NaN attitude)
    from tepinn_flight.model.smoother import disagreement_sigma

    rng = np.random.default_rng(3)
    n = 900
    t = np.cumsum(rng.uniform(0.005, 0.02, n))
    seg = np.r_[np.zeros(500, np.int32), np.ones(n - 500, np.int32)]
    ra = Rotation.from_euler("ZYX", rng.normal(0, 0.3, (n, 3)))
    rb = ra * Rotation.from_rotvec(rng.normal(0, 0.02, (n, 3)))
    qa, qb = _q(ra), _q(rb)
    qb[100] = np.nan
    got = disagreement_sigma(t, qa, qb, seg, 1.0)
    da = _down_in_body(qa)
    db = _down_in_body(np.where(np.isnan(qb), qa, qb))
    ang = np.arccos(np.clip(np.sum(da * db, 1), -1.0, 1.0))
    ang[100] = np.nan
    want = np.empty(n)
    for i in range(n):
        j = (seg == seg[i]) & (np.abs(t - t[i]) <= 0.5) & np.isfinite(ang)
        want[i] = np.sqrt(np.mean(ang[j] ** 2))
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(disagreement_sigma(t, qa, qb, seg, 0.0)[:100], ang[:100], rtol=1e-6, atol=1e-7)


def test_where_the_smoothed_tilt_departs_from_the_causal_one_sigma_is_at_least_k_times_the_departure():
    # the stand-in offline filter tilts a stretch by 0.02 rad: with weight 1 the smoothed tilt is 0.02 rad from the
    # causal one, so σ = max(s σ, k·0.02), s the smoothing's σ factor; gain 0 gives s σ (the stand-in's rates are not
    # given: no rotation term)
    n = 6000
    t = np.arange(n) * 0.01
    seg, gate = np.zeros(n, np.int32), np.zeros(n)
    gate[:1000] = 1.0  # a gate acts for the first 10 s: the stretch ramps in from 10 s to 15 s
    q = _q(Rotation.from_euler("ZYX", np.c_[0.1 * t, np.zeros(n), np.zeros(n)]))

    def offline(sl):
        m = sl.stop - sl.start
        return _q(Rotation.from_euler("ZYX", np.c_[0.1 * t[sl], np.full(m, 0.02), np.zeros(m)]))

    for sig0, k in ((0.01, 0.5), (0.01, 0.0), (0.001, 0.5)):
        sigma = np.full(n, sig0)
        cfg = SmootherConfig(min_stretch_s=20.0, ramp_s=5.0, sigma_disagreement_gain=k)
        _, sig, done = smooth(t, q, sigma, gate, seg, cfg, offline)
        assert done.applied
        np.testing.assert_allclose(sig[2000:5000], max(cfg.sigma_scale * sig0, k * 0.02), rtol=1e-6)
        np.testing.assert_array_equal(sig[:990], sigma[:990])  # gated and away from the stretch: untouched
    # half-way up the ramp the smoothed tilt is half-way too (0.01 rad from the causal one, rising 0.004 rad/s):
    # σ = k times the RMS of that line over the centred second's 101 samples
    tau = np.arange(-50, 51) * 0.01
    assert sig[1250] == pytest.approx(0.5 * np.sqrt(np.mean((0.01 + 0.004 * tau) ** 2)), rel=1e-4)


def test_the_settings_are_checked():
    from tepinn_flight.errors import ConfigError

    for bad in ({"min_stretch_s": -1.0}, {"ramp_s": float("nan")}, {"sigma_scale": 0.0}, {"sigma_scale": 1.5}):
        with pytest.raises(ConfigError):
            SmootherConfig(**bad)


def test_on_a_motion_acceleration_the_smoothed_tilt_is_nearer_the_truth():
    # VQF's low-pass lags behind the motion acceleration and the turning; run both ways it does not
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import EST_Q_COLS, estimate_anchored

    model, anchor, _ = load_model(default_model_path())
    rec, q_true = gentle_record(60.0)

    def rmse_deg(df):
        m = rec.t_s >= 10.0
        return np.degrees(np.sqrt(np.mean(inclination_error_rad(error_quat_earth(df[EST_Q_COLS].to_numpy()[m], q_true[m])) ** 2)))

    causal = estimate_anchored(model, rec, dataclasses.replace(anchor, smoother=False))
    smoothed = estimate_anchored(model, rec, anchor)
    assert "smoother" not in causal.attrs and anchor.smoother  # the shipped model smooths offline (session 25)
    assert smoothed.attrs["smoother"].endswith("100 % of the samples in 1 stretch(es); applied")
    assert rmse_deg(smoothed) < 0.6 * rmse_deg(causal), (rmse_deg(smoothed), rmse_deg(causal))  # 1.06° → 0.40°
    # the heading is the causal estimate's
    _, head = inclination_heading_split(error_quat_earth(smoothed[EST_Q_COLS].to_numpy(), causal[EST_Q_COLS].to_numpy()))
    assert np.max(np.abs(head)) < 1e-9
    assert not anchor.learned_off.smoother


@pytest.mark.slow
def test_on_a_real_trial_the_tilt_is_the_vqf_packages_offline_filter_and_nearer_the_optical_truth():
    # BROAD trial 01 (no gate fires there): the smoothed tilt is vqf.offlineVQF's on the same
    # samples, computed here straight from the package with the frames done by scipy
    import vqf

    from tests.conftest import broad_trial
    from tepinn_flight.ingest import load_record
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import EST_Q_COLS, estimate_anchored

    rec = load_record(broad_trial("broad_01_*.hdf5"))
    model, anchor, _ = load_model(default_model_path())
    causal = estimate_anchored(model, rec, dataclasses.replace(anchor, smoother=False))
    smoothed = estimate_anchored(model, rec, anchor)
    assert smoothed.attrs["smoother"].startswith("offline tilt smoothing") and "100 %" in smoothed.attrs["smoother"]
    flip = np.array([1.0, -1.0, -1.0])  # body FRD → VQF's z-up sensor frame (180° about x)
    ts = float(np.median(np.diff(rec.t_s[:52])))
    ref = vqf.offlineVQF(np.ascontiguousarray(rec.gyr_rad_s * flip), np.ascontiguousarray(rec.acc_m_s2 * flip), None, ts,
                         {"tauAcc": anchor.tau_acc_s, "biasClip": anchor.bias_clip_deg_s})["quat6D"]  # fmt: skip
    up_s = Rotation.from_quat(ref[:, [1, 2, 3, 0]]).inv().apply([0.0, 0.0, 1.0])  # earth up in sensor axes
    np.testing.assert_allclose(_down_in_body(smoothed[EST_Q_COLS].to_numpy()), -up_s * flip, atol=1e-9)

    def rmse_deg(df):
        m = (rec.t_s >= rec.t_s[0] + 5.0) & np.all(np.isfinite(rec.q_ref_wxyz), 1)
        return np.degrees(np.sqrt(np.mean(inclination_error_rad(error_quat_earth(df[EST_Q_COLS].to_numpy()[m],
                                                                                rec.q_ref_wxyz[m])) ** 2)))  # fmt: skip

    assert rmse_deg(smoothed) < 0.8 * rmse_deg(causal), (rmse_deg(smoothed), rmse_deg(causal))  # 0.60° → 0.37°


def test_estimate_smooths_by_default_says_what_it_did_and_no_smooth_gives_the_causal_tilt(tmp_path, capsys):
    import pandas as pd
    import pyarrow.parquet as pq
    import torch

    from tepinn_flight.cli.main import main
    from tepinn_flight.model.checkpoint import default_lstm_path, default_model_path, load_model
    from tepinn_flight.model.estimate import EST_Q_COLS, estimate_anchored
    from tepinn_flight.record import write_record

    rec, _ = gentle_record(40.0)
    write_record(rec, tmp_path / "fly.parquet")
    assert main(["estimate", str(tmp_path / "fly.parquet"), "-o", str(tmp_path / "smooth.parquet")]) == 0
    out = capsys.readouterr().out
    line = pq.read_schema(tmp_path / "smooth.parquet").metadata[b"smoother"].decode()
    assert line.startswith("offline tilt smoothing") and line.endswith("; applied") and line in out
    assert main(["estimate", str(tmp_path / "fly.parquet"), "-o", str(tmp_path / "plain.parquet"), "--no-smooth"]) == 0
    assert "smoothing" not in capsys.readouterr().out
    assert b"smoother" not in (pq.read_schema(tmp_path / "plain.parquet").metadata or {})
    # --no-smooth is the estimator without it (PyTorch here; estimate ran the shipped ONNX export: 1e-5)
    model, anchor, _ = load_model(default_model_path())
    want = estimate_anchored(model, rec, dataclasses.replace(anchor, smoother=False))[EST_Q_COLS].to_numpy()
    got = pd.read_parquet(tmp_path / "plain.parquet")[EST_Q_COLS].to_numpy()
    np.testing.assert_allclose(got, want, atol=1e-4)
    # a checkpoint written before session 25 does not smooth; --smooth turns it on there
    ck = torch.load(default_model_path(), weights_only=True)
    del ck["anchor_config"]["smoother"]  # as written before session 15: the key did not exist
    torch.save(ck, tmp_path / "old.pt")
    assert main(["estimate", str(tmp_path / "fly.parquet"), "-o", str(tmp_path / "old.parquet"), "--model", str(tmp_path / "old.pt")]) == 0
    assert b"smoother" not in (pq.read_schema(tmp_path / "old.parquet").metadata or {})
    assert main(["estimate", str(tmp_path / "fly.parquet"), "-o", str(tmp_path / "old_s.parquet"), "--model",
                 str(tmp_path / "old.pt"), "--smooth"]) == 0  # fmt: skip
    assert pq.read_schema(tmp_path / "old_s.parquet").metadata[b"smoother"].decode() == line
    capsys.readouterr()
    assert main(["estimate", str(tmp_path / "fly.parquet"), "-o", str(tmp_path / "x.parquet"), "--smooth",
                 "--model", str(default_lstm_path())]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--smooth" in err[0] and "network-centred fusion" in err[0]
    assert not (tmp_path / "x.parquet").exists()


def test_an_estimator_with_an_offline_step_is_not_called_causal():
    from tepinn_flight.evaluation.estimators import TepinnEstimator
    from tepinn_flight.model.checkpoint import default_model_path

    shipped = TepinnEstimator.from_checkpoint(default_model_path(), "tepinn")
    assert not shipped.causal  # the scale reads, the gyro self-calibration and the GNSS aid read the whole record
    live = TepinnEstimator(shipped.model, dataclasses.replace(shipped.fusion, gyro_selfcal=False, gnss_aid=False,
                                                              accel_scale_selfcal=False, smoother=False))  # fmt: skip
    assert live.causal
    assert not TepinnEstimator(shipped.model, dataclasses.replace(live.fusion, accel_scale_selfcal=True)).causal
    assert shipped.fusion.smoother  # the offline smoothing reads the record both ways
    assert not TepinnEstimator(shipped.model, dataclasses.replace(live.fusion, smoother=True)).causal
    plain = shipped.unsmoothed()
    assert plain.name == "tepinn-nosmooth" and not plain.fusion.smoother and plain.unsmoothed() is None
    sm = plain.smoothed()
    assert sm.name == "tepinn-nosmooth-smooth" and sm.fusion.smoother and not sm.causal


def test_evaluate_no_smooth_scores_the_causal_tilt_beside_the_shipped_one(tmp_path, capsys):
    import json

    from tepinn_flight.cli.main import main
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import EST_Q_COLS, estimate_anchored
    from tepinn_flight.record import write_record

    rec, q_true = gentle_record(40.0)
    write_record(rec, tmp_path / "gentle.parquet")
    out = tmp_path / "rep"
    assert main(["evaluate", str(tmp_path / "gentle.parquet"), "-o", str(out), "--no-peers", "--no-smooth", "-q"]) == 0, capsys.readouterr().err
    ds = json.loads((out / "metrics.json").read_text())["dataset"]
    assert ds["tepinn"]["inclination_rmse_deg"] < 0.7 * ds["tepinn-nosmooth"]["inclination_rmse_deg"]
    # the harness's scores are the two estimates', computed here without it (evaluate's 5 s warm-up)
    model, anchor, _ = load_model(default_model_path())
    m = rec.t_s >= 5.0
    for name, cfg in (("tepinn", anchor), ("tepinn-nosmooth", dataclasses.replace(anchor, smoother=False))):
        q = estimate_anchored(model, rec, cfg)[EST_Q_COLS].to_numpy()
        want = np.degrees(np.sqrt(np.mean(inclination_error_rad(error_quat_earth(q[m], q_true[m])) ** 2)))
        assert ds[name]["inclination_rmse_deg"] == pytest.approx(want, abs=2e-3)
    assert "TE-PINN, not smoothed" in (out / "report.md").read_text()
    # --smooth adds nothing to a model that already smooths, and says so
    assert main(["evaluate", str(tmp_path / "gentle.parquet"), "-o", str(tmp_path / "rep2"), "--no-peers", "--smooth", "-q"]) == 0
    assert "tepinn-smooth" not in json.loads((tmp_path / "rep2" / "metrics.json").read_text())["dataset"]
