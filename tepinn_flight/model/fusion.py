"""Causal per-sample attitude output: RK4 gyro propagation fused with TE-PINN window estimates.

The network gives a tilt estimate with a calibrated σ at each token end (25 Hz by default). Between
them, and to carry heading, the attitude is propagated sample by sample with RK4 quaternion
kinematics of the bias-corrected gyro ``ω − b̂``. At each window estimate, the tilt is pulled
toward the network's by a Kalman gain ``K = P / (P + σ²)`` (P: propagated tilt variance), and the
bias follows the network's per-window bias estimate through a first-order low-pass (the bias is a
slow random walk). Heading comes from gyro integration only (6-D) and starts at 0. A saturated
gyro sample reads less than the true rate: it is propagated at ``(1 + clip_rate_gain)``× its
reading (the model's learned declipping gain κ, when calibration finds that it helps) and adds
``clip_inflation_rad`` to the propagated σ.

Innovation-adaptive covariance (``adaptive_nis`` = ν > 0): when the squared tilt innovation e²
exceeds ν·(P + σ²), the propagation was worse than P says (an uncalibrated gyro, a bias the
network has not found yet, an unflagged saturation), so P is raised to e²/ν − σ² before the
update. With a good gyro this never fires; with a bad one the output falls back toward the
network's window estimates instead of drifting away with the gyro.

Bias states (``bias_states`` = True): instead of the low-pass, a 6-state error Kalman filter
(tilt/heading error δθ in body axes, gyro-bias error δb) is updated at each window estimate. Its
covariance is carried between estimates with the exact rotation of the interval
(``δθ⁺ = ΔRᵀ δθ − J δb``, ``J = ∫₀ᵀ Exp(−φ u/T) du``, exact for a constant rate), so the tilt
innovations themselves estimate the bias — as VQF and an EKF do — and the network's per-window bias is a second measurement of it
(σ ``bias_sigma_rad_s``). A bias far outside what the network was trained on (an uncalibrated
gyro: 15–20 °/s) is then found from the drift, not followed blindly.

One sample at a time, compiled (numba, float64): the offline estimator runs the loop over a whole
segment in one call (:class:`FusionRun`), the live bridge one sample per call (:class:`AttitudeFusion`);
both are the same kernel. ``tests/fusion_reference.py`` keeps the pure-Python implementation it
replaced as the reference it is tested against.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..config import check_range
from ..errors import ConfigError
from ..quat_scalar import down_in_body, exp_rotvec, qmul, qnorm
from ..small_linalg import mul, mul_bt, solve_in_place


@dataclass(frozen=True)
class FusionConfig:
    """The older fusion's settings. Defaults are the shipped model's (its checkpoint's calibrated
    ``fusion_config``: the bias-state Kalman update with bias feedback); :meth:`uncalibrated` gives
    the settings calibration starts from, which are also what a checkpoint written before a field
    existed ran with (:func:`~.checkpoint.fusion_config_from` fills them in)."""

    enabled: bool = True  # False: take each window estimate as is (then propagate to the next)
    process_noise_rad2_s: float = 1e-4  # tilt variance growth of the propagation (gyro noise + bias)
    # ... plus this much per radian turned (rad²/rad): a gyro's scale-factor and misalignment errors
    # grow the attitude error with the angle rotated, not with time (a 1 % scale error is 3.6° per
    # aileron roll and nothing in level flight)
    process_noise_rate_rad: float = 0.0
    bias_time_constant_s: float = 10.0  # low-pass of the network's per-window bias estimates (low-pass update)
    sigma_scale: float = 3.0  # calibration factor applied to the network's σ
    clip_inflation_rad: float = 0.35  # a saturated gyro/accel sample adds this σ to the propagation
    clip_rate_gain: float = 0.8397  # a saturated sample is propagated at (1 + gain)× its reading (κ)
    output_sigma_scale: float = 1.4134260780354513  # calibration of the reported σ (fitted on validation flights)
    adaptive_nis: float = 0.0  # > 0: innovation-adaptive P (see the low-pass update); 0: off
    yaw: str = "gyro"  # "gyro": heading from gyro integration; "zero": yaw := 0 on the output
    bias_states: bool = True  # True: the 6-state Kalman update with gyro-bias states; False: the low-pass update
    bias_sigma_rad_s: float = 0.3  # σ of the network's per-window bias as a measurement (bias_states)
    bias_rw_rad_s_sqrt_s: float = 1e-4  # random walk of the gyro bias (bias_states)
    bias_init_sigma_rad_s: float = 0.3  # σ of the first bias estimate (bias_states)
    # after a saturated sample the attitude stays untrusted for this long (the inflation above goes
    # on for every sample up to clip_hold_s after the last clipped one), and with clip_skip_updates
    # the window estimates made in that time are not applied: a window that saw the saturation
    # mid-flip is as wrong as the gyro (the network's σ rarely says so), while the first estimates
    # after it, from tokens after the flip, are not — they should meet an open covariance
    clip_hold_s: float = 2.0
    clip_skip_updates: bool = False
    # bias feedback (> 0): the network sees the gyro minus the fusion's current bias estimate, as
    # an EKF propagates with its bias-corrected gyro; the estimate is refreshed every this many
    # windows (one network batch: offline and live take the same values). The network's own bias
    # output is then a correction to it. 0: the raw gyro (a turn-on bias of 15–20 °/s rotates the
    # window's physics by tens of degrees and the network follows it)
    bias_feedback_windows: int = 25
    # only the part of each bias component beyond this is fed back (soft threshold): the network
    # handles the small biases it was trained with, and a calibrated gyro's estimate, which wanders
    # with the tilt errors of long turns, is then not fed back at all (2 °/s)
    bias_feedback_deadzone_rad_s: float = 0.03490658503988659

    @classmethod
    def uncalibrated(cls, **changes) -> "FusionConfig":
        """The low-pass update with nothing calibrated and every option off: where calibration
        starts (``TrainConfig.fusion``), and the value of any field a checkpoint lacks."""
        return cls(**{**UNCALIBRATED, **changes})

    def __post_init__(self):
        if self.yaw not in ("gyro", "zero"):
            raise ConfigError(f"fusion 'yaw' must be gyro or zero, got {self.yaw!r}")
        for name in ("enabled", "bias_states", "clip_skip_updates"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"fusion {name!r} must be true or false, got {getattr(self, name)!r}")
        if not isinstance(self.bias_feedback_windows, int):
            raise ConfigError(f"fusion 'bias_feedback_windows' must be an integer, got {self.bias_feedback_windows!r}")
        check_range("bias_feedback_windows", self.bias_feedback_windows, 0, 10**6)
        for f in dataclasses.fields(self):
            if f.type == "float":
                strict = f.name in ("bias_time_constant_s", "sigma_scale", "output_sigma_scale")
                check_range(f.name, getattr(self, f.name), 0, None, lo_open=strict)

    def kernel_params(self) -> np.ndarray:
        """The settings as the compiled loop reads them (float64, indices ``_P_*``)."""
        p = np.zeros(_NP)
        p[_P_ENABLED] = self.enabled
        p[_P_PN] = self.process_noise_rad2_s
        p[_P_PN_RATE] = self.process_noise_rate_rad
        p[_P_BIAS_TAU] = self.bias_time_constant_s
        p[_P_SIGMA_SCALE] = self.sigma_scale
        p[_P_CLIP_INFL] = self.clip_inflation_rad
        p[_P_CLIP_GAIN] = self.clip_rate_gain
        p[_P_OUT_SCALE] = self.output_sigma_scale
        p[_P_NIS] = self.adaptive_nis
        p[_P_YAW_ZERO] = self.yaw == "zero"
        p[_P_KF] = self.bias_states and self.enabled
        p[_P_BIAS_SIGMA] = self.bias_sigma_rad_s
        p[_P_BIAS_RW] = self.bias_rw_rad_s_sqrt_s
        p[_P_BIAS_INIT] = self.bias_init_sigma_rad_s
        p[_P_CLIP_HOLD] = self.clip_hold_s
        p[_P_CLIP_SKIP] = self.clip_skip_updates
        return p


#: FusionConfig.uncalibrated(): the defaults before they became the shipped model's
UNCALIBRATED = dict(enabled=True, process_noise_rad2_s=1e-4, process_noise_rate_rad=0.0, bias_time_constant_s=10.0,
                    sigma_scale=1.0, clip_inflation_rad=0.35, clip_rate_gain=0.0, output_sigma_scale=1.0,
                    adaptive_nis=0.0, yaw="gyro", bias_states=False, bias_sigma_rad_s=0.02,
                    bias_rw_rad_s_sqrt_s=1e-3, bias_init_sigma_rad_s=0.1, clip_hold_s=0.0, clip_skip_updates=False,
                    bias_feedback_windows=0, bias_feedback_deadzone_rad_s=0.0)  # fmt: skip

# settings vector (FusionConfig.kernel_params)
(_P_ENABLED, _P_PN, _P_PN_RATE, _P_BIAS_TAU, _P_SIGMA_SCALE, _P_CLIP_INFL, _P_CLIP_GAIN, _P_OUT_SCALE, _P_NIS, _P_YAW_ZERO,
 _P_KF, _P_BIAS_SIGMA, _P_BIAS_RW, _P_BIAS_INIT, _P_CLIP_HOLD, _P_CLIP_SKIP, _NP) = range(17)  # fmt: skip
# state vector (NaN: not yet known)
_S_Q = 0  # (4) attitude body→NED
_S_B = 4  # (3) gyro bias
_S_P = 7  # propagated tilt variance
_S_T = 8  # time of the last sample
_S_W = 9  # (3) its gyro (times the declipping gain)
_S_TEST = 12  # time of the last window estimate applied
_S_QE = 13  # (4) bias states: attitude right after the last update
_S_QACC = 17  # bias states: tilt variance added by the propagation since the update
_S_TCLIP = 18  # time of the last saturated sample
_S_COV = 19  # (36) bias states: 6×6 covariance of (δθ, δb) at the last update, row-major
_NS = _S_COV + 36


# the live step's one buffer (views of it: the state, the settings, the sample's gyro, a window's tilt and bias, the
# output): two arguments to pass instead of six (numba checks each argument's type on every call from Python)
_O_S = 0
_O_P = _O_S + _NS
_O_W = _O_P + _NP
_O_QM = _O_W + 3
_O_BM = _O_QM + 4
_O_OUT = _O_BM + 3
_NBUF = _O_OUT + 8


def new_state() -> np.ndarray:
    s = np.full(_NS, np.nan)
    s[_S_B : _S_B + 3] = 0.0
    s[_S_P] = 0.0
    s[_S_QACC] = 0.0
    return s


# ---------------------------------------------------------------------------------- the compiled loop


@njit(cache=True)
def rk4(q, w0, w1, dt):
    """RK4 of q̇ = ½ q ⊗ (0, ω) with ω linear from w0 to w1 over dt (4-/3-tuples of floats)."""
    q0, q1, q2, q3 = q
    wm0, wm1, wm2 = (w0[0] + w1[0]) * 0.5, (w0[1] + w1[1]) * 0.5, (w0[2] + w1[2]) * 0.5
    h = 0.5 * dt
    a0, a1, a2, a3 = qmul(q0, q1, q2, q3, 0.0, w0[0], w0[1], w0[2])
    a0, a1, a2, a3 = a0 * 0.5, a1 * 0.5, a2 * 0.5, a3 * 0.5
    b0, b1, b2, b3 = qmul(q0 + h * a0, q1 + h * a1, q2 + h * a2, q3 + h * a3, 0.0, wm0, wm1, wm2)
    b0, b1, b2, b3 = b0 * 0.5, b1 * 0.5, b2 * 0.5, b3 * 0.5
    c0, c1, c2, c3 = qmul(q0 + h * b0, q1 + h * b1, q2 + h * b2, q3 + h * b3, 0.0, wm0, wm1, wm2)
    c0, c1, c2, c3 = c0 * 0.5, c1 * 0.5, c2 * 0.5, c3 * 0.5
    d0, d1, d2, d3 = qmul(q0 + dt * c0, q1 + dt * c1, q2 + dt * c2, q3 + dt * c3, 0.0, w1[0], w1[1], w1[2])
    d0, d1, d2, d3 = d0 * 0.5, d1 * 0.5, d2 * 0.5, d3 * 0.5
    s = dt / 6.0
    return qnorm(q0 + s * (a0 + 2 * b0 + 2 * c0 + d0), q1 + s * (a1 + 2 * b1 + 2 * c1 + d1),
                 q2 + s * (a2 + 2 * b2 + 2 * c2 + d2), q3 + s * (a3 + 2 * b3 + 2 * c3 + d3))  # fmt: skip


@njit(cache=True)
def _tilt_axis_angle(q, p):
    """(gp × gm, |gp × gm|, angle) between the gravity directions of two attitudes (body axes of q)."""
    gp = down_in_body(q[0], q[1], q[2], q[3])
    gm = down_in_body(p[0], p[1], p[2], p[3])
    c = (gp[1] * gm[2] - gp[2] * gm[1], gp[2] * gm[0] - gp[0] * gm[2], gp[0] * gm[1] - gp[1] * gm[0])
    s = math.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
    return c, s, math.atan2(s, gp[0] * gm[0] + gp[1] * gm[1] + gp[2] * gm[2])


@njit(cache=True)
def tilt_toward(q, q_meas, gain):
    """Rotate q (in its body frame) so its gravity direction moves ``gain`` of the way to q_meas's."""
    c, s, ang = _tilt_axis_angle(q, q_meas)
    if s < 1e-12:
        return (q[0], q[1], q[2], q[3])
    k = -gain * ang / s  # rotation by -gain·ang about n = gp × gm (body frame)
    e = exp_rotvec(k * c[0], k * c[1], k * c[2])
    return qnorm(*qmul(q[0], q[1], q[2], q[3], e[0], e[1], e[2], e[3]))


@njit(cache=True)
def zero_yaw_np(q):
    g = down_in_body(q[0], q[1], q[2], q[3])
    roll = math.atan2(g[1], g[2])
    pitch = math.atan2(-g[0], math.sqrt(g[1] * g[1] + g[2] * g[2]))
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    return (cr * cp, sr * cp, cr * sp, -sr * sp)


# the state accessors are inlined (numba IR): called with constant offsets and with arrays or
# tuples, they would otherwise be compiled once per combination (6 compiles, ≈ 0.4 s cold)
@njit(cache=True, inline="always")
def _q(s, i):
    return (s[i], s[i + 1], s[i + 2], s[i + 3])


@njit(cache=True, inline="always")
def _set_q(s, i, q):
    s[i], s[i + 1], s[i + 2], s[i + 3] = q[0], q[1], q[2], q[3]


@njit(cache=True)
def _update_lowpass(s, p, q_m, sigma, b_m):
    """The low-pass fusion's window update: Kalman-weighted tilt pull, bias low-pass (module doc)."""
    enabled = p[_P_ENABLED] != 0.0
    r = (p[_P_SIGMA_SCALE] * sigma) ** 2
    if math.isnan(s[_S_Q]):
        _set_q(s, _S_Q, q_m)
        s[_S_P] = r
        s[_S_B], s[_S_B + 1], s[_S_B + 2] = b_m[0], b_m[1], b_m[2]
    else:
        q = _q(s, _S_Q)
        if enabled and p[_P_NIS] > 0:
            e = _tilt_axis_angle(q, q_m)[2]
            s[_S_P] = max(s[_S_P], e * e / p[_P_NIS] - r)
        gain = s[_S_P] / (s[_S_P] + r) if enabled else 1.0
        _set_q(s, _S_Q, tilt_toward(q, q_m, gain))
        s[_S_P] = (1 - gain) * s[_S_P]
        if enabled and not math.isnan(s[_S_TEST]):
            a = min(1.0, max(0.0, s[_S_T] - s[_S_TEST]) / p[_P_BIAS_TAU])
            for i in range(3):
                s[_S_B + i] = s[_S_B + i] + a * (b_m[i] - s[_S_B + i])
        elif not enabled:
            s[_S_B], s[_S_B + 1], s[_S_B + 2] = b_m[0], b_m[1], b_m[2]
    s[_S_TEST] = s[_S_T]


@njit(cache=True)
def _rotvec(q):
    """quat_to_rotvec (canonical w >= 0, Taylor branch below 1e-4) of a unit quaternion."""
    w, x, y, z = q
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    n2 = x * x + y * y + z * z
    if n2 < 1e-8:
        ws = max(abs(w), 1e-12) * (-1.0 if w < 0 else 1.0)
        k = 2.0 / ws * (1.0 - n2 / (3.0 * ws * ws))
    else:
        n = math.sqrt(n2)
        k = 2.0 * math.atan2(n, w) / n
    return x * k, y * k, z * k


@njit(cache=True)
def _integral_of_exp(phi0, phi1, phi2, J):
    """J ← ∫₀¹ Exp(s φ) ds = I + (1 − cos θ)/θ² [φ×] + (θ − sin θ)/θ³ [φ×]² (θ = |φ|; J 3×3)."""
    X = np.empty((3, 3))
    th = math.sqrt(phi0 * phi0 + phi1 * phi1 + phi2 * phi2)
    X[0, 0], X[0, 1], X[0, 2] = 0.0, -phi2, phi1
    X[1, 0], X[1, 1], X[1, 2] = phi2, 0.0, -phi0
    X[2, 0], X[2, 1], X[2, 2] = -phi1, phi0, 0.0
    if th < 1e-6:
        XX = np.empty((3, 3))
        mul(X, X, XX)
        for i in range(3):
            for j in range(3):
                J[i, j] = ((1.0 if i == j else 0.0) + 0.5 * X[i, j]) + XX[i, j] / 6.0
        return
    c1 = (1 - math.cos(th)) / th**2
    c2 = (th - math.sin(th)) / th**3
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for l in range(3):
                acc += (c2 * X[i, l]) * X[l, j]
            J[i, j] = ((1.0 if i == j else 0.0) + c1 * X[i, j]) + acc


@njit(cache=True)
def _dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def _quad3(e, P):
    """eᵀ P[:3, :3] e."""
    acc = 0.0
    for j in range(3):
        acc += (e[0] * P[0, j] + e[1] * P[1, j] + e[2] * P[2, j]) * e[j]
    return acc


@njit(cache=True)
def _kalman(P, H, z, r, dx):
    """One linear Kalman update of the 6-state error with the m×6 H (measurement noise r·I):
    ``dx ← K z`` and ``P ← P − K H P`` in place (K = P Hᵀ S⁻¹, S = H P Hᵀ + r I)."""
    m = H.shape[0]
    HP = np.empty((m, 6))
    S = np.empty((m, m))
    X = np.empty((m, 6))
    mul(H, P, HP)
    mul_bt(HP, H, S)
    for i in range(m):
        S[i, i] += r
    for i in range(m):
        for j in range(6):
            X[i, j] = HP[i, j]
    solve_in_place(S, X)  # X = S⁻¹ H P = Kᵀ
    for i in range(6):
        acc = 0.0
        for j in range(m):
            acc += X[j, i] * z[j]
        dx[i] = acc
    for i in range(6):
        for j in range(6):
            acc = 0.0
            for l in range(m):
                acc += X[l, i] * HP[l, j]
            P[i, j] = P[i, j] - acc


@njit(cache=True)
def _update_kf(s, p, q_m, sigma, b_m):
    """The bias-state fusion's window update: a 6-state error Kalman filter (module doc)."""
    r = (p[_P_SIGMA_SCALE] * sigma) ** 2
    if math.isnan(s[_S_Q]):
        _set_q(s, _S_Q, q_m)
        s[_S_B], s[_S_B + 1], s[_S_B + 2] = b_m[0], b_m[1], b_m[2]
        for k in range(36):
            s[_S_COV + k] = 0.0
        for i in range(3):
            s[_S_COV + 7 * i] = r
            s[_S_COV + 7 * (3 + i)] = p[_P_BIAS_INIT] ** 2
        s[_S_P] = r
        _set_q(s, _S_QE, q_m)
        s[_S_TEST] = s[_S_T]
        s[_S_QACC] = 0.0
        return
    F = np.empty((6, 6))  # work buffers (once per window estimate)
    C = np.empty((6, 6))
    T = np.empty((6, 6))
    P = np.empty((6, 6))
    J = np.empty((3, 3))
    dx = np.empty(6)
    q = _q(s, _S_Q)
    qe = _q(s, _S_QE)
    # covariance from the last update to now: δθ⁺ = ΔRᵀ δθ − J δb (ΔR = Exp φ over the interval)
    dt = max(0.0, s[_S_T] - s[_S_TEST])
    w, x, y, z_ = qmul(qe[0], -qe[1], -qe[2], -qe[3], q[0], q[1], q[2], q[3])
    phi = _rotvec((w, x, y, z_))
    _integral_of_exp(-phi[0], -phi[1], -phi[2], J)
    # F = [[ΔRᵀ, −dt J], [0, I]] (ΔR's rows below, transposed into F)
    F[0, 0], F[1, 0], F[2, 0] = 1 - 2 * (y * y + z_ * z_), 2 * (x * y - w * z_), 2 * (x * z_ + w * y)
    F[0, 1], F[1, 1], F[2, 1] = 2 * (x * y + w * z_), 1 - 2 * (x * x + z_ * z_), 2 * (y * z_ - w * x)
    F[0, 2], F[1, 2], F[2, 2] = 2 * (x * z_ - w * y), 2 * (y * z_ + w * x), 1 - 2 * (x * x + y * y)
    for i in range(3):
        for j in range(3):
            F[i, 3 + j] = -dt * J[i, j]
            F[3 + i, j] = 0.0
            F[3 + i, 3 + j] = 1.0 if i == j else 0.0
    for i in range(6):
        for j in range(6):
            C[i, j] = s[_S_COV + 6 * i + j]
    mul(F, C, T)
    mul_bt(T, F, P)  # F C Fᵀ
    for i in range(3):
        P[i, i] += s[_S_QACC]
        P[3 + i, 3 + i] += p[_P_BIAS_RW] ** 2 * dt
    # tilt measurement: the 2 components of the error rotation perpendicular to gravity
    gp = down_in_body(q[0], q[1], q[2], q[3])
    cx, sn, ang = _tilt_axis_angle(q, q_m)
    ax = (1.0, 0.0, 0.0) if abs(gp[0]) < 0.9 else (0.0, 1.0, 0.0)
    e1 = (gp[1] * ax[2] - gp[2] * ax[1], gp[2] * ax[0] - gp[0] * ax[2], gp[0] * ax[1] - gp[1] * ax[0])
    n1 = math.sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2])
    e1 = (e1[0] / n1, e1[1] / n1, e1[2] / n1)
    e2 = (gp[1] * e1[2] - gp[2] * e1[1], gp[2] * e1[0] - gp[0] * e1[2], gp[0] * e1[1] - gp[1] * e1[0])
    res = (0.0, 0.0, 0.0)
    if sn > 1e-12:  # δθ that moves gp onto gm
        k = -ang / sn
        res = (k * cx[0], k * cx[1], k * cx[2])
    H = np.zeros((2, 6))
    for j in range(3):
        H[0, j] = e1[j]
        H[1, j] = e2[j]
    z = np.empty(2)
    z[0], z[1] = _dot3(e1, res), _dot3(e2, res)
    if p[_P_NIS] > 0:  # innovation-adaptive: the propagation was worse than P says
        p_tilt = 0.5 * (_quad3(e1, P) + _quad3(e2, P))
        extra = ang * ang / p[_P_NIS] - r - p_tilt
        if extra > 0:
            for i in range(3):
                P[i, i] += extra
    _kalman(P, H, z, r, dx)
    if p[_P_BIAS_SIGMA] > 0:  # the network's bias estimate, a direct measurement of b
        Hb = np.zeros((3, 6))
        zb = np.empty(3)
        for i in range(3):
            Hb[i, 3 + i] = 1.0
            zb[i] = b_m[i] - (s[_S_B + i] + dx[3 + i])
        dxb = np.empty(6)
        _kalman(P, Hb, zb, p[_P_BIAS_SIGMA] ** 2, dxb)
        for i in range(6):  # sequential update: the innovation is taken after the tilt correction
            dx[i] = dx[i] + dxb[i]
    e = exp_rotvec(dx[0], dx[1], dx[2])
    q = qnorm(*qmul(q[0], q[1], q[2], q[3], e[0], e[1], e[2], e[3]))
    _set_q(s, _S_Q, q)
    for i in range(3):
        s[_S_B + i] = s[_S_B + i] + dx[3 + i]
    for i in range(6):
        for j in range(6):
            s[_S_COV + 6 * i + j] = 0.5 * (P[i, j] + P[j, i])
    g = down_in_body(q[0], q[1], q[2], q[3])
    tr = s[_S_COV] + s[_S_COV + 7] + s[_S_COV + 14]
    gPg = 0.0
    for i in range(3):
        for j in range(3):
            gPg += g[i] * s[_S_COV + 6 * i + j] * g[j]
    s[_S_P] = 0.5 * (tr - gPg)  # per-axis tilt variance
    _set_q(s, _S_QE, q)
    s[_S_TEST] = s[_S_T]
    s[_S_QACC] = 0.0


@njit(cache=True)
def _step(s, p, t, w_in, clipped, has_est, q_m, sigma_m, b_m, out):
    """One sample (see :meth:`AttitudeFusion.step`); writes (q, σ, bias) into ``out`` (8) and
    returns whether q is known."""
    k = 1.0 + p[_P_CLIP_GAIN] if clipped else 1.0  # a saturated gyro reads less than the rate
    w0, w1, w2 = k * w_in[0], k * w_in[1], k * w_in[2]
    hold = p[_P_CLIP_HOLD]
    held = not math.isnan(s[_S_TCLIP]) and not math.isnan(s[_S_T]) and s[_S_T] - s[_S_TCLIP] <= hold
    if clipped:
        s[_S_TCLIP] = t
    if has_est and not (p[_P_CLIP_SKIP] != 0.0 and held and not math.isnan(s[_S_Q])):
        if p[_P_KF] != 0.0:  # (the estimate belongs to the previous sample: `held` is judged there)
            _update_kf(s, p, q_m, sigma_m, b_m)
        else:
            _update_lowpass(s, p, q_m, sigma_m, b_m)
    if not math.isnan(s[_S_Q]) and not math.isnan(s[_S_T]):
        dt = t - s[_S_T]
        if dt > 0:
            b0, b1, b2 = s[_S_B], s[_S_B + 1], s[_S_B + 2]
            pw0, pw1, pw2 = s[_S_W], s[_S_W + 1], s[_S_W + 2]
            q = rk4(_q(s, _S_Q), (pw0 - b0, pw1 - b1, pw2 - b2), (w0 - b0, w1 - b1, w2 - b2), dt)
            _set_q(s, _S_Q, q)
            dP = p[_P_PN] * dt
            if p[_P_PN_RATE] > 0:
                m0, m1, m2 = 0.5 * (pw0 + w0) - b0, 0.5 * (pw1 + w1) - b1, 0.5 * (pw2 + w2) - b2
                dP += p[_P_PN_RATE] * math.sqrt(m0 * m0 + m1 * m1 + m2 * m2) * dt
            if clipped or (hold > 0 and not math.isnan(s[_S_TCLIP]) and t - s[_S_TCLIP] <= hold):
                dP += p[_P_CLIP_INFL] ** 2  # a saturated sensor: the attitude is no longer trusted
            s[_S_P] += dP
            s[_S_QACC] += dP
    s[_S_T] = t
    s[_S_W], s[_S_W + 1], s[_S_W + 2] = w0, w1, w2
    out[4] = p[_P_OUT_SCALE] * math.sqrt(s[_S_P])
    out[5], out[6], out[7] = s[_S_B], s[_S_B + 1], s[_S_B + 2]
    if math.isnan(s[_S_Q]):
        return False
    q = _q(s, _S_Q)
    if p[_P_YAW_ZERO] != 0.0:
        q = zero_yaw_np(q)
    out[0], out[1], out[2], out[3] = q[0], q[1], q[2], q[3]
    return True


@njit(cache=True)
def _run(s, p, t_s, gyr, clipped, est_at, est_q, est_sigma, est_bias, q_out, s_out, b_out, start, stop):
    """Samples ``start:stop`` of a segment; ``est_at[i]`` ≥ 0: the window estimate (row of the
    ``est_*`` arrays) applied when sample i arrives."""
    out = np.empty(8)
    none = np.zeros(4)
    for i in range(start, stop):
        j = est_at[i]
        has_est = j >= 0  # one call with a run-time flag: _step is compiled once, for the live path too
        if has_est:
            q_m, sigma_m, b_m = est_q[j], est_sigma[j], est_bias[j]
        else:
            q_m, sigma_m, b_m = none, 0.0, none
        ok = _step(s, p, t_s[i], gyr[i], clipped[i], has_est, q_m, sigma_m, b_m, out)
        if ok:
            q_out[i, 0], q_out[i, 1], q_out[i, 2], q_out[i, 3] = out[0], out[1], out[2], out[3]
            s_out[i] = out[4]
            b_out[i, 0], b_out[i, 1], b_out[i, 2] = out[5], out[6], out[7]


# ---------------------------------------------------------------------------------- Python side


class AttitudeFusion:
    """State of one causal pass: call :meth:`step` for every IMU sample in order (the compiled
    per-sample update; the state lives in one float64 vector)."""

    def __init__(self, config: FusionConfig):
        self.c = config
        # the kernel's arrays, views of one buffer (float64, C-contiguous, writable: the types the offline loop
        # passes, one compiled signature for both paths); the live step takes the buffer whole
        self._buf = b = np.zeros(_NBUF)
        self.s, self.p = b[_O_S:_O_P], b[_O_P:_O_W]
        self.p[:] = config.kernel_params()
        self._w, self._q_m, self._b_m, self._out = b[_O_W:_O_QM], b[_O_QM:_O_BM], b[_O_BM:_O_OUT], b[_O_OUT:_NBUF]
        self.reset()

    def reset(self) -> None:
        self.s[:] = new_state()

    @property
    def q(self):
        """Full attitude body→NED (tuple), None until the first window estimate."""
        return None if math.isnan(self.s[_S_Q]) else tuple(float(v) for v in self.s[_S_Q : _S_Q + 4])

    @property
    def bias(self) -> tuple:
        return tuple(self.s[_S_B : _S_B + 3].tolist())  # the same floats (tolist is exact), one conversion

    @property
    def P(self) -> float:
        return float(self.s[_S_P])

    @property
    def cov6(self):
        """Bias states: 6×6 covariance of (δθ, δb) at the last update (a view; None before it)."""
        return None if math.isnan(self.s[_S_COV]) else self.s[_S_COV : _S_COV + 36].reshape(6, 6)

    @cov6.setter
    def cov6(self, value) -> None:
        self.s[_S_COV : _S_COV + 36] = np.asarray(value, np.float64).reshape(36)

    def step(self, t: float, w_rad_s, est=None, clipped: bool = False):
        """Advance to sample time ``t`` with gyro ``w`` and return (q or None, σ, bias) for it.

        ``est`` = (q_tilt, σ_rad, bias) is a window estimate that ended at the *previous* sample
        (a token is known to be complete only when the next sample arrives): it corrects the state
        at that time, before the propagation to ``t``. Offline and live runs therefore agree.
        """
        w0, w1, w2 = w_rad_s
        if est is None:
            ok = _step_live(self._buf, float(t), float(w0), float(w1), float(w2), bool(clipped), False, 0.0)
        else:
            q_m, sigma, b_m = est
            self._q_m[:] = q_m
            self._b_m[:] = b_m
            ok = _step_live(self._buf, float(t), float(w0), float(w1), float(w2), bool(clipped), True, float(sigma))
        o = self._out.tolist()  # (one conversion: this runs on every live sample)
        bias = (o[5], o[6], o[7])
        if not ok:
            return None, float("nan"), bias
        return (o[0], o[1], o[2], o[3]), o[4], bias


@njit(cache=True)
def _step_live(buf, t, w0, w1, w2, clipped, has_est, sigma_m):
    """:func:`_step` of one live sample on :class:`AttitudeFusion`'s buffer (its views at ``_O_*``)."""
    w = buf[_O_W:_O_QM]
    w[0], w[1], w[2] = w0, w1, w2
    return _step(buf[_O_S:_O_P], buf[_O_P:_O_W], t, w, clipped, has_est, buf[_O_QM:_O_BM], sigma_m, buf[_O_BM:_O_OUT],
                 buf[_O_OUT:_NBUF])  # fmt: skip


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
        # copies (C-contiguous, writable: a record's columns are read-only views), so the kernel
        # is compiled for one signature whatever the caller passes
        self.t_s = np.array(t_s, np.float64, order="C")
        self.gyr = np.array(gyr, np.float64, order="C")
        self.clipped = np.zeros(n, bool) if clipped is None else np.array(clipped, bool, order="C")
        self.q = np.full((n, 4), np.nan)
        self.sigma = np.full(n, np.nan)
        self.bias = np.full((n, 3), np.nan)
        self.fusion = AttitudeFusion(config)
        self.est_at = np.full(n, -1, np.int64)
        # the window estimates added so far: the first n_est rows of buffers grown by doubling (a
        # concatenation per add cost O(windows) each time: quadratic on a long busy segment)
        self.n_est = 0
        self._est_q = np.zeros((0, 4))
        self._est_sigma = np.zeros(0)
        self._est_bias = np.zeros((0, 3))
        self.i = 0

    @property
    def est_q(self) -> np.ndarray:
        return self._est_q[: self.n_est]

    @property
    def est_sigma(self) -> np.ndarray:
        return self._est_sigma[: self.n_est]

    @property
    def est_bias(self) -> np.ndarray:
        return self._est_bias[: self.n_est]

    def add(self, est_index, est_q, est_sigma, est_bias) -> None:
        est_index = np.asarray(est_index, np.int64)
        if not len(est_index):
            return
        est_sigma = np.asarray(est_sigma, np.float64).reshape(-1)
        k0, k1 = self.n_est, self.n_est + len(est_sigma)
        if k1 > len(self._est_sigma):
            cap = max(k1, 2 * len(self._est_sigma), 64)
            self._est_q = np.concatenate([self.est_q, np.zeros((cap - k0, 4))])
            self._est_sigma = np.concatenate([self.est_sigma, np.zeros(cap - k0)])
            self._est_bias = np.concatenate([self.est_bias, np.zeros((cap - k0, 3))])
        self._est_q[k0:k1] = np.asarray(est_q, np.float64).reshape(-1, 4)
        self._est_sigma[k0:k1] = est_sigma
        self._est_bias[k0:k1] = np.asarray(est_bias, np.float64).reshape(-1, 3)
        self.n_est = k1
        at = est_index + 1
        if at.max() < len(self.t_s):  # every one applies at a sample of the segment (the common case: one index op)
            self.est_at[at] = np.arange(k0, k1)
        else:
            keep = at < len(self.t_s)
            self.est_at[at[keep]] = k0 + np.flatnonzero(keep)

    def advance(self, stop: int) -> None:
        stop = min(stop, len(self.t_s))
        if stop > self.i:
            _run(self.fusion.s, self.fusion.p, self.t_s, self.gyr, self.clipped, self.est_at, self.est_q, self.est_sigma,
                 self.est_bias, self.q, self.sigma, self.bias, self.i, stop)  # fmt: skip
        self.i = max(self.i, stop)
