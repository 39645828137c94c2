"""The GNSS aid's compiled arithmetic (``model/gnss_aid_kernels.py``) gives numpy's bits: the centred
average against the numpy formula it replaced (kept here as the reference), the row rotation against
``quat.quat_rotate`` and, independently, scipy's ``Rotation``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tepinn_flight.model.gnss_aid import _centred_mean
from tepinn_flight.model.gnss_aid_kernels import rotate_rows, window_sums
from tepinn_flight.quat import quat_rotate


def centred_mean_numpy(x: np.ndarray, k: int) -> np.ndarray:
    """The numpy form used until session 21 (cumulative sums, gathered ends, NaN where a window holds one)."""
    n = len(x)
    bad = ~np.isfinite(x)
    z = np.where(bad, 0.0, x)
    cs = np.concatenate([np.zeros((1,) + z.shape[1:]), np.cumsum(z, axis=0)])
    cb = np.concatenate([[0], np.cumsum(bad.reshape(n, -1).any(axis=1))])
    i = np.arange(n)
    lo = np.clip(i - k // 2, 0, n)
    hi = np.clip(i - k // 2 + k, 0, n)
    cnt = (hi - lo).reshape((n,) + (1,) * (x.ndim - 1))
    out = (cs[hi] - cs[lo]) / cnt
    out[(cb[hi] - cb[lo]) > 0] = np.nan
    return out


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _inputs(rng: np.random.Generator, n: int = 5000):
    real = rng.normal(size=n) * 10.0 ** rng.integers(-3, 4, size=n)  # magnitudes that round differently
    real[[3, 777, 778, 4000]] = [np.nan, np.inf, np.nan, -np.inf]
    real[0] = -0.0
    pair = rng.normal(size=(n, 2))
    pair[[10, 2500], [1, 0]] = np.nan  # one column of a row: the row is NaN, the other column still sums
    cplx = rng.normal(size=n) + 1j * rng.normal(size=n)
    cplx[[50, 51]] = [complex(1.0, np.nan), complex(np.inf, 2.0)]
    flags = (rng.random(n) < 0.3).astype(float)
    return real, pair, cplx, flags


@pytest.mark.parametrize("k", [1, 2, 7, 400, 12000])
def test_centred_mean_is_the_numpy_formula_bit_for_bit(k):
    for x in _inputs(np.random.default_rng(k)):
        assert same_bits(_centred_mean(x, k), centred_mean_numpy(x, k)), (x.dtype, x.shape)


def test_window_sums_closed_form():
    z = np.arange(1.0, 7.0).reshape(6, 1)  # 1..6
    bad = np.array([False, False, True, False, False, False])
    sums, cnt, nbad = window_sums(z, bad, 3)  # window i-1 .. i+1, cut at the ends
    assert sums[:, 0].tolist() == [3.0, 6.0, 9.0, 12.0, 15.0, 11.0]
    assert cnt.tolist() == [2.0, 3.0, 3.0, 3.0, 3.0, 2.0]
    assert nbad.tolist() == [0, 1, 1, 1, 0, 0]
    assert _centred_mean(np.array([]), 3).shape == (0,)


def test_rotate_rows_is_quat_rotate_bit_for_bit_and_scipy_to_round_off():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(20000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    v = rng.normal(size=(20000, 3)) * 9.81
    out = rotate_rows(q, v)
    assert same_bits(out, quat_rotate(q, v))
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]]).apply(v)  # scipy: scalar-last
    assert np.max(np.abs(out - ref)) < 1e-12 * 9.81 * 10
