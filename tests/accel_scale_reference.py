"""The slow, obviously-correct reference of the live accelerometer-scale reading: the plain-Python
tracker (two deques) that :mod:`tepinn_flight.model.accel_scale_kernels` compiled, kept verbatim
(renamed ``AccelScaleTrackerReference``) but for rule 21 (session 31: the quiet threshold above a noisy
gyro's floor, the mean of |ω − ω_prev|/√2 over the same window), added here in plain Python. The compiled
tracker must equal it bit for bit (``tests/test_accel_scale.py``)."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from tepinn_flight.conventions import GRAVITY_M_S2
from tepinn_flight.model.accel_scale import MAX_STEP_S, AccelScale, AccelScaleConfig


class AccelScaleTrackerReference:
    """The same reading made causally, for the live estimator: trailing averages instead of centred
    ones, and the scale decided once, from the first ``min_quiet_s`` of quiet, steady samples (a vehicle
    on the ground before it takes off gives them in seconds); from then on :meth:`update` divides by it
    where it is ``tolerance`` or more off 1. Before that decision — and on a vehicle that never holds
    still — the accelerometer passes as it is. Stops tracking once decided (no cost per sample then)."""

    def __init__(self, cfg: AccelScaleConfig | None = None):
        self.cfg = cfg or AccelScaleConfig()
        self.scale = 1.0
        self.decided: AccelScale | None = None
        self._avg = deque()  # (t, |ω|, ax, ay, az, |ω − ω_prev|/√2) of the last avg_s
        self._sums = [0.0, 0.0, 0.0, 0.0, 0.0]
        self._g_prev = (0.0, 0.0, 0.0)
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
        d = 0.0
        if self._t_first is None or not 0.0 < dt <= MAX_STEP_S:  # the start, a time jump or a dropout:
            self._t_first, dt = t, 0.0  # the trailing windows start again (the quiet samples so far are kept)
            self._avg.clear()
            self._norms.clear()
            self._sums = [0.0, 0.0, 0.0, 0.0, 0.0]
            self._n1 = self._n2 = 0.0
        else:
            e = [gyr[i] - self._g_prev[i] for i in range(3)]
            d = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]) / math.sqrt(2.0)
        self._t_prev = t
        self._g_prev = (gyr[0], gyr[1], gyr[2])
        w = math.sqrt(gyr[0] * gyr[0] + gyr[1] * gyr[1] + gyr[2] * gyr[2])
        avg = self._avg
        avg.append((t, w, ax, ay, az, d))
        sums = self._sums
        sums[0] += w
        sums[1] += ax
        sums[2] += ay
        sums[3] += az
        sums[4] += d
        while t - avg[0][0] >= c.avg_s:
            _, w0, x0, y0, z0, d0 = avg.popleft()
            sums[0] -= w0
            sums[1] -= x0
            sums[2] -= y0
            sums[3] -= z0
            sums[4] -= d0
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
        thr = max(c.quiet_rate_rad_s, min(c.quiet_rate_cap_rad_s, c.noise_floor_factor * (sums[4] / n)))
        if sums[0] / n < thr and spread < c.steady_m_s2:
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


def quiet_threshold(noise_floor, cfg: AccelScaleConfig):
    """The averaged |ω| below which a sample is quiet, given the gyro's noise floor over the same window
    (the mean of |ω_i − ω_(i−1)|/√2; rad/s): ``quiet_rate_rad_s``, raised to ``noise_floor_factor`` × the floor
    where that is higher, at most ``quiet_rate_cap_rad_s`` (rule 21). The package computes it only in its compiled
    loops (``accel_scale_kernels.track_step`` live, ``quiet_rows`` offline; moved here from ``accel_scale`` in session
    43, when nothing in the package called it any more)."""
    return np.maximum(cfg.quiet_rate_rad_s, np.minimum(cfg.quiet_rate_cap_rad_s, cfg.noise_floor_factor * noise_floor))


def noise_norms(gyr, ok) -> np.ndarray:
    """(n,) |ω_i − ω_(i−1)|/√2 per sample (0 at the first and next to a non-finite sample): what white
    noise alone adds to |ω|, in distribution. (First differences, not the second differences of
    ``record_stats.sample_noise``, which reports a per-axis σ: the norm of a first difference over √2 has the
    distribution of the noise vector's own norm, and the live tracker needs only the previous sample.) The package
    computes it only in its compiled loops, as :func:`quiet_threshold`."""
    d = np.zeros(len(gyr))
    if len(gyr) > 1:
        step = np.diff(np.where(ok[:, None], gyr, 0.0), axis=0)
        d[1:] = np.where(ok[1:] & ok[:-1], np.sqrt(np.einsum("ij,ij->i", step, step)) / math.sqrt(2.0), 0.0)
    return d


def quiet_samples(t_s, gyr, acc, cfg: AccelScaleConfig | None = None):
    """The offline reading's quiet samples as numpy computed them before session 42 compiled them
    (:func:`tepinn_flight.model.accel_scale.quiet_samples`, :func:`..accel_scale_kernels.quiet_rows`), verbatim: the
    compiled form must give the same mask and averaged accelerometer bit for bit (``tests/test_accel_scale.py``)."""
    from tepinn_flight.model.gyro_selfcal import _boxcar

    cfg = cfg or AccelScaleConfig()
    t_s = np.asarray(t_s, np.float64)
    n = len(t_s)
    step = float(np.median(np.diff(t_s))) if n > 1 else 0.0
    if n < 3 or not (math.isfinite(step) and step > 0):
        return None
    gyr = np.asarray(gyr, np.float64)
    acc = np.asarray(acc, np.float64)
    ok = np.all(np.isfinite(gyr), axis=1) & np.all(np.isfinite(acc), axis=1)
    k = max(1, int(round(cfg.avg_s / step)))
    if ok.sum() < 2 * k:
        return None
    g_norm = np.sqrt(np.einsum("ij,ij->i", np.where(ok[:, None], gyr, 0.0), np.where(ok[:, None], gyr, 0.0)))
    rate = _boxcar(g_norm[:, None], k)[:, 0]
    acc_lp = _boxcar(np.where(ok[:, None], acc, 0.0), k)
    whole = _boxcar(ok[:, None].astype(np.float64), k)[:, 0] > 1.0 - 1e-9  # the average saw no hole
    a_norm = np.linalg.norm(acc_lp, axis=1)
    m = max(1, int(round(cfg.steady_s / step)))  # the norm steady over steady_s: not accelerating
    if n < m:  # shorter than one steadiness window
        return None
    mean = _boxcar(a_norm[:, None], m)[:, 0]
    spread = np.sqrt(np.maximum(_boxcar((a_norm**2)[:, None], m)[:, 0] - mean**2, 0.0))
    thr = quiet_threshold(_boxcar(noise_norms(gyr, ok)[:, None], k)[:, 0], cfg)  # a noisy gyro's floor (rule 21)
    quiet = whole & (rate < thr) & (spread < cfg.steady_m_s2)
    return quiet, acc_lp, step
