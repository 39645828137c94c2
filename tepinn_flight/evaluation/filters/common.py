"""Helpers shared by the baseline filters: input checks, time steps, the initial attitude.

Every filter has the same batch API (causal, one pass, numpy in / numpy out)::

    Filter(params).estimate(gyr (N,3) rad/s, acc (N,3) m/s², t_s (N,), mag=None, q0=None)
        -> {"q_nb_wxyz": (N, 4) body FRD -> NED, optionally "bias_rad_s": (N, 3), "sigma_rad": (N,)}

Row ``i`` of the output is the state after processing sample ``i`` (the state is set to ``q0`` or to
the attitude from the first accelerometer/magnetometer sample, then sample 0 is processed). Inputs
that are not finite are neutralised up front: a non-finite gyro sample counts as zero rate, a
non-finite or all-zero accelerometer (magnetometer) sample skips that correction — the convention of
Madgwick's C code (``acc == 0`` → no feedback).
"""

from __future__ import annotations

import math

import numpy as np

from ...errors import TepinnError


def check_inputs(gyr, acc, t_s, mag=None):
    """Validate shapes and return clean float64 arrays ``(gyr, acc, dt, mag_or_None)``.

    ``dt[i] = t[i] - t[i-1]``; ``dt[0]`` (and any non-positive or non-finite step) is the median step.
    The arrays are C-contiguous and writable whatever the caller passed (a record's columns are
    read-only, Fortran-ordered views; they are copied): the compiled loops then see one type and
    compile once. The caller's arrays are never modified.
    """
    gyr = np.asarray(gyr, np.float64)
    acc = np.asarray(acc, np.float64)
    t_s = np.asarray(t_s, np.float64)
    n = len(t_s)
    if gyr.shape != (n, 3) or acc.shape != (n, 3):
        raise TepinnError(f"filter input shapes disagree: gyr {gyr.shape}, acc {acc.shape}, t_s {t_s.shape}")
    if mag is not None:
        mag = np.asarray(mag, np.float64)
        if mag.shape != (n, 3):
            raise TepinnError(f"filter input shapes disagree: mag {mag.shape}, t_s {t_s.shape}")
        bad = ~np.all(np.isfinite(mag), axis=1)
        if bad.all():
            mag = None
        elif bad.any():
            mag = mag.copy()
            mag[bad] = 0.0
    gyr = np.where(np.isfinite(gyr), gyr, 0.0)
    bad = ~np.all(np.isfinite(acc), axis=1)
    if bad.any():
        acc = acc.copy()
        acc[bad] = 0.0
    dt = np.diff(t_s, prepend=np.nan)
    ok = np.isfinite(dt) & (dt > 0)
    nominal = float(np.median(dt[ok])) if ok.any() else 0.01
    dt[~ok] = nominal
    return _loop_array(gyr), _loop_array(acc), dt, None if mag is None else _loop_array(mag)


def _loop_array(x: np.ndarray) -> np.ndarray:
    """x as the compiled loops take it: float64, C-contiguous, writable (a copy only when it is not)."""
    return np.require(x, np.float64, ["C_CONTIGUOUS", "WRITEABLE"])


def initial_attitude(acc, mag=None) -> np.ndarray:
    """Attitude body→NED from one accelerometer sample (roll, pitch) and, if given, a magnetometer
    sample (heading toward magnetic north); yaw = 0 without a magnetometer.

    Down in body axes is ``-acc/|acc|`` (specific force at rest points up).
    """
    a = np.asarray(acc, np.float64)
    na = float(np.linalg.norm(a))
    if not np.isfinite(na) or na < 1e-9:
        return np.array([1.0, 0.0, 0.0, 0.0])
    down = -a / na
    if mag is not None and np.all(np.isfinite(mag)) and np.linalg.norm(mag) > 0:
        east = np.cross(down, mag)
        ne = np.linalg.norm(east)
        if ne > 1e-9:
            east /= ne
            north = np.cross(east, down)
            return rotmat_rows_to_quat(north, east, down)
    # yaw = 0: roll/pitch from the down vector (aerospace Z-Y-X)
    roll = math.atan2(down[1], down[2])
    pitch = math.atan2(-down[0], math.hypot(down[1], down[2]))
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    return np.array([cr * cp, sr * cp, cr * sp, -sr * sp])


def rotmat_rows_to_quat(north_b, east_b, down_b) -> np.ndarray:
    """q_nb from the earth axes expressed in body coordinates (the rows of R_nb)."""
    from ...quat import rotmat_to_quat

    return rotmat_to_quat(np.array([north_b, east_b, down_b], np.float64))


def as_tuple4(q) -> tuple[float, float, float, float]:
    q = np.asarray(q, np.float64).ravel()
    if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) == 0:
        raise TepinnError(f"initial quaternion must be 4 finite numbers, got {q!r}")
    q = q / np.linalg.norm(q)
    return float(q[0]), float(q[1]), float(q[2]), float(q[3])
