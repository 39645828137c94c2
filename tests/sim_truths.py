"""Closed-form noise-free trajectories for sensor-model tests (no JSBSim)."""

from __future__ import annotations

import numpy as np

from tepinn_flight.conventions import GRAVITY_M_S2
from tepinn_flight.quat import quat_conj, quat_from_euler_zyx, quat_rotate
from tepinn_flight.sim.truth import TruthTrajectory

MAG_EARTH_UT = np.array([21.0, 1.5, 43.0])


def static_truth(n: int, rate_hz: float) -> TruthTrajectory:
    """Level and at rest: zero rates, specific force (0, 0, -g)."""
    t = np.arange(n) / rate_hz
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    acc = np.tile([0.0, 0.0, -GRAVITY_M_S2], (n, 1))
    return _truth(t, q, np.zeros((n, 3)), acc, rate_hz)


def wobble_truth(n: int, rate_hz: float, extra_acc: bool = True) -> TruthTrajectory:
    """Roll/pitch oscillations and a steady yaw turn; body rates from the Euler rates in closed form.

    The specific force is gravity seen in the body plus (optionally) sinusoidal translational terms,
    so that an affine least-squares fit of the accelerometer is well conditioned.
    """
    t = np.arange(n) / rate_hz
    w1, w2, w3 = 2 * np.pi * 0.31, 2 * np.pi * 0.17, 2 * np.pi * 0.23
    phi, phid = 0.6 * np.sin(w1 * t), 0.6 * w1 * np.cos(w1 * t)
    th, thd = 0.4 * np.sin(w2 * t + 0.5), 0.4 * w2 * np.cos(w2 * t + 0.5)
    psi, psid = 0.8 * t + 0.3 * np.sin(w3 * t), 0.8 + 0.3 * w3 * np.cos(w3 * t)
    p = phid - psid * np.sin(th)
    q_ = thd * np.cos(phi) + psid * np.cos(th) * np.sin(phi)
    r = -thd * np.sin(phi) + psid * np.cos(th) * np.cos(phi)
    q = quat_from_euler_zyx(phi, th, psi)
    acc = quat_rotate(quat_conj(q), np.broadcast_to([0.0, 0.0, -GRAVITY_M_S2], (n, 3)))
    if extra_acc:
        acc = acc + np.stack([2.0 * np.sin(1.3 * t), 1.5 * np.sin(0.7 * t + 1.0), 3.0 * np.sin(2.1 * t)], 1)
    return _truth(t, q, np.stack([p, q_, r], 1), acc, rate_hz)


def _truth(t, q, gyr, acc, rate_hz) -> TruthTrajectory:
    n = len(t)
    return TruthTrajectory(
        t_s=t, q_nb_wxyz=q, gyr_true_rad_s=gyr, acc_true_m_s2=acc, mag_earth_ut=MAG_EARTH_UT.copy(),
        pos_ned_m=np.zeros((n, 3)), vel_ned_m_s=np.zeros((n, 3)),
        maneuvers=[(0.0, float(t[-1]) if n else 0.0, "synthetic")],
        meta={"aircraft": "synthetic", "vehicle_type": "multirotor", "rate_hz": rate_hz, "seed": 0,
              "termination": "completed", "jsbsim_version": "none"},
    )  # fmt: skip
