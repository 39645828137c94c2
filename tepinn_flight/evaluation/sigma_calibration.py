"""Fitting the anchored estimator's σ (``AnchorConfig.sigma_floor_deg`` σ₀, ``sigma_acc_gain`` c) to
real files with a trusted reference.

With every gate off (the case on real data; :mod:`.anchor`), ``σ² = σ₀² + (c·e)² + g·v + E²``, e the
accelerometer-disagreement angle the filter computes anyway, v the sampling term (the attitude's
turn within a sample period, ``AnchorConfig.sigma_sampling_gain`` g: 0 or its physical 1) and E the
gyro-saturation term (``sigma_clip_gain``, ``sigma_clip_tau_s``: kept as configured, not fitted; zero
on a file whose gyro never clips).
:func:`error_samples` runs the plain filter over a record (:func:`estimator_error_samples`: the whole
anchored estimator, what the fine-tuning fits on) and keeps, per scored sample, the squared 2-D tilt
error, e and v — each read from the filter's own σ with the other parts switched off; then any
(σ₀, c, g) is scored without running the filter again. :func:`fit_sigma` picks, on a grid, the pair
whose mean NEES (per file averaged) is nearest 2 (a 2-D error: E[NEES] = 2 when σ is right) among
those that keep at least ``coverage`` of the samples within 3σ, per file averaged.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..model.anchor import AnchorConfig, AnchoredVQF, acc_gain, aircraft_var_rad2
from ..record import FlightRecord
from ..record_gaps import bridge_gaps, segment_period_s
from .harness import scoring_mask
from .metrics import error_quat_earth, tilt_error_vector_rad


@dataclass(frozen=True)
class ErrorSamples:
    """One file's scored samples: squared tilt error (rad²), the σ model's input e (rad), its
    sampling term at g = 1 (rad²; None: zero) and its saturation term E² as configured (rad²; None:
    zero)."""

    name: str
    err2_rad2: np.ndarray
    e_acc_rad: np.ndarray
    samp_var_rad2: np.ndarray | None = None
    clip_var_rad2: np.ndarray | None = None
    vehicle: str | None = None  # the record's vehicle_type (σ's aircraft term, rule 28)

    def var_rad2(self, sigma_floor_deg: float, sigma_acc_gain: float, sigma_sampling_gain: float = 0.0,
                 sigma_aircraft_deg: float = 0.0, sigma_acc_gain_aircraft: float = 0.0) -> np.ndarray:  # fmt: skip
        """σ² of each sample of the causal estimate for (σ₀, c, g), with σ_a and c_a (rules 28, 29) where the file's
        vehicle takes them."""
        c, extra = sigma_acc_gain, 0.0
        if sigma_aircraft_deg or sigma_acc_gain_aircraft:  # (a fit leaves both at 0: no settings made per grid point)
            cfg = AnchorConfig(sigma_acc_gain=sigma_acc_gain, sigma_aircraft_deg=sigma_aircraft_deg,
                               sigma_acc_gain_aircraft=sigma_acc_gain_aircraft)  # fmt: skip
            c, extra = acc_gain(cfg, self.vehicle, causal=True), aircraft_var_rad2(cfg, self.vehicle)
        v = np.radians(sigma_floor_deg) ** 2 + (c * self.e_acc_rad) ** 2 + extra
        if sigma_sampling_gain and self.samp_var_rad2 is not None:
            v = v + sigma_sampling_gain * self.samp_var_rad2
        if self.clip_var_rad2 is not None:
            v = v + self.clip_var_rad2
        return v


@dataclass(frozen=True)
class SigmaFit:
    sigma_floor_deg: float
    sigma_acc_gain: float
    sigma_sampling_gain: float
    nees: float  # mean NEES, per file averaged
    coverage_3sigma: float  # share within 3σ, per file averaged


def error_samples(rec: FlightRecord, name: str = "", anchor: AnchorConfig | None = None,
                  warmup_s: float = 5.0) -> ErrorSamples:  # fmt: skip
    """Run the anchored filter with its learned corrections off (what real files see when no gate
    fires) over the first segment of ``rec`` — its short dropouts bridged, as every estimate bridges them
    (:func:`~tepinn_flight.record_gaps.bridge_gaps`) — and keep the scored samples."""
    rec = bridge_gaps(rec).record  # (the filled samples carry no reference: never scored)
    off = (anchor or AnchorConfig()).learned_off
    seg0 = rec.segment == rec.segment[0]
    t = rec.t_s[seg0]
    clipped = rec.gyr_clipped[seg0]
    outs = []
    for probe in _probes(off, bool(np.any(clipped))):
        flt = AnchoredVQF(probe, segment_period_s(t, 0.01))
        outs.append(flt.update(t, rec.gyr_rad_s[seg0], rec.acc_m_s2[seg0], None, clipped))
    return _scored(name, outs[0][0], outs[0][2], outs[1][2], rec.q_ref_wxyz[seg0],
                   (scoring_mask(rec, warmup_s) & seg0)[seg0], outs[2][2] if len(outs) > 2 else None)  # fmt: skip


def estimator_error_samples(model, rec: FlightRecord, anchor: AnchorConfig, name: str = "",
                            warmup_s: float = 5.0) -> ErrorSamples:  # fmt: skip
    """The scored samples of the whole anchored estimator ``anchor`` (every segment, its gates and
    offline steps) on ``rec``: e is read from its own σ with σ₀ = 0, c = 1 and the other parts off
    (σ = e), the sampling term with σ₀ = c = 0, g = 1 (σ² = the term; the estimates are the same: σ is
    an output only), the saturation term alone where the gyro clips. What the fine-tuning fits σ on: the estimate
    ``estimate`` gives and the samples ``evaluate`` scores (short dropouts bridged, not restarted: session 53)."""
    from ..model.estimate import EST_Q_COLS, estimate_anchored

    br = bridge_gaps(rec)
    est = [br.original(estimate_anchored(model, br.record, p)) for p in _probes(anchor, bool(np.any(rec.gyr_clipped)))]
    mask = scoring_mask(br.record, warmup_s)[br.rows]  # the harness's mask (on the bridged record), on rec's rows
    return _scored(name, est[0][EST_Q_COLS].to_numpy(), est[0]["sigma_rad"].to_numpy(),
                   est[1]["sigma_rad"].to_numpy(), rec.q_ref_wxyz, mask,
                   est[2]["sigma_rad"].to_numpy() if len(est) > 2 else None, rec.meta.get("vehicle_type"))  # fmt: skip


def _probes(anchor: AnchorConfig, clips: bool = False) -> tuple[AnchorConfig, ...]:
    """``anchor`` whose σ is e alone, and whose σ² is the sampling term at g = 1 alone (the network's
    share and the saturation term off); with ``clips`` (the gyro clips), a third whose σ is the
    saturation term alone, as ``anchor`` sets it."""
    off = dict(sigma_floor_deg=0.0, sigma_net_scale=0.0, sigma_clip_gain=0.0, sigma_aircraft_deg=0.0,
               sigma_acc_gain_aircraft=0.0)  # fmt: skip
    e_only = dataclasses.replace(anchor, **off, sigma_acc_gain=1.0, sigma_sampling_gain=0.0)
    samp_only = dataclasses.replace(anchor, **off, sigma_acc_gain=0.0, sigma_sampling_gain=1.0)
    if not (clips and anchor.sigma_clip_gain > 0):
        return e_only, samp_only
    clip_only = dataclasses.replace(anchor, **{**off, "sigma_clip_gain": anchor.sigma_clip_gain}, sigma_acc_gain=0.0,
                                    sigma_sampling_gain=0.0)  # fmt: skip
    return e_only, samp_only, clip_only


def motion_probe(anchor: AnchorConfig) -> AnchorConfig:
    """``anchor`` whose σ is e alone — the 1-s mean angle between the accelerometer and VQF's gravity, the witness of
    σ's accelerometer term — every other term of σ off (floor, sampling, network, saturation, gap, aircraft terms):
    the estimates are ``anchor``'s (σ is an output only). Rule 29's gain was chosen with it."""
    return dataclasses.replace(anchor, sigma_floor_deg=0.0, sigma_net_scale=0.0, sigma_clip_gain=0.0, sigma_acc_gain=1.0,
                               sigma_sampling_gain=0.0, sigma_gap_gain=0.0, sigma_aircraft_deg=0.0,
                               sigma_acc_gain_aircraft=0.0)  # fmt: skip


def _scored(name: str, q, e, s_samp, q_ref, mask, s_clip=None, vehicle: str | None = None) -> ErrorSamples:
    """The samples of ``mask`` where the estimate and e are finite: squared 2-D tilt error, e, the
    sampling term (``s_samp``² per sample) and the saturation term (``s_clip``²; None: zero)."""
    m = mask & np.all(np.isfinite(q), axis=1) & np.isfinite(e) & np.isfinite(s_samp)
    ev = tilt_error_vector_rad(error_quat_earth(q[m], q_ref[m]))
    return ErrorSamples(name, np.sum(ev**2, axis=1), e[m], s_samp[m] ** 2, None if s_clip is None else s_clip[m] ** 2,
                        vehicle)  # fmt: skip


def score(files: list[ErrorSamples], sigma_floor_deg: float, sigma_acc_gain: float,
          sigma_sampling_gain: float = 0.0, sigma_aircraft_deg: float = 0.0,
          sigma_acc_gain_aircraft: float = 0.0) -> tuple[float, float]:  # fmt: skip
    """(mean NEES, share within 3σ), each per file averaged; ``sigma_aircraft_deg``, ``sigma_acc_gain_aircraft``: σ_a
    and c_a on the files whose vehicle takes them (the fit leaves both at 0: a fine-tuned model's σ₀ and c are its
    vehicle's own)."""
    nees, cov = [], []
    for f in files:
        if not len(f.err2_rad2):
            continue
        s2 = f.var_rad2(sigma_floor_deg, sigma_acc_gain, sigma_sampling_gain, sigma_aircraft_deg, sigma_acc_gain_aircraft)
        nees.append(float(np.mean(f.err2_rad2 / s2)))
        cov.append(float(np.mean(f.err2_rad2 <= 9.0 * s2)))
    return float(np.mean(nees)), float(np.mean(cov))


def rule_key(nees: float, share_3sigma: float, coverage: float = 0.97, nees_target: float = 2.0) -> tuple:
    """σ's rule as a sort key (smaller is better): among σs that keep at least ``coverage`` of the samples within 3σ,
    the mean NEES nearest ``nees_target``; any of those before one that does not, and of those the higher share."""
    return (0, abs(nees - nees_target)) if share_3sigma >= coverage else (1, -share_3sigma)


def fit_sigma(files: list[ErrorSamples], coverage: float = 0.97, nees_target: float = 2.0,
              floors_deg=np.arange(0.2, 1.01, 0.05), gains=np.arange(0.0, 0.151, 0.005),
              sampling_gains=(0.0,)) -> SigmaFit:  # fmt: skip
    """The grid point (σ₀, c, g) with mean NEES nearest ``nees_target`` among those with coverage ≥
    ``coverage``; if none reaches it, the one with the highest coverage (ties: the first, g = 0
    before 1 with the default order)."""
    if not any(len(f.err2_rad2) for f in files):
        raise ValueError("no scored samples to fit σ on")
    best, best_key = None, None
    for g in sampling_gains:
        for f0 in floors_deg:
            for c in gains:
                n, cv = score(files, float(f0), float(c), float(g))
                key = rule_key(n, cv, coverage, nees_target)
                if best_key is None or key < best_key:
                    best, best_key = SigmaFit(round(float(f0), 4), round(float(c), 4), float(g), n, cv), key
    return best


def fit_added_sigma(files: list[tuple[np.ndarray, np.ndarray, np.ndarray | float]], coverage: float = 0.97,
                    nees_target: float = 2.0, grid=np.arange(0.0, 1.001, 0.05)) -> tuple[float | None, list[tuple[float, float, float]]]:  # fmt: skip
    """σ's rule for a term added to an estimator's σ, σ'² = σ² + (x·u)² (rule 28's aircraft term: x = σ_a in degrees,
    u = 1° in radians; rule 29's causal motion term: x = c_a, u = e per sample): ``files`` each (squared 2-D tilt
    error, σ without the term, u) on its scored samples → (the ``grid``'s x whose per-file mean NEES is nearest
    ``nees_target`` among those with at least ``coverage`` within 3σ, per file averaged — None if none reaches it —,
    and every grid point's (x, NEES, share within 3σ))."""
    table, best, best_key = [], None, None
    for x in grid:
        r = [e2 / (s * s + (float(x) * u) ** 2) for e2, s, u in files if len(e2)]
        n, cv = float(np.mean([np.mean(v) for v in r])), float(np.mean([np.mean(v <= 9.0) for v in r]))
        table.append((round(float(x), 4), n, cv))
        key = rule_key(n, cv, coverage, nees_target)
        if key[0] == 0 and (best_key is None or key < best_key):
            best, best_key = round(float(x), 4), key
    return best, table
