"""The network's physics head outside the ONNX graph: :meth:`~.network.TEPINN.physics_head` compiled.

An export of version 3 ends at the heads' linear layers (:meth:`~.network.TEPINN.linear_heads`):
the head quaternion, the pooling logits, the body velocity and its rate. What follows is a few
dozen float operations per token: the centripetal compensation of each token's rotated specific
force, the pooled gravity and the tilt it gives, corrected by the head quaternion. As graph operators
they were a quarter of a one-window run in onnxruntime (about two hundred tiny operators, each
with its own dispatch; session 41); here they are one compiled loop, in float64.

The formulas are :meth:`~.network.TEPINN.physics_head`'s (tested equal to it for every switch that
changes them, ``tests/test_head_physics.py``); the quaternion ones are :mod:`..quat_scalar`'s.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..quat_scalar import down_in_body, euler_zyx_half_angles, qmul, qrot
from .config import ModelConfig


def window_attitude(config: ModelConfig, graph: dict, features: dict) -> np.ndarray:
    """(B, 4) float64 attitude ``q`` of each window from an export's outputs ``graph`` (``q_head``
    (B, 4), ``pool`` (B, K), ``vel``, ``acc_v`` (B, 3)) and the runner's token features ``features``
    (``v`` (B, K, 3), ``u`` (B, K), ``cen``, ``cen_rate`` (B, K, 3, 3) as the model has them)."""
    c = config
    q_head = np.ascontiguousarray(graph["q_head"], dtype=np.float32)
    b = len(q_head)
    none3, none4 = np.zeros((b, 0, 3), np.float32), np.zeros((b, 0, 3, 3), np.float32)

    def arr(name, empty, ok=True):
        a = features.get(name) if ok else None
        return empty if a is None else np.ascontiguousarray(a, dtype=np.float32)

    physics = bool(c.physics)
    centripetal = physics and bool(c.centripetal)
    rate = centripetal and bool(c.centripetal_rate)
    learned = physics and bool(c.learned_pooling)
    pool = np.ascontiguousarray(graph["pool"], dtype=np.float32) if learned else np.zeros((b, 0), np.float32)
    return _attitude(q_head, pool, np.ascontiguousarray(graph["vel"], dtype=np.float32),
                     np.ascontiguousarray(graph["acc_v"], dtype=np.float32),
                     arr("v", none3, physics), arr("u", np.zeros((b, 0), np.float32), physics and not learned),
                     arr("cen", none4, centripetal), arr("cen_rate", none4, rate),
                     physics, centripetal, rate, learned, bool(c.correction_layer))  # fmt: skip


@njit(cache=True)
def _gravity_tilt(gx, gy, gz):
    """:func:`~.network.gravity_tilt`: the zero-yaw attitude whose gravity in body axes is g."""
    roll = math.atan2(gy, gz)
    pitch = math.atan2(-gx, math.sqrt(gy * gy + gz * gz + 1e-12))
    return euler_zyx_half_angles(math.cos(0.5 * roll), math.sin(0.5 * roll),
                                 math.cos(0.5 * pitch), math.sin(0.5 * pitch), 1.0, 0.0)  # fmt: skip


@njit(cache=True)
def _attitude(q_head, pool, vel, acc_v, v, u, cen, cen_rate, physics, centripetal, rate, learned, correction):
    b = q_head.shape[0]
    out = np.empty((b, 4))
    for i in range(b):
        qw, qx, qy, qz = float(q_head[i, 0]), float(q_head[i, 1]), float(q_head[i, 2]), float(q_head[i, 3])
        if not physics:
            if correction:
                qw, qx, qy, qz = _gravity_tilt(*down_in_body(qw, qx, qy, qz))
            out[i, 0], out[i, 1], out[i, 2], out[i, 3] = qw, qx, qy, qz
            continue
        k = v.shape[1]
        # pooling weights: the softmax of the logits (shifted by their largest), or the trust's share
        top = -np.inf
        if learned:
            for j in range(k):
                top = max(top, float(pool[i, j]))
        total = 0.0
        for j in range(k):
            total += math.exp(float(pool[i, j]) - top) if learned else float(u[i, j])
        fx = fy = fz = 0.0
        for j in range(k):
            vx, vy, vz = float(v[i, j, 0]), float(v[i, j, 1]), float(v[i, j, 2])
            if centripetal:  # gravity = a − f with a ≈ ω × v̂ (+ (t − t_K)·ω × â + â)
                for kk in range(3):
                    s = float(vel[i, kk])
                    vx -= float(cen[i, j, kk, 0]) * s
                    vy -= float(cen[i, j, kk, 1]) * s
                    vz -= float(cen[i, j, kk, 2]) * s
                    if rate:
                        r = float(acc_v[i, kk])
                        vx -= float(cen_rate[i, j, kk, 0]) * r
                        vy -= float(cen_rate[i, j, kk, 1]) * r
                        vz -= float(cen_rate[i, j, kk, 2]) * r
            w = (math.exp(float(pool[i, j]) - top) if learned else float(u[i, j])) / total
            fx += w * vx
            fy += w * vy
            fz += w * vz
        if correction:  # zero_yaw(q_base ⊗ δq) = the tilt of −f turned by δq*
            gx, gy, gz = qrot(qw, -qx, -qy, -qz, -fx, -fy, -fz)
            qw, qx, qy, qz = _gravity_tilt(gx, gy, gz)
        else:
            bw, bx, by, bz = _gravity_tilt(-fx, -fy, -fz)
            qw, qx, qy, qz = qmul(bw, bx, by, bz, qw, qx, qy, qz)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = qw, qx, qy, qz
    return out
