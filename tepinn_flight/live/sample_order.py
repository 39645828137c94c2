"""Which timestamped samples the bridge passes on: duplicates and out-of-order frames are dropped,
a reboot of the autopilot is told apart from a stale frame. Pure (no I/O, no clock of its own).

Redundant links (two radios, a router that also forwards a second copy) and reordered UDP deliver
valid frames that are copies of earlier ones or that arrive after newer ones: their own time
(``time_usec`` / ``time_boot_ms``) is older than the newest sample already passed on. Passed to the
estimator, each one is a time reversal (the estimator resets) followed by a jump forward at the next
live sample (another reset): 18 such frames made 37 time jumps and 19 resets, and the published
attitude jumped by up to 140°. A reboot also sends the time back, and *must* reset the estimator.

:class:`SampleOrder` decides per frame with a small state machine. State: ``last``, the newest
accepted time (none before the first frame), its arrival time, the accepted times of the last
``recent`` samples, and a *candidate* new timeline (first, last, count) made of frames older than
``last``.

==========  ===============================================================================
verdict     when
==========  ===============================================================================
accept      the first frame, or ``t > last``. Any candidate is dropped: the old timeline is
            alive, so the candidate's frames were stale after all.
duplicate   ``t == last``, ``t`` is one of the recently accepted times, or ``t`` repeats the
            candidate's newest frame.
stale       ``t < last`` and not a known time (out of order, or an old copy beyond the recent
            window). It extends the candidate when it follows the candidate's newest frame by
            ``0 < dt <= max_step_s``, else it starts a new candidate of one frame.
reboot      the frame would be ``stale``, but it brings the candidate to ``confirm_n`` frames
            counting up consistently with no frame of the old timeline in between, and (when
            arrival times are given) nothing was accepted for ``silence_s``: the old timeline
            has stopped. The frame is accepted (``last = t``) and the caller resets the
            estimator; the candidate's earlier ``confirm_n - 1`` frames are lost (milliseconds
            of a reboot that takes seconds).
==========  ===============================================================================

Why the silence as well as the count: a redundant link that flushes a buffer delivers a burst of
old copies that also count up consistently, but the live link keeps delivering newer frames around
them (and a newer frame cancels the candidate). A real reboot is seconds of silence first.

Limits: a lone corrupt time far in the future is accepted; the live stream then looks stale until
the rule above adopts it as a "reboot" (``silence_s`` and ``confirm_n`` frames later): one estimator
reset. Dropping an out-of-order frame loses that sample; the estimator bridges gaps up to 2.5
nominal sample periods without a reset, so a frame swapped with its neighbour costs nothing more.
"""

from __future__ import annotations

from collections import deque

ACCEPT = "accept"
DUPLICATE = "duplicate"
STALE = "stale"
REBOOT = "reboot"
VERDICTS = (ACCEPT, DUPLICATE, STALE, REBOOT)


class SampleOrder:
    """``accept(t, now=None)`` → ``'accept' | 'duplicate' | 'stale' | 'reboot'`` (see the module doc).

    ``t``: the sample's own time in s (compared exactly: frames carry integer µs or ms); ``now``:
    its arrival time in s on any monotonic clock, or None to decide on the own times alone.
    ``counts`` holds how many frames got each verdict (since construction; :meth:`reset` keeps them).
    """

    def __init__(self, confirm_n: int = 5, max_step_s: float = 1.0, silence_s: float = 0.25, recent: int = 256):
        if confirm_n < 2 or not max_step_s > 0 or silence_s < 0 or recent < 1:
            raise ValueError("confirm_n >= 2, max_step_s > 0, silence_s >= 0 and recent >= 1 required")
        self.confirm_n = confirm_n
        self.max_step_s = max_step_s
        self.silence_s = silence_s
        self.recent = recent
        self.counts = dict.fromkeys(VERDICTS, 0)
        self.reset()

    def reset(self) -> None:
        """Forget the timeline (another message, another clock); the counts stay."""
        self.last: float | None = None
        self.last_arrival: float | None = None
        self._recent: deque = deque()
        self._recent_set: set = set()
        self._cand: list | None = None  # [first, newest, count]

    @property
    def dropped(self) -> int:
        return self.counts[DUPLICATE] + self.counts[STALE]

    def accept(self, t: float, now: float | None = None) -> str:
        v = self._decide(float(t), now)
        self.counts[v] += 1
        return v

    def _decide(self, t: float, now: float | None) -> str:
        if self.last is None or t > self.last:
            self._cand = None
            self._take(t, now)
            return ACCEPT
        if t == self.last or t in self._recent_set:
            return DUPLICATE
        c = self._cand
        if c is not None and t == c[1]:
            return DUPLICATE
        if c is not None and 0.0 < t - c[1] <= self.max_step_s:
            c[1] = t
            c[2] += 1
        else:
            c = self._cand = [t, t, 1]
        silent = now is None or self.last_arrival is None or now - self.last_arrival >= self.silence_s
        if c[2] >= self.confirm_n and silent:
            self._cand = None
            self._recent.clear()
            self._recent_set.clear()
            self._take(t, now)
            return REBOOT
        return STALE

    def _take(self, t: float, now: float | None) -> None:
        self.last = t
        self.last_arrival = now
        self._recent.append(t)
        self._recent_set.add(t)
        if len(self._recent) > self.recent:
            self._recent_set.discard(self._recent.popleft())
