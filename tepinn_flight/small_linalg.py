"""Small dense matrices in compiled per-sample loops (numba): the covariance algebra of the older
fusion's bias states and of the baseline EKF. Loops, not BLAS: numba's ``@`` would need scipy's BLAS,
and for 2×2 … 6×6 matrices the call costs more than the arithmetic.

In place, on preallocated 2-D float64 C arrays whose shapes give the sizes: no array is allocated
and no array expression is compiled, and each function is compiled once, for one signature (sizes
passed as constants would compile one version per size), so the loops that call them compile in
seconds rather than tens of seconds (``benchmarks/jit_compile.py``). Every sum runs in the order of the
textbook formula, ``Σ_l`` from ``l = 0`` upward, starting from 0.
"""

from __future__ import annotations

from numba import njit


@njit(cache=True)
def mul(A, B, C):
    """C = A @ B (C must not share memory with A or B)."""
    n, k, m = A.shape[0], A.shape[1], B.shape[1]
    for i in range(n):
        for j in range(m):
            acc = 0.0
            for l in range(k):
                acc += A[i, l] * B[l, j]
            C[i, j] = acc


@njit(cache=True)
def mul_bt(A, B, C):
    """C = A @ Bᵀ (C must not share memory with A or B)."""
    n, k, m = A.shape[0], A.shape[1], B.shape[0]
    for i in range(n):
        for j in range(m):
            acc = 0.0
            for l in range(k):
                acc += A[i, l] * B[j, l]
            C[i, j] = acc


@njit(cache=True)
def sub_at_bt(P, A, B):
    """P ← P − Aᵀ Bᵀ in place (A k×n, B m×k, P n×m; P must not share memory with A or B)."""
    n, k, m = A.shape[1], A.shape[0], B.shape[0]
    for i in range(n):
        for j in range(m):
            acc = 0.0
            for l in range(k):
                acc += A[l, i] * B[j, l]
            P[i, j] = P[i, j] - acc


@njit(cache=True)
def symmetrize(P):
    """P ← ½ (P + Pᵀ), in place."""
    n = P.shape[0]
    for i in range(n):
        for j in range(i, n):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v


@njit(cache=True)
def solve_in_place(A, X):
    """X ← A⁻¹ X for a small symmetric positive definite A (Gauss-Jordan with partial pivoting);
    A is overwritten."""
    n, m = A.shape[0], X.shape[1]
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
