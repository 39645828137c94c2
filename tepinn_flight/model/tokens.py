"""IMU samples → tokens on a fixed time grid (numpy), so one model serves 25–400 Hz logs.

Within each record segment, token k collects the samples with
``t0 + (k-1)·Δ < t ≤ t0 + k·Δ`` (``Δ = 1 / token_rate_hz``, ``t0`` the segment's first sample, which
forms token 0). A token carries the mean gyro, mean specific force, mean magnetometer, the sample
count and the index and time of its last sample — the time its estimate belongs to. A token with no
sample (IMU slower than the token rate) repeats the previous token's means with count 0 (causal
hold) and has no target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..record import FlightRecord
from .tokens_kernels import token_means


@dataclass
class Tokens:
    """All tokens of one record, segments one after another."""

    t_s: np.ndarray  # (T,) time of the token's last sample (or its grid time when empty)
    dt_s: np.ndarray  # (T,) token duration (Δ; the first token of a segment: Δ too)
    gyr: np.ndarray  # (T, 3) mean rad/s
    acc: np.ndarray  # (T, 3) mean m/s²
    mag: np.ndarray  # (T, 3) mean µT (NaN where none)
    count: np.ndarray  # (T,) samples in the token
    clip: np.ndarray  # (T,) fraction of the token's samples with a sensor axis at its range limit
    last_index: np.ndarray  # (T,) index into the record of the token's last sample (-1 if empty)
    segment_start: np.ndarray  # (S,) first token of each segment
    segment_len: np.ndarray  # (S,)

    def __len__(self) -> int:
        return len(self.t_s)

    def windows_ending(self, window_tokens: int) -> np.ndarray:
        """Indices of tokens that end a full window inside their segment and are not empty."""
        ends = []
        for s0, n in zip(self.segment_start, self.segment_len):
            if n >= window_tokens:
                ends.append(np.arange(s0 + window_tokens - 1, s0 + n))
        idx = np.concatenate(ends) if ends else np.zeros(0, np.int64)
        return idx[self.count[idx] > 0]


def tokenize(
    t_s: np.ndarray,
    segment: np.ndarray,
    gyr: np.ndarray,
    acc: np.ndarray,
    mag: np.ndarray | None,
    token_rate_hz: float,
    clipped: np.ndarray | None = None,
) -> Tokens:
    """Tokens for arrays of samples (see module doc)."""
    delta = 1.0 / token_rate_hz
    n = len(t_s)
    if mag is None:
        mag = np.full((n, 3), np.nan)
    clip = np.zeros((n, 1)) if clipped is None else np.asarray(clipped, float).reshape(n, 1)
    parts = []
    seg_ids, seg_first = np.unique(segment, return_index=True)
    bounds = list(seg_first) + [n]
    for a, b in zip(bounds[:-1], bounds[1:]):
        parts.append(_tokenize_segment(t_s[a:b], gyr[a:b], acc[a:b], mag[a:b], clip[a:b], delta, a))
    if not parts:
        z3 = np.zeros((0, 3))
        return Tokens(np.zeros(0), np.zeros(0), z3, z3, z3, np.zeros(0), np.zeros(0), np.zeros(0, np.int64),
                      np.zeros(0, np.int64), np.zeros(0, np.int64))  # fmt: skip
    lens = np.array([len(p["t_s"]) for p in parts])
    starts = np.concatenate([[0], np.cumsum(lens)[:-1]])
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return Tokens(segment_start=starts, segment_len=lens, **cat)


def tokenize_record(rec: FlightRecord, token_rate_hz: float) -> Tokens:
    return tokenize(rec.t_s, rec.segment, rec.gyr_rad_s, rec.acc_m_s2, rec.mag_ut, token_rate_hz, rec.clipped)


def _tokenize_segment(t, gyr, acc, mag, clip, delta, offset) -> dict:
    k = np.ceil((t - t[0]) / delta - 1e-6).astype(np.int64)  # token index per sample
    k[0] = 0
    n_tok = int(k[-1]) + 1
    count = np.bincount(k, minlength=n_tok).astype(np.float64)

    def mean(x):  # per token: the finite samples' mean (NaN: none), compiled (tokens_kernels, session 42)
        return token_means(k, np.asarray(x, np.float64), n_tok)

    g, a, m, cl = mean(gyr), mean(acc), mean(mag), mean(clip)[:, 0]
    last = np.full(n_tok, -1, np.int64)
    last[k] = np.arange(len(t)) + offset  # later samples overwrite: the last one stays
    t_tok = t[0] + np.arange(n_tok) * delta
    has = count > 0
    t_tok[has] = t[last[has] - offset]
    # empty tokens: hold the previous token's means (causal)
    if not np.all(has):
        idx = np.where(has, np.arange(n_tok), 0)
        idx = np.maximum.accumulate(idx)
        g, a = g[idx], a[idx]
        m, cl = m[idx], cl[idx]
    return {
        "t_s": t_tok,
        "dt_s": np.full(n_tok, delta),
        "gyr": g,
        "acc": a,
        "mag": m,
        "count": count,
        "clip": np.nan_to_num(cl),
        "last_index": last,
    }


def decimate(t_s, segment, arrays: dict[str, np.ndarray], factor: int) -> tuple:
    """Lower the IMU rate by an integer factor, averaging each group of samples (anti-aliased,
    like an IMU that integrates between outputs) — the training-time rate augmentation.

    Groups never straddle segments; returns ``(t_s, segment, arrays, kept_index)`` where
    ``kept_index`` is the record index of each group's last sample.
    """
    if factor <= 1:
        return t_s, segment, arrays, np.arange(len(t_s))
    keep_idx, groups = [], []
    seg_ids, first = np.unique(segment, return_index=True)
    bounds = list(first) + [len(t_s)]
    for a, b in zip(bounds[:-1], bounds[1:]):
        n = (b - a) // factor
        if n == 0:
            continue
        gi = a + np.arange(n * factor).reshape(n, factor)
        groups.append(gi)
        keep_idx.append(gi[:, -1])
    if not groups:
        return t_s[:0], segment[:0], {k: v[:0] for k, v in arrays.items()}, np.zeros(0, np.int64)
    gi = np.concatenate(groups)
    kept = np.concatenate(keep_idx)
    out = {}
    for name, v in arrays.items():
        if name in ("clipped", "gyr_clipped"):  # a group holding a clipped sample is clipped
            out[name] = v[gi].any(axis=1)
        elif name.startswith("q_") or name in ("valid", "bias"):
            out[name] = v[kept]
        else:
            with np.errstate(invalid="ignore"):
                out[name] = np.nanmean(v[gi], axis=1) if np.isnan(v).any() else v[gi].mean(axis=1)
    return t_s[kept], segment[kept], out, kept


def decimate_record(rec: FlightRecord, factor: int) -> FlightRecord:
    """``rec`` at ``1/factor`` of its IMU rate by :func:`decimate` (gyro and accelerometer averaged,
    the clip flags kept where any sample of a group had them, every other column taken at each group's
    last sample): a real or simulated record as a slower IMU would have logged it."""
    from ..record import ACC_COLS, GYR_COLS

    flags = {"clipped": rec.clipped, "gyr_clipped": rec.gyr_clipped}
    _, seg, arr, kept = decimate(rec.t_s, rec.segment, {"g": rec.gyr_rad_s, "a": rec.acc_m_s2, **flags}, factor)
    df = rec.data.iloc[kept].reset_index(drop=True).copy()
    df[GYR_COLS], df[ACC_COLS], df["clipped"], df["segment"] = arr["g"], arr["a"], arr["clipped"], seg
    if "gyr_clipped" in df:
        df["gyr_clipped"] = arr["gyr_clipped"]
    return FlightRecord(df, {**rec.meta, "imu_rate_hz": rec.meta["imu_rate_hz"] / factor})
