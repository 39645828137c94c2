"""The in-place small-matrix helpers of the compiled loops (:mod:`tepinn_flight.small_linalg`)
against numpy's ``@`` and ``np.linalg.solve`` on random matrices of the sizes the fusion and the
EKF use (2×6 … 6×6), including the leading-block shapes."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tepinn_flight.small_linalg import mul, mul_bt, solve_in_place, sub_at_bt, symmetrize

SIZES = st.sampled_from([(2, 6, 6), (3, 6, 6), (6, 6, 6), (6, 3, 3), (3, 3, 3), (6, 6, 3)])


@settings(max_examples=60, deadline=None)
@given(SIZES, st.integers(0, 2**32 - 1))
def test_products_equal_numpy(nkm, seed):
    n, k, m = nkm
    rng = np.random.default_rng(seed)
    A, B, Bt = rng.normal(size=(n, k)), rng.normal(size=(k, m)), rng.normal(size=(m, k))
    C = np.full((n, m), np.nan)
    mul(A, B, C)
    np.testing.assert_allclose(C, A @ B, rtol=0, atol=1e-12)
    mul_bt(A, Bt, C)
    np.testing.assert_allclose(C, A @ Bt.T, rtol=0, atol=1e-12)
    P0, K, H = rng.normal(size=(k, m)), rng.normal(size=(n, k)), rng.normal(size=(m, n))
    P = P0.copy()
    sub_at_bt(P, K, H)  # P (k×m) − Kᵀ Hᵀ
    np.testing.assert_allclose(P, P0 - K.T @ H.T, rtol=0, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.sampled_from([2, 3, 6]), st.integers(0, 2**32 - 1))
def test_solve_and_symmetrize_equal_numpy(n, seed):
    rng = np.random.default_rng(seed)
    M = rng.normal(size=(n, n))
    S = M @ M.T + 0.1 * np.eye(n)  # symmetric positive definite, as an innovation covariance
    X = rng.normal(size=(n, 6))
    A, got = S.copy(), X.copy()
    solve_in_place(A, got)
    np.testing.assert_allclose(got, np.linalg.solve(S, X), rtol=1e-9, atol=1e-12)
    P = rng.normal(size=(n, n))
    want = 0.5 * (P + P.T)
    symmetrize(P)
    np.testing.assert_array_equal(P, want)


def test_solve_pivots_on_a_zero_leading_entry():
    S = np.array([[0.0, 2.0], [2.0, 1.0]])  # no pivoting would divide by zero
    X = np.array([[1.0, 2.0], [3.0, 4.0]])
    want = np.linalg.solve(S, X)
    solve_in_place(S, X)
    np.testing.assert_allclose(X, want, rtol=0, atol=1e-14)
