"""The anchored filter's steps compiled with numba: a block of samples, one live sample, one network window, and a
whole segment's samples with its windows applied in turn — what :class:`.anchor.AnchoredVQF` does, on its state held
in float arrays.

:mod:`.anchor` holds the estimator's design (the gates, σ, the pull; its module doc) and the class that keeps a
filter's arrays; this module is that design's arithmetic, in the order the former Python methods ran it, so a filter
gives the same bits whether its samples came one at a time (live), in blocks (one network window each) or a segment at
once (offline: :func:`run_segment`, one call instead of two Python calls per window). Its VQF is
:mod:`.vqf_kernel` (the ``vqf`` package's C++ to the bit), whose state the pull turns in place. The former Python
class is kept as the reference the steps are held to (``tests/anchor_reference.py``, ``tests/test_anchor_steps.py``).

Arrays of one filter:
- ``k`` (:data:`N_K`): its settings, fixed when made (:data:`K_*` slots; angles already in radians);
- ``f`` (:data:`N_F`): its state beside VQF's (:data:`F_*` slots; flags 0/1, "none" NaN);
- ``cv``, ``sv``: VQF's coefficients and state (:mod:`.vqf_kernel`);
- ``cb``: the times of the saturated samples still remembered (a queue: ``f[F_CLIP_HEAD]``, ``f[F_CLIP_COUNT]``);
  :func:`clip_room` says whether a block's may be added, the caller makes it larger where not.

A window (:data:`N_WIN` floats, :data:`W_*` slots): the network's tilt (the pull target), σ, bias, v̂, â, the
older fusion's bias (with a flag: none), and whether the GNSS aid holds at its end (and the receiver says fast).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..conventions import GRAVITY_M_S2
from ..record_gaps import GAP_PERIODS
from . import vqf_kernel as vk
from .anchor_kernels import (clip_sigma_step, horizontal_bias, q_nb_from_vqf_f, rest_step, sigma_step, step_weight,
                             tilt_pull_f, turn_acc_state, up_in_earth_f)  # fmt: skip
from ..quat_scalar import down_in_body

BIAS_EVIDENCE_S = 2.0  # the older fusion's bias must stay beyond its gate this long
THRUST_TAU_S = 10.0  # the accelerometer's mean direction (bias_gate_thrust_deg) is low-passed over this
CLIP_SIGMA_CAP_RAD = math.pi / 2  # the saturation term's most: a tilt σ of 90° says nothing is known

# ---------------------------------------------------------------- settings (k)
K_TS, K_CENTRIPETAL, K_SPEED_GATE, K_USE_MAG, K_CLIP_GATE_MAX = 0, 1, 2, 3, 4
K_REST_GYR2, K_REST_ACC2, K_REST_SPIKE2, K_HAS_GSCALE, K_GSCALE = 5, 6, 7, 8, 9  # (K_GSCALE: 3)
K_SLOW, K_STEP_WEIGHTING, K_CLIP_GAIN_DT, K_REST_RELEVEL_S, K_CLIP_HOLD_S, K_CLIP_MIN_S = 12, 13, 14, 15, 16, 17
K_SIGMA_CLIP_TAU_S, K_SPEED_LO, K_SPEED_HI, K_GNSS_AID_IN_FLIGHT, K_BIAS_GATE_WEIGHT = 18, 19, 20, 21, 22
K_BIAS_LATCH_RAD_S, K_BIAS_GATE_FUSION_RAD_S, K_BIAS_GATE_VQF_RAD_S, K_BIAS_GATE_THRUST_COS = 23, 24, 25, 26
K_BIAS_GATE_THRUST_ON, K_SIGMA_GAP_GAIN, K_SIGMA_GAP_HOLD_S, K_SIGMA_GAP_BIAS_EVIDENCE = 27, 28, 29, 30
K_QUIET_BIAS_RAD_S, K_PULL_GAIN, K_TAU_ACC_FLIGHT_S, K_TAU_ACC_S, K_SIGMA_NET_SCALE = 31, 32, 33, 34, 35
K_REST_KEEPS_RUN, K_BIAS_DEADZONE_RAD_S, K_BIAS_GATE_FUSION_ON, K_BIAS_PULL = 36, 37, 38, 39
N_K = 40

# ---------------------------------------------------------------- state beside VQF's (f)
F_VEL, F_ACC_V, F_TURN_ON, F_GYR_CORR = 0, 3, 6, 7  # (3, 3, 1, 3)
F_BIAS_LATCHED, F_T_BIAS_OVER, F_ACC_MEAN, F_HAS_ACC_MEAN, F_T_ACC_MEAN = 10, 11, 12, 15, 16
F_TAU_ACC, F_CLIP_HEAD, F_CLIP_COUNT, F_T_CLIP_HIGH, F_T_CLIP_LAST = 17, 18, 19, 20, 21
F_STILL, F_AT_REST, F_REST_SAMPLES, F_REST_BASE, F_T = 22, 29, 30, 31, 32  # (F_STILL: 7, rest_step's run)
F_GATE, F_GATE_PARTS, F_SIGMA_NET, F_VAR_GAP, F_T_GATED = 33, 34, 37, 38, 39  # (F_GATE_PARTS: 3)
F_SP, F_E_CLIP, F_CLIP_DECAY, F_LAST_G, F_LAST_A = 40, 46, 47, 48, 51  # (F_SP: 6, sigma_step's e α var0 gain samp var_net)
F_HOLES, F_T_PREV, F_RELEVELS = 54, 55, 56
N_F = 57

# ---------------------------------------------------------------- one buffer for the live step (fewer arguments to pass)
O_K = 0
O_F = O_K + N_K
O_CV = O_F + N_F
O_SV = O_CV + vk.N_COEFFS
O_ROWS = O_SV + vk.N_STATE  # update_one's scratch: (6, 3) rows, (2, 4) quaternions, its (12,) output
O_QUATS = O_ROWS + 18
O_OUT = O_QUATS + 8
N_BUF = O_OUT + 12

# ---------------------------------------------------------------- a network window
W_Q, W_SIGMA, W_BIAS, W_VEL, W_ACC, W_FUSION_BIAS, W_HAS_FUSION_BIAS, W_GNSS_AIDED, W_GNSS_FAST = 0, 4, 5, 8, 11, 14, 17, 18, 19
N_WIN = 20


# ================================================================ helpers


@njit(cache=True)
def _pymax(a, b):
    """Python's ``max(a, b)`` (the first where neither is larger, also with a NaN)."""
    return b if b > a else a


@njit(cache=True)
def _pymin(a, b):
    return b if b < a else a


@njit(cache=True)
def _absmax3(v, at):
    return _pymax(_pymax(abs(v[at]), abs(v[at + 1])), abs(v[at + 2]))


@njit(cache=True)
def clip_room(f, cb, n):
    """Whether ``n`` more saturated samples fit in ``cb`` (after moving the remembered ones to its start)."""
    head, count = int(f[F_CLIP_HEAD]), int(f[F_CLIP_COUNT])
    if head + count + n <= cb.shape[0]:
        return True
    for i in range(count):
        cb[i] = cb[head + i]
    f[F_CLIP_HEAD] = 0.0
    return count + n <= cb.shape[0]


# ================================================================ samples


@njit(cache=True)
def update_rows(k, f, cv, sv, cb, t, gyr_b, acc_b, mag_b, clipped, q6, q9, sigma, bias):
    """A block of samples (rows; body FRD, SI; ``mag_b`` read only with the magnetometer, ``clipped`` the gyro's
    saturation flags) → ``q6`` (n, 4) body → NED, ``q9`` (n, 4, with the magnetometer), ``sigma`` (n,), ``bias``
    (n, 3) body axes. A non-finite row is a hole, bridged with the last finite sample. ``cb`` must have room for the
    block's saturated samples (:func:`clip_room`). The block's rows are copied where they change (the gyro scale,
    a hole): the caller's stay as they were."""
    n = t.shape[0]
    gyr = gyr_b
    if k[K_HAS_GSCALE] != 0.0:  # the vehicle's gyro calibration (a hole stays a hole)
        gyr = np.empty((n, 3))
        for i in range(n):
            for j in range(3):
                gyr[i, j] = gyr_b[i, j] * k[K_GSCALE + j]
    any_clip = False
    for i in range(n):
        if clipped[i]:
            any_clip = True
            cb[int(f[F_CLIP_HEAD] + f[F_CLIP_COUNT])] = t[i]
            f[F_CLIP_COUNT] += 1.0
            f[F_T_CLIP_LAST] = t[i]
            if _absmax3(gyr[i], 0) > k[K_CLIP_GATE_MAX]:
                f[F_T_CLIP_HIGH] = t[i]
    if k[K_REST_RELEVEL_S] > 0.0:  # the still run, only while a saturation or a re-levelling is remembered
        if f[F_CLIP_COUNT] > 0.0 or f[F_AT_REST] != 0.0:
            st = f[F_STILL : F_STILL + 7]
            for i in range(n):
                rest_step(st, gyr[i, 0], gyr[i, 1], gyr[i, 2], acc_b[i, 0], acc_b[i, 1], acc_b[i, 2], k[K_REST_GYR2],
                          k[K_REST_ACC2], k[K_REST_SPIKE2])  # fmt: skip
            _rest_goes_on(f, n)
        elif f[F_STILL] != 0.0:
            f[F_STILL : F_STILL + 7] = 0.0
    acc = acc_b
    for i in range(n):  # holes: bridged with the last finite sample
        if not (math.isfinite(gyr[i, 0]) and math.isfinite(gyr[i, 1]) and math.isfinite(gyr[i, 2])
                and math.isfinite(acc[i, 0]) and math.isfinite(acc[i, 1]) and math.isfinite(acc[i, 2])):  # fmt: skip
            if gyr is gyr_b:
                gyr = gyr_b.copy()
            if acc is acc_b:
                acc = acc_b.copy()
            for j in range(3):
                gyr[i, j] = f[F_LAST_G + j]
                acc[i, j] = f[F_LAST_A + j]
            f[F_HOLES] += 1.0
        for j in range(3):
            f[F_LAST_G + j] = gyr[i, j]
            f[F_LAST_A + j] = acc[i, j]
    cen = k[K_CENTRIPETAL] != 0.0 and f[F_TURN_ON] != 0.0
    use_mag = k[K_USE_MAG] != 0.0
    sp = f[F_SP : F_SP + 6]
    gc0, gc1, gc2 = f[F_GYR_CORR], f[F_GYR_CORR + 1], f[F_GYR_CORR + 2]
    v0, v1, v2 = f[F_VEL], f[F_VEL + 1], f[F_VEL + 2]
    av0, av1, av2 = f[F_ACC_V], f[F_ACC_V + 1], f[F_ACC_V + 2]
    for i in range(n):
        gx, gy, gz = gyr[i, 0], gyr[i, 1], gyr[i, 2]
        ax, ay, az = acc[i, 0], acc[i, 1], acc[i, 2]
        sx, sy, sz = gx - gc0, -(gy - gc1), -(gz - gc2)  # VQF's z-up sensor frame
        if cen:  # a − (ω × v̂ + â)
            ax = ax - ((gy * v2 - gz * v1) + av0)
            ay = ay - ((gz * v0 - gx * v2) + av1)
            az = az - ((gx * v1 - gy * v0) + av2)
        ax, ay, az = ax, -ay, -az
        w = 1.0  # VQF integrates the gyro over the sample's own step
        if k[K_STEP_WEIGHTING] != 0.0:
            w = step_weight(t[i] - f[F_T_PREV], k[K_TS], GAP_PERIODS)
            f[F_T_PREV] = t[i]
        if use_mag:
            mx, my, mz = mag_b[i, 0], mag_b[i, 1], mag_b[i, 2]
            mx = mx if math.isfinite(mx) else 0.0  # zero: VQF skips the magnetometer update
            my = -(my if math.isfinite(my) else 0.0)
            mz = -(mz if math.isfinite(mz) else 0.0)
            vk.update_9d(cv, sv, sx * w, sy * w, sz * w, ax, ay, az, mx, my, mz)
        else:
            vk.update(cv, sv, sx * w, sy * w, sz * w, ax, ay, az)
        qw, qx, qy, qz = vk.quat_6d(sv)
        q6[i, 0], q6[i, 1], q6[i, 2], q6[i, 3] = q_nb_from_vqf_f(qw, qx, qy, qz)
        bias[i, 0] = sv[vk.S_BIAS] + gc0
        bias[i, 1] = -sv[vk.S_BIAS + 1] + gc1
        bias[i, 2] = -sv[vk.S_BIAS + 2] + gc2
        sig, sp[0] = sigma_step(qw, qx, qy, qz, ax, ay, az, sx, sy, sz, sp[0], sp[1], sp[2], sp[3], sp[4], sp[5])
        if use_mag:
            a, b, c, d = vk.quat_9d(sv)
            q9[i, 0], q9[i, 1], q9[i, 2], q9[i, 3] = q_nb_from_vqf_f(a, b, c, d)
        if k[K_CLIP_GAIN_DT] > 0.0 and (f[F_E_CLIP] > 0.0 or any_clip):  # the saturation term
            sig, f[F_E_CLIP] = clip_sigma_step(sig, f[F_E_CLIP], clipped[i], sx, sy, sz, f[F_CLIP_DECAY],
                                               k[K_CLIP_GAIN_DT], CLIP_SIGMA_CAP_RAD)  # fmt: skip
        sigma[i] = sig
    if n:
        f[F_T] = t[n - 1]


@njit(cache=True)
def _rest_goes_on(f, n):
    """After ``n`` more samples: the rest a re-levelling found ends with its still run."""
    if f[F_AT_REST] != 0.0:
        f[F_REST_SAMPLES] += n
        f[F_AT_REST] = 1.0 if f[F_STILL] == f[F_REST_BASE] + f[F_REST_SAMPLES] else 0.0


@njit(cache=True)
def update_one(buf, cb, t, gx, gy, gz, ax, ay, az, mx, my, mz, clipped):
    """One sample in plain floats (the live path): :func:`update_rows` of a block of one. ``buf`` holds the filter's
    arrays (:data:`O_K` …: ``k``, ``f``, ``cv``, ``sv``) and the scratch it is made in; its output at :data:`O_OUT`
    (12,): q6 (4), q9 (4, with the magnetometer), σ, bias (3). (Two arrays to pass instead of eight: numba checks
    each argument's type on every call from Python, ~0.1 µs an array.)"""
    k, f = buf[O_K:O_F], buf[O_F:O_CV]
    cv, sv = buf[O_CV:O_SV], buf[O_SV:O_ROWS]
    rows = buf[O_ROWS:O_QUATS].reshape((6, 3))
    quats = buf[O_QUATS:O_OUT].reshape((2, 4))
    out = buf[O_OUT:N_BUF]
    rows[0, 0], rows[0, 1], rows[0, 2] = gx, gy, gz
    rows[1, 0], rows[1, 1], rows[1, 2] = ax, ay, az
    rows[2, 0], rows[2, 1], rows[2, 2] = mx, my, mz
    rows[3, 0] = t
    flag = np.empty(1, np.bool_)
    flag[0] = clipped
    update_rows(k, f, cv, sv, cb, rows[3][0:1], rows[0:1], rows[1:2], rows[2:3], flag, quats[0:1], quats[1:2],
                rows[5][0:1], rows[4:5])  # fmt: skip
    for m in range(4):
        out[m] = quats[0, m]
        out[4 + m] = quats[1, m]
    out[8] = rows[5, 0]
    out[9], out[10], out[11] = rows[4, 0], rows[4, 1], rows[4, 2]


# ================================================================ windows


@njit(cache=True)
def pull(sv, dw, dx, dy, dz):
    """Turn VQF's attitude by the earth-frame rotation ``d`` (a horizontal axis): its inclination quaternion and,
    with it, its low-passed accelerometer (``accLpState``, ``lastAccLp``) — turning only ``accQuat`` would be undone
    at the next sample."""
    turn_acc_state(sv[vk.S_ACC_QUAT : vk.S_ACC_QUAT + 4], dw, dx, dy, dz, sv[vk.S_LAST_ACC_LP : vk.S_LAST_ACC_LP + 3],
                   sv[vk.S_ACC_LP_STATE : vk.S_ACC_LP_STATE + 6])  # fmt: skip


@njit(cache=True)
def _relevel(k, f, sv):
    """At rest after a saturation: VQF's tilt set to the still run's mean specific force (gravity alone) and the
    saturation gate shut (its remembered samples and E cleared) → the gate, 0. A mean under half of g (a free fall,
    no gravity to read) leaves it on → 1."""
    n, sx, sy, sz = f[F_STILL], f[F_STILL + 1], f[F_STILL + 2], f[F_STILL + 3]
    fm = math.sqrt(sx * sx + sy * sy + sz * sz) / n
    if fm < 0.5 * GRAVITY_M_S2:
        return 1.0
    qw, qx, qy, qz = vk.quat_6d(sv)
    # the specific force at rest points up: the earth's down in body axes is −f, its up in S (f₀, −f₁, −f₂)
    d = tilt_pull_f(qw, qx, qy, qz, sx, -sy, -sz, 1.0)
    pull(sv, d[0], d[1], d[2], d[3])
    # VQF's accelerometer low-pass still holds the tumble and the impact: it starts again, as at VQF's own start
    sv[vk.S_ACC_LP_STATE : vk.S_ACC_LP_STATE + 6] = np.nan
    f[F_CLIP_HEAD] = 0.0
    f[F_CLIP_COUNT] = 0.0
    if k[K_REST_KEEPS_RUN] != 0.0:
        f[F_REST_BASE] = f[F_STILL]
    else:
        f[F_STILL : F_STILL + 7] = 0.0
    f[F_E_CLIP] = 0.0
    f[F_RELEVELS] += 1.0
    f[F_AT_REST] = 1.0
    f[F_REST_SAMPLES] = 0.0
    return 0.0


@njit(cache=True)
def _thrust_cos(f):
    """Cosine of the angle between the body's −z axis and the accelerometer's mean, the last sample of each window
    low-passed over :data:`THRUST_TAU_S` (1 while that mean is zero)."""
    if f[F_HAS_ACC_MEAN] == 0.0:
        for j in range(3):
            f[F_ACC_MEAN + j] = f[F_LAST_A + j]
        f[F_HAS_ACC_MEAN] = 1.0
    else:
        kk = _pymin(1.0, _pymax(0.0, f[F_T] - f[F_T_ACC_MEAN]) / THRUST_TAU_S)
        for j in range(3):
            m = f[F_ACC_MEAN + j]
            f[F_ACC_MEAN + j] = m + kk * (f[F_LAST_A + j] - m)
    f[F_T_ACC_MEAN] = f[F_T]
    m0, m1, m2 = f[F_ACC_MEAN], f[F_ACC_MEAN + 1], f[F_ACC_MEAN + 2]
    nm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    return -m2 / nm if nm > 0 else 1.0


@njit(cache=True)
def correct(k, f, cv, sv, cb, win):
    """Apply a network window ``win`` (:data:`N_WIN`) made at the last sample pushed (:mod:`.anchor`'s doc).
    Returns whether it re-levelled the tilt at rest."""
    relevels = f[F_RELEVELS]
    _correct(k, f, cv, sv, cb, win)
    ns = k[K_SIGMA_NET_SCALE] * f[F_SIGMA_NET]  # σ's network share: while a gate acts its σ, in a gap the gap term
    f[F_SP + 5] = f[F_GATE] * (ns * ns) + f[F_VAR_GAP]
    return f[F_RELEVELS] != relevels


@njit(cache=True)
def _correct(k, f, cv, sv, cb, win):
    ts = k[K_TS]
    if k[K_SLOW] != 0.0:  # below the rates the network learned: nothing of the window acts; E decays as VQF recovers
        f[F_GATE] = 0.0
        f[F_GATE_PARTS : F_GATE_PARTS + 3] = 0.0
        f[F_VAR_GAP] = 0.0
        f[F_CLIP_DECAY] = math.exp(-ts / f[F_TAU_ACC])
        return
    t = f[F_T]
    shut = win[W_GNSS_AIDED] != 0.0 and not (k[K_GNSS_AID_IN_FLIGHT] != 0.0 and win[W_GNSS_FAST] != 0.0)
    vx, vy, vz = (0.0, 0.0, 0.0) if shut else (win[W_VEL], win[W_VEL + 1], win[W_VEL + 2])
    speed = math.sqrt(vx * vx + vy * vy + vz * vz)
    g_flight = _pymin(1.0, _pymax(0.0, (speed - k[K_SPEED_LO]) / (k[K_SPEED_HI] - k[K_SPEED_LO])))
    if k[K_SPEED_GATE] == 0.0:  # a vehicle the gate was not learned on
        g_flight = 0.0
    head, count = int(f[F_CLIP_HEAD]), int(f[F_CLIP_COUNT])  # enough saturated time in the last clip_hold_s
    while count and t - cb[head] >= k[K_CLIP_HOLD_S]:
        head += 1
        count -= 1
    f[F_CLIP_HEAD], f[F_CLIP_COUNT] = head, count
    g_clip = 1.0 if count and count * ts >= k[K_CLIP_MIN_S] else 0.0
    if g_clip and k[K_REST_RELEVEL_S] > 0 and f[F_STILL] * ts >= k[K_REST_RELEVEL_S]:
        g_clip = _relevel(k, f, sv)
    if f[F_AT_REST] != 0.0:  # still at rest since: whatever windows still holding the tumble say of speed
        g_flight = 0.0
    if g_clip and t - f[F_T_CLIP_HIGH] < k[K_CLIP_HOLD_S]:  # a range the network did not learn to declip
        g_clip = 0.0
    # E decays as what brings the tilt back: the network's pull or, after a range it did not learn, VQF's accelerometer
    tau_e = f[F_TAU_ACC] if -math.inf < f[F_T_CLIP_LAST] <= f[F_T_CLIP_HIGH] else k[K_SIGMA_CLIP_TAU_S]
    f[F_CLIP_DECAY] = math.exp(-ts / tau_e)
    # only the bias component perpendicular to gravity turns the tilt: that part is the evidence and the correction
    qw, qx, qy, qz = vk.quat_6d(sv)
    fb = W_BIAS if win[W_HAS_FUSION_BIAS] == 0.0 else W_FUSION_BIAS
    bh0, bh1, bh2 = horizontal_bias(qw, qx, qy, qz, win[fb], win[fb + 1], win[fb + 2])
    nbh = math.sqrt(bh0 * bh0 + bh1 * bh1 + bh2 * bh2)
    if k[K_BIAS_GATE_WEIGHT] > 0 and f[F_BIAS_LATCHED] == 0.0:
        b_vqf = _absmax3(sv, vk.S_BIAS)
        latched = b_vqf >= k[K_BIAS_LATCH_RAD_S]
        if k[K_BIAS_GATE_FUSION_ON] != 0.0 and win[W_HAS_FUSION_BIAS] != 0.0:  # for 2 s on end
            over = nbh > k[K_BIAS_GATE_FUSION_RAD_S]
            over &= b_vqf >= k[K_BIAS_GATE_VQF_RAD_S]  # VQF agrees
            if k[K_BIAS_GATE_THRUST_ON] != 0.0:  # ... in the network's domain
                over &= _thrust_cos(f) > k[K_BIAS_GATE_THRUST_COS]
            if over:
                if math.isnan(f[F_T_BIAS_OVER]):
                    f[F_T_BIAS_OVER] = t
            else:
                f[F_T_BIAS_OVER] = np.nan
            latched |= over and t - f[F_T_BIAS_OVER] >= BIAS_EVIDENCE_S
        f[F_BIAS_LATCHED] = 1.0 if latched else 0.0
    g_bias = k[K_BIAS_GATE_WEIGHT] if f[F_BIAS_LATCHED] != 0.0 else 0.0
    gate = _pymax(_pymax(g_flight, g_clip), g_bias)
    f[F_GATE] = gate
    f[F_VAR_GAP] = 0.0
    if gate > 0:
        f[F_T_GATED] = t
    elif k[K_SIGMA_GAP_GAIN] > 0 and (t - f[F_T_GATED] <= k[K_SIGMA_GAP_HOLD_S] or _bias_evidence(k, sv, nbh)):
        d = down_in_body(win[W_Q], win[W_Q + 1], win[W_Q + 2], win[W_Q + 3])  # the target's up in S: (−d₀, d₁, d₂)
        ex, ey, ez = up_in_earth_f(qw, qx, qy, qz, -d[0], d[1], d[2])
        gg = k[K_SIGMA_GAP_GAIN] * math.atan2(math.hypot(ex, ey), ez)
        f[F_VAR_GAP] = gg * gg
    # what each gate did to the attitude (reported per record): none where nothing it drives is on
    pulls = k[K_PULL_GAIN] > 0
    drives = pulls or k[K_CENTRIPETAL] != 0.0 or k[K_TAU_ACC_FLIGHT_S] > 0
    f[F_GATE_PARTS] = g_flight if drives else 0.0
    f[F_GATE_PARTS + 1] = g_clip if pulls else 0.0
    f[F_GATE_PARTS + 2] = g_bias
    if k[K_TAU_ACC_FLIGHT_S] > 0:
        tau = k[K_TAU_ACC_FLIGHT_S] if g_flight > 0.5 else k[K_TAU_ACC_S]
        if tau != f[F_TAU_ACC]:
            vk.set_tau_acc(cv, sv, tau)
            f[F_TAU_ACC] = tau
    f[F_SIGMA_NET] = win[W_SIGMA]
    if k[K_CENTRIPETAL] != 0.0:  # not where GNSS-aided: the receiver's acceleration is already out of the accelerometer
        g_cen = 0.0 if win[W_GNSS_AIDED] != 0.0 else g_flight
        f[F_VEL], f[F_VEL + 1], f[F_VEL + 2] = g_cen * vx, g_cen * vy, g_cen * vz
        for j in range(3):
            f[F_ACC_V + j] = g_cen * win[W_ACC + j]
        on = False
        for j in range(3):
            on |= f[F_VEL + j] != 0.0 or f[F_ACC_V + j] != 0.0
        f[F_TURN_ON] = 1.0 if on else 0.0
    if f[F_BIAS_LATCHED] != 0.0:  # the older fusion's bias where it runs (bias states), else the network's
        if nbh > 0:
            s = _pymax(0.0, 1.0 - k[K_BIAS_DEADZONE_RAD_S] / nbh)
            f[F_GYR_CORR], f[F_GYR_CORR + 1], f[F_GYR_CORR + 2] = bh0 * s, bh1 * s, bh2 * s
        else:
            f[F_GYR_CORR : F_GYR_CORR + 3] = 0.0
    # the uncalibrated-gyro gate pulls only where the vehicle allows it (rule 33); its bias removal above acts anyway
    kk = k[K_PULL_GAIN] * (gate if k[K_BIAS_PULL] != 0.0 else _pymax(g_flight, g_clip))
    if kk > 0:
        d = down_in_body(win[W_Q], win[W_Q + 1], win[W_Q + 2], win[W_Q + 3])
        p = tilt_pull_f(qw, qx, qy, qz, -d[0], d[1], d[2], kk)
        pull(sv, p[0], p[1], p[2], p[3])


@njit(cache=True)
def _bias_evidence(k, sv, nbh):
    """The uncalibrated-gyro gate's evidence building (``sigma_gap_bias_evidence``, rule 22): the older fusion's
    horizontal bias (norm ``nbh``) beyond ``quiet_bias_deg_s`` and VQF's own at ``bias_gate_vqf_deg_s`` or more."""
    if k[K_SIGMA_GAP_BIAS_EVIDENCE] == 0.0 or nbh <= k[K_QUIET_BIAS_RAD_S]:
        return False
    return _absmax3(sv, vk.S_BIAS) >= k[K_BIAS_GATE_VQF_RAD_S]


# ================================================================ a segment


@njit(cache=True)
def run_segment(k, f, cv, sv, cb, t, gyr_b, acc_b, mag_b, clipped, ends, wins, q_out, sigma, bias, gates, parts,
                relevel_win):  # fmt: skip
    """A segment's samples with its windows applied in turn: window ``j`` (``wins[j]``) at the end of sample
    ``ends[j]`` (non-decreasing), for the samples after it → per sample ``q_out`` (n, 4: 9-D with the magnetometer,
    else 6-D), ``sigma``, ``bias``; per window the gate and its parts after it (``gates``, ``parts``) and whether it
    re-levelled the tilt at rest (``relevel_win``). ``cb`` must hold every saturated sample of the segment."""
    n = t.shape[0]
    q6 = np.empty((n, 4))
    q9 = np.empty((n, 4)) if k[K_USE_MAG] != 0.0 else q6
    cur = 0
    for j in range(ends.shape[0]):
        i = ends[j] + 1
        if i > cur:
            update_rows(k, f, cv, sv, cb, t[cur:i], gyr_b[cur:i], acc_b[cur:i], mag_b[cur:i], clipped[cur:i], q6[cur:i],
                        q9[cur:i], sigma[cur:i], bias[cur:i])  # fmt: skip
            cur = i
        relevel_win[j] = correct(k, f, cv, sv, cb, wins[j])
        gates[j] = f[F_GATE]
        for m in range(3):
            parts[j, m] = f[F_GATE_PARTS + m]
    if cur < n:
        update_rows(k, f, cv, sv, cb, t[cur:], gyr_b[cur:], acc_b[cur:], mag_b[cur:], clipped[cur:], q6[cur:], q9[cur:],
                    sigma[cur:], bias[cur:])  # fmt: skip
    src = q9 if k[K_USE_MAG] != 0.0 else q6
    for i in range(n):
        for m in range(4):
            q_out[i, m] = src[i, m]
