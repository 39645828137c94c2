"""σ's vibration term of a smoothed sample (rule 41): the accelerometer's running sample noise against a naive loop
and against known white noise, and σ of a smoothed sample against its formula."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.model.smoother import SmootherConfig, smooth, vibration_sigma
from tepinn_flight.record_stats import running_sample_noise, sample_noise, second_differences


def test_the_running_sample_noise_against_a_naive_loop():
    # uneven sampling, two segments, a NaN sample: per sample √(mean over axes and the centred window's finite
    # second differences (within the segment) of d² / 6)
    rng = np.random.default_rng(11)
    n = 500
    t = np.cumsum(rng.uniform(0.002, 0.01, n))
    seg = np.r_[np.zeros(200, np.int64), np.ones(n - 200, np.int64)]
    x = rng.normal(0.0, 1.0, (n, 3)) + np.sin(t)[:, None]
    x[77] = np.nan
    got = running_sample_noise(t, x, seg, 0.5)
    want = np.zeros(n)
    for i in range(n):
        vals = []
        for j in range(n):
            if seg[j] != seg[i] or abs(t[j] - t[i]) > 0.25 or j == 0 or j == n - 1:
                continue
            if seg[j - 1] != seg[j] or seg[j + 1] != seg[j]:
                continue
            d = x[j - 1] - 2 * x[j] + x[j + 1]
            if np.all(np.isfinite(d)):
                vals.append(np.mean(d * d) / 6.0)
        want[i] = math.sqrt(np.mean(vals)) if vals else 0.0
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)


def test_white_noise_reads_its_sigma_and_the_per_record_reading_is_the_same_formula():
    rng = np.random.default_rng(5)
    n = 40000
    t = np.arange(n) * 0.0025
    seg = np.zeros(n, np.int64)
    x = np.c_[np.sin(0.5 * t), np.cos(0.3 * t), np.full(n, -9.81)] + rng.normal(0.0, 0.7, (n, 3))
    r = running_sample_noise(t, x, seg, 1.0)
    assert np.median(r) == pytest.approx(0.7, rel=0.02)
    assert sample_noise(x, seg, 0.0025) == pytest.approx(np.median(r), rel=0.02)
    d = second_differences(x, seg)
    assert np.isnan(d[0]).all() and np.isnan(d[-1]).all()
    np.testing.assert_allclose(d[1:-1], x[:-2] - 2 * x[1:-1] + x[2:])


def test_sigma_of_a_smoothed_sample_takes_the_vibration_term():
    # a fully weighted smoothed sample's σ is sqrt((s·σ)² + (k·R)² + (k_v·N·√Δt)²), Δt the segment's period; k_v = 0 is rule 40's σ bit for bit
    n = 6000
    t = np.arange(n) * 0.01
    seg, gate = np.zeros(n, np.int32), np.zeros(n)
    gate[:1000] = 1.0
    q = Rotation.from_euler("ZYX", np.c_[0.1 * t, np.zeros(n), np.zeros(n)]).as_quat()[:, [3, 0, 1, 2]]
    gyr = np.c_[np.sin(0.3 * t), np.zeros(n), np.full(n, 0.1)]
    rng = np.random.default_rng(3)
    acc = np.tile([0.0, 0.0, -9.81], (n, 1)) + rng.normal(0.0, 1.0 + (t > 40)[:, None] * 3.0, (n, 3))
    sigma = np.full(n, 0.01)

    def offline(sl):
        return q[sl]

    base = dict(min_stretch_s=20.0, ramp_s=5.0, sigma_disagreement_gain=0.0)
    cfg0 = SmootherConfig(**base, sigma_vibration_gain=0.0)
    _, s0, _ = smooth(t, q, sigma, gate, seg, cfg0, offline, gyr_rad_s=gyr, acc_m_s2=acc)
    _, s_none, _ = smooth(t, q, sigma, gate, seg, cfg0, offline, gyr_rad_s=gyr)
    np.testing.assert_array_equal(s0, s_none)
    kv = 0.05
    cfg = SmootherConfig(**base, sigma_vibration_gain=kv)
    q1, s1, _ = smooth(t, q, sigma, gate, seg, cfg, offline, gyr_rad_s=gyr, acc_m_s2=acc)
    from tepinn_flight.model.rotation_memory import rotation_memory

    r = cfg.sigma_rotation_gain * rotation_memory(t, gyr, seg, cfg.sigma_rotation_tau_s)
    v = kv * running_sample_noise(t, acc, seg, 1.0) * math.sqrt(0.01)
    full = slice(1600, n)
    np.testing.assert_allclose(s1[full], np.sqrt((cfg.sigma_scale * 0.01) ** 2 + r[full] ** 2 + v[full] ** 2), rtol=1e-12)
    np.testing.assert_allclose(vibration_sigma(t, acc, seg), v / kv, rtol=1e-12)
    np.testing.assert_array_equal(s1[:1000], sigma[:1000])
    assert np.median(s1[4500:]) > np.median(s1[2000:3500])  # louder after 40 s: larger σ


def test_the_vibration_setting_is_checked():
    from tepinn_flight.errors import ConfigError

    with pytest.raises(ConfigError):
        SmootherConfig(sigma_vibration_gain=-0.01)
