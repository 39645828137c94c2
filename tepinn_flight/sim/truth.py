"""Noise-free truth trajectory produced by the flight-dynamics simulation.

All arrays are SI, body frame FRD, earth frame NED, quaternions Hamilton scalar-first
rotating body FRD -> NED (``q_nb_wxyz``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class TruthTrajectory:
    t_s: np.ndarray             # (N,) float64, 0, 1/rate, 2/rate, ... (sample times of the IMU)
    q_nb_wxyz: np.ndarray       # (N, 4) true attitude body FRD -> NED, unit
    gyr_true_rad_s: np.ndarray  # (N, 3) true body angular rate (the noise-free gyro), body FRD
    acc_true_m_s2: np.ndarray   # (N, 3) true specific force, body FRD (level at rest: z ~ -9.81)
    mag_earth_ut: np.ndarray    # (3,) Earth magnetic field in NED, uT (site constant, from the seed)
    pos_ned_m: np.ndarray       # (N, 3) position, NED from the start point
    vel_ned_m_s: np.ndarray     # (N, 3)
    maneuvers: list = field(default_factory=list)  # [(t_start_s, t_end_s, name), ...] in order
    meta: dict = field(default_factory=dict)       # aircraft, vehicle_type, seed, rate_hz,
    # jsbsim_version, termination ("completed" or the clean stop reason), ...

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def rate_hz(self) -> float:
        return float(self.meta.get("rate_hz", 0.0))
