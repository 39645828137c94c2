"""Offline tilt smoothing: where no gate of the anchored estimator acts, VQF run both ways.

The anchored estimator (:mod:`.anchor`) is causal: each estimate uses the samples up to it, so
VQF's low-pass lags behind the motion and its gyro-bias estimate behind the sensor. Offline the
whole record is at hand. Where the network's gates stay shut the anchored estimate *is* VQF's on
the inputs it saw, and the acausal VQF (``vqf.offlineVQF``, Laidig & Seel 2023: the same filter
run forward and backward, its gyro bias estimated from both) on those same inputs — the gyro times
the anchored pass's scale (the record's own rests, :mod:`.gyro_selfcal`, or a fine-tuning's), the
accelerometer with the GNSS-measured motion acceleration taken out (:mod:`.gnss_aid`) — gives the
better tilt. So:

- the record is cut into **ungated stretches**: the samples where the anchored pass's gate (the
  largest of its flight-speed, saturation and uncalibrated-gyro gates, :class:`.anchor.AnchoredVQF`)
  is zero, in runs of at least ``min_stretch_s`` where a gate acts next to them, of at least
  ``min_free_stretch_s`` where none does (a whole short segment; shorter ones keep the causal estimate);
- each stretch is smoothed **on its own** (``offlineVQF`` sees none of the gated samples, whose
  rates or accelerations VQF would take wrongly);
- from a gate's edge the smoothed tilt's weight ramps 0 → 1 over ``ramp_s`` (at a segment's own
  start and end it is 1 at once: there the causal filter is the one still converging);
- the tilt is blended as the direction of gravity in body axes and applied as the minimal turn of
  the causal attitude about a horizontal axis, so the **heading stays the causal estimate's**
  (VQF's, or 9-D's magnetometer heading);
- σ (``sigma_rad``) of a smoothed sample is the causal σ times ``1 − w·(1 − sigma_scale)``, w the
  smoothed tilt's weight, with ``(w·k·R)²`` added to σ² (rule 40: R the rotation around the sample in time,
  :mod:`.rotation_memory`, k ``sigma_rotation_gain``): ``sigma_scale`` and k fitted on the BROAD trials the
  network saw (mean NEES in 1.75–2.25, the most samples within 3σ, per file averaged), and at least
  ``sigma_disagreement_gain`` times the centred RMS, over ``sigma_disagreement_window_s``, of the
  tilt angle between the causal and the smoothed estimate (:func:`disagreement_sigma`).

With every gate shut on a whole segment of ≥ ``min_free_stretch_s``, its tilt is ``offlineVQF``'s
(tested against the package). Offline only: the live bridge cannot see the future.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..config import check_range
from .anchor_kernels import blend_tilt_rows, tilt_angle_rows
from .clip_turn import describe_clip_turns, fit_clip_turns
from ..record import segment_slices


@dataclass(frozen=True)
class SmootherConfig:
    """Offline tilt smoothing (:mod:`.smoother`). Defaults are the shipped model's."""

    min_stretch_s: float = 30.0  # ungated stretches next to a gate shorter than this keep the causal estimate
    # ... and stretches next to no gate (bounded by the segment's ends, clipped samples or re-levellings: a whole
    # short log, the flight before a flip) shorter than this (session 26, rule 15; 30 s for both before: set
    # in session 15 against the short gaps between a fixed wing's gates, where VQF's tilt is what is wrong)
    min_free_stretch_s: float = 5.0
    ramp_s: float = 5.0  # from a gate's edge, the smoothed tilt's weight goes 0 → 1 over this
    # σ of a smoothed sample: the causal σ times this (weight 1), beside the rotation term below; fitted with it on
    # the 17 seen BROAD trials by rule 40 (session 66, `runs/exp66/rule40.md`: mean NEES in 1.75–2.25, the most
    # samples within 3σ; NEES 1.73 → 1.78, 98.2 → 98.9 % within 3σ; leave one trial out 97.5 → 98.7 %). Before it
    # 0.75 (session 18: mean NEES nearest 2 with ≥ 97.5 % within 3σ, `benchmarks/sigma_fit.py --smooth`)
    sigma_scale: float = 0.5
    # k and W: σ of a smoothed sample is at least k times the centred RMS over W s of the tilt angle between
    # the causal and the smoothed estimate (where the forward-only and the forward-backward filter disagree,
    # the motion fooled the forward one, and the smoothed tilt is not exact either); 0: off (before session
    # 26). Fitted by rule 14 on the seen BROAD trials and every 4th training flight (their per-file NEES
    # 1.76 / 5.36 -> 1.73 / 1.96 where smoothed, 98.1 / 87.2 -> 98.2 / 97.0 % within 3σ; docs/design-log.md)
    sigma_disagreement_gain: float = 0.5
    sigma_disagreement_window_s: float = 1.0
    # k and τ of σ's rotation term (rule 40, session 66): a smoothed sample's σ² takes (w·k·R)², R the rotation
    # around it in time (:func:`.rotation_memory.rotation_memory`, decaying over τ both ways), rad of σ per rad
    # turned: the gyro's scale and misalignment error the smoothing cannot read out; 0: off (before session 66)
    sigma_rotation_gain: float = 0.0005
    sigma_rotation_tau_s: float = 3.0
    # k_v of σ's vibration term (rule 41, session 66): a smoothed sample's σ² takes (w·k_v·N·√Δt)², N the
    # accelerometer's sample noise around it (:func:`..record_stats.running_sample_noise`, a centred 1-s window), Δt the
    # segment's period; rad per (m/s²·√s) (VQF's 3-s low-pass run both ways: about 0.03); 0: off. Fitted by rule
    # 41 on the seen BROAD trials with 1, 2, 4 m/s² of vibration added (pooled NEES 3.40, 92.3 % → 2.06, 98.4 % within 3σ)
    sigma_vibration_gain: float = 0.02
    # A clipped gyro's missed turn put back before VQF runs both ways (:mod:`.clip_turn`, rule 25, session 34): per
    # episode of clipping (runs less than merge_s apart), one excess rate per clipped axis (0 .. max_excess × the
    # range) fitted so that the mean specific force over window_s before and after it (at least min_window_s each)
    # points the same way; taken where it leaves at most accept_ratio of gravity's disagreement and removes at least
    # min_gain_deg of it. Set on the flip probe's design flights (seeds 101-103); False: as before session 34
    clip_turn: bool = True
    clip_turn_window_s: float = 10.0
    clip_turn_min_window_s: float = 2.0
    clip_turn_merge_s: float = 0.25
    clip_turn_max_excess: float = 1.0
    clip_turn_accept_ratio: float = 0.5
    clip_turn_min_gain_deg: float = 5.0

    def __post_init__(self):
        check_range("min_stretch_s", self.min_stretch_s, 0, None)
        check_range("min_free_stretch_s", self.min_free_stretch_s, 0, None)
        check_range("ramp_s", self.ramp_s, 0, None)
        check_range("sigma_scale", self.sigma_scale, 0, 1, lo_open=True)
        check_range("sigma_disagreement_gain", self.sigma_disagreement_gain, 0, None)
        check_range("sigma_disagreement_window_s", self.sigma_disagreement_window_s, 0, None)
        check_range("sigma_rotation_gain", self.sigma_rotation_gain, 0, None)
        check_range("sigma_rotation_tau_s", self.sigma_rotation_tau_s, 0, None, lo_open=True)
        check_range("sigma_vibration_gain", self.sigma_vibration_gain, 0, None)
        check_range("clip_turn_window_s", self.clip_turn_window_s, 0, None, lo_open=True)
        check_range("clip_turn_min_window_s", self.clip_turn_min_window_s, 0, self.clip_turn_window_s)
        check_range("clip_turn_merge_s", self.clip_turn_merge_s, 0, None)
        check_range("clip_turn_max_excess", self.clip_turn_max_excess, 0, 10, lo_open=True)
        check_range("clip_turn_accept_ratio", self.clip_turn_accept_ratio, 0, 1)
        check_range("clip_turn_min_gain_deg", self.clip_turn_min_gain_deg, 0, None)


@dataclass(frozen=True)
class Smoothing:
    """What the smoothing did on a record (``describe()``: one line for the user)."""

    n_samples: int
    n_smoothed: int  # samples with a smoothed-tilt weight > 0
    n_stretches: int
    n_gated: int  # samples where a gate acts
    min_stretch_s: float  # the settings it ran with (to say why nothing was smoothed)
    min_free_s: float = 0.0
    clip_turns: tuple = ()  # (ClipTurn, ...): the clippings inside smoothed stretches and what their fit found

    @property
    def applied(self) -> bool:
        return self.n_smoothed > 0

    def describe(self) -> str:
        pct = 100.0 * self.n_smoothed / max(self.n_samples, 1)
        gated = 100.0 * self.n_gated / max(self.n_samples, 1)
        head = "offline tilt smoothing (VQF forward and backward where no gate acts)"
        if not self.applied:
            why = (f"no stretch of {self.min_stretch_s:g} s without a gate" if self.n_gated
                   else f"no segment of {self.min_free_s:g} s")  # fmt: skip
            return f"{head}: none ({why}); not applied"
        turns = describe_clip_turns(list(self.clip_turns))
        return (f"{head}: {pct:.0f} % of the samples in {self.n_stretches} stretch(es)"
                f"{f'; gates act on {gated:.0f} %' if self.n_gated else ''}{f'; {turns}' if turns else ''}; applied")  # fmt: skip


def ungated_stretches(t_s: np.ndarray, gate: np.ndarray, min_s: float) -> list[slice]:
    """Runs of samples with ``gate`` ≤ 0 lasting at least ``min_s`` (first to last sample)."""
    free = np.asarray(gate) <= 0
    edges = np.flatnonzero(np.diff(np.r_[0, free.astype(np.int8), 0]))
    return [slice(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2]) if t_s[b - 1] - t_s[a] >= min_s]


def ramp_weight(t_s: np.ndarray, ramp_in: bool, ramp_out: bool, ramp_s: float) -> np.ndarray:
    """The smoothed tilt's weight over one stretch: 0 → 1 over ``ramp_s`` from its start where a
    gate precedes it (``ramp_in``) and 1 → 0 toward its end where one follows (``ramp_out``)."""
    t = np.asarray(t_s, np.float64)
    d = np.full(len(t), np.inf)  # seconds from the nearest gated edge
    if ramp_in:
        d = np.minimum(d, t - t[0])
    if ramp_out:
        d = np.minimum(d, t[-1] - t)
    return np.clip(d / ramp_s, 0.0, 1.0) if ramp_s > 0 else np.ones(len(t))


def blend_tilt(q_nb: np.ndarray, q_smooth_nb: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The tilt of ``q_smooth_nb`` with weight ``w`` (per row) and of ``q_nb`` with 1 − w, on the
    heading of ``q_nb``: the two down directions in body axes blended and normalised, then ``q_nb`` turned in body
    axes by the minimal rotation onto that down (the tilt changes, the heading does not) — compiled per row
    (``anchor_kernels.blend_tilt_f``; numpy's whole-array form, kept as the tests' reference, cost 0.7 s an hour of
    samples, session 29)."""
    q = np.ascontiguousarray(q_nb, np.float64)
    out = np.empty_like(q)
    blend_tilt_rows(q, np.ascontiguousarray(q_smooth_nb, np.float64), np.ascontiguousarray(w, np.float64), out)
    return out


def smooth(t_s, q_nb, sigma_rad, gate, seg, cfg: SmootherConfig, offline,
           gyr_clipped=None, relevel=None, imu=None, gyr_rad_s=None,
           acc_m_s2=None) -> tuple[np.ndarray, np.ndarray, Smoothing]:  # fmt: skip
    """The causal estimate ``q_nb`` (σ ``sigma_rad``) with its tilt smoothed on every ungated stretch
    of every segment → (q_nb, σ, what was done). ``offline(slice)`` gives the smoothed attitude
    (body→NED) of the samples of one stretch, run on those samples alone.

    ``gyr_clipped`` (per sample, the gyro at its range; None: none was): a saturated gyro's turn is what
    VQF cannot take, and a backward pass that crossed one carries it into the samples before — a tumble
    past an autopilot's ±2000 °/s, where the saturation gate stays shut by design, left 12–19° in the 5 s
    before it (session 25). So within a stretch, the samples up to its last clipped one take the tilt of
    stretches that also end at every clipped sample (no backward pass crossed a clip before them), the
    samples after it the whole stretch's (whose backward pass starts after the clip).

    ``relevel`` (indices: the first sample the causal estimator gave after each re-levelling at rest,
    :attr:`.anchor.AnchorConfig.rest_relevel_s`; None: none): there the causal tilt was set from the
    accelerometer of a still vehicle, and a forward pass that crossed it still holds the tumble before
    (after a crash, 17° decaying over 3 s against the causal 0.02°, σ at its floor: session 26). So the
    cut runs above also end at re-levellings, and the samples from a re-levelling after a stretch's last
    clip to its end take a run starting there (its weight ramping in from the causal tilt), or the
    causal tilt where that run is too short (:func:`smoothed_stretches`). A stretch without a clipped or
    re-levelled sample is smoothed as a whole.

    ``imu`` (``(gyr, acc, bias)``, per sample: the gyro as the filter integrates it, the accelerometer it
    corrects with, the filter's gyro bias; None: not done) with ``cfg.clip_turn``: each clipping inside a
    smoothed stretch has its missed turn fitted from gravity before and after it (:mod:`.clip_turn`), and where
    one is taken ``offline(slice, extra)`` is given the (n, 3) rates to add to the filter's gyro (0 elsewhere).

    ``gyr_rad_s`` ((n, 3), the record's rates; None: no rotation term) with ``cfg.sigma_rotation_gain`` > 0: a
    smoothed sample's σ takes the rotation term (rule 40, :mod:`.rotation_memory`); ``acc_m_s2`` ((n, 3); None: no
    vibration term) with ``cfg.sigma_vibration_gain`` > 0, the vibration term (rule 41)."""
    added = None  # σ's added terms at weight 1: rotation and vibration in quadrature (None: neither)
    if gyr_rad_s is not None and cfg.sigma_rotation_gain > 0:
        from .rotation_memory import rotation_memory

        added = cfg.sigma_rotation_gain * rotation_memory(t_s, gyr_rad_s, seg, cfg.sigma_rotation_tau_s)
    if acc_m_s2 is not None and cfg.sigma_vibration_gain > 0:
        vib = cfg.sigma_vibration_gain * vibration_sigma(t_s, acc_m_s2, seg)
        added = vib if added is None else np.hypot(added, vib)
    turns, exempt = [], None
    if imu is not None and cfg.clip_turn and gyr_clipped is not None and np.any(gyr_clipped):
        t_a, g_a = np.asarray(t_s, np.float64), np.asarray(gate, np.float64)
        runs = [st for s in segment_slices(seg) for st in smoothed_stretches(t_a, g_a, g_a, s, cfg)]
        clipped = np.asarray(gyr_clipped, bool)
        if any(clipped[r].any() for r in runs):
            fitted, turns = fit_clip_turns(t_s, imu[0], imu[1], clipped, imu[2], runs, cfg)
            if any(c.accepted for c in turns):
                extra = fitted - np.asarray(imu[0], np.float64)
                base = offline
                offline = lambda sl: base(sl, extra)  # noqa: E731
                exempt = np.zeros(len(clipped), bool)  # a clipping whose turn was put back takes the whole run
                for c in turns:
                    if c.accepted:
                        exempt[c.start : c.stop] = True
    out, sig, info = _smooth_tilt(t_s, q_nb, sigma_rad, gate, seg, cfg, offline, gyr_clipped, relevel, exempt, added)
    info = replace(info, clip_turns=tuple(turns))
    if cfg.sigma_disagreement_gain > 0 and info.applied:
        floor = cfg.sigma_disagreement_gain * disagreement_sigma(t_s, q_nb, out, seg, cfg.sigma_disagreement_window_s)
        sig = np.where(np.isfinite(floor), np.maximum(sig, floor), sig)
    return out, sig, info


def vibration_sigma(t_s, acc_m_s2, seg) -> np.ndarray:
    """(n,) N·√Δt (rule 41): the accelerometer's sample noise around each sample
    (:func:`..record_stats.running_sample_noise`, a centred 1-s window) times the square root of its segment's
    period (:func:`..record_gaps.segment_period_s`, 0 for a segment of one sample); σ's vibration term is
    ``sigma_vibration_gain`` times this."""
    from ..record_gaps import segment_period_s
    from ..record_stats import running_sample_noise

    t_s = np.asarray(t_s, np.float64)
    step = np.zeros(len(t_s))
    for s in segment_slices(np.asarray(seg)):
        step[s] = segment_period_s(t_s[s], 0.0)
    return running_sample_noise(t_s, acc_m_s2, seg, 1.0) * np.sqrt(step)


def disagreement_sigma(t_s, q_a, q_b, seg, window_s: float) -> np.ndarray:
    """(n,) the centred RMS over ``window_s`` (within each segment; 0: none) of the angle between the tilts of
    ``q_a`` and ``q_b`` (body→NED), rad."""
    q_a, q_b = np.ascontiguousarray(q_a, np.float64), np.ascontiguousarray(q_b, np.float64)
    d2 = np.empty(len(q_a))
    tilt_angle_rows(q_a, q_b, d2)  # (compiled: numpy's gravity, cross and norms cost 0.2 s an hour, session 29)
    d2 **= 2
    if window_s <= 0:
        return np.sqrt(d2)
    from ..record_stats import centred_mean

    return np.sqrt(centred_mean(t_s, d2, seg, window_s))


def _smooth_tilt(t_s, q_nb, sigma_rad, gate, seg, cfg: SmootherConfig, offline, gyr_clipped, relevel, exempt=None,
                 added=None):  # fmt: skip
    """:func:`smooth` without the disagreement's σ floor. ``exempt`` (None: none): samples that keep the whole
    stretch's run though runs before them end there (a clipping whose missed turn ``offline`` puts back); ``added``
    (None: none): σ's added terms per sample at weight 1 — rotation k·R (rule 40) and vibration (rule 41) in quadrature."""
    t_s = np.asarray(t_s, np.float64)
    gate = np.asarray(gate, np.float64)
    n = len(t_s)
    out, sig, done, n_str = _smoothed(t_s, q_nb, sigma_rad, gate, seg, cfg, offline, added=added)
    clipped = np.zeros(n, bool) if gyr_clipped is None else np.asarray(gyr_clipped, bool)
    rl = np.zeros(n, bool)
    if relevel is not None and len(relevel):
        rl[np.asarray(relevel, np.int64)] = True
    if not np.any((clipped | rl) & done):
        return out, sig, _summary(done, n_str, gate, cfg)
    upto = []  # (start, end after the last clip) of each stretch holding a clip
    after = []  # (a re-levelling after a stretch's last clip, the stretch's end)
    for s in segment_slices(seg):
        for st in smoothed_stretches(t_s, gate, gate, s, cfg):
            a, b = st.start, st.stop
            hits = np.flatnonzero(clipped[a:b])
            last = a + int(hits[-1]) + 1 if hits.size else a + 1
            if hits.size:
                upto.append((a, last))
            lev = np.flatnonzero(rl[last:b])
            if lev.size:
                after.append((last + int(lev[0]), b))
    if upto:  # up to the last clip: runs that also end at clipped and re-levelled samples, made only inside such
        # stretches (every other sample counts as gated: their edges are gates or segment ends anyway)
        cut = np.maximum(gate, (clipped | rl).astype(np.float64))
        keep = np.zeros(n, bool)
        for a, last in upto:
            keep[a:last] = True
        if exempt is not None:
            keep &= ~exempt
        out_c, sig_c, done_c, _ = _smoothed(t_s, q_nb, sigma_rad, np.where(keep, cut, 1.0), seg, cfg, offline, gate,
                                            added)  # fmt: skip
        out[keep], sig[keep], done[keep] = out_c[keep], sig_c[keep], done_c[keep]
    if after:  # from a re-levelling on: a run of its own (the causal tilt where it is too short)
        own = np.zeros(n, bool)
        for r, b in after:
            own[r:b] = True
        out_r, sig_r, done_r, _ = _smoothed(t_s, q_nb, sigma_rad, np.where(own, gate, 1.0), seg, cfg, offline, gate,
                                            added)  # fmt: skip
        out[own], sig[own], done[own] = out_r[own], sig_r[own], done_r[own]
    return out, sig, _summary(done, n_str, gate, cfg)


def _summary(done: np.ndarray, n_stretches: int, gate: np.ndarray, cfg: SmootherConfig) -> Smoothing:
    return Smoothing(len(done), int(done.sum()), n_stretches, int(np.sum(gate > 0)), cfg.min_stretch_s,
                     cfg.min_free_stretch_s)  # fmt: skip


def smoothed_stretches(t_s, gate, real_gate, sl: slice, cfg: SmootherConfig) -> list[slice]:
    """The stretches of segment ``sl`` where ``gate`` ≤ 0 that are smoothed (record indices): those next to a
    sample where ``real_gate`` acts lasting ≥ ``min_stretch_s``, the others ≥ ``min_free_stretch_s``
    (``gate`` may also mark clipped or re-levelled samples, which are no gate)."""
    a0, b0 = sl.start, sl.stop
    out = []
    for st in ungated_stretches(t_s[sl], gate[sl], min(cfg.min_stretch_s, cfg.min_free_stretch_s)):
        a, b = a0 + st.start, a0 + st.stop
        near_gate = (a > a0 and real_gate[a - 1] > 0) or (b < b0 and real_gate[b] > 0)
        if t_s[b - 1] - t_s[a] >= (cfg.min_stretch_s if near_gate else cfg.min_free_stretch_s):
            out.append(slice(a, b))
    return out


def _smoothed(t_s, q_nb, sigma_rad, gate, seg, cfg: SmootherConfig, offline, real_gate=None, added=None):
    """``q_nb`` and σ with every stretch where ``gate`` ≤ 0 smoothed on its own → (q_nb, σ, the samples
    smoothed, the number of stretches). ``real_gate``: where a gate acts (default ``gate``), for
    :func:`smoothed_stretches`; ``added``: σ's added terms per sample at weight 1 (None: none)."""
    real_gate = gate if real_gate is None else real_gate
    out = np.array(q_nb, np.float64, copy=True)
    sig = np.array(sigma_rad, np.float64, copy=True)
    done = np.zeros(len(t_s), bool)
    n_stretches = 0
    for s in segment_slices(seg):
        for st in smoothed_stretches(t_s, gate, real_gate, s, cfg):
            a, b = st.start, st.stop
            w = ramp_weight(t_s[a:b], a > s.start, b < s.stop, cfg.ramp_s)
            q_s = offline(slice(a, b))
            ok = (w > 0) & np.all(np.isfinite(q_s), 1) & np.all(np.isfinite(out[a:b]), 1)
            if not ok.any():
                continue
            rows = np.flatnonzero(ok) + a
            out[rows] = blend_tilt(out[rows], q_s[ok], w[ok])
            sig[rows] *= 1.0 - w[ok] * (1.0 - cfg.sigma_scale)
            if added is not None:  # rules 40 and 41: σ² += w²·((k·R)² + (k_v·N·√Δt)²)
                sig[rows] = np.hypot(sig[rows], w[ok] * added[rows])
            done[rows] = True
            n_stretches += 1
    return out, sig, done, n_stretches
