"""Estimates at about a rate, live (:class:`RateThinner`, the bridge's worker) as offline (:func:`due_at_rate`)."""

from __future__ import annotations

import numpy as np
import pytest

from tepinn_flight.rate_thinning import RateThinner, due_at_rate


def _live(t, rate):
    th = RateThinner(rate)
    out = []
    for ti in t.tolist():
        th.seen(ti)
        out.append(th.due(ti))
    return np.array(out)


@pytest.mark.parametrize("steps, rate", [
    ([0.018, 0.019, 0.020, 0.021], 50.0),  # an ArduCopter 50-Hz log's stamps (fixed ticks took 78 % of them)
    ([0.0025], 50.0),  # 400 Hz: every 8th
    ([0.0049, 0.0050, 0.0051], 50.0),
    ([0.0098, 0.0100, 0.0102], 50.0),
    ([1 / 60], 50.0), ([1 / 70], 50.0), ([1 / 75], 50.0),  # between the rate and twice it (the first rule: all)
    ([0.02], 35.0), ([0.02], 40.0), ([0.02], 30.0),  # a 50-Hz stream asked for less
    ([0.02], 100.0), ([0.04], 50.0),  # a stream slower than the rate: every sample
])
def test_the_mean_rate_is_the_rate_or_the_streams(steps, rate):
    rng = np.random.default_rng(len(steps) + int(rate))
    t = np.cumsum(rng.choice(steps, 6000))
    f = (len(t) - 1) / (t[-1] - t[0])
    want = min(rate, f) * (t[-1] - t[0])
    for got in (_live(t, rate), due_at_rate(t, rate)):
        assert abs(got.sum() - want) <= 0.02 * want + 2, (got.sum(), want)
        gaps = np.diff(t[got])
        assert gaps.max() < max(1.0 / rate, max(steps)) + max(steps) + 1e-9  # no hole past a target and a step
    assert np.mean(_live(t, rate) == due_at_rate(t, rate)) > 0.95


def test_a_jittery_stream_at_the_rate_keeps_every_sample_and_a_faster_one_is_thinned_evenly():
    rng = np.random.default_rng(0)
    t50 = np.arange(3000) * 0.02 + rng.uniform(-0.002, 0.002, 3000)  # a 50-Hz loop's stamps jitter about its clock
    assert _live(t50, 50.0).all() and due_at_rate(t50, 50.0).all()
    walk = np.cumsum(rng.choice([0.018, 0.019, 0.020, 0.021, 0.022], 3000))  # steps that wander: nearly every one
    assert _live(walk, 50.0).sum() >= 0.99 * len(walk) and due_at_rate(walk, 50.0).sum() >= 0.99 * len(walk)
    t400 = np.arange(4000) / 400.0
    assert np.array_equal(np.flatnonzero(due_at_rate(t400, 50.0)), np.arange(0, 4000, 8))


def test_the_period_recovers_from_a_tiny_first_step_and_a_slower_stream():
    """A 0.5-ms first step locked the running period small, every later step counted as a gap, and a jittery 50-Hz
    stream lost a third of its samples."""
    rng = np.random.default_rng(1)
    t = np.concatenate([[0.0, 0.0005], 0.0005 + np.cumsum(rng.choice([0.018, 0.019, 0.020, 0.021, 0.022], 3000))])
    assert _live(t, 50.0).sum() >= 0.99 * len(t)


def test_a_reset_a_time_reversal_or_a_rate_that_is_no_rate():
    th = RateThinner(50.0)
    for ti in (0.0, 0.005):
        th.seen(ti)
    assert th.due(0.0) and not th.due(0.005)
    th.seen(-5.0)
    assert th.due(-5.0)  # a reversal (a reboot's clock): taken
    th.reset()
    th.seen(-4.999)
    assert th.due(-4.999)
    t = np.arange(4000) / 400.0
    for bad in (float("nan"), 0.0, -5.0, float("inf")):
        assert _live(t, bad).all() and due_at_rate(t, bad).all()  # live as offline: every sample
