"""The live estimator's compiled push (``streaming_kernels.live_sample``, session 51) against the same push made of
the calls one by one from Python (``StreamingEstimator.compiled = False``, the path every push took before): the
same estimates to the bit — attitude, σ and bias — on jittered stamps with holes, a bridged dropout and a new segment,
a gyro that saturates (its samples queued for the saturation term; the older fusion's tilt while the saturation gate
holds), σ's aircraft term, the network's gates forced open, prepare() between samples and the magnetometer (9-D, a
shared BROAD trial)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tepinn_flight.model import streaming
from tepinn_flight.model.checkpoint import default_model_path, load_model
from tepinn_flight.model.streaming import StreamingEstimator
from tepinn_flight.model.synthetic import synthetic_record
from tests.conftest import broad_trial


def _stream(model, cfg, rec, compiled: bool, vehicle=None, prepare=False, mag=False):
    live = StreamingEstimator(model, cfg, vehicle=vehicle)
    live.compiled = compiled
    out = np.full((len(rec), 9), np.nan)
    t, g, a, m = rec.t_s, rec.gyr_rad_s, rec.acc_m_s2, rec.mag_ut
    cl, gc = rec.clipped, rec.gyr_clipped
    for i in range(len(t)):
        e = live.push(t[i], g[i], a[i], m[i] if mag else None, bool(cl[i]), bool(gc[i]))
        q = e.q_nb_wxyz if e.q_nb_wxyz is not None else (np.nan,) * 4
        out[i] = (*q, e.sigma_rad, *e.gyr_bias_rad_s, e.model_ran)
        if prepare:
            live.prepare()
    return out


def _counting(monkeypatch) -> list:
    calls = [0]
    kernel = streaming.live_sample

    def counted(*args):
        calls[0] += 1
        return kernel(*args)

    monkeypatch.setattr(streaming, "live_sample", counted)
    return calls


def _flight(seed: int, rate_hz: float):
    """A synthetic flight with jittered stamps, a 0.06-s dropout (bridged), a 2-s gap (a new segment), 20 non-finite
    samples and the gyro marked at its range wherever |ω| exceeds its 97th percentile. (16 s: 10 s in the first
    segment, the dropout 3.2 s into its network windows, and 6 s in the second, its first window full after 3.2 s)"""
    rec = synthetic_record(seed=seed, duration_s=16.0, rate_hz=rate_hz, max_rate_rad_s=6.0)
    d = rec.data.copy()
    rng = np.random.default_rng(seed)
    n = len(d)
    t = d["t_s"].to_numpy() + rng.uniform(-0.3, 0.3, n) / rate_hz
    t[int(0.4 * n):] += 0.06
    t[int(0.625 * n):] += 2.0
    d["t_s"] = t
    w = np.linalg.norm(rec.gyr_rad_s, axis=1)
    hot = w > np.quantile(w, 0.97)
    d["clipped"] = hot
    d["gyr_clipped"] = hot
    d.loc[rng.choice(n, 20, replace=False), "acc_x_m_s2"] = np.nan
    return type(rec)(d, dict(rec.meta))


@pytest.mark.parametrize("rate_hz", [50.0, 400.0])
def test_the_compiled_push_gives_the_python_pushs_estimates(rate_hz, monkeypatch):
    model, shipped, _ = load_model(default_model_path())
    opened = dataclasses.replace(shipped, speed_lo_m_s=0.0, speed_hi_m_s=1e-3, smoother=False)
    rec = _flight(7, rate_hz)
    assert rec.gyr_clipped.sum() > 10
    for cfg, vehicle, prepare in ((shipped, None, False), (shipped, "quadrotor", True), (opened, "fixedwing", False)):
        ref = _stream(model, cfg, rec, compiled=False, vehicle=vehicle, prepare=prepare)
        calls = _counting(monkeypatch)
        got = _stream(model, cfg, rec, compiled=True, vehicle=vehicle, prepare=prepare)
        monkeypatch.undo()
        assert np.isfinite(ref[:, 0]).sum() > 0.7 * len(rec)
        np.testing.assert_array_equal(got, ref)  # NaN where NaN, the same bits elsewhere
        # the compiled push made most of them (at 50 Hz a token holds two samples, and a push whose window applies
        # is Python's)
        assert calls[0] > (0.8 if rate_hz > 100 else 0.45) * len(rec)


def test_the_compiled_push_gives_the_python_pushs_estimates_in_9d(monkeypatch):
    path = broad_trial("broad_32_*.hdf5")
    from tepinn_flight.ingest import load_record
    from tepinn_flight.record import FlightRecord

    rec = load_record(path)
    rec = FlightRecord(rec.data.iloc[: int(25 * 286)].reset_index(drop=True), dict(rec.meta))
    model, shipped, _ = load_model(default_model_path())
    cfg = dataclasses.replace(shipped, mode="9d")
    ref = _stream(model, cfg, rec, compiled=False, mag=True)
    calls = _counting(monkeypatch)
    got = _stream(model, cfg, rec, compiled=True, mag=True)
    np.testing.assert_array_equal(got, ref)
    assert calls[0] > 0.8 * len(rec)
    six = _stream(model, shipped, rec, compiled=True)  # the magnetometer did change the estimate (its heading)
    assert not np.array_equal(six[:, :4], got[:, :4], equal_nan=True)
