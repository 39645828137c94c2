"""The anchored filter's compiled steps (``model/anchor_steps.py``, through :class:`AnchoredVQF`) against the former
Python class on the ``vqf`` package's C++ VQF (``tests/anchor_reference.py``): the same estimates.

Every gate is driven: windows at flight speed (ramped, GNSS-aided, aided and fast), saturated gyro samples (a range
the network learned and one it did not), a tumble then a rest (the re-levelling), an uncalibrated gyro (the bias
gate's evidence and latch), holes, lost samples and jittered stamps, a gyro scale, the magnetometer; the samples in
blocks between windows, one at a time (live), and a whole segment at once. The attitude and the bias must be the
same bits; σ the same to 1e-14 (the former code squared with Python's ``**`` and took ``math.hypot``, which round
differently in the last bit from ``x * x`` and libm's ``hypot`` in a few samples of the gap term)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tepinn_flight.model.anchor import AnchorConfig, AnchoredVQF, WindowOutput, window_rows
from tepinn_flight.model.synthetic import synthetic_record

from .anchor_reference import AnchoredVQFReference

SIGMA_RTOL = 1e-14


def _record(seed: int, rate_hz: float = 200.0, duration_s: float = 24.0):
    """A synthetic record's arrays, with a saturating stretch, a tumble past a learned range, a rest, holes, lost
    samples and jittered stamps; an uncalibrated gyro on odd seeds."""
    rec = synthetic_record(seed=seed, duration_s=duration_s, rate_hz=rate_hz, max_rate_rad_s=5.0,
                           gyr_bias_rad_s=0.08 if seed % 2 else 0.002)  # fmt: skip
    rng = np.random.default_rng(seed)
    t, gyr, acc = rec.t_s.copy(), rec.gyr_rad_s.copy(), rec.acc_m_s2.copy()
    n = len(t)
    mag = np.tile([20.0, 0.0, 45.0], (n, 1)) + rng.normal(0, 0.5, (n, 3))
    clipped = np.zeros(n, bool)
    a, b = n // 6, n // 6 + int(0.6 * rate_hz)  # saturated at ±400 °/s (a range the network learned)
    gyr[a:b, 0] = np.clip(gyr[a:b, 0] * 4, -math.radians(400), math.radians(400))
    clipped[a:b] = np.abs(gyr[a:b, 0]) >= math.radians(400) - 1e-9
    clipped[a : a + 30] = True
    c = n // 3  # a tumble read past ±2000 °/s, then a rest
    gyr[c : c + 20] = [math.radians(2100), 0.0, 0.0]
    clipped[c : c + 20] = True
    r0, r1 = c + 20, c + 20 + int(2.5 * rate_hz)
    gyr[r0:r1] = rng.normal(0, 0.002, (r1 - r0, 3))
    acc[r0:r1] = [0.3, -0.2, -9.8] + rng.normal(0, 0.02, (r1 - r0, 3))
    d = 2 * n // 3  # another saturated spell, then a still rest: the re-levelling
    gyr[d : d + 40] = [math.radians(400), 0.0, 0.0]
    clipped[d : d + 40] = True
    gyr[d + 40 : d + 40 + int(2 * rate_hz)] = 0.0
    acc[d + 40 : d + 40 + int(2 * rate_hz)] = [0.0, 0.0, -9.81]
    for k in rng.choice(n, 6, replace=False):  # holes
        (gyr if k % 2 else acc)[k, rng.integers(3)] = np.nan
    mag[rng.choice(n, 4, replace=False)] = np.nan
    keep = rng.random(n) > 0.01  # lost samples, jittered stamps
    t = t + rng.uniform(-0.05, 0.05, n) / rate_hz
    return tuple(np.ascontiguousarray(x[keep]) for x in (t, gyr, acc, mag)) + (clipped[keep],)


def _windows(seed: int, n_win: int):
    """Network outputs that drive every gate: tilts off by up to 15°, |v̂| across the flight-speed ramp, a fusion
    bias beyond the uncalibrated-gyro gate on stretches, some windows GNSS-aided (some fast)."""
    rng = np.random.default_rng(100 + seed)
    q = np.column_stack([np.ones(n_win), rng.normal(0, 0.08, (n_win, 2)), np.zeros(n_win)])
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    speed = np.clip(np.cumsum(rng.normal(0, 3.0, n_win)) % 60.0, 0, None)
    vel = np.column_stack([speed, rng.normal(0, 2, n_win), rng.normal(0, 1, n_win)])
    fus = np.zeros((n_win, 3))
    on = (np.arange(n_win) // 40) % 3 == 1  # 3.2 s on end at 200 Hz
    fus[on] = [math.radians(4.0), math.radians(-1.0), 0.0]
    fus += rng.normal(0, 0.005, (n_win, 3))
    return dict(q=q, sigma=rng.uniform(0.01, 0.2, n_win).astype(np.float32), bias=rng.normal(0, 0.01, (n_win, 3)),
                vel=vel, acc_v=rng.normal(0, 2, (n_win, 3)), fusion=fus, aided=rng.random(n_win) < 0.2,
                fast=rng.random(n_win) < 0.5)  # fmt: skip


def _reference(cfg, ts, use_mag, rec, ends, w, with_fusion=True, vehicle=None):
    t, gyr, acc, mag, clipped = rec
    ref = AnchoredVQFReference(cfg, ts, use_mag, vehicle)
    n = len(t)
    q, s, b = np.full((n, 4), np.nan), np.full(n, np.nan), np.full((n, 3), np.nan)
    gates, parts, cur = [], [], 0
    for j, e in enumerate(ends):
        i = int(e) + 1
        if i > cur:
            q6, q9, sg, bb = ref.update(t[cur:i], gyr[cur:i], acc[cur:i], mag[cur:i] if use_mag else None, clipped[cur:i])
            q[cur:i], s[cur:i], b[cur:i] = q9 if use_mag else q6, sg, bb
            cur = i
        ref.correct(WindowOutput(w["q"][j], float(w["sigma"][j]), w["bias"][j], w["vel"][j], w["acc_v"][j],
                                 w["fusion"][j] if with_fusion else None, bool(w["aided"][j]), bool(w["fast"][j])))  # fmt: skip
        gates.append(ref.gate)
        parts.append(ref.gate_parts)
    q6, q9, sg, bb = ref.update(t[cur:], gyr[cur:], acc[cur:], mag[cur:] if use_mag else None, clipped[cur:])
    q[cur:], s[cur:], b[cur:] = q9 if use_mag else q6, sg, bb
    return q, s, b, np.array(gates), np.array(parts), ref.relevel_t, ref


def _same(a_q, a_s, a_b, b_q, b_s, b_b):
    np.testing.assert_array_equal(a_q, b_q)
    np.testing.assert_array_equal(a_b, b_b)
    np.testing.assert_allclose(a_s, b_s, rtol=SIGMA_RTOL, atol=0)


CONFIGS = {
    "shipped": AnchorConfig(),
    "every gate": dataclasses.replace(AnchorConfig(), speed_lo_m_s=5.0, speed_hi_m_s=15.0, bias_gate_fusion_deg_s=2.0,
                                      bias_clip_deg_s=0.5, bias_gate_vqf_deg_s=0.1, bias_gate_thrust_deg=120.0,
                                      sigma_acc_gain=0.02, gyro_scale=(1.02, 0.98, 1.0)),  # fmt: skip
    "no re-levelling, old rules": dataclasses.replace(AnchorConfig(), rest_relevel_s=0.0, clip_gate_max_deg_s=0.0,
                                                      gyro_step_weighting=False, rest_keeps_run=False,
                                                      tau_acc_flight_s=0.0, clip_min_s=0.0),  # fmt: skip
}


@pytest.mark.parametrize("name", list(CONFIGS))
@pytest.mark.parametrize("seed,use_mag", [(1, False), (2, False), (3, True)])
def test_a_segment_at_once_and_in_blocks_is_the_reference(name, seed, use_mag):
    cfg = CONFIGS[name]
    rec = _record(seed)
    t = rec[0]
    ts = float(np.median(np.diff(t[:50])))
    ends = np.arange(40, len(t) - 5, 16)
    w = _windows(seed, len(ends))
    r_q, r_s, r_b, r_g, r_p, r_rl, ref = _reference(cfg, ts, use_mag, rec, ends, w)
    assert (bool(r_rl) == (cfg.rest_relevel_s > 0)) and r_g.max() > 0 and ref.holes > 0  # the scenario drove it
    if name == "every gate":  # the flight-speed and saturation gates; the uncalibrated gyro's where its bias is
        assert {0, 1} <= set(np.flatnonzero(r_p.max(0) > 0))
        assert ref.bias_latched == (r_p[:, 2].max() > 0) and (ref.bias_latched or seed != 1)
    seg = AnchoredVQF(cfg, ts, use_mag)  # a segment at once
    wins = window_rows(w["q"], w["sigma"], w["bias"], w["vel"], w["acc_v"], w["fusion"], w["aided"], w["fast"])
    q, s, b, gates, parts, relevel = seg.run_windows(rec[0], rec[1], rec[2], rec[3], rec[4], ends, wins)
    _same(q, s, b, r_q, r_s, r_b)
    np.testing.assert_array_equal(gates, r_g)
    np.testing.assert_array_equal(parts, r_p)
    assert seg.relevel_t == r_rl and relevel.sum() == len(r_rl) and seg.holes == ref.holes
    blk = AnchoredVQF(cfg, ts, use_mag)  # in blocks between windows, as the live estimator's correct()
    t_, g_, a_, m_, c_ = rec
    q2, s2, b2 = np.full_like(r_q, np.nan), np.full_like(r_s, np.nan), np.full_like(r_b, np.nan)
    cur = 0
    for j, e in enumerate(ends):
        i = int(e) + 1
        q6, q9, sg, bb = blk.update(t_[cur:i], g_[cur:i], a_[cur:i], m_[cur:i] if use_mag else None, c_[cur:i])
        q2[cur:i], s2[cur:i], b2[cur:i] = q9 if use_mag else q6, sg, bb
        cur = i
        blk.correct(WindowOutput(w["q"][j], float(w["sigma"][j]), w["bias"][j], w["vel"][j], w["acc_v"][j], w["fusion"][j],
                                 bool(w["aided"][j]), bool(w["fast"][j])))  # fmt: skip
        assert blk.gate == r_g[j] and blk.gate_parts == tuple(r_p[j])
    q6, q9, sg, bb = blk.update(t_[cur:], g_[cur:], a_[cur:], m_[cur:] if use_mag else None, c_[cur:])
    q2[cur:], s2[cur:], b2[cur:] = q9 if use_mag else q6, sg, bb
    _same(q2, s2, b2, r_q, r_s, r_b)
    assert blk.relevel_t == r_rl


def test_a_hand_held_imu_is_the_reference_too():
    """Rules 31 and 33 (the uncalibrated-gyro gate's older-fusion path shut, and no pull of that gate, on a hand-held
    IMU): the compiled steps against the reference, told the vehicle, where every gate acts, with and without those
    rules — which change the estimate (the scenario reaches them; the flight-speed gate is shut in both)."""
    rec = _record(1)
    ts = float(np.median(np.diff(rec[0][:50])))
    ends = np.arange(40, len(rec[0]) - 5, 16)
    w = _windows(1, len(ends))
    wins = window_rows(w["q"], w["sigma"], w["bias"], w["vel"], w["acc_v"], w["fusion"], w["aided"], w["fast"])
    every = CONFIGS["every gate"]
    out = []
    for cfg, latches in ((every, False),  # rule 31: the older fusion's evidence, which latches it here, not used
                         (dataclasses.replace(every, bias_gate_fusion_shut_for=()), True),  # rule 33 alone: no pull
                         (dataclasses.replace(every, bias_gate_fusion_shut_for=(), bias_pull_shut_for=()), True)):  # fmt: skip
        r_q, r_s, r_b, r_g, r_p, _, _ = _reference(cfg, ts, False, rec, ends, w, vehicle="handheld-imu")
        q, s, b, gates, parts, _ = AnchoredVQF(cfg, ts, False, "handheld-imu").run_windows(*rec, ends, wins)
        _same(q, s, b, r_q, r_s, r_b)
        np.testing.assert_array_equal(gates, r_g)
        np.testing.assert_array_equal(parts, r_p)
        assert parts[:, 0].max() == 0 and bool(parts[:, 2].max() > 0) is latches  # never the flight-speed gate
        out.append(q)
    assert np.nanmax(np.abs(out[1] - out[2])) > 1e-3  # the pull


@pytest.mark.parametrize("seed,use_mag", [(4, False), (5, True)])
def test_one_sample_at_a_time_is_the_reference_one_sample_at_a_time(seed, use_mag):
    """The live path (``update_one``) against the reference's ``update_one``, windows every 16 samples; the older
    fusion's bias absent on half of them."""
    cfg = CONFIGS["every gate"]
    t, gyr, acc, mag, clipped = _record(seed, rate_hz=100.0, duration_s=16.0)
    ts = float(np.median(np.diff(t[:50])))
    w = _windows(seed, len(t) // 16 + 1)
    ref, new = AnchoredVQFReference(cfg, ts, use_mag), AnchoredVQF(cfg, ts, use_mag)
    for i in range(len(t)):
        m = mag[i] if use_mag and i % 7 else None
        a = ref.update_one(t[i], gyr[i], acc[i], m, bool(clipped[i]))
        b = new.update_one(t[i], gyr[i], acc[i], m, bool(clipped[i]))
        assert a[0] == b[0] and a[1] == b[1] and a[3] == b[3]
        assert b[2] == pytest.approx(a[2], rel=SIGMA_RTOL, abs=0)
        if i % 16 == 15:
            j = i // 16
            win = WindowOutput(w["q"][j], float(w["sigma"][j]), w["bias"][j], w["vel"][j], w["acc_v"][j],
                               w["fusion"][j] if j % 2 else None, bool(w["aided"][j]), bool(w["fast"][j]))  # fmt: skip
            ref.correct(win)
            new.correct(win)
            assert ref.gate == new.gate and ref.gate_parts == new.gate_parts
    assert new.relevel_t == ref.relevel_t and ref.relevel_t and new.holes == ref.holes > 0


def test_a_changed_rule_is_seen():
    """The comparison can fail: the compiled steps with a pull 1 % weaker differ."""
    cfg = CONFIGS["shipped"]
    rec = _record(1)
    ts = float(np.median(np.diff(rec[0][:50])))
    ends = np.arange(40, len(rec[0]) - 5, 16)
    w = _windows(1, len(ends))
    r_q = _reference(cfg, ts, False, rec, ends, w)[0]
    seg = AnchoredVQF(dataclasses.replace(cfg, pull_gain=0.99 * cfg.pull_gain), ts)
    wins = window_rows(w["q"], w["sigma"], w["bias"], w["vel"], w["acc_v"], w["fusion"], w["aided"], w["fast"])
    q = seg.run_windows(rec[0], rec[1], rec[2], None, rec[4], ends, wins)[0]
    assert not np.array_equal(q, r_q)


def test_the_saturated_samples_queue_grows():
    """More saturated samples than the queue holds between two windows: it grows, and forgets none."""
    cfg = dataclasses.replace(AnchorConfig(), rest_relevel_s=0.0)
    n = 500
    t = np.arange(n) * 0.01
    gyr, acc = np.tile([0.5, 0.0, 0.0], (n, 1)), np.tile([0.0, 0.0, -9.81], (n, 1))
    new, ref = AnchoredVQF(cfg, 0.01), AnchoredVQFReference(cfg, 0.01)
    assert len(new.cb) < n
    for f in (new, ref):
        f.update(t, gyr, acc, clipped=np.ones(n, bool))
        f.correct(WindowOutput((1.0, 0.0, 0.0, 0.0), 0.05, np.zeros(3), np.zeros(3), np.zeros(3)))
    assert len(new.cb) >= n and new.gate == ref.gate == 1.0
