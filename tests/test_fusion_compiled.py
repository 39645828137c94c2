"""The compiled fusion (:mod:`tepinn_flight.model.fusion`) equals the pure-Python implementation it
replaced (``tests/fusion_reference.py``) to 1e-9, on a real shared log with the shipped network's
windows and on a simulated flight, for both update algorithms and the options around them — and
sample by sample (the live path) as over a whole segment (the offline path)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tepinn_flight.errors import ConfigError
from tepinn_flight.model.fusion import AttitudeFusion, FusionConfig, FusionRun
from tepinn_flight.model.synthetic import synthetic_record
from tepinn_flight.quat import quat_from_rotvec, quat_mul, quat_normalize, quat_zero_yaw
from tests import fusion_reference as ref
from tests.conftest import real_log

CONFIGS = {
    "lowpass": FusionConfig(bias_states=False),
    "lowpass-nis-zero-yaw-skip": FusionConfig(bias_states=False, adaptive_nis=4.0, yaw="zero", clip_hold_s=1.0,
                                              clip_skip_updates=True, process_noise_rate_rad=1e-3, clip_rate_gain=0.5),
    "bias-states": FusionConfig(bias_states=True, sigma_scale=3.0, bias_sigma_rad_s=0.3, bias_rw_rad_s_sqrt_s=1e-4,
                                bias_init_sigma_rad_s=0.3, clip_rate_gain=0.84, clip_hold_s=2.0),
    "bias-states-nis-rate-nobias": FusionConfig(bias_states=True, adaptive_nis=4.0, process_noise_rate_rad=1e-3,
                                                bias_sigma_rad_s=0.0, yaw="zero"),
    "disabled": FusionConfig(enabled=False),
}  # fmt: skip


def _both(cfg, t, gyr, clipped, idx, q, sigma, bias):
    out = []
    for mod in (ref, None):
        run = (ref.FusionRun if mod else FusionRun)(t, gyr, cfg, clipped)
        run.add(idx, q, sigma, bias)
        run.advance(len(t) // 3)  # in pieces, as bias feedback runs it
        run.advance(len(t))
        out.append((run.q, run.sigma, run.bias))
    return out


def _assert_equal(a, b):
    for x, y, what in zip(a, b, ("q", "sigma", "bias")):
        np.testing.assert_array_equal(np.isnan(x), np.isnan(y), err_msg=what)
        ok = np.isfinite(x)
        assert ok.any()
        np.testing.assert_allclose(y[ok], x[ok], rtol=0, atol=1e-9, err_msg=what)


def _simulated_windows(rec, every=16, seed=0):
    """Window estimates from the truth: the tilt turned by a random 0.05 rad, σ, a bias near the gyro's."""
    rng = np.random.default_rng(seed)
    idx = np.arange(every * 3, len(rec), every)
    q = quat_zero_yaw(quat_normalize(quat_mul(rec.q_ref_wxyz[idx], quat_from_rotvec(rng.normal(0, 0.05, (len(idx), 3))))))
    sigma = rng.uniform(0.01, 0.2, len(idx))
    bias = rng.normal(0.02, 0.01, (len(idx), 3))
    return idx, q, sigma, bias


@pytest.mark.parametrize("name", list(CONFIGS))
def test_compiled_fusion_equals_the_reference_on_a_simulated_flight(name):
    rec = synthetic_record(seed=3, duration_s=20.0, rate_hz=400.0, max_rate_rad_s=6.0)
    clipped = np.zeros(len(rec), bool)
    clipped[2000:2040] = True  # a saturation mid-flight: the clip gain, inflation and hold act
    gyr = rec.gyr_rad_s + 0.1  # a gyro bias the windows do not report at first
    windows = _simulated_windows(rec)
    a, b = _both(CONFIGS[name], rec.t_s, gyr, clipped, *windows)
    _assert_equal(a, b)



def test_windows_added_one_at_a_time_up_to_the_segment_s_last_sample_equal_the_reference():
    """As the quiet blocks add them: one window per ``add``, a bias read between, and the last one ending at the
    segment's last sample (applied at a sample the segment does not have: dropped, as the reference drops it)."""
    rec = synthetic_record(seed=5, duration_s=8.0, rate_hz=200.0, max_rate_rad_s=4.0)
    idx, q, sigma, bias = _simulated_windows(rec, every=16, seed=1)
    idx = np.append(idx, len(rec) - 1)
    q, sigma, bias = np.vstack([q, q[-1:]]), np.append(sigma, sigma[-1]), np.vstack([bias, bias[-1:]])
    cfg = CONFIGS["bias-states"]
    out = []
    for cls in (ref.FusionRun, FusionRun):
        run, biases = cls(rec.t_s, rec.gyr_rad_s, cfg, np.zeros(len(rec), bool)), []
        for k in range(len(idx)):
            run.add(idx[k : k + 1], q[k : k + 1], sigma[k : k + 1], bias[k : k + 1])
            run.advance(int(idx[k]) + 2)
            biases.append(run.fusion.bias)
        run.advance(len(rec))
        out.append(((run.q, run.sigma, run.bias), biases))
    _assert_equal(*(o[0] for o in out))
    np.testing.assert_allclose(out[1][1], out[0][1], rtol=0, atol=1e-9)
    assert all(type(b) is tuple and len(b) == 3 and all(type(x) is float for x in b) for b in out[1][1])

def test_compiled_fusion_sample_by_sample_equals_the_reference():
    """The live path: :class:`AttitudeFusion.step` one sample at a time (here on the bias states)."""
    rec = synthetic_record(seed=4, duration_s=6.0, rate_hz=200.0)
    idx, q, sigma, bias = _simulated_windows(rec, every=8)
    cfg = CONFIGS["bias-states"]
    f_ref, f = ref.AttitudeFusion(cfg), AttitudeFusion(cfg)
    est_at = {int(i) + 1: (tuple(q[k]), float(sigma[k]), tuple(bias[k])) for k, i in enumerate(idx)}
    n_q = 0
    for i in range(len(rec)):
        est = est_at.get(i)
        clipped = 300 <= i < 310
        r = f_ref.step(rec.t_s[i], rec.gyr_rad_s[i], est, clipped)
        c = f.step(rec.t_s[i], rec.gyr_rad_s[i], est, clipped)
        assert (r[0] is None) == (c[0] is None)
        if r[0] is not None:
            n_q += 1
            np.testing.assert_allclose(c[0], r[0], rtol=0, atol=1e-9)
            np.testing.assert_allclose(c[1], r[1], rtol=0, atol=1e-9)
        np.testing.assert_allclose(c[2], r[2], rtol=0, atol=1e-9)
    assert n_q > 1000
    np.testing.assert_allclose(f.cov6, f_ref.cov6, rtol=0, atol=1e-12)


@pytest.mark.slow
def test_compiled_fusion_equals_the_reference_on_a_real_log_with_the_shipped_network():
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.estimate import window_estimates

    rec = ingest_log(real_log("erle_pxf_copter_15-12-2014_16.BIN"))
    model, anchor, _ = load_model(default_model_path())
    windows = window_estimates(model, rec)
    clipped = rec.clipped.copy()
    clipped[3000:3005] = True
    for cfg in (anchor.fusion_config, CONFIGS["lowpass-nis-zero-yaw-skip"], CONFIGS["bias-states-nis-rate-nobias"]):
        a, b = _both(cfg, rec.t_s, rec.gyr_rad_s, clipped, *windows)
        _assert_equal(a, b)


@pytest.mark.parametrize("bad", [{"yaw": "north"}, {"sigma_scale": 0.0}, {"process_noise_rad2_s": -1.0},
                                 {"bias_time_constant_s": float("nan")}, {"bias_states": "yes"},
                                 {"bias_feedback_windows": 2.5}, {"bias_feedback_windows": -1},
                                 {"clip_hold_s": float("inf")}, {"output_sigma_scale": 0.0}])  # fmt: skip
def test_fusion_config_refuses_bad_values_with_a_config_error(bad):
    (key,) = bad
    with pytest.raises(ConfigError, match=f"'{key}' must be"):
        dataclasses.replace(FusionConfig(), **bad)


def test_fusion_config_defaults_are_the_shipped_model():
    import torch

    from tepinn_flight.model.checkpoint import default_model_path

    path = default_model_path()
    if not path.exists():
        pytest.skip(f"shipped model not available ({path})")
    stored = torch.load(path, weights_only=True)["fusion_config"]
    assert set(stored) == {f.name for f in dataclasses.fields(FusionConfig)}
    assert FusionConfig(**stored) == FusionConfig()
