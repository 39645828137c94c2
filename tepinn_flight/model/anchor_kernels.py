"""The anchored VQF's per-sample formulas, compiled with numba: VQF's frames and the conversions into and
out of them, σ's terms, the tilt pull and the turn of VQF's accelerometer state that goes with it, the
still run, the gyro's step weight, the tilt blends. The filter's steps (:mod:`.anchor_steps`) call them;
the offline smoothing and the live path call the blends and conversions from Python (one signature each).

VQF's frames are defined here (the one home; :mod:`.anchor` and ``evaluation/peers.py`` import
them): a z-up sensor frame ``S`` (body FRD turned 180° about x) and a z-up earth frame (ENU-type).

The formulas are :mod:`..quat_scalar`'s (Hamilton product, normalisation, rotation matrix, the
earth's vertical in body axes), applied in the order the former numpy code applied them, so the
frame conversions give the same bits as :func:`..quat.quat_mul` / :func:`..quat.quat_normalize`
(tested against the numpy peers' conversion, ``tests/test_anchor_kernels.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..conventions import Q_ENU_FROM_NED_WXYZ
from ..quat import quat_conj
from ..quat_scalar import down_in_body, qmul, qnorm, rotmat_entries

#: q_SB (180° about x) and q_NE (ENU-type z-up earth → NED)
Q_SENSOR_BODY = np.array([0.0, 1.0, 0.0, 0.0])
Q_NED_ENU = quat_conj(np.asarray(Q_ENU_FROM_NED_WXYZ, np.float64))
FLIP = np.array([1.0, -1.0, -1.0])  # body FRD ↔ S, per axis
_SB = tuple(float(v) for v in Q_SENSOR_BODY)
_NE = tuple(float(v) for v in Q_NED_ENU)


@njit(cache=True)
def q_nb_from_vqf_f(w, x, y, z):
    """VQF's sensor → z-up earth quaternion → body FRD → NED: ``q_NE ⊗ q_ES ⊗ q_SB``, normalised."""
    a = qmul(w, x, y, z, _SB[0], _SB[1], _SB[2], _SB[3])
    b = qmul(_NE[0], _NE[1], _NE[2], _NE[3], a[0], a[1], a[2], a[3])
    return qnorm(b[0], b[1], b[2], b[3])


@njit(cache=True)
def q_nb_rows(q_es, q_nb):
    """:func:`q_nb_from_vqf_f` of each row of ``q_es`` (n, 4) into ``q_nb`` (n, 4)."""
    for i in range(q_es.shape[0]):
        r = q_nb_from_vqf_f(q_es[i, 0], q_es[i, 1], q_es[i, 2], q_es[i, 3])
        q_nb[i, 0], q_nb[i, 1], q_nb[i, 2], q_nb[i, 3] = r


@njit(cache=True)
def sigma_step(qw, qx, qy, qz, ax, ay, az, gx, gy, gz, e, alpha, var0, gain, samp, var_net):
    """One sample's σ (rad) → (σ, e): ``e`` low-passes (``e ← (1 − α) e + α·angle``) the angle between
    the accelerometer VQF saw (``a``, sensor axes) and its earth vertical (attitude ``q``, sensor →
    earth); ``σ² = var0 + (gain·e)² + samp·|ω|² + var_net`` with ω the gyro VQF integrated (``g``) and
    ``samp`` = g·Δt²/12: the sampling term, the attitude's change within one sample period Δt (an
    estimate held over a sample against a reference taken anywhere in it: std |ω|·Δt/√12)."""
    ux, uy, uz = down_in_body(qw, qx, qy, qz)  # R's third row: the earth's z axis in sensor axes
    an = math.sqrt(ax * ax + ay * ay + az * az)
    c = (ux * ax + uy * ay + uz * az) / max(an, 1e-9)
    if c > 1.0:
        c = 1.0
    elif c < -1.0:
        c = -1.0
    ang = math.acos(c)
    beta = 1.0 - alpha
    e = beta * e + alpha * ang if beta > 0 else ang
    ge = gain * e
    var = var0 + ge * ge
    if samp > 0.0:  # (0: the σ of checkpoints before session 17, to the bit)
        var += samp * (gx * gx + gy * gy + gz * gz)
    var += var_net
    return math.sqrt(var), e


@njit(cache=True)
def clip_sigma_step(sig, e, clipped, gx, gy, gz, decay, gain_dt, cap):
    """One sample's σ with the gyro-saturation term → (σ, e): ``e`` (rad), the tilt a saturated gyro
    may have lost, decays by ``decay`` (exp(−Δt/τ)) and grows by ``gain_dt``·|ω| (``gain_dt`` = k·Δt,
    ω the clipped reading: k of the rotation those samples show went missing) where the sample is
    ``clipped``, at most ``cap``; ``σ ← √(σ² + e²)``. Below 1e-9 rad ``e`` is 0 (callers skip it)."""
    e = e * decay
    if clipped:
        e += gain_dt * math.sqrt(gx * gx + gy * gy + gz * gz)
        if e > cap:
            e = cap
    if e < 1e-9:
        return sig, 0.0
    return math.sqrt(sig * sig + e * e), e


#: a step within this fraction of the filter's period counts as exactly one period (time stamps' rounding)
STEP_EVEN_TOL = 1e-6


@njit(cache=True)
def step_weight(dt, ts, w_max):
    """The factor on a gyro sample that VQF integrates over its fixed period ``ts`` so that it turns
    the attitude over its own step ``dt``: ``dt / ts`` clamped to [0, ``w_max``]; 1 where ``dt`` is
    within :data:`STEP_EVEN_TOL` of ``ts`` or not finite (a segment's first sample)."""
    if not math.isfinite(dt):
        return 1.0
    w = dt / ts
    if abs(w - 1.0) <= STEP_EVEN_TOL:
        return 1.0
    return min(max(w, 0.0), w_max)


@njit(cache=True)
def step_weights(t, t_prev, ts, w_max, w):
    """:func:`step_weight` of each row of ``t`` (its step from the row before; the first row's from
    ``t_prev``, NaN: none) into ``w``. Returns whether any weight differs from 1."""
    uneven = False
    prev = t_prev
    for i in range(t.shape[0]):
        w[i] = step_weight(t[i] - prev, ts, w_max)
        uneven |= w[i] != 1.0
        prev = t[i]
    return uneven


@njit(cache=True)
def horizontal_bias(qw, qx, qy, qz, bx, by, bz):
    """The part of a body-axes gyro bias ``b`` perpendicular to gravity, for VQF's attitude ``q``
    (sensor → earth): ``(I − d dᵀ) b`` with d the filter's down in body axes."""
    q = q_nb_from_vqf_f(qw, qx, qy, qz)
    d = down_in_body(q[0], q[1], q[2], q[3])
    return ((1.0 - d[0] * d[0]) * bx + (0.0 - d[0] * d[1]) * by + (0.0 - d[0] * d[2]) * bz,
            (0.0 - d[1] * d[0]) * bx + (1.0 - d[1] * d[1]) * by + (0.0 - d[1] * d[2]) * bz,
            (0.0 - d[2] * d[0]) * bx + (0.0 - d[2] * d[1]) * by + (1.0 - d[2] * d[2]) * bz)  # fmt: skip


@njit(cache=True)
def up_in_earth_f(qw, qx, qy, qz, ux, uy, uz):
    """A target's up direction ``u`` in sensor axes (normalised here) in the filter's earth frame
    (``q``: sensor → earth): its angle to ``e_z`` is the tilt between the two."""
    n = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux, uy, uz = ux / n, uy / n, uz / n
    r = rotmat_entries(qw, qx, qy, qz)
    return (r[0] * ux + r[1] * uy + r[2] * uz, r[3] * ux + r[4] * uy + r[5] * uz, r[6] * ux + r[7] * uy + r[8] * uz)


@njit(cache=True)
def tilt_pull_f(qw, qx, qy, qz, ux, uy, uz, fraction):
    """Earth-frame rotation (a quaternion) that turns the filter attitude ``q`` (sensor → earth) by
    ``fraction`` of the tilt between it and a target whose up direction in sensor axes is ``u``;
    about a horizontal axis (``u_earth × e_z``), so the heading is untouched."""
    ex, ey, ez = up_in_earth_f(qw, qx, qy, qz, ux, uy, uz)  # the target's up in the filter's earth frame
    m = math.sqrt(ey * ey + ex * ex)  # |(ey, −ex, 0)|
    ang = math.atan2(m, ez) * fraction
    if m < 1e-12 or ang == 0.0:
        return (1.0, 0.0, 0.0, 0.0)
    s = math.sin(ang / 2)
    return (math.cos(ang / 2), s * ey / m, s * -ex / m, 0.0)


@njit(cache=True)
def _unit4(w, x, y, z):
    """:func:`..quat.quat_normalize` of one quaternion, its ``eps`` included."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    d = n if n > 1e-12 else 1e-12
    return (w / d, x / d, y / d, z / d)


@njit(cache=True)
def blend_tilt_f(qw, qx, qy, qz, sw, sx, sy, sz, w):
    """``smoother.blend_tilt`` of one sample: the tilt of ``s`` with weight ``w`` and of ``q`` with 1 − w, on
    ``q``'s heading — the down directions blended and normalised, then ``q`` turned in body axes by the shortest
    turn onto that down: the arithmetic of the numpy form it replaced, equal to its rounding (tests/test_smoother.py)."""
    ax, ay, az = down_in_body(qw, qx, qy, qz)
    bx, by, bz = down_in_body(sw, sx, sy, sz)
    vx, vy, vz = (1.0 - w) * ax + w * bx, (1.0 - w) * ay + w * by, (1.0 - w) * az + w * bz
    n = math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / n, vy / n, vz / n
    cw, cx, cy, cz = _unit4(1.0 + (vx * ax + vy * ay + vz * az), vy * az - vz * ay, vz * ax - vx * az, vx * ay - vy * ax)
    rw, rx, ry, rz = qmul(qw, qx, qy, qz, cw, cx, cy, cz)
    return _unit4(rw, rx, ry, rz)


@njit(cache=True)
def blend_tilt_rows(q, q_s, w, out):
    """:func:`blend_tilt_f` of each row into ``out`` (n, 4)."""
    for i in range(q.shape[0]):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = blend_tilt_f(q[i, 0], q[i, 1], q[i, 2], q[i, 3], q_s[i, 0],
                                                                  q_s[i, 1], q_s[i, 2], q_s[i, 3], w[i])  # fmt: skip


@njit(cache=True)
def tilt_angle_rows(q_a, q_b, out):
    """Per row, the angle (rad) between the down directions (body axes) of ``q_a`` and ``q_b``:
    atan2(|a × b|, a · b) (``smoother.disagreement_sigma``'s; NaN where either is)."""
    for i in range(q_a.shape[0]):
        ax, ay, az = down_in_body(q_a[i, 0], q_a[i, 1], q_a[i, 2], q_a[i, 3])
        bx, by, bz = down_in_body(q_b[i, 0], q_b[i, 1], q_b[i, 2], q_b[i, 3])
        cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        out[i] = math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), ax * bx + ay * by + az * bz)


@njit(cache=True)
def fusion_tilt_f(qw, qx, qy, qz, fw, fx, fy, fz):
    """:func:`.anchor.with_fusion_tilt` for one sample (the live path; numpy on one row cost 10× a sample):
    ``q`` turned in body axes by the shortest turn that gives it the down direction of ``f`` —
    :func:`blend_tilt_f` at weight 1; ``q`` unchanged where ``f`` is not finite or the two downs are opposite
    (tested against the batched form)."""
    ax, ay, az = down_in_body(qw, qx, qy, qz)
    bx, by, bz = down_in_body(fw, fx, fy, fz)
    if not 1.0 + (ax * bx + ay * by + az * bz) > 1e-9:  # (also a NaN)
        return qw, qx, qy, qz
    return blend_tilt_f(qw, qx, qy, qz, fw, fx, fy, fz, 1.0)


@njit(cache=True)
def fusion_tilt_rows(q, f, out):
    """:func:`fusion_tilt_f` of each row into ``out`` (n, 4) (offline: :func:`.anchor.with_fusion_tilt`)."""
    for i in range(q.shape[0]):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = fusion_tilt_f(q[i, 0], q[i, 1], q[i, 2], q[i, 3], f[i, 0],
                                                                   f[i, 1], f[i, 2], f[i, 3])  # fmt: skip


@njit(cache=True)
def rest_step(st, gx, gy, gz, ax, ay, az, gyr_max2, acc_dev2, spike2):
    """One sample into the still run ``st`` (7,: its length in samples, the sum of its accelerometer and
    the sum of its gyro, body axes), in place: the sample continues it when the accelerometer lies
    within √``acc_dev2`` of the run's mean so far and the gyro's |ω|² is below ``gyr_max2`` — or below
    ``spike2`` while the run's mean gyro, the sample included, stays below √``gyr_max2`` (a noisy gyro's
    single samples: white noise averages out of the mean, a turn does not; rule 23). Otherwise a run
    starts at it (when its gyro is below √``gyr_max2``) or none (a non-finite sample too)."""
    w2 = gx * gx + gy * gy + gz * gz
    if not (w2 < spike2 and math.isfinite(ax + ay + az)):  # (a NaN compares False)
        st[0], st[1], st[2], st[3], st[4], st[5], st[6] = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        return
    if st[0] > 0.0:
        dx, dy, dz = ax - st[1] / st[0], ay - st[2] / st[0], az - st[3] / st[0]
        if dx * dx + dy * dy + dz * dz < acc_dev2:
            n = st[0] + 1.0
            mx, my, mz = (st[4] + gx) / n, (st[5] + gy) / n, (st[6] + gz) / n
            if w2 < gyr_max2 or mx * mx + my * my + mz * mz < gyr_max2:
                st[0], st[1], st[2], st[3] = n, st[1] + ax, st[2] + ay, st[3] + az
                st[4], st[5], st[6] = st[4] + gx, st[5] + gy, st[6] + gz
                return
    if w2 < gyr_max2:
        st[0], st[1], st[2], st[3], st[4], st[5], st[6] = 1.0, ax, ay, az, gx, gy, gz
    else:
        st[0], st[1], st[2], st[3], st[4], st[5], st[6] = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


@njit(cache=True)
def _rotate3(r, v, i, j, k):
    """v[i], v[j], v[k] ← R (v[i], v[j], v[k]) for R's nine entries ``r``."""
    x, y, z = v[i], v[j], v[k]
    v[i] = r[0] * x + r[1] * y + r[2] * z
    v[j] = r[3] * x + r[4] * y + r[5] * z
    v[k] = r[6] * x + r[7] * y + r[8] * z


@njit(cache=True)
def turn_acc_state(acc_quat, dw, dx, dy, dz, last_acc_lp, acc_lp_state):
    """VQF's inclination quaternion ``acc_quat`` (4,) ← normalise(d ⊗ acc_quat) for an earth-frame
    rotation ``d``, and its low-passed accelerometer with it, in place: ``last_acc_lp`` (3,) and
    ``acc_lp_state`` (6,: two filter states per axis, x0 x1 y0 y1 z0 z1; while still averaging its
    first samples, NaN first and their sum in [2:5]) turned by ``R(a* ⊗ d* ⊗ a)``, the same rotation in
    the frame they live in."""
    aw, ax, ay, az = acc_quat[0], acc_quat[1], acc_quat[2], acc_quat[3]
    p = qmul(dw, -dx, -dy, -dz, aw, ax, ay, az)
    c = qmul(aw, -ax, -ay, -az, p[0], p[1], p[2], p[3])
    r = rotmat_entries(c[0], c[1], c[2], c[3])
    _rotate3(r, last_acc_lp, 0, 1, 2)
    if math.isnan(acc_lp_state[0]):
        _rotate3(r, acc_lp_state, 2, 3, 4)
    else:
        _rotate3(r, acc_lp_state, 0, 2, 4)
        _rotate3(r, acc_lp_state, 1, 3, 5)
    t = qmul(dw, dx, dy, dz, aw, ax, ay, az)
    acc_quat[0], acc_quat[1], acc_quat[2], acc_quat[3] = qnorm(t[0], t[1], t[2], t[3])
