"""Estimates sent at about a rate: every sample of a stream at that rate, through its stamps' jitter, and a faster one
thinned to about it.

A sample is taken once ``1/rate`` less half a sample period has passed since the last one taken
(:func:`min_spacing_s`). Fixed ticks of ``1/rate`` (the first sample of each) lost 22 % of a 50-Hz ArduCopter log whose
stamps step 18–21 ms: two samples in one tick, none in the next. With the rule, a 50-Hz stream gives every sample at
50 Hz, a 400-Hz one every 8th. Offline over a whole record (:func:`due_at_rate`: the tlog an estimate is written into)
and live one sample at a time (:class:`RateThinner`: the bridge's worker).
"""

from __future__ import annotations

import numpy as np


def min_spacing_s(rate_hz: float, period_s: float) -> float:
    """The least time between two samples taken at about ``rate_hz`` from a stream of period ``period_s``."""
    return 1.0 / rate_hz - 0.5 * period_s


def due_at_rate(t_s: np.ndarray, rate_hz: float, candidates: np.ndarray | None = None) -> np.ndarray:
    """Rows to take at about ``rate_hz`` (bool mask; the first candidate, then by :func:`min_spacing_s` with the
    record's median step). ``rate_hz`` ≤ 0: every candidate."""
    t = np.asarray(t_s, np.float64)
    cand = np.ones(len(t), bool) if candidates is None else np.asarray(candidates, bool)
    if rate_hz <= 0 or not np.isfinite(rate_hz):
        return cand.copy()
    dt = np.diff(t)
    dt = dt[(dt > 0) & np.isfinite(dt)]
    gap = min_spacing_s(rate_hz, float(np.median(dt)) if len(dt) else 0.0) - 1e-9
    due = np.zeros(len(t), bool)
    last = -np.inf
    for i in np.flatnonzero(cand).tolist():
        ti = float(t[i])
        if ti - last >= gap:
            due[i] = True
            last = ti
    return due


class RateThinner:
    """:func:`due_at_rate` one sample at a time: the stream's period followed as a running mean of its steps (a step
    over ten periods — a gap — left out), a time reversal or :meth:`reset` starting over."""

    GAIN = 0.05  # of the running mean of the steps

    def __init__(self, rate_hz: float):
        self.rate_hz = float(rate_hz)
        self.reset()

    def reset(self) -> None:
        self.last_taken = None
        self.t_prev = None
        self.period = None

    def seen(self, t_s: float) -> None:
        """A sample of the stream, taken or not (its step feeds the period)."""
        if self.t_prev is not None:
            dt = t_s - self.t_prev
            if dt > 0 and (self.period is None or dt < 10.0 * self.period):
                self.period = dt if self.period is None else self.period + self.GAIN * (dt - self.period)
        self.t_prev = t_s

    def due(self, t_s: float) -> bool:
        """Whether a sample at ``t_s`` (already :meth:`seen`) is to be taken; if so it is the last taken."""
        last = self.last_taken
        if (last is None or t_s < last or self.rate_hz <= 0
                or t_s - last >= min_spacing_s(self.rate_hz, self.period or 0.0) - 1e-9):  # fmt: skip
            self.last_taken = t_s
            return True
        return False
