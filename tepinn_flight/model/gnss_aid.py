"""GNSS-aided tilt: the motion acceleration the receiver's velocity shows, taken out of the
accelerometer before the filter reads it as gravity (offline, whole records).

A gravity-referenced filter (VQF, ours) takes the accelerometer's low-passed direction for "down".
In a turn, a pull-up or a long acceleration the specific force is ``f = R_bn (a_n − g_n)``: it
points away from down by ``a_n``, and the filter tilts toward it. The autopilot's own EKF removes
that with the GNSS velocity; this does the same for any estimator, in three steps:

1. **Motion acceleration in NED** from the receiver: ``a_n = dv/dt``, the velocity's difference
   over ``smooth_s`` (a centred average of the derivative), read ``latency_s`` later (the fix
   describes the vehicle a little before it is logged). Horizontal only: a vertical acceleration
   changes the specific force's length, not its direction.
2. **The filter's heading**: a 6-D filter's heading is arbitrary and drifts, so ``a_n`` cannot be
   turned into body axes directly. In the filter's earth frame the specific force's horizontal
   part *is* the horizontal acceleration, turned by the heading offset ψ: with complex numbers
   ``f_h ≈ e^{iψ} a_h``. ψ is read over a sliding ``heading_window_s`` as the argument of
   ``Σ f_h · conj(a_h)``, and trusted where the two agree (coherence
   ``|Σ f_h conj(a_h)| / √(Σ|f_h|² Σ|a_h|²) ≥ min_coherence``) with enough acceleration to read a
   direction from (``min_accel_m_s2`` RMS), below ``max_speed_m_s`` of ground speed — a limit the
   shipped estimator lifts (``AnchorConfig.gnss_aid_in_flight``: at speed the network's flight-speed
   gate acts beside the aid). Elsewhere no correction: where the vehicle hardly accelerates there is
   nothing to correct either.
3. **Body axes**: ``a_b = R_nbᵀ e^{iψ} a_h``, clipped to ``max_accel_m_s2``, with the previous
   pass's attitude; the filter then runs again on ``f − a_b`` (``passes`` corrections in all:
   :func:`tepinn_flight.model.estimate.gnss_aided_acc`, which also marks the windows where the aid
   holds: there the flight-speed gate drops its centripetal term, :class:`.anchor.WindowOutput`).

Offline only: the averages are centred and the filter runs over the record again. A causal version
(the acceleration of the last second of fixes, ~0.6 s old) gained nothing on the training flights
(docs/design-log.md, session 14).

No learned part, no reference. A record without GNSS velocity, or one where it never agrees with
the accelerometer, gets no correction (the estimate is the plain one, bit for bit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import check, finite_nonneg
from .gnss_aid_kernels import rotate_rows, window_sums


@dataclass(frozen=True)
class GnssAidConfig:
    """Settings of the GNSS-aided tilt; the defaults are the shipped estimator's."""

    smooth_s: float = 1.0  # the velocity's difference (and the specific force's average) over this
    latency_s: float = 0.1  # a fix describes the vehicle this long before its log time
    heading_window_s: float = 30.0  # the heading offset ψ is read over this sliding window
    min_coherence: float = 0.7  # ψ trusted where |Σ f conj(a)| / √(Σ|f|² Σ|a|²) reaches this
    min_accel_m_s2: float = 0.2  # … and the window's RMS horizontal acceleration reaches this
    # the correction is clipped to this length: beyond it a 5 Hz receiver's differenced velocity is too
    # coarse to follow (aerobatics: loops at 3 g). Clipped, not dropped: removing the small
    # accelerations of a manoeuvre and leaving its peaks biases the filter's low-pass, which the
    # manoeuvre's accelerations otherwise average out of
    max_accel_m_s2: float = 15.0
    # no correction above this ground speed (and margin_s around) where aided windows shut the
    # flight-speed gate (AnchorConfig.gnss_aid_in_flight false, session 14): measured on the training
    # campaign's fixed-wing flights, the aid alone turned loops, pull-ups and pushovers into flips.
    # With the gate kept beside it (gnss_aid_in_flight, the shipped estimator) there is no limit
    max_speed_m_s: float = 20.0
    margin_s: float = 1.0
    passes: int = 2  # attitude → correction → attitude, this many corrections
    # no heading evidence within the averages' span of a sample whose gyro clipped (``motion_acc_body``'s
    # ``gyr_clipped``): the attitude that turns the specific force into the earth frame is wrong there, and
    # a tumble past the gyro's range would turn ψ for the heading window around it. The correction itself
    # is kept everywhere (cutting it on and off biases the filter's low-pass: an accelerometer whose
    # clipping is marked every 3 s took the training multirotors from 4.1° to 6.7°, session 22)
    clip_guard: bool = True
    # a hole in the fixes inside their span (ingest leaves NaN across a gap of more than 2.5 fix periods) is bridged
    # linearly for the correction: there it is the hole's mean acceleration, whose integral is the velocity's change
    # across it, so the filter's low-pass sees the right mean. The heading's evidence is read from real fixes only.
    # Off, the correction is zero in the hole and kept on both sides: a short outage at a manoeuvre's peak (an
    # antenna turned over in a flip) left its acceleration uncorrected where the rest was (rule 36). ``bridge_gaps``
    # is this record's: :func:`tepinn_flight.model.estimate.aid_settings` sets it where the log names a vehicle of a
    # class in ``bridge_gaps_for`` (rule 36b: multirotors; on fixed wing the hole's windows leave the network's
    # flight-speed gate its centripetal term, which did better there than the bridged aid)
    bridge_gaps: bool = False
    bridge_gaps_for: tuple[str, ...] = ("multirotor",)
    # the receiver's latency read from the record (rule 37): the candidate latency whose acceleration agrees best with
    # the specific force (:func:`latency_scores`, pooled over ``heading_window_s`` blocks with the first aided pass's
    # attitude, or the plain pass's where that trusts nothing: :func:`tepinn_flight.model.estimate.gnss_aided_acc`)
    # replaces ``latency_s`` where its pooled coherence is at least ``latency_min_gain`` above ``latency_s``'s. A
    # receiver 0.5 s late read as 0.1 s turned the aid's gain into a loss (session 63's GNSS hunt). () reads none:
    # ``latency_s`` as set. ``latency_grid_s`` is this record's: :func:`tepinn_flight.model.estimate.
    # aid_settings` empties it unless the log names a vehicle of a class in ``read_latency_for`` (rule 37b:
    # multirotors; on fixed wing a receiver read late made the aid trusted again where it had hurt, rule 37)
    latency_grid_s: tuple[float, ...] = tuple(round(0.05 * i, 2) for i in range(13))
    latency_min_gain: float = 0.02
    read_latency_for: tuple[str, ...] = ("multirotor",)

    def __post_init__(self):
        finite_nonneg("margin_s", self.margin_s)
        for name in ("smooth_s", "heading_window_s", "min_accel_m_s2", "max_accel_m_s2"):
            check(np.isfinite(getattr(self, name)) and getattr(self, name) > 0, f"'{name}' must be > 0")
        check(self.max_speed_m_s > 0, "'max_speed_m_s' must be > 0 (inf: no limit)")
        finite_nonneg("latency_s", self.latency_s)
        check(0.0 <= self.min_coherence <= 1.0, "'min_coherence' must be in [0, 1]")
        check(int(self.passes) == self.passes and self.passes >= 1, "'passes' must be an integer ≥ 1")
        check(all(np.isfinite(x) and x >= 0 for x in self.latency_grid_s), "'latency_grid_s' takes latencies ≥ 0 s")
        finite_nonneg("latency_min_gain", self.latency_min_gain)
        from ..vehicle_class import CLASSES

        for name in ("bridge_gaps_for", "read_latency_for"):
            bad = [c for c in getattr(self, name) if c not in CLASSES]
            check(not bad, f"'{name}' takes vehicle classes ({', '.join(CLASSES)}), got {bad}")


@dataclass(frozen=True)
class GnssAid:
    """What the GNSS aid found on a record (``describe()`` is what ``estimate`` prints and stores)."""

    applied: bool
    covered_fraction: float  # samples with a usable GNSS acceleration
    corrected_fraction: float  # samples whose heading offset was trusted (correction applied)
    accel_rms_m_s2: float  # RMS of the horizontal motion acceleration where corrected
    reason: str
    latency_s: float | None = None  # the receiver's latency the aid used, where read from the record (rule 37)

    def describe(self) -> str:
        """One line for a user (ends with "; applied" where it was)."""
        if not self.applied:
            return f"GNSS-aided tilt: {self.reason}; not applied"
        late = "" if self.latency_s is None else f", the receiver read as {self.latency_s:.2f} s late"
        return (f"GNSS-aided tilt: motion acceleration {self.accel_rms_m_s2:.2f} m/s² RMS taken out of the accelerometer on "
                f"{100 * self.corrected_fraction:.0f} % of the samples (GNSS acceleration on {100 * self.covered_fraction:.0f} %"
                f"{late}); applied")  # fmt: skip


def _centred_mean(x: np.ndarray, k: int) -> np.ndarray:
    """Centred moving average over k samples (fewer at the ends), NaN-aware: NaN where any sample of
    the window is NaN. (``gyro_selfcal._boxcar`` is the rest detector's: NaN-free input, the edges
    holding the nearest full average.) The sums are compiled (:func:`.gnss_aid_kernels.window_sums`:
    the running sum's differences, numpy's operations in its order); the division stays numpy's
    (a complex average divides as numpy divides complex numbers)."""
    x = np.asarray(x)
    n = len(x)
    if n == 0:
        return np.array(x, dtype=np.complex128 if np.iscomplexobj(x) else np.float64)
    bad = ~np.isfinite(x)
    z = np.where(bad, 0.0, x).astype(np.complex128 if np.iscomplexobj(x) else np.float64, copy=False)  # sums in 64 bits
    row_bad = bad.reshape(n, -1).any(axis=1)
    cols = np.ascontiguousarray(z).view(np.float64).reshape(n, -1)  # a complex column: its (re, im)
    sums, cnt, nbad = window_sums(cols, row_bad, int(k))
    sums = (sums.view(np.complex128) if np.iscomplexobj(z) else sums).reshape(z.shape)
    out = sums / cnt.reshape((n,) + (1,) * (z.ndim - 1))
    out[nbad > 0] = np.nan
    return out


def _velocity_difference(t_lo, t_hi, h: float, tk, vk) -> np.ndarray:
    """(N, 2) the velocity's mean rate of change from ``t_lo`` to ``t_hi`` (``h`` apart), linear between the fixes
    ``(tk, vk)``."""
    return np.stack([np.interp(t_hi, tk, vk[:, k]) - np.interp(t_lo, tk, vk[:, k]) for k in range(2)], 1) / h


def motion_acc_ne(t_s: np.ndarray, vel_ne_m_s: np.ndarray, cfg: GnssAidConfig, bridge: bool = False) -> np.ndarray:
    """(N, 2) horizontal motion acceleration (north, east) from the GNSS velocity on the IMU samples:
    the velocity's difference over ``smooth_s``, read ``latency_s`` later; NaN where either end has no fix
    (``bridge``: only outside the fixes' span — a hole inside it is bridged linearly)."""
    h = cfg.smooth_s
    ok = np.all(np.isfinite(vel_ne_m_s), axis=1)
    out = np.full((len(t_s), 2), np.nan)
    if ok.sum() < 2:
        return out
    tk, vk = t_s[ok], vel_ne_m_s[ok]
    t_hi = t_s + cfg.latency_s + h / 2
    t_lo = t_s + cfg.latency_s - h / 2
    out[:] = _velocity_difference(t_lo, t_hi, h, tk, vk)
    # no fix at either end (outside the covered span, or across a hole in the fixes unless bridged): NaN
    covered = (t_lo >= tk[0]) & (t_hi <= tk[-1])
    if not bridge:
        covered &= np.interp(t_hi, t_s, ok.astype(float)) > 0.999
        covered &= np.interp(t_lo, t_s, ok.astype(float)) > 0.999
    out[~covered] = np.nan
    return out


@dataclass(frozen=True)
class GnssEvidence:
    """What :func:`motion_acc_body` reads from the receiver (and the gyro's clipping) alone on one segment, without
    the attitude: the same for every pass of the aid, so made once per record (:func:`gnss_evidence`) — on a long
    record by the helper process beside the anchored pass (``estimate._beside_work``)."""

    dt: float  # the segment's median sample step
    covered: np.ndarray  # (N,) where the horizontal motion acceleration (:func:`motion_acc_ne`) is finite
    za: np.ndarray  # (N,) that acceleration as complex numbers (north + i east), NaN where no fix
    za_pow: np.ndarray  # (N,) |za|²
    clip_ok: np.ndarray | None  # (N,) where heading evidence may be read (:attr:`GnssAidConfig.clip_guard`); None: all
    near_wild: np.ndarray  # (N,) within margin_s of ground speed ≥ max_speed_m_s
    # whether any sample may be trusted, whatever the attitude (:func:`may_trust_any`); False: the passes skip the aid
    may_trust: bool = True
    # (N,) where a correction may be made: ``covered`` and, with :attr:`GnssAidConfig.bridge_gaps`, the holes inside
    # the fixes' span (``za`` bridged there); None: ``covered``
    corrigible: np.ndarray | None = None


def gnss_evidence(t_s, vel_ne_m_s, cfg: GnssAidConfig, gyr_clipped=None) -> GnssEvidence | None:
    """:class:`GnssEvidence` of one segment (``gyr_clipped``: as :func:`motion_acc_body`'s); None under 3 samples."""
    n = len(t_s)
    if n < 3:
        return None
    dt = float(np.median(np.diff(t_s)))
    k = max(1, int(round(cfg.smooth_s / dt)))
    a_ne = motion_acc_ne(t_s, vel_ne_m_s, cfg)
    covered = np.all(np.isfinite(a_ne), axis=1)
    corrigible = None
    if cfg.bridge_gaps:
        bridged = motion_acc_ne(t_s, vel_ne_m_s, cfg, bridge=True)
        corrigible = np.all(np.isfinite(bridged), axis=1)
        if np.array_equal(corrigible, covered):  # no hole inside the fixes' span: the same bits as without
            corrigible = None
        else:
            a_ne = bridged
    za = a_ne[:, 0] + 1j * a_ne[:, 1]
    clip_ok = None
    if cfg.clip_guard and gyr_clipped is not None and np.any(gyr_clipped):
        m_clip = k + 2 * int(round(cfg.latency_s / dt))  # the averages' span, the fixes' latency on each side
        clip_ok = ~(_centred_mean(np.asarray(gyr_clipped, float), m_clip) > 0)
    speed = np.hypot(vel_ne_m_s[:, 0], vel_ne_m_s[:, 1])
    wild = ~(speed < cfg.max_speed_m_s)  # NaN (no fix): only where covered, below
    m = max(1, int(round(2 * cfg.margin_s / dt)) + 1)
    near_wild = _centred_mean((wild & covered).astype(float), m) > 0
    za_pow = np.abs(za) ** 2
    may = may_trust_any(covered, za_pow, clip_ok, near_wild, dt, cfg)
    return GnssEvidence(dt, covered, za, za_pow, clip_ok, near_wild, may, corrigible)


def may_trust_any(covered, za_pow, clip_ok, near_wild, dt: float, cfg: GnssAidConfig) -> bool:
    """Whether :func:`motion_acc_body` may trust any sample of the segment, read from the receiver alone: False
    where, whatever the attitude, no sample has the acceleration to read a heading from (a hovering or hand-held
    record: every pass would then compute the whole aid to find nothing to correct).

    A necessary condition of its mask: the samples whose evidence a pass reads (``use``) are the covered ones where
    the specific force's average is finite (the attitude's part) and the clipping guard allows — at most
    ``use_max = covered & clip_ok``. With the window sums over ``use_max``, ``frac ≤ frac_max`` and ``pa ≤ pa_max``
    (sums of non-negative terms over fewer samples); a trusted sample is covered, not near a fast stretch, and has
    ``frac > 0.5`` and ``pa / frac ≥ min_accel²``, so ``2 pa_max > min_accel²``. It is tested at twice that
    (``4 pa_max``) so that the running sums' rounding cannot make it miss a sample a pass would trust."""
    use = covered if clip_ok is None else covered & clip_ok
    if not use.any():
        return False
    w = max(1, int(round(cfg.heading_window_s / dt)))
    frac = _centred_mean(use.astype(float), w)
    pa = _centred_mean(np.where(use, za_pow, 0.0), w)
    return bool(np.any(covered & ~near_wild & (frac > 0.5) & (4.0 * pa >= cfg.min_accel_m_s2**2)))


LATENCY_STEP_S = 0.02  # the latency read's samples: ~50 Hz, ten and more to a 5 Hz fix period


def latency_scores(t_s, q_nb_wxyz, acc_b, vel_ne_m_s, cfg: GnssAidConfig, clip_ok=None) -> tuple[np.ndarray, np.ndarray]:
    """The pooled coherence's two sums at each of :func:`latency_candidates` (``cfg.latency_grid_s`` and
    ``cfg.latency_s``) on one segment estimated as ``q_nb_wxyz`` →
    ``(num, den)``: ``Σ_b |Σ f conj(a_L)|`` and ``Σ_b √(Σ|f|² Σ|a_L|²)`` over blocks b of ``heading_window_s``, where
    ``f`` is the specific force's horizontal part in the filter's earth frame averaged over ``smooth_s`` (as
    :func:`motion_acc_body` reads it) and ``a_L`` the receiver's acceleration read ``L`` late (:func:`motion_acc_ne`'s
    difference), on the samples (every ``LATENCY_STEP_S``) inside the fixes' span with no hole (NaN) from the earliest
    candidate's start to the latest's end, and where ``clip_ok`` (:attr:`GnssEvidence.clip_ok`, made for the setting's
    latency; None: all). Blocks, not a sliding window: a 6-D filter's heading drifts between them. A record's latency is the grid's argmax of ``Σ num / Σ den`` over its segments (:func:`read_latency`)."""
    grid = latency_candidates(cfg)
    n = len(t_s)
    zero = np.zeros(len(grid))
    if n < 3 or not cfg.latency_grid_s:
        return zero, zero.copy()
    dt = float(np.median(np.diff(t_s)))
    k = max(1, int(round(cfg.smooth_s / dt)))
    rows = (np.require(x, np.float64, "CW") for x in (q_nb_wxyz, acc_b))
    f_ne = _centred_mean(rotate_rows(*rows)[:, :2], k)
    at = np.arange(0, n, max(1, int(round(LATENCY_STEP_S / dt))))
    t = t_s[at]
    zf = f_ne[at, 0] + 1j * f_ne[at, 1]
    use = np.isfinite(zf) if clip_ok is None else np.isfinite(zf) & clip_ok[at]
    # every candidate's differences read from real fixes only: no hole (NaN) from the earliest candidate's start to the
    # latest's end, inside the fixes' span
    ok = np.all(np.isfinite(vel_ne_m_s), axis=1)
    if ok[at].sum() < 2:
        return zero, zero.copy()
    h = cfg.smooth_s
    ok_at = ok[at]  # linear between fixes: on ~50 Hz samples, the same line but within 20 ms of a fix
    tk, vk = t[ok_at], np.asarray(vel_ne_m_s)[at][ok_at]
    first, last = t + grid[0] - h / 2, t + grid[-1] + h / 2
    holes = np.r_[0, np.cumsum(~ok)]
    use &= (first >= tk[0]) & (last <= tk[-1])
    use &= holes[np.searchsorted(t_s, last, "right")] == holes[np.searchsorted(t_s, first, "left")]
    if not use.any():
        return zero, zero.copy()
    tu, f = t[use], zf[use]
    block = np.floor((tu - t_s[0]) / cfg.heading_window_s).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, np.diff(block) != 0])
    pf = np.add.reduceat(np.abs(f) ** 2, starts)
    num, den = zero.copy(), zero.copy()
    for j, lat in enumerate(grid):  # (:func:`motion_acc_ne`'s difference, here on the read's samples)
        a_ne = _velocity_difference(tu + lat - h / 2, tu + lat + h / 2, h, tk, vk)
        a = a_ne[:, 0] + 1j * a_ne[:, 1]
        num[j] = np.sum(np.abs(np.add.reduceat(f * np.conj(a), starts)))
        den[j] = np.sum(np.sqrt(pf * np.add.reduceat(np.abs(a) ** 2, starts)))
    return num, den


def latency_candidates(cfg: GnssAidConfig) -> np.ndarray:
    """The latencies :func:`latency_scores` scores: ``cfg.latency_grid_s`` and ``cfg.latency_s``, ascending."""
    return np.unique(np.r_[np.asarray(cfg.latency_grid_s, float), cfg.latency_s])


def read_latency(num: np.ndarray, den: np.ndarray, cfg: GnssAidConfig) -> float:
    """The receiver's latency from :func:`latency_scores`' sums over a record's segments: the best pooled coherence
    of :func:`latency_candidates` where it is at least ``cfg.latency_min_gain`` above that at ``cfg.latency_s``, else
    ``cfg.latency_s`` (no evidence, or none clear enough: as set)."""
    grid = latency_candidates(cfg)
    if not cfg.latency_grid_s or not np.all(den > 0):
        return cfg.latency_s
    p = num / den
    best = int(np.argmax(p))
    p_set = p[int(np.searchsorted(grid, cfg.latency_s))]
    return float(grid[best]) if p[best] >= p_set + cfg.latency_min_gain else cfg.latency_s


def motion_acc_body(t_s, q_nb_wxyz, acc_b, vel_ne_m_s, cfg: GnssAidConfig, gyr_clipped=None,
                    evidence: GnssEvidence | None = None):  # fmt: skip
    """The motion acceleration in body axes (N, 3) to take out of the accelerometer, for one segment
    estimated as ``q_nb_wxyz`` (any heading origin), and the per-sample mask where it is applied.
    ``gyr_clipped``: the samples where the gyro read its range (:attr:`GnssAidConfig.clip_guard`;
    None: none did). ``evidence``: the segment's :func:`gnss_evidence` where already made (the same bits)."""
    n = len(t_s)
    if n < 3:
        return np.zeros((n, 3)), np.zeros(n, bool), np.zeros(n, bool)
    ev = evidence if evidence is not None else gnss_evidence(t_s, vel_ne_m_s, cfg, gyr_clipped)
    if not ev.may_trust:  # nothing to correct, whatever the attitude (:func:`may_trust_any`): the same masks, no rotation
        return np.zeros((n, 3)), np.zeros(n, bool), ev.covered
    k = max(1, int(round(cfg.smooth_s / ev.dt)))
    covered, za = ev.covered, ev.za
    rows = (np.require(x, np.float64, "CW") for x in (q_nb_wxyz, acc_b))  # the kernels' one signature
    f_ne = _centred_mean(rotate_rows(*rows)[:, :2], k)  # specific force in the filter's earth frame
    zf = f_ne[:, 0] + 1j * f_ne[:, 1]
    finite = np.isfinite(zf)
    use = covered & finite  # where the heading's evidence is read: real fixes only
    if ev.clip_ok is not None:
        use &= ev.clip_ok
    usable = (covered if ev.corrigible is None else ev.corrigible) & finite  # where a correction can be made
    w = max(1, int(round(cfg.heading_window_s / ev.dt)))
    c = _centred_mean(np.where(use, zf * np.conj(za), 0), w)
    pf = _centred_mean(np.where(use, np.abs(zf) ** 2, 0.0), w)
    pa = _centred_mean(np.where(use, ev.za_pow, 0.0), w)
    frac = _centred_mean(use.astype(float), w)
    with np.errstate(invalid="ignore", divide="ignore"):
        coh = np.abs(c) / np.sqrt(pf * pa)
        rms_a = np.sqrt(pa / np.maximum(frac, 1e-12))
    trusted = usable & (frac > 0.5) & (coh >= cfg.min_coherence) & (rms_a >= cfg.min_accel_m_s2)
    rot = np.exp(1j * np.angle(c))
    za_e = rot * za  # the GNSS acceleration in the filter's earth frame
    trusted &= ~ev.near_wild
    a_n = np.zeros((n, 3))
    za_t = za_e[trusted]
    za_t = za_t * np.minimum(1.0, cfg.max_accel_m_s2 / np.maximum(np.abs(za_t), 1e-12))
    a_n[trusted, 0] = za_t.real
    a_n[trusted, 1] = za_t.imag
    q_conj = q_nb_wxyz * np.array([1.0, -1.0, -1.0, -1.0])
    return rotate_rows(np.require(q_conj, np.float64, "CW"), a_n), trusted, covered  # zero where not trusted


def summarize(trusted: np.ndarray, covered: np.ndarray, a_b: np.ndarray, vel_ne_m_s: np.ndarray | None,
              cfg: GnssAidConfig) -> GnssAid:  # fmt: skip
    """The :class:`GnssAid` of a record from its per-sample masks and its GNSS velocity (None: none)."""
    n = max(len(trusted), 1)
    if vel_ne_m_s is None:
        return GnssAid(False, 0.0, 0.0, 0.0, "no GNSS velocity in the record")
    if not covered.any():
        return GnssAid(False, 0.0, 0.0, 0.0, "no stretch with GNSS fixes long enough for an acceleration")
    if not trusted.any() and np.isfinite(cfg.max_speed_m_s) and not np.any(np.hypot(vel_ne_m_s[:, 0], vel_ne_m_s[:, 1]) < cfg.max_speed_m_s):
        return GnssAid(False, float(covered.mean()), 0.0, 0.0,
                       f"faster than {cfg.max_speed_m_s:g} m/s throughout (fast flight is the flight-speed gate's)")  # fmt: skip
    if not trusted.any():
        return GnssAid(False, float(covered.mean()), 0.0, 0.0,
                       "the GNSS acceleration never agreed with the accelerometer's (or was too small)")  # fmt: skip
    rms = float(np.sqrt(np.mean(np.sum(a_b[trusted] ** 2, axis=1))))
    return GnssAid(True, float(covered.sum() / n), float(trusted.sum() / n), rms, "applied")
