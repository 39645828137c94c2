"""The bias-state Kalman fusion (``FusionConfig.bias_states``): covariance propagation against the
matrix exponential of the error dynamics, and a gyro bias found from the tilt innovations."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from tepinn_flight.model.fusion import AttitudeFusion, FusionConfig

LEVEL = (1.0, 0.0, 0.0, 0.0)


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@pytest.mark.parametrize("w", [(0.3, -0.2, 1.0), (7.0, 0.5, -2.0)])
def test_covariance_propagation_matches_the_error_dynamics(w):
    """Constant rate, no process noise: between two estimates the 6×6 covariance must be
    expm(A T) P₀ expm(A T)ᵀ with A = [[−[ω×], −I], [0, 0]] (δθ̇ = −ω×δθ − δb, δḃ = 0). The second
    estimate carries a huge σ so it leaves the propagated covariance (almost) as it is. The state
    covariance after the first estimate is replaced by a random full one (all blocks coupled)."""
    cfg = FusionConfig.uncalibrated(bias_states=True, process_noise_rad2_s=0.0, bias_rw_rad_s_sqrt_s=0.0,
                       bias_sigma_rad_s=0.0, bias_init_sigma_rad_s=0.2)  # fmt: skip
    f = AttitudeFusion(cfg)
    sigma0, n, rate = 0.05, 16, 400.0  # one token at 400 Hz: 40 ms
    q_first = tuple(Rotation.from_euler("ZYX", [0.3, 0.2, -0.1]).as_quat(scalar_first=True))
    L = np.random.default_rng(3).normal(size=(6, 6)) * 0.05
    P0 = L @ L.T + 1e-4 * np.eye(6)
    for i in range(n + 2):
        est = None
        if i == 1:
            est = (q_first, sigma0, (0.0, 0.0, 0.0))
        elif i == n + 1:
            est = (f.q, 1e4, (0.0, 0.0, 0.0))  # at t = n/400: no information
        f.step(i / rate, w, est)
        if i == 1:
            f.cov6 = P0.copy()
    T = n / rate
    A = np.zeros((6, 6))
    A[:3, :3] = -_skew(np.array(w))
    A[:3, 3:] = -np.eye(3)
    Phi = expm(A * T)
    np.testing.assert_allclose(f.cov6, Phi @ P0 @ Phi.T, rtol=1e-6, atol=1e-12)


def _fuse(cfg, gyro_bias, seconds=40.0, sigma=0.05, net_bias=(0.0, 0.0, 0.0)):
    """Level vehicle at rest; window estimates = the truth every 40 ms with σ and a network bias
    ``net_bias``; the gyro reads ``gyro_bias``. Returns (final tilt error rad, final bias)."""
    f = AttitudeFusion(cfg)
    q = b = None
    for i in range(int(seconds * 400)):
        est = (LEVEL, sigma, net_bias) if i % 16 == 1 else None
        q, _, b = f.step(i / 400.0, gyro_bias, est)
    g = Rotation.from_quat(q, scalar_first=True).inv().apply([0.0, 0.0, 1.0])
    return float(np.arccos(np.clip(g[2], -1, 1))), np.array(b)


def test_bias_states_find_an_unreported_gyro_bias():
    """The network reports no bias (it was never shown 8 °/s), the gyro has it: the low-pass fusion
    drifts away, the bias states find the bias on the two level axes from the tilt innovations;
    the vertical axis (rotation about gravity) leaves no trace in the tilt and stays unestimated."""
    bad = np.radians([8.0, -5.0, 3.0])
    lowpass, _ = _fuse(FusionConfig.uncalibrated(process_noise_rad2_s=1e-6), bad)
    kf_cfg = FusionConfig.uncalibrated(bias_states=True, process_noise_rad2_s=1e-6, bias_sigma_rad_s=0.0, bias_init_sigma_rad_s=0.3)
    tilt, b = _fuse(kf_cfg, bad)
    assert lowpass > np.radians(20.0)
    assert tilt < np.radians(0.5)
    np.testing.assert_allclose(b[:2], bad[:2], atol=np.radians(0.1))
    assert abs(b[2]) < np.radians(0.1)


def test_bias_states_weigh_the_network_bias_by_its_sigma():
    """With a true, unreported gyro bias and the network insisting on 0: a tight network σ keeps the
    estimate near 0 (then the tilt errs), a loose one lets the innovations win."""
    bad = np.radians([6.0, 0.0, 0.0])
    base = FusionConfig.uncalibrated(bias_states=True, process_noise_rad2_s=1e-6, bias_init_sigma_rad_s=0.3,
                        bias_rw_rad_s_sqrt_s=1e-4)  # fmt: skip
    tight_tilt, tight = _fuse(dataclasses.replace(base, bias_sigma_rad_s=1e-4), bad)
    loose_tilt, loose = _fuse(dataclasses.replace(base, bias_sigma_rad_s=1.0), bad)
    assert abs(tight[0]) < 0.2 * bad[0] and abs(loose[0] - bad[0]) < 0.05 * bad[0]
    assert loose_tilt < tight_tilt


@pytest.mark.slow
def test_calibration_picks_bias_states_for_a_gyro_bias_the_network_never_saw():
    """An untrained model (its physics baseline gives the windows) on flights whose gyro is 0.3 rad/s
    (17 °/s) off: the calibration must choose the bias-state fusion, and it must beat the best
    low-pass setting on the same flights; the bias it then reports is near the truth. Feeding that
    bias back into the windows (their RK4 rotations are then nearly right) must win too."""
    import torch

    from tepinn_flight.model.config import ModelConfig
    from tepinn_flight.model.estimate import estimate_record
    from tepinn_flight.model.network import TEPINN
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.model.calibration import calibrate_fusion

    torch.manual_seed(0)
    # the untrained physics baseline this test reasons about: the clip-trusted mean, no v̂ compensation
    model = TEPINN(ModelConfig(window_tokens=16, d_model=16, n_heads=2, n_layers=1, d_ff=32, declip=False,
                               learned_pooling=False, centripetal=False, centripetal_rate=False)).eval()
    recs = [synthetic_record(seed=s, duration_s=30.0, rate_hz=100.0, max_rate_rad_s=1.0, gyr_bias_rad_s=0.3)
            for s in (2, 4)]  # fmt: skip
    fusion, metrics = calibrate_fusion(model, recs, FusionConfig.uncalibrated(), max_records=2, bias_state_sweeps=1,
                                       feedback_deadzones_rad_s=(0.02,), feedback_windows=10)  # fmt: skip
    assert fusion.bias_states
    assert metrics["fusion_val_tilt_rmse_mean_deg"] < 0.8 * min(metrics["fusion_grid"].values())
    fb = metrics["fusion_feedback_grid"]
    assert fusion.bias_feedback_windows == 10 and fusion.bias_feedback_deadzone_rad_s == 0.02
    assert fb["0.02"] < 0.9 * fb["off"]
    est = estimate_record(model, recs[0], fusion)
    b = est[["gyr_bias_est_x_rad_s", "gyr_bias_est_y_rad_s", "gyr_bias_est_z_rad_s"]].to_numpy()[-100:]
    b_true = recs[0].data[["gyr_bias_x_rad_s", "gyr_bias_y_rad_s", "gyr_bias_z_rad_s"]].to_numpy()[-100:]
    lowpass_b = estimate_record(model, recs[0], FusionConfig.uncalibrated())
    lowpass_b = lowpass_b[["gyr_bias_est_x_rad_s", "gyr_bias_est_y_rad_s", "gyr_bias_est_z_rad_s"]].to_numpy()[-100:]
    assert np.linalg.norm(b - b_true, axis=1).mean() < 0.5 * np.linalg.norm(lowpass_b - b_true, axis=1).mean()

