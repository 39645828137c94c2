"""The slow, obviously-correct reference of :mod:`tepinn_flight.model.fusion` (the pure-Python
per-sample implementation it replaced, kept verbatim): the compiled fusion must equal it.

The method is described in that module's docstring; this is pure numpy/float math, one sample at a time.
"""

from __future__ import annotations

import math

import numpy as np

from tepinn_flight.model.fusion import FusionConfig
from tepinn_flight.quat import gravity_body_f, quat_to_rotmat, quat_to_rotvec


def _qmul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def _qnorm(q):
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def _qdot(q, w):
    return _scale(_qmul(q, (0.0, w[0], w[1], w[2])), 0.5)


def _scale(q, s):
    return (q[0] * s, q[1] * s, q[2] * s, q[3] * s)


def _add(q, p, s):
    return (q[0] + s * p[0], q[1] + s * p[1], q[2] + s * p[2], q[3] + s * p[3])


def rk4(q, w0, w1, dt):
    """RK4 of q̇ = ½ q ⊗ (0, ω) with ω linear from w0 to w1 over dt."""
    wm = ((w0[0] + w1[0]) * 0.5, (w0[1] + w1[1]) * 0.5, (w0[2] + w1[2]) * 0.5)
    k1 = _qdot(q, w0)
    k2 = _qdot(_add(q, k1, 0.5 * dt), wm)
    k3 = _qdot(_add(q, k2, 0.5 * dt), wm)
    k4 = _qdot(_add(q, k3, dt), w1)
    s = dt / 6.0
    return _qnorm(tuple(q[i] + s * (k1[i] + 2 * k2[i] + 2 * k3[i] + k4[i]) for i in range(4)))


def _exp(r):
    th = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    if th < 1e-12:
        return (1.0, 0.5 * r[0], 0.5 * r[1], 0.5 * r[2])
    k = math.sin(0.5 * th) / th
    return (math.cos(0.5 * th), k * r[0], k * r[1], k * r[2])


def _tilt_axis_angle(q, p):
    """(gp × gm, |gp × gm|, angle) between the gravity directions of two attitudes (body axes of q)."""
    gp = gravity_body_f(q)
    gm = gravity_body_f(p)
    c = (gp[1] * gm[2] - gp[2] * gm[1], gp[2] * gm[0] - gp[0] * gm[2], gp[0] * gm[1] - gp[1] * gm[0])
    s = math.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
    return c, s, math.atan2(s, gp[0] * gm[0] + gp[1] * gm[1] + gp[2] * gm[2])


def tilt_toward(q, q_meas, gain):
    """Rotate q (in its body frame) so its gravity direction moves ``gain`` of the way to q_meas's."""
    c, s, ang = _tilt_axis_angle(q, q_meas)
    if s < 1e-12:
        return q
    k = -gain * ang / s  # rotation by -gain·ang about n = gp × gm (body frame)
    return _qnorm(_qmul(q, _exp((k * c[0], k * c[1], k * c[2]))))


def zero_yaw_np(q):
    g = gravity_body_f(q)
    roll = math.atan2(g[1], g[2])
    pitch = math.atan2(-g[0], math.sqrt(g[1] * g[1] + g[2] * g[2]))
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    return (cr * cp, sr * cp, cr * sp, -sr * sp)


class AttitudeFusion:
    """State of one causal pass: call :meth:`step` for every IMU sample in order."""

    def __init__(self, config: FusionConfig):
        self.c = config
        self.reset()

    def reset(self) -> None:
        self.q = None  # full attitude body→NED (tuple), None until the first window estimate
        self.bias = (0.0, 0.0, 0.0)
        self.P = 0.0
        self.t = None
        self.w = None
        self.t_est = None
        self.cov6 = None  # bias_states: 6×6 covariance of (δθ, δb) at the last update
        self.q_est = None  # bias_states: attitude right after the last update
        self.Q_acc = 0.0  # bias_states: tilt variance added by the propagation since the update
        self.t_clip = None  # time of the last saturated sample

    def step(self, t: float, w_rad_s, est=None, clipped: bool = False):
        """Advance to sample time ``t`` with gyro ``w`` and return (q or None, σ, bias) for it.

        ``est`` = (q_tilt, σ_rad, bias) is a window estimate that ended at the *previous* sample
        (a token is known to be complete only when the next sample arrives): it corrects the state
        at that time, before the propagation to ``t``. Offline and live runs therefore agree.
        """
        c = self.c
        k = 1.0 + c.clip_rate_gain if clipped else 1.0  # a saturated gyro reads less than the rate
        w = (k * float(w_rad_s[0]), k * float(w_rad_s[1]), k * float(w_rad_s[2]))
        held = self.t_clip is not None and self.t is not None and self.t - self.t_clip <= c.clip_hold_s
        if clipped:
            self.t_clip = t
        if est is not None and not (c.clip_skip_updates and held and self.q is not None):
            self._update(est)  # (the estimate belongs to the previous sample: `held` is judged there)
        if self.q is not None and self.t is not None:
            dt = t - self.t
            if dt > 0:
                b = self.bias
                self.q = rk4(self.q, (self.w[0] - b[0], self.w[1] - b[1], self.w[2] - b[2]),
                             (w[0] - b[0], w[1] - b[1], w[2] - b[2]), dt)  # fmt: skip
                dP = c.process_noise_rad2_s * dt
                if c.process_noise_rate_rad > 0:
                    wm = (0.5 * (self.w[0] + w[0]) - b[0], 0.5 * (self.w[1] + w[1]) - b[1], 0.5 * (self.w[2] + w[2]) - b[2])
                    dP += c.process_noise_rate_rad * math.sqrt(wm[0] * wm[0] + wm[1] * wm[1] + wm[2] * wm[2]) * dt
                if clipped or (c.clip_hold_s > 0 and self.t_clip is not None and t - self.t_clip <= c.clip_hold_s):
                    dP += c.clip_inflation_rad**2  # a saturated sensor: the attitude is no longer trusted
                self.P += dP
                self.Q_acc += dP
        self.t, self.w = t, w
        if self.q is None:
            return None, float("nan"), self.bias
        q = zero_yaw_np(self.q) if c.yaw == "zero" else self.q
        return q, c.output_sigma_scale * math.sqrt(self.P), self.bias

    def _update(self, est) -> None:
        c = self.c
        if c.bias_states and c.enabled:
            return self._update_kf(est)
        q_m, sigma, b_m = est
        r = (c.sigma_scale * float(sigma)) ** 2
        t = self.t
        if self.q is None:
            self.q, self.P = tuple(float(v) for v in q_m), r
            self.bias = tuple(float(v) for v in b_m)
        else:
            if c.enabled and c.adaptive_nis > 0:
                e = _tilt_axis_angle(self.q, q_m)[2]
                self.P = max(self.P, e * e / c.adaptive_nis - r)
            gain = self.P / (self.P + r) if c.enabled else 1.0
            self.q = tilt_toward(self.q, q_m, gain)
            self.P = (1 - gain) * self.P
            if c.enabled and self.t_est is not None:
                a = min(1.0, max(0.0, t - self.t_est) / c.bias_time_constant_s)
                self.bias = tuple(self.bias[i] + a * (float(b_m[i]) - self.bias[i]) for i in range(3))
            elif not c.enabled:
                self.bias = tuple(float(v) for v in b_m)
        self.t_est = t

    def _update_kf(self, est) -> None:
        c = self.c
        q_m, sigma, b_m = est
        r = (c.sigma_scale * float(sigma)) ** 2
        b_m = np.asarray(b_m, dtype=float)
        if self.q is None:
            self.q = tuple(float(v) for v in q_m)
            self.bias = tuple(float(v) for v in b_m)
            self.cov6 = np.diag([r] * 3 + [c.bias_init_sigma_rad_s**2] * 3)
            self.P, self.q_est, self.t_est, self.Q_acc = r, self.q, self.t, 0.0
            return
        # covariance from the last update to now: δθ⁺ = ΔRᵀ δθ − J δb (ΔR = Exp φ over the interval)
        dt = max(0.0, self.t - self.t_est)
        q_rel = np.array(_qmul((self.q_est[0], -self.q_est[1], -self.q_est[2], -self.q_est[3]), self.q))
        F = np.eye(6)
        F[:3, :3] = quat_to_rotmat(q_rel).T
        F[:3, 3:] = -dt * _integral_of_exp(-quat_to_rotvec(q_rel))
        P = F @ self.cov6 @ F.T
        P[:3, :3] += self.Q_acc * np.eye(3)
        P[3:, 3:] += c.bias_rw_rad_s_sqrt_s**2 * dt * np.eye(3)
        # tilt measurement: the 2 components of the error rotation perpendicular to gravity
        gp = np.array(gravity_body_f(self.q))
        cx, s, ang = _tilt_axis_angle(self.q, q_m)
        e1 = np.cross(gp, [1.0, 0.0, 0.0] if abs(gp[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(gp, e1)
        res = -ang / s * np.array(cx) if s > 1e-12 else np.zeros(3)  # δθ that moves gp onto gm
        H = np.zeros((2, 6))
        H[0, :3], H[1, :3] = e1, e2
        zt = H[:, :3] @ res
        if c.adaptive_nis > 0:  # innovation-adaptive: the propagation was worse than P says
            p_tilt = 0.5 * (e1 @ P[:3, :3] @ e1 + e2 @ P[:3, :3] @ e2)
            extra = ang * ang / c.adaptive_nis - r - p_tilt
            if extra > 0:
                P[:3, :3] += extra * np.eye(3)
        dx, P = _kalman(P, H, zt, r)
        if c.bias_sigma_rad_s > 0:  # the network's bias estimate, a direct measurement of b
            Hb = np.zeros((3, 6))
            Hb[:, 3:] = np.eye(3)
            dxb, P = _kalman(P, Hb, b_m - (np.asarray(self.bias) + dx[3:]), c.bias_sigma_rad_s**2)
            dx = dx + dxb  # sequential update: the innovation is taken after the tilt correction
        self.q = _qnorm(_qmul(self.q, _exp(tuple(dx[:3]))))
        self.bias = tuple(float(v) for v in np.asarray(self.bias) + dx[3:])
        self.cov6 = 0.5 * (P + P.T)
        g = np.array(gravity_body_f(self.q))
        self.P = 0.5 * (np.trace(self.cov6[:3, :3]) - g @ self.cov6[:3, :3] @ g)  # per-axis tilt variance
        self.q_est, self.t_est, self.Q_acc = self.q, self.t, 0.0


def _integral_of_exp(phi):
    """∫₀¹ Exp(s φ) ds = I + (1 − cos θ)/θ² [φ×] + (θ − sin θ)/θ³ [φ×]² (θ = |φ|)."""
    th = float(np.linalg.norm(phi))
    X = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if th < 1e-6:
        return np.eye(3) + 0.5 * X + X @ X / 6.0
    return np.eye(3) + (1 - math.cos(th)) / th**2 * X + (th - math.sin(th)) / th**3 * X @ X


def _kalman(P, H, z, r):
    """One linear Kalman update of the error state (measurement noise r·I); returns (dx, P⁺)."""
    S = H @ P @ H.T + r * np.eye(len(z))
    K = np.linalg.solve(S, H @ P).T
    return K @ z, P - K @ H @ P


def feedback_bias(config: FusionConfig, bias) -> tuple[float, float, float]:
    """The gyro offset the network's windows get under bias feedback: the fusion's bias estimate,
    soft-thresholded by ``bias_feedback_deadzone_rad_s`` per axis."""
    d = config.bias_feedback_deadzone_rad_s
    return tuple(math.copysign(max(abs(float(b)) - d, 0.0), float(b)) for b in bias)


class FusionRun:
    """An offline pass over one segment, advanced in pieces: window estimates can be added while it
    runs (the bias feedback needs the fusion's bias before it can make the next windows).
    ``add`` takes window estimates by the sample index of their window's last sample (each one is
    applied when the next sample arrives, as live); ``advance(stop)`` steps through samples up to
    ``stop`` (exclusive)."""

    def __init__(self, t_s, gyr, config: FusionConfig, clipped=None):
        n = len(t_s)
        self.t_s, self.gyr, self.clipped = t_s, gyr, clipped
        self.q = np.full((n, 4), np.nan)
        self.sigma = np.full(n, np.nan)
        self.bias = np.full((n, 3), np.nan)
        self.fusion = AttitudeFusion(config)
        self.pending: dict[int, tuple] = {}
        self.i = 0

    def add(self, est_index, est_q, est_sigma, est_bias) -> None:
        for k, i in enumerate(est_index):
            self.pending[int(i) + 1] = (est_q[k], float(est_sigma[k]), est_bias[k])

    def advance(self, stop: int) -> None:
        f, clipped = self.fusion, self.clipped
        for i in range(self.i, min(stop, len(self.t_s))):
            est = self.pending.pop(i, None)
            q, s, b = f.step(float(self.t_s[i]), self.gyr[i], est, bool(clipped[i]) if clipped is not None else False)
            if q is not None:
                self.q[i] = q
                self.sigma[i] = s
                self.bias[i] = b
        self.i = max(self.i, min(stop, len(self.t_s)))

