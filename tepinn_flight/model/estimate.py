"""Offline estimation over whole records: batched sliding windows, then the causal fusion pass."""

from __future__ import annotations

import numpy as np
import pandas as pd
import torch

from ..record import FlightRecord
from .fusion import FusionConfig, FusionRun, feedback_bias
from .network import TEPINN
from .tokens import tokenize_record

EST_Q_COLS = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]
EST_BIAS_COLS = ["gyr_bias_est_x_rad_s", "gyr_bias_est_y_rad_s", "gyr_bias_est_z_rad_s"]


@torch.inference_mode()
def network_on_windows(model: TEPINN, tok, ends: np.ndarray, gyr_offset: np.ndarray | None = None,
                       batch_size: int = 256):  # fmt: skip
    """(q (W, 4), sigma (W,), bias (W, 3)) of the windows ending at token indices ``ends``;
    ``gyr_offset`` (W, 3) rad/s is subtracted from every gyro token of each window (bias feedback)
    and added back to its bias output."""
    c = model.config
    qs, ss, bs = [], [], []
    dtype = next(model.parameters()).dtype
    gyr = np.nan_to_num(tok.gyr)
    acc = np.nan_to_num(tok.acc)
    mag = np.nan_to_num(tok.mag)
    for a in range(0, len(ends), batch_size):
        e = ends[a : a + batch_size]
        idx = e[:, None] + np.arange(-c.window_tokens + 1, 1)[None, :]
        t = tok.t_s[idx]
        g = gyr[idx] if gyr_offset is None else gyr[idx] - gyr_offset[a : a + batch_size, None, :]
        out = model(
            torch.as_tensor(g, dtype=dtype), torch.as_tensor(acc[idx], dtype=dtype),
            torch.as_tensor(tok.count[idx], dtype=dtype), torch.as_tensor(t - t[:, -1:], dtype=dtype),
            torch.as_tensor(tok.dt_s[idx], dtype=dtype), torch.as_tensor(mag[idx], dtype=dtype),
            torch.as_tensor(tok.clip[idx], dtype=dtype),
        )  # fmt: skip
        qs.append(out["q"].double().numpy())
        ss.append(out["sigma"].double().numpy() if "sigma" in out else np.full(len(e), np.radians(2.0)))
        bs.append(out["bias"].double().numpy())
    if not qs:
        return np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3))
    bias = np.concatenate(bs)
    if gyr_offset is not None:
        bias = bias + gyr_offset
    return np.concatenate(qs), np.concatenate(ss), bias


def window_estimates(model: TEPINN, rec: FlightRecord, batch_size: int = 256):
    """Network estimates at every token that ends a full window (on the raw gyro).

    Returns (sample_index (W,), q (W, 4), sigma (W,), bias (W, 3)) — sample_index is the record row
    of each window's last sample, the time the estimate belongs to.
    """
    tok = tokenize_record(rec, model.config.token_rate_hz)
    ends = tok.windows_ending(model.config.window_tokens)
    q, s, b = network_on_windows(model, tok, ends, batch_size=batch_size)
    return tok.last_index[ends], q, s, b


def estimate_record(model: TEPINN, rec: FlightRecord, fusion: FusionConfig | None = None,
                    batch_size: int = 256, windows=None) -> pd.DataFrame:  # fmt: skip
    """One output row per record row: ``t_s``, ``q_est_*`` (body→NED), ``sigma_rad``,
    ``gyr_bias_est_*``; NaN until the first window of a segment is full. ``windows`` takes the
    result of :func:`window_estimates` when it is already at hand (fusion tuning; not with bias
    feedback, whose windows depend on the fusion).

    With bias feedback (``fusion.bias_feedback_windows`` = L > 0) the windows of a segment are made
    in blocks of L: block b sees the gyro minus the fusion's bias right after the last estimate of
    block b − 1 was applied (soft-thresholded, :func:`~.fusion.feedback_bias`) — what the live
    estimator has at hand when it makes them."""
    fusion = fusion or FusionConfig()
    feedback = fusion.bias_feedback_windows
    if feedback > 0 and windows is not None:
        raise ValueError("precomputed windows cannot be used with bias feedback")
    if feedback > 0:
        tok = tokenize_record(rec, model.config.token_rate_hz)
        ends = tok.windows_ending(model.config.window_tokens)
        idx = tok.last_index[ends]
    else:
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
        run = FusionRun(t[a:b], gyr[a:b], fusion, clipped[a:b])
        if feedback > 0:
            e_seg, i_seg = ends[m], idx[m] - a
            for s0 in range(0, len(e_seg), feedback):
                blk = slice(s0, s0 + feedback)
                fb = np.tile(feedback_bias(fusion, run.fusion.bias), (len(e_seg[blk]), 1))
                run.add(i_seg[blk], *network_on_windows(model, tok, e_seg[blk], fb, batch_size))
                run.advance(int(i_seg[blk][-1]) + 2)  # through the sample that applies the block's last
        else:
            run.add(idx[m] - a, q[m], sigma[m], bias[m])
        run.advance(b - a)
        q_out[a:b], s_out[a:b], b_out[a:b] = run.q, run.sigma, run.bias
    df = pd.DataFrame({"t_s": t})
    for i, c in enumerate(EST_Q_COLS):
        df[c] = q_out[:, i]
    df["sigma_rad"] = s_out
    for i, c in enumerate(EST_BIAS_COLS):
        df[c] = b_out[:, i]
    return df
