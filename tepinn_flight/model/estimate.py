"""Offline estimation over whole records: batched sliding windows, then the causal fusion pass."""

from __future__ import annotations

import numpy as np
import pandas as pd
import torch

from ..record import FlightRecord
from .fusion import FusionConfig, run_fusion
from .network import TEPINN
from .tokens import tokenize_record

EST_Q_COLS = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]
EST_BIAS_COLS = ["gyr_bias_est_x_rad_s", "gyr_bias_est_y_rad_s", "gyr_bias_est_z_rad_s"]


@torch.inference_mode()
def window_estimates(model: TEPINN, rec: FlightRecord, batch_size: int = 256):
    """Network estimates at every token that ends a full window.

    Returns (sample_index (W,), q (W, 4), sigma (W,), bias (W, 3)) — sample_index is the record row
    of each window's last sample, the time the estimate belongs to.
    """
    c = model.config
    tok = tokenize_record(rec, c.token_rate_hz)
    ends = tok.windows_ending(c.window_tokens)
    qs, ss, bs = [], [], []
    dtype = next(model.parameters()).dtype
    gyr = np.nan_to_num(tok.gyr)
    acc = np.nan_to_num(tok.acc)
    mag = np.nan_to_num(tok.mag)
    for a in range(0, len(ends), batch_size):
        e = ends[a : a + batch_size]
        idx = e[:, None] + np.arange(-c.window_tokens + 1, 1)[None, :]
        t = tok.t_s[idx]
        out = model(
            torch.as_tensor(gyr[idx], dtype=dtype), torch.as_tensor(acc[idx], dtype=dtype),
            torch.as_tensor(tok.count[idx], dtype=dtype), torch.as_tensor(t - t[:, -1:], dtype=dtype),
            torch.as_tensor(tok.dt_s[idx], dtype=dtype), torch.as_tensor(mag[idx], dtype=dtype),
            torch.as_tensor(tok.clip[idx], dtype=dtype),
        )  # fmt: skip
        qs.append(out["q"].double().numpy())
        ss.append(out["sigma"].double().numpy() if "sigma" in out else np.full(len(e), np.radians(2.0)))
        bs.append(out["bias"].double().numpy())
    if not qs:
        return np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3))
    return tok.last_index[ends], np.concatenate(qs), np.concatenate(ss), np.concatenate(bs)


def estimate_record(model: TEPINN, rec: FlightRecord, fusion: FusionConfig | None = None,
                    batch_size: int = 256, windows=None) -> pd.DataFrame:  # fmt: skip
    """One output row per record row: ``t_s``, ``q_est_*`` (body→NED), ``sigma_rad``,
    ``gyr_bias_est_*``; NaN until the first window of a segment is full. ``windows`` takes the
    result of :func:`window_estimates` when it is already at hand (fusion tuning)."""
    fusion = fusion or FusionConfig()
    idx, q, sigma, bias = windows if windows is not None else window_estimates(model, rec, batch_size)
    n = len(rec)
    q_out = np.full((n, 4), np.nan)
    s_out = np.full(n, np.nan)
    b_out = np.full((n, 3), np.nan)
    seg = rec.segment
    t = rec.t_s
    gyr = rec.gyr_rad_s
    clipped = rec.clipped
    bounds = np.flatnonzero(np.diff(seg)) + 1
    for a, b in zip(np.r_[0, bounds], np.r_[bounds, n]):
        m = (idx >= a) & (idx < b)
        qo, so, bo = run_fusion(t[a:b], gyr[a:b], idx[m] - a, q[m], sigma[m], bias[m], fusion, clipped[a:b])
        q_out[a:b], s_out[a:b], b_out[a:b] = qo, so, bo
    df = pd.DataFrame({"t_s": t})
    for i, c in enumerate(EST_Q_COLS):
        df[c] = q_out[:, i]
    df["sigma_rad"] = s_out
    for i, c in enumerate(EST_BIAS_COLS):
        df[c] = b_out[:, i]
    return df
