"""The slow, obviously-correct references of the baseline filters' per-sample loops: the plain-float
Python loops that :mod:`tepinn_flight.evaluation.filters` compiled with numba, kept verbatim (renamed
``<filter>_run``). The compiled filters must equal them (``tests/test_filters_compiled.py``)."""

from __future__ import annotations

import math

import numpy as np

from tepinn_flight.conventions import GRAVITY_M_S2
from tepinn_flight.evaluation.filters.ekf import EkfParams
from tepinn_flight.quat import gravity_body_f

# --- complementary: the loop of tepinn_flight/evaluation/filters/complementary.py before it was compiled

def complementary_run(gyr, acc, mag, dt, tau_acc, tau_mag, q):
    n = len(gyr)
    out = [None] * n
    w, x, y, z = q
    sqrt, sin, cos, atan2 = math.sqrt, math.sin, math.cos, math.atan2
    for i in range(n):
        h = dt[i]
        gx, gy, gz = gyr[i]
        # --- gyro propagation: q ⊗ exp(ω h)
        rx, ry, rz = gx * h, gy * h, gz * h
        th = sqrt(rx * rx + ry * ry + rz * rz)
        if th > 1e-12:
            c = cos(0.5 * th)
            s = sin(0.5 * th) / th
            dx, dy, dz = rx * s, ry * s, rz * s
            w, x, y, z = (w * c - x * dx - y * dy - z * dz, w * dx + x * c + y * dz - z * dy,
                          w * dy - x * dz + y * c + z * dx, w * dz + x * dy - y * dx + z * c)  # fmt: skip
        # --- tilt correction toward the accelerometer
        ax, ay, az = acc[i]
        na = ax * ax + ay * ay + az * az
        if na > 0.0:
            na = -1.0 / sqrt(na)
            ax, ay, az = ax * na, ay * na, az * na  # measured down, body
            vx, vy, vz = gravity_body_f((w, x, y, z))  # predicted down, body
            ex, ey, ez = ay * vz - az * vy, az * vx - ax * vz, ax * vy - ay * vx  # d × v
            ne = sqrt(ex * ex + ey * ey + ez * ez)
            if ne > 1e-12:
                alpha = h / tau_acc
                if alpha > 1.0:
                    alpha = 1.0
                ang = alpha * atan2(ne, ax * vx + ay * vy + az * vz)
                s = sin(0.5 * ang) / ne
                c = cos(0.5 * ang)
                dx, dy, dz = ex * s, ey * s, ez * s
                w, x, y, z = (w * c - x * dx - y * dy - z * dz, w * dx + x * c + y * dz - z * dy,
                              w * dy - x * dz + y * c + z * dx, w * dz + x * dy - y * dx + z * c)  # fmt: skip
        # --- heading correction toward magnetic north (9-D)
        if mag is not None:
            mx, my, mz = mag[i]
            if mx != 0.0 or my != 0.0 or mz != 0.0:
                # horizontal field in NED: R m (first two rows)
                hx = (1 - 2 * (y * y + z * z)) * mx + 2 * (x * y - w * z) * my + 2 * (x * z + w * y) * mz
                hy = 2 * (x * y + w * z) * mx + (1 - 2 * (x * x + z * z)) * my + 2 * (y * z - w * x) * mz
                if hx * hx + hy * hy > 0.0:
                    alpha = h / tau_mag
                    if alpha > 1.0:
                        alpha = 1.0
                    ang = -alpha * atan2(hy, hx)  # earth-frame rotation about z (down)
                    c, s = cos(0.5 * ang), sin(0.5 * ang)
                    w, x, y, z = c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w
        r = 1.0 / sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w * r, x * r, y * r, z * r
        out[i] = (w, x, y, z)
    return np.array(out, np.float64).reshape(n, 4)


# --- madgwick: the loop of tepinn_flight/evaluation/filters/madgwick.py before it was compiled

def madgwick_run(gyr, acc, mag, dt, beta, k, q):
    """The per-sample loop (plain floats). ``acc`` is the gravity direction (earth +z in body)."""
    n = len(gyr)
    out = [None] * n
    q0, q1, q2, q3 = q
    sqrt = math.sqrt
    for i in range(n):
        gx, gy, gz = gyr[i]
        ax, ay, az = acc[i]
        h = dt[i]
        qd1 = 0.5 * (-q1 * gx - q2 * gy - q3 * gz)
        qd2 = 0.5 * (q0 * gx + q2 * gz - q3 * gy)
        qd3 = 0.5 * (q0 * gy - q1 * gz + q3 * gx)
        qd4 = 0.5 * (q0 * gz + q1 * gy - q2 * gx)
        if ax != 0.0 or ay != 0.0 or az != 0.0:
            r = 1.0 / sqrt(ax * ax + ay * ay + az * az)
            ax *= r
            ay *= r
            az *= r
            if mag is not None:
                mx, my, mz = mag[i]
            else:
                mx = my = mz = 0.0
            if mx != 0.0 or my != 0.0 or mz != 0.0:
                r = 1.0 / sqrt(mx * mx + my * my + mz * mz)
                mx *= r
                my *= r
                mz *= r
                _2q0mx = 2.0 * q0 * mx
                _2q0my = 2.0 * q0 * my
                _2q0mz = 2.0 * q0 * mz
                _2q1mx = 2.0 * q1 * mx
                _2q0 = 2.0 * q0
                _2q1 = 2.0 * q1
                _2q2 = 2.0 * q2
                _2q3 = 2.0 * q3
                _2q0q2 = 2.0 * q0 * q2
                _2q2q3 = 2.0 * q2 * q3
                q0q0 = q0 * q0
                q0q1 = q0 * q1
                q0q2 = q0 * q2
                q0q3 = q0 * q3
                q1q1 = q1 * q1
                q1q2 = q1 * q2
                q1q3 = q1 * q3
                q2q2 = q2 * q2
                q2q3 = q2 * q3
                q3q3 = q3 * q3
                hx = mx * q0q0 - _2q0my * q3 + _2q0mz * q2 + mx * q1q1 + _2q1 * my * q2 + _2q1 * mz * q3 - mx * q2q2 - mx * q3q3
                hy = _2q0mx * q3 + my * q0q0 - _2q0mz * q1 + _2q1mx * q2 - my * q1q1 + my * q2q2 + _2q2 * mz * q3 - my * q3q3
                _2bx = k * sqrt(hx * hx + hy * hy)  # original C code: k = 1 (the quirk)
                _2bz = k * (-_2q0mx * q2 + _2q0my * q1 + mz * q0q0 + _2q1mx * q3 - mz * q1q1 + _2q2 * my * q3 - mz * q2q2 + mz * q3q3)
                _4bx = 2.0 * _2bx
                _4bz = 2.0 * _2bz
                fa1 = 2.0 * q1q3 - _2q0q2 - ax
                fa2 = 2.0 * q0q1 + _2q2q3 - ay
                fa3 = 1.0 - 2.0 * q1q1 - 2.0 * q2q2 - az
                fm1 = _2bx * (0.5 - q2q2 - q3q3) + _2bz * (q1q3 - q0q2) - mx
                fm2 = _2bx * (q1q2 - q0q3) + _2bz * (q0q1 + q2q3) - my
                fm3 = _2bx * (q0q2 + q1q3) + _2bz * (0.5 - q1q1 - q2q2) - mz
                s0 = -_2q2 * fa1 + _2q1 * fa2 - _2bz * q2 * fm1 + (-_2bx * q3 + _2bz * q1) * fm2 + _2bx * q2 * fm3
                s1 = _2q3 * fa1 + _2q0 * fa2 - 4.0 * q1 * fa3 + _2bz * q3 * fm1 + (_2bx * q2 + _2bz * q0) * fm2 + (_2bx * q3 - _4bz * q1) * fm3
                s2 = -_2q0 * fa1 + _2q3 * fa2 - 4.0 * q2 * fa3 + (-_4bx * q2 - _2bz * q0) * fm1 + (_2bx * q1 + _2bz * q3) * fm2 + (_2bx * q0 - _4bz * q2) * fm3
                s3 = _2q1 * fa1 + _2q2 * fa2 + (-_4bx * q3 + _2bz * q1) * fm1 + (-_2bx * q0 + _2bz * q2) * fm2 + _2bx * q1 * fm3
            else:
                _2q0 = 2.0 * q0
                _2q1 = 2.0 * q1
                _2q2 = 2.0 * q2
                _2q3 = 2.0 * q3
                _4q0 = 4.0 * q0
                _4q1 = 4.0 * q1
                _4q2 = 4.0 * q2
                _8q1 = 8.0 * q1
                _8q2 = 8.0 * q2
                q0q0 = q0 * q0
                q1q1 = q1 * q1
                q2q2 = q2 * q2
                q3q3 = q3 * q3
                s0 = _4q0 * q2q2 + _2q2 * ax + _4q0 * q1q1 - _2q1 * ay
                s1 = _4q1 * q3q3 - _2q3 * ax + 4.0 * q0q0 * q1 - _2q0 * ay - _4q1 + _8q1 * q1q1 + _8q1 * q2q2 + _4q1 * az
                s2 = 4.0 * q0q0 * q2 + _2q0 * ax + _4q2 * q3q3 - _2q3 * ay - _4q2 + _8q2 * q1q1 + _8q2 * q2q2 + _4q2 * az
                s3 = 4.0 * q1q1 * q3 - _2q1 * ax + 4.0 * q2q2 * q3 - _2q2 * ay
            ns = s0 * s0 + s1 * s1 + s2 * s2 + s3 * s3
            if ns > 0.0:
                r = beta / sqrt(ns)
                qd1 -= r * s0
                qd2 -= r * s1
                qd3 -= r * s2
                qd4 -= r * s3
        q0 += qd1 * h
        q1 += qd2 * h
        q2 += qd3 * h
        q3 += qd4 * h
        r = 1.0 / sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        q0 *= r
        q1 *= r
        q2 *= r
        q3 *= r
        out[i] = (q0, q1, q2, q3)
    return np.array(out, np.float64).reshape(n, 4)


# --- ekf: the loop of tepinn_flight/evaluation/filters/ekf.py before it was compiled

def _rotate_body(w, x, y, z, rx, ry, rz):
    """``q ⊗ exp(r)`` for a body-frame rotation vector ``r`` (rad), scalars for the per-sample loop.
    Returns (the new q, the increment exp(r)) as (w, x, y, z) tuples."""
    th = math.sqrt(rx * rx + ry * ry + rz * rz)
    if th > 1e-12:
        s = math.sin(0.5 * th) / th
        dw, dx, dy, dz = math.cos(0.5 * th), rx * s, ry * s, rz * s
    else:
        dw, dx, dy, dz = 1.0, 0.5 * rx, 0.5 * ry, 0.5 * rz
    q = (w * dw - x * dx - y * dy - z * dz, w * dx + x * dw + y * dz - z * dy,
         w * dy - x * dz + y * dw + z * dx, w * dz + x * dy - y * dx + z * dw)  # fmt: skip
    return q, (dw, dx, dy, dz)


def ekf_run(gyr, acc, dt, p: EkfParams, q, b):
    n = len(gyr)
    q_out = [None] * n
    b_out = [None] * n
    s_out = [0.0] * n
    w, x, y, z = q
    bx, by, bz = b
    P = np.diag([p.init_attitude_sigma_rad**2] * 3 + [p.init_bias_sigma_rad_s**2] * 3)
    F = np.eye(6)
    qd = np.zeros((6, 6))
    sg2, sb2 = p.gyro_noise_rad_s_sqrt_hz**2, p.bias_walk_rad_s_sqrt_s**2
    g = GRAVITY_M_S2
    lim = p.bias_limit_rad_s
    lp_tau = p.acc_lowpass_tau_s
    lp = None
    qi = (1.0, 0.0, 0.0, 0.0)
    rest_sigma = p.rest_gyr_sigma_rad_s
    rest_r = np.eye(3) * rest_sigma**2
    rest_g2, rest_a2 = p.rest_gyr_dev_rad_s**2, p.rest_acc_dev_m_s2**2
    rest_t = 0.0
    lg = la = None
    sqrt = math.sqrt
    inv = np.linalg.inv
    gyr_l, acc_l, dt_l = gyr.tolist(), acc.tolist(), dt.tolist()
    for i in range(n):
        h = dt_l[i]
        gx, gy, gz = gyr_l[i]
        (w, x, y, z), (dw, dx, dy, dz) = _rotate_body(w, x, y, z, (gx - bx) * h, (gy - by) * h, (gz - bz) * h)
        dw0, dx0, dy0, dz0 = dw, dx, dy, dz
        # F: attitude block = R(dq)ᵀ, bias coupling −I·h
        F[0:3, 0:3] = (
            (1 - 2 * (dy * dy + dz * dz), 2 * (dx * dy + dw * dz), 2 * (dx * dz - dw * dy)),
            (2 * (dx * dy - dw * dz), 1 - 2 * (dx * dx + dz * dz), 2 * (dy * dz + dw * dx)),
            (2 * (dx * dz + dw * dy), 2 * (dy * dz - dw * dx), 1 - 2 * (dx * dx + dy * dy)),
        )
        F[0, 3] = F[1, 4] = F[2, 5] = -h
        qd[0, 0] = qd[1, 1] = qd[2, 2] = sg2 * h
        qd[3, 3] = qd[4, 4] = qd[5, 5] = sb2 * h
        P = F @ P @ F.T + qd
        ax, ay, az = acc_l[i]
        if rest_sigma > 0.0:
            al = 1.0 - math.exp(-h / 0.5)
            if lg is None:
                lg, la = [gx, gy, gz], [ax, ay, az]
            else:
                lg[0] += al * (gx - lg[0])
                lg[1] += al * (gy - lg[1])
                lg[2] += al * (gz - lg[2])
                la[0] += al * (ax - la[0])
                la[1] += al * (ay - la[1])
                la[2] += al * (az - la[2])
            dg = (gx - lg[0]) ** 2 + (gy - lg[1]) ** 2 + (gz - lg[2]) ** 2
            da = (ax - la[0]) ** 2 + (ay - la[1]) ** 2 + (az - la[2]) ** 2
            rest_t = rest_t + h if (dg < rest_g2 and da < rest_a2) else 0.0
            if rest_t >= p.rest_min_s:
                # zero-angular-rate update: the low-passed gyro measures the bias, H = [0, I]
                pb = P[:, 3:6]
                S = pb[3:6] + rest_r
                K = pb @ inv(S)
                d = K @ (lg[0] - bx, lg[1] - by, lg[2] - bz)
                P = P - K @ pb.T
                P = 0.5 * (P + P.T)
                ex, ey, ez, b0, b1, b2 = d.tolist()
                bx = min(lim, max(-lim, bx + b0))
                by = min(lim, max(-lim, by + b1))
                bz = min(lim, max(-lim, bz + b2))
        # predicted down direction in body
        vx, vy, vz = gravity_body_f((w, x, y, z))
        if lp_tau > 0.0 and (ax != 0.0 or ay != 0.0 or az != 0.0):
            # VQF's idea: low-pass the specific force in an inertial frame I that follows the
            # bias-corrected gyro only (no corrections), so zero-mean linear accelerations cancel
            gw, gx_, gy_, gz_ = qi
            qi = (gw * dw0 - gx_ * dx0 - gy_ * dy0 - gz_ * dz0, gw * dx0 + gx_ * dw0 + gy_ * dz0 - gz_ * dy0,
                  gw * dy0 - gx_ * dz0 + gy_ * dw0 + gz_ * dx0, gw * dz0 + gx_ * dy0 - gy_ * dx0 + gz_ * dw0)  # fmt: skip
            gw, gx_, gy_, gz_ = qi
            r00, r01, r02 = 1 - 2 * (gy_ * gy_ + gz_ * gz_), 2 * (gx_ * gy_ - gw * gz_), 2 * (gx_ * gz_ + gw * gy_)
            r10, r11, r12 = 2 * (gx_ * gy_ + gw * gz_), 1 - 2 * (gx_ * gx_ + gz_ * gz_), 2 * (gy_ * gz_ - gw * gx_)
            r20, r21, r22 = 2 * (gx_ * gz_ - gw * gy_), 2 * (gy_ * gz_ + gw * gx_), 1 - 2 * (gx_ * gx_ + gy_ * gy_)
            nx, ny, nz = r00 * ax + r01 * ay + r02 * az, r10 * ax + r11 * ay + r12 * az, r20 * ax + r21 * ay + r22 * az
            if lp is None:
                lp = [nx, ny, nz]
            else:
                al = 1.0 - math.exp(-h / lp_tau)
                lp[0] += al * (nx - lp[0])
                lp[1] += al * (ny - lp[1])
                lp[2] += al * (nz - lp[2])
            ax = r00 * lp[0] + r10 * lp[1] + r20 * lp[2]
            ay = r01 * lp[0] + r11 * lp[1] + r21 * lp[2]
            az = r02 * lp[0] + r12 * lp[1] + r22 * lp[2]
            if i % 1000 == 999:  # keep q_I normalised
                nq = 1.0 / sqrt(gw * gw + gx_ * gx_ + gy_ * gy_ + gz_ * gz_)
                qi = (gw * nq, gx_ * nq, gy_ * nq, gz_ * nq)
        na = sqrt(ax * ax + ay * ay + az * az)
        dev = abs(na - g)
        if na > 0.0 and dev <= p.acc_gate_m_s2:
            sa = (p.acc_noise_m_s2 + p.acc_dynamic_gain * dev) / g
            vx_ = np.array(((0.0, -vz, vy), (vz, 0.0, -vx), (-vy, vx, 0.0)))  # [v]×
            pht = P[:, 0:3] @ vx_  # P Hᵀ, Hᵀ = [[v]×; 0]
            S = -(vx_ @ pht[0:3])  # H P Hᵀ
            S[0, 0] += sa * sa
            S[1, 1] += sa * sa
            S[2, 2] += sa * sa
            K = pht @ inv(S)
            r = 1.0 / na
            res = (ax * r + vx, ay * r + vy, az * r + vz)  # z − h, h = −v
            d = K @ res
            P = P - K @ pht.T
            P = 0.5 * (P + P.T)
            ex, ey, ez, b0, b1, b2 = d.tolist()
            # the accelerometer cannot observe heading: drop the correction's earth-vertical part
            # (its component along the body-frame down vector v), so heading comes from the gyro only
            pv = ex * vx + ey * vy + ez * vz
            ex, ey, ez = ex - pv * vx, ey - pv * vy, ez - pv * vz
            w, x, y, z = _rotate_body(w, x, y, z, ex, ey, ez)[0]
            bx = min(lim, max(-lim, bx + b0))
            by = min(lim, max(-lim, by + b1))
            bz = min(lim, max(-lim, bz + b2))
            vx, vy, vz = gravity_body_f((w, x, y, z))
        r = 1.0 / sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w * r, x * r, y * r, z * r
        q_out[i] = (w, x, y, z)
        b_out[i] = (bx, by, bz)
        # tilt σ per axis: (tr Pθθ − vᵀ Pθθ v) / 2
        t00, t01, t02, t11, t12, t22 = P[0, 0], P[0, 1], P[0, 2], P[1, 1], P[1, 2], P[2, 2]
        vpv = (vx * vx * t00 + vy * vy * t11 + vz * vz * t22
               + 2.0 * (vx * vy * t01 + vx * vz * t02 + vy * vz * t12))  # fmt: skip
        s_out[i] = sqrt(max(0.0, 0.5 * (t00 + t11 + t22 - vpv)))
    return (np.array(q_out, np.float64).reshape(n, 4), np.array(b_out, np.float64).reshape(n, 3),
            np.array(s_out, np.float64))  # fmt: skip
