"""σ's rotation term of a smoothed sample (rule 40, model/rotation_memory.py and the smoothing's use of it): the
rotation memory against a naive double sum and a closed form, and σ of a smoothed sample against its formula."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.model.rotation_memory import MAX_STEP_S, rotation_memory
from tepinn_flight.model.smoother import SmootherConfig, smooth


def _naive(t, gyr, seg, tau):
    """R_i = (Σ_{j≤i} |ω_j| Δt_j e^{-(t_i-t_j)/τ} + Σ_{j≥i} |ω_j| Δt'_j e^{-(t_j-t_i)/τ}) / 2 within a segment, the
    decay over the steps counted (each step at most MAX_STEP_S), sample by sample."""
    n = len(t)
    rate = np.linalg.norm(gyr, axis=1)
    rate[~np.isfinite(rate)] = 0.0
    out = np.zeros(n)
    for i in range(n):
        same = np.flatnonzero(seg == seg[i])
        a, b = same[0], same[-1]
        steps = np.minimum(np.maximum(np.diff(t[a : b + 1]), 0.0), MAX_STEP_S)  # step k: from a+k to a+k+1
        clock = np.r_[0.0, np.cumsum(steps)]  # the counted time of each sample of the segment
        c_i = clock[i - a]
        f = sum(rate[j] * steps[j - a - 1] * math.exp(-(c_i - clock[j - a]) / tau) for j in range(a + 1, i + 1))
        bk = sum(rate[j] * steps[j - a] * math.exp(-(clock[j - a] - c_i) / tau) for j in range(i, b))
        out[i] = 0.5 * (f + bk)
    return out


def test_the_rotation_memory_against_a_naive_double_sum():
    # uneven sampling, two segments, a non-finite rate (no rotation) and a logging gap (counted as MAX_STEP_S)
    rng = np.random.default_rng(7)
    n = 400
    t = np.cumsum(rng.uniform(0.002, 0.02, n))
    t[250:] += 3.0  # a gap inside the second segment
    seg = np.r_[np.zeros(150, np.int64), np.ones(n - 150, np.int64)]
    gyr = rng.normal(0.0, 2.0, (n, 3))
    gyr[40] = np.nan
    for tau in (0.3, 1.0):
        np.testing.assert_allclose(rotation_memory(t, gyr, seg, tau), _naive(t, gyr, seg, tau), rtol=1e-12, atol=1e-14)


def test_a_steady_turn_reaches_the_closed_form():
    # |ω| = 2 rad/s at 100 Hz for 60 s: far from the ends F = B = ω·Δt / (1 − e^{−Δt/τ}) (the geometric series; F
    # counts the step ending at i, B the step starting at i), so R = ω·Δt / (1 − e^{−Δt/τ}) ≈ ω·τ
    dt, tau, w = 0.01, 1.0, 2.0
    t = np.arange(6000) * dt
    gyr = np.tile([0.0, w / math.sqrt(2.0), w / math.sqrt(2.0)], (len(t), 1))
    r = rotation_memory(t, gyr, np.zeros(len(t), np.int64), tau)
    assert r[3000] == pytest.approx(w * dt / (1.0 - math.exp(-dt / tau)), rel=1e-9)
    assert r[0] == pytest.approx(0.5 * r[3000], rel=1e-6)  # at an end only the other side has turned
    assert np.all(r >= 0.0)


def test_sigma_of_a_smoothed_sample_takes_the_rotation_term():
    # the stand-in offline filter returns the causal attitude (no disagreement): a fully weighted smoothed sample's σ
    # is sqrt((s·σ)² + (k·R)²); the ramp's samples take w·(…) as the formula says; gated samples are untouched and
    # the attitude is the same whatever k; k = 0 is the σ of before bit for bit
    n = 6000
    t = np.arange(n) * 0.01
    seg, gate = np.zeros(n, np.int32), np.zeros(n)
    gate[:1000] = 1.0
    q = Rotation.from_euler("ZYX", np.c_[0.1 * t, np.zeros(n), np.zeros(n)]).as_quat()[:, [3, 0, 1, 2]]
    gyr = np.c_[np.sin(0.3 * t), np.zeros(n), np.full(n, 0.1)] * 3.0
    sigma = np.full(n, 0.01)

    def offline(sl):
        return q[sl]

    base = SmootherConfig(min_stretch_s=20.0, ramp_s=5.0, sigma_disagreement_gain=0.0, sigma_rotation_gain=0.0)
    q0, s0, _ = smooth(t, q, sigma, gate, seg, base, offline)
    q_none, s_none, _ = smooth(t, q, sigma, gate, seg, base, offline, gyr_rad_s=gyr)
    np.testing.assert_array_equal(s_none, s0)  # gain 0: no term
    k, tau = 0.002, 1.0
    cfg = SmootherConfig(min_stretch_s=20.0, ramp_s=5.0, sigma_disagreement_gain=0.0, sigma_rotation_gain=k,
                         sigma_rotation_tau_s=tau)  # fmt: skip
    q1, s1, done = smooth(t, q, sigma, gate, seg, cfg, offline, gyr_rad_s=gyr)
    assert done.applied
    np.testing.assert_array_equal(q1, q0)
    r = rotation_memory(t, gyr, seg, tau)
    full = slice(1600, n)  # past the 5-s ramp from the gate's edge at 10 s
    np.testing.assert_allclose(s1[full], np.sqrt((cfg.sigma_scale * 0.01) ** 2 + (k * r[full]) ** 2), rtol=1e-12)
    w = (s0[1000:1500] / 0.01 - 1.0) / (base.sigma_scale - 1.0)  # the ramp's weights, read from σ without the term
    np.testing.assert_allclose(s1[1000:1500], np.hypot(s0[1000:1500], w * k * r[1000:1500]), rtol=1e-12)
    np.testing.assert_array_equal(s1[:1000], sigma[:1000])
    assert np.all(s1 >= s0)


def test_the_rotation_settings_are_checked():
    from tepinn_flight.errors import ConfigError

    for bad in ({"sigma_rotation_gain": -0.001}, {"sigma_rotation_tau_s": 0.0}, {"sigma_rotation_gain": float("nan")}):
        with pytest.raises(ConfigError):
            SmootherConfig(**bad)
