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
  noise_floor_factor, quiet_rate_cap_rad_s (the quiet threshold, :mod:`.accel_scale`'s docstring; its numpy form
  ``tests/accel_scale_reference.quiet_threshold``).
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
    thr = max(quiet_rate, min(rate_cap, floor_factor * (state[SUM_D] / n)))  # the quiet threshold (accel_scale's docstring)
    if state[SUM_W] / n < thr and spread < steady_m_s2:
        quiet[idx[QUIET_LEN]] = norm
        idx[QUIET_LEN] += 1
        state[QUIET_S] += dt
        if state[QUIET_S] >= min_quiet_s:
            return DECIDE
    return PASS


@njit(cache=True)
def quiet_rows(gyr, acc, k, m, quiet_rate, rate_cap, floor_factor, steady, acc_lp, quiet):
    """:func:`.accel_scale.quiet_samples`' whole-record arithmetic: ``acc_lp`` (n, 3), the accelerometer averaged over
    ``k`` rows, and ``quiet`` (n,) bools, its mask, from ``gyr``, ``acc`` (n, 3) with ``n ≥ max(k, m)``.

    numpy's operations in its order, so the same bits as the numpy form it replaced (kept as
    ``tests/accel_scale_reference.quiet_samples``): a row with a non-finite value zeroed; ``einsum("ij,ij->i")`` adds
    the squares as (x² + z²) + y², ``linalg.norm`` as (x² + y²) + z²; each centred average (``gyro_selfcal._boxcar``)
    is the difference of a running sum (``cumsum`` from 0) ``k`` rows apart over ``k``, the edges holding the nearest
    full one. The running sums are made as the averages need them and kept for the last ``k + 1`` (``m + 1``) rows
    only: the outputs are the only whole-record arrays. numpy's form made ~25 whole-record temporaries, 0.21–0.28 s of a
    one-hour log, ~0.45 s where their pages were fresh, before anything else of its estimate could start (session 42)."""
    n = gyr.shape[0]
    # the average over k rows: running sums of |ω|, the row's finiteness, |ω − ω_prev|/√2 and the accelerometer, the
    # last k + 1 kept in a ring (c[t] in slot t mod (k + 1); slots advanced by hand: a modulo per row cost more)
    rk = k + 1
    ring = np.empty((rk, 6))
    ring[0, :] = 0.0
    r0 = r1 = r2 = r3 = r4 = r5 = 0.0
    made, w = 1, 1  # running sums made (c[0 .. made − 1]) and the slot of the next one
    lo = 0  # the slot of c[j], j the average's first row; c[j + k] is in the slot before it
    j_prev = 0
    prev_ok = False
    px = py = pz = 0.0
    for i in range(n):
        j = min(max(i - (k - 1) // 2, 0), n - k)
        if j != j_prev:  # (j grows by one a row, after the leading edge)
            lo = lo + 1 if lo + 1 < rk else 0
            j_prev = j
        while made <= j + k:
            r = made - 1  # the row c[made] adds
            gx, gy, gz, ax, ay, az = gyr[r, 0], gyr[r, 1], gyr[r, 2], acc[r, 0], acc[r, 1], acc[r, 2]
            ok = (math.isfinite(gx) and math.isfinite(gy) and math.isfinite(gz) and math.isfinite(ax)
                  and math.isfinite(ay) and math.isfinite(az))  # fmt: skip
            if not ok:
                gx = gy = gz = ax = ay = az = 0.0
            d = 0.0  # the noise norm (reference: noise_norms): 0 at the first row and next to a non-finite one
            if r > 0 and ok and prev_ok:
                dx, dy, dz = gx - px, gy - py, gz - pz
                d = math.sqrt((dx * dx + dz * dz) + dy * dy) / SQRT2
            prev_ok, px, py, pz = ok, gx, gy, gz
            r0 = r0 + math.sqrt((gx * gx + gz * gz) + gy * gy)
            r1 = r1 + (1.0 if ok else 0.0)
            r2 = r2 + d
            r3 = r3 + ax
            r4 = r4 + ay
            r5 = r5 + az
            ring[w, 0], ring[w, 1], ring[w, 2], ring[w, 3], ring[w, 4], ring[w, 5] = r0, r1, r2, r3, r4, r5
            w = w + 1 if w + 1 < rk else 0
            made += 1
        hi = lo - 1 if lo > 0 else k  # the slot of c[j + k]
        acc_lp[i, 0] = (ring[hi, 3] - ring[lo, 3]) / k
        acc_lp[i, 1] = (ring[hi, 4] - ring[lo, 4]) / k
        acc_lp[i, 2] = (ring[hi, 5] - ring[lo, 5]) / k
        thr = max(quiet_rate, min(rate_cap, floor_factor * ((ring[hi, 2] - ring[lo, 2]) / k)))  # the quiet threshold
        whole = (ring[hi, 1] - ring[lo, 1]) / k > 1.0 - 1e-9  # the average saw no hole
        quiet[i] = whole and (ring[hi, 0] - ring[lo, 0]) / k < thr
    # the averaged accelerometer's norm steady over m rows: running sums of |ā| and |ā|², the same way
    rm = m + 1
    ring2 = np.empty((rm, 2))
    ring2[0, 0] = ring2[0, 1] = 0.0
    s1 = s2 = 0.0
    made, w, lo, j_prev = 1, 1, 0, 0
    for i in range(n):
        j = min(max(i - (m - 1) // 2, 0), n - m)
        if j != j_prev:
            lo = lo + 1 if lo + 1 < rm else 0
            j_prev = j
        while made <= j + m:
            r = made - 1
            x, y, z = acc_lp[r, 0], acc_lp[r, 1], acc_lp[r, 2]
            a = math.sqrt((x * x + y * y) + z * z)
            s1 = s1 + a
            s2 = s2 + a * a
            ring2[w, 0], ring2[w, 1] = s1, s2
            w = w + 1 if w + 1 < rm else 0
            made += 1
        hi = lo - 1 if lo > 0 else m
        mean = (ring2[hi, 0] - ring2[lo, 0]) / m
        v = (ring2[hi, 1] - ring2[lo, 1]) / m - mean * mean
        spread = math.sqrt(v) if v >= 0.0 or v != v else 0.0  # numpy's maximum(v, 0): NaN stays NaN
        quiet[i] = quiet[i] and spread < steady
