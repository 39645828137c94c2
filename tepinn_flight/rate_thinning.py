"""Estimates sent at about a rate: every sample of a stream at that rate, through its stamps' jitter; a faster one
thinned to the rate; a slower one whole.

Targets fall every ``1/rate``; a sample is taken once it is no more than half a sample period before the next
target (:func:`take_from`), which then moves on by ``1/rate`` — or, where the stream fell behind the targets (a
slower stream, a gap), to ``1/rate`` after the sample. Fixed ticks of ``1/rate`` (the first sample of each) lost 22 %
of a 50-Hz ArduCopter log whose stamps step 18–21 ms (two samples in one tick, none in the next); a spacing of
``1/rate`` less half a period from the last sample taken (session 45's first rule) let up to 1.5× the rate through
(a 70-Hz stream at 50). With the targets the output's mean rate is min(rate, the stream's): a 50-Hz stream gives every
sample at 50 Hz, a 400-Hz one every 8th, a 70-Hz one 50 a second. Offline over a whole record (:func:`due_at_rate`:
the tlog an estimate is written into, a replay's ATTITUDE) and live one sample at a time (:class:`RateThinner`: the
bridge's worker), by the same step.
"""

from __future__ import annotations

import math

import numpy as np


def take_from(t_s: float, target_s: float, rate_hz: float, period_s: float) -> float | None:
    """The next target after taking a sample at ``t_s`` when the target was ``target_s``, or None: not taken (the
    sample is more than half a period early)."""
    if t_s < target_s - 0.5 * period_s - 1e-9:
        return None
    nxt = target_s + 1.0 / rate_hz
    return nxt if nxt >= t_s else t_s + 1.0 / rate_hz  # behind the targets (a slower stream, a gap): start again


class RateThinner:
    """One sample at a time. ``period_s``: the stream's period, if known (offline: the record's median step); else
    followed as a running mean of the steps, a step over ten periods (a gap) left out unless three come in a row
    (the stream slowed down). A time reversal or :meth:`reset` starts over; a rate that is not finite and > 0 takes
    every sample."""

    GAIN = 0.05  # of the running mean of the steps

    def __init__(self, rate_hz: float, period_s: float | None = None):
        self.rate_hz = float(rate_hz)
        self.every = not (math.isfinite(self.rate_hz) and self.rate_hz > 0)
        self.fixed_period = period_s
        self.reset()

    def reset(self) -> None:
        self.target = None
        self.last_taken = None
        self.t_prev = None
        self.period = self.fixed_period
        self.long_steps = 0

    def seen(self, t_s: float) -> None:
        """A sample of the stream, taken or not (its step feeds the period)."""
        if self.fixed_period is None and self.t_prev is not None:
            dt = t_s - self.t_prev
            if dt > 0:
                if self.period is None or dt < 10.0 * self.period:
                    self.period = dt if self.period is None else self.period + self.GAIN * (dt - self.period)
                    self.long_steps = 0
                else:
                    self.long_steps += 1
                    if self.long_steps >= 3:  # not gaps: a slower stream
                        self.period, self.long_steps = dt, 0
        self.t_prev = t_s

    def due(self, t_s: float) -> bool:
        """Whether a sample at ``t_s`` (already :meth:`seen`) is to be taken; if so it is the last taken."""
        if self.every:
            return True
        if self.target is None or (self.last_taken is not None and t_s < self.last_taken):
            self.target = t_s + 1.0 / self.rate_hz
        else:
            nxt = take_from(t_s, self.target, self.rate_hz, self.period or 0.0)
            if nxt is None:
                return False
            self.target = nxt
        self.last_taken = t_s
        return True


def due_at_rate(t_s: np.ndarray, rate_hz: float, candidates: np.ndarray | None = None) -> np.ndarray:
    """Rows to take at about ``rate_hz`` (bool mask), by :class:`RateThinner` with the record's median step as the
    period, over the candidate rows. ``rate_hz`` not finite and > 0: every candidate."""
    t = np.asarray(t_s, np.float64)
    cand = np.ones(len(t), bool) if candidates is None else np.asarray(candidates, bool)
    dt = np.diff(t)
    dt = dt[(dt > 0) & np.isfinite(dt)]
    th = RateThinner(rate_hz, float(np.median(dt)) if len(dt) else 0.0)
    due = np.zeros(len(t), bool)
    for i in np.flatnonzero(cand).tolist():
        due[i] = th.due(float(t[i]))
    return due
