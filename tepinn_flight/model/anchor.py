"""Filter-anchored TE-PINN: a VQF filter does the attitude; the network corrects what VQF cannot know.

The physics filter is VQF (Laidig & Seel 2023, the ``vqf`` package): strapdown integration of the
gyro, the accelerometer's gravity low-passed in a quasi-inertial frame, gyro-bias estimation in
motion and at rest, and, with a magnetometer, heading with magnetic-disturbance rejection. With
every learned correction at zero this module *is* VQF, bit for bit (tested).

The network (TE-PINN, :mod:`.network`) runs on each 3.2 s window of IMU tokens (25 Hz) and gives
its tilt ``q``, a σ, a gyro bias ``b̂`` and, from its transport-theorem head, a body velocity ``v̂``
and its rate ``â``. Each enters only where there is run-time evidence that VQF's assumptions fail:

- **flight speed** (``|v̂|`` between ``speed_lo_m_s`` and ``speed_hi_m_s`` ramps a gate 0 → 1): an
  aircraft at tens of m/s reads ``ω × v + v̇`` besides gravity, for seconds on end in a turn or a
  loop; VQF's low-pass takes that for gravity. The gate removes ``ω × v̂ + â`` from the
  accelerometer VQF sees (per sample, with the current gyro) and pulls VQF's tilt toward the
  network's. Hand-held and multirotor motion stays far below the gate (|v̂| < 10 m/s).
- **gyro saturation** (a sample with the gyro clipped within ``clip_hold_s``: the ``clipped`` argument
  of :meth:`AnchoredVQF.update`, a record's ``gyr_clipped``): the integrated rate is wrong, so VQF's
  tilt is pulled toward the network's window tilt (its physics inputs are clip-aware). An
  accelerometer at its range leaves the integrated rate right and does not open it.
- **gyro bias beyond VQF's clip** (VQF's bias estimate reaches ``bias_clip_deg_s``, an
  uncalibrated gyro): from then on, in that segment, the network's bias beyond
  ``bias_deadzone_deg_s`` is removed from the gyro VQF sees, and its tilt pulls with weight
  ``bias_gate_weight``.

**Quiet blocks** (``quiet_blocks``): where every gate stays shut the estimate is VQF's whatever the
windows say, so the network need not run there. Windows come in the older fusion's bias-feedback
blocks (``bias_feedback_windows`` tokens, 1 s); a block whose first window and those of the last
``quiet_memory_blocks`` blocks show |v̂| below ``quiet_speed_m_s`` (the network reads a fixed wing's
speed only while it turns) and the older fusion's gyro bias below ``quiet_bias_deg_s`` (so
neither the flight-speed nor the bias gate can open before the next block) runs only that window,
and those holding a saturated token (the clip gate); a segment's first ``quiet_after_blocks`` and any
other block run every window. Decided from what has been seen, so live and offline run the same
windows.

A *pull* by a fraction k turns VQF's attitude about a horizontal earth axis by k times its tilt
difference to the network's (heading untouched). VQF keeps its tilt in the low-passed
accelerometer, so the pull rotates that filter state with it (``accLpState``, ``lastAccLp``) —
turning only ``accQuat`` would be undone at the next sample.

σ (``sigma_rad``, per-axis σ of the 2-D tilt error): ``σ² = σ₀² + (c·e)² + w·(s·σ_net)²`` with e a
1-s average of the angle between the accelerometer VQF sees and its gravity (motion acceleration
the filter is averaging out), w the gate, σ_net the network's σ; fitted on validation files.

Frames: VQF works in a z-up sensor frame ``S`` (body FRD turned 180° about x) and a z-up earth
frame; conversions happen only at this module's edges (body FRD / NED outside).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ..config import check_choice, check_range
from ..conventions import Q_ENU_FROM_NED_WXYZ
from .fusion import FusionConfig
from ..quat import gravity_body, quat_conj, quat_mul, quat_normalize, quat_to_rotmat
from ..quat_scalar import qmul, qnorm

#: q_SB (180° about x) and q_NE (ENU-type z-up earth → NED), as in evaluation/peers.py
Q_SENSOR_BODY = np.array([0.0, 1.0, 0.0, 0.0])
Q_NED_ENU = quat_conj(np.asarray(Q_ENU_FROM_NED_WXYZ, np.float64))
_FLIP = np.array([1.0, -1.0, -1.0])
_EZ = np.array([0.0, 0.0, 1.0])
_Q_SB = tuple(float(v) for v in Q_SENSOR_BODY)
_Q_NE = tuple(float(v) for v in Q_NED_ENU)
BIAS_EVIDENCE_S = 2.0  # the older fusion's bias must stay beyond its gate this long
MODES = ("6d", "9d", "auto")


@dataclass(frozen=True)
class AnchorConfig:
    """The filter-anchored estimator. Defaults are the shipped model's."""

    enabled: bool = True  # False: the checkpoint's older network-centred fusion (FusionConfig)
    mode: Literal["6d", "9d", "auto"] = "6d"  # "6d", "9d" (magnetometer heading), "auto" (9-D when the record has a magnetometer)
    tau_acc_s: float = 3.0  # VQF's accelerometer low-pass (its default)
    # ... while the flight-speed gate is on (> ½): the accelerometer then holds ω × v residuals, so VQF
    # leans on the gyro and the pulls (0: tau_acc_s)
    tau_acc_flight_s: float = 10.0
    bias_clip_deg_s: float = 2.0  # VQF's bias limit (its default)
    pull_gain: float = 0.8  # fraction of the tilt difference removed per window at gate 1
    # (the pulls pull toward the older network-centred fusion of the same windows run alongside:
    # gyro-propagated, Kalman-weighted by the network's σ, gyro-bias states, the windows' noise
    # averaged out; pulling toward each window's own tilt, the option pull_target = "window" that
    # was removed, measured worse: validation flights 6.21° against 5.05°)
    speed_lo_m_s: float = 20.0  # flight-speed gate: 0 below, 1 above speed_hi_m_s
    speed_hi_m_s: float = 30.0
    centripetal: bool = True  # remove ω × v̂ + â (times the flight gate) from VQF's accelerometer
    clip_hold_s: float = 4.0  # gyro-saturation gate stays on this long after the last clipped sample
    bias_gate_weight: float = 0.6  # pull weight while the uncalibrated-gyro gate is on (0: never)
    bias_deadzone_deg_s: float = 2.0  # the network's bias beyond this is removed from the gyro
    # ... and the gate also opens when the older fusion's bias estimate (pull target "fusion") exceeds
    # this on an axis (calibrated autopilot gyros and BROAD stay below 1 °/s there; 0: off)
    bias_gate_fusion_deg_s: float = 3.0
    sigma_floor_deg: float = 0.45  # σ₀ (fitted on the 17 BROAD trials the network was trained or validated on)
    sigma_acc_gain: float = 0.025  # c
    sigma_net_scale: float = 1.0  # s
    sigma_acc_tau_s: float = 1.0
    # quiet blocks (speed): the windows matter only where a gate may open. A block of the older
    # fusion's bias feedback (its bias_feedback_windows tokens) whose first window shows |v̂| below
    # quiet_speed_m_s and a fusion gyro bias below quiet_bias_deg_s on every axis runs only that window
    # (and those holding a saturated token); False: the network runs on every token
    quiet_blocks: bool = True
    quiet_speed_m_s: float = 15.0  # ... on the windows of the last quiet_memory_blocks blocks too
    quiet_memory_blocks: int = 10
    quiet_bias_deg_s: float = 1.5
    quiet_after_blocks: int = 10  # a segment's first blocks run every window (the older fusion's bias converges)
    # the older fusion's settings (the checkpoint's fusion_config; filled in when loaded)
    fusion_config: FusionConfig | None = field(default=None, compare=False)

    def __post_init__(self):
        if isinstance(self.fusion_config, dict):  # from a checkpoint's JSON-like dict
            object.__setattr__(self, "fusion_config", FusionConfig(**self.fusion_config))
        check_choice("mode", self.mode, MODES)
        for name in ("tau_acc_s", "bias_clip_deg_s", "sigma_acc_tau_s"):
            check_range(name, getattr(self, name), 0, None, lo_open=True)
        check_range("tau_acc_flight_s", self.tau_acc_flight_s, 0, None)  # 0: tau_acc_s
        check_range("pull_gain", self.pull_gain, 0, 1)
        check_range("bias_gate_weight", self.bias_gate_weight, 0, 1)
        check_range("speed_lo_m_s", self.speed_lo_m_s, 0, None)
        check_range("quiet_after_blocks", self.quiet_after_blocks, 0, 10**6)
        check_range("quiet_memory_blocks", self.quiet_memory_blocks, 0, 10**6)
        check_range("speed_hi_m_s", self.speed_hi_m_s, self.speed_lo_m_s, None, lo_open=True)
        for name in ("quiet_speed_m_s", "quiet_bias_deg_s", "clip_hold_s", "bias_deadzone_deg_s", "bias_gate_fusion_deg_s", "sigma_floor_deg", "sigma_acc_gain",
                     "sigma_net_scale"):  # fmt: skip
            check_range(name, getattr(self, name), 0, None)

    def quiet_in(self, fusion: FusionConfig) -> int:
        """Tokens per quiet block with the older fusion ``fusion`` alongside (0: no quiet blocks)."""
        return fusion.bias_feedback_windows if self.quiet_blocks else 0

    def block_busy(self, block: int, speed_m_s: float, fusion_bias_rad_s) -> bool:
        """Whether block ``block`` (0: a segment's first) runs every window: too early in the segment,
        or |v̂| (``speed_m_s``: the largest on the windows of the last ``quiet_memory_blocks`` blocks and
        this block's first) or the older fusion's gyro bias then (body axes) say a gate may open in it
        (never below the flight-speed gate's own threshold)."""
        if block < self.quiet_after_blocks or speed_m_s >= min(self.quiet_speed_m_s, self.speed_lo_m_s):
            return True
        return bool(np.max(np.abs(np.asarray(fusion_bias_rad_s, np.float64))) >= math.radians(self.quiet_bias_deg_s))

    @property
    def learned_off(self) -> "AnchorConfig":
        """The same filter with every learned correction switched off: plain VQF."""
        import dataclasses

        return dataclasses.replace(self, pull_gain=0.0, centripetal=False, bias_gate_weight=0.0,
                                   bias_deadzone_deg_s=1e9, sigma_net_scale=0.0)  # fmt: skip


@dataclass
class WindowOutput:
    """The network's outputs for one window (body FRD / NED; SI units)."""

    q_nb_wxyz: np.ndarray  # (4,) tilt (zero yaw)
    sigma_rad: float
    gyr_bias_rad_s: np.ndarray  # (3,)
    vel_m_s: np.ndarray  # (3,) body velocity v̂ (zeros where the model has no such head)
    acc_m_s2: np.ndarray  # (3,) its rate â
    fusion_bias_rad_s: np.ndarray | None = None  # (3,) the older fusion's gyro-bias estimate (pull target "fusion")


def to_sensor(v_b: np.ndarray) -> np.ndarray:
    """Body FRD vectors → VQF's z-up sensor frame."""
    return np.ascontiguousarray(np.asarray(v_b, np.float64) * _FLIP)


def q_nb_from_vqf(q_es: np.ndarray) -> np.ndarray:
    """VQF's sensor → z-up earth quaternion(s) → body FRD → NED."""
    q_es = np.asarray(q_es, np.float64)
    sh = q_es.shape
    return quat_normalize(quat_mul(np.broadcast_to(Q_NED_ENU, sh), quat_mul(q_es, np.broadcast_to(Q_SENSOR_BODY, sh))))


def _q_nb_from_vqf_f(q_es) -> tuple:
    """:func:`q_nb_from_vqf` of one quaternion, in plain floats."""
    a = qmul(float(q_es[0]), float(q_es[1]), float(q_es[2]), float(q_es[3]), *_Q_SB)
    return qnorm(*qmul(*_Q_NE, *a))


def tilt_pull_quat(q_es: np.ndarray, up_s: np.ndarray, fraction: float) -> np.ndarray:
    """Earth-frame rotation that turns the filter attitude ``q_es`` by ``fraction`` of the tilt
    between it and a target whose up direction in sensor axes is ``up_s``; about a horizontal
    axis, so the heading is untouched."""
    u = quat_to_rotmat(q_es) @ (up_s / np.linalg.norm(up_s))  # the target's up in the filter's earth frame
    axis = np.cross(u, _EZ)
    n = np.linalg.norm(axis)
    ang = math.atan2(n, float(u @ _EZ)) * fraction
    if n < 1e-12 or ang == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.r_[math.cos(ang / 2), math.sin(ang / 2) * axis / n]


class AnchoredVQF:
    """One segment of the anchored estimator; samples in, one estimate per sample out.

    ``update(gyr, acc, mag)`` takes a block of samples (rows, body FRD, SI) — one sample or many:
    the result is the same — and ``correct(window)`` applies a network window made at the last
    sample pushed, for the samples after it (causal)."""

    def __init__(self, config: AnchorConfig, ts_s: float, use_mag: bool = False):
        import vqf

        self.cfg = c = config
        self.use_mag = use_mag
        self.ts = ts_s
        self.f = vqf.VQF(ts_s, tauAcc=c.tau_acc_s, biasClip=c.bias_clip_deg_s)
        self.vel = np.zeros(3)  # gated v̂ and â in body axes
        self.acc_v = np.zeros(3)
        self.gyr_corr = np.zeros(3)  # body axes, removed from the gyro
        self.bias_latched = False
        self.t_bias_over = None  # since when the older fusion's horizontal bias is beyond its gate
        self.tau_acc = c.tau_acc_s
        self.t_clip = -math.inf  # time of the last saturated sample
        self.t = 0.0
        self.gate = 0.0
        self.sigma_net = 0.0
        self.e_acc = 0.0  # low-passed accelerometer-vs-gravity angle (rad)
        self.last_imu = (np.zeros(3), np.zeros(3))  # the last finite gyro/accelerometer sample
        self.holes = 0  # non-finite samples bridged

    # ------------------------------------------------------------------ samples

    def update(self, t_s, gyr_b, acc_b, mag=None, clipped=None):
        """Rows of samples → (q_nb (n, 4), q_nb_9d (n, 4) or None, sigma (n,), bias_b (n, 3)).
        A non-finite gyro/accelerometer row is a hole, bridged with the last finite sample."""
        t_s = np.atleast_1d(np.asarray(t_s, np.float64))
        gyr_b = np.atleast_2d(np.asarray(gyr_b, np.float64))
        acc_b = np.atleast_2d(np.asarray(acc_b, np.float64))
        n = len(t_s)
        if clipped is not None:
            cl = np.flatnonzero(np.atleast_1d(clipped))
            if cl.size:
                self.t_clip = max(self.t_clip, float(t_s[cl[-1]]))
        bad = ~(np.all(np.isfinite(gyr_b), 1) & np.all(np.isfinite(acc_b), 1))
        if bad.any():  # a hole: bridged with the last finite sample (counted)
            gyr_b, acc_b = gyr_b.copy(), acc_b.copy()
            gyr_b[bad] = np.nan
            acc_b[bad] = np.nan
            ffill_rows(gyr_b, self.last_imu[0])
            ffill_rows(acc_b, self.last_imu[1])
            self.holes += int(bad.sum())
        if n:
            self.last_imu = (gyr_b[-1].copy(), acc_b[-1].copy())
        g = gyr_b - self.gyr_corr
        a = acc_b
        if self.cfg.centripetal and (self.vel.any() or self.acc_v.any()):
            a = a - (np.cross(gyr_b, self.vel) + self.acc_v)
        m = None
        if self.use_mag:
            m = np.full((n, 3), np.nan) if mag is None else np.atleast_2d(np.asarray(mag, np.float64))
            m = to_sensor(np.where(np.isfinite(m), m, 0.0))  # zero: VQF skips the magnetometer update
        out = self.f.updateBatch(to_sensor(g), to_sensor(a), m)
        q6 = q_nb_from_vqf(out["quat6D"])
        q9 = q_nb_from_vqf(out["quat9D"]) if self.use_mag else None
        bias = out["bias"] * _FLIP + self.gyr_corr
        sig = self._sigma(out["quat6D"], to_sensor(a))
        if n:
            self.t = float(t_s[-1])
        return q6, q9, sig, bias

    def update_one(self, t_s: float, gyr_b, acc_b, mag=None, clipped: bool = False):
        """:meth:`update` of one sample in plain floats (the live path: numpy's per-call overhead
        on one row cost 10× the arithmetic) → (q_nb, q_nb_9d or None, sigma, bias_b) as tuples and
        a float; the numbers of a one-row :meth:`update` (tested)."""
        if clipped:
            self.t_clip = max(self.t_clip, float(t_s))
        g = [float(v) for v in gyr_b]
        a = [float(v) for v in acc_b]
        if not all(math.isfinite(v) for v in (*g, *a)):  # a hole: bridged with the last finite sample
            g, a = [float(v) for v in self.last_imu[0]], [float(v) for v in self.last_imu[1]]
            self.holes += 1
        self.last_imu = (np.array(g), np.array(a))
        gc, v, av = self.gyr_corr, self.vel, self.acc_v
        gx, gy, gz = g[0] - gc[0], g[1] - gc[1], g[2] - gc[2]
        ax, ay, az = a
        if self.cfg.centripetal and (v.any() or av.any()):  # a − (ω × v̂ + â)
            ax = ax - ((g[1] * v[2] - g[2] * v[1]) + av[0])
            ay = ay - ((g[2] * v[0] - g[0] * v[2]) + av[1])
            az = az - ((g[0] * v[1] - g[1] * v[0]) + av[2])
        a_s = (ax, -ay, -az)  # VQF's z-up sensor frame
        if self.use_mag:
            m = [0.0, 0.0, 0.0] if mag is None else [float(x) if math.isfinite(float(x)) else 0.0 for x in mag]
            self.f.update(np.array([gx, -gy, -gz]), np.array(a_s), np.array([m[0], -m[1], -m[2]]))
        else:
            self.f.update(np.array([gx, -gy, -gz]), np.array(a_s))
        q_es = self.f.getQuat6D()
        q6 = _q_nb_from_vqf_f(q_es)
        q9 = _q_nb_from_vqf_f(self.f.getQuat9D()) if self.use_mag else None
        b = self.f.getBiasEstimate()[0]
        bias = (b[0] + gc[0], -b[1] + gc[1], -b[2] + gc[2])
        # σ: as _sigma for one row
        c = self.cfg
        w, x, y, z = float(q_es[0]), -float(q_es[1]), -float(q_es[2]), -float(q_es[3])  # conj: earth up in sensor axes
        up = (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y))
        an = math.sqrt(a_s[0] * a_s[0] + a_s[1] * a_s[1] + a_s[2] * a_s[2])
        cosang = (up[0] * a_s[0] + up[1] * a_s[1] + up[2] * a_s[2]) / max(an, 1e-9)
        ang = math.acos(min(1.0, max(-1.0, cosang)))
        alpha = min(1.0, self.ts / c.sigma_acc_tau_s)
        beta = 1.0 - alpha
        self.e_acc = e = beta * self.e_acc + alpha * ang if beta > 0 else ang
        var = math.radians(c.sigma_floor_deg) ** 2 + (c.sigma_acc_gain * e) ** 2
        var += self.gate * (c.sigma_net_scale * self.sigma_net) ** 2
        self.t = float(t_s)
        return q6, q9, math.sqrt(var), bias

    def _sigma(self, q_es, a_s):
        """Per-sample σ (rad) of the tilt error for the rows just filtered (``a_s``: the
        accelerometer VQF saw, sensor axes)."""
        c = self.cfg
        up = quat_to_rotmat(quat_conj(np.asarray(q_es)))[..., :, 2]  # earth up in sensor axes (n, 3)
        an = np.linalg.norm(a_s, axis=1)
        cosang = np.einsum("ij,ij->i", up, a_s) / np.maximum(an, 1e-9)
        ang = np.arccos(np.clip(cosang, -1.0, 1.0))
        e = _low_pass(ang, self.e_acc, min(1.0, self.ts / c.sigma_acc_tau_s))
        self.e_acc = float(e[-1])
        var = math.radians(c.sigma_floor_deg) ** 2 + (c.sigma_acc_gain * e) ** 2
        var += self.gate * (c.sigma_net_scale * self.sigma_net) ** 2
        return np.sqrt(var)

    # ------------------------------------------------------------------ network windows

    def correct(self, w: WindowOutput) -> None:
        """Apply the network's window made at the last sample pushed (see module doc)."""
        c = self.cfg
        speed = float(np.linalg.norm(w.vel_m_s))
        g_flight = min(1.0, max(0.0, (speed - c.speed_lo_m_s) / (c.speed_hi_m_s - c.speed_lo_m_s)))
        g_clip = 1.0 if self.t - self.t_clip < c.clip_hold_s else 0.0
        # only the bias component perpendicular to gravity turns the tilt (the one along it turns the
        # heading, which no tilt measurement can check): that part is the evidence and the correction
        down = gravity_body(q_nb_from_vqf(self.f.getQuat6D()))  # the filter's own vertical
        horiz = np.eye(3) - np.outer(down, down)
        b_src = w.gyr_bias_rad_s if w.fusion_bias_rad_s is None else w.fusion_bias_rad_s
        b_h = horiz @ np.asarray(b_src, np.float64)
        if c.bias_gate_weight > 0 and not self.bias_latched:
            b, _ = self.f.getBiasEstimate()
            self.bias_latched = bool(np.max(np.abs(b)) >= 0.95 * math.radians(c.bias_clip_deg_s))
            if c.bias_gate_fusion_deg_s > 0 and w.fusion_bias_rad_s is not None:  # for 2 s on end
                over = bool(np.linalg.norm(b_h) > math.radians(c.bias_gate_fusion_deg_s))
                self.t_bias_over = (self.t_bias_over if self.t_bias_over is not None else self.t) if over else None
                self.bias_latched |= over and self.t - self.t_bias_over >= BIAS_EVIDENCE_S
        g_bias = c.bias_gate_weight if self.bias_latched else 0.0
        self.gate = max(g_flight, g_clip, g_bias)
        if c.tau_acc_flight_s > 0:
            tau = c.tau_acc_flight_s if g_flight > 0.5 else c.tau_acc_s
            if tau != self.tau_acc:
                self.f.setTauAcc(tau)
                self.tau_acc = tau
        self.sigma_net = float(w.sigma_rad)
        if c.centripetal:
            self.vel = g_flight * np.asarray(w.vel_m_s, np.float64)
            self.acc_v = g_flight * np.asarray(w.acc_m_s2, np.float64)
        if self.bias_latched:  # the older fusion's bias where it runs (bias states), else the network's
            nb = float(np.linalg.norm(b_h))
            dz = math.radians(c.bias_deadzone_deg_s)
            self.gyr_corr = b_h * max(0.0, 1.0 - dz / nb) if nb > 0 else np.zeros(3)
        k = c.pull_gain * self.gate
        if k > 0:
            up_s = to_sensor(-gravity_body(np.asarray(w.q_nb_wxyz, np.float64)))
            self.pull(tilt_pull_quat(self.f.getQuat6D(), up_s, k))

    def pull(self, d: np.ndarray) -> None:
        """Turn the filter's attitude by the earth-frame rotation ``d`` (horizontal axis): its
        inclination quaternion and, with it, its low-passed accelerometer states."""
        st = self.f.state
        aq = np.asarray(st["accQuat"], np.float64)
        rot = quat_to_rotmat(quat_mul(quat_conj(aq), quat_mul(quat_conj(d), aq)))
        st["lastAccLp"] = rot @ np.asarray(st["lastAccLp"], np.float64)
        s = np.asarray(st["accLpState"], np.float64).copy()
        if np.isnan(s[0]):  # still averaging its first samples: s[2:5] is their sum
            s[2:5] = rot @ s[2:5]
        else:  # two filter states per axis
            s = (rot @ s.reshape(3, 2)).reshape(6)
        st["accLpState"] = s
        st["accQuat"] = quat_normalize(quat_mul(d, aq))
        self.f.state = st


def _low_pass(x: np.ndarray, s0: float, alpha: float, block: int = 256) -> np.ndarray:
    """First-order low-pass ``s ← s + α(x − s)`` over ``x`` from state ``s0`` (vectorised in blocks:
    ``s_i = β^(i+1) s0 + α Σ_k β^(i−k) x_k``, β = 1 − α)."""
    out = np.empty(len(x))
    beta = 1.0 - alpha
    for a in range(0, len(x), block):
        v = x[a : a + block]
        m = len(v)
        p = beta ** np.arange(m)  # β^i
        with np.errstate(over="ignore", divide="ignore"):
            acc = np.cumsum(v / p) * p if beta > 0 else v.copy()
        out[a : a + m] = beta * p * s0 + alpha * acc if beta > 0 else v
        s0 = float(out[a + m - 1])
    return out


def ffill_rows(arr, first=None):
    """Forward-fill NaN rows of ``arr`` in place (from ``first`` before the first finite row)."""
    bad = ~np.all(np.isfinite(arr.reshape(len(arr), -1)), axis=1)
    if not bad.any():
        return
    idx = np.where(~bad, np.arange(len(arr)), -1)
    np.maximum.accumulate(idx, out=idx)
    have = idx >= 0
    arr[bad & have] = arr[idx[bad & have]]
    if first is not None:
        arr[~have] = first
