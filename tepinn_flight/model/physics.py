"""Physics of TE-PINN in torch: sensor models, RK4 quaternion kinematics, rigid-body dynamics.

Everything is batched over leading axes and differentiable. Conventions as in
:mod:`tepinn_flight.conventions`: ``q_nb`` scalar-first Hamilton, body FRD → NED, rad/s, m/s².

Quaternion kinematics of a body→earth quaternion under body rate ω: ``q̇ = ½ q ⊗ (0, ω)``.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from ..quat import quat_mul, quat_normalize


def quat_derivative(q: torch.Tensor, w_b: torch.Tensor) -> torch.Tensor:
    """``q̇ = ½ q ⊗ (0, ω)`` for ``(..., 4)`` q and ``(..., 3)`` body rate (rad/s)."""
    zero = torch.zeros_like(w_b[..., :1])
    return 0.5 * quat_mul(q, torch.cat([zero, w_b], dim=-1))


def rk4_step(q: torch.Tensor, w0: torch.Tensor, w1: torch.Tensor, dt: torch.Tensor) -> torch.Tensor:
    """One RK4 step of quaternion kinematics from t to t+dt, rate linear between ``w0`` and ``w1``.

    ``dt`` broadcasts against ``q[..., :1]`` (shape ``(...,)`` or ``(..., 1)``). The result is
    renormalised (RK4 does not preserve the norm exactly).
    """
    if dt.dim() == q.dim() - 1:
        dt = dt[..., None]
    wm = 0.5 * (w0 + w1)
    k1 = quat_derivative(q, w0)
    k2 = quat_derivative(q + 0.5 * dt * k1, wm)
    k3 = quat_derivative(q + 0.5 * dt * k2, wm)
    k4 = quat_derivative(q + dt * k3, w1)
    return quat_normalize(q + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4))


def rk4_delta(w_b: torch.Tensor, dt: torch.Tensor) -> torch.Tensor:
    """Rotation over one step of constant body rate, by RK4 from the identity: ``(..., 4)``.

    For a linear ODE classical RK4 is the 4th-order Taylor polynomial of the exact step, and with
    M = ½ dt Ω(ω) (q ↦ ½ dt q ⊗ (0, ω)) M² = −φ² I, φ = |ω| dt / 2. So :func:`rk4_step` from the
    identity is ``(1 − φ²/2 + φ⁴/24, (1 − φ²/6) ω dt/2)``, renormalised — written so here: the same
    numbers (tested against :func:`rk4_step`) in a few tensor ops instead of four quaternion products.
    """
    if dt.dim() == w_b.dim() - 1:
        dt = dt[..., None]
    v = 0.5 * dt * w_b  # (..., 3)
    phi2 = (v * v).sum(dim=-1, keepdim=True)
    return quat_normalize(torch.cat([1.0 - 0.5 * phi2 + phi2 * phi2 / 24.0, (1.0 - phi2 / 6.0) * v], dim=-1))


def prefix_products(dq: torch.Tensor) -> torch.Tensor:
    """Inclusive prefix Hamilton products along axis -2: ``P_j = dq_0 ⊗ dq_1 ⊗ … ⊗ dq_j``.

    ``dq`` is ``(..., K, 4)``. Hillis–Steele scan: log2(K) batched products instead of K
    sequential ones (order matters: earlier factors stay on the left).
    """
    p = dq
    k = dq.shape[-2]
    s = 1
    while s < k:
        left = p[..., :-s, :]
        right = p[..., s:, :]
        p = torch.cat([p[..., :s, :], quat_mul(left, right)], dim=-2)
        s *= 2
    return p


class SensorModel(nn.Module):
    """Learned sensor corrections ``ω_c = ω − b_g − S_g ω`` and ``a_c = a − b_a − S_a a``.

    ``b_g`` (rad/s), ``b_a`` (m/s²) and the 3×3 scale/misalignment matrices start at zero. These
    are global (per model) systematic errors; per-flight biases are estimated by the network.

    With limits (``scale_max`` etc.), each value is ``limit · tanh(raw / limit)``: equal to the raw
    parameter near zero, never beyond a physically plausible range. Unbounded, the optimiser can
    use them to make physics losses trivially small instead of calibrating the sensor (we saw a
    yaw-rate scale of −77 %: shrinking ω_z shrinks the rigid-body residual), which wrecks the RK4
    rotations of every log whose vehicle does not fly like the training data.
    """

    def __init__(self, scale_max: float | None = None, gyro_bias_max_rad_s: float | None = None,
                 accel_bias_max_m_s2: float | None = None, declip_max: float | None = None):  # fmt: skip
        super().__init__()
        if declip_max is not None:  # κ = declip_max·sigmoid(raw), starting at 1 (twice the range)
            self.k_clip_raw = nn.Parameter(torch.tensor(-math.log(declip_max - 1.0)))
        self.declip_max = declip_max
        self.b_g = nn.Parameter(torch.zeros(3))
        self.S_g = nn.Parameter(torch.zeros(3, 3))
        self.b_a = nn.Parameter(torch.zeros(3))
        self.S_a = nn.Parameter(torch.zeros(3, 3))
        self.limits = (scale_max, gyro_bias_max_rad_s, accel_bias_max_m_s2)

    @staticmethod
    def _bounded(p: torch.Tensor, limit: float | None) -> torch.Tensor:
        return p if limit is None else limit * torch.tanh(p / limit)

    def values(self) -> dict[str, torch.Tensor]:
        """The effective ``b_g``, ``S_g``, ``b_a``, ``S_a`` (after the limits)."""
        s, bg, ba = self.limits
        return {"b_g": self._bounded(self.b_g, bg), "S_g": self._bounded(self.S_g, s),
                "b_a": self._bounded(self.b_a, ba), "S_a": self._bounded(self.S_a, s)}  # fmt: skip

    def clip_gain(self) -> torch.Tensor | None:
        """κ: how much larger than its reading a saturated gyro's true rate is taken to be."""
        return None if self.declip_max is None else self.declip_max * torch.sigmoid(self.k_clip_raw)

    def gyro(self, w: torch.Tensor, clip: torch.Tensor | None = None) -> torch.Tensor:
        """Corrected rate; with declipping and ``clip`` (the clipped fraction of each row,
        shape ``w.shape[:-1]``), saturated rows are scaled by ``1 + κ·clip``."""
        s, bg, _ = self.limits
        w_c = w - self._bounded(self.b_g, bg) - w @ self._bounded(self.S_g, s).T
        if self.declip_max is not None and clip is not None:
            w_c = w_c * (1 + self.clip_gain() * clip)[..., None]
        return w_c

    def accel(self, a: torch.Tensor) -> torch.Tensor:
        s, _, ba = self.limits
        return a - self._bounded(self.b_a, ba) - a @ self._bounded(self.S_a, s).T


class RigidBody(nn.Module):
    """Euler's rotation equation ``I ω̇ + ω × (I ω) = τ`` with a learned inertia tensor.

    ``I = L Lᵀ + ε·1`` (L lower-triangular: a Cholesky factor) is symmetric positive definite by
    construction, then scaled to unit trace: the torque τ comes from the network in the same
    learned units, so only the inertia's *shape* (ratios, products of inertia) is identifiable —
    which is what the gyroscopic coupling ``ω × (I ω)`` needs.
    """

    def __init__(self, eps: float = 1e-3):
        super().__init__()
        self.L_raw = nn.Parameter(torch.eye(3) * (1.0 / 3.0) ** 0.5)
        self.eps = eps

    def inertia(self) -> torch.Tensor:
        L = torch.tril(self.L_raw)
        inertia = L @ L.T + self.eps * torch.eye(3, dtype=L.dtype, device=L.device)
        return inertia / torch.diagonal(inertia).sum()

    def residual(self, w: torch.Tensor, w_dot: torch.Tensor, torque: torch.Tensor) -> torch.Tensor:
        """``I ω̇ + ω × (I ω) − τ`` for ``(..., 3)`` tensors."""
        inertia = self.inertia()
        iw = w @ inertia.T
        return w_dot @ inertia.T + torch.linalg.cross(w, iw, dim=-1) - torque
