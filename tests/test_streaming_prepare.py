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


QUIET_BY_SPEED = dict(quiet_speed_m_s=1.7, quiet_after_blocks=1, quiet_memory_blocks=2, speed_lo_m_s=1.6,
                      speed_hi_m_s=2.1, smoother=False)  # the synthetic flight's |v̂| crosses 1.7 m/s: blocks turn busy
# and quiet by the network's speed (the block speeds and the speeds of the last blocks decide), and the speed gate opens


def _state(e: StreamingEstimator) -> tuple:
    """What the windows' bookkeeping holds: what an undone early close must give back."""
    return (e.k, e.n_windows, e.busy, e.block_speed, tuple(e.speeds), e.feedback, repr(e.last_means), e.win.n,
            e.win.buf.tobytes())  # fmt: skip


@pytest.mark.parametrize("rate_hz,settings", [(60.0, {}), (90.0, QUIET_BY_SPEED)])
def test_a_sample_inside_the_token_undoes_the_early_close(rate_hz, settings):
    """At 60 or 90 Hz a 25 Hz token holds 2.4 or 3.6 periods: after some tokens' last regular sample prepare closes the
    token (the next regular one, 1 period later, opens a new one). An extra sample 0.3 periods later, on about half of
    those, still belongs to the token: it finds the state as before the early close — compared field by field with a
    twin that never prepares —, and every estimate stays the twin's. The vehicle's class, told to both every 400
    samples, undoes an early close too."""
    model, cfg, _ = load_model(default_model_path())
    cfg = dataclasses.replace(cfg, **settings)
    rec = synthetic_record(seed=3 if settings else 2, duration_s=40.0 if settings else 8.0, rate_hz=rate_hz)
    rng = np.random.default_rng(4)
    live, twin = StreamingEstimator(model, cfg), StreamingEstimator(model, cfg)
    closed = undone = busy_changes = 0
    busy_prev = None
    ts, gyr, acc = rec.t_s, rec.gyr_rad_s, rec.acc_m_s2  # (taken once: each property makes a new array, ~0.3 ms)
    for i in range(len(rec)):
        t, g, a = ts[i], gyr[i], acc[i]
        assert live.push(t, g, a).q_nb_wxyz == twin.push(t, g, a).q_nb_wxyz
        assert _state(live) == _state(twin)
        busy_changes += twin.busy != busy_prev
        busy_prev = twin.busy
        live.prepare()
        if i % 400 == 399:  # the class learnt: it undoes an early close (the window read the class it replaces)
            v = ("quadrotor", None)[(i // 400) % 2]
            live.set_vehicle(v)
            twin.set_vehicle(v)
            assert live.early is None
        if live.early is None:
            continue
        closed += 1
        t_in = t + 0.3 / rate_hz
        if rng.random() < 0.5 and int(np.ceil((t_in - live.t0) / live.delta - 1e-6)) == live.k:  # inside the token
            assert live.push(t_in, g, a).q_nb_wxyz == twin.push(t_in, g, a).q_nb_wxyz
            assert live.early is None and _state(live) == _state(twin)
            undone += 1
    assert closed > 50 and undone > 10
    if settings:
        assert busy_changes > 4  # blocks did turn busy and quiet (the speeds' bookkeeping was exercised)


def _run_worker(make_estimator, records: list[bytes]):
    """``worker_loop`` over ``records`` (one write each, so each is its own batch) → the frames it wrote, as
    (kind, payload) in order. Each record is written only once the worker has called the estimator's ``prepare``
    after the previous one, so each is its own batch however slow or loaded the machine (no timing in the test)."""
    import os

    import tepinn_flight.live.worker as worker

    r_in, w_in = os.pipe()
    r_out, w_out = os.pipe()
    frames = []
    warm, worker.warm_up = worker.warm_up, lambda e: None
    try:
        import threading

        done, ready, batch_done = threading.Event(), threading.Event(), threading.Event()

        def paced():
            est = make_estimator()
            prepare = est.prepare

            def prepare_then_signal():
                try:
                    return prepare()
                finally:
                    batch_done.set()  # the worker is through this batch: the feeder may write the next record

            est.prepare = prepare_then_signal
            return est

        def read_all():
            buf = b""
            while True:
                chunk = os.read(r_out, 1 << 16)
                if not chunk:
                    break
                buf += chunk
                ready.set()  # the worker's first frame is its ready frame: it is now reading samples
            i = 0
            while i < len(buf):
                n, kind = worker.HEADER.unpack_from(buf, i)
                i += worker.HEADER.size
                frames.append((bytes([kind]), buf[i:i + n]))
                i += n
            done.set()

        th = threading.Thread(target=read_all, daemon=True)
        th.start()

        def feed():
            ready.wait(60)  # (the worker compiles and warms up first: records written before would arrive as one batch)
            for rec in records:  # one at a time, as an IMU streams, each its own batch
                batch_done.clear()
                os.write(w_in, rec)
                if not batch_done.wait(60):
                    break  # the worker stopped calling prepare: the counts below fail the test
            os.close(w_in)

        feeder = threading.Thread(target=feed, daemon=True)
        feeder.start()
        assert worker.worker_loop(r_in, w_out, paced, rate_hz=1000.0, max_age_s=1e9) == 0
        feeder.join()
        os.close(w_out)
        done.wait(10)
    finally:
        worker.warm_up = warm
        os.close(r_in)
        os.close(r_out)
    return frames


def test_the_workers_estimates_with_prepare_are_those_of_the_estimator_without_it():
    """The bridge's worker calls prepare after each batch: each estimate it sends is the one a plain push-only run gives,
    and its counters count the network runs made between samples."""
    from tepinn_flight.live.worker import pack_sample, unpack_estimate

    model, cfg, _ = load_model(default_model_path())
    rec = synthetic_record(seed=6, duration_s=5.0, rate_hz=100.0)
    plain = StreamingEstimator(model, cfg)
    ref = {}
    for i in range(len(rec)):
        e = plain.push(rec.t_s[i], rec.gyr_rad_s[i], rec.acc_m_s2[i])
        if e.q_nb_wxyz is not None:
            ref[i] = tuple(e.q_nb_wxyz)
    records = [pack_sample(i, float(rec.t_s[i]), 0.0, tuple(rec.gyr_rad_s[i]), tuple(rec.acc_m_s2[i]), None, 0, None)
               for i in range(len(rec))]  # fmt: skip (arrival 0: max_age_s is infinite here)
    frames = _run_worker(lambda: StreamingEstimator(model, cfg), records)
    sent = [unpack_estimate(p) for k, p in frames if k == b"E"]
    assert len(sent) > 100
    for est, _ in sent:
        assert est["q"] == ref[est["seq"]]  # the same bits
    processed, _, _, errors, model_runs, _, _, steps = sent[-1][1]
    assert errors == 0 and model_runs > 20
    assert steps > processed - model_runs // 2  # most network runs were made between samples, not in a push


def test_an_estimator_whose_prepare_raises_is_reported_reset_and_goes_on():
    from tepinn_flight.live.worker import pack_sample

    class Est:
        t0 = None

        def __init__(self):
            self.resets = 0
            self.calls = 0

        def push(self, t, *a):
            from tepinn_flight.model.streaming import Estimate

            return Estimate(t, (1.0, 0.0, 0.0, 0.0), 0.01, (0.0, 0.0, 0.0), False, 1e-6)

        def prepare(self):
            self.calls += 1
            if self.calls == 2:
                raise RuntimeError("the network's window failed")
            return False, 0.0

        def reset(self, sensor=False):
            self.resets += 1

    est = Est()
    import time

    now = time.monotonic()
    records = [pack_sample(i, 0.01 * i, now, (0.0, 0.0, 0.0), (0.0, 0.0, -9.81), None, 0, None) for i in range(4)]
    frames = _run_worker(lambda: est, records)
    errs = [p.decode() for k, p in frames if k == b"X"]
    assert errs == ["estimator error #1: RuntimeError: the network's window failed"]
    assert est.resets == 1 and est.calls >= 3  # reset once, and prepare called again after it
    from tepinn_flight.live.worker import COUNTERS, EST

    last = [p for k, p in frames if k == b"E"][-1]
    processed, _, _, errors, *_ = COUNTERS.unpack_from(last, EST.size)
    assert processed == 4 and errors == 0  # no sample was lost to it: the bridge's queue count stays right
