"""σ's gyro-saturation term (``AnchorConfig.sigma_clip_gain`` k, ``sigma_clip_tau_s`` τ): where the gyro
clips, the tilt the clipped samples may have lost enters σ (E += k·|ω|·Δt per clipped sample, decaying
over τ, at most π/2; σ² += E²), and nothing else changes."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.signal import lfilter

from tepinn_flight.model.anchor import CLIP_SIGMA_CAP_RAD, AnchorConfig, AnchoredVQF
from tests.conftest import broad_trial


def _clipped_trial(pattern: str, range_deg_s: float):
    """A real BROAD trial's first segment with its gyro saturating at ±``range_deg_s`` on every axis
    (the samples at the range marked clipped, as a reader marks them)."""
    from tepinn_flight.ingest import load_record

    rec = load_record(broad_trial(pattern))
    seg0 = rec.segment == rec.segment[0]
    lim = math.radians(range_deg_s)
    gyr = rec.gyr_rad_s[seg0]
    clipped = np.any(np.abs(gyr) >= lim, axis=1)
    return rec.t_s[seg0], np.clip(gyr, -lim, lim), rec.acc_m_s2[seg0], clipped, rec.q_ref_wxyz[seg0]


def _run(cfg, t, gyr, acc, clipped, block=None):
    ts = float(np.median(np.diff(t[:51])))
    f = AnchoredVQF(cfg, ts)
    if block is None:
        return f.update(t, gyr, acc, None, clipped), ts
    parts = [f.update(t[a:a + block], gyr[a:a + block], acc[a:a + block], None, clipped[a:a + block])
             for a in range(0, len(t), block)]  # fmt: skip
    return tuple(np.concatenate([p[i] for p in parts]) for i in (0, 2)), ts


def test_the_saturation_term_is_its_closed_form_and_changes_only_sigma_on_a_real_trial():
    t, gyr, acc, clipped, _ = _clipped_trial("broad_06_*.hdf5", 300.0)
    assert 0.05 < clipped.mean() < 0.5  # fast rotation past a ±300 °/s gyro
    shipped = AnchorConfig().learned_off
    assert shipped.sigma_clip_gain > 0
    (q_on, _, s_on, _), ts = _run(shipped, t, gyr, acc, clipped)
    (q_off, _, s_off, _), _ = _run(dataclasses.replace(shipped, sigma_clip_gain=0.0), t, gyr, acc, clipped)
    np.testing.assert_array_equal(q_on, q_off)  # σ is an output only
    # the reference: the recursion written out sample by sample, the cap included (reached here) ...
    k, tau = shipped.sigma_clip_gain, shipped.sigma_clip_tau_s
    u = k * np.linalg.norm(gyr, axis=1) * ts * clipped
    e, x, d = np.zeros(len(u)), 0.0, math.exp(-ts / tau)
    for i in range(len(u)):
        x = min(x * d + u[i], CLIP_SIGMA_CAP_RAD)
        x = 0.0 if x < 1e-9 else x  # below that the term is dropped
        e[i] = x
    assert e.max() == CLIP_SIGMA_CAP_RAD
    np.testing.assert_allclose(s_on**2 - s_off**2, e**2, rtol=1e-9, atol=1e-15)
    # ... and, away from the cap, a first-order filter through scipy
    free = lfilter([1.0], [1.0, -d], u)
    below = np.maximum.accumulate(free >= CLIP_SIGMA_CAP_RAD) == 0  # before the cap is first reached
    assert below.sum() > 1000
    np.testing.assert_allclose(e[below], np.where(free[below] < 1e-9, 0.0, free[below]), rtol=1e-9, atol=1e-12)
    assert (s_on > s_off).mean() > 0.5  # it acts (and decays: the trial's quiet end is back at σ₀)
    assert s_on[-1] == s_off[-1]
    # offline in blocks of any size: the same numbers
    (q_b, s_b), _ = _run(shipped, t, gyr, acc, clipped, block=17)
    np.testing.assert_array_equal(q_b, q_on)
    np.testing.assert_allclose(s_b, s_on, rtol=1e-12)


@pytest.mark.parametrize("pattern", ["broad_06_*.hdf5", "broad_08_*.hdf5"])
def test_sigma_covers_the_tilt_a_saturated_gyro_loses_on_a_real_trial(pattern):
    # the plain filter (no network) on real fast rotation past a ±200 °/s gyro loses tens of degrees of
    # tilt: without the term σ stays at its floor (NEES in the thousands, under half the samples within
    # 3σ); with it (the shipped k, τ, fitted on simulated flights) NEES 0.48 / 1.00, 98.5 / 98.6 % within 3σ
    from tepinn_flight.evaluation.metrics import error_quat_earth, tilt_error_vector_rad

    t, gyr, acc, clipped, q_ref = _clipped_trial(pattern, 200.0)
    cfg = AnchorConfig().learned_off
    (q, _, s_on, _), _ = _run(cfg, t, gyr, acc, clipped)
    (_, _, s_off, _), _ = _run(dataclasses.replace(cfg, sigma_clip_gain=0.0), t, gyr, acc, clipped)
    e2 = np.sum(tilt_error_vector_rad(error_quat_earth(q, q_ref)) ** 2, axis=1)
    m = np.isfinite(e2) & (t > t[0] + 5.0)
    assert math.degrees(math.sqrt(e2[m].mean())) > 10.0
    nees_off, in3_off = np.mean(e2[m] / s_off[m] ** 2), np.mean(e2[m] <= 9 * s_off[m] ** 2)
    nees_on, in3_on = np.mean(e2[m] / s_on[m] ** 2), np.mean(e2[m] <= 9 * s_on[m] ** 2)
    assert nees_off > 100 and in3_off < 0.6, (nees_off, in3_off)
    assert 0.3 < nees_on < 2.5 and in3_on >= 0.95, (nees_on, in3_on)


def test_the_term_is_capped_and_live_equals_offline():
    rng = np.random.default_rng(4)
    n, ts = 2000, 0.0025
    t = np.arange(n) * ts
    gyr = rng.normal(0, 0.3, (n, 3))
    gyr[200:900] = [7.0, 0.0, 0.0]  # 1.75 s at a ±400 °/s gyro's range: k·|ω|·1.75 s ≈ 2.4 rad
    acc = np.tile([0.0, 0.0, -9.81], (n, 1))
    clipped = np.zeros(n, bool)
    clipped[200:900] = True
    cfg = AnchorConfig().learned_off
    (_, _, s, _), _ = _run(cfg, t, gyr, acc, clipped)
    assert s.max() == pytest.approx(math.hypot(math.radians(cfg.sigma_floor_deg), CLIP_SIGMA_CAP_RAD), rel=0.02)
    samp = (np.linalg.norm(gyr, axis=1).max() * ts) ** 2 / 12  # the sampling term's most
    assert s.max() <= math.sqrt(math.radians(cfg.sigma_floor_deg) ** 2 + samp + CLIP_SIGMA_CAP_RAD**2) + 1e-12
    one = AnchoredVQF(cfg, ts)
    s_one = np.array([one.update_one(t[i], gyr[i], acc[i], None, bool(clipped[i]))[2] for i in range(n)])
    np.testing.assert_allclose(s_one, s, rtol=1e-12)


def test_sigma_fitting_counts_the_saturation_term_where_the_gyro_clips():
    from tepinn_flight.evaluation.sigma_calibration import error_samples, score
    from tepinn_flight.ingest import load_record

    rec = load_record(broad_trial("broad_06_*.hdf5"))
    plain = error_samples(rec, "b06")
    assert plain.clip_var_rad2 is None  # this trial's gyro never clips
    lim = math.radians(300.0)
    data = rec.data.copy()
    cols = ["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"]
    sat = (data[cols].abs() >= lim).any(axis=1).to_numpy()
    data[cols] = data[cols].clip(-lim, lim)
    data["clipped"] = sat
    data["gyr_clipped"] = sat
    clip = error_samples(type(rec)(data, dict(rec.meta)), "b06 at ±300 °/s")
    assert clip.clip_var_rad2 is not None and clip.clip_var_rad2.max() > math.radians(10) ** 2
    cfg = AnchorConfig()
    n_with, cv_with = score([clip], cfg.sigma_floor_deg, cfg.sigma_acc_gain, cfg.sigma_sampling_gain)
    n_without, cv_without = score([dataclasses.replace(clip, clip_var_rad2=None)], cfg.sigma_floor_deg,
                                  cfg.sigma_acc_gain, cfg.sigma_sampling_gain)  # fmt: skip
    assert n_with < 0.01 * n_without and cv_with > cv_without + 0.3
