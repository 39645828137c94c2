"""The accelerometer's scale read from a record alone — no reference, no learned part (offline).

A gravity-referenced filter reads only the accelerometer's *direction*, so a board that reads
|a| ≈ 7.8 m/s² at rest (0.8 g: a wrong range setting or calibration) does not bother VQF. Everything
that reads its *magnitude* in m/s² does: the GNSS aid (:mod:`.gnss_aid`) takes the receiver's motion
acceleration, in m/s², out of the accelerometer — on a board at 0.8 g it removes 1/0.8 of what the
board shows of it — and the network, trained on accelerometers within a few per cent of true,
estimates the body velocity and the centripetal term from the specific force's size (a simulated
c172x flight with the accelerometer × 0.8: 2.84° → 24.4°, README).

Where the vehicle is neither turning nor shaking — at rest, hovering, flying straight and level — the
accelerometer's low-passed norm is g times its scale. So over ``avg_s`` the rate's norm is averaged
and the accelerometer is averaged (vibration out of the norm: a noisy vector's norm is biased up), and
the scale is the median of that norm over the *quiet* samples (rate below ``quiet_rate_rad_s``: a
coordinated 15° banked turn at 50 m/s turns at 0.05 rad/s and reads 1.035 g), over at least
``min_quiet_s`` of them. It is **applied only where it is clearly not 1** (``|s − 1| ≥ tolerance``,
beyond what calibrated boards and gentle turns show): then the accelerometer is divided by it before
anything else reads it. Every record whose scale is within the tolerance is estimated bit for bit as
before.

Offline it is a median over the whole record; the live estimator makes the same reading causally
(:class:`AccelScaleTracker`: trailing averages, decided once from its first ``min_quiet_s`` of quiet,
steady samples, applied from then on).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..config import check_range
from ..conventions import GRAVITY_M_S2
from .gyro_selfcal import _boxcar


@dataclass(frozen=True)
class AccelScaleConfig:
    """Settings of the accelerometer scale read from a record; the defaults are the shipped model's."""

    avg_s: float = 0.5  # rate and accelerometer averaged over this before the quiet test and the norm
    quiet_rate_rad_s: float = 0.05  # a quiet sample: the averaged rate's norm below this
    steady_s: float = 2.0  # ... and the averaged accelerometer's norm steady over this
    steady_m_s2: float = 0.1  # (its standard deviation there below this)
    min_quiet_s: float = 5.0  # at least this much quiet time for a reading
    # applied only where |scale − 1| reaches this: the 120 training-campaign flights and 17 seen BROAD
    # trials read 0.966–1.010 where they read at all (most simulated flights never hold still long enough)
    tolerance: float = 0.10

    def __post_init__(self):
        for name in ("avg_s", "quiet_rate_rad_s", "steady_s", "steady_m_s2", "min_quiet_s", "tolerance"):
            check_range(name, getattr(self, name), 0, None, lo_open=True)


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
        what = "divided out; applied" if self.applied else "within the tolerance; not applied"
        return f"accelerometer scale: {self.read:.3f} g at {self.quiet_s:.0f} s of quiet, steady samples; {what}"


def read_accel_scale(t_s, gyr, acc, cfg: AccelScaleConfig | None = None) -> AccelScale:
    """The accelerometer's scale of a record (rows: body axes, SI; non-finite rows left out), applied
    only on evidence (module docstring)."""
    cfg = cfg or AccelScaleConfig()
    t_s = np.asarray(t_s, np.float64)
    n = len(t_s)
    step = float(np.median(np.diff(t_s))) if n > 1 else 0.0
    if n < 3 or not (math.isfinite(step) and step > 0):
        return AccelScale(1.0, False, None, 0.0)
    gyr = np.asarray(gyr, np.float64)
    acc = np.asarray(acc, np.float64)
    ok = np.all(np.isfinite(gyr), axis=1) & np.all(np.isfinite(acc), axis=1)
    k = max(1, int(round(cfg.avg_s / step)))
    if ok.sum() < 2 * k:
        return AccelScale(1.0, False, None, 0.0)
    g_norm = np.sqrt(np.einsum("ij,ij->i", np.where(ok[:, None], gyr, 0.0), np.where(ok[:, None], gyr, 0.0)))
    rate = _boxcar(g_norm[:, None], k)[:, 0]
    acc_lp = _boxcar(np.where(ok[:, None], acc, 0.0), k)
    whole = _boxcar(ok[:, None].astype(np.float64), k)[:, 0] > 1.0 - 1e-9  # the average saw no hole
    a_norm = np.linalg.norm(acc_lp, axis=1)
    m = max(1, int(round(cfg.steady_s / step)))  # the norm steady over steady_s: not accelerating
    if n < m:  # shorter than one steadiness window: no reading
        return AccelScale(1.0, False, None, 0.0)
    mean = _boxcar(a_norm[:, None], m)[:, 0]
    spread = np.sqrt(np.maximum(_boxcar((a_norm**2)[:, None], m)[:, 0] - mean**2, 0.0))
    quiet = whole & (rate < cfg.quiet_rate_rad_s) & (spread < cfg.steady_m_s2)
    quiet_s = float(quiet.sum()) * step
    if quiet_s < cfg.min_quiet_s:
        return AccelScale(1.0, False, None, quiet_s)
    s = float(np.median(a_norm[quiet])) / GRAVITY_M_S2
    applied = abs(s - 1.0) >= cfg.tolerance and s > 0
    return AccelScale(s if applied else 1.0, applied, s, quiet_s)


#: a step longer than this (or backwards) restarts the live reading's trailing windows
MAX_STEP_S = 1.0


class AccelScaleTracker:
    """The same reading made causally, for the live estimator: trailing averages instead of centred
    ones, and the scale decided once, from the first ``min_quiet_s`` of quiet, steady samples (a vehicle
    on the ground before it takes off gives them in seconds); from then on :meth:`update` divides by it
    where it is ``tolerance`` or more off 1. Before that decision — and on a vehicle that never holds
    still — the accelerometer passes as it is. Stops tracking once decided (no cost per sample then)."""

    def __init__(self, cfg: AccelScaleConfig | None = None):
        self.cfg = cfg or AccelScaleConfig()
        self.scale = 1.0
        self.decided: AccelScale | None = None
        self._avg = deque()  # (t, |ω|, ax, ay, az) of the last avg_s
        self._sums = [0.0, 0.0, 0.0, 0.0]
        self._norms = deque()  # (t, |ā|) of the last steady_s
        self._n1 = self._n2 = 0.0
        self._quiet: list[float] = []
        self._t_first = None
        self._t_prev = None
        self._quiet_s = 0.0

    def update(self, t: float, gyr, acc) -> tuple[float, float, float]:
        """One finite sample (body axes, SI) → the accelerometer to use (divided by the scale once it is
        decided and applies)."""
        ax, ay, az = acc
        if self.decided is not None:
            s = self.scale
            return (ax / s, ay / s, az / s) if s != 1.0 else (ax, ay, az)
        c = self.cfg
        dt = 0.0 if self._t_prev is None else t - self._t_prev
        if self._t_first is None or not 0.0 < dt <= MAX_STEP_S:  # the start, a time jump or a dropout:
            self._t_first, dt = t, 0.0  # the trailing windows start again (the quiet samples so far are kept)
            self._avg.clear()
            self._norms.clear()
            self._sums = [0.0, 0.0, 0.0, 0.0]
            self._n1 = self._n2 = 0.0
        self._t_prev = t
        w = math.sqrt(gyr[0] * gyr[0] + gyr[1] * gyr[1] + gyr[2] * gyr[2])
        avg = self._avg
        avg.append((t, w, ax, ay, az))
        sums = self._sums
        sums[0] += w
        sums[1] += ax
        sums[2] += ay
        sums[3] += az
        while t - avg[0][0] >= c.avg_s:
            _, w0, x0, y0, z0 = avg.popleft()
            sums[0] -= w0
            sums[1] -= x0
            sums[2] -= y0
            sums[3] -= z0
        n = len(avg)
        norm = math.sqrt(sums[1] * sums[1] + sums[2] * sums[2] + sums[3] * sums[3]) / n
        norms = self._norms
        norms.append((t, norm))
        self._n1 += norm
        self._n2 += norm * norm
        while t - norms[0][0] >= c.steady_s:
            _, v = norms.popleft()
            self._n1 -= v
            self._n2 -= v * v
        if t - self._t_first < c.avg_s + c.steady_s:  # the trailing windows are not full yet
            return ax, ay, az
        m = len(norms)
        mean = self._n1 / m
        spread = math.sqrt(max(self._n2 / m - mean * mean, 0.0))
        if sums[0] / n < c.quiet_rate_rad_s and spread < c.steady_m_s2:
            self._quiet.append(norm)
            self._quiet_s += dt
            if self._quiet_s >= c.min_quiet_s:
                s = float(np.median(self._quiet)) / GRAVITY_M_S2
                applied = abs(s - 1.0) >= c.tolerance and s > 0
                self.decided = AccelScale(s if applied else 1.0, applied, s, self._quiet_s)
                self.scale = self.decided.scale
                self._avg = self._norms = None
                self._quiet = []
                return self.update(t, gyr, acc)
        return ax, ay, az
