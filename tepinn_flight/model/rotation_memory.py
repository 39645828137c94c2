"""The rotation a sample's tilt has recently been carried through: σ's rotation term of a smoothed sample (rule 40).

A gyro's scale and misalignment errors turn the integrated attitude by a fraction of the rotation it integrates;
the accelerometer pulls that back over the filter's time constant, and the offline smoothing, which runs the filter
both ways, from either side. So the tilt error a smoothed sample can still hold grows with the rotation around it
in time: ``R(t_i) = (F_i + B_i) / 2``, ``F_i = Σ_{j ≤ i} |ω_j|·Δt_j·exp(−(c_i − c_j)/τ)`` and ``B`` its backward
twin (``Δt_j`` the step ending at ``j`` going forward, the step starting at ``j`` going backward), per segment, where
the clock ``c`` counts the steps as taken: each at most ``MAX_STEP_S`` (a logging gap is neither rotation seen nor
time to forget the rotation before it: across a 5-s gap the memory keeps e^(−0.1/τ) of it, not e^(−5/τ)), a step
back in time as none. Non-finite rates count as no rotation; a non-finite time stamp makes its segment's R NaN (a
record's checks refuse one).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..record import segment_slices

#: the longest step counted (s): a gap inside a segment is not rotation seen
MAX_STEP_S = 0.1


@njit(cache=True)
def _decayed_both_ways(t, w, tau, max_step, out):
    """``out`` = (forward + backward) / 2 of the decayed sums of ``w·Δt`` over ``t`` (one segment)."""
    n = len(t)
    acc = 0.0
    for i in range(n):
        dt = 0.0 if i == 0 else min(max(t[i] - t[i - 1], 0.0), max_step)
        acc = acc * math.exp(-dt / tau) + w[i] * dt
        out[i] = 0.5 * acc
    acc = 0.0
    for i in range(n - 1, -1, -1):
        dt = 0.0 if i == n - 1 else min(max(t[i + 1] - t[i], 0.0), max_step)
        acc = acc * math.exp(-dt / tau) + w[i] * dt
        out[i] += 0.5 * acc


def rotation_memory(t_s, gyr_rad_s, segment, tau_s: float) -> np.ndarray:
    """(n,) R in rad (module docstring) for rates ``gyr_rad_s`` (n, 3) at ``t_s`` within each segment."""
    t = np.array(t_s, np.float64)  # a writable copy: a record's read-only column would compile a second signature
    rate = np.linalg.norm(np.asarray(gyr_rad_s, np.float64), axis=1)
    rate = np.where(np.isfinite(rate), rate, 0.0)
    out = np.zeros(len(t))
    for s in segment_slices(np.asarray(segment)):
        seg_out = np.empty(s.stop - s.start)
        _decayed_both_ways(t[s], np.ascontiguousarray(rate[s]), float(tau_s), MAX_STEP_S, seg_out)
        out[s] = seg_out
    return out
