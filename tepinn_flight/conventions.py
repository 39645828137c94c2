"""Frames, quaternion order and units: one definition for the whole project.

Frames
    body  : FRD — x forward, y right, z down, fixed to the vehicle (or to the IMU's sensor axes).
    earth : NED — x north, y east, z down, local tangent plane.

Quaternions
    Hamilton product, scalar first: ``q = (w, x, y, z)``.
    ``q_nb_wxyz`` rotates body (FRD) vectors into earth (NED): ``v_n = q ⊗ v_b ⊗ q*``.
    q and -q are the same attitude (double cover); we canonicalise to ``w >= 0`` only where a
    unique representative is needed (e.g. writing records), never inside estimation.

Euler angles
    roll, pitch, yaw in radians, aerospace Z-Y-X (yaw about NED z, then pitch, then roll):
    ``q_nb = qz(yaw) ⊗ qy(pitch) ⊗ qx(roll)``. ArduPilot ATT, MAVLink ATTITUDE and JSBSim
    all use this sequence.

Units (SI, converted only at the edges — readers and writers)
    time            s        (``t_s``)
    angular rate    rad/s    (``gyr_*_rad_s``)
    accelerometer   m/s², specific force (a level vehicle at rest reads z ≈ -9.81)
    magnetometer    µT       (``mag_*_ut``; 1 gauss = 100 µT, 1 mGauss = 0.1 µT)
"""

from __future__ import annotations

import numpy as np

BODY_FRAME = "FRD"
EARTH_FRAME = "NED"
QUATERNION_ORDER = "wxyz"
QUATERNION_CONVENTION = "hamilton"
ROTATION_DIRECTION = "body_to_earth"

#: Standard gravity, m/s².
GRAVITY_M_S2 = 9.80665

#: Unit conversions applied by readers.
MILLI_G_TO_M_S2 = GRAVITY_M_S2 / 1000.0
MRAD_S_TO_RAD_S = 1e-3
GAUSS_TO_UT = 100.0
MILLIGAUSS_TO_UT = 0.1
FT_TO_M = 0.3048
DEG_TO_RAD = np.pi / 180.0

#: q_ENU←NED: swaps north/east and negates down; R = [[0,1,0],[1,0,0],[0,0,-1]].
Q_ENU_FROM_NED_WXYZ = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])

#: Time values above this (µs) are UNIX time rather than time since boot.
UNIX_TIME_THRESHOLD_US = 1e15


def describe() -> dict:
    """The conventions as a small dict, stored in records and checkpoints."""
    return {
        "body_frame": BODY_FRAME,
        "earth_frame": EARTH_FRAME,
        "quaternion_order": QUATERNION_ORDER,
        "quaternion_convention": QUATERNION_CONVENTION,
        "rotation": ROTATION_DIRECTION,
        "units": {"time": "s", "gyr": "rad/s", "acc": "m/s^2 (specific force)", "mag": "uT"},
    }
