"""Fitting the anchored estimator's σ (``AnchorConfig.sigma_floor_deg`` σ₀, ``sigma_acc_gain`` c) to
real files with a trusted reference.

With every gate off (the case on real data; :mod:`.anchor`), ``σ² = σ₀² + (c·e)²``, e the
accelerometer-disagreement angle the filter computes anyway. :func:`error_samples` runs the plain
filter over a record once (:func:`estimator_error_samples`: the whole anchored estimator, what the
fine-tuning fits on) and keeps, per scored sample, the squared 2-D tilt error and e; then any
(σ₀, c) is scored without running the filter again. :func:`fit_sigma` picks, on a grid, the pair
whose mean NEES (per file averaged) is nearest 2 (a 2-D error: E[NEES] = 2 when σ is right) among
those that keep at least ``coverage`` of the samples within 3σ, per file averaged.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..model.anchor import AnchorConfig, AnchoredVQF
from ..model.streaming import TS_STEPS
from ..record import FlightRecord
from .harness import scoring_mask
from .metrics import error_quat_earth, tilt_error_vector_rad


@dataclass(frozen=True)
class ErrorSamples:
    """One file's scored samples: squared tilt error (rad²) and the σ model's input e (rad)."""

    name: str
    err2_rad2: np.ndarray
    e_acc_rad: np.ndarray


@dataclass(frozen=True)
class SigmaFit:
    sigma_floor_deg: float
    sigma_acc_gain: float
    nees: float  # mean NEES, per file averaged
    coverage_3sigma: float  # share within 3σ, per file averaged


def error_samples(rec: FlightRecord, name: str = "", anchor: AnchorConfig | None = None,
                  warmup_s: float = 5.0) -> ErrorSamples:  # fmt: skip
    """Run the anchored filter with its learned corrections off (what real files see when no gate
    fires) over the first segment of ``rec`` and keep the scored samples."""
    cfg = dataclasses.replace((anchor or AnchorConfig()).learned_off, sigma_floor_deg=0.0, sigma_acc_gain=1.0)
    seg0 = rec.segment == rec.segment[0]
    t = rec.t_s[seg0]
    dt = np.diff(t[: TS_STEPS + 1])
    flt = AnchoredVQF(cfg, float(np.median(dt)) if dt.size else 0.01)
    q, _, e, _ = flt.update(t, rec.gyr_rad_s[seg0], rec.acc_m_s2[seg0], None, rec.gyr_clipped[seg0])
    return _scored(name, q, e, rec.q_ref_wxyz[seg0], (scoring_mask(rec, warmup_s) & seg0)[seg0])


def estimator_error_samples(model, rec: FlightRecord, anchor: AnchorConfig, name: str = "",
                            warmup_s: float = 5.0) -> ErrorSamples:  # fmt: skip
    """The scored samples of the whole anchored estimator ``anchor`` (every segment, its gates and
    offline steps) on ``rec``: e is read from its own σ with σ₀ = 0, c = 1 and the network's share
    off (σ = e). What the fine-tuning fits σ on."""
    from ..model.estimate import EST_Q_COLS, estimate_anchored

    probe = dataclasses.replace(anchor, sigma_floor_deg=0.0, sigma_acc_gain=1.0, sigma_net_scale=0.0)
    est = estimate_anchored(model, rec, probe)
    return _scored(name, est[EST_Q_COLS].to_numpy(), est["sigma_rad"].to_numpy(), rec.q_ref_wxyz,
                   scoring_mask(rec, warmup_s))  # fmt: skip


def _scored(name: str, q, e, q_ref, mask) -> ErrorSamples:
    """The samples of ``mask`` where the estimate and e are finite: squared 2-D tilt error and e."""
    m = mask & np.all(np.isfinite(q), axis=1) & np.isfinite(e)
    ev = tilt_error_vector_rad(error_quat_earth(q[m], q_ref[m]))
    return ErrorSamples(name, np.sum(ev**2, axis=1), e[m])


def score(files: list[ErrorSamples], sigma_floor_deg: float, sigma_acc_gain: float) -> tuple[float, float]:
    """(mean NEES, share within 3σ), each per file averaged."""
    nees, cov = [], []
    for f in files:
        if not len(f.err2_rad2):
            continue
        s2 = np.radians(sigma_floor_deg) ** 2 + (sigma_acc_gain * f.e_acc_rad) ** 2
        nees.append(float(np.mean(f.err2_rad2 / s2)))
        cov.append(float(np.mean(f.err2_rad2 <= 9.0 * s2)))
    return float(np.mean(nees)), float(np.mean(cov))


def fit_sigma(files: list[ErrorSamples], coverage: float = 0.97, nees_target: float = 2.0,
              floors_deg=np.arange(0.2, 1.01, 0.05), gains=np.arange(0.0, 0.151, 0.005)) -> SigmaFit:  # fmt: skip
    """The grid point with mean NEES nearest ``nees_target`` among those with coverage ≥
    ``coverage``; if none reaches it, the one with the highest coverage."""
    if not any(len(f.err2_rad2) for f in files):
        raise ValueError("no scored samples to fit σ on")
    best, best_key = None, None
    for f0 in floors_deg:
        for c in gains:
            n, cv = score(files, float(f0), float(c))
            key = (0, abs(n - nees_target)) if cv >= coverage else (1, -cv)
            if best_key is None or key < best_key:
                best, best_key = SigmaFit(round(float(f0), 4), round(float(c), 4), n, cv), key
    return best

