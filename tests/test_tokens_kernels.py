"""The tokens' compiled per-token means (``model/tokens_kernels.py``) give the bits of the numpy form they replaced
(session 42; kept here as the reference): on a real BROAD trial and a real PX4 log, and on samples with NaN, ±inf
and −0.0, empty tokens and several segments."""

from __future__ import annotations

import numpy as np
import pytest

from tepinn_flight.model import tokens
from tepinn_flight.model.tokens_kernels import token_means

from .conftest import broad_trial


def means_numpy(k: np.ndarray, x: np.ndarray, n_tok: int) -> np.ndarray:
    """``_tokenize_segment``'s means before session 42, verbatim."""
    out = np.empty((n_tok, x.shape[1]))
    for c in range(x.shape[1]):
        out[:, c] = np.bincount(k, weights=np.nan_to_num(x[:, c]), minlength=n_tok)
    good = np.stack([np.bincount(k, weights=np.isfinite(x[:, c]).astype(float), minlength=n_tok)
                     for c in range(x.shape[1])], 1)  # fmt: skip
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(good > 0, out / np.maximum(good, 1), np.nan)


def same_bits(a, b) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_the_means_are_the_numpy_formula_bit_for_bit_on_awkward_samples():
    rng = np.random.default_rng(0)
    n = 20_000
    k = np.sort(rng.integers(0, 3000, n))  # token per sample, some tokens empty
    x = rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-6, 6, size=(n, 3))  # magnitudes that round differently
    x[rng.integers(0, n, 40), rng.integers(0, 3, 40)] = np.nan
    x[rng.integers(0, n, 10), 0] = np.inf
    x[rng.integers(0, n, 10), 2] = -np.inf
    x[rng.integers(0, n, 30), 1] = -0.0
    x[k == k[500]] = np.nan  # a token with no finite sample
    for arr in (x, np.asfortranarray(x), x[:, :2], x.astype(np.float32)):
        want = means_numpy(k, np.asarray(arr, np.float64), 3000)
        assert same_bits(token_means(k, np.asarray(arr, np.float64), 3000), want)
    assert np.isnan(want[k[500]]).all() and np.isnan(want).any(axis=1).sum() >= 3  # empty tokens and the all-NaN one


@pytest.mark.parametrize("log", ["broad", "px4"])
def test_tokenize_gives_the_numpy_formulas_tokens_on_real_records(log, monkeypatch):
    """The whole tokenization of a real record (its read-only column-ordered arrays, with a second segment spliced in
    behind a time gap) equals the one with the numpy means, every array bit for bit."""
    from tepinn_flight.ingest import ingest_log
    from tests.conftest import real_log

    rec = ingest_log(broad_trial("broad_06_*.hdf5") if log == "broad" else real_log("pyulog_sample_px4_events.ulg"))
    seg = rec.segment.copy()
    seg[len(seg) // 2 :] += 1
    args = (rec.t_s, seg, rec.gyr_rad_s, rec.acc_m_s2, rec.mag_ut, 25.0, rec.clipped)
    got = tokens.tokenize(*args)
    monkeypatch.setattr(tokens, "token_means", lambda k, x, n: means_numpy(k, np.asarray(x), n))
    want = tokens.tokenize(*args)
    for name in ("t_s", "dt_s", "gyr", "acc", "mag", "count", "clip", "last_index", "segment_start", "segment_len"):
        assert same_bits(getattr(got, name), getattr(want, name)), name
    assert len(got.segment_len) == 2
