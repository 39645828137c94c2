"""The gyro's per-axis scale read from a record alone — no reference, no learned part (offline).

At a *rest* — a quasi-static moment: over ``rest_min_s`` the rotation rate stays below
``rest_rate_rad_s`` and the accelerometer's norm within ``rest_acc_tol_m_s2`` of its resting norm —
the accelerometer shows gravity in body axes. Between two rests the gyro's rotation, integrated,
must carry the first gravity direction onto the second. A per-axis scale error ``s`` (gyro read
× s) breaks that by about ``ε·θ`` per phase turned through θ: on a hand-held trial that turns
thousands of degrees between its rests, half a per cent is degrees of disagreement, and it is what
VQF's tilt carries between its accelerometer corrections (BROAD's gyro, session 10).

The gyro's bias, removed before the scale is read, is its mean over the stillest rest samples: those whose
averaged rate is below ``still_rate_rad_s`` or, on a noisy gyro whose white noise alone averages above that,
below ``still_floor_factor`` × the rests' 5th-percentile rate (rule 20, session 30: otherwise the bias came
from every rest sample, slow motion included, and a wrong scale was read).

A *phase* runs from the end of a rest to the start of the first later rest that is at least
``min_turn_deg`` of turning away, within ``max_phase_s``, inside one segment and with no gyro sample
at its range (saturation); its ends sit at the stillest moment of the rests' last and first
``end_s`` (a rest's edge may already lie in the turn's slow start). The disagreements of all phases fix
``s`` by Gauss–Newton (one pass over the record per step gives the phases' attitudes and their
sensitivity to each axis' scale, :func:`attitude_at`; a Gaussian prior ``s − 1 ~ N(0, prior_sigma²)``
per axis, so an axis the motion does not excite stays at 1 — rotation about gravity, a yaw turn,
tells nothing).

The fitted scale is **applied only on evidence** (``gate_ratio``): each phase is predicted by the
scale fitted on the others (leave one phase out), and the scale is taken only where those
predictions disagree by at most ``gate_ratio`` × the disagreement at scale 1 (RMS over phases).
Most records give no such evidence — in flight, "rests" are hovers or cruise, whose accelerometer
is not gravity alone — and keep the scale they had.

Whole-record and not causal: the offline estimator (:func:`.estimate.estimate_anchored`) fits it
before its pass, and where it applies its scale replaces ``AnchorConfig.gyro_scale``; the live
estimator does not (a vehicle's calibration for the live path: ``AnchorConfig.gyro_scale``, fitted
by ``train --init``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..config import check_range
from ..quat import quat_to_rotmat
from ..quat_scalar import exp_rotvec, qmul, qnorm, rotmat_entries


@dataclass(frozen=True)
class GyroSelfCalConfig:
    """The self-calibration's settings. Defaults are the shipped model's (set on the shared BROAD
    trials and the training-campaign flights, session 13)."""

    rest_rate_rad_s: float = 0.35  # a rest: the rate's norm, averaged over rest_min_s, below this
    rest_acc_tol_m_s2: float = 0.3  # ... and the accelerometer's norm within this of its resting norm
    rest_min_s: float = 0.2  # the averaging and the shortest rest
    still_rate_rad_s: float = 0.05  # the gyro's bias: its mean where the rate stays below this at rest ...
    # ... or below this × the 5th percentile of the averaged rate at rest, where that is higher: a noisy gyro's
    # floor (white noise of 2 °/s per sample averages to |ω| ≈ 0.056 rad/s: no sample would be still, and the
    # bias would come from slow motion; session 30, rule 20). 0: off (before session 30)
    still_floor_factor: float = 1.5
    end_s: float = 1.0  # a phase starts (ends) at the stillest moment of a rest's last (first) end_s
    max_phase_s: float = 120.0
    min_turn_deg: float = 60.0  # integrated |ω| over a phase
    min_phases: int = 3
    prior_sigma: float = 0.02  # of each axis' scale error
    gate_ratio: float = 0.5  # leave-one-phase-out RMS ≤ this × the RMS at scale 1
    iterations: int = 3
    max_scale_error: float = 0.05  # a fit beyond ±5 % on an axis is not a calibration residual: not applied

    def __post_init__(self):
        for name in ("rest_rate_rad_s", "rest_acc_tol_m_s2", "rest_min_s", "still_rate_rad_s", "end_s", "max_phase_s",
                     "prior_sigma", "max_scale_error"):  # fmt: skip
            check_range(name, getattr(self, name), 0, None, lo_open=True)
        check_range("min_turn_deg", self.min_turn_deg, 0, None)
        check_range("still_floor_factor", self.still_floor_factor, 0, None)
        check_range("min_phases", self.min_phases, 2, 10**6)
        check_range("gate_ratio", self.gate_ratio, 0, 1)
        check_range("iterations", self.iterations, 1, 100)


@dataclass(frozen=True)
class GyroSelfCal:
    """What :func:`self_calibrate` found. ``scale`` is what to apply (ones unless ``applied``)."""

    scale: tuple[float, float, float]
    applied: bool
    phases: int
    fitted: tuple[float, float, float] | None = None  # the fit on every phase (None: too few phases)
    rms_deg: float = math.nan  # end-to-end gravity disagreement at scale 1, RMS over phases
    rms_loo_deg: float = math.nan  # ... each phase predicted by the scale fitted on the others

    def describe(self) -> str:
        """One line for a user."""
        if self.fitted is None:
            return f"gyro self-calibration: {self.phases} phase(s) between rests, too few to read a scale; not applied"
        f = ", ".join(f"{v:.4f}" for v in self.fitted)
        what = "applied" if self.applied else "not applied (no evidence)"
        return (f"gyro self-calibration: scale ({f}) from {self.phases} phases between rests, "
                f"disagreement {self.rms_deg:.2f}° at 1, {self.rms_loo_deg:.2f}° predicted; {what}")  # fmt: skip


@njit(cache=True)
def attitude_at(gyr, dt, s0, s1, s2, b0, b1, b2, at, q_out, a_out):
    """The gyro ``s ⊙ (gyr − b)`` integrated over the record (exact per-sample turns) from the
    identity at sample ``at[0]``, read at the sorted sample indices ``at``: ``q_out`` (m, 4) the
    attitude there (body → the frame at ``at[0]``); ``a_out`` (m, 3, 3) the running sum, in that frame,
    of each step's turn per unit of each axis' scale (column k: ``R_i e_k (gyr_k − b_k) dt``, R_i the
    attitude after step i — first order in the step). Between samples i0 and i1 a scale change δ on
    axis k then turns body-at-i1 by ``R_i0ᵀ (a[i1] − a[i0])[:, k] δ`` in body-at-i0 axes."""
    w, x, y, z = 1.0, 0.0, 0.0, 0.0
    a00 = a10 = a20 = a01 = a11 = a21 = a02 = a12 = a22 = 0.0
    i = at[0]
    for m in range(len(at)):
        while i < at[m]:
            p0, p1, p2 = (gyr[i, 0] - b0) * dt[i], (gyr[i, 1] - b1) * dt[i], (gyr[i, 2] - b2) * dt[i]
            dw, dx, dy, dz = exp_rotvec(s0 * p0, s1 * p1, s2 * p2)
            w, x, y, z = qnorm(*qmul(w, x, y, z, dw, dx, dy, dz))
            r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotmat_entries(w, x, y, z)
            a00 += r00 * p0
            a10 += r10 * p0
            a20 += r20 * p0
            a01 += r01 * p1
            a11 += r11 * p1
            a21 += r21 * p1
            a02 += r02 * p2
            a12 += r12 * p2
            a22 += r22 * p2
            i += 1
        q_out[m, 0], q_out[m, 1], q_out[m, 2], q_out[m, 3] = w, x, y, z
        a_out[m, 0, 0], a_out[m, 1, 0], a_out[m, 2, 0] = a00, a10, a20
        a_out[m, 0, 1], a_out[m, 1, 1], a_out[m, 2, 1] = a01, a11, a21
        a_out[m, 0, 2], a_out[m, 1, 2], a_out[m, 2, 2] = a02, a12, a22


def _boxcar(x: np.ndarray, k: int) -> np.ndarray:
    """Centred moving average over ``k`` rows (the edges hold the nearest full average)."""
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x]), axis=0)
    full = (c[k:] - c[:-k]) / k
    lead = (k - 1) // 2
    return np.concatenate([np.repeat(full[:1], lead, 0), full, np.repeat(full[-1:], len(x) - len(full) - lead, 0)])


@dataclass(frozen=True)
class Phases:
    """Phases between rests: sample bounds, gravity directions at both ends (body axes), the bias."""

    i0: np.ndarray
    i1: np.ndarray
    up0: np.ndarray  # (P, 3) unit
    up1: np.ndarray
    bias: np.ndarray  # (3,) rad/s, removed before scaling

    def __len__(self) -> int:
        return len(self.i0)


def find_phases(t_s, gyr, acc, segment, gyr_clipped, cfg: GyroSelfCalConfig) -> tuple[np.ndarray, Phases]:
    """(dt per sample, the record's :class:`Phases`). Inputs: finite rows, body axes, SI."""
    n = len(t_s)
    d = np.diff(t_s)
    dt = np.append(d, np.median(d) if n > 1 else 0.0)
    empty = Phases(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(3))
    step = float(np.median(d)) if n > 1 else 0.0
    if n < 3 or not (np.isfinite(step) and step > 0):
        return dt, empty
    k = max(1, int(round(cfg.rest_min_s / step)))
    if n < 2 * k:
        return dt, empty
    g_norm = np.sqrt(np.einsum("ij,ij->i", gyr, gyr))
    rate = _boxcar(g_norm[:, None], k)[:, 0]
    acc_lp = _boxcar(acc, k)
    a_norm = np.sqrt(np.einsum("ij,ij->i", acc_lp, acc_lp))
    quiet = rate < cfg.rest_rate_rad_s
    if quiet.sum() < k:
        return dt, empty
    rest = quiet & (np.abs(a_norm - np.median(a_norm[quiet])) < cfg.rest_acc_tol_m_s2)  # the resting norm: a board may read 0.8 g
    still_below = cfg.still_rate_rad_s
    if cfg.still_floor_factor > 0 and rest.any():  # above a noisy gyro's floor (the config's comment)
        still_below = max(still_below, cfg.still_floor_factor * float(np.percentile(rate[rest], 5.0)))
    still = rest & (rate < still_below)
    bias = gyr[still].mean(0) if still.sum() >= 10 * k else (gyr[rest].mean(0) if rest.sum() >= 10 * k else np.zeros(3))
    idx = np.flatnonzero(rest)
    runs = [r for r in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1) if len(r) >= k]
    if len(runs) < 2:
        return dt, empty
    # each rest's end and start at its stillest moment within end_s of the edge: a rest's edge
    # samples may sit in the turn's slow start, whose averaged accelerometer leans into the turn
    m = max(1, int(round(cfg.end_s / step)))
    ends = np.array([int(r[-m:][np.argmin(rate[r[-m:]])]) for r in runs])
    starts = np.array([int(r[:m][np.argmin(rate[r[:m]])]) for r in runs])
    turned = np.concatenate([[0.0], np.cumsum(g_norm * dt)])  # non-decreasing
    clip_count = np.concatenate([[0], np.cumsum(np.asarray(gyr_clipped, bool))])
    turned_at_starts = turned[starts]
    i0s, i1s = [], []
    for j in range(len(runs) - 1):
        i0 = int(ends[j])
        # the first later rest at least min_turn_deg of turning away
        nxt = max(j + 1, int(np.searchsorted(turned_at_starts, turned[i0] + math.radians(cfg.min_turn_deg), "left")))
        if nxt >= len(runs):
            continue
        i1 = int(starts[nxt])
        if t_s[i1] - t_s[i0] > cfg.max_phase_s or segment[i1] != segment[i0] or clip_count[i1 + 1] > clip_count[i0]:
            continue
        i0s.append(i0)
        i1s.append(i1)
    i0a, i1a = np.array(i0s, np.int64), np.array(i1s, np.int64)
    up0 = acc_lp[i0a] / np.linalg.norm(acc_lp[i0a], axis=1, keepdims=True) if len(i0a) else np.zeros((0, 3))
    up1 = acc_lp[i1a] / np.linalg.norm(acc_lp[i1a], axis=1, keepdims=True) if len(i1a) else np.zeros((0, 3))
    return dt, Phases(i0a, i1a, up0, up1, bias)


def carried(gyr, dt, ph: Phases, scale) -> tuple[np.ndarray, np.ndarray]:
    """(c (P, 3), dc (P, 3, 3)): each phase's start gravity carried by the gyro × ``scale`` to its end
    (body axes there) and its derivative by each axis' scale — one pass over the record."""
    at, inv = np.unique(np.concatenate([ph.i0, ph.i1]), return_inverse=True)
    q = np.empty((len(at), 4))
    acc = np.empty((len(at), 3, 3))
    s, b = [float(v) for v in scale], [float(v) for v in ph.bias]
    if len(at):
        attitude_at(gyr, dt, s[0], s[1], s[2], b[0], b[1], b[2], at, q, acc)
    p = len(ph)
    r0, r1 = quat_to_rotmat(q[inv[:p]]), quat_to_rotmat(q[inv[p:]])  # body at i0 / i1 → the frame at at[0]
    turn = np.einsum("pji,pjk->pik", r0, r1)  # body at i1 → body at i0
    c = np.einsum("pji,pj->pi", turn, ph.up0)  # turnᵀ up0
    a = np.einsum("pji,pjk->pik", r0, acc[inv[p:]] - acc[inv[:p]])  # columns a_k, body-at-i0 axes
    dc = -np.einsum("pji,pjk->pik", turn, np.cross(a, ph.up0[:, :, None], axisa=1, axisb=1, axisc=1))
    return c, dc


def _jacobian(gyr, dt, ph: Phases, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(r (P, 3), J (P, 3, 3)): the disagreements at ``s`` — ``carried × up1`` per phase, the
    small-angle rotation (rad) between the gravity the gyro carries to each phase's end and the gravity
    the accelerometer shows there — and their derivative by each axis' scale."""
    c, dc = carried(gyr, dt, ph, s)
    return np.cross(c, ph.up1), np.cross(dc, ph.up1[:, :, None], axisa=1, axisb=1, axisc=1)


def _step(r: np.ndarray, jac: np.ndarray, s: np.ndarray, cfg: GyroSelfCalConfig) -> np.ndarray:
    """The Gauss–Newton step from ``s`` for residuals ``r`` (P, 3), Jacobians ``jac`` (P, 3, 3), with
    the prior; the residuals' own mean square as their variance."""
    var = max(float(np.mean(r**2)), 1e-12)
    jj = np.einsum("pki,pkj->ij", jac, jac)
    jr = np.einsum("pki,pk->i", jac, r)
    a = jj / var + np.eye(3) / cfg.prior_sigma**2
    return np.linalg.solve(a, -jr / var - (s - 1.0) / cfg.prior_sigma**2)


def fit_scale(gyr, dt, ph: Phases, cfg: GyroSelfCalConfig):
    """(s, r, J, r₁): the per-axis scale that best carries each phase's gravity onto its end
    (Gauss–Newton with the prior), the disagreements and their Jacobians there, and the
    disagreements at scale 1."""
    s = np.ones(3)
    base = None
    for _ in range(cfg.iterations):
        r, jac = _jacobian(gyr, dt, ph, s)
        base = r if base is None else base
        s = s + _step(r, jac, s, cfg)
    r, jac = _jacobian(gyr, dt, ph, s)
    return s, r, jac, base


def self_calibrate(t_s, gyr, acc, segment=None, gyr_clipped=None, cfg: GyroSelfCalConfig | None = None) -> GyroSelfCal:
    """The per-axis gyro scale of a record (rows: body axes, SI; non-finite rows are read as zeros
    — bridge holes first), applied only on evidence (module docstring)."""
    cfg = cfg or GyroSelfCalConfig()
    t_s = np.asarray(t_s, np.float64)
    gyr = np.ascontiguousarray(np.nan_to_num(np.asarray(gyr, np.float64)))
    acc = np.nan_to_num(np.asarray(acc, np.float64))
    segment = np.zeros(len(t_s), np.int64) if segment is None else np.asarray(segment)
    gyr_clipped = np.zeros(len(t_s), bool) if gyr_clipped is None else np.asarray(gyr_clipped, bool)
    dt, ph = find_phases(t_s, gyr, acc, segment, gyr_clipped, cfg)
    p = len(ph)
    if p < cfg.min_phases:
        return GyroSelfCal((1.0, 1.0, 1.0), False, p)
    s, r, jac, base = fit_scale(gyr, dt, ph, cfg)
    loo = np.empty_like(base)  # each phase predicted by the fit on the others (one step from s: linear there)
    for j in range(p):
        o = np.arange(p) != j
        loo[j] = r[j] + jac[j] @ _step(r[o], jac[o], s, cfg)
    rms = float(np.sqrt(np.mean(np.sum(base**2, 1))))
    rms_loo = float(np.sqrt(np.mean(np.sum(loo**2, 1))))
    ok = rms_loo <= cfg.gate_ratio * rms and bool(np.all(np.abs(s - 1.0) <= cfg.max_scale_error))
    fitted = tuple(float(v) for v in s)
    return GyroSelfCal(fitted if ok else (1.0, 1.0, 1.0), ok, p, fitted, math.degrees(rms), math.degrees(rms_loo))
