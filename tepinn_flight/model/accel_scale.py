"""The accelerometer's scale read from a record alone — no reference, no learned part (offline).

A gravity-referenced filter reads only the accelerometer's *direction*, so a board that reads
|a| ≈ 7.8 m/s² at rest (0.8 g: a wrong range setting or calibration) does not bother VQF. Everything
that reads its *magnitude* in m/s² does: the GNSS aid (:mod:`.gnss_aid`) takes the receiver's motion
acceleration, in m/s², out of the accelerometer — on a board at 0.8 g it removes 1/0.8 of what the
board shows of it — and the network, trained on accelerometers within a few per cent of true,
estimates the body velocity and the centripetal term from the specific force's size (a simulated
c172x flight with the accelerometer × 0.8: 2.84° → 24.4°, docs/design-log.md).

Where the vehicle is neither turning nor shaking — at rest, hovering, flying straight and level — the
accelerometer's low-passed norm is g times its scale. So over ``avg_s`` the rate's norm is averaged
and the accelerometer is averaged (vibration out of the norm: a noisy vector's norm is biased up), and
the scale is the median of that norm over the *quiet* samples (rate below ``quiet_rate_rad_s``: a
coordinated 15° banked turn at 50 m/s turns at 0.05 rad/s and reads 1.035 g), over at least
``min_quiet_s`` of them. A noisy gyro's mean |ω| keeps its noise (white noise of 2 °/s per sample
averages to |ω| ≈ 0.056 rad/s: no sample would be quiet), so the threshold is raised to
``noise_floor_factor`` × the window's noise floor where that is higher, at most ``quiet_rate_cap_rad_s``
(rule 21): the floor is the mean of |ω_i − ω_(i−1)|/√2 over the same window — for white noise a
consecutive difference over √2 has the noise's own distribution, and a steady turn adds nothing to it,
so a clean gyro turning at 0.08 rad/s is still not quiet (the threshold
``max(quiet_rate_rad_s, min(quiet_rate_cap_rad_s, noise_floor_factor × floor))``, computed by the compiled loops
of :mod:`.accel_scale_kernels`; its numpy form is ``tests/accel_scale_reference.quiet_threshold``). The scale is
**applied only where it is clearly not 1** (``|s − 1| ≥ tolerance``, beyond what calibrated boards
and gentle turns show): then the accelerometer is divided by it before
anything else reads it. Every record whose scale is within the tolerance is estimated bit for bit as
before.

Offline it is a median over the whole record; the live estimator makes the same reading causally
(:class:`AccelScaleTracker`: trailing averages, decided once from its first ``min_quiet_s`` of quiet,
steady samples, applied from then on).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import check_range
from ..conventions import GRAVITY_M_S2
from .accel_scale_kernels import (AVG_HEAD, AVG_LEN, DECIDE, FULL, NORM_HEAD, NORM_LEN, QUIET_LEN, QUIET_S, new_state,
                                  quiet_rows, track_step)


@dataclass(frozen=True)
class AccelScaleConfig:
    """Settings of the accelerometer scale read from a record; the defaults are the shipped model's."""

    avg_s: float = 0.5  # rate and accelerometer averaged over this before the quiet test and the norm
    quiet_rate_rad_s: float = 0.05  # a quiet sample: the averaged rate's norm below this ...
    # ... or below this × the gyro's noise floor over the same window, where that is higher (rule 21, session 31;
    # 0: off), up to quiet_rate_cap_rad_s
    noise_floor_factor: float = 1.5
    quiet_rate_cap_rad_s: float = 0.1
    steady_s: float = 2.0  # ... and the averaged accelerometer's norm steady over this
    steady_m_s2: float = 0.1  # (its standard deviation there below this)
    min_quiet_s: float = 5.0  # at least this much quiet time for a reading
    # applied only where |scale − 1| reaches this: the 120 training-campaign flights and 17 seen BROAD
    # trials read 0.966–1.010 where they read at all (most simulated flights never hold still long enough)
    tolerance: float = 0.10

    def __post_init__(self):
        for name in ("avg_s", "quiet_rate_rad_s", "steady_s", "steady_m_s2", "min_quiet_s", "tolerance",
                     "quiet_rate_cap_rad_s"):
            check_range(name, getattr(self, name), 0, None, lo_open=True)
        check_range("noise_floor_factor", self.noise_floor_factor, 0, None)


@dataclass(frozen=True)
class AccelScale:
    """What :func:`read_accel_scale` found. ``scale`` is what to divide by (1 unless ``applied``)."""

    scale: float
    applied: bool
    read: float | None  # the median quiet norm over g (None: too little quiet time)
    quiet_s: float

    def describe(self) -> str:
        """One line for a user."""
        if self.read is None:
            return f"accelerometer scale: {self.quiet_s:.1f} s quiet, too little to read; not applied"
        if self.applied:
            what = "divided out; applied"
        elif self.read <= 0.0:
            what = "no gravity to read a scale from (a sensor written as zeros?); not applied"
        else:
            what = "within the tolerance; not applied"
        return f"accelerometer scale: {self.read:.3f} g at {self.quiet_s:.0f} s of quiet, steady samples; {what}"


def quiet_samples(t_s, gyr, acc, cfg: AccelScaleConfig | None = None):
    """The samples where the vehicle is neither turning nor shaking (module docstring: the rate's norm,
    averaged over ``avg_s``, below ``quiet_rate_rad_s`` or a noisy gyro's floor (module docstring); the
    averaged accelerometer's norm steady over ``steady_s``) → (quiet mask (n,), the averaged accelerometer (n, 3), the sample step in s), or None
    where the record is too short to tell. There the accelerometer shows gravity alone."""
    cfg = cfg or AccelScaleConfig()
    t_s = np.asarray(t_s, np.float64)
    n = len(t_s)
    step = float(np.median(np.diff(t_s))) if n > 1 else 0.0
    if n < 3 or not (math.isfinite(step) and step > 0):
        return None
    gyr, acc = _columns(gyr), _columns(acc)
    ok = np.all(np.isfinite(gyr), axis=1) & np.all(np.isfinite(acc), axis=1)
    k = max(1, int(round(cfg.avg_s / step)))
    if ok.sum() < 2 * k:
        return None
    m = max(1, int(round(cfg.steady_s / step)))  # the norm steady over steady_s: not accelerating
    if n < m:  # shorter than one steadiness window
        return None
    acc_lp, quiet = np.empty((n, 3)), np.empty(n, np.bool_)
    # the rate's norm and the averaged accelerometer over avg_s (no hole in the average), its norm's spread over
    # steady_s, a noisy gyro's floor (rule 21): compiled, numpy's operations in its order (session 42; the numpy form
    # is kept as tests/accel_scale_reference.quiet_samples)
    quiet_rows(gyr, acc, k, m, cfg.quiet_rate_rad_s, cfg.quiet_rate_cap_rad_s, cfg.noise_floor_factor, cfg.steady_m_s2,
               acc_lp, quiet)  # fmt: skip
    return quiet, acc_lp, step


def _columns(x) -> np.ndarray:
    """``x`` as a record's columns are, the compiled loop's one signature: float64, column-ordered, read-only (a view,
    no copy, where it is so already)."""
    v = np.asfortranarray(x, np.float64).view()
    v.flags.writeable = False
    return v


def read_accel_scale(t_s, gyr, acc, cfg: AccelScaleConfig | None = None) -> AccelScale:
    """The accelerometer's scale of a record (rows: body axes, SI; non-finite rows left out), applied
    only on evidence (module docstring)."""
    cfg = cfg or AccelScaleConfig()
    found = quiet_samples(t_s, gyr, acc, cfg)
    if found is None:
        return AccelScale(1.0, False, None, 0.0)
    quiet, acc_lp, step = found
    quiet_s = float(quiet.sum()) * step
    if quiet_s < cfg.min_quiet_s:
        return AccelScale(1.0, False, None, quiet_s)
    s = float(np.median(np.linalg.norm(acc_lp[quiet], axis=1))) / GRAVITY_M_S2
    applied = abs(s - 1.0) >= cfg.tolerance and s > 0
    return AccelScale(s if applied else 1.0, applied, s, quiet_s)


#: a step longer than this (or backwards) restarts the live reading's trailing windows
MAX_STEP_S = 1.0


class AccelScaleTracker:
    """The same reading made causally, for the live estimator: trailing averages instead of centred
    ones, and the scale decided once, from the first ``min_quiet_s`` of quiet, steady samples (a vehicle
    on the ground before it takes off gives them in seconds); from then on :meth:`update` divides by it
    where it is ``tolerance`` or more off 1. Before that decision — and on a vehicle that never holds
    still — the accelerometer passes as it is. Stops tracking once decided (no cost per sample then).
    The per-sample step is compiled (:mod:`.accel_scale_kernels`, session 27: 9 µs a sample in Python)."""

    def __init__(self, cfg: AccelScaleConfig | None = None):
        self.cfg = c = cfg or AccelScaleConfig()
        self.scale = 1.0
        self.decided: AccelScale | None = None
        self._cfg = np.array([c.avg_s, c.steady_s, c.quiet_rate_rad_s, c.steady_m_s2, c.min_quiet_s, MAX_STEP_S,
                              c.noise_floor_factor, c.quiet_rate_cap_rad_s])  # fmt: skip
        self._state, self._idx = new_state()
        # ring buffers of the two trailing windows and the quiet norms, grown when full (FULL)
        self._avg, self._norms, self._quiet = np.zeros((256, 6)), np.zeros((1024, 2)), np.zeros(1024)

    def window_lengths(self) -> tuple[int, int]:
        """How many samples the trailing ``avg_s`` and ``steady_s`` windows hold (0, 0 once decided)."""
        if self.decided is not None:
            return 0, 0
        return int(self._idx[AVG_LEN]), int(self._idx[NORM_LEN])

    def update(self, t: float, gyr, acc) -> tuple[float, float, float]:
        """One finite sample (body axes, SI) → the accelerometer to use (divided by the scale once it is
        decided and applies)."""
        ax, ay, az = acc
        if self.decided is not None:
            s = self.scale
            return (ax / s, ay / s, az / s) if s != 1.0 else (ax, ay, az)
        args = (float(t), float(gyr[0]), float(gyr[1]), float(gyr[2]), float(ax), float(ay), float(az))
        r = track_step(self._state, self._idx, self._avg, self._norms, self._quiet, self._cfg, *args)
        while r == FULL:
            self._grow()
            r = track_step(self._state, self._idx, self._avg, self._norms, self._quiet, self._cfg, *args)
        if r == DECIDE:
            c = self.cfg
            quiet_s = float(self._state[QUIET_S])
            s = float(np.median(self._quiet[: self._idx[QUIET_LEN]])) / GRAVITY_M_S2
            applied = abs(s - 1.0) >= c.tolerance and s > 0
            self.decided = AccelScale(s if applied else 1.0, applied, s, quiet_s)
            self.scale = self.decided.scale
            self._avg = self._norms = self._quiet = None
            return self.update(t, gyr, acc)
        return ax, ay, az

    def _grow(self) -> None:
        """Double whichever buffer is full, the rings unrolled oldest first."""
        i = self._idx
        for name, head, length in (("_avg", AVG_HEAD, AVG_LEN), ("_norms", NORM_HEAD, NORM_LEN)):
            buf = getattr(self, name)
            if i[length] >= buf.shape[0]:
                setattr(self, name, np.concatenate([np.roll(buf, -int(i[head]), axis=0), np.zeros_like(buf)]))
                i[head] = 0
        if i[QUIET_LEN] >= self._quiet.shape[0]:
            self._quiet = np.concatenate([self._quiet, np.zeros_like(self._quiet)])
