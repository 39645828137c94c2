"""ArduPilot's 32-bit microsecond clock in ``RAW_IMU.time_usec``, put back on a running clock.

ArduPilot fills ``RAW_IMU.time_usec`` with ``AP_HAL::micros()``, a 32-bit count: it falls back to 0 every
2**32 µs (71.6 min after boot) while the ``time_boot_ms`` of its other messages (ATTITUDE, SCALED_IMU2, ...)
goes on. Read as it comes, a tlog recorded across the wrap had its later IMU samples sorted before the earlier
ones and paired with the reference of another moment, and the live bridge took the wrap for a reboot
(session 53). A sample's wrap count is the one that brings it nearest the autopilot's ``time_boot_ms`` of the
same moment; a reboot sets both clocks back, so it is left a reboot. Pure: numbers in, numbers out; the tlog
reader (:mod:`.tlog`, arrays) and the bridge (:mod:`tepinn_flight.live.imu_stream`, one sample) use it.
"""

from __future__ import annotations

import numpy as np

#: one turn of the 32-bit microsecond count, s
US32_WRAP_S = 2.0**32 / 1e6
#: how near (s) a sample with its wraps added must come to the boot clock of its moment to take that count
WRAP_MATCH_S = 30.0
#: a fall of at least this much (s) in a ``time_usec`` stream may be a wrap (the gap across it under 10 min)
WRAP_MIN_BACKSTEP_S = US32_WRAP_S - 600.0


def wrap_count(t_s, boot_s):
    """The number of 2**32-µs wraps that puts ``t_s`` (a 32-bit ``time_usec``, s) within :data:`WRAP_MATCH_S` of
    ``boot_s`` (the autopilot's ``time_boot_ms`` at that moment, s), or -1 where none does (arrays or floats)."""
    k = np.rint((np.asarray(boot_s, np.float64) - t_s) / US32_WRAP_S)
    ok = (k >= 0) & (np.abs(t_s + k * US32_WRAP_S - boot_s) <= WRAP_MATCH_S) & (np.asarray(t_s) < US32_WRAP_S)
    out = np.where(ok, k, -1.0)
    return int(out) if np.ndim(out) == 0 else out


def top_to_bottom(t_prev_s, t_s):
    """Whether a 32-bit ``time_usec`` stream falling from ``t_prev_s`` to ``t_s`` (s) wrapped, read from the
    stream alone (no boot clock to compare with): from its last :data:`WRAP_MATCH_S` to its first (floats, or
    arrays element by element)."""
    return (US32_WRAP_S - WRAP_MATCH_S < t_prev_s) & (t_prev_s < US32_WRAP_S) & (0.0 <= t_s) & (t_s < WRAP_MATCH_S)
