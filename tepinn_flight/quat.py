"""Quaternion and rotation math, batched over leading axes, for numpy arrays and torch tensors.

Conventions (see :mod:`tepinn_flight.conventions`): Hamilton product, scalar first ``(w, x, y, z)``,
``q_nb`` maps body (FRD) vectors into earth (NED). Every function takes ``(..., 4)`` quaternions
(``(..., 3)`` vectors) and broadcasts over the leading axes. The same code runs on numpy and torch:
the array namespace is picked from the first argument, and torch is never imported here (so file
readers that use this module stay torch-free).

Functions whose derivative has a removable singularity (exp/log at angle 0) use a "safe where" so
gradients stay finite at 0 and at π.
"""

from __future__ import annotations

import math
import sys
from typing import Any

import numpy as np

Array = Any  # numpy.ndarray or torch.Tensor

_SMALL_ANGLE = 1e-4  # below this rotation-vector norm / half-angle sine, use Taylor series


# --------------------------------------------------------------------------- array namespace


def _is_torch(x: Array) -> bool:
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(x, torch.Tensor)


class _NumpyOps:
    @staticmethod
    def stack(xs, axis=-1):
        return np.stack(xs, axis=axis)

    @staticmethod
    def where(c, a, b):
        return np.where(c, a, b)

    @staticmethod
    def clip(x, lo, hi):
        return np.clip(x, lo, hi)

    sqrt = staticmethod(np.sqrt)
    sin = staticmethod(np.sin)
    cos = staticmethod(np.cos)
    atan2 = staticmethod(np.arctan2)
    asin = staticmethod(np.arcsin)
    acos = staticmethod(np.arccos)
    abs = staticmethod(np.abs)

    @staticmethod
    def sum(x, axis=-1, keepdims=False):
        return np.sum(x, axis=axis, keepdims=keepdims)

    @staticmethod
    def asarray_like(v, ref):
        return np.asarray(v, dtype=ref.dtype if np.issubdtype(ref.dtype, np.floating) else float)

    @staticmethod
    def float(x):
        x = np.asarray(x)
        return x if np.issubdtype(x.dtype, np.floating) else x.astype(np.float64)


class _TorchOps:
    def __init__(self):
        self.t = sys.modules["torch"]

    def stack(self, xs, axis=-1):
        return self.t.stack(xs, dim=axis)

    def where(self, c, a, b):
        return self.t.where(c, a, b)

    def clip(self, x, lo, hi):
        return self.t.clamp(x, lo, hi)

    def sqrt(self, x):
        return self.t.sqrt(x)

    def sin(self, x):
        return self.t.sin(x)

    def cos(self, x):
        return self.t.cos(x)

    def atan2(self, a, b):
        return self.t.atan2(a, b)

    def asin(self, x):
        return self.t.asin(x)

    def acos(self, x):
        return self.t.acos(x)

    def abs(self, x):
        return self.t.abs(x)

    def sum(self, x, axis=-1, keepdims=False):
        return self.t.sum(x, dim=axis, keepdim=keepdims)

    def asarray_like(self, v, ref):
        return self.t.as_tensor(v, dtype=ref.dtype, device=ref.device)

    def float(self, x):
        return x if x.is_floating_point() else x.double()


def _ops(x: Array):
    return _TorchOps() if _is_torch(x) else _NumpyOps()


def _split(q: Array):
    # torch: unbind (one backward op) instead of four selects (each a full-size zero-fill)
    if _is_torch(q):
        return q.unbind(-1)
    return q[..., 0], q[..., 1], q[..., 2], q[..., 3]


# --------------------------------------------------------------------------- basic algebra


# p ⊗ q as one bilinear map: component k is the sum over i, j of _HAMILTON[4 i + j, k] · p_i · q_j
_HAMILTON = np.zeros((16, 4))
for _k, _terms in enumerate(("+00 -11 -22 -33", "+01 +10 +23 -32", "+02 -13 +20 +31", "+03 +12 -21 +30")):
    for _t in _terms.split():
        _HAMILTON[4 * int(_t[1]) + int(_t[2]), _k] = 1.0 if _t[0] == "+" else -1.0
del _k, _terms, _t


def quat_mul(p: Array, q: Array) -> Array:
    """Hamilton product ``p ⊗ q`` of ``(..., 4)`` quaternions (broadcasting).

    Torch: the outer product p qᵀ times the constant ``_HAMILTON`` (the same four sums of ±p_i q_j,
    exact zeros added): a handful of tensor ops instead of some forty scalar ones, which is what the
    network's exported graph runs per window."""
    if _is_torch(p):
        outer = p.unsqueeze(-1) * q.unsqueeze(-2)  # (..., 4, 4)
        return outer.flatten(-2) @ sys.modules["torch"].as_tensor(_HAMILTON, dtype=outer.dtype, device=outer.device)
    o = _ops(p)
    pw, px, py, pz = _split(p)
    qw, qx, qy, qz = _split(q)
    return o.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ]
    )


def quat_conj(q: Array) -> Array:
    """Conjugate (= inverse for unit quaternions)."""
    o = _ops(q)
    w, x, y, z = _split(q)
    return o.stack([w, -x, -y, -z])


def quat_norm(q: Array) -> Array:
    o = _ops(q)
    return o.sqrt(o.sum(q * q, axis=-1))


def quat_normalize(q: Array, eps: float = 1e-12) -> Array:
    """Unit quaternion; a zero quaternion stays finite (divides by ``eps``)."""
    o = _ops(q)
    n = o.sqrt(o.sum(q * q, axis=-1, keepdims=True))
    return q / o.where(n > eps, n, o.asarray_like(eps, n) + 0 * n)


def quat_canonical(q: Array) -> Array:
    """The representative with ``w >= 0`` (q and -q are the same rotation)."""
    o = _ops(q)
    sign = o.where(q[..., :1] < 0, -1.0 + 0 * q[..., :1], 1.0 + 0 * q[..., :1])
    return q * sign


def quat_identity(shape: tuple = (), like: Array | None = None) -> Array:
    q = np.zeros(tuple(shape) + (4,))
    q[..., 0] = 1.0
    if like is not None and _is_torch(like):
        return _ops(like).asarray_like(q, like)
    return q


def quat_rotate(q_ab: Array, v_b: Array) -> Array:
    """Rotate vectors: ``v_a = q_ab ⊗ v_b ⊗ q_ab*`` for ``(..., 4)`` unit q and ``(..., 3)`` v."""
    o = _ops(q_ab)
    w = q_ab[..., :1]
    u = q_ab[..., 1:]
    t = 2.0 * _cross(o, u, v_b)
    return v_b + w * t + _cross(o, u, t)


def _cross(o, a: Array, b: Array) -> Array:
    ax, ay, az = a.unbind(-1) if _is_torch(a) else (a[..., 0], a[..., 1], a[..., 2])
    bx, by, bz = b.unbind(-1) if _is_torch(b) else (b[..., 0], b[..., 1], b[..., 2])
    return o.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx])


def cross(a: Array, b: Array) -> Array:
    """Cross product of ``(..., 3)`` vectors (numpy or torch)."""
    return _cross(_ops(a), a, b)


def _rotmat_entries(w, x, y, z):
    """The formula of :func:`quat_to_rotmat` on components (arrays or floats): R's nine entries,
    row by row."""
    return (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )  # fmt: skip


def quat_to_rotmat(q: Array) -> Array:
    """``(..., 4)`` unit quaternion → ``(..., 3, 3)`` rotation matrix R with ``v_a = R v_b``."""
    o = _ops(q)
    r = _rotmat_entries(*_split(q))
    rows = [o.stack(list(r[0:3])), o.stack(list(r[3:6])), o.stack(list(r[6:9]))]
    return o.stack(rows, axis=-2)


def rotmat_to_quat(m: Array) -> Array:
    """``(..., 3, 3)`` rotation matrix → unit quaternion with ``w >= 0`` (Shepperd's method)."""
    o = _ops(m)
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    tr = m00 + m11 + m22
    # four candidates, each well conditioned where its diagonal term is the largest
    cands = [
        o.stack([1 + tr, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]]),
        o.stack([m[..., 2, 1] - m[..., 1, 2], 1 + m00 - m11 - m22, m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0]]),
        o.stack([m[..., 0, 2] - m[..., 2, 0], m[..., 0, 1] + m[..., 1, 0], 1 - m00 + m11 - m22, m[..., 1, 2] + m[..., 2, 1]]),
        o.stack([m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1], 1 - m00 - m11 + m22]),
    ]  # fmt: skip
    diag = o.stack([tr, m00, m11, m22])
    best = diag.argmax(-1) if not _is_torch(m) else diag.argmax(dim=-1)
    q = cands[0]
    for k in (1, 2, 3):
        q = o.where((best == k)[..., None], cands[k], q)
    return quat_canonical(quat_normalize(q))


# --------------------------------------------------------------------------- exp / log


def quat_from_rotvec(r: Array) -> Array:
    """Rotation vector (axis × angle, rad, ``(..., 3)``) → unit quaternion. Finite gradient at 0."""
    o = _ops(r)
    r = o.float(r)
    th2 = o.sum(r * r, axis=-1)
    small = th2 < _SMALL_ANGLE**2
    th = o.sqrt(o.where(small, 1.0 + 0 * th2, th2))  # safe sqrt: never sqrt(0)
    half = 0.5 * th
    # sin(θ/2)/θ and its Taylor series 1/2 - θ²/48
    k = o.where(small, 0.5 - th2 / 48.0, o.sin(half) / th)
    w = o.where(small, 1.0 - th2 / 8.0, o.cos(half))
    return o.stack([w, k * r[..., 0], k * r[..., 1], k * r[..., 2]])


def quat_to_rotvec(q: Array) -> Array:
    """Unit quaternion → rotation vector with angle in [0, π] (canonical ``w >= 0``)."""
    return quat_log(quat_canonical(q))


def quat_log(q: Array) -> Array:
    """Unit quaternion → rotation vector ``2·atan2(|v|, w)·v/|v|`` (angle in [0, 2π) when w < 0).

    Finite value and gradient at angle 0 (Taylor branch) and at π (w = 0 is regular here).
    """
    o = _ops(q)
    w = q[..., 0]
    v = q[..., 1:]
    n2 = o.sum(v * v, axis=-1)
    small = n2 < _SMALL_ANGLE**2
    n = o.sqrt(o.where(small, 1.0 + 0 * n2, n2))
    # w only enters the Taylor branch; elsewhere use 1 so the unused branch has no 1/0 (NaN grads)
    w_safe = o.where(small, o.where(w < 0, -1.0 + 0 * w, 1.0 + 0 * w) * o.clip(o.abs(w), 1e-12, None), 1.0 + 0 * w)
    # 2·atan2(n, w)/n, Taylor near n = 0: 2/w · (1 - n²/(3w²))
    k = o.where(small, 2.0 / w_safe * (1.0 - n2 / (3.0 * w_safe * w_safe)), 2.0 * o.atan2(n, w) / n)
    return v * k[..., None]


def quat_angle(q: Array) -> Array:
    """Rotation angle in [0, π] of a unit quaternion (double-cover invariant)."""
    o = _ops(q)
    n = o.sqrt(o.sum(q[..., 1:] ** 2, axis=-1))
    return 2.0 * o.atan2(n, o.abs(q[..., 0]))


def quat_angle_between(p: Array, q: Array) -> Array:
    """Angle (rad, [0, π]) of the rotation taking q to p; q ≡ -q."""
    return quat_angle(quat_mul(p, quat_conj(q)))


# --------------------------------------------------------------------------- Euler angles


def quat_from_euler_zyx(roll: Array, pitch: Array, yaw: Array) -> Array:
    """Aerospace Z-Y-X Euler angles (rad) → ``q_nb = qz(yaw) ⊗ qy(pitch) ⊗ qx(roll)``."""
    o = _ops(roll)
    roll, pitch, yaw = o.float(roll), o.float(pitch), o.float(yaw)
    cr, sr = o.cos(0.5 * roll), o.sin(0.5 * roll)
    cp, sp = o.cos(0.5 * pitch), o.sin(0.5 * pitch)
    cy, sy = o.cos(0.5 * yaw), o.sin(0.5 * yaw)
    return o.stack(list(_euler_zyx_half_angles(cr, sr, cp, sp, cy, sy)))


def _euler_zyx_half_angles(cr, sr, cp, sp, cy, sy):
    """The formula of :func:`quat_from_euler_zyx` on the half angles' cosines and sines: arrays or floats."""
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def quat_from_euler_zyx_f(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """:func:`quat_from_euler_zyx` for one set of float angles, without numpy (per-step loops: the
    simulated multirotor's controller)."""
    return _euler_zyx_half_angles(math.cos(0.5 * roll), math.sin(0.5 * roll), math.cos(0.5 * pitch),
                                  math.sin(0.5 * pitch), math.cos(0.5 * yaw), math.sin(0.5 * yaw))  # fmt: skip


def quat_to_euler_zyx(q: Array) -> tuple[Array, Array, Array]:
    """Unit ``q_nb`` → (roll, pitch, yaw) in rad; roll, yaw in (-π, π], pitch in [-π/2, π/2]."""
    o = _ops(q)
    w, x, y, z = _split(q)
    sp = 2 * (w * y - z * x)
    roll = o.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = o.asin(o.clip(sp, -1.0, 1.0))
    yaw = o.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    # gimbal lock (pitch = ±90°): only roll ∓ yaw is defined and both atan2 above lose it; report
    # it as roll with yaw = 0 (the q·qᵀ terms are rounding noise there)
    lock = o.abs(sp) >= 1.0 - 1e-14
    r2 = 2 * o.atan2(x, w)
    roll = o.where(lock, o.atan2(o.sin(r2), o.cos(r2)), roll)
    yaw = o.where(lock, 0.0 * yaw, yaw)
    return roll, pitch, yaw


def quat_zero_yaw(q: Array) -> Array:
    """Keep roll and pitch, set yaw to 0 (the paper's attitude correction, via Euler angles)."""
    roll, pitch, _ = quat_to_euler_zyx(q)
    return quat_from_euler_zyx(roll, pitch, 0.0 * roll)


def quat_about_z(angle: Array) -> Array:
    """Rotation by ``angle`` (rad) about the earth z (down) axis."""
    o = _ops(angle)
    angle = o.float(angle)
    z = 0.0 * angle
    return o.stack([o.cos(0.5 * angle), z, z, o.sin(0.5 * angle)])


# --------------------------------------------------------------------------- derived quantities


def _down_in_body(w, x, y, z):
    """The formula of :func:`gravity_body` (unit down, body axes) on components: arrays or floats."""
    return 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)


def gravity_body(q_nb: Array, g: float = 1.0) -> Array:
    """Earth 'down' (0, 0, g) expressed in body axes: ``R_nbᵀ (0, 0, g)``.

    The accelerometer of a vehicle at rest reads the negative of ``gravity_body(q, 9.81)``.
    """
    o = _ops(q_nb)
    down = o.stack(list(_down_in_body(*_split(q_nb))))
    return down if g == 1.0 else g * down


def gravity_body_f(q) -> tuple[float, float, float]:
    """:func:`gravity_body` (g = 1) for one (w, x, y, z) tuple of floats, without numpy: the
    per-sample loops (fusion, live inputs, baseline filters) use it."""
    return _down_in_body(*q)


def inclination_heading_split(q_err: Array) -> tuple[Array, Array]:
    """Split an earth-frame error quaternion into (inclination, heading) angles in rad.

    heading = 2·atan(|z/w|) (rotation about earth vertical), inclination = 2·acos(√(w² + z²)).
    """
    o = _ops(q_err)
    w, _, _, z = _split(q_err)
    heading = 2.0 * o.atan2(o.abs(z), o.abs(w))
    inclination = 2.0 * o.acos(o.clip(o.sqrt(w * w + z * z), 0.0, 1.0))
    return inclination, heading


def body_rates_from_quats(q_nb: Array, dt_s: Array) -> Array:
    """Mean body angular rate between consecutive attitudes: ``2·log(q_k* ⊗ q_{k+1}) / dt``.

    ``q_nb`` is ``(N, 4)``, ``dt_s`` is ``(N-1,)`` (or scalar); returns ``(N-1, 3)`` rad/s.
    """
    dq = quat_mul(quat_conj(q_nb[:-1]), q_nb[1:])
    return quat_to_rotvec(dq) / (dt_s[..., None] if hasattr(dt_s, "shape") and dt_s.ndim else dt_s)


# --------------------------------------------------------------------------- interpolation (numpy)


def slerp(t_query: np.ndarray, t_knots: np.ndarray, q_knots: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of ``(M, 4)`` knots at increasing ``t_knots`` onto ``t_query``.

    Query times outside ``[t_knots[0], t_knots[-1]]`` give NaN. Takes the short way (q ≡ -q).
    numpy only (used by readers).
    """
    t_query = np.asarray(t_query, dtype=np.float64)
    t_knots = np.asarray(t_knots, dtype=np.float64)
    q_knots = quat_normalize(np.asarray(q_knots, dtype=np.float64))
    out = np.full(t_query.shape + (4,), np.nan)
    if len(t_knots) == 0:
        return out
    inside = (t_query >= t_knots[0]) & (t_query <= t_knots[-1])
    if len(t_knots) == 1:
        out[inside] = q_knots[0]
        return out
    tq = t_query[inside]
    i = np.clip(np.searchsorted(t_knots, tq, side="right") - 1, 0, len(t_knots) - 2)
    t0, t1 = t_knots[i], t_knots[i + 1]
    span = t1 - t0
    u = np.where(span > 0, (tq - t0) / np.where(span > 0, span, 1.0), 0.0)
    q0, q1 = q_knots[i], q_knots[i + 1]
    dq = quat_mul(quat_conj(q0), q1)
    dq = quat_canonical(dq)  # shortest path
    out[inside] = quat_normalize(quat_mul(q0, quat_from_rotvec(quat_log(dq) * u[:, None])))
    return out
