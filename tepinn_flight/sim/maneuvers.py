"""Maneuver base class and the sequencer that chains maneuvers with short recoveries.

A maneuver is a small state machine: ``start`` draws its parameters from the flight's random
generator (so the whole flight follows from the seed) and ``update`` writes references into the
vehicle's controller once per simulation step, returning True when it has finished. The
sequencer flies, in order, either a random choice from the vehicle's library or the names the
caller gave (cycled), each followed by a recovery, until the flight's duration is used up.
"""

from __future__ import annotations

import numpy as np

from tepinn_flight.errors import ConfigError

RECOVERY = "recovery"


class Maneuver:
    """Base class: subclasses set ``name`` and ``description`` and override start/update."""

    name = "maneuver"
    description = ""
    #: multiplies the motor-vibration amplitude while this maneuver flies (multirotors)
    vibration_gain = 1.0
    #: height above ground needed to start it; below, a recovery climbs first
    min_agl_m = 0.0

    def start(self, ctl, t: float, rng: np.random.Generator) -> None:  # pragma: no cover
        raise NotImplementedError

    def update(self, ctl, t: float) -> bool:  # pragma: no cover
        raise NotImplementedError

    def finish(self, ctl, t: float) -> None:
        """Called once when the maneuver ends (finished or cut by the end of the flight)."""


def validate_names(library: dict, names: list[str] | None, aircraft: str) -> list[str] | None:
    """Check that every requested maneuver exists for this vehicle (ConfigError otherwise)."""
    if names is None:
        return None
    if isinstance(names, str):
        names = [names]
    names = list(names)
    if not names:
        raise ConfigError("the maneuver list is empty")
    unknown = [n for n in names if n not in library]
    if unknown:
        raise ConfigError(
            f"unknown maneuver {unknown[0]!r} for {aircraft} (known: {', '.join(sorted(library))})"
        )
    return names


class Sequencer:
    """Chains maneuvers (random from the seed, or the given list cycled) with recoveries."""

    def __init__(self, library: dict, recovery_cls, names: list[str] | None, rng: np.random.Generator,
                 weights: dict[str, float] | None = None):
        self.library = library
        self.recovery_cls = recovery_cls
        self.names = names
        self.rng = rng
        pool = sorted(library)
        w = np.array([(weights or {}).get(n, 1.0) for n in pool], dtype=float)
        self._pool, self._p = pool, w / w.sum()
        self._i = 0
        self.current: Maneuver | None = None
        self.t_start = 0.0
        self.segments: list[tuple[float, float, str]] = []
        self.gains: list[float] = []  # vibration gain of each segment
        self._last = None

    def _next(self, ctl):
        """The next maneuver class, or None when the vehicle must climb first."""
        ctl.read_state()
        agl = ctl.agl_m
        lib = self.library
        if self.names is not None:
            cls = lib[self.names[self._i % len(self.names)]]
            if agl < cls.min_agl_m:
                return None
            self._i += 1
            return cls
        ok = [agl >= lib[n].min_agl_m and (n != self._last or len(self._pool) == 1) for n in self._pool]
        if not any(ok):
            return None
        p = np.where(ok, self._p, 0.0)
        name = str(self.rng.choice(self._pool, p=p / p.sum()))
        self._last = name
        return lib[name]

    def _begin(self, m: Maneuver, ctl, t: float) -> None:
        self.current = m
        self.t_start = t
        m.start(ctl, t, self.rng)

    def _begin_next(self, ctl, t: float) -> None:
        cls = self._next(ctl)
        if cls is None:  # too low for anything requested: climb in a recovery first
            rec = self.recovery_cls()
            if self.names is not None:
                need = self.library[self.names[self._i % len(self.names)]].min_agl_m
            else:
                need = min(self.library[n].min_agl_m for n in self._pool)
            rec.target_agl_m = need + 100.0
            self._begin(rec, ctl, t)
        else:
            self._begin(cls(), ctl, t)

    def start(self, ctl, t: float) -> None:
        self._begin_next(ctl, t)

    def update(self, ctl, t: float) -> None:
        if self.current.update(ctl, t):
            self.advance(ctl, t)

    def advance(self, ctl, t: float) -> None:
        """The current maneuver finished at ``t`` (its update said so: here, or in a compiled loop): record
        it and begin the next (a recovery after a maneuver, the next maneuver after a recovery)."""
        m = self.current
        m.finish(ctl, t)
        self.segments.append((self.t_start, t, m.name))
        self.gains.append(float(m.vibration_gain))
        if m.name == RECOVERY:
            self._begin_next(ctl, t)
        else:
            self._begin(self.recovery_cls(), ctl, t)

    def close(self, ctl, t: float) -> None:
        """End of flight: record the maneuver in progress, cut at ``t``."""
        if self.current is not None and t > self.t_start:
            self.current.finish(ctl, t)
            self.segments.append((self.t_start, t, self.current.name))
            self.gains.append(float(self.current.vibration_gain))
        self.current = None
