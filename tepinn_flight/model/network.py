"""TE-PINN: transformer encoder over IMU token windows, physics-informed, with a quaternion output.

Forward pass for one window of K tokens ending at time t_K (B batch, K tokens, d d_model):

1. sensor model     ω_c = ω − b_g − S_g ω,  a_c = a − b_a − S_a a                       (B, K, 3)
                    and, for tokens with saturated samples, ω_c·(1 + κ·clipped fraction): a
                    clipped gyro reads less than the true rate (κ learned, starts at 1)
2. RK4 kinematics   R_{K←j}: rotation body(t_j) → body(t_K) from ω_c (log-depth prefix products
                    of per-token RK4 steps); v_j = R_{K←j^mid} a_c,j is each token's specific
                    force seen in the *current* body frame. Unaccelerated, every v_j = −g_body(t_K).
                    A saturated gyro sample makes every rotation across it wrong: tokens j with
                    clipping in (t_{j-1}, t_K] get trust u_j = 0 (else 1; the last token always 1).
   centripetal on: c_jk = R_{K←j^mid}(ω_c,j × e_k)/g, k = x, y, z: the acceleration ω × v of a
                    body-frame velocity v (per m/s of each component), seen in body(t_K);
                    with centripetal_rate also c'_jk = R_{K←j}((t_j − t_K)·ω_c,j × e_k + e_k)/g
                    for a velocity changing linearly, v(t) = v̂ + (t − t_K)·â (dives, pull-ups)
3. tokens           x_j = [ω_c, a_c/g, log n, clipped fraction, v_j/g, u_j (, c_j) (, mag)]
                    → Linear + PE(t_j − t_K, seconds)
4. encoder          L post-LayerNorm transformer layers (multi-head self-attention + feed-forward)
5. heads            last token → quaternion (normalised), σ (rad), gyro bias b̂ (rad/s), and a
                    torque τ per token for the rigid-body loss
6. output           physics on: the quaternion head is a correction δq of the physics baseline
                    q_base (the tilt whose gravity is a pooled mean of the v_j: weights softmax of
                    a per-token logit from the encoder, which starts as the plain mean, a boxcar
                    complementary filter; without learned pooling, the u-weighted mean):
                    q = q_base ⊗ δq; physics off: q = head output. Centripetal on: the pooled
                    v_j are first compensated by Σ_k v̂_k c_jk (+ Σ_k â_k c'_jk) with the window's
                    body velocity v̂ (and its rate â) from a head (gravity = a − f, a ≈ ω × v + v̇:
                    an aircraft's turn, loop or dive)
7. correction       yaw := 0 (the paper's attitude correction layer; the 6-D estimate is tilt)

A window holds only samples up to t_K, so the estimate at t_K uses nothing after it (causal).
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

from ..conventions import GRAVITY_M_S2
from ..quat import gravity_body, quat_conj, quat_from_euler_zyx, quat_mul, quat_normalize, quat_rotate
from .config import CEN_FEATURE_M_S, ModelConfig
from .physics import RigidBody, SensorModel, prefix_products, rk4_delta

BIAS_SCALE_RAD_S = 0.02  # bias head output units (≈ 1.1 °/s per unit)
VEL_SCALE_M_S = 30.0  # velocity head output units (centripetal compensation)
ACC_SCALE_M_S2 = 5.0  # velocity-change head output units (centripetal_rate)


def zero_yaw(q: torch.Tensor) -> torch.Tensor:
    """The paper's correction layer: keep roll and pitch of ``q_nb``, set yaw to 0.

    Computed from the gravity direction in body axes (equal to the Euler route
    q → (φ, θ, ψ) → (φ, θ, 0) → q, but with bounded gradients at ±90° pitch).
    """
    return gravity_tilt(gravity_body(q))  # R_nbᵀ e_z = (−sinθ, sinφ cosθ, cosφ cosθ)


def gravity_tilt(g_body: torch.Tensor) -> torch.Tensor:
    """Zero-yaw attitude whose gravity direction in body axes is ``g_body`` (any length)."""
    gx, gy, gz = g_body.unbind(-1)
    roll = torch.atan2(gy, gz)
    pitch = torch.atan2(-gx, torch.sqrt(gy * gy + gz * gz + 1e-12))
    return quat_from_euler_zyx(roll, pitch, torch.zeros_like(roll))


def trust_after_clipping(clip: torch.Tensor) -> torch.Tensor:
    """(B, K) clipped fractions → 1 for tokens whose rotation to the last token crosses no
    saturated sample (none in the token itself or after it), else 0; the last token is always 1
    (its own rotation spans half a token)."""
    after = torch.flip(torch.cumsum(torch.flip(clip, [1]), dim=1), [1])  # clip_j + Σ_{i>j} clip_i
    u = (after <= 0).to(clip.dtype)
    u[:, -1] = 1.0
    return u


class TimestampEncoding(nn.Module):
    """Sinusoidal encoding of token timestamps in seconds (not indices).

    ``P[2k] = sin(2π t / λ_k)``, ``P[2k+1] = cos(2π t / λ_k)`` with wavelengths λ_k spaced
    geometrically from ``min_wavelength_s`` to ``max_wavelength_s`` (the paper's 10000^(2k/d)
    progression, rescaled so that it resolves seconds-long windows).
    """

    def __init__(self, d_model: int, min_wavelength_s: float, max_wavelength_s: float):
        super().__init__()
        n = d_model // 2
        lam = min_wavelength_s * (max_wavelength_s / min_wavelength_s) ** (torch.arange(n) / max(n - 1, 1))
        self.register_buffer("omega", 2 * math.pi / lam, persistent=False)
        self.d_model = d_model

    def forward(self, t_s: torch.Tensor) -> torch.Tensor:  # (B, K) -> (B, K, d)
        ang = t_s[..., None] * self.omega
        pe = torch.stack([torch.sin(ang), torch.cos(ang)], dim=-1).flatten(-2)
        if pe.shape[-1] < self.d_model:
            pe = F.pad(pe, (0, self.d_model - pe.shape[-1]))
        return pe


def encoder_layer(layer: nn.TransformerEncoderLayer, h: torch.Tensor, k: int, d: int, heads: int) -> torch.Tensor:
    """One post-LayerNorm transformer layer (``nn.TransformerEncoderLayer``'s math, its own weights
    and dropouts) on ``h`` (B, k, d), written with the window length, width and head count as
    constants: its ONNX export then has no shape arithmetic (``nn.MultiheadAttention`` exports about
    150 Shape/Gather/Concat operators for a dynamic batch; a batch-1 run was 16 % faster without them),
    and its linear layers act on (B·k, d), which onnxruntime runs as Gemm with the bias inside
    (a separate Add after a 3-D MatMul otherwise; 4–6 % of a run, session 12)."""
    sa = layer.self_attn
    dh = d // heads
    h = h.reshape(-1, d)  # (B·k, d): the linear layers as 2-D products, which the export fuses with their bias (Gemm)
    qkv = F.linear(h, sa.in_proj_weight, sa.in_proj_bias).reshape(-1, k, 3, heads, dh).permute(2, 0, 3, 1, 4)
    att = torch.softmax((qkv[0] * dh**-0.5) @ qkv[1].transpose(-1, -2), dim=-1)  # (B, heads, k, k)
    att = F.dropout(att, sa.dropout, layer.training)
    a = sa.out_proj((att @ qkv[2]).transpose(1, 2).reshape(-1, d))
    h = layer.norm1(h + layer.dropout1(a))
    h = layer.norm2(h + layer.dropout2(layer.linear2(layer.dropout(layer.activation(layer.linear1(h))))))
    return h.reshape(-1, k, d)


class CausalMeanMLP(nn.Module):
    """'No sequence model' ablation: per-token MLP, then a causal running mean."""

    def __init__(self, d: int, d_ff: int, n_layers: int):
        super().__init__()
        layers: list[nn.Module] = []
        for _ in range(n_layers):
            layers += [nn.Linear(d, d_ff), nn.GELU(), nn.Linear(d_ff, d)]
        self.net = nn.Sequential(*layers)

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        h = self.net(h)
        n = torch.arange(1, h.shape[1] + 1, device=h.device, dtype=h.dtype)[None, :, None]
        return torch.cumsum(h, dim=1) / n


class TEPINN(nn.Module):
    def __init__(self, config: ModelConfig):
        super().__init__()
        self.config = c = config
        self.sensor = SensorModel(c.sensor_scale_max or None, c.sensor_gyro_bias_max_rad_s or None,
                                  c.sensor_accel_bias_max_m_s2 or None,
                                  c.declip_max if c.declip and c.physics else None)  # fmt: skip
        self.body = RigidBody()
        self.inp = nn.Linear(c.n_inputs, c.d_model)
        self.pe = TimestampEncoding(c.d_model, c.pe_min_wavelength_s, c.pe_max_wavelength_s)
        if c.encoder == "transformer":
            layer = nn.TransformerEncoderLayer(
                c.d_model, c.n_heads, c.d_ff, c.dropout, activation="gelu", batch_first=True, norm_first=False
            )
            self.encoder = nn.TransformerEncoder(layer, c.n_layers, enable_nested_tensor=False)
        elif c.encoder == "lstm":
            self.encoder = nn.LSTM(c.d_model, c.d_model, c.n_layers, batch_first=True, dropout=c.dropout if c.n_layers > 1 else 0.0)
        else:
            self.encoder = CausalMeanMLP(c.d_model, c.d_ff, c.n_layers)
        self.head_q = nn.Linear(c.d_model, 4)
        self.head_sigma = nn.Linear(c.d_model, 1)
        self.head_bias = nn.Linear(c.d_model, 3)
        self.head_torque = nn.Linear(c.d_model, 3)
        if c.physics and c.centripetal:  # body velocity (and its rate) for the centripetal term; zero: none
            self.head_vel = nn.Linear(c.d_model, 6 if c.centripetal_rate else 3)
            nn.init.zeros_(self.head_vel.weight)
            nn.init.zeros_(self.head_vel.bias)
        if c.physics and c.learned_pooling:  # baseline pooling logits; zero: the plain mean
            self.head_pool = nn.Linear(c.d_model, 1)
            nn.init.zeros_(self.head_pool.weight)
            nn.init.zeros_(self.head_pool.bias)
        # the quaternion head starts near "level" so early training is stable
        with torch.no_grad():
            self.head_q.weight.mul_(0.1)
            self.head_q.bias.copy_(torch.tensor([1.0, 0.0, 0.0, 0.0]))
            self.head_bias.weight.mul_(0.1)
            self.head_bias.bias.zero_()
            self.head_sigma.bias.fill_(-1.0)
        self.register_buffer("in_mean", torch.zeros(c.n_inputs))
        self.register_buffer("in_std", torch.ones(c.n_inputs))

    # ------------------------------------------------------------------ helpers

    def physics_parameters(self) -> list[nn.Parameter]:
        return list(self.sensor.parameters()) + list(self.body.parameters())

    def network_parameters(self) -> list[nn.Parameter]:
        ids = {id(p) for p in self.physics_parameters()}
        return [p for p in self.parameters() if id(p) not in ids]

    def set_normalization(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        self.in_mean.copy_(torch.as_tensor(mean, dtype=self.in_mean.dtype))
        self.in_std.copy_(torch.as_tensor(std, dtype=self.in_std.dtype).clamp_min(1e-6))

    @staticmethod
    def frames(w_c: torch.Tensor, dt: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """RK4 rotations body(t_j) → body(t_0): at token ends ``P`` and token midpoints ``P_mid``.

        Token j's mean rate acts over its own interval ``(t_{j-1}, t_j]`` of length ``dt_j``.
        """
        one = w_c.new_tensor([1.0, 0.0, 0.0, 0.0])
        dq = rk4_delta(w_c[:, 1:], dt[:, 1:])  # (B, K-1, 4)
        p_end = prefix_products(torch.cat([one.expand_as(dq[:, :1]), dq], dim=1))  # P_0 = 1
        half = rk4_delta(w_c[:, 1:], 0.5 * dt[:, 1:])
        p_mid = torch.cat([p_end[:, :1], quat_mul(p_end[:, :-1], half)], dim=1)
        return p_end, p_mid

    def features(self, gyr, acc, count, mag=None, dt=None, clip=None, t_rel=None):
        """Token inputs (B, K, n_inputs) before normalisation, the corrected gyro and accel,
        (physics on) the rotated specific forces ``v`` (B, K, 3) in g with their trust ``u`` (B, K),
        and (centripetal on) ``cen`` (B, K, 3, 3): ``cen[:, j, k]`` = R_{K←j}(ω_c,j × e_k)/g, the
        acceleration per m/s of body velocity along e_k, in g, seen in body(t_K); with
        ``centripetal_rate`` (and ``t_rel``) the pair (cen, cen_rate), cen_rate per m/s² of â."""
        c = self.config
        clip = torch.zeros_like(count) if clip is None else clip
        if c.physics:
            w_c = self.sensor.gyro(gyr, clip)
            a_c = self.sensor.accel(acc)
        else:
            w_c, a_c = gyr, acc
        parts = [w_c, a_c / GRAVITY_M_S2, torch.log1p(count)[..., None], clip[..., None]]
        v = u = cen = None
        if c.physics:
            p_end, p_mid = self.frames(w_c, dt)
            to_last = quat_mul(quat_conj(p_end[:, -1:]), p_mid)  # body(t_j mid) → body(t_K)
            v = quat_rotate(to_last, a_c) / GRAVITY_M_S2  # (B, K, 3) in units of g
            parts.append(v)
            u = torch.ones_like(count)
            if c.clip_aware:
                u = trust_after_clipping(clip)
                parts.append(u[..., None])
            if c.centripetal:
                w3 = w_c[:, :, None, :].expand(-1, -1, 3, -1)  # (B, K, 3, 3): row k is ω_c,j
                e3 = torch.eye(3, dtype=w_c.dtype, device=w_c.device).expand_as(w3)  # row k is e_k
                wxe = torch.linalg.cross(w3, e3, dim=-1)
                cen = quat_rotate(to_last[:, :, None, :], wxe) / GRAVITY_M_S2  # (B, K, 3, 3)
                parts.append(CEN_FEATURE_M_S * cen.flatten(-2))
                if c.centripetal_rate and t_rel is not None:  # c'_jk = R_{K←j}((t_j − t_K)·ω_c,j × e_k + e_k)/g, per m/s² of â
                    t_mid = torch.cat([t_rel[:, :1], t_rel[:, 1:] - 0.5 * dt[:, 1:]], dim=1)  # as frames()
                    t_mid = t_mid[..., None, None]  # (B, K, 1, 1)
                    rot_e = quat_rotate(to_last[:, :, None, :], e3) / GRAVITY_M_S2
                    cen = (cen, t_mid * cen + rot_e)
        if c.use_mag:
            parts.append(torch.nan_to_num(mag) / 50.0)
        return torch.cat(parts, dim=-1), w_c, a_c, v, u, cen

    # ------------------------------------------------------------------ forward

    def forward(self, gyr, acc, count, t_rel, dt, mag=None, clip=None) -> dict[str, torch.Tensor]:
        """``gyr``/``acc`` (B, K, 3) token means in rad/s and m/s², ``count`` (B, K) samples per
        token, ``t_rel`` (B, K) seconds relative to the last token (≤ 0), ``dt`` (B, K) token
        durations in s, ``mag`` (B, K, 3) µT (9-D mode), ``clip`` (B, K) clipped fraction.

        Returns the window's estimate for t_K: ``q`` (B, 4) body→NED, ``sigma`` (B,) rad,
        ``bias`` (B, 3) rad/s, ``f_mean`` (B, 3) the window's mean specific force in body(t_K)
        (physics on); and per token ``torque`` (B, K, 3), ``w_c``, ``a_c`` (B, K, 3).
        """
        x, w_c, a_c, v, u, cen = self.features(gyr, acc, count, mag, dt, clip, t_rel)
        cen, cen_rate = cen if isinstance(cen, tuple) else (cen, None)
        out = self.head(x, t_rel, v, u, cen, cen_rate)
        out["w_c"] = w_c
        out["a_c"] = a_c
        return out

    def head(self, x, t_rel, v=None, u=None, cen=None, cen_rate=None) -> dict[str, torch.Tensor]:
        """Everything after :meth:`features`: normalisation, timestamp encoding, encoder and heads
        (what an ONNX export holds; :mod:`.window_features` computes the features outside it).
        ``v``, ``u`` with physics; ``cen`` with the centripetal term, ``cen_rate`` with its rate."""
        return self.physics_head(self.linear_heads(self.encode(x, t_rel)), v, u, cen, cen_rate)

    def encode(self, x: torch.Tensor, t_rel: torch.Tensor) -> torch.Tensor:
        """Token features ``x`` (B, K, n_inputs) before normalisation and their times ``t_rel`` (B, K)
        → the encoder's output (B, K, d): normalisation, input layer, timestamp encoding, encoder."""
        c = self.config
        h = self.inp((x - self.in_mean) / self.in_std) + self.pe(t_rel)  # (B, K, d)
        if c.encoder == "lstm":
            h, _ = self.encoder(h)
        elif c.encoder == "transformer" and (torch.jit.is_tracing() or self.training or torch.is_grad_enabled()):
            # exported, trained: the layers as written here (no shape arithmetic in the graph; training
            # steps as fast as nn.TransformerEncoder's here, 44–50 ms at batch 64 on this machine)
            k = c.window_tokens if torch.jit.is_tracing() else h.shape[1]  # exported: the config's K, a constant
            for layer in self.encoder.layers:  # full attention inside the window (it ends at t_K)
                h = encoder_layer(layer, h, k, c.d_model, c.n_heads)
        else:  # the MLP; and the transformer's inference in PyTorch, where its fused kernel is faster
            h = self.encoder(h)  # (batch 256: 72–86 ms against 115–135 ms as written above; the same math)
        return h

    def linear_heads(self, h: torch.Tensor) -> dict[str, torch.Tensor]:
        """The heads' linear layers on the encoder's output ``h`` (B, K, d): the head quaternion
        ``q_head`` (normalised), ``bias``, per-token ``torque``, and as the model has them ``sigma``,
        the body velocity ``vel`` and its rate ``acc_v`` (the centripetal term), the pooling logits
        ``pool`` (B, K). Where an ONNX export (version 3) ends: :meth:`physics_head` is its runner's
        compiled tail (:mod:`.head_physics`)."""
        c = self.config
        last = h[:, -1]  # (B, d)
        out = {
            "q_head": quat_normalize(self.head_q(last)),  # (B, 4)
            "bias": BIAS_SCALE_RAD_S * self.head_bias(last),
            "torque": self.head_torque(h),
        }
        if c.physics and c.centripetal:
            hv = self.head_vel(last)
            out["vel"] = VEL_SCALE_M_S * hv[:, :3]  # (B, 3) m/s in body(t_K)
            # v(t) = v̂ + (t − t_K)·â (centripetal_rate), â in m/s² in body(t_K)
            out["acc_v"] = ACC_SCALE_M_S2 * hv[:, 3:] if c.centripetal_rate else torch.zeros_like(out["vel"])
        if c.physics and c.learned_pooling:
            out["pool"] = self.head_pool(h)[..., 0]  # (B, K)
        if c.uncertainty:
            # σ reads the representation but does not shape it (its NLL would swamp early training)
            out["sigma"] = F.softplus(self.head_sigma(last.detach()))[..., 0] + 1e-4
        return out

    def physics_head(self, out, v=None, u=None, cen=None, cen_rate=None) -> dict[str, torch.Tensor]:
        """The window's attitude ``q`` from :meth:`linear_heads`' outputs ``out`` (updated in place and
        returned) and the physics features: with physics, the pooled gravity (``f_mean``, ``f_spread``)
        corrected by the head quaternion; without, the head quaternion (yaw zeroed by the correction
        layer)."""
        c = self.config
        q = out["q_head"]
        if v is not None:
            if cen is not None:  # gravity = a − f with a ≈ ω × v̂: compensate each token
                vel, acc_v = out["vel"], out["acc_v"]
                if c.centripetal_rate:  # v(t) = v̂ + (t − t_K)·â: a = ω × v̂ + (t − t_K)·ω × â + â
                    v = v - torch.einsum("bjkc,bk->bjc", cen_rate, acc_v)
                v = v - torch.einsum("bjkc,bk->bjc", cen, vel)
            if c.learned_pooling:  # learned weights (u is an input the logits can use)
                wts = torch.softmax(out["pool"], dim=1)[..., None]
            else:
                wts = (u / u.sum(dim=1, keepdim=True))[..., None]  # (B, K, 1)
            f_mean = (wts * v).sum(dim=1)  # pooled specific force in body(t_K), in g
            if c.correction_layer:  # zero_yaw(q_base ⊗ δq), q_base = gravity_tilt(−f): its gravity in body
                # axes is −f, so the product's is δq* turning −f — one rotation instead of a second
                # tilt and a product (the same numbers to round-off, tests/test_model.py)
                q = gravity_tilt(quat_rotate(quat_conj(q), -f_mean))
            else:
                q = quat_mul(gravity_tilt(-f_mean), q)  # correction of the physics baseline
            out["f_mean"] = f_mean  # (compensated, centripetal on)
            out["f_spread"] = (wts[..., 0] * (v - f_mean[:, None]).pow(2).sum(-1)).sum(dim=1).sqrt()
        elif c.correction_layer:
            q = zero_yaw(q)
        out["q"] = q
        return out
