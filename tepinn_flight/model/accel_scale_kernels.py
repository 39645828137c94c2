"""The live accelerometer-scale reading's per-sample step, compiled with numba (one signature).

:class:`.accel_scale.AccelScaleTracker` runs on every sample the bridge receives until it has read the
scale, and on a vehicle that never holds still that is every sample of the flight: its Python (two
trailing windows as deques) cost about 9 µs a sample, a sixth of the live estimator's budget
(``benchmarks/PROFILE.md``, session 27). The step below is the same arithmetic in the same order
(bit-identical outputs; ``tests/test_accel_scale.py`` checks it against the former Python, kept in
``tests/accel_scale_reference.py``), on ring buffers the tracker owns:

* ``state`` (float64): t_first, t_prev (NaN: none yet), quiet seconds, the rate-norm and
  accelerometer sums over ``avg_s``, the norm's sum and sum of squares over ``steady_s``, the gyro's
  noise-floor sum over ``avg_s`` and the previous gyro sample (rule 21);
* ``idx`` (int64): head and length of each ring, and how many quiet norms are kept;
* ``avg`` (cap, 6): (t, |ω|, ax, ay, az, |ω − ω_prev|/√2) of the last ``avg_s``; ``norms`` (cap, 2): (t, |ā|) of the
  last ``steady_s``; ``quiet`` (cap,): the quiet samples' norms;
* ``cfg`` (float64): avg_s, steady_s, quiet_rate_rad_s, steady_m_s2, min_quiet_s, max_step_s,
  noise_floor_factor, quiet_rate_cap_rad_s (the quiet threshold: :func:`.accel_scale.quiet_threshold`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: what :func:`track_step` returns
PASS, DECIDE, FULL = 0, 1, 2

# state / idx slots
T_FIRST, T_PREV, QUIET_S, SUM_W, SUM_X, SUM_Y, SUM_Z, N1, N2, SUM_D, GX_PREV, GY_PREV, GZ_PREV = range(13)
SQRT2 = math.sqrt(2.0)
AVG_HEAD, AVG_LEN, NORM_HEAD, NORM_LEN, QUIET_LEN = range(5)


def new_state() -> tuple[np.ndarray, np.ndarray]:
    """(state, idx) of a tracker that has seen nothing."""
    state = np.zeros(13)
    state[T_FIRST] = state[T_PREV] = np.nan
    return state, np.zeros(5, np.int64)


@njit(cache=True)
def track_step(state, idx, avg, norms, quiet, cfg, t, gx, gy, gz, ax, ay, az):
    """One finite sample into the trailing windows → PASS (no reading yet), DECIDE (the quiet time
    reached ``min_quiet_s``: the caller reads the median of ``quiet[:idx[QUIET_LEN]]``) or FULL (a
    buffer has no room: nothing was changed; grow it and call again)."""
    cap_a, cap_n, cap_q = avg.shape[0], norms.shape[0], quiet.shape[0]
    if idx[AVG_LEN] >= cap_a or idx[NORM_LEN] >= cap_n or idx[QUIET_LEN] >= cap_q:
        return FULL
    avg_s, steady_s, quiet_rate, steady_m_s2, min_quiet_s, max_step_s = cfg[0], cfg[1], cfg[2], cfg[3], cfg[4], cfg[5]
    floor_factor, rate_cap = cfg[6], cfg[7]
    dt = 0.0 if math.isnan(state[T_PREV]) else t - state[T_PREV]
    d = 0.0  # |ω − ω_prev|/√2: what white noise alone adds to |ω| (0 at a window's start)
    if math.isnan(state[T_FIRST]) or not (0.0 < dt <= max_step_s):  # the start, a time jump or a dropout:
        state[T_FIRST] = t  # the trailing windows start again (the quiet samples so far are kept)
        dt = 0.0
        idx[AVG_HEAD] = idx[AVG_LEN] = idx[NORM_HEAD] = idx[NORM_LEN] = 0
        state[SUM_W] = state[SUM_X] = state[SUM_Y] = state[SUM_Z] = 0.0
        state[N1] = state[N2] = state[SUM_D] = 0.0
    else:
        ex, ey, ez = gx - state[GX_PREV], gy - state[GY_PREV], gz - state[GZ_PREV]
        d = math.sqrt(ex * ex + ey * ey + ez * ez) / SQRT2
    state[T_PREV] = t
    state[GX_PREV], state[GY_PREV], state[GZ_PREV] = gx, gy, gz
    w = math.sqrt(gx * gx + gy * gy + gz * gz)
    j = (idx[AVG_HEAD] + idx[AVG_LEN]) % cap_a
    avg[j, 0], avg[j, 1], avg[j, 2], avg[j, 3], avg[j, 4], avg[j, 5] = t, w, ax, ay, az, d
    idx[AVG_LEN] += 1
    state[SUM_W] += w
    state[SUM_X] += ax
    state[SUM_Y] += ay
    state[SUM_Z] += az
    state[SUM_D] += d
    while t - avg[idx[AVG_HEAD], 0] >= avg_s:
        h = idx[AVG_HEAD]
        state[SUM_W] -= avg[h, 1]
        state[SUM_X] -= avg[h, 2]
        state[SUM_Y] -= avg[h, 3]
        state[SUM_Z] -= avg[h, 4]
        state[SUM_D] -= avg[h, 5]
        idx[AVG_HEAD] = (h + 1) % cap_a
        idx[AVG_LEN] -= 1
    n = idx[AVG_LEN]
    sx, sy, sz = state[SUM_X], state[SUM_Y], state[SUM_Z]
    norm = math.sqrt(sx * sx + sy * sy + sz * sz) / n
    j = (idx[NORM_HEAD] + idx[NORM_LEN]) % cap_n
    norms[j, 0], norms[j, 1] = t, norm
    idx[NORM_LEN] += 1
    state[N1] += norm
    state[N2] += norm * norm
    while t - norms[idx[NORM_HEAD], 0] >= steady_s:
        h = idx[NORM_HEAD]
        v = norms[h, 1]
        state[N1] -= v
        state[N2] -= v * v
        idx[NORM_HEAD] = (h + 1) % cap_n
        idx[NORM_LEN] -= 1
    if t - state[T_FIRST] < avg_s + steady_s:  # the trailing windows are not full yet
        return PASS
    m = idx[NORM_LEN]
    mean = state[N1] / m
    spread = math.sqrt(max(state[N2] / m - mean * mean, 0.0))
    thr = max(quiet_rate, min(rate_cap, floor_factor * (state[SUM_D] / n)))  # accel_scale.quiet_threshold
    if state[SUM_W] / n < thr and spread < steady_m_s2:
        quiet[idx[QUIET_LEN]] = norm
        idx[QUIET_LEN] += 1
        state[QUIET_S] += dt
        if state[QUIET_S] >= min_quiet_s:
            return DECIDE
    return PASS
