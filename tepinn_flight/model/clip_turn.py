"""A clipped gyro's missed turn, read back from gravity before and after the clipping (offline).

A gyro past its range reads the range: over the clipped samples the turn it integrates falls short of the
body's by the rate past the range on each clipped axis — a flip at 2400 °/s on a ±2000 °/s gyro misses 60°,
and every filter carries that error until its accelerometer correction has taken it out (VQF: seconds; its
offline run both ways blurs it into the seconds before and after). Gravity does not turn. So the mean
specific force over ``window_s`` before the clipping, carried by the (bias-corrected) gyro into the frame of
the body at the clipping's start, and the mean over ``window_s`` after it, carried there through the clipped
samples, point the same way once the missed turn is put back. Per clipped axis (one reading its own range, the
largest in the record) one excess rate (the sign of the clip's, ``0 .. max_excess × the gyro's range``) is
fitted to make the two agree (a grid over the clipped axes together, then finer ones per axis around its best);
the fit is taken where it removes most of their disagreement (``accept_ratio``, ``min_gain_deg``), else the gyro
is left as it read. Gravity fixes the missed turn's horizontal part only: a part about the vertical (the heading)
it cannot see, nor therefore how a turn about several axes splits between them along the vertical.

The offline smoothing (:mod:`.smoother`) runs VQF both ways on the gyro with the fitted turns put back
(rule 25, session 34). The causal estimate (and the live bridge) never sees the future, and stays as it was.

Pure math: arrays in, arrays out; the per-sample integration compiled (numba).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..quat_scalar import exp_rotvec, qmul, qnorm, rotmat_entries


@dataclass(frozen=True)
class ClipTurn:
    """One episode of the gyro's clipping and what the fit found."""

    start: int  # first clipped sample (record index)
    stop: int  # one past the last
    t_s: float  # time of the first
    excess_rad_s: tuple[float, float, float]  # per body axis, added on that axis's clipped samples (signed as the clip)
    angle_before_deg: float  # gravity's disagreement across the episode as the gyro read it
    angle_after_deg: float  # ... with the excess put back
    accepted: bool
    why: str = ""  # why no fit was tried (too little unclipped time beside it, no axis at its range)


def clip_episodes(t_s: np.ndarray, clipped: np.ndarray, merge_s: float) -> list[tuple[int, int]]:
    """(start, stop) of each run of clipped samples, runs less than ``merge_s`` apart merged."""
    idx = np.flatnonzero(np.asarray(clipped, bool))
    if idx.size == 0:
        return []
    out = []
    a = prev = int(idx[0])
    for i in idx[1:]:
        i = int(i)
        if t_s[i] - t_s[prev] > merge_s:
            out.append((a, prev + 1))
            a = i
        prev = i
    out.append((a, prev + 1))
    return out


@njit(cache=True)
def _mean_force(gyr, acc, dt, lo, hi, backward):
    """The mean of the specific force over samples [lo, hi), each carried into the frame of the body at ``hi``
    (``backward``: the gyro integrated back from ``hi``) or at ``lo`` (forward from ``lo``)."""
    w, x, y, z = 1.0, 0.0, 0.0, 0.0
    sx = sy = sz = 0.0
    n = hi - lo
    for j in range(n):
        k = hi - 1 - j if backward else lo + j
        if backward:  # the body at k from the body at k+1: the step k → k+1 undone
            e = exp_rotvec(-gyr[k, 0] * dt[k], -gyr[k, 1] * dt[k], -gyr[k, 2] * dt[k])
            w, x, y, z = qnorm(*qmul(w, x, y, z, e[0], e[1], e[2], e[3]))
        m = rotmat_entries(w, x, y, z)
        ax, ay, az = acc[k, 0], acc[k, 1], acc[k, 2]
        sx += m[0] * ax + m[1] * ay + m[2] * az
        sy += m[3] * ax + m[4] * ay + m[5] * az
        sz += m[6] * ax + m[7] * ay + m[8] * az
        if not backward:
            e = exp_rotvec(gyr[k, 0] * dt[k], gyr[k, 1] * dt[k], gyr[k, 2] * dt[k])
            w, x, y, z = qnorm(*qmul(w, x, y, z, e[0], e[1], e[2], e[3]))
    return sx / n, sy / n, sz / n


@njit(cache=True)
def _angle_across(gyr, sgn, dt, a, b, ex, ey, ez, pre, post):
    """The angle (rad) between ``pre`` and ``post`` carried back across samples [a, b) by the gyro plus the
    excess (ex, ey, ez) on each axis where ``sgn`` (the clip's sign, 0 where that axis did not clip) is set."""
    w, x, y, z = 1.0, 0.0, 0.0, 0.0
    for k in range(a, b):
        e = exp_rotvec((gyr[k, 0] + ex * sgn[k, 0]) * dt[k], (gyr[k, 1] + ey * sgn[k, 1]) * dt[k],
                       (gyr[k, 2] + ez * sgn[k, 2]) * dt[k])  # fmt: skip
        w, x, y, z = qnorm(*qmul(w, x, y, z, e[0], e[1], e[2], e[3]))
    m = rotmat_entries(w, x, y, z)
    px = m[0] * post[0] + m[1] * post[1] + m[2] * post[2]
    py = m[3] * post[0] + m[4] * post[1] + m[5] * post[2]
    pz = m[6] * post[0] + m[7] * post[1] + m[8] * post[2]
    c = pre[0] * px + pre[1] * py + pre[2] * pz
    n = math.sqrt(pre[0] ** 2 + pre[1] ** 2 + pre[2] ** 2) * math.sqrt(px * px + py * py + pz * pz)
    if n <= 0.0:
        return math.pi
    return math.acos(min(1.0, max(-1.0, c / n)))


@njit(cache=True)
def _angle_grid(gyr, sgn, dt, a, b, pre, post, cand):
    """:func:`_angle_across` for each row (ex, ey, ez) of ``cand``."""
    out = np.empty(cand.shape[0])
    for i in range(cand.shape[0]):
        out[i] = _angle_across(gyr, sgn, dt, a, b, cand[i, 0], cand[i, 1], cand[i, 2], pre, post)
    return out


def _steps(t_s: np.ndarray) -> np.ndarray:
    """Each sample's step to the next (the last one's and any non-finite or > 5 median steps: the median)."""
    dt = np.diff(np.asarray(t_s, np.float64))
    med = float(np.median(dt)) if dt.size else 0.0
    dt = np.r_[dt, med]
    bad = ~np.isfinite(dt) | (dt <= 0) | (dt > 5 * med)
    dt[bad] = med
    return np.ascontiguousarray(dt)


def fit_clip_turns(t_s, gyr_rad_s, acc_m_s2, clipped, bias_rad_s, bounds: list[slice],
                   cfg) -> tuple[np.ndarray, list[ClipTurn]]:  # fmt: skip
    """The gyro with each clipping's missed turn put back where the fit is taken → (gyro, what was done).

    ``clipped``: (n,) the gyro marked clipped (runs of marked samples are the episodes; the axes reading their own
    range there, the clipped ones); ``bias_rad_s``: (n, 3) the gyro's bias (the causal filter's estimate,
    NaN read as 0); ``bounds``: the runs of samples the windows may use (each episode's are cut at its run's
    ends and at the neighbouring episodes); ``cfg``: :class:`.smoother.SmootherConfig` (its ``clip_turn_*``)."""
    t = np.asarray(t_s, np.float64)
    g_raw = np.asarray(gyr_rad_s, np.float64)
    out = np.array(g_raw, copy=True)
    finite = np.all(np.isfinite(g_raw), 1)
    clip = np.asarray(clipped, bool) & finite
    if not clip.any():
        return out, []
    # each axis's range: its largest reading (a clipped axis reads it; a log's calibration or board rotation can make
    # the plateau differ between axes), for the axes that reach half the largest of them
    top = np.max(np.abs(g_raw[finite]), 0)
    rng = float(np.max(top))
    # an episode is a run of marked samples; the excess goes on the axes that read their range there (a sample marked
    # for another reason — a DataFlash log's unhealthy gyro, an average of clipped and unclipped readings — has none)
    axis_clip = clip[:, None] & (np.abs(g_raw) >= 0.98 * top[None, :]) & (top >= 0.5 * rng)[None, :]
    sgn = np.ascontiguousarray(np.sign(g_raw) * axis_clip)
    acc = np.ascontiguousarray(np.nan_to_num(np.asarray(acc_m_s2, np.float64)))
    turns = []
    for run in bounds:
        lo0, hi0 = run.start, run.stop
        eps = clip_episodes(t[lo0:hi0], clip[lo0:hi0], cfg.clip_turn_merge_s)
        eps = [(a + lo0, b + lo0) for a, b in eps]
        for j, (a, b) in enumerate(eps):
            lo = eps[j - 1][1] if j else lo0
            hi = eps[j + 1][0] if j + 1 < len(eps) else hi0
            lo = max(lo, int(np.searchsorted(t, t[a] - cfg.clip_turn_window_s, "left")))
            hi = min(hi, int(np.searchsorted(t, t[b - 1] + cfg.clip_turn_window_s, "right")))
            if a - lo < 2 or hi - b < 2 or t[a - 1] - t[lo] < cfg.clip_turn_min_window_s or \
                    t[hi - 1] - t[b] < cfg.clip_turn_min_window_s:  # fmt: skip
                turns.append(ClipTurn(a, b, float(t[a]), (0.0, 0.0, 0.0), math.nan, math.nan, False,
                                      f"less than {cfg.clip_turn_min_window_s:g} s without clipping on a side"))
                continue
            if not axis_clip[a:b].any():
                turns.append(ClipTurn(a, b, float(t[a]), (0.0, 0.0, 0.0), math.nan, math.nan, False,
                                      "no axis at the range"))
                continue
            turns.append(_fit_one(t, g_raw, acc, sgn, bias_rad_s, a, b, lo, hi, rng, cfg))
            if turns[-1].accepted:
                out[a:b] += np.asarray(turns[-1].excess_rad_s)[None, :] * sgn[a:b]
    return out, turns


def _fit_one(t, g_raw, acc, sgn, bias_rad_s, a, b, lo, hi, rng, cfg) -> ClipTurn:
    """The excess of episode [a, b) from the windows [lo, a) and [b, hi)."""
    b0 = np.nan_to_num(np.asarray(bias_rad_s, np.float64)[a])
    sl = slice(lo, hi)
    g = np.ascontiguousarray(np.nan_to_num(g_raw[sl] - b0))  # a hole (non-finite sample) turns nothing
    dt = _steps(t[sl])
    s, A, B = np.ascontiguousarray(sgn[sl]), a - lo, b - lo
    ac = acc[sl]
    pre = np.array(_mean_force(g, ac, dt, 0, A, True))  # in the frame of the body at a
    post = np.array(_mean_force(g, ac, dt, B, hi - lo, False))  # in the frame of the body at b

    top = cfg.clip_turn_max_excess * rng
    axes = [k for k in range(3) if np.any(s[A:B, k] != 0)]
    pre, post = np.ascontiguousarray(pre), np.ascontiguousarray(post)
    # a grid over the clipped axes together (several axes: the turn they missed is one rotation, and axis by axis a
    # search can settle on another that gravity cannot tell apart), then a finer one per axis around the best, twice
    side = {1: 101, 2: 41, 3: 21}[len(axes)]
    mesh = np.meshgrid(*[np.linspace(0.0, top, side)] * len(axes), indexing="ij")
    cand = np.zeros((mesh[0].size, 3))
    for j, k in enumerate(axes):
        cand[:, k] = mesh[j].ravel()
    vals = _angle_grid(g, s, dt, A, B, pre, post, cand)
    r0 = float(vals[0])  # the first candidate: no excess
    i = int(np.argmin(vals))
    e, best = cand[i].copy(), float(vals[i])
    step = top / (side - 1)
    for _ in range(2):
        for k in axes:
            fine = np.linspace(max(0.0, e[k] - step), min(top, e[k] + step), 41)
            cand = np.tile(e, (len(fine), 1))
            cand[:, k] = fine
            vals = _angle_grid(g, s, dt, A, B, pre, post, cand)
            i = int(np.argmin(vals))
            if vals[i] < best:
                e[k], best = fine[i], float(vals[i])
        step /= 10.0
    before, after = math.degrees(r0), math.degrees(best)
    ok = after <= cfg.clip_turn_accept_ratio * before and before - after >= cfg.clip_turn_min_gain_deg
    return ClipTurn(a, b, float(t[a]), tuple(float(v) for v in e) if ok else (0.0, 0.0, 0.0), before, after, bool(ok))


def describe_clip_turns(turns: list[ClipTurn]) -> str:
    """A clause for the smoothing's line: where the clipped gyro's turn was put back."""
    took = [c for c in turns if c.accepted]
    if not turns:
        return ""
    head = f"the clipped gyro's missed turn read from gravity on {len(took)} of {len(turns)} clipping(s)"
    if took:
        c = max(took, key=lambda c: float(np.max(np.abs(c.excess_rad_s))))
        head += (f" (largest: {math.degrees(float(np.max(np.abs(c.excess_rad_s)))):.0f} °/s past the range at "
                 f"t = {c.t_s:.1f} s; gravity before and after it {c.angle_before_deg:.0f}° → "
                 f"{c.angle_after_deg:.0f}° apart)")
    return head
