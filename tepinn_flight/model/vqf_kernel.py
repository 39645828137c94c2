"""VQF (Laidig & Seel 2023) compiled with numba, for the anchored estimator (:mod:`.anchor`).

The ``vqf`` package's ``VQF`` is a C++ object whose state Python can read and write only whole (a dict of ~30
arrays): the anchored filter, which turns that state at each network window and reads the attitude and the bias
between them, spent most of a busy flight's time in those round trips and in the Python around blocks of ~16
samples (``benchmarks/PROFILE.md``, sessions 41 and 49). Here the filter is two float64 arrays — its coefficients
(:data:`C_*` slots: VQF's ``VQFParams`` and ``VQFCoefficients``) and its state (:data:`S_*` slots: ``VQFState``) —
and functions that compiled code calls directly.

The algorithm is the paper's and the package's full ``VQF``: strapdown integration of the gyro, the accelerometer
low-passed in a quasi-inertial frame (second-order Butterworth, its first ``tau`` seconds averaged), the inclination
correction, gyro-bias estimation in motion (a Kalman update of the low-passed rotation and bias) and at rest (rest
detection on low-passed gyro and accelerometer), and the magnetometer's heading with disturbance rejection. Only the
default switches (motion and rest bias estimation, magnetic disturbance rejection: all on) are built. Each formula
is evaluated in the package's order of operations, so the results are VQF's to the bit on the same machine
(``tests/test_vqf_kernel.py`` holds them to the ``vqf`` package on real BROAD trials and logs, with the time constant
changed mid-run and the state turned between samples as the anchored filter turns it).

Frames and units are VQF's: its z-up sensor frame, rad/s, m/s², any magnetometer unit (a zero sample is skipped).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..quat_scalar import qmul

EPS = float(np.finfo(np.float64).eps)
PI = math.pi
D2R = PI / 180.0  # (the package's vqf_real_t(PI/180.0))
_SQRT2 = math.sqrt(2.0)  # (the package's SQRT2 and std::sqrt(2): the same double)

# ---------------------------------------------------------------- the coefficients' slots (VQFParams, VQFCoefficients)
C_GYR_TS, C_ACC_TS, C_MAG_TS = 0, 1, 2
C_TAU_ACC, C_TAU_MAG, C_BIAS_CLIP = 3, 4, 5  # (biasClip in °/s, as VQF's parameter)
C_REST_MIN_T, C_REST_FILTER_TAU, C_REST_TH_GYR, C_REST_TH_ACC = 6, 7, 8, 9
C_MAG_CURRENT_TAU, C_MAG_REF_TAU, C_MAG_NORM_TH, C_MAG_DIP_TH = 10, 11, 12, 13
C_MAG_NEW_TIME, C_MAG_NEW_FIRST_TIME, C_MAG_NEW_MIN_GYR = 14, 15, 16
C_MAG_MIN_UNDISTURBED_T, C_MAG_MAX_REJECTION_T, C_MAG_REJECTION_FACTOR = 17, 18, 19
C_ACC_LP_B, C_ACC_LP_A = 20, 23  # (3, 2)
C_K_MAG, C_BIAS_P0, C_BIAS_V, C_BIAS_MOTION_W, C_BIAS_VERTICAL_W, C_BIAS_REST_W = 25, 26, 27, 28, 29, 30
C_REST_GYR_LP_B, C_REST_GYR_LP_A = 31, 34
C_REST_ACC_LP_B, C_REST_ACC_LP_A = 36, 39
C_K_MAG_REF = 41
C_MAG_NORM_DIP_LP_B, C_MAG_NORM_DIP_LP_A = 42, 45
N_COEFFS = 47

# ---------------------------------------------------------------- the state's slots (VQFState)
S_GYR_QUAT, S_ACC_QUAT, S_DELTA = 0, 4, 8
S_REST_DETECTED, S_MAG_DIST_DETECTED = 9, 10  # (1.0: true)
S_LAST_ACC_LP, S_ACC_LP_STATE, S_LAST_ACC_CORR_RATE = 11, 14, 20  # (3, 6, 1)
S_K_MAG_INIT, S_LAST_MAG_DIS_ANGLE, S_LAST_MAG_CORR_RATE = 21, 22, 23
S_BIAS, S_BIAS_P = 24, 27  # (3, 9)
S_MOTION_R_LP_STATE, S_MOTION_BIAS_LP_STATE = 36, 54  # (18, 4)
S_REST_SQ_DEV, S_REST_T = 58, 60  # (2, 1)
S_REST_LAST_GYR_LP, S_REST_GYR_LP_STATE = 61, 64  # (3, 6)
S_REST_LAST_ACC_LP, S_REST_ACC_LP_STATE = 70, 73  # (3, 6)
S_MAG_REF_NORM, S_MAG_REF_DIP, S_MAG_UNDISTURBED_T, S_MAG_REJECT_T = 79, 80, 81, 82
S_MAG_CANDIDATE_NORM, S_MAG_CANDIDATE_DIP, S_MAG_CANDIDATE_T = 83, 84, 85
S_MAG_NORM_DIP, S_MAG_NORM_DIP_LP_STATE = 86, 88  # (2, 4)
N_VQF_STATE = 92
# ... then scratch for one update's vectors and 3×3 matrices (no allocation per sample): not VQF's state
W_V, W_R, W_BLP, W_E, W_W, W_K, W_T = 92, 95, 104, 106, 109, 112, 121
N_STATE = 130

#: the package's state dict keys → (slot, size), for :func:`state_dict` (tests, and a reader's check)
STATE_KEYS = {
    "gyrQuat": (S_GYR_QUAT, 4), "accQuat": (S_ACC_QUAT, 4), "delta": (S_DELTA, 1),
    "restDetected": (S_REST_DETECTED, 1), "magDistDetected": (S_MAG_DIST_DETECTED, 1),
    "lastAccLp": (S_LAST_ACC_LP, 3), "accLpState": (S_ACC_LP_STATE, 6),
    "lastAccCorrAngularRate": (S_LAST_ACC_CORR_RATE, 1), "kMagInit": (S_K_MAG_INIT, 1),
    "lastMagDisAngle": (S_LAST_MAG_DIS_ANGLE, 1), "lastMagCorrAngularRate": (S_LAST_MAG_CORR_RATE, 1),
    "bias": (S_BIAS, 3), "biasP": (S_BIAS_P, 9), "motionBiasEstRLpState": (S_MOTION_R_LP_STATE, 18),
    "motionBiasEstBiasLpState": (S_MOTION_BIAS_LP_STATE, 4), "restLastSquaredDeviations": (S_REST_SQ_DEV, 2),
    "restT": (S_REST_T, 1), "restLastGyrLp": (S_REST_LAST_GYR_LP, 3), "restGyrLpState": (S_REST_GYR_LP_STATE, 6),
    "restLastAccLp": (S_REST_LAST_ACC_LP, 3), "restAccLpState": (S_REST_ACC_LP_STATE, 6),
    "magRefNorm": (S_MAG_REF_NORM, 1), "magRefDip": (S_MAG_REF_DIP, 1), "magUndisturbedT": (S_MAG_UNDISTURBED_T, 1),
    "magRejectT": (S_MAG_REJECT_T, 1), "magCandidateNorm": (S_MAG_CANDIDATE_NORM, 1),
    "magCandidateDip": (S_MAG_CANDIDATE_DIP, 1), "magCandidateT": (S_MAG_CANDIDATE_T, 1),
    "magNormDip": (S_MAG_NORM_DIP, 2), "magNormDipLpState": (S_MAG_NORM_DIP_LP_STATE, 4),
}  # fmt: skip

#: VQF's parameters that this port takes (the package's defaults); the switches stay at theirs (all on)
DEFAULT_PARAMS = {
    "tauAcc": 3.0, "tauMag": 9.0, "biasSigmaInit": 0.5, "biasForgettingTime": 100.0, "biasClip": 2.0,
    "biasSigmaMotion": 0.1, "biasVerticalForgettingFactor": 0.0001, "biasSigmaRest": 0.03, "restMinT": 1.5,
    "restFilterTau": 0.5, "restThGyr": 2.0, "restThAcc": 0.5, "magCurrentTau": 0.05, "magRefTau": 20.0,
    "magNormTh": 0.1, "magDipTh": 10.0, "magNewTime": 20.0, "magNewFirstTime": 5.0, "magNewMinGyr": 20.0,
    "magMinUndisturbedTime": 0.5, "magMaxRejectionTime": 60.0, "magRejectionFactor": 2.0,
}  # fmt: skip


# ================================================================ set-up (Python: once per filter)


def new_filter(gyr_ts_s: float, **params) -> tuple[np.ndarray, np.ndarray]:
    """A filter at its start → ``(coeffs, state)``: VQF's ``VQF(gyrTs, **params)`` with the accelerometer and
    magnetometer at the gyro's rate. ``params``: keys of :data:`DEFAULT_PARAMS` (VQF's names)."""
    unknown = set(params) - set(DEFAULT_PARAMS)
    if unknown:
        raise ValueError(f"VQF parameters this port does not take: {', '.join(sorted(unknown))}")
    if not gyr_ts_s > 0:
        raise ValueError(f"VQF needs a positive sample period, got {gyr_ts_s!r}")
    p = dict(DEFAULT_PARAMS, **{k: float(v) for k, v in params.items()})
    c = np.zeros(N_COEFFS)
    ts = float(gyr_ts_s)
    c[C_GYR_TS] = c[C_ACC_TS] = c[C_MAG_TS] = ts
    for slot, key in ((C_TAU_ACC, "tauAcc"), (C_TAU_MAG, "tauMag"), (C_BIAS_CLIP, "biasClip"), (C_REST_MIN_T, "restMinT"),
                      (C_REST_FILTER_TAU, "restFilterTau"), (C_REST_TH_GYR, "restThGyr"), (C_REST_TH_ACC, "restThAcc"),
                      (C_MAG_CURRENT_TAU, "magCurrentTau"), (C_MAG_REF_TAU, "magRefTau"), (C_MAG_NORM_TH, "magNormTh"),
                      (C_MAG_DIP_TH, "magDipTh"), (C_MAG_NEW_TIME, "magNewTime"), (C_MAG_NEW_FIRST_TIME, "magNewFirstTime"),
                      (C_MAG_NEW_MIN_GYR, "magNewMinGyr"), (C_MAG_MIN_UNDISTURBED_T, "magMinUndisturbedTime"),
                      (C_MAG_MAX_REJECTION_T, "magMaxRejectionTime"), (C_MAG_REJECTION_FACTOR, "magRejectionFactor")):  # fmt: skip
        c[slot] = p[key]
    filter_coeffs(p["tauAcc"], ts, c, C_ACC_LP_B, C_ACC_LP_A)
    c[C_K_MAG] = gain_from_tau(p["tauMag"], ts)
    c[C_BIAS_P0] = (p["biasSigmaInit"] * 100.0) * (p["biasSigmaInit"] * 100.0)
    # the system noise raises the variance from 0 to (0.1 °/s)² in biasForgettingTime seconds
    c[C_BIAS_V] = (0.1 * 100.0) * (0.1 * 100.0) * ts / p["biasForgettingTime"]
    p_motion = (p["biasSigmaMotion"] * 100.0) * (p["biasSigmaMotion"] * 100.0)
    c[C_BIAS_MOTION_W] = p_motion * p_motion / c[C_BIAS_V] + p_motion
    c[C_BIAS_VERTICAL_W] = c[C_BIAS_MOTION_W] / max(p["biasVerticalForgettingFactor"], 1e-10)
    p_rest = (p["biasSigmaRest"] * 100.0) * (p["biasSigmaRest"] * 100.0)
    c[C_BIAS_REST_W] = p_rest * p_rest / c[C_BIAS_V] + p_rest
    filter_coeffs(p["restFilterTau"], ts, c, C_REST_GYR_LP_B, C_REST_GYR_LP_A)
    filter_coeffs(p["restFilterTau"], ts, c, C_REST_ACC_LP_B, C_REST_ACC_LP_A)
    c[C_K_MAG_REF] = gain_from_tau(p["magRefTau"], ts)
    if p["magCurrentTau"] > 0:
        filter_coeffs(p["magCurrentTau"], ts, c, C_MAG_NORM_DIP_LP_B, C_MAG_NORM_DIP_LP_A)
    else:
        c[C_MAG_NORM_DIP_LP_B : C_MAG_NORM_DIP_LP_A + 2] = np.nan
    s = np.zeros(N_STATE)
    reset_state(c, s)
    return c, s


def state_dict(state: np.ndarray) -> dict:
    """The state as the package's ``VQF.state`` dict names it (copies; flags as bools, scalars as floats)."""
    out = {}
    for key, (i, n) in STATE_KEYS.items():
        v = state[i : i + n].copy()
        out[key] = (bool(v[0]) if key in ("restDetected", "magDistDetected") else float(v[0])) if n == 1 else v
    return out


# ================================================================ compiled


@njit(cache=True)
def gain_from_tau(tau, ts):
    """A first-order low-pass's gain per sample for time constant ``tau`` (0: 1, negative: 0)."""
    if tau < 0.0:
        return 0.0
    if tau == 0.0:
        return 1.0
    return 1.0 - math.exp(-ts / tau)


@njit(cache=True)
def filter_coeffs(tau, ts, c, b_at, a_at):
    """A second-order Butterworth low-pass for time constant ``tau`` at sample period ``ts`` into ``c[b_at:b_at+3]``
    (b) and ``c[a_at:a_at+2]`` (a1, a2); a pass-through where ``tau`` < ``ts``/2 (past 90 % of Nyquist)."""
    if tau < ts / 2.0:
        c[b_at], c[b_at + 1], c[b_at + 2], c[a_at], c[a_at + 1] = 1.0, 0.0, 0.0, 0.0, 0.0
        return
    fc = (_SQRT2 / (2.0 * PI)) / tau  # the step response's dampened, non-oscillating part
    cc = math.tan(PI * fc * ts)
    d = cc * cc + _SQRT2 * cc + 1.0
    b0 = cc * cc / d
    c[b_at], c[b_at + 1], c[b_at + 2] = b0, 2.0 * b0, b0
    c[a_at] = 2.0 * (cc * cc - 1.0) / d
    c[a_at + 1] = (1.0 - _SQRT2 * cc + cc * cc) / d


@njit(cache=True)
def reset_state(c, s):
    """``s`` ← VQF's state at its start (``resetState``)."""
    s[:] = 0.0
    s[S_GYR_QUAT] = 1.0
    s[S_ACC_QUAT] = 1.0
    s[S_MAG_DIST_DETECTED] = 1.0
    s[S_ACC_LP_STATE : S_ACC_LP_STATE + 6] = np.nan
    s[S_K_MAG_INIT] = 1.0
    for i in range(9):
        s[S_BIAS_P + i] = c[C_BIAS_P0] if i % 4 == 0 else 0.0
    s[S_MOTION_R_LP_STATE : S_MOTION_R_LP_STATE + 18] = np.nan
    s[S_MOTION_BIAS_LP_STATE : S_MOTION_BIAS_LP_STATE + 4] = np.nan
    s[S_REST_GYR_LP_STATE : S_REST_GYR_LP_STATE + 6] = np.nan
    s[S_REST_ACC_LP_STATE : S_REST_ACC_LP_STATE + 6] = np.nan
    s[S_MAG_REJECT_T] = c[C_MAG_MAX_REJECTION_T]
    s[S_MAG_CANDIDATE_NORM] = -1.0
    s[S_MAG_NORM_DIP_LP_STATE : S_MAG_NORM_DIP_LP_STATE + 4] = np.nan


@njit(cache=True)
def _filter_vec(x, x_at, n, tau, ts, c, b_at, a_at, st, st_at, out, out_at):
    """``out[out_at:+n]`` ← the low-pass of ``x[x_at:+n]`` (state ``st[st_at:+2n]``; ``x`` and ``out`` may be the
    same slots). Its first ``tau`` seconds are averaged (the state's first slot NaN, its second the count, the sums
    after), then the filter starts from that average in steady state."""
    if math.isnan(st[st_at]):  # averaging the first samples
        if math.isnan(st[st_at + 1]):  # the first one
            st[st_at + 1] = 0.0
            for i in range(n):
                st[st_at + 2 + i] = 0.0
        st[st_at + 1] += 1.0
        for i in range(n):
            st[st_at + 2 + i] += x[x_at + i]
            out[out_at + i] = st[st_at + 2 + i] / st[st_at + 1]
        if st[st_at + 1] * ts >= tau:
            for i in range(n):  # steady state for input = output = the average
                x0 = out[out_at + i]
                st[st_at + 2 * i] = x0 * (1.0 - c[b_at])
                st[st_at + 2 * i + 1] = x0 * (c[b_at + 2] - c[a_at + 1])
        return
    for i in range(n):
        xi = x[x_at + i]
        k = st_at + 2 * i
        y = c[b_at] * xi + st[k]
        st[k] = c[b_at + 1] * xi - c[a_at] * y + st[k + 1]
        st[k + 1] = c[b_at + 2] * xi - c[a_at + 1] * y
        out[out_at + i] = y


@njit(cache=True)
def _adapt_state(last_y, y_at, n, c_old, b_old, a_old, c_new, st, st_at):
    """A low-pass's state kept continuous across a change of its coefficients (``filterAdaptStateForCoeffChange``):
    old ones at ``c_old[b_old]``/``c_old[a_old]``, new ones ``c_new`` (b0 b1 b2 a1 a2)."""
    if math.isnan(st[st_at]):
        return
    for i in range(n):
        y = last_y[y_at + i]
        st[st_at + 2 * i] = st[st_at + 2 * i] + (c_old[b_old] - c_new[0]) * y
        st[st_at + 2 * i + 1] = st[st_at + 2 * i + 1] + (c_old[b_old + 1] - c_new[1] - c_old[a_old] + c_new[3]) * y


@njit(cache=True)
def set_tau_acc(c, s, tau):
    """VQF's ``setTauAcc``: the accelerometer low-pass's time constant changed, its states (and the motion bias
    estimate's low-passes) kept continuous."""
    if c[C_TAU_ACC] == tau:
        return
    c[C_TAU_ACC] = tau
    new = np.empty(5)
    filter_coeffs(tau, c[C_ACC_TS], new, 0, 3)
    _adapt_state(s, S_LAST_ACC_LP, 3, c, C_ACC_LP_B, C_ACC_LP_A, new, s, S_ACC_LP_STATE)
    # the low-passed R and R·b̂ keep no last output: b0 is small, so the state's first entry stands for it
    last = np.empty(9)
    for i in range(9):
        last[i] = s[S_MOTION_R_LP_STATE + 2 * i]
    _adapt_state(last, 0, 9, c, C_ACC_LP_B, C_ACC_LP_A, new, s, S_MOTION_R_LP_STATE)
    for i in range(2):
        last[i] = s[S_MOTION_BIAS_LP_STATE + 2 * i]
    _adapt_state(last, 0, 2, c, C_ACC_LP_B, C_ACC_LP_A, new, s, S_MOTION_BIAS_LP_STATE)
    for i in range(3):
        c[C_ACC_LP_B + i] = new[i]
    c[C_ACC_LP_A], c[C_ACC_LP_A + 1] = new[3], new[4]


@njit(cache=True)
def _norm(v, at, n):
    acc = 0.0
    for i in range(n):
        acc += v[at + i] * v[at + i]
    return math.sqrt(acc)


@njit(cache=True)
def _normalize(v, at, n):
    nv = _norm(v, at, n)
    if nv < EPS:
        return
    for i in range(n):
        v[at + i] /= nv


@njit(cache=True)
def _rotate(qw, qx, qy, qz, vx, vy, vz):
    """VQF's ``quatRotate`` (its own order of operations)."""
    x = (1.0 - 2.0 * qy * qy - 2.0 * qz * qz) * vx + 2.0 * vy * (qy * qx - qw * qz) + 2.0 * vz * (qw * qy + qz * qx)
    y = 2.0 * vx * (qw * qz + qy * qx) + vy * (1.0 - 2.0 * qx * qx - 2.0 * qz * qz) + 2.0 * vz * (qy * qz - qx * qw)
    z = 2.0 * vx * (qz * qx - qw * qy) + 2.0 * vy * (qw * qx + qz * qy) + vz * (1.0 - 2.0 * qx * qx - 2.0 * qy * qy)
    return x, y, z


@njit(cache=True)
def quat_6d(s):
    """The 6-D attitude (sensor → z-up earth, heading from the gyro): accQuat ⊗ gyrQuat."""
    return qmul(s[S_ACC_QUAT], s[S_ACC_QUAT + 1], s[S_ACC_QUAT + 2], s[S_ACC_QUAT + 3],
                s[S_GYR_QUAT], s[S_GYR_QUAT + 1], s[S_GYR_QUAT + 2], s[S_GYR_QUAT + 3])  # fmt: skip


@njit(cache=True)
def quat_9d(s):
    """The 9-D attitude: the 6-D one turned about the vertical by the magnetometer's heading correction δ."""
    w, x, y, z = quat_6d(s)
    h = s[S_DELTA] / 2.0
    cd, sd = math.cos(h), math.sin(h)
    return cd * w - sd * z, cd * x - sd * y, cd * y + sd * x, cd * z + sd * w


@njit(cache=True)
def bias_sigma(c, s):
    """The bias estimate's σ (rad/s): Gershgorin's bound on P's largest eigenvalue, clipped to its start."""
    p = s[S_BIAS_P:]
    s1 = abs(p[0]) + abs(p[1]) + abs(p[2])
    s2 = abs(p[3]) + abs(p[4]) + abs(p[5])
    s3 = abs(p[6]) + abs(p[7]) + abs(p[8])
    return math.sqrt(min(max(max(s1, s2), s3), c[C_BIAS_P0])) * (PI / 100.0 / 180.0)


@njit(cache=True)
def _update_gyr(c, s, gx, gy, gz):
    s[W_V], s[W_V + 1], s[W_V + 2] = gx, gy, gz  # (the rest detection's low-pass reads it as a vector)
    _filter_vec(s, W_V, 3, c[C_REST_FILTER_TAU], c[C_GYR_TS], c, C_REST_GYR_LP_B, C_REST_GYR_LP_A, s,
                S_REST_GYR_LP_STATE, s, S_REST_LAST_GYR_LP)  # fmt: skip
    lx, ly, lz = s[S_REST_LAST_GYR_LP], s[S_REST_LAST_GYR_LP + 1], s[S_REST_LAST_GYR_LP + 2]
    s[S_REST_SQ_DEV] = (gx - lx) * (gx - lx) + (gy - ly) * (gy - ly) + (gz - lz) * (gz - lz)
    clip = c[C_BIAS_CLIP] * D2R
    th = c[C_REST_TH_GYR] * D2R
    if s[S_REST_SQ_DEV] >= th * th or abs(lx) > clip or abs(ly) > clip or abs(lz) > clip:
        s[S_REST_T] = 0.0
        s[S_REST_DETECTED] = 0.0
    nx, ny, nz = gx - s[S_BIAS], gy - s[S_BIAS + 1], gz - s[S_BIAS + 2]  # the bias removed
    gn = math.sqrt(nx * nx + ny * ny + nz * nz)
    angle = gn * c[C_GYR_TS]
    if gn > EPS:
        cw = math.cos(angle / 2.0)
        sk = math.sin(angle / 2.0) / gn
        q = qmul(s[S_GYR_QUAT], s[S_GYR_QUAT + 1], s[S_GYR_QUAT + 2], s[S_GYR_QUAT + 3], cw, sk * nx, sk * ny, sk * nz)
        s[S_GYR_QUAT], s[S_GYR_QUAT + 1], s[S_GYR_QUAT + 2], s[S_GYR_QUAT + 3] = q
        _normalize(s, S_GYR_QUAT, 4)


@njit(cache=True)
def _mat_mul(s, a, b, out, ta, tb):
    """``s[out:+9]`` ← op(A) op(B) for the 3×3 row-major matrices at ``s[a:+9]``, ``s[b:+9]`` (op: transposed where
    ``ta``/``tb``); ``out`` may be ``a`` or ``b`` (made in the scratch ``W_T`` first)."""
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                aik = s[a + k * 3 + i] if ta else s[a + i * 3 + k]
                bkj = s[b + j * 3 + k] if tb else s[b + k * 3 + j]
                acc = aik * bkj if k == 0 else acc + aik * bkj
            s[W_T + i * 3 + j] = acc
    for i in range(9):
        s[out + i] = s[W_T + i]


@njit(cache=True)
def _mat_inv(s, at):
    """``s[at:+9]`` ← its inverse (3×3 row-major) by the adjugate (zeros where |det| ≤ eps)."""
    m = s[at : at + 9]
    out = m
    aa = m[4] * m[8] - m[5] * m[7]
    dd = m[2] * m[7] - m[1] * m[8]
    gg = m[1] * m[5] - m[2] * m[4]
    bb = m[5] * m[6] - m[3] * m[8]
    ee = m[0] * m[8] - m[2] * m[6]
    hh = m[2] * m[3] - m[0] * m[5]
    cc = m[3] * m[7] - m[4] * m[6]
    ff = m[1] * m[6] - m[0] * m[7]
    ii = m[0] * m[4] - m[1] * m[3]
    det = m[0] * aa + m[1] * bb + m[2] * cc
    if -EPS <= det <= EPS:
        out[:] = 0.0
        return
    out[0], out[1], out[2] = aa / det, dd / det, gg / det
    out[3], out[4], out[5] = bb / det, ee / det, hh / det
    out[6], out[7], out[8] = cc / det, ff / det, ii / det


@njit(cache=True)
def _update_acc(c, s, ax, ay, az):
    if ax == 0.0 and ay == 0.0 and az == 0.0:  # a zero sample is skipped
        return
    ts = c[C_ACC_TS]
    v = s[W_V : W_V + 3]
    v[0], v[1], v[2] = ax, ay, az
    # rest detection
    _filter_vec(s, W_V, 3, c[C_REST_FILTER_TAU], ts, c, C_REST_ACC_LP_B, C_REST_ACC_LP_A, s, S_REST_ACC_LP_STATE, s,
                S_REST_LAST_ACC_LP)  # fmt: skip
    lx, ly, lz = s[S_REST_LAST_ACC_LP], s[S_REST_LAST_ACC_LP + 1], s[S_REST_LAST_ACC_LP + 2]
    s[S_REST_SQ_DEV + 1] = (ax - lx) * (ax - lx) + (ay - ly) * (ay - ly) + (az - lz) * (az - lz)
    if s[S_REST_SQ_DEV + 1] >= c[C_REST_TH_ACC] * c[C_REST_TH_ACC]:
        s[S_REST_T] = 0.0
        s[S_REST_DETECTED] = 0.0
    else:
        s[S_REST_T] += ts
        if s[S_REST_T] >= c[C_REST_MIN_T]:
            s[S_REST_DETECTED] = 1.0
    # the accelerometer low-passed in the quasi-inertial frame
    gq = s[S_GYR_QUAT:]
    v[0], v[1], v[2] = _rotate(gq[0], gq[1], gq[2], gq[3], ax, ay, az)
    _filter_vec(s, W_V, 3, c[C_TAU_ACC], ts, c, C_ACC_LP_B, C_ACC_LP_A, s, S_ACC_LP_STATE, s, S_LAST_ACC_LP)
    # into the 6-D earth frame, normalised
    aq = s[S_ACC_QUAT:]
    lp = s[S_LAST_ACC_LP:]
    v[0], v[1], v[2] = _rotate(aq[0], aq[1], aq[2], aq[3], lp[0], lp[1], lp[2])
    _normalize(s, W_V, 3)
    ex, ey, ez = v[0], v[1], v[2]
    # the inclination correction
    qw = math.sqrt((ez + 1.0) / 2.0)
    if qw > 1e-6:
        cq = (qw, 0.5 * ey / qw, -0.5 * ex / qw, 0.0)
    else:  # a correction within 0.00011° of 180°
        cq = (0.0, 1.0, 0.0, 0.0)
    q = qmul(cq[0], cq[1], cq[2], cq[3], aq[0], aq[1], aq[2], aq[3])
    s[S_ACC_QUAT], s[S_ACC_QUAT + 1], s[S_ACC_QUAT + 2], s[S_ACC_QUAT + 3] = q
    _normalize(s, S_ACC_QUAT, 4)
    s[S_LAST_ACC_CORR_RATE] = math.acos(ez) / ts
    # bias estimation
    clip = c[C_BIAS_CLIP] * D2R
    w, x, y, z = quat_6d(s)
    r = s[W_R : W_R + 9]
    r[0] = 1.0 - 2.0 * (y * y) - 2.0 * (z * z)
    r[1] = 2.0 * (y * x - w * z)
    r[2] = 2.0 * (w * y + z * x)
    r[3] = 2.0 * (w * z + y * x)
    r[4] = 1.0 - 2.0 * (x * x) - 2.0 * (z * z)
    r[5] = 2.0 * (y * z - x * w)
    r[6] = 2.0 * (z * x - w * y)
    r[7] = 2.0 * (w * x + z * y)
    r[8] = 1.0 - 2.0 * (x * x) - 2.0 * (y * y)
    b = s[S_BIAS:]
    blp = s[W_BLP : W_BLP + 2]  # R·b̂, its x and y
    blp[0] = r[0] * b[0] + r[1] * b[1] + r[2] * b[2]
    blp[1] = r[3] * b[0] + r[4] * b[1] + r[5] * b[2]
    _filter_vec(s, W_R, 9, c[C_TAU_ACC], ts, c, C_ACC_LP_B, C_ACC_LP_A, s, S_MOTION_R_LP_STATE, s, W_R)
    _filter_vec(s, W_BLP, 2, c[C_TAU_ACC], ts, c, C_ACC_LP_B, C_ACC_LP_A, s, S_MOTION_BIAS_LP_STATE, s, W_BLP)
    e = s[W_E : W_E + 3]
    wv = s[W_W : W_W + 3]
    if s[S_REST_DETECTED] != 0.0:  # at rest: the low-passed gyro is the bias
        for i in range(3):
            e[i] = s[S_REST_LAST_GYR_LP + i] - b[i]
        r[:] = 0.0
        r[0] = r[4] = r[8] = 1.0
        wv[:] = c[C_BIAS_REST_W]
    else:  # in motion
        e[0] = -ey / ts + blp[0] - r[0] * b[0] - r[1] * b[1] - r[2] * b[2]
        e[1] = ex / ts + blp[1] - r[3] * b[0] - r[4] * b[1] - r[5] * b[2]
        e[2] = -r[6] * b[0] - r[7] * b[1] - r[8] * b[2]
        wv[0] = wv[1] = c[C_BIAS_MOTION_W]
        wv[2] = c[C_BIAS_VERTICAL_W]
    p = s[S_BIAS_P : S_BIAS_P + 9]
    for i in (0, 4, 8):  # P ← P + V, also without a measurement
        if p[i] < c[C_BIAS_P0]:
            p[i] += c[C_BIAS_V]
    for i in range(3):  # the disagreement clipped to ± biasClip
        if e[i] < -clip:
            e[i] = -clip
        elif e[i] > clip:
            e[i] = clip
    k = s[W_K : W_K + 9]
    _mat_mul(s, S_BIAS_P, W_R, W_K, False, True)  # K = P Rᵀ
    _mat_mul(s, W_R, W_K, W_K, False, False)  # R P Rᵀ
    k[0] += wv[0]
    k[4] += wv[1]
    k[8] += wv[2]
    _mat_inv(s, W_K)
    _mat_mul(s, W_R, W_K, W_K, True, False)  # Rᵀ (W + R P Rᵀ)⁻¹
    _mat_mul(s, S_BIAS_P, W_K, W_K, False, False)  # K
    b[0] += k[0] * e[0] + k[1] * e[1] + k[2] * e[2]
    b[1] += k[3] * e[0] + k[4] * e[1] + k[5] * e[2]
    b[2] += k[6] * e[0] + k[7] * e[1] + k[8] * e[2]
    _mat_mul(s, W_K, W_R, W_K, False, False)  # K R
    _mat_mul(s, W_K, S_BIAS_P, W_K, False, False)  # K R P
    for i in range(9):
        p[i] -= k[i]
    for i in range(3):
        if b[i] < -clip:
            b[i] = -clip
        elif b[i] > clip:
            b[i] = clip


@njit(cache=True)
def _wrap_pi(a):
    if a > PI:
        return a - 2.0 * PI
    if a < -PI:
        return a + 2.0 * PI
    return a


@njit(cache=True)
def _update_mag(c, s, mx, my, mz):
    if mx == 0.0 and my == 0.0 and mz == 0.0:  # a zero sample is skipped
        return
    ts = c[C_MAG_TS]
    w, x, y, z = quat_6d(s)
    ex, ey, ez = _rotate(w, x, y, z, mx, my, mz)  # into the 6-D earth frame
    nd = S_MAG_NORM_DIP
    s[nd] = math.sqrt(ex * ex + ey * ey + ez * ez)
    s[nd + 1] = -math.asin(ez / s[nd])
    if c[C_MAG_CURRENT_TAU] > 0:
        _filter_vec(s, nd, 2, c[C_MAG_CURRENT_TAU], ts, c, C_MAG_NORM_DIP_LP_B, C_MAG_NORM_DIP_LP_A, s,
                    S_MAG_NORM_DIP_LP_STATE, s, nd)  # fmt: skip
    dip_th = c[C_MAG_DIP_TH] * D2R
    # disturbance detection
    if abs(s[nd] - s[S_MAG_REF_NORM]) < c[C_MAG_NORM_TH] * s[S_MAG_REF_NORM] and abs(s[nd + 1] - s[S_MAG_REF_DIP]) < dip_th:
        s[S_MAG_UNDISTURBED_T] += ts
        if s[S_MAG_UNDISTURBED_T] >= c[C_MAG_MIN_UNDISTURBED_T]:
            s[S_MAG_DIST_DETECTED] = 0.0
            s[S_MAG_REF_NORM] += c[C_K_MAG_REF] * (s[nd] - s[S_MAG_REF_NORM])
            s[S_MAG_REF_DIP] += c[C_K_MAG_REF] * (s[nd + 1] - s[S_MAG_REF_DIP])
    else:
        s[S_MAG_UNDISTURBED_T] = 0.0
        s[S_MAG_DIST_DETECTED] = 1.0
    # a new field's acceptance
    if (abs(s[nd] - s[S_MAG_CANDIDATE_NORM]) < c[C_MAG_NORM_TH] * s[S_MAG_CANDIDATE_NORM]
            and abs(s[nd + 1] - s[S_MAG_CANDIDATE_DIP]) < dip_th):  # fmt: skip
        if _norm(s, S_REST_LAST_GYR_LP, 3) >= c[C_MAG_NEW_MIN_GYR] * D2R:
            s[S_MAG_CANDIDATE_T] += ts
        s[S_MAG_CANDIDATE_NORM] += c[C_K_MAG_REF] * (s[nd] - s[S_MAG_CANDIDATE_NORM])
        s[S_MAG_CANDIDATE_DIP] += c[C_K_MAG_REF] * (s[nd + 1] - s[S_MAG_CANDIDATE_DIP])
        if s[S_MAG_DIST_DETECTED] != 0.0 and (s[S_MAG_CANDIDATE_T] >= c[C_MAG_NEW_TIME] or (
                s[S_MAG_REF_NORM] == 0.0 and s[S_MAG_CANDIDATE_T] >= c[C_MAG_NEW_FIRST_TIME])):  # fmt: skip
            s[S_MAG_REF_NORM] = s[S_MAG_CANDIDATE_NORM]
            s[S_MAG_REF_DIP] = s[S_MAG_CANDIDATE_DIP]
            s[S_MAG_DIST_DETECTED] = 0.0
            s[S_MAG_UNDISTURBED_T] = c[C_MAG_MIN_UNDISTURBED_T]
    else:
        s[S_MAG_CANDIDATE_T] = 0.0
        s[S_MAG_CANDIDATE_NORM] = s[nd]
        s[S_MAG_CANDIDATE_DIP] = s[nd + 1]
    # the heading's disagreement, in [−π, π]
    s[S_LAST_MAG_DIS_ANGLE] = _wrap_pi(math.atan2(ex, ey) - s[S_DELTA])
    k = c[C_K_MAG]
    if s[S_MAG_DIST_DETECTED] != 0.0:  # disturbance rejection
        if s[S_MAG_REJECT_T] <= c[C_MAG_MAX_REJECTION_T]:
            s[S_MAG_REJECT_T] += ts
            k = 0.0
        else:
            k /= c[C_MAG_REJECTION_FACTOR]
    else:
        s[S_MAG_REJECT_T] = max(s[S_MAG_REJECT_T] - c[C_MAG_REJECTION_FACTOR] * ts, 0.0)
    if s[S_K_MAG_INIT] != 0.0:  # fast initial convergence: a gain of at least 1/N over the first samples
        if k < s[S_K_MAG_INIT]:
            k = s[S_K_MAG_INIT]
        s[S_K_MAG_INIT] = s[S_K_MAG_INIT] / (s[S_K_MAG_INIT] + 1.0)
        if s[S_K_MAG_INIT] * c[C_TAU_MAG] < ts:
            s[S_K_MAG_INIT] = 0.0
    s[S_DELTA] += k * s[S_LAST_MAG_DIS_ANGLE]
    s[S_LAST_MAG_CORR_RATE] = k * s[S_LAST_MAG_DIS_ANGLE] / ts
    s[S_DELTA] = _wrap_pi(s[S_DELTA])


@njit(cache=True)
def update(c, s, gx, gy, gz, ax, ay, az):
    """One 6-D sample (VQF's ``update(gyr, acc)``)."""
    _update_gyr(c, s, gx, gy, gz)
    _update_acc(c, s, ax, ay, az)


@njit(cache=True)
def update_9d(c, s, gx, gy, gz, ax, ay, az, mx, my, mz):
    """One 9-D sample (VQF's ``update(gyr, acc, mag)``)."""
    _update_gyr(c, s, gx, gy, gz)
    _update_acc(c, s, ax, ay, az)
    _update_mag(c, s, mx, my, mz)


@njit(cache=True)
def update_rows(c, s, gyr, acc, q6, bias):
    """VQF's ``updateBatch`` of rows ``gyr``, ``acc`` (n, 3) → the 6-D attitude ``q6`` (n, 4) and the bias ``bias``
    (n, 3) after each."""
    for i in range(gyr.shape[0]):
        update(c, s, gyr[i, 0], gyr[i, 1], gyr[i, 2], acc[i, 0], acc[i, 1], acc[i, 2])
        q6[i, 0], q6[i, 1], q6[i, 2], q6[i, 3] = quat_6d(s)
        for j in range(3):
            bias[i, j] = s[S_BIAS + j]


@njit(cache=True)
def update_rows_9d(c, s, gyr, acc, mag, q6, q9, bias):
    """:func:`update_rows` with the magnetometer ``mag`` (n, 3) and the 9-D attitude ``q9`` (n, 4)."""
    for i in range(gyr.shape[0]):
        update_9d(c, s, gyr[i, 0], gyr[i, 1], gyr[i, 2], acc[i, 0], acc[i, 1], acc[i, 2], mag[i, 0], mag[i, 1],
                  mag[i, 2])  # fmt: skip
        q6[i, 0], q6[i, 1], q6[i, 2], q6[i, 3] = quat_6d(s)
        q9[i, 0], q9[i, 1], q9[i, 2], q9[i, 3] = quat_9d(s)
        for j in range(3):
            bias[i, j] = s[S_BIAS + j]
