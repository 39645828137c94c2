"""Scalar quaternion formulas compiled with numba, for the per-sample loops (the older fusion, the
baseline filters): Hamilton product, normalisation, the exponential of a body rotation vector and
the gravity direction in body axes. Plain floats in, tuples out; callable from Python too.

The gravity formula is :mod:`.quat`'s own ``_down_in_body`` compiled (one home for it); the others
are the scalar forms of :func:`.quat.quat_mul`, :func:`.quat.quat_normalize` and
:func:`.quat.quat_from_rotvec`'s closed form.
"""

from __future__ import annotations

import math

from numba import njit

from .quat import _down_in_body

down_in_body = njit(cache=True)(_down_in_body)


@njit(cache=True)
def qmul(aw, ax, ay, az, bw, bx, by, bz):
    """Hamilton product a ⊗ b of two (w, x, y, z) quaternions given as scalars."""
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)  # fmt: skip


@njit(cache=True)
def qnorm(w, x, y, z):
    """q / |q| (divides, as the fusion always did)."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return (w / n, x / n, y / n, z / n)


@njit(cache=True)
def exp_rotvec(rx, ry, rz):
    """exp of a rotation vector (rad) as a unit quaternion; first order below 1e-12 rad."""
    th = math.sqrt(rx * rx + ry * ry + rz * rz)
    if th < 1e-12:
        return (1.0, 0.5 * rx, 0.5 * ry, 0.5 * rz)
    k = math.sin(0.5 * th) / th
    return (math.cos(0.5 * th), k * rx, k * ry, k * rz)
