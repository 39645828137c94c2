"""The tokens' per-token means, compiled with numba (one signature).

:func:`.tokens.tokenize` made each token's mean from two ``np.bincount`` runs per column (the values with
``nan_to_num``, and their finiteness) and their temporaries: 0.17–0.2 s of a one-hour log, before the network's
first window (session 42). :func:`token_means` is the same arithmetic in the same order (bincount adds each sample's
weight to its token's sum in the samples' order, from 0), so the same bits (``tests/test_tokens_kernels.py`` against
the numpy form, kept there as the reference). Its explicit signature takes any float64 rows (numba converts the
layout and writability), so callers need no conversion of their own.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: ``np.nan_to_num``'s value for +inf (−inf: its negative)
_BIG = float(np.finfo(np.float64).max)


@njit("float64[:, ::1](int64[::1], Array(float64, 2, 'A', readonly=True), int64)", cache=True)
def token_means(k, x, n_tok):
    """(n_tok, c): per token ``k[i]``, the sum of ``nan_to_num(x[i])`` over its samples divided by how many of them
    are finite; NaN where none is (``.tokens._tokenize_segment``'s means)."""
    n, c = x.shape
    out = np.zeros((n_tok, c))
    good = np.zeros((n_tok, c))
    for i in range(n):
        b = k[i]
        for j in range(c):
            v = x[i, j]
            if math.isfinite(v):
                out[b, j] += v
                good[b, j] += 1.0
            elif v != v:  # NaN: nan_to_num's 0
                out[b, j] += 0.0
            else:
                out[b, j] += _BIG if v > 0 else -_BIG
    for b in range(n_tok):
        for j in range(c):
            out[b, j] = out[b, j] / max(good[b, j], 1.0) if good[b, j] > 0 else np.nan
    return out
