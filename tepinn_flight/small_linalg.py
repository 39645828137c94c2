"""Small dense matrices in compiled per-sample loops (numba): the covariance algebra of the older
fusion's bias states and of the baseline EKF. Loops, not BLAS: numba's ``@`` would need scipy's BLAS,
and for 2×2 … 6×6 matrices the call costs more than the arithmetic."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def mm(A, B):
    """A @ B (2-D) by loops, in the order of the textbook sum."""
    n, k, m = A.shape[0], A.shape[1], B.shape[1]
    C = np.zeros((n, m))
    for i in range(n):
        for j in range(m):
            acc = 0.0
            for l in range(k):
                acc += A[i, l] * B[l, j]
            C[i, j] = acc
    return C


@njit(cache=True)
def solve(S, B):
    """S⁻¹ B for a small symmetric positive definite S (Gauss-Jordan with partial pivoting)."""
    n, m = S.shape[0], B.shape[1]
    A = S.copy()
    X = B.copy()
    for c in range(n):
        piv = c
        for r in range(c + 1, n):
            if abs(A[r, c]) > abs(A[piv, c]):
                piv = r
        if piv != c:
            for j in range(n):
                A[c, j], A[piv, j] = A[piv, j], A[c, j]
            for j in range(m):
                X[c, j], X[piv, j] = X[piv, j], X[c, j]
        d = A[c, c]
        for r in range(n):
            if r != c:
                f = A[r, c] / d
                for j in range(n):
                    A[r, j] -= f * A[c, j]
                for j in range(m):
                    X[r, j] -= f * X[c, j]
    for r in range(n):
        for j in range(m):
            X[r, j] /= A[r, r]
    return X
