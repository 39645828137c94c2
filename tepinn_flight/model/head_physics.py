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

import functools
import math

import numpy as np
from numba import njit

from ..quat_scalar import down_in_body, euler_zyx_half_angles, qmul, qrot
from .config import ModelConfig


#: stand-ins for the features a model without them does not have (never read: the switches say so)
_NONE2 = np.zeros((0, 0), np.float32)
_NONE3 = np.zeros((0, 0, 3), np.float32)
_NONE4 = np.zeros((0, 0, 3, 3), np.float32)


def _f32(a) -> np.ndarray:
    return a if type(a) is np.ndarray and a.dtype == np.float32 and a.flags.c_contiguous else np.ascontiguousarray(a, np.float32)


@functools.lru_cache(maxsize=16)
def _switches(config: ModelConfig) -> tuple[bool, bool, bool, bool, bool]:
    """(physics, centripetal, its rate term, learned pooling, correction layer) as the model has them."""
    physics = bool(config.physics)
    centripetal = physics and bool(config.centripetal)
    return (physics, centripetal, centripetal and bool(config.centripetal_rate), physics and bool(config.learned_pooling),
            bool(config.correction_layer))  # fmt: skip


def window_attitude(config: ModelConfig, graph: dict, features: dict) -> np.ndarray:
    """(B, 4) float64 attitude ``q`` of each window from an export's outputs ``graph`` (``q_head``
    (B, 4), ``pool`` (B, K), ``vel``, ``acc_v`` (B, 3)) and the runner's token features ``features``
    (``v`` (B, K, 3), ``u`` (B, K), ``cen``, ``cen_rate`` (B, K, 3, 3) as the model has them)."""
    physics, centripetal, rate, learned, correction = _switches(config)
    q_head = _f32(graph["q_head"])
    b = q_head.shape[0]
    vel, acc_v = _f32(graph["vel"]), _f32(graph["acc_v"])
    pool, v, u, cen, cen_rate = _NONE2, _NONE3, _NONE2, _NONE4, _NONE4
    if physics:  # (the compiled loop does not check its indices: the shapes are checked here)
        v, u = _f32(features["v"]), _f32(features["u"])
        k = v.shape[1]
        ok = v.shape == (b, k, 3) and u.shape == (b, k) and vel.shape == (b, 3) and acc_v.shape == (b, 3)
        if learned:
            pool = _f32(graph["pool"])
            ok = ok and pool.shape == (b, k)
        if centripetal:
            cen = _f32(features["cen"])
            ok = ok and cen.shape == (b, k, 3, 3)
        if rate:
            cen_rate = _f32(features["cen_rate"])
            ok = ok and cen_rate.shape == (b, k, 3, 3)
        if not ok:
            raise ValueError(f"physics head: mismatched shapes (q_head {q_head.shape}, v {v.shape}, u {u.shape}, "
                             f"pool {pool.shape}, cen {cen.shape}, cen_rate {cen_rate.shape})")  # fmt: skip
    if q_head.shape != (b, 4):
        raise ValueError(f"physics head: q_head of shape {q_head.shape}")
    return _attitude(q_head, pool, vel, acc_v, v, u, cen, cen_rate, physics, centripetal, rate, learned, correction)


@njit(cache=True)
def _gravity_tilt(gx, gy, gz):
    """:func:`~.network.gravity_tilt`: the zero-yaw attitude whose gravity in body axes is g."""
    roll = math.atan2(gy, gz)
    pitch = math.atan2(-gx, math.sqrt(gy * gy + gz * gz + 1e-12))
    return euler_zyx_half_angles(math.cos(0.5 * roll), math.sin(0.5 * roll),
                                 math.cos(0.5 * pitch), math.sin(0.5 * pitch), 1.0, 0.0)  # fmt: skip


@njit(cache=True, error_model="numpy")  # (a division by zero gives inf or NaN, as in the graph, not an exception)
def _attitude(q_head, pool, vel, acc_v, v, u, cen, cen_rate, physics, centripetal, rate, learned, correction):
    b = q_head.shape[0]
    k = v.shape[1]
    out = np.empty((b, 4))
    w = np.empty(k)
    for i in range(b):
        qw, qx, qy, qz = float(q_head[i, 0]), float(q_head[i, 1]), float(q_head[i, 2]), float(q_head[i, 3])
        if not physics:
            if correction:
                qw, qx, qy, qz = _gravity_tilt(*down_in_body(qw, qx, qy, qz))
            out[i, 0], out[i, 1], out[i, 2], out[i, 3] = qw, qx, qy, qz
            continue
        # pooling weights: the softmax of the logits (shifted by their largest), or the trust's share
        total = 0.0
        if learned:
            top = -np.inf
            for j in range(k):
                top = max(top, float(pool[i, j]))
            for j in range(k):
                w[j] = math.exp(float(pool[i, j]) - top)
                total += w[j]
        else:
            for j in range(k):
                w[j] = float(u[i, j])
                total += w[j]
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
            wj = w[j] / total
            fx += wj * vx
            fy += wj * vy
            fz += wj * vz
        if correction:  # zero_yaw(q_base ⊗ δq) = the tilt of −f turned by δq*
            gx, gy, gz = qrot(qw, -qx, -qy, -qz, -fx, -fy, -fz)
            qw, qx, qy, qz = _gravity_tilt(gx, gy, gz)
        else:
            bw, bx, by, bz = _gravity_tilt(-fx, -fy, -fz)
            qw, qx, qy, qz = qmul(bw, bx, by, bz, qw, qx, qy, qz)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = qw, qx, qy, qz
    return out
