"""ArduPilot's level trim: the attitude it reports is the vehicle's, its IMU data are the board's.

ArduPilot's level calibration stores the board's roll and pitch relative to the vehicle in the
parameters ``AHRS_TRIM_X`` and ``AHRS_TRIM_Y`` (rad). The IMU data it logs and streams (DataFlash
``IMU``, MAVLink ``RAW_IMU``/``SCALED_IMU*``) are in the board's frame (after ``AHRS_ORIENTATION``),
and so are the EKF cores' own quaternions (DataFlash ``XKQ``/``NKQ``). Every attitude it *reports*
is the vehicle's, the trim away: DataFlash ``ATT``, ``AHR2`` and the EKF's Euler logs
(``XKF1``/``NKF1``/``EKF1``), MAVLink ``ATTITUDE`` and ``ATTITUDE_QUATERNION``, with

    R_board→NED = R_vehicle→NED · R(roll = trim_x, pitch = trim_y, yaw = 0).

Measured on ``ardusub_small.BIN`` (trims 1.54° and 1.55°): ATT, AHR2 and XKF1 are 2.2° from XKQ
before this turn and 0.01–0.02° after it; on the ArduSub tlogs VQF's distance to ``ATTITUDE`` falls
from 2.3° to 1.2–1.5°. A reference the autopilot reports in the vehicle's frame is therefore turned
into the board's, the frame of the IMU data every estimator reads (none of them can see the trim).
"""

from __future__ import annotations

import math

import numpy as np

from ..quat import quat_from_euler_zyx, quat_mul

#: the parameters, roll then pitch (rad); ArduPilot ignores AHRS_TRIM_Z
TRIM_PARAMS = ("AHRS_TRIM_X", "AHRS_TRIM_Y")


def trim_quat(trim_x_rad: float, trim_y_rad: float) -> np.ndarray:
    """The board's attitude in the vehicle's frame (w, x, y, z)."""
    return quat_from_euler_zyx(np.float64(trim_x_rad), np.float64(trim_y_rad), np.float64(0.0))


def vehicle_to_board(q_nv_wxyz: np.ndarray, trim_x_rad: float, trim_y_rad: float) -> np.ndarray:
    """(n, 4) vehicle→NED quaternions → board→NED (the IMU's frame)."""
    return quat_mul(np.asarray(q_nv_wxyz, np.float64), trim_quat(trim_x_rad, trim_y_rad))


def usable_trim(trim_x_rad, trim_y_rad) -> tuple[float, float] | None:
    """The trim as two floats when at least one is known, finite and non-zero (a missing one is 0),
    else None (nothing to turn)."""
    vals = [0.0 if v is None else float(v) for v in (trim_x_rad, trim_y_rad)]
    if not all(math.isfinite(v) for v in vals) or not any(vals):
        return None
    return vals[0], vals[1]


def trim_note(source: str, trim: tuple[float, float]) -> str:
    return (f"reference {source} is ArduPilot's vehicle attitude: turned into the IMU board's frame by "
            f"AHRS_TRIM_X/Y = {math.degrees(trim[0]):.2f}°, {math.degrees(trim[1]):.2f}°")  # fmt: skip
