"""Quaternion complementary filter — the TE-PINN paper's "analytical method" baseline.

Per sample: integrate the gyro (``q ← q ⊗ exp(ω·dt)``), then turn the estimate a fraction
``α = min(1, dt/τ_acc)`` of the way toward the tilt the accelerometer indicates (rotation about the
body axis ``d × v`` between the measured down direction ``d = -acc/|acc|`` and the predicted one
``v = R_nbᵀ e_z``). With a magnetometer the heading is pulled toward magnetic north the same way
(``τ_mag``). No gyro bias state: this is the plain first-order complementary filter (Mahony with
``Ki = 0`` and an exact-angle correction), a deliberately simple analytical baseline.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ...errors import ConfigError
from ...quat_scalar import down_in_body
from .common import as_tuple4, check_inputs, initial_attitude


@dataclass(frozen=True)
class ComplementaryParams:
    tau_acc_s: float = 1.0  # time constant of the tilt correction toward the accelerometer
    tau_mag_s: float = 5.0  # time constant of the heading correction toward the magnetometer (9-D)

    def __post_init__(self):
        for k in ("tau_acc_s", "tau_mag_s"):
            v = getattr(self, k)
            if not (v > 0):
                raise ConfigError(f"complementary.{k} must be > 0, got {v!r}")


class Complementary:
    name = "complementary"

    def __init__(self, params: ComplementaryParams | None = None):
        self.params = params or ComplementaryParams()

    def estimate(self, gyr, acc, t_s, mag=None, q0=None) -> dict:
        gyr, acc, dt, mag = check_inputs(gyr, acc, t_s, mag)
        if q0 is None:
            q0 = initial_attitude(acc[0], None if mag is None else mag[0]) if len(acc) else [1, 0, 0, 0]
        q = _run(gyr, acc, np.zeros((0, 3)) if mag is None else mag, dt, self.params.tau_acc_s, self.params.tau_mag_s,
                 as_tuple4(q0))  # fmt: skip
        return {"q_nb_wxyz": q}


@njit(cache=True)
def _run(gyr, acc, mag, dt, tau_acc, tau_mag, q):
    """The per-sample loop (compiled; float64 arrays in, (n, 4) out). ``mag`` with no rows: 6-D."""
    n = len(gyr)
    out = np.empty((n, 4))
    w, x, y, z = q
    sqrt, sin, cos, atan2 = math.sqrt, math.sin, math.cos, math.atan2
    has_mag = len(mag) > 0
    for i in range(n):
        h = dt[i]
        gx, gy, gz = gyr[i, 0], gyr[i, 1], gyr[i, 2]
        # --- gyro propagation: q ⊗ exp(ω h)
        rx, ry, rz = gx * h, gy * h, gz * h
        th = sqrt(rx * rx + ry * ry + rz * rz)
        if th > 1e-12:
            c = cos(0.5 * th)
            s = sin(0.5 * th) / th
            dx, dy, dz = rx * s, ry * s, rz * s
            w, x, y, z = (w * c - x * dx - y * dy - z * dz, w * dx + x * c + y * dz - z * dy,
                          w * dy - x * dz + y * c + z * dx, w * dz + x * dy - y * dx + z * c)  # fmt: skip
        # --- tilt correction toward the accelerometer
        ax, ay, az = acc[i, 0], acc[i, 1], acc[i, 2]
        na = ax * ax + ay * ay + az * az
        if na > 0.0:
            na = -1.0 / sqrt(na)
            ax, ay, az = ax * na, ay * na, az * na  # measured down, body
            vx, vy, vz = down_in_body(w, x, y, z)  # predicted down, body
            ex, ey, ez = ay * vz - az * vy, az * vx - ax * vz, ax * vy - ay * vx  # d × v
            ne = sqrt(ex * ex + ey * ey + ez * ez)
            if ne > 1e-12:
                alpha = h / tau_acc
                if alpha > 1.0:
                    alpha = 1.0
                ang = alpha * atan2(ne, ax * vx + ay * vy + az * vz)
                s = sin(0.5 * ang) / ne
                c = cos(0.5 * ang)
                dx, dy, dz = ex * s, ey * s, ez * s
                w, x, y, z = (w * c - x * dx - y * dy - z * dz, w * dx + x * c + y * dz - z * dy,
                              w * dy - x * dz + y * c + z * dx, w * dz + x * dy - y * dx + z * c)  # fmt: skip
        # --- heading correction toward magnetic north (9-D)
        if has_mag:
            mx, my, mz = mag[i, 0], mag[i, 1], mag[i, 2]
            if mx != 0.0 or my != 0.0 or mz != 0.0:
                # horizontal field in NED: R m (first two rows)
                hx = (1 - 2 * (y * y + z * z)) * mx + 2 * (x * y - w * z) * my + 2 * (x * z + w * y) * mz
                hy = 2 * (x * y + w * z) * mx + (1 - 2 * (x * x + z * z)) * my + 2 * (y * z - w * x) * mz
                if hx * hx + hy * hy > 0.0:
                    alpha = h / tau_mag
                    if alpha > 1.0:
                        alpha = 1.0
                    ang = -alpha * atan2(hy, hx)  # earth-frame rotation about z (down)
                    c, s = cos(0.5 * ang), sin(0.5 * ang)
                    w, x, y, z = c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w
        r = 1.0 / sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w * r, x * r, y * r, z * r
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = w, x, y, z
    return out
