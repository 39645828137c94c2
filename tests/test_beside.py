"""The helper process beside a long record's offline estimate (model/beside.py): its results come back in order, a
helper that fails or dies leaves the work to the caller, and the estimate is the same bits with it as without it —
on a real trial, on a real log whose receiver leaves the accelerometer as read, on a flight whose receiver changes
it, and where the helper dies."""

from __future__ import annotations

import os
import signal
import sys
import time

import numpy as np
import pytest

from tepinn_flight.model import beside, estimate
from tepinn_flight.model.beside import Beside, BesideFailed
from tepinn_flight.model.gnss_aid import GnssEvidence

from .conftest import broad_trial, real_log

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the helper runs on Linux only")


def test_results_come_back_in_order_and_a_helper_that_raises_gives_the_rest_to_the_caller():
    def work():
        yield 1
        yield np.arange(5.0)
        raise ValueError("broken")

    with Beside(work) as side:
        assert side.next() == 1
        np.testing.assert_array_equal(side.next(), np.arange(5.0))
        with pytest.raises(BesideFailed):
            side.next()
        with pytest.raises(BesideFailed):  # and stays failed
            side.next()



def test_a_large_result_waiting_in_the_pipe_does_not_hold_up_the_next():
    """After its first result the child hands each to a writer thread: a result larger than the pipe holds waits there
    for the caller while the child goes on to the next (session 40: the GNSS aid's evidence, read only after the
    anchored pass, had held up the smoothing's VQF runs behind it), and each still arrives whole and in order."""
    big = np.arange(2_000_000, dtype=np.float64)  # 16 MB: far more than a pipe holds

    def work():
        yield 1
        yield big
        yield time.time()  # when the child got past the large result

    with Beside(work) as side:
        assert side.next() == 1
        t0 = time.time()
        time.sleep(1.5)  # the caller busy elsewhere, reading nothing
        np.testing.assert_array_equal(side.next(), big)
        past = side.next()
    assert past - t0 < 1.0  # not blocked until the caller read the large one

def test_leaving_it_stops_a_child_still_running_and_reaps_it():
    def work():
        time.sleep(60)
        yield 1

    t0 = time.perf_counter()
    side = Beside(work)
    pid = side.pid
    side.close()
    assert time.perf_counter() - t0 < 10
    with pytest.raises(ChildProcessError):  # reaped: no zombie left
        os.waitpid(pid, os.WNOHANG)


def test_used_only_where_it_pays_and_not_when_switched_off(monkeypatch):
    monkeypatch.setenv(beside.ENV, "1")
    if beside.usable_cores() >= 2:
        assert beside.worth_it(beside.MIN_SAMPLES)
    assert not beside.worth_it(beside.MIN_SAMPLES - 1)
    monkeypatch.setenv(beside.ENV, "0")
    assert not beside.worth_it(10 * beside.MIN_SAMPLES)


def _both(monkeypatch, rec, work=None):
    """The shipped estimate of ``rec`` without the helper, and with it (forced on, however short the record;
    ``work``: what the helper does instead of its own work; its results waited for) → (without, with, how many
    results each helper gave, those results in order)."""
    from tepinn_flight.model.checkpoint import default_model_path, load_model

    model, settings, _ = load_model(default_model_path())
    monkeypatch.setenv(beside.ENV, "0")
    off = estimate.estimate_record(model, rec, settings)
    started, given = [], []

    class Counted(Beside):
        def __init__(self, w):
            started.append(0)
            super().__init__(w)

        def take(self, wait_s=0.0, max_wait_s=None):  # waits for the child however loaded the machine is, and counts what it gave
            got = self.next()
            started[-1] += 1
            given.append(got)
            return got

    monkeypatch.setenv(beside.ENV, "1")
    monkeypatch.setattr(beside, "usable_cores", lambda: 2)
    monkeypatch.setattr(estimate, "Beside", Counted)
    monkeypatch.setattr(estimate, "worth_it", lambda n: beside.worth_it(n, min_samples=1))
    if work is not None:
        monkeypatch.setattr(estimate, "_beside_work", work)
    on = estimate.estimate_record(model, rec, settings)
    return off, on, started, given


def _same(off, on):
    assert list(off.columns) == list(on.columns)
    assert np.array_equal(off.to_numpy(), on.to_numpy(), equal_nan=True)
    assert off.attrs == on.attrs


@pytest.mark.slow
def test_the_estimate_of_a_real_trial_is_the_same_bits_with_the_helper(monkeypatch):
    from tepinn_flight.ingest import ingest_log

    rec = ingest_log(broad_trial("broad_08_*.hdf5"))  # the gyro self-calibration applies here (the helper's part)
    off, on, started, given = _both(monkeypatch, rec)
    assert started == [2]  # the self-calibration and the smoothing's run came from the helper
    assert "applied" in off.attrs["gyro_selfcal"] and "applied" in off.attrs["smoother"]
    _same(off, on)


@pytest.mark.slow
def test_with_a_receiver_whose_aid_does_not_apply_the_smoothing_run_comes_from_the_helper(monkeypatch):
    """A PX4 log with GNSS velocity where the aid leaves the accelerometer as read: the helper's runs on it are the
    smoothing's (before session 39 the helper made none on such a record, and the caller ran VQF both ways itself)."""
    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.record import segment_slices

    rec = ingest_log(real_log("pyulog_sample_px4_events.ulg"))
    assert rec.gnss_vel_ne_m_s is not None
    made_here = []
    real = estimate.gnss_evidences
    monkeypatch.setattr(estimate, "gnss_evidences", lambda *a: made_here.append(1) or real(*a))  # in this process only
    off, on, started, given = _both(monkeypatch, rec)
    assert "not applied" in off.attrs["gnss_aid"] and "applied" in off.attrs["smoother"]
    # the self-calibration, the GNSS aid's evidence from the receiver (session 40) and the smoothing's run came from
    # the helper: the caller made the evidence only in the run without it
    assert started == [3] and made_here == [1]
    segments = {(s.start, s.stop) for s in segment_slices(rec.segment)}
    assert set(given[1]) == segments and all(isinstance(e, GnssEvidence) for e in given[1].values())
    assert set(given[2]) == segments  # the smoothing's runs over each whole segment
    _same(off, on)


@pytest.mark.slow
def test_a_helper_that_dies_or_raises_leaves_the_estimate_as_it_was(monkeypatch):
    from tepinn_flight.model.synthetic import synthetic_record

    rec = synthetic_record(seed=3, duration_s=40.0, rate_hz=200.0)

    def dies(anchor, rec):
        def work():
            yield estimate.self_calibrated(anchor, rec)
            os.kill(os.getpid(), signal.SIGKILL)  # before the smoothing's runs
            yield {}

        return work

    def raises(anchor, rec):
        def work():
            raise RuntimeError("no")
            yield  # noqa: unreachable - a generator

        return work

    for work, gave in ((dies, [1]), (raises, [0])):
        off, on, started, given = _both(monkeypatch, rec, work)
        assert started == gave
        _same(off, on)


@pytest.mark.slow
def test_with_a_receiver_a_second_helper_runs_the_smoothing_on_the_aided_accelerometer(monkeypatch):
    from tepinn_flight.sim.simulate import simulate_record

    rec = simulate_record("F450", 30.0, rate_hz=200.0, seed=4)
    assert rec.gnss_vel_ne_m_s is not None
    off, on, started, given = _both(monkeypatch, rec)
    assert "applied" in off.attrs["gnss_aid"] and "applied" in off.attrs["smoother"]
    # the first helper gave the self-calibration and the aid's evidence from the receiver (its smoothing runs, on the
    # accelerometer as read, are not asked for: it is stopped); a second, forked once the aid had changed the
    # accelerometer, the smoothing's runs on it
    assert started == [2, 1]
    _same(off, on)


def test_a_result_not_ready_when_asked_for_stops_the_child_and_is_computed_by_the_caller():
    def work():
        yield 1
        time.sleep(60)
        yield 2

    with Beside(work) as side:
        t0 = time.perf_counter()
        while not side.ready() and time.perf_counter() - t0 < 30:
            time.sleep(0.01)
        assert side.take() == 1
        pid = side.pid
        with pytest.raises(BesideFailed):  # still sleeping: not waited for
            side.take()
        assert time.perf_counter() - t0 < 30
        with pytest.raises(ChildProcessError):  # stopped and reaped
            os.waitpid(pid, os.WNOHANG)


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads /proc (Linux)")
def test_a_child_still_computing_is_waited_for_past_the_first_wait_and_a_stalled_one_is_not():
    """Past ``wait_s`` the caller goes on waiting, up to ``max_wait_s``, only while the child's CPU time grows (session
    42: a late helper's work had been thrown away and done again): a child computing for ~1 s gives its result; one
    that has stopped computing (asleep, as one starved by a busy machine) is given up at once."""

    def busy():
        t_end = time.process_time() + 1.0
        x = 0
        while time.process_time() < t_end:  # CPU, not sleep
            x += 1
        yield x

    with Beside(busy) as side:
        t0 = time.perf_counter()
        assert side.take(0.05, 20.0) > 0
        assert 0.5 < time.perf_counter() - t0 < 15.0  # waited past wait_s, for the result
        with pytest.raises(BesideFailed):
            side.take(0.05, 20.0)  # no more results: the child has ended

    def stalled():
        time.sleep(60)
        yield 1

    with Beside(stalled) as side:
        t0 = time.perf_counter()
        pid = side.pid
        with pytest.raises(BesideFailed):
            side.take(0.05, 20.0)
        assert time.perf_counter() - t0 < 3.0  # one slice past wait_s, not max_wait_s
        with pytest.raises(ChildProcessError):  # stopped and reaped
            os.waitpid(pid, os.WNOHANG)


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads /proc (Linux)")
def test_the_child_dies_with_its_parent():
    """A parent killed outright (no cleanup runs) takes its helper with it: nothing is left computing."""
    import subprocess

    code = (
        "import os, sys, time\n"
        "from tepinn_flight.model.beside import Beside\n"
        "def work():\n"
        "    time.sleep(60)\n"
        "    yield 1\n"
        "side = Beside(work)\n"
        "print(side.pid, flush=True)\n"
        "time.sleep(0.5)\n"
        "os.kill(os.getpid(), 9)\n"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert p.returncode == -9, p.stderr
    pid = int(p.stdout.split()[0])

    def running() -> bool:
        try:
            with open(f"/proc/{pid}/status") as f:
                state = next(ln for ln in f if ln.startswith("State:"))
        except (FileNotFoundError, ProcessLookupError):
            return False
        return "Z" not in state.split()[1]  # a zombie computes nothing (its reaper may be slow in a container)

    t0 = time.perf_counter()
    while running() and time.perf_counter() - t0 < 10:
        time.sleep(0.05)
    assert not running()
