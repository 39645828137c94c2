"""Madgwick's gradient-descent AHRS (2010/2011 report and C code), corrected or with the original quirk.

The update is a line-by-line transcription of ``MadgwickAHRS.c`` (``update`` for 9-D, ``updateIMU``
for 6-D), in float64, written in our frames: the "accelerometer" the algorithm sees is the measured
**down** direction ``-acc`` (specific force points up at rest), so its earth frame — z along the
gravity reference, x along the horizontal magnetic field — is NED (magnetic north) and its state is
``q_nb`` (body FRD → NED). Madgwick's update is equivariant under fixed rotations of the body and
earth frames, so this gives exactly the attitude the C code would give on the same data in its own
z-up frame, re-expressed (checked against BROAD's published numbers in
:mod:`tepinn_flight.evaluation.broad_benchmark`).

**The quirk.** The original C code computes ``_2bx = sqrt(hx² + hy²)`` and ``_2bz = hz`` although the
gradient formulas that follow need twice those values (BROAD issue #1, arduino MadgwickAHRS #50,
Reefwing #13): the magnetometer part of the objective then compares the measurement with a
reference field of *half* its length. ``original_quirk=True`` keeps it (needed to reproduce BROAD's
published numbers); the default is the corrected filter. The 6-D update has no such factor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ...errors import ConfigError
from .common import as_tuple4, check_inputs, initial_attitude


@dataclass(frozen=True)
class MadgwickParams:
    beta: float = 0.1  # gradient step gain, rad/s (β = √(3/4)·gyro error); BROAD's TAGP is 0.12
    original_quirk: bool = False  # True: the C code's missing factor 2 in bx/bz (9-D only)

    def __post_init__(self):
        if not (math.isfinite(self.beta) and self.beta >= 0):
            raise ConfigError(f"madgwick.beta must be a finite number >= 0, got {self.beta!r}")


class Madgwick:
    name = "madgwick"

    def __init__(self, params: MadgwickParams | None = None):
        self.params = params or MadgwickParams()

    def estimate(self, gyr, acc, t_s, mag=None, q0=None) -> dict:
        gyr, acc, dt, mag = check_inputs(gyr, acc, t_s, mag)
        if q0 is None:
            i = int(np.argmax(np.linalg.norm(acc, axis=1) > 0)) if len(acc) else 0
            q0 = initial_attitude(acc[i], None if mag is None else mag[i]) if len(acc) else [1, 0, 0, 0]
        k = 1.0 if self.params.original_quirk else 2.0
        q = _run(gyr, -acc, np.zeros((0, 3)) if mag is None else mag, dt, float(self.params.beta), k, as_tuple4(q0))
        return {"q_nb_wxyz": q}


@njit(cache=True)
def _run(gyr, acc, mag, dt, beta, k, q):
    """The per-sample loop (compiled; float64 arrays in, (n, 4) out). ``acc`` is the gravity
    direction (earth +z in body); ``mag`` with no rows: 6-D."""
    n = len(gyr)
    out = np.empty((n, 4))
    q0, q1, q2, q3 = q
    sqrt = math.sqrt
    has_mag = len(mag) > 0
    for i in range(n):
        gx, gy, gz = gyr[i, 0], gyr[i, 1], gyr[i, 2]
        ax, ay, az = acc[i, 0], acc[i, 1], acc[i, 2]
        h = dt[i]
        qd1 = 0.5 * (-q1 * gx - q2 * gy - q3 * gz)
        qd2 = 0.5 * (q0 * gx + q2 * gz - q3 * gy)
        qd3 = 0.5 * (q0 * gy - q1 * gz + q3 * gx)
        qd4 = 0.5 * (q0 * gz + q1 * gy - q2 * gx)
        if ax != 0.0 or ay != 0.0 or az != 0.0:
            r = 1.0 / sqrt(ax * ax + ay * ay + az * az)
            ax *= r
            ay *= r
            az *= r
            if has_mag:
                mx, my, mz = mag[i, 0], mag[i, 1], mag[i, 2]
            else:
                mx = my = mz = 0.0
            if mx != 0.0 or my != 0.0 or mz != 0.0:
                r = 1.0 / sqrt(mx * mx + my * my + mz * mz)
                mx *= r
                my *= r
                mz *= r
                _2q0mx = 2.0 * q0 * mx
                _2q0my = 2.0 * q0 * my
                _2q0mz = 2.0 * q0 * mz
                _2q1mx = 2.0 * q1 * mx
                _2q0 = 2.0 * q0
                _2q1 = 2.0 * q1
                _2q2 = 2.0 * q2
                _2q3 = 2.0 * q3
                _2q0q2 = 2.0 * q0 * q2
                _2q2q3 = 2.0 * q2 * q3
                q0q0 = q0 * q0
                q0q1 = q0 * q1
                q0q2 = q0 * q2
                q0q3 = q0 * q3
                q1q1 = q1 * q1
                q1q2 = q1 * q2
                q1q3 = q1 * q3
                q2q2 = q2 * q2
                q2q3 = q2 * q3
                q3q3 = q3 * q3
                hx = mx * q0q0 - _2q0my * q3 + _2q0mz * q2 + mx * q1q1 + _2q1 * my * q2 + _2q1 * mz * q3 - mx * q2q2 - mx * q3q3
                hy = _2q0mx * q3 + my * q0q0 - _2q0mz * q1 + _2q1mx * q2 - my * q1q1 + my * q2q2 + _2q2 * mz * q3 - my * q3q3
                _2bx = k * sqrt(hx * hx + hy * hy)  # original C code: k = 1 (the quirk)
                _2bz = k * (-_2q0mx * q2 + _2q0my * q1 + mz * q0q0 + _2q1mx * q3 - mz * q1q1 + _2q2 * my * q3 - mz * q2q2 + mz * q3q3)
                _4bx = 2.0 * _2bx
                _4bz = 2.0 * _2bz
                fa1 = 2.0 * q1q3 - _2q0q2 - ax
                fa2 = 2.0 * q0q1 + _2q2q3 - ay
                fa3 = 1.0 - 2.0 * q1q1 - 2.0 * q2q2 - az
                fm1 = _2bx * (0.5 - q2q2 - q3q3) + _2bz * (q1q3 - q0q2) - mx
                fm2 = _2bx * (q1q2 - q0q3) + _2bz * (q0q1 + q2q3) - my
                fm3 = _2bx * (q0q2 + q1q3) + _2bz * (0.5 - q1q1 - q2q2) - mz
                s0 = -_2q2 * fa1 + _2q1 * fa2 - _2bz * q2 * fm1 + (-_2bx * q3 + _2bz * q1) * fm2 + _2bx * q2 * fm3
                s1 = _2q3 * fa1 + _2q0 * fa2 - 4.0 * q1 * fa3 + _2bz * q3 * fm1 + (_2bx * q2 + _2bz * q0) * fm2 + (_2bx * q3 - _4bz * q1) * fm3
                s2 = -_2q0 * fa1 + _2q3 * fa2 - 4.0 * q2 * fa3 + (-_4bx * q2 - _2bz * q0) * fm1 + (_2bx * q1 + _2bz * q3) * fm2 + (_2bx * q0 - _4bz * q2) * fm3
                s3 = _2q1 * fa1 + _2q2 * fa2 + (-_4bx * q3 + _2bz * q1) * fm1 + (-_2bx * q0 + _2bz * q2) * fm2 + _2bx * q1 * fm3
            else:
                _2q0 = 2.0 * q0
                _2q1 = 2.0 * q1
                _2q2 = 2.0 * q2
                _2q3 = 2.0 * q3
                _4q0 = 4.0 * q0
                _4q1 = 4.0 * q1
                _4q2 = 4.0 * q2
                _8q1 = 8.0 * q1
                _8q2 = 8.0 * q2
                q0q0 = q0 * q0
                q1q1 = q1 * q1
                q2q2 = q2 * q2
                q3q3 = q3 * q3
                s0 = _4q0 * q2q2 + _2q2 * ax + _4q0 * q1q1 - _2q1 * ay
                s1 = _4q1 * q3q3 - _2q3 * ax + 4.0 * q0q0 * q1 - _2q0 * ay - _4q1 + _8q1 * q1q1 + _8q1 * q2q2 + _4q1 * az
                s2 = 4.0 * q0q0 * q2 + _2q0 * ax + _4q2 * q3q3 - _2q3 * ay - _4q2 + _8q2 * q1q1 + _8q2 * q2q2 + _4q2 * az
                s3 = 4.0 * q1q1 * q3 - _2q1 * ax + 4.0 * q2q2 * q3 - _2q2 * ay
            ns = s0 * s0 + s1 * s1 + s2 * s2 + s3 * s3
            if ns > 0.0:
                r = beta / sqrt(ns)
                qd1 -= r * s0
                qd2 -= r * s1
                qd3 -= r * s2
                qd4 -= r * s3
        q0 += qd1 * h
        q1 += qd2 * h
        q2 += qd3 * h
        q3 += qd4 * h
        r = 1.0 / sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        q0 *= r
        q1 *= r
        q2 *= r
        q3 *= r
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = q0, q1, q2, q3
    return out
