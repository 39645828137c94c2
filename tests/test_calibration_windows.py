"""Fusion calibration reuses the windows it made once: with bias feedback, a block whose fed-back
offset is zero takes the precomputed windows, the others are made again — the estimate equals the
one made from scratch (up to the float32 rounding of a different batch)."""

from __future__ import annotations

import numpy as np
import torch

from tepinn_flight.model import estimate as est_mod
from tepinn_flight.model.config import ModelConfig
from tepinn_flight.model.fusion import FusionConfig
from tepinn_flight.model.network import TEPINN
from tepinn_flight.model.synthetic import synthetic_record

SMALL = ModelConfig(window_tokens=16, d_model=16, n_heads=2, n_layers=1, d_ff=32)
FEEDBACK = FusionConfig(bias_states=True, bias_init_sigma_rad_s=0.3, bias_sigma_rad_s=0.3, bias_feedback_windows=3,
                        bias_feedback_deadzone_rad_s=0.002)  # fmt: skip


def test_feedback_estimate_from_precomputed_windows_equals_the_one_from_scratch(monkeypatch):
    torch.manual_seed(1)
    m = TEPINN(SMALL).eval()
    rec = synthetic_record(seed=5, duration_s=6.0, rate_hz=160.0)
    rec.data[["gyr_x_rad_s", "gyr_y_rad_s"]] += 0.2  # the fusion's bias leaves the dead zone after a while
    scratch = est_mod.estimate_record(m, rec, FEEDBACK)
    windows = est_mod.window_estimates(m, rec)
    calls = []
    inner = est_mod.network_on_windows
    monkeypatch.setattr(est_mod, "network_on_windows", lambda *a, **k: calls.append(len(a[2])) or inner(*a, **k))
    reused = est_mod.estimate_record(m, rec, FEEDBACK, windows=windows)
    n_blocks = -(-len(windows[0]) // FEEDBACK.bias_feedback_windows)
    assert 0 < len(calls) < n_blocks  # both: blocks taken from the precomputed windows, blocks made again
    a, b = scratch.to_numpy(), reused.to_numpy()
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    ok = np.isfinite(a)
    np.testing.assert_allclose(b[ok], a[ok], rtol=0, atol=1e-5)
