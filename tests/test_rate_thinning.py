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


@pytest.mark.parametrize("hz, steps, rate, every", [
    (50, [0.018, 0.019, 0.020, 0.021], 50.0, 1),  # an ArduCopter 50-Hz log's stamps: every sample (fixed ticks: 78 %)
    (400, [0.0025], 50.0, 8),
    (200, [0.0049, 0.0050, 0.0051], 50.0, 4),
    (100, [0.0098, 0.0100, 0.0102], 50.0, 2),
])
def test_live_takes_what_offline_takes(hz, steps, rate, every):
    rng = np.random.default_rng(hz)
    t = np.cumsum(rng.choice(steps, 4000))
    live, off = _live(t, rate), due_at_rate(t, rate)
    n_want = len(t) / every
    assert abs(live.sum() - n_want) <= 0.02 * n_want and abs(off.sum() - n_want) <= 0.02 * n_want
    assert np.mean(live == off) > 0.97
    gaps = np.diff(t[live])
    assert gaps.max() < 1.0 / rate + max(steps) + 1e-9  # never a hole longer than one step past the rate's period


def test_a_reset_or_a_time_reversal_starts_over():
    th = RateThinner(50.0)
    for ti in (0.0, 0.005):
        th.seen(ti)
    assert th.due(0.0) and not th.due(0.005)
    th.seen(-5.0)
    assert th.due(-5.0)  # a reversal (a reboot's clock): taken
    th.reset()
    th.seen(-4.999)
    assert th.due(-4.999)
