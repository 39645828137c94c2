"""``StreamingEstimator.prepare`` (session 46): the network's window run between samples gives the same estimates,
to the bit, as the window run inside the next sample's push — on a regular stream, on stamps that jitter by up to
0.45 periods each (the early close undone), across a gap bridged and one that starts a new segment, with the vehicle's
class learnt between a prepare and the next push, and with the gates forced open (every window's output used)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tepinn_flight.model.checkpoint import default_model_path, load_model
from tepinn_flight.model.streaming import StreamingEstimator
from tepinn_flight.model.synthetic import synthetic_record


def _stream(model, cfg, t, gyr, acc, prepare: bool, vehicle_at: int | None = None):
    """Every estimate's (q, σ, bias) row, and the network runs in push and in prepare."""
    live = StreamingEstimator(model, cfg)
    out = np.full((len(t), 8), np.nan)
    in_push = in_prepare = 0
    for i in range(len(t)):
        if vehicle_at is not None and i == vehicle_at:
            live.set_vehicle("quadrotor")
        e = live.push(t[i], gyr[i], acc[i])
        in_push += e.model_ran
        if e.q_nb_wxyz is not None:
            out[i] = (*e.q_nb_wxyz, e.sigma_rad, *e.gyr_bias_rad_s)
        if prepare:
            in_prepare += live.prepare()[0]
    return out, in_push, in_prepare


def _times(n: int, rate_hz: float, jitter: float, rng) -> np.ndarray:
    """Stamps at ``rate_hz`` with uniform jitter of ± ``jitter`` periods, a 0.06-s dropout at 40 % (bridged where it
    is over 2.5 periods) and a 2-s gap at 75 % (a new segment)."""
    t = np.arange(n) / rate_hz + rng.uniform(-jitter, jitter, n) / rate_hz
    t[int(0.4 * n):] += 0.06
    t[int(0.75 * n):] += 2.0
    assert np.all(np.diff(t) > 0)
    return t


@pytest.mark.parametrize("rate_hz,jitter", [(100.0, 0.0), (50.0, 0.45), (400.0, 0.45)])
def test_prepare_gives_the_same_estimates_as_the_network_run_in_push(rate_hz, jitter):
    model, shipped, _ = load_model(default_model_path())
    # the flight-speed gate forced open on every window: each window's output moves the estimate
    opened = dataclasses.replace(shipped, speed_lo_m_s=0.0, speed_hi_m_s=1e-3, smoother=False)
    rec = synthetic_record(seed=5, duration_s=14.0, rate_hz=rate_hz)
    rng = np.random.default_rng(1)
    t = _times(len(rec), rate_hz, jitter, rng)
    gyr, acc = rec.gyr_rad_s, rec.acc_m_s2
    for cfg, vehicle_at in ((shipped, None), (opened, None), (opened, len(rec) // 3)):
        ref, runs_ref, _ = _stream(model, cfg, t, gyr, acc, prepare=False, vehicle_at=vehicle_at)
        got, runs_push, runs_prep = _stream(model, cfg, t, gyr, acc, prepare=True, vehicle_at=vehicle_at)
        assert np.isfinite(ref[:, 0]).sum() > 0.8 * len(rec)
        np.testing.assert_array_equal(got, ref)  # NaN where NaN, the same bits elsewhere
        assert runs_prep > 0.3 * runs_ref  # many windows ran between samples ...
        if jitter == 0.0:
            assert runs_push == 0  # ... on a regular stream, all of them
        else:
            assert runs_push + runs_prep >= runs_ref  # early closes undone ran again in a push


def test_a_sample_inside_the_token_undoes_the_early_close():
    """At 60 Hz a 25 Hz token holds 2.4 periods: after some tokens' last regular sample prepare closes the token (the
    next regular one, 1 period later, opens a new one). An extra sample 0.3 periods later still belongs to the token:
    it finds the state as before the early close, and every estimate stays the twin's, which never prepares."""
    model, cfg, _ = load_model(default_model_path())
    rate = 60.0
    rec = synthetic_record(seed=2, duration_s=8.0, rate_hz=rate)
    live, twin = StreamingEstimator(model, cfg), StreamingEstimator(model, cfg)
    closed = undone = 0
    for i in range(len(rec)):
        t, g, a = rec.t_s[i], rec.gyr_rad_s[i], rec.acc_m_s2[i]
        assert live.push(t, g, a).q_nb_wxyz == twin.push(t, g, a).q_nb_wxyz
        live.prepare()
        if live.early is None:
            continue
        closed += 1
        t_in = t + 0.3 / rate
        if int(np.ceil((t_in - live.t0) / live.delta - 1e-6)) == live.k:  # inside the token prepare closed
            n_before = live.early[1][1]
            assert live.push(t_in, g, a).q_nb_wxyz == twin.push(t_in, g, a).q_nb_wxyz
            assert live.early is None and live.win.n == n_before
            undone += 1
    assert closed > 50 and undone > 20
