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
  drift so steady over most of a log that the gyro check takes it for the gyro's bias.

On the shared files (the 13 logs that ``ingest`` reads, the 17 BROAD trials, the 76 held-out and every
third training simulated flight) every reference passes but that one log's: its reference turns unlike
its gyro on 31 % of its seconds; the others on at most 3 % (1-s intervals over 10 °/s, the simulated
uncalibrated gyros' turn-on biases of up to 20 °/s taken out), and agree with gravity within 1.1°.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..quat import gravity_body, quat_angle, quat_conj, quat_mul, quat_to_rotvec
from ..record import FlightRecord, segment_slices
from .accel_scale import quiet_samples
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


@dataclass(frozen=True)
class ReferenceCheck:
    """What :func:`check_reference` found (None: too little to judge that part)."""

    turn_share: float | None  # share of the intervals where the reference turns unlike the gyro
    intervals: int
    gravity_deg: float | None  # median angle to the quiet accelerometer's gravity
    quiet_s: float
    config: ReferenceTrustConfig = ReferenceTrustConfig()

    @property
    def trusted(self) -> bool:
        c = self.config
        return (self.turn_share is None or self.turn_share <= c.max_share) and (
            self.gravity_deg is None or self.gravity_deg <= c.max_gravity_deg)  # fmt: skip

    def describe(self) -> str:
        """One line for a user."""
        c = self.config
        gyro = ("gyro: too short to check" if self.turn_share is None else
                f"turns unlike the gyro (by > {c.max_turn_deg_s:g} °/s) on {100 * self.turn_share:.0f} % of "
                f"{self.intervals} {c.interval_s:g}-s intervals")  # fmt: skip
        grav = ("gravity: too little quiet time to check" if self.gravity_deg is None else
                f"{self.gravity_deg:.1f}° from the accelerometer's gravity (median over {self.quiet_s:.0f} s quiet)")  # fmt: skip
        verdict = "trusted" if self.trusted else (
            f"not trusted (over {100 * c.max_share:.0f} % or {c.max_gravity_deg:g}°: an estimator that failed, or another frame)")  # fmt: skip
        return f"reference attitude: {gyro}; {grav}; {verdict}"


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
        q = q_ref[sl][edges]
        turn_ref = quat_mul(quat_conj(q[:-1]), q[1:])  # body-at-start axes, as the gyro's
        clip = np.r_[0, np.cumsum(rec.gyr_clipped[sl])]
        with np.errstate(invalid="ignore"):
            has = np.linalg.norm(q, axis=1) > 0.5  # a reference at the interval's ends (NaN or zeros: none)
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


def gravity_disagreement_deg(rec: FlightRecord) -> tuple[np.ndarray, float]:
    """(the angle (°) between the reference's down direction and the averaged accelerometer's at each quiet
    sample with a finite reference, the quiet seconds those make)."""
    found = quiet_samples(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2)
    if found is None:
        return np.zeros(0), 0.0
    quiet, acc_lp, step = found
    q = rec.q_ref_wxyz
    with np.errstate(invalid="ignore"):
        m = quiet & (np.linalg.norm(q, axis=1) > 0.5)  # a finite reference (a zero quaternion is none)
    down_ref = gravity_body(q[m] / np.linalg.norm(q[m], axis=1, keepdims=True))
    down_acc = -acc_lp[m] / np.linalg.norm(acc_lp[m], axis=1, keepdims=True)  # specific force at rest points up
    cos = np.clip(np.einsum("ij,ij->i", down_ref, down_acc), -1.0, 1.0)
    return np.degrees(np.arccos(cos)), float(m.sum()) * step


def check_reference(rec: FlightRecord, cfg: ReferenceTrustConfig | None = None) -> ReferenceCheck:
    """Both checks of the module docstring on one record."""
    cfg = cfg or ReferenceTrustConfig()
    turn = turn_disagreement_deg_s(rec, cfg.interval_s)
    share = float(np.mean(turn > cfg.max_turn_deg_s)) if len(turn) >= cfg.min_intervals else None
    grav, quiet_s = gravity_disagreement_deg(rec)
    gdeg = float(np.median(grav)) if quiet_s >= cfg.min_quiet_s else None
    return ReferenceCheck(share, len(turn), gdeg, quiet_s, cfg)
