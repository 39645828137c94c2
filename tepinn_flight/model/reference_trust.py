"""Whether a log's reference attitude is the IMU's attitude: does it turn as the gyro turns, and does it
agree with the accelerometer's gravity where the vehicle is quiet? The fine-tuning learns only from logs
that pass; ``info`` and ``evaluate`` say where a reference fails (its errors then measure the reference's
failure — an autopilot estimator that diverged is worth knowing about in its own right).

Fine-tuning (:mod:`.finetune`) takes the autopilot's own estimate as the label, and fits the
estimator's settings and σ to agree with it. A log whose reference is not the IMU's attitude — an
estimator that diverged, a reference in another frame or mounting, a broken Euler convention —
then teaches everything wrong: the shared ArduPilot log ``aplogan_nan.log``, whose attitude pitches
to 100° in five seconds while its gyro turns a few degrees a second and its accelerometer stays
within 20° of level, took a fine-tuning on the shared logs from 0.43° to 0.79° validation error and
its σ's NEES from 1.1 to 39 (session 27). Two checks, each set a priori, each passing where it
cannot judge (what the fine-tuning did before them):

- **the gyro**: over consecutive 1-s intervals (none holding a saturated gyro sample), the
  reference's own turn against the gyro's, integrated; the angle between the two turns per second.
  A reference that turns differently from the gyro by more than ``max_turn_deg_s`` (10 °/s: ten
  times a consumer gyro's bias, more than its scale error gives on anything but the fastest flips)
  on more than ``max_share`` of the intervals (20 %: a flip or a crash is seconds of a log) is not the
  IMU's attitude. At least ``min_intervals`` (5) are needed to judge.
- **gravity**: where the vehicle is neither turning nor shaking (:func:`.accel_scale.quiet_samples`:
  at rest, hovering, flying straight) the averaged accelerometer shows gravity alone; the median angle
  between the reference's down direction and the accelerometer's there must stay within
  ``max_gravity_deg`` (10°: five times what a 0.1-g bias or a coordinated 14° bank gives, far from a
  wrong frame's tens of degrees), over at least ``min_quiet_s`` (2 s) of quiet samples. This one sees
  a reference tilted by a fixed offset where the vehicle turns too little for the gyro check to, and a
  drift so steady over most of a log that the gyro check takes it for the gyro's bias. Since session 57 a
  quiet sample must also turn gently for its speed where a GNSS speed is known (the averaged rate times it
  under ``max_turn_acc_m_s2``, 0.05 g), and a fixed wing without one gives none: a simulated c172x's gentle
  coordinated turns had leaned its "gravity" 11–12° off its true attitude (4 of 12 flights refused).

Two more read the reference's body rate against the gyro's on a grid of ``step_s`` (20 ms, or the IMU's
period where slower), each passing where it cannot judge (too little motion, or no rate agreement to speak of):

- **timing**: the shift of the reference against the gyro (within ±``max_shift_s``, 1 s) at which their
  rates correlate best (judged where the IMU's period is at most half of ``max_lag_s``: not on the 2-Hz IMU
  stream of a telemetry log); a reference more than ``max_lag_s`` (0.1 s) early or late is not the IMU's attitude
  at the IMU's time (a logger's clock, a stamp taken on receipt, a delayed stream): learned from, it
  teaches the network to lag. An autopilot's attitude messages are interpolated onto the IMU's times, and
  its estimator predicts to the IMU's time, so a healthy log shows a few milliseconds;
- **frame**: the rotation that best carries the reference's body rates onto the gyro's (the least-squares
  rotation of the two rate sets, at the best shift); more than ``max_frame_deg`` (20°) is a reference of
  another body frame — a board mounted turned about the vertical, which the gravity check cannot see on a
  level vehicle, nor the turn check on a gentle one. Judged only where the rates agree once turned
  (correlation ≥ ``min_corr``, 0.5) and at least two axes turn (the second singular value of their
  cross-covariance ≥ a tenth of the first: turns about one axis leave a rotation about it unknown).

A reference stored only on its own rows of a faster IMU's (NaN between: a 100-Hz motion capture in a 400-Hz record)
is read between them where its rows are at most :data:`REF_GAP_SPACINGS` of their spacing apart
(:func:`reference_at`); before session 58 every interval edge and grid cell landing on a row without one went
unjudged, and such a reference 0.4 s late and turned 90° was trusted. A quiet sample whose averaged accelerometer
reads under half a g (zeros written for a dropout) gives gravity no direction and is left out.

On the shared files (the 13 logs that ``ingest`` reads, the 17 BROAD trials, the 76 held-out and every
third training simulated flight) every reference passes but that one log's: its reference turns unlike
its gyro on 31 % of its seconds; the others on at most 3 % (1-s intervals over 10 °/s, the simulated
uncalibrated gyros' turn-on biases of up to 20 °/s taken out), and agree with gravity within 1.1°.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..quat import (gravity_body, quat_angle, quat_conj, quat_from_rotvec, quat_mul, quat_to_rotvec, rotmat_to_quat,
                    slerp)
from ..record import QREF_COLS, FlightRecord, segment_slices
from ..vehicle_class import FIXED_WING, vehicle_class
from .accel_scale import AccelScaleConfig, quiet_samples
from .gyro_selfcal import attitude_at


@dataclass(frozen=True)
class ReferenceTrustConfig:
    """Settings of :func:`check_reference`; the defaults are the shipped fine-tuning's (set a priori)."""

    interval_s: float = 1.0
    max_turn_deg_s: float = 10.0
    max_share: float = 0.2
    min_intervals: int = 5
    max_gravity_deg: float = 10.0
    min_quiet_s: float = 2.0
    max_turn_acc_m_s2: float = 0.49  # 0.05 g: the lean of a 2.9° bank (inf: quiet alone, as before session 57)
    step_s: float = 0.02
    max_shift_s: float = 1.0
    max_lag_s: float = 0.1
    max_frame_deg: float = 20.0
    min_corr: float = 0.5
    min_rate_s: float = 10.0  # seconds of grid cells with both rates, at least


@dataclass(frozen=True)
class ReferenceCheck:
    """What :func:`check_reference` found (None: too little to judge that part)."""

    turn_share: float | None  # share of the intervals where the reference turns unlike the gyro
    intervals: int
    gravity_deg: float | None  # median angle to the quiet accelerometer's gravity
    quiet_s: float
    config: ReferenceTrustConfig = ReferenceTrustConfig()
    lag_s: float | None = None  # the reference's delay behind the gyro (negative: ahead)
    frame_deg: float | None = None  # the rotation between the reference's body frame and the gyro's
    frame_rotation: np.ndarray | None = field(default=None, compare=False, repr=False)  # R: gyro ≈ R · reference
    rate_note: str | None = field(default=None, compare=False)  # why timing or frame was not judged (None: both were)
    lag_bracketed: bool = True  # False: the best shift lay at the search's edge: the lag is at least lag_s

    def refusals(self) -> list[str]:
        """Why the reference is not trusted (empty: trusted); a part not judged (None, or NaN) refuses nothing."""
        c = self.config

        def over(x, limit) -> bool:
            return x is not None and bool(np.isfinite(x)) and x > limit

        why = []
        if over(self.turn_share, c.max_share):
            why.append(f"over {100 * c.max_share:.0f} % of intervals: an estimator that failed, or another frame")
        if over(self.gravity_deg, c.max_gravity_deg):
            why.append(f"over {c.max_gravity_deg:g}° from gravity: another frame, or an estimator that failed")
        if over(None if self.lag_s is None else abs(self.lag_s), c.max_lag_s):
            why.append(f"over {c.max_lag_s:g} s off the IMU's time: a clock or stamp fault")
        if over(self.frame_deg, c.max_frame_deg):
            why.append(f"over {c.max_frame_deg:g}° between the frames: another mounting")
        return why

    @property
    def trusted(self) -> bool:
        return not self.refusals()

    def describe(self) -> str:
        """One line for a user."""
        c = self.config
        gyro = ("gyro: too short to check" if self.turn_share is None else
                f"turns unlike the gyro (by > {c.max_turn_deg_s:g} °/s) on {100 * self.turn_share:.0f} % of "
                f"{self.intervals} {c.interval_s:g}-s intervals")  # fmt: skip
        grav = ("gravity: too little quiet time to check" if self.gravity_deg is None else
                f"{self.gravity_deg:.1f}° from the accelerometer's gravity (median over {self.quiet_s:.0f} s quiet)")  # fmt: skip
        if self.lag_s is None:
            timing = f"timing: not judged ({self.rate_note or 'too little motion'})"
        else:
            timing = (f"{'at least ' if not self.lag_bracketed else ''}{abs(self.lag_s):.3f} s "
                      f"{'behind' if self.lag_s >= 0 else 'ahead of'} the gyro"
                      + (f" (the edge of the ±{c.max_shift_s:g}-s search)" if not self.lag_bracketed else ""))  # fmt: skip
        if self.frame_deg is not None:
            frame = f", its body frame {self.frame_deg:.1f}° from the gyro's"
        else:
            frame = f", frame: not judged ({self.rate_note})" if self.lag_s is not None and self.rate_note else ""
        why = self.refusals()
        verdict = ("trusted" if self.judged else "not judged: nothing to check it by (kept, as trusted)") if not why \
            else f"not trusted ({'; '.join(why)})"  # (review60: "trusted" where no part had been checked)
        return f"reference attitude: {gyro}; {grav}; {timing}{frame}; {verdict}"

    @property
    def judged(self) -> bool:
        """Whether any part was checked (a log of a second or two, or one that never turns nor rests, has none)."""
        return any(x is not None and bool(np.isfinite(x)) for x in (self.turn_share, self.gravity_deg, self.lag_s,
                                                                    self.frame_deg))


#: a reference row's neighbours may be this many times the reference rows' median spacing apart and still be bridged
#: (the readers' rule for a stream put on the IMU's times, ``ingest.assemble``: a longer gap is a hole)
REF_GAP_SPACINGS = 2.5


def reference_at(t: np.ndarray, q_ref: np.ndarray, t_query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The reference (rows ``q_ref`` at times ``t``: one segment; NaN or zero rows: none) at ``t_query``, slerped
    between the rows that have one, and where it is known: between two such rows at most :data:`REF_GAP_SPACINGS` of
    their median spacing apart (or exactly at one). A reference stored only on its own rows of a faster IMU's (a
    motion capture at 100 Hz in a 400-Hz record) is read between them; a hole in it stays one. ((M, 4) unit
    quaternions, identity where unknown; (M,) known)."""
    with np.errstate(invalid="ignore"):
        n = np.linalg.norm(q_ref, axis=1)
        has = n > 0.5  # (NaN or zeros: none)
    m = len(t_query)
    if has.sum() < 2:
        out = np.tile([1.0, 0.0, 0.0, 0.0], (m, 1))
        if has.sum() == 1:  # exactly at its one row
            k = int(np.flatnonzero(has)[0])
            at = t_query == t[k]
            out[at] = q_ref[k] / n[k]
            return out, at
        return out, np.zeros(m, bool)
    tk, qk = t[has], q_ref[has] / n[has, None]
    max_gap = REF_GAP_SPACINGS * float(np.median(np.diff(tk)))
    j = np.clip(np.searchsorted(tk, t_query, side="right") - 1, 0, len(tk) - 2)
    known = (((t_query >= tk[j]) & (t_query <= tk[j + 1]) & (tk[j + 1] - tk[j] <= max_gap))
             | (t_query == tk[j]) | (t_query == tk[j + 1]))  # fmt: skip
    return slerp(t_query, tk, qk), known


def turn_disagreement_deg_s(rec: FlightRecord, interval_s: float = 1.0) -> np.ndarray:
    """Per consecutive ``interval_s`` of each segment (those with a finite reference at both ends and no
    saturated gyro sample): the angle (°) between the reference's turn and the gyro's over it, per second
    — the gyro less its constant bias, read per segment as the median over the intervals of the two
    turns' difference (an uncalibrated gyro's bias of tens of degrees a second is the gyro's fault, not
    the reference's)."""
    out = []
    q_ref = rec.q_ref_wxyz
    for sl in segment_slices(rec.segment):
        t = rec.t_s[sl]
        if len(t) < 3:
            continue
        edges = np.unique(np.searchsorted(t, np.arange(t[0], t[-1], interval_s)))
        if len(edges) < 2:
            continue
        gyr = np.ascontiguousarray(np.nan_to_num(rec.gyr_rad_s[sl]), np.float64)  # a hole: no turn
        dt = np.r_[np.diff(t), 0.0]
        span = np.diff(t[edges])
        q, has = reference_at(t, q_ref[sl], t[edges])  # a reference at the interval's ends
        turn_ref = quat_mul(quat_conj(q[:-1]), q[1:])  # body-at-start axes, as the gyro's
        clip = np.r_[0, np.cumsum(rec.gyr_clipped[sl])]
        ok = has[:-1] & has[1:] & (clip[edges[1:]] - clip[edges[:-1]] == 0)
        def gyro_turns(bias):
            q_g = np.zeros((len(edges), 4))
            attitude_at(gyr, dt, 1.0, 1.0, 1.0, *bias, edges.astype(np.int64), q_g, np.zeros((len(edges), 3, 3)))
            return quat_mul(quat_conj(q_g[:-1]), q_g[1:])

        turn_gyr = gyro_turns((0.0, 0.0, 0.0))
        if ok.any():  # less the constant bias the turns show
            bias = np.median((quat_to_rotvec(turn_gyr[ok]) - quat_to_rotvec(turn_ref[ok])) / span[ok, None], axis=0)
            turn_gyr = gyro_turns(tuple(float(v) for v in bias))
        ang = np.degrees(quat_angle(quat_mul(quat_conj(turn_gyr), turn_ref))) / span
        out.append(ang[ok])
    return np.concatenate(out) if out else np.zeros(0)


def gravity_disagreement_deg(rec: FlightRecord, cfg: ReferenceTrustConfig | None = None) -> tuple[np.ndarray, float]:
    """(the angle (°) between the reference's down direction and the averaged accelerometer's at each quiet
    sample with a finite reference, the quiet seconds those make). Quiet is not enough in flight: a gentle
    coordinated turn (0.05–0.1 rad/s, under the quiet test's rate) at an aircraft's 50 m/s pulls 2.5–5 m/s²
    sideways, and the accelerometer's "gravity" leans by the bank. So where the GNSS speed is known a quiet sample
    also needs its turn's centripetal acceleration, the averaged rate times that speed, under
    ``max_turn_acc_m_s2``; on a fixed wing without a GNSS speed none is taken (its speed is unknown)."""
    cfg = cfg or ReferenceTrustConfig()
    found = quiet_samples(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2)
    if found is None:
        return np.zeros(0), 0.0
    quiet, acc_lp, step = found
    quiet = quiet & _slow_turns(rec, step, cfg.max_turn_acc_m_s2)
    q = rec.q_ref_wxyz
    with np.errstate(invalid="ignore"):
        m = quiet & (np.linalg.norm(q, axis=1) > 0.5)  # a finite reference (a zero quaternion is none)
        m &= _reads_gravity(acc_lp)
    down_ref = gravity_body(q[m] / np.linalg.norm(q[m], axis=1, keepdims=True))
    down_acc = -acc_lp[m] / np.linalg.norm(acc_lp[m], axis=1, keepdims=True)  # specific force at rest points up
    cos = np.clip(np.einsum("ij,ij->i", down_ref, down_acc), -1.0, 1.0)
    return np.degrees(np.arccos(cos)), float(m.sum()) * step


#: a quiet sample's averaged specific force must be at least this (m/s², half of 1 g) to be read as gravity: an
#: accelerometer reading zeros (a dropout written as 0) has no direction
MIN_GRAVITY_M_S2 = 4.9


def _reads_gravity(acc_lp: np.ndarray) -> np.ndarray:
    """(N,) the rows of the averaged accelerometer with a direction to read gravity from (finite, ≥
    :data:`MIN_GRAVITY_M_S2`)."""
    with np.errstate(invalid="ignore"):
        return np.linalg.norm(acc_lp, axis=1) >= MIN_GRAVITY_M_S2


def _averaged_rate(rec: FlightRecord, step: float) -> np.ndarray:
    """(N,) the norm of the gyro's rate averaged over the quiet test's window (centred; a hole counts as 0)."""
    k = max(1, int(round(AccelScaleConfig().avg_s / step)))
    gyr = np.nan_to_num(rec.gyr_rad_s)
    box = np.ones(k) / k
    return np.linalg.norm(np.stack([np.convolve(gyr[:, i], box, mode="same") for i in range(3)], axis=1), axis=1)


def _slow_turns(rec: FlightRecord, step: float, max_turn_acc_m_s2: float) -> np.ndarray:
    """The samples whose turn pulls less than ``max_turn_acc_m_s2`` sideways: the rate averaged over the quiet test's
    window times the GNSS horizontal speed; where no speed is known, every sample but a fixed wing's."""
    n = len(rec.t_s)
    if not np.isfinite(max_turn_acc_m_s2):
        return np.ones(n, bool)
    vel = rec.gnss_vel_ne_m_s
    speed = np.full(n, np.nan) if vel is None else np.hypot(vel[:, 0], vel[:, 1])
    rate = _averaged_rate(rec, step)
    unknown_ok = vehicle_class(rec.meta.get("vehicle_type")) != FIXED_WING
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(speed), rate * speed <= max_turn_acc_m_s2, unknown_ok)


def rates_on_grid(rec: FlightRecord, step_s: float) -> tuple[list[tuple[np.ndarray, np.ndarray]], float]:
    """Per segment, the gyro's mean rate and the reference's body rate (its turn over the cell, as a rotation
    vector, per second) over consecutive cells of a uniform time grid of ``step_s``, or the IMU's period where
    longer: ((gyro, reference) (n, 3) rad/s each, NaN where a cell lacks a reference at an end, a finite gyro or
    holds a saturated sample), the grid's step (s). The gyro's integral is read between samples as the trapezoid
    rule gives it, the reference slerped: so a shift of k cells is k steps of time, whatever the
    stamps' jitter."""
    t_all = rec.t_s
    dts = np.diff(t_all)
    dts = dts[dts > 0]
    step = max(step_s, float(np.median(dts)) if len(dts) else step_s)
    out = []
    q_ref = rec.q_ref_wxyz
    for sl in segment_slices(rec.segment):
        t = t_all[sl]
        if len(t) < 3 or t[-1] - t[0] < 3 * step:
            continue
        grid = t[0] + step * np.arange(int((t[-1] - t[0]) / step) + 1)
        gyr = rec.gyr_rad_s[sl]
        dt = np.r_[np.diff(t), 0.0]
        g0 = np.nan_to_num(gyr)
        # ∫ up to t[k], trapezoidal: a sample is the rate at its instant (a forward hold had read every reference
        # half a period early: −1.2 ms on a 400-Hz simulation, whose moved copy then missed by ~1° in flips)
        cum = np.r_[np.zeros((1, 3)), np.cumsum(0.5 * (g0[:-1] + g0[1:]) * dt[:-1, None], axis=0)]
        turn_gyr = np.stack([np.interp(grid, t, cum[:, k]) for k in range(3)], axis=1)
        w_gyr = np.diff(turn_gyr, axis=0) / step
        q_g, ref_ok = reference_at(t, q_ref[sl], grid)
        w_ref = quat_to_rotvec(quat_mul(quat_conj(q_g[:-1]), q_g[1:])) / step
        i = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 2)  # the samples around each grid time
        bad = np.r_[0, np.cumsum(~np.isfinite(gyr).all(axis=1) | rec.gyr_clipped[sl])]  # bad samples before k
        # a cell's integral reads the samples from the one at or before its start to the one after its end
        ok = ref_ok[:-1] & ref_ok[1:] & (bad[i[1:] + 2] - bad[i[:-1]] == 0)
        w_gyr[~ok] = np.nan
        w_ref[~ok] = np.nan
        out.append((w_gyr, w_ref))
    return out, step


def _centred(x: np.ndarray) -> np.ndarray:
    """Less its mean over the finite rows (a gyro's constant bias, a reference's steady turn)."""
    ok = np.isfinite(x).all(axis=1)
    return x - (x[ok].mean(axis=0) if ok.any() else 0.0)


class RateAlignment(NamedTuple):
    """What :func:`rate_alignment` read (None: not judged)."""

    lag_s: float | None  # the reference's delay behind the gyro (s)
    frame_deg: float | None  # the angle between the two body frames (°)
    rotation: np.ndarray | None  # R (3×3) carrying the reference's body axes onto the gyro's: g ≈ R r
    corr: float  # the best correlation of the two rates (NaN: none computed)
    note: str | None = None  # why timing or frame was not judged
    bracketed: bool = True  # False: the best shift lay at the search's edge (the lag is at least that)


#: a sample period this close to the timing check's limit (half of ``max_lag_s``) is at it: a 20-Hz IMU's stamps
#: from 250 s give a median period of 0.05000000000001 s
_PERIOD_TOL = 1e-6


def rate_alignment(rec: FlightRecord, cfg: ReferenceTrustConfig | None = None) -> RateAlignment:
    """The timing and frame checks of the module docstring (:class:`RateAlignment`). Positive delay: the reference
    shows at ``t + lag`` the turn the gyro shows at ``t``."""
    cfg = cfg or ReferenceTrustConfig()
    segs, step = rates_on_grid(rec, cfg.step_s)
    nan = float("nan")
    if step > cfg.max_lag_s / 2.0 * (1.0 + _PERIOD_TOL):  # a telemetry-rate IMU: too coarse to time
        return RateAlignment(None, None, None, nan, f"an IMU at {1.0 / step:.3g} Hz, under {2.0 / cfg.max_lag_s:g} Hz")
    segs = [(_centred(g), _centred(r)) for g, r in segs]
    n_cells = sum(int((np.isfinite(g).all(axis=1) & np.isfinite(r).all(axis=1)).sum()) for g, r in segs)
    few = f"under {cfg.min_rate_s:g} s where both the gyro and the reference have rates"
    if n_cells * step < cfg.min_rate_s:
        return RateAlignment(None, None, None, nan, few)
    max_k = int(round(cfg.max_shift_s / step))

    def turned(k: int) -> tuple[float, float, np.ndarray, np.ndarray]:
        """Gyro at i against the reference at i + k over every segment's finite pairs: (their correlation once the
        reference's rates are turned by the least-squares rotation onto the gyro's, that rotation's angle (°), the
        singular values of the cross-covariance Σ r gᵀ, the rotation)."""
        h, aa, bb, n = np.zeros((3, 3)), 0.0, 0.0, 0
        for g, r in segs:
            if abs(k) >= len(g):
                continue
            a, b = (g[: len(g) - k], r[k:]) if k >= 0 else (g[-k:], r[: len(r) + k])
            m = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
            a, b = a[m], b[m]
            h += b.T @ a
            aa += float(np.sum(a * a))
            bb += float(np.sum(b * b))
            n += len(a)
        if n * step < cfg.min_rate_s or aa <= 0.0 or bb <= 0.0:
            return float("nan"), float("nan"), np.zeros(3), np.eye(3)
        u, sv, vt = np.linalg.svd(h)  # H = U S Vᵀ: R = V diag(1, 1, d) Uᵀ carries r onto g, Σ g·(R r) = tr(R H)
        d = 1.0 if np.linalg.det(vt.T @ u.T) >= 0.0 else -1.0
        rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
        ang = float(np.degrees(np.arccos(np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0))))
        return float((sv[0] + sv[1] + d * sv[2]) / np.sqrt(aa * bb)), ang, sv, rot

    # the shift is judged on the rates turned into the gyro's frame: a reference of another mounting still has
    # a timing, and its untouched rates may not correlate at all (turned 90°)
    found = [(turned(k)[0], k) for k in range(-max_k, max_k + 1)]
    found = [(c, k) for c, k in found if np.isfinite(c)]
    if not found:  # (the cells are there: one of the two rates is constant throughout)
        return RateAlignment(None, None, None, nan, "too little motion")
    best_c, best_k = max(found, key=lambda ck: (ck[0], -abs(ck[1])))
    if best_c < cfg.min_corr:
        return RateAlignment(None, None, None, best_c, f"the rates correlate at best {best_c:.2f}, under "
                             f"{cfg.min_corr:g}: too little motion, or a reference that does not turn as the gyro")
    _, ang, sv, rot = turned(best_k)
    shift = float(best_k)
    by_k = dict((k, c) for c, k in found)
    if best_k - 1 in by_k and best_k + 1 in by_k:  # the peak between cells: a parabola through its three
        lo, hi = by_k[best_k - 1], by_k[best_k + 1]
        curv = lo - 2.0 * best_c + hi
        if curv < 0.0:
            shift += float(np.clip(0.5 * (lo - hi) / curv, -0.5, 0.5))
    judged = sv[1] >= 0.1 * sv[0]
    note = None if judged else "turns about one axis only"
    return RateAlignment(shift * step, ang if judged else None, rot if judged else None, best_c, note,
                         abs(best_k) < max_k)


def check_reference(rec: FlightRecord, cfg: ReferenceTrustConfig | None = None) -> ReferenceCheck:
    """The checks of the module docstring on one record."""
    cfg = cfg or ReferenceTrustConfig()
    turn = turn_disagreement_deg_s(rec, cfg.interval_s)
    share = float(np.mean(turn > cfg.max_turn_deg_s)) if len(turn) >= cfg.min_intervals else None
    grav, quiet_s = gravity_disagreement_deg(rec, cfg)
    gdeg = float(np.median(grav)) if quiet_s >= cfg.min_quiet_s else None
    gdeg = gdeg if gdeg is None or np.isfinite(gdeg) else None
    ra = rate_alignment(rec, cfg)
    return ReferenceCheck(share, len(turn), gdeg, quiet_s, cfg, ra.lag_s, ra.frame_deg, ra.rotation, ra.note, ra.bracketed)


def align_reference(rec: FlightRecord, chk: ReferenceCheck,
                    min_shift_s: float | None = None) -> tuple[FlightRecord, float, float]:
    """``rec`` with its reference moved onto the IMU's time and frame where ``chk`` refused it for either — by the
    measured lag (the reference slerped at ``t + lag``, NaN past its ends and where a row had none) and turned by the
    measured frame rotation (q_ref ⊗ R⁻¹: the reference's body axes onto the gyro's) — and (the shift applied (s), the
    turn applied (°)); each 0 where that check passed or could not judge (a measured 2-ms lag or 1° is the
    measurement's own noise: left alone; ``min_shift_s``, where given, moves any lag past it) — and never by a lag
    at the search's edge (the true one is larger, and not known). What a researcher does with motion capture on
    another clock or another body frame (``--align-reference``); the caller checks the result again."""
    c = chk.config
    floor = c.max_lag_s if min_shift_s is None else min_shift_s
    shift = chk.lag_s if chk.lag_s is not None and chk.lag_bracketed and abs(chk.lag_s) > floor else 0.0
    turn = chk.frame_deg if chk.frame_deg is not None and chk.frame_deg > c.max_frame_deg else 0.0
    if not shift and not turn:
        return rec, 0.0, 0.0
    q = rec.q_ref_wxyz
    if shift:  # read at t + lag as the checks read it (between its own rows, its holes kept: NaN there)
        out = np.full_like(q, np.nan)
        t = rec.t_s
        for sl in segment_slices(rec.segment):
            moved, known = reference_at(t[sl], q[sl], t[sl] + shift)
            out[sl] = np.where(known[:, None], moved, np.nan)
        q = out
    tilt = 0.0
    if turn:
        q = quat_mul(q, quat_conj(rotmat_to_quat(chk.frame_rotation)))
        phi = gravity_tilt(rec, q, c)  # the fit from rates leans by the IMU's own axis errors: gravity says how much
        if phi is not None:
            q = quat_mul(q, quat_from_rotvec(phi))
            tilt = float(np.degrees(np.linalg.norm(phi)))
    data = rec.data.copy()
    data[QREF_COLS] = q
    meta = dict(rec.meta, reference_aligned={"shift_s": float(shift), "turned_deg": float(turn), "tilt_from_gravity_deg": tilt})
    return FlightRecord(data, meta), float(shift), float(turn)


#: a sample at rest for :func:`gravity_tilt`: its rate averaged over the quiet test's window under this (rad/s, 0.6 °/s).
#: Quiet is not enough there: a multirotor hovering in wind reads its thrust, not gravity (erle's hover leaned a
#: refinement 3° off its reference); at rest, on the ground or in the hand, the accelerometer reads gravity alone.
STILL_RATE_RAD_S = 0.01


def _still(rec: FlightRecord, step: float) -> np.ndarray:
    """The samples whose rate, averaged over the quiet test's window, is under :data:`STILL_RATE_RAD_S`."""
    return _averaged_rate(rec, step) < STILL_RATE_RAD_S


#: the largest tilt correction :func:`gravity_tilt` applies (°): past it the quiet samples disagree with the fitted
#: frame by more than an axis error could, and the fit is left as it is
MAX_GRAVITY_TILT_DEG = 5.0


def gravity_tilt(rec: FlightRecord, q_nb: np.ndarray, cfg: ReferenceTrustConfig) -> np.ndarray | None:
    """The small turn φ (rotation vector, body axes) that brings the reference ``q_nb``'s down direction onto the
    averaged accelerometer's at the record's quiet samples at rest (:func:`_still`): q_nb ⊗ exp(φ) is then level as
    the accelerometer says. Least squares of [d]× φ = d_acc − d (d_acc ≈ Eᵀ d for the small turn E); where the rests
    share one orientation the turn about down is left at 0 (minimum norm). None where the rests last under
    ``min_quiet_s`` or the turn would pass :data:`MAX_GRAVITY_TILT_DEG`."""
    found = quiet_samples(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2)
    if found is None:
        return None
    quiet, acc_lp, step = found
    quiet = quiet & _still(rec, step) & np.isfinite(q_nb).all(axis=1) & _reads_gravity(acc_lp)
    if quiet.sum() * step < cfg.min_quiet_s:
        return None
    d = gravity_body(q_nb[quiet] / np.linalg.norm(q_nb[quiet], axis=1, keepdims=True))
    d_acc = -acc_lp[quiet] / np.linalg.norm(acc_lp[quiet], axis=1, keepdims=True)
    cross = np.zeros((len(d), 3, 3))  # [d]×
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -d[:, 2], d[:, 1], -d[:, 0]
    cross[:, 1, 0], cross[:, 2, 0], cross[:, 2, 1] = d[:, 2], -d[:, 1], d[:, 0]
    phi = np.linalg.lstsq(cross.reshape(-1, 3), (d_acc - d).ravel(), rcond=1e-2)[0]
    if np.degrees(np.linalg.norm(phi)) > MAX_GRAVITY_TILT_DEG:
        return None
    return phi


#: ``--align-reference`` moves a refused reference by a measured lag past this (s: two 20-ms cells; the shared
#: files' own lags read 0–15 ms)
ALIGN_MIN_SHIFT_S = 0.04


def aligned_if_refused(rec: FlightRecord, cfg: ReferenceTrustConfig | None = None) -> tuple[FlightRecord, str | None]:
    """``--align-reference``: a record whose reference the check refuses on its timing or frame, moved onto the IMU's
    (:func:`align_reference`) where that makes it pass every check — (the record to use, a line saying what was done,
    or None where nothing was: trusted as it is, refused for another reason, or still refused once aligned; the
    record is then returned as recorded)."""
    chk = check_reference(rec, cfg)
    if chk.trusted:
        return rec, None
    # refused anyway: a lag under the timing check's limit is moved by too where it is past the measurement's noise
    # (a 60-ms lag refused by the turn check on a fast flight)
    moved, shift, turn = align_reference(rec, chk, min_shift_s=ALIGN_MIN_SHIFT_S)
    if not (shift or turn):
        return rec, None
    what = ", ".join(p for p in (f"moved {abs(shift):.3f} s {'earlier' if shift > 0 else 'later'}" if shift else "",
                                 f"turned {turn:.1f}° into the gyro's axes" if turn else "") if p)  # fmt: skip
    after = check_reference(moved, cfg)
    if not after.trusted:
        return rec, f"reference {what} but still not trusted ({after.describe()}): left as recorded"
    tilt = moved.meta["reference_aligned"]["tilt_from_gravity_deg"]
    if not turn:
        fit = ""
    elif tilt:
        fit = (f"; the turn is fitted from the rates, its lean from the accelerometer at rest ({tilt:.2f}°): good to "
               "about half a degree on BROAD, 1.2–1.4° on an ArduCopter flight")
    else:
        fit = ("; the turn is fitted from the rates alone (no rest to read its lean from): its lean is as good as the "
               "IMU's axes, 0.4–0.7° on BROAD")
    return moved, f"reference {what} (it was {chk.describe()}){fit}"
