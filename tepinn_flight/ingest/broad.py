"""BROAD trial (HDF5, Laidig et al. 2021) → :class:`~tepinn_flight.ingest.streams.RawLog`.

File layout: root datasets ``imu_gyr`` (rad/s), ``imu_acc`` (m/s²), ``imu_mag`` (µT) in the IMU's
own sensor axes S; ``opt_quat`` (w, x, y, z, S → ENU, NaN during marker dropouts); ``movement``
(bool, the samples BROAD's errors count); attribute ``sampling_rate`` (285.714 Hz, t = index /
rate); attribute ``info`` (its ``Trial:`` line names the trial).

Frames. The sensor at rest with z up reads ``imu_acc`` ≈ (0, 0, +9.81), i.e. S is "z up". Our body
frame B is FRD-like: S turned 180° about its x axis, ``v_B = (x, -y, -z)_S``, so the same sensor
at rest reads (0, 0, -9.81) like a level vehicle. The earth frame goes ENU → NED
(``v_N = (E_y, E_x, -E_z)``). With Hamilton, scalar-first quaternions (``q_ab`` maps b-vectors to
a):

    q_NB = q_NE ⊗ q_ES ⊗ q_SB,   q_NE = (0, √½, √½, 0),   q_SB = q_BS = (0, 1, 0, 0)
    gyr_B = q_BS ⊗ gyr_S ⊗ q_BS*  (same for acc and mag)

Both fixed rotations are stored in ``meta`` (``broad_q_sensor_body_wxyz``,
``broad_q_ned_enu_wxyz``) so an evaluator can go back: ``q_ES = q_NE* ⊗ q_NB ⊗ q_SB*``.

NaN reference samples stay NaN (the assembler never interpolates across reference gaps longer than
2.5 samples; BROAD's dropouts are ≥ 3 samples long in the shared trials). ``movement`` becomes the
record's ``valid`` column.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ..errors import ConfigError, CorruptLog, NoImuData
from ..quat import quat_conj, quat_mul, quat_rotate
from .streams import ImuStream, MagStream, RawLog, RefStream

#: q_SB: body (FRD-like) → sensor axes; 180° about x, its own inverse (up to sign).
Q_SENSOR_BODY_WXYZ = np.array([0.0, 1.0, 0.0, 0.0])
#: q_NE: ENU → NED; swaps the horizontal axes and flips the vertical (180° about (1, 1, 0)/√2).
Q_NED_ENU_WXYZ = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])

REQUIRED = ("imu_gyr", "imu_acc", "opt_quat", "movement")


def sensor_to_body(v_s: np.ndarray, q_sensor_body: np.ndarray = Q_SENSOR_BODY_WXYZ) -> np.ndarray:
    """Vectors in sensor axes → body axes: ``v_B = q_SB* ⊗ v_S ⊗ q_SB``."""
    v_s = np.asarray(v_s, np.float64)
    return quat_rotate(np.broadcast_to(quat_conj(q_sensor_body), v_s.shape[:-1] + (4,)), v_s)


def q_nb_from_q_es(
    q_es: np.ndarray, q_sensor_body: np.ndarray = Q_SENSOR_BODY_WXYZ, q_ned_enu: np.ndarray = Q_NED_ENU_WXYZ
) -> np.ndarray:
    """BROAD's ``opt_quat`` (S → ENU) → ``q_NB = q_NE ⊗ q_ES ⊗ q_SB`` (body → NED); NaN stays NaN."""
    q_es = np.asarray(q_es, np.float64)
    shape = q_es.shape
    return quat_mul(np.broadcast_to(q_ned_enu, shape), quat_mul(q_es, np.broadcast_to(q_sensor_body, shape)))


def q_es_from_q_nb(
    q_nb: np.ndarray, q_sensor_body: np.ndarray = Q_SENSOR_BODY_WXYZ, q_ned_enu: np.ndarray = Q_NED_ENU_WXYZ
) -> np.ndarray:
    """Inverse of :func:`q_nb_from_q_es`: an estimate body → NED back to BROAD's sensor → ENU."""
    q_nb = np.asarray(q_nb, np.float64)
    shape = q_nb.shape
    q_en = quat_conj(np.broadcast_to(q_ned_enu, shape))
    return quat_mul(q_en, quat_mul(q_nb, quat_conj(np.broadcast_to(q_sensor_body, shape))))


def trial_name(info: str, path: str | os.PathLike) -> str:
    """'01_undisturbed_slow_rotation_A' from the ``info`` attribute's ``Trial:`` line, else the file name."""
    m = re.search(r"^\s*Trial:\s*(\S+)", info or "", re.MULTILINE)
    if m:
        return m.group(1)
    return re.sub(r"^broad_", "", Path(path).stem)


def _read_arrays(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], float, str]:
    import h5py

    try:
        with h5py.File(path, "r") as h:
            missing = [k for k in REQUIRED if k not in h]
            if missing:
                raise CorruptLog(f"HDF5 file is not a BROAD trial: no dataset(s) {', '.join(missing)}", path)
            names = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement")
            arrays = {k: np.asarray(h[k][()]) for k in names if k in h}
            if "sampling_rate" not in h.attrs:
                raise CorruptLog("BROAD trial without the 'sampling_rate' attribute", path)
            rate = float(np.asarray(h.attrs["sampling_rate"]).ravel()[0])
            info = h.attrs.get("info", "")
            info = info.decode(errors="replace") if isinstance(info, bytes) else str(info)
    except CorruptLog:
        raise
    except Exception as exc:  # h5py raises OSError, KeyError, ValueError, ... on damaged files
        msg = str(exc).strip().splitlines()
        reason = f"unreadable HDF5 file ({type(exc).__name__}: {msg[0] if msg else 'no message'})"
        raise CorruptLog(reason, path) from None
    return arrays, rate, info


def read(path: str | os.PathLike, imu: int | None = None, reference: str | None = None) -> RawLog:
    """Read a BROAD trial into body-FRD / NED streams (see the module docstring)."""
    arrays, rate, info = _read_arrays(path)
    if imu not in (None, 0):
        raise NoImuData(f"IMU instance {imu} is not in a BROAD trial; instances: 0 (imu_gyr/imu_acc, {rate:.1f} Hz)")
    if reference not in (None, "optitrack", "opt_quat"):
        raise ConfigError(f"reference {reference!r} is not in a BROAD trial; available: optitrack (opt_quat)")
    gyr, acc, q_es, movement = (arrays[k] for k in ("imu_gyr", "imu_acc", "opt_quat", "movement"))
    n = len(gyr)
    shapes_ok = gyr.shape == (n, 3) and acc.shape == (n, 3) and q_es.shape == (n, 4) and movement.shape == (n,)
    mag_s = arrays.get("imu_mag")
    if mag_s is not None and mag_s.shape != (n, 3):
        shapes_ok = False
    if not shapes_ok:
        raise CorruptLog("BROAD datasets have inconsistent shapes: "
                         + ", ".join(f"{k} {v.shape}" for k, v in arrays.items()), path)  # fmt: skip
    if n == 0:
        raise NoImuData("BROAD trial with no samples", path)
    if not (np.isfinite(rate) and rate > 0):
        raise CorruptLog(f"BROAD sampling_rate {rate!r} is not a positive number", path)

    t_s = np.arange(n, dtype=np.float64) / rate
    imu_stream = ImuStream(t_s, sensor_to_body(gyr), sensor_to_body(acc), np.zeros(n, bool))
    mag = None if mag_s is None else MagStream(t_s, sensor_to_body(mag_s))
    ref = RefStream(t_s, q_nb_from_q_es(q_es), "optitrack")
    nan_ref = int(np.count_nonzero(~np.all(np.isfinite(q_es), axis=1)))
    trial = trial_name(info, path)
    meta = {
        "source_kind": "broad",
        "vehicle_type": "handheld-imu",
        "autopilot": "none",
        "firmware": "none",
        "imu_instance": 0,
        "imu_instances": [{"instance": 0, "name": "imu_gyr/imu_acc (myon aktos-t)", "samples": n, "rate_hz": rate}],
        "reference_candidates": ["optitrack"],
        "broad_trial": trial,
        "broad_sampling_rate_hz": rate,
        "broad_q_sensor_body_wxyz": Q_SENSOR_BODY_WXYZ.tolist(),
        "broad_q_ned_enu_wxyz": Q_NED_ENU_WXYZ.tolist(),
        "broad_earth_frame_conversion": (
            "q_NB = q_NE * q_ES * q_SB with q_ES = opt_quat (sensor -> ENU), q_NE = broad_q_ned_enu_wxyz "
            "(ENU -> NED), q_SB = broad_q_sensor_body_wxyz (body = sensor turned 180 deg about x: "
            "v_B = (x, -y, -z)_S); back: q_ES = conj(q_NE) * q_NB * conj(q_SB)"
        ),
        "broad_reference_nan_samples": nan_ref,
        "notes": [
            f"BROAD trial {trial}: hand-moved IMU with optical (OptiTrack) reference, not a flight; "
            "errors count only where valid (BROAD's movement mask) is true",
        ],
    }
    return RawLog(imu=imu_stream, mag=mag, ref=ref, meta=meta, valid=np.asarray(movement, bool))
