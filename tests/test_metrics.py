"""Metrics against hand-computed cases and independent references (scipy Rotation / scipy.stats)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tepinn_flight.evaluation import metrics as M

Rotation = pytest.importorskip("scipy.spatial.transform").Rotation


def wxyz(r) -> np.ndarray:
    """scipy Rotation → our (w, x, y, z) (scipy is x, y, z, w; same Hamilton/active convention)."""
    return np.roll(r.as_quat(), 1, axis=-1)


def test_constant_error_gives_known_inclination_heading_split():
    rng = np.random.default_rng(1)
    n = 500
    ref = Rotation.random(n, random_state=2)
    incl_true, head_true = math.radians(7.0), math.radians(-25.0)
    axis = np.array([math.cos(0.3), math.sin(0.3), 0.0])  # horizontal axis (earth frame)
    err = Rotation.from_rotvec([0, 0, head_true]) * Rotation.from_rotvec(axis * incl_true)
    est = err * ref  # earth-frame error: q_est = q_e ⊗ q_ref
    q_e = M.error_quat_earth(wxyz(est), wxyz(ref) * rng.choice([-1.0, 1.0], (n, 1)))  # sign flips must not matter
    np.testing.assert_allclose(M.inclination_error_rad(q_e), incl_true, atol=1e-9)
    np.testing.assert_allclose(M.heading_error_rad(q_e), abs(head_true), atol=1e-9)
    np.testing.assert_allclose(M.signed_heading_error_rad(q_e), head_true, atol=1e-9)
    np.testing.assert_allclose(M.total_error_rad(q_e), err.magnitude(), atol=1e-9)
    # the 2-D tilt error vector of a pure tilt has the tilt's axis and angle
    tilt_only = M.error_quat_earth(wxyz(Rotation.from_rotvec(axis * incl_true) * ref), wxyz(ref))
    np.testing.assert_allclose(M.tilt_error_vector_rad(tilt_only), np.broadcast_to(axis[:2] * incl_true, (n, 2)), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(M.tilt_error_vector_rad(q_e), axis=1), incl_true, atol=1e-9)


@pytest.mark.parametrize("offset_deg", [30.0, 179.0, -179.5])
def test_heading_alignment_removes_exactly_a_constant_yaw_offset(offset_deg):
    rng = np.random.default_rng(3)
    n = 2000
    ref = Rotation.random(n, random_state=4)
    tilt = Rotation.from_rotvec(np.c_[rng.normal(0, 0.02, (n, 2)), np.zeros(n)])  # small tilt errors
    est = Rotation.from_rotvec([0, 0, math.radians(offset_deg)]) * tilt * ref
    q_est, q_ref = wxyz(est), wxyz(ref)
    incl_before = M.inclination_error_rad(M.error_quat_earth(q_est, q_ref))
    delta = M.heading_offset_rad(q_est, q_ref)
    # the offset is recovered (circular mean across the ±180° wrap); the tilt errors' own heading parts
    # average out to ~0
    assert abs(M.wrap_angle(delta - math.radians(offset_deg))) < 2e-4
    q_al = M.align_heading(q_est, delta)
    q_e = M.error_quat_earth(q_al, q_ref)
    np.testing.assert_allclose(M.inclination_error_rad(q_e), incl_before, atol=1e-12)  # tilt untouched
    assert M.rmse(M.heading_error_rad(q_e)) < 2e-3  # only the tilt errors' tiny heading part is left
    # a pure yaw offset is removed completely
    q_al2 = M.align_heading(wxyz(Rotation.from_rotvec([0, 0, math.radians(offset_deg)]) * ref), delta)
    assert np.max(M.total_error_rad(M.error_quat_earth(q_al2, q_ref))) < 2e-4


def test_alignment_removes_only_the_mean_of_a_heading_ramp_and_drift_slope():
    n = 6001
    t = np.linspace(0.0, 600.0, n)  # 10 minutes
    rate_deg_min = 90.0  # ramp across several ±180° wraps of the signed error: 900° in total
    ramp = np.radians(rate_deg_min / 60.0 * t) + 0.4
    ref = Rotation.random(n, random_state=5)
    est = Rotation.from_rotvec(np.c_[np.zeros(n), np.zeros(n), ramp]) * ref
    q_est, q_ref = wxyz(est), wxyz(ref)
    e_h = M.signed_heading_error_rad(M.error_quat_earth(q_est, q_ref))
    assert M.drift_rate_deg_per_min(t, e_h) == pytest.approx(rate_deg_min, rel=1e-9)
    short = t < 60  # 90° over the first minute: no wrap; alignment leaves the centred ramp
    d = M.heading_offset_rad(q_est[short], q_ref[short])
    q_e = M.error_quat_earth(M.align_heading(q_est[short], d), q_ref[short])
    span = math.radians(rate_deg_min / 60.0 * (t[short][-1] - t[short][0]))
    assert M.rmse(M.heading_error_rad(q_e)) == pytest.approx(span / math.sqrt(12), rel=2e-3)


def test_score_run_aligns_each_run_separately_and_drift():
    n = 2000
    t = np.arange(n) * 0.01
    ref = Rotation.random(n, random_state=6)
    runs = (np.arange(n) >= 1000).astype(int)
    yaw = np.where(runs == 0, 0.5, -2.0)  # a different heading origin per filter run
    est = Rotation.from_rotvec(np.c_[np.zeros(n), np.zeros(n), yaw]) * ref
    s = M.score_run(t, wxyz(est), wxyz(ref), np.ones(n, bool), runs=runs)
    assert s["total_rmse_rad"] < 1e-7 and s["heading_rmse_rad"] < 1e-7
    np.testing.assert_allclose(s["heading_offsets_rad"], [0.5, -2.0], atol=1e-9)
    s9 = M.score_run(t, wxyz(est), wxyz(ref), np.ones(n, bool), runs=runs, align=False)
    assert s9["heading_rmse_rad"] == pytest.approx(math.sqrt((0.5**2 + 2.0**2) / 2), rel=1e-9)


def test_roll_pitch_errors_and_quaternion_distance():
    n = 300
    rng = np.random.default_rng(7)
    r, p, y = rng.uniform(-3, 3, n), rng.uniform(-1.2, 1.2, n), rng.uniform(-3, 3, n)
    dr, dp = 0.03, -0.02
    ref = Rotation.from_euler("ZYX", np.c_[y, p, r])  # aerospace yaw-pitch-roll, intrinsic
    est = Rotation.from_euler("ZYX", np.c_[y, p + dp, r + dr])
    er, ep, ey = M.euler_errors_rad(wxyz(est), wxyz(ref))
    np.testing.assert_allclose(er, dr, atol=1e-9)  # also across the ±π roll wrap
    np.testing.assert_allclose(ep, dp, atol=1e-9)
    np.testing.assert_allclose(ey, 0.0, atol=1e-9)
    ang = 0.2
    q_ref = wxyz(Rotation.random(n, random_state=8))
    q_est = wxyz(Rotation.from_rotvec([ang, 0, 0]) * Rotation.from_quat(np.roll(q_ref, -1, axis=1)))
    q_est[::2] *= -1  # q ≡ −q
    np.testing.assert_allclose(M.quat_distance(q_est, q_ref), 2 * math.sin(ang / 4), atol=1e-12)
    np.testing.assert_allclose(M.quat_angle_error_rad(q_est, q_ref), ang, atol=1e-9)


def test_rmse_masks_and_nans():
    e = np.array([1.0, np.nan, 3.0, 100.0])
    assert M.rmse(e, np.array([True, True, True, False])) == pytest.approx(math.sqrt(5.0))
    assert math.isnan(M.rmse(e, np.zeros(4, bool)))


def test_dynamic_error_bins_and_bias_error_by_hand():
    err = np.radians([1.0, 2.0, 3.0, 4.0, 5.0])
    rate = np.radians([10.0, 20.0, 50.0, 500.0, 100.0])
    sq, cnt = M.binned_sq_error(err, rate, np.array([True, True, True, True, False]))
    assert cnt.tolist() == [2, 1, 0, 0, 0, 1]
    np.testing.assert_allclose(np.degrees(M.binned_rmse(sq, cnt))[[0, 1, 5]], [math.sqrt(2.5), 3.0, 4.0])
    assert np.isnan(M.binned_rmse(sq, cnt)[2])
    b_true = np.zeros((4, 3))
    b_est = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [np.nan, 0.0, 0.0]])
    out = M.bias_error_rms(b_est, b_true)
    assert out["total"] == pytest.approx(math.sqrt((25 + 0 + 1) / 3))
    np.testing.assert_allclose(out["axes"], [math.sqrt(10 / 3), math.sqrt(16 / 3), 0.0])


def test_coverage_and_nees_on_synthetic_gaussian_errors():
    rng = np.random.default_rng(9)
    n = 200_000
    sigma = rng.uniform(0.005, 0.05, n)
    e = rng.normal(size=(n, 2)) * sigma[:, None]
    u = M.uncertainty_metrics(e, sigma)
    for k, expected in ((1, 0.3935), (2, 0.8647), (3, 0.9889)):
        assert u[f"coverage_{k}sigma"] == pytest.approx(expected, abs=0.004)
        assert M.COVERAGE_EXPECTED_2D[k] == pytest.approx(expected, abs=1e-4)
    assert u["nees"] == pytest.approx(2.0, rel=0.02)
    assert u["spearman"] > 0.5
    over = M.uncertainty_metrics(e, sigma / 2)  # overconfident σ: NEES × 4, coverage collapses
    assert over["nees"] == pytest.approx(8.0, rel=0.02)
    assert over["coverage_1sigma"] == pytest.approx(1 - math.exp(-1 / 8), abs=0.004)


def test_rank_and_spearman_match_scipy():
    stats = pytest.importorskip("scipy.stats")
    rng = np.random.default_rng(10)
    x = rng.integers(0, 20, 300).astype(float)  # many ties
    y = x + rng.normal(0, 5, 300)
    np.testing.assert_allclose(M.rankdata(x), stats.rankdata(x))
    assert M.spearman(x, y) == pytest.approx(stats.spearmanr(x, y).statistic, abs=1e-12)


@pytest.mark.parametrize("n, ties, alternative", [(12, False, "two-sided"), (12, False, "less"), (20, False, "greater"),
                                                   (60, False, "two-sided"), (40, True, "two-sided"), (40, True, "less")])
def test_wilcoxon_matches_scipy(n, ties, alternative):
    stats = pytest.importorskip("scipy.stats")
    rng = np.random.default_rng(n + ties)
    a = rng.normal(1.0, 0.3, n)
    b = a + rng.normal(0.15, 0.3, n)
    if ties:
        a, b = np.round(a, 1), np.round(b, 1)
    ours = M.wilcoxon_signed_rank(a, b, alternative=alternative)
    ref = stats.wilcoxon(a, b, alternative=alternative)
    assert ours["pvalue"] == pytest.approx(ref.pvalue, rel=1e-6, abs=1e-12)
    stat = ours["statistic_min"] if alternative == "two-sided" else ours["statistic"]
    assert stat == pytest.approx(ref.statistic)


def test_wilcoxon_exact_small_case_by_hand():
    # d = 1, 2, 3 (all positive): W+ = 6, P(W+ >= 6) = 1/8 under H0, two-sided p = 1/4
    out = M.wilcoxon_signed_rank(np.array([1.0, 2.0, 3.0]), np.zeros(3))
    assert out["statistic"] == 6 and out["method"] == "exact"
    assert out["pvalue"] == pytest.approx(0.25)
    assert M.wilcoxon_signed_rank(np.zeros(3), np.zeros(3))["n"] == 0
