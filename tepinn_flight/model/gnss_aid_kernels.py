"""The GNSS-aided tilt's whole-record arithmetic, compiled: centred window sums and rows of vector
rotations, each the numpy formula's own operations in its order, so the results are the same bits
(``tests/test_gnss_aid_kernels.py``: against the numpy form they replaced and :func:`.quat.quat_rotate`).

On a one-hour 400 Hz record the numpy forms made ~20 temporaries of 1.44 M rows per pass (gathers,
stacks, ``cumsum`` copies), a quarter of an aided busy flight's offline time
(``benchmarks/PROFILE.md``, session 21); these make one output each.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..quat_scalar import qrot


@njit(cache=True)
def window_sums(z, row_bad, k):
    """Centred sums over ``k`` rows (fewer at the ends) of each column of ``z`` (n, m), as
    ``cs[hi] − cs[lo]`` of the running sum ``cs`` (``cs[0] = 0``, then numpy's ``cumsum`` order), with
    ``lo = clip(i − k//2, 0, n)`` and ``hi = clip(i − k//2 + k, 0, n)`` → (sums (n, m), the window's
    length (n,) as float, the number of ``row_bad`` rows in the window (n,))."""
    n, m = z.shape
    cs = np.empty((n + 1, m))
    cb = np.empty(n + 1, np.int64)
    cs[0, :] = 0.0
    cb[0] = 0
    for j in range(m):
        if n:
            cs[1, j] = z[0, j]  # numpy's cumsum starts from the first value itself (a −0.0 stays −0.0)
        for i in range(1, n):
            cs[i + 1, j] = cs[i, j] + z[i, j]
    for i in range(n):
        cb[i + 1] = cb[i] + (1 if row_bad[i] else 0)
    sums = np.empty((n, m))
    cnt = np.empty(n)
    nbad = np.empty(n, np.int64)
    h = k // 2
    for i in range(n):
        lo = min(max(i - h, 0), n)
        hi = min(max(i - h + k, 0), n)
        for j in range(m):
            sums[i, j] = cs[hi, j] - cs[lo, j]
        cnt[i] = hi - lo
        nbad[i] = cb[hi] - cb[lo]
    return sums, cnt, nbad


@njit(cache=True)
def rotate_rows(q, v):
    """(n, 3): each row of ``v`` turned by the unit quaternion in that row of ``q`` (n, 4)
    (:func:`.quat_scalar.qrot`, :func:`.quat.quat_rotate`'s operations)."""
    n = q.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        out[i, 0], out[i, 1], out[i, 2] = qrot(q[i, 0], q[i, 1], q[i, 2], q[i, 3], v[i, 0], v[i, 1], v[i, 2])
    return out
