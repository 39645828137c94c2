"""A worker process that stops answering while samples wait for it is taken for hung after HANG_S, killed and
restarted with the dead worker's backoff (session 53: a stopped worker had left the bridge without estimates for the
rest of the flight, and nothing said so). A worker that answers, or that is not fed, is left alone."""

from __future__ import annotations

import subprocess
import sys
from types import SimpleNamespace

from tepinn_flight.live.estimate_path import HANG_S, EstimatorFeed
from tepinn_flight.live.inputs import ImuSample


class _Silent:
    """A worker process that takes samples and never answers (a real child: ``sleep``)."""

    def __init__(self):
        self.proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
        self.submitted = 0
        self.eof = False

    def submit(self, rec) -> bool:
        self.submitted += 1
        return True

    def read(self):
        return []

    def exit_code(self):
        return self.proc.poll()

    def read_stderr(self):
        return None

    def last_stderr_line(self):
        return ""

    def stop(self, timeout_s=3.0):
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()


def _feed(notes):
    cfg = SimpleNamespace(queue_samples=10_000, worker="process")
    feed = EstimatorFeed(cfg, None, notes.append)
    feed.worker = _Silent()
    feed.worker_ready = feed.ever_ready = True
    return feed


def _sample(t):
    return ImuSample(t, int(t * 1e6), int(t * 1e3), (0.0, 0.0, 0.0), (0.0, 0.0, -9.81), None, "RAW_IMU", 0)


def _noop(*a):
    return None


def test_a_silent_worker_fed_samples_is_killed_and_restarted():
    notes = []
    feed = _feed(notes)
    w = feed.worker
    try:
        for k in range(100):
            feed.submit(_sample(100.0 + 0.01 * k), 100.0 + 0.01 * k, None, "quadrotor")
        feed.upkeep(100.0 + HANG_S - 0.5, _noop, _noop)
        assert feed.worker is w and w.exit_code() is None  # not yet
        feed.upkeep(100.0 + HANG_S + 0.5, _noop, _noop)
        assert feed.worker is None and w.exit_code() is not None  # killed
        assert feed.hangs == 1 and feed.restart_at is not None
        assert any("hung" in n and "restarting" in n for n in notes)
    finally:
        w.stop()


def test_a_worker_not_fed_is_not_taken_for_hung():
    notes = []
    feed = _feed(notes)
    w = feed.worker
    try:
        feed.upkeep(1000.0, _noop, _noop)
        assert feed.worker is w and feed.hangs == 0 and w.exit_code() is None
    finally:
        w.stop()
