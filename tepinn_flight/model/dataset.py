"""Training/validation windows from flight records: tokens, targets and batches (numpy → torch).

Every record is tokenized once per rate-augmentation factor (the IMU decimated by averaging, so the
model sees 25–400 Hz data); all tokens go into flat arrays and a window is the K consecutive
tokens ending at a target token of the same segment. Splits are by flight (record), never by
window.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import torch

from ..quat import quat_canonical
from ..record import GYR_BIAS_COLS, FlightRecord
from .config import ModelConfig
from .network import zero_yaw
from .tokens import decimate, tokenize


@dataclass
class TokenBank:
    """Flat token arrays of many records, and the window ends usable as training targets."""

    gyr: np.ndarray  # (T, 3)
    acc: np.ndarray  # (T, 3)
    mag: np.ndarray  # (T, 3)
    count: np.ndarray  # (T,)
    clip: np.ndarray  # (T,) clipped fraction
    t_s: np.ndarray  # (T,)
    dt_s: np.ndarray  # (T,)
    q_ref: np.ndarray  # (T, 4) at each token's last sample (NaN: no target)
    bias: np.ndarray  # (T, 3) true gyro bias (NaN: unknown)
    ends: np.ndarray  # (W,) token indices that end a full window and have a target
    prev_ok: np.ndarray  # (W,) the window n tokens earlier is also full (for L_gyro pairs)
    record_of_end: np.ndarray  # (W,) which record each end comes from

    def __len__(self) -> int:
        return len(self.ends)


def build_bank(records: list[FlightRecord], model: ModelConfig, rate_factors=(1,), gyro_pair_tokens=5,
               max_rate_hz: float | None = None) -> TokenBank:  # fmt: skip
    """Tokenize ``records`` at each decimation factor in ``rate_factors`` (a factor that would
    bring the IMU below 20 Hz is skipped); ``max_rate_hz`` first decimates very fast records."""
    cols = {k: [] for k in ("gyr", "acc", "mag", "count", "clip", "t_s", "dt_s", "q_ref", "bias")}
    ends, prev_ok, rec_of = [], [], []
    offset = 0
    k = model.window_tokens
    for ri, rec in enumerate(records):
        rate = rec.meta.get("imu_rate_hz") or 0.0
        if rate < 20.0:
            continue
        base = {
            "gyr": rec.gyr_rad_s, "acc": rec.acc_m_s2, "mag": rec.mag_ut,
            "q_ref": rec.q_ref_wxyz,
            "bias": rec.data[GYR_BIAS_COLS].to_numpy(float) if GYR_BIAS_COLS[0] in rec.data else np.full((len(rec), 3), np.nan),
            "valid": rec.valid,
            "clipped": rec.clipped,
        }  # fmt: skip
        for f in rate_factors:
            if rate / f < 20.0:
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                t, seg, arr, _ = decimate(rec.t_s, rec.segment, base, int(f))
            if len(t) == 0:
                continue
            tok = tokenize(t, seg, arr["gyr"], arr["acc"], arr["mag"], model.token_rate_hz, arr["clipped"])
            li = tok.last_index
            has = li >= 0
            q = np.full((len(tok), 4), np.nan)
            b = np.full((len(tok), 3), np.nan)
            ok = np.zeros(len(tok), bool)
            q[has] = arr["q_ref"][li[has]]
            b[has] = arr["bias"][li[has]]
            ok[has] = arr["valid"][li[has]]
            q[~ok] = np.nan
            e = tok.windows_ending(k)
            e = e[np.all(np.isfinite(q[e]), axis=1) & np.all(np.isfinite(tok.gyr[e]), axis=1)]
            # the pair window (n tokens earlier) must also be full and inside the same segment
            seg_start = np.repeat(tok.segment_start, tok.segment_len)
            p_ok = (e - gyro_pair_tokens - (k - 1)) >= seg_start[e]
            for name, v in (("gyr", tok.gyr), ("acc", tok.acc), ("mag", tok.mag), ("count", tok.count), ("clip", tok.clip),
                            ("t_s", tok.t_s), ("dt_s", tok.dt_s), ("q_ref", q), ("bias", b)):  # fmt: skip
                cols[name].append(v)
            ends.append(e + offset)
            prev_ok.append(p_ok)
            rec_of.append(np.full(len(e), ri))
            offset += len(tok)
    if not sum(len(e) for e in ends):  # no records, or none long enough for one full window
        raise ValueError("no usable windows: records too short, too slow (< 20 Hz) or without reference")
    cat = {n: np.concatenate(v) for n, v in cols.items()}
    for n in ("gyr", "acc"):
        cat[n] = np.nan_to_num(cat[n])
    return TokenBank(**cat, ends=np.concatenate(ends), prev_ok=np.concatenate(prev_ok),
                     record_of_end=np.concatenate(rec_of))  # fmt: skip


def make_batch(bank: TokenBank, ends: np.ndarray, window_tokens: int, correction_layer: bool,
               dtype=torch.float32) -> dict[str, torch.Tensor]:  # fmt: skip
    """Tensors for the windows ending at token indices ``ends`` (B,)."""
    idx = ends[:, None] + np.arange(-window_tokens + 1, 1)[None, :]  # (B, K)
    t = bank.t_s[idx]
    q_ref = quat_canonical(bank.q_ref[ends])
    batch = {
        "gyr": torch.as_tensor(bank.gyr[idx], dtype=dtype),
        "acc": torch.as_tensor(bank.acc[idx], dtype=dtype),
        "mag": torch.as_tensor(np.nan_to_num(bank.mag[idx]), dtype=dtype),
        "count": torch.as_tensor(bank.count[idx], dtype=dtype),
        "clip": torch.as_tensor(bank.clip[idx], dtype=dtype),
        "t_rel": torch.as_tensor(t - t[:, -1:], dtype=dtype),
        "dt": torch.as_tensor(bank.dt_s[idx], dtype=dtype),
        "q_ref": torch.as_tensor(q_ref, dtype=dtype),
    }
    if correction_layer:
        batch["q_ref"] = zero_yaw(batch["q_ref"])
    b = bank.bias[ends]
    batch["has_bias"] = torch.as_tensor(np.all(np.isfinite(b), axis=1))
    batch["bias_true"] = torch.as_tensor(np.nan_to_num(b), dtype=dtype)
    return batch


def input_statistics(model_cls_features, bank: TokenBank, config: ModelConfig, n: int = 4096, seed: int = 0):
    """Mean and std of the encoder's input channels over ``n`` random windows (for normalisation)."""
    rng = np.random.default_rng(seed)
    ends = rng.choice(bank.ends, size=min(n, len(bank.ends)), replace=False)
    b = make_batch(bank, ends, config.window_tokens, config.correction_layer)
    with torch.no_grad():
        x = model_cls_features(b["gyr"], b["acc"], b["count"], b["mag"], b["dt"], b["clip"])[0]
    x = x.reshape(-1, x.shape[-1])
    return x.mean(0), x.std(0)
