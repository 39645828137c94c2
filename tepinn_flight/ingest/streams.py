"""What a log reader hands over: raw streams in SI units on the log's own clock.

Readers (``tlog``, ``dataflash``, ``ulog``, ``broad``) only parse and convert units; putting the
streams on one time base, splitting segments and interpolating the reference onto the IMU samples
is done once, in :mod:`tepinn_flight.ingest.assemble`.

Clock: ``t_s`` is the source's own sample time in seconds (time since boot, or UNIX time), never a
receive timestamp. ``epoch`` numbers boot epochs: it increases by one at each reboot the reader
detected (time going backwards in file order), so streams of the same epoch share one clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


#: a reader takes another IMU source than its default one where that holds this many times its samples or comes at
#: this many times its rate (the bridge's rule for a less preferred IMU message, ``live/imu_stream.py``)
PREFER_FACTOR = 1.5


def covering_instance(samples: dict[int, int]) -> int:
    """The IMU instance a reader takes by default, of {instance: its samples}: the first (lowest) unless another holds
    over :data:`PREFER_FACTOR` times its samples — the first IMU failing or stopping in flight while the others go on
    (review59: a record of 15 s of a 40-s flight, unsaid), or logged far slower. The most samples, then the lowest."""
    first = min(samples)
    best = max(samples, key=lambda k: (samples[k], -k))
    return best if samples[best] > PREFER_FACTOR * samples[first] else first


def covering_note(read: int, read_n: int, first: int, first_n: int) -> str:
    """The note where :func:`covering_instance` read IMU ``read`` (``read_n`` samples) instead of the first."""
    return (f"IMU {read} read ({read_n} samples): IMU {first}, the first, holds {first_n} (it stops or is slower; "
            f"--imu {first} reads it)")


@dataclass
class ImuStream:
    t_s: np.ndarray  # (N,) float64, source clock
    gyr_rad_s: np.ndarray  # (N, 3) body FRD
    acc_m_s2: np.ndarray  # (N, 3) specific force, body FRD
    clipped: np.ndarray | None = None  # (N,) bool: a gyro or accelerometer axis at its range (or unhealthy)
    epoch: np.ndarray | None = None  # (N,) int, boot epoch
    gyr_clipped: np.ndarray | None = None  # (N,) bool: those of the gyro (None: the reader cannot tell)


@dataclass
class MagStream:
    t_s: np.ndarray  # (M,)
    mag_ut: np.ndarray  # (M, 3) µT, body FRD
    epoch: np.ndarray | None = None


@dataclass
class RefStream:
    t_s: np.ndarray  # (K,)
    q_nb_wxyz: np.ndarray  # (K, 4) body FRD -> NED
    source: str  # e.g. "ATT", "XKQ", "vehicle_attitude", "ATTITUDE_QUATERNION", "optitrack"
    epoch: np.ndarray | None = None


@dataclass
class GnssVelStream:
    """The GNSS receiver's velocity over ground, horizontal (its fixes with a 3-D lock only)."""

    t_s: np.ndarray  # (K,) source clock (the IMU's: boot time)
    vel_ne_m_s: np.ndarray  # (K, 2) north, east, m/s
    source: str  # e.g. "GPS", "GPS_RAW_INT", "vehicle_gps_position"
    epoch: np.ndarray | None = None


@dataclass
class RawLog:
    """A parsed log: the selected IMU, optional magnetometer and reference, and what we know.

    ``meta`` carries at least ``source_kind``; readers add what they know: ``vehicle_type``,
    ``autopilot``, ``firmware``, ``imu_instance``, ``imu_instances`` (list of
    ``{"instance", "name", "samples", "rate_hz"}``), ``reference_candidates`` (list of names),
    ``corrupt_frames``, ``skipped_frames``, ``notes`` (list of str).
    """

    imu: ImuStream
    mag: MagStream | None = None
    ref: RefStream | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    valid: np.ndarray | None = None  # (N,) bool on the IMU samples (BROAD's movement mask)
    extra: dict[str, np.ndarray] = field(default_factory=dict)  # optional record columns (N, ...)
    gnss: GnssVelStream | None = None  # the receiver's velocity (GNSS-aided tilt), where the log has one


def nominal_period_s(t_s: np.ndarray, epoch: np.ndarray | None = None) -> float:
    """1 / nominal rate: the median positive step inside boot epochs (NaN if fewer than 2)."""
    t_s = np.asarray(t_s, np.float64)
    if len(t_s) < 2:
        return float("nan")
    dt = np.diff(t_s)
    ok = dt > 0
    if epoch is not None:
        ok &= np.diff(epoch) == 0
    if not np.any(ok):
        return float("nan")
    return float(np.median(dt[ok]))


def detect_epochs(t_s: np.ndarray, backstep_s: float = 1.0) -> np.ndarray:
    """Boot epochs from one clock in file order: a new epoch where time jumps back > ``backstep_s``.

    Small backward steps (reordering, jitter) are not reboots; they end a segment only.
    """
    t_s = np.asarray(t_s, np.float64)
    if len(t_s) == 0:
        return np.zeros(0, np.int64)
    back = np.diff(t_s) < -backstep_s
    return np.concatenate([[0], np.cumsum(back)]).astype(np.int64)
