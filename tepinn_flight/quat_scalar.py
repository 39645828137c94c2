"""Scalar quaternion formulas compiled with numba, for the per-sample loops (the older fusion, the
baseline filters, the simulated multirotor's controller, the anchored VQF's kernels): Hamilton
product, normalisation, the exponential of a body rotation vector, the gravity direction in body
axes, a quaternion's rotation matrix, Euler angles and rotation matrices to quaternions. Plain floats in, tuples out; callable from Python too.

The gravity, Euler and rotation-matrix formulas are :mod:`.quat`'s own ``_down_in_body``,
``_euler_zyx_half_angles`` and ``_rotmat_entries`` compiled (one home for each); the others are the scalar forms of
:func:`.quat.quat_mul`, :func:`.quat.quat_normalize`, :func:`.quat.quat_from_rotvec`'s closed form
and :func:`.quat.rotmat_to_quat` (Shepperd's method).
"""

from __future__ import annotations

import math

from numba import njit

from .quat import _down_in_body, _euler_zyx_half_angles, _rotmat_entries

down_in_body = njit(cache=True)(_down_in_body)
euler_zyx_half_angles = njit(cache=True)(_euler_zyx_half_angles)
rotmat_entries = njit(cache=True)(_rotmat_entries)  # R of a unit quaternion, its nine entries row by row


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


@njit(cache=True)
def rotmat_to_quat(m00, m01, m02, m10, m11, m12, m20, m21, m22):
    """Rotation matrix (rows given as scalars) -> quaternion by Shepperd's method: the branch of the
    positive trace when it is positive, else that of the largest diagonal term. The sign is
    whatever the branch gives (not made canonical, unlike :func:`.quat.rotmat_to_quat`)."""
    tr = m00 + m11 + m22
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        return (0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s)
    if m00 > m11 and m00 > m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        return ((m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s)
    if m11 > m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        return ((m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s)
    s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
    return ((m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s)


@njit(cache=True)
def qrot(qw, qx, qy, qz, vx, vy, vz):
    """Rotate a vector by a unit quaternion, ``q ⊗ v ⊗ q*`` (:func:`.quat.quat_rotate`'s form:
    ``v + w t + u × t``, ``t = 2 u × v``)."""
    tx = 2.0 * (qy * vz - qz * vy)
    ty = 2.0 * (qz * vx - qx * vz)
    tz = 2.0 * (qx * vy - qy * vx)
    return (vx + qw * tx + (qy * tz - qz * ty),
            vy + qw * ty + (qz * tx - qx * tz),
            vz + qw * tz + (qx * ty - qy * tx))  # fmt: skip
