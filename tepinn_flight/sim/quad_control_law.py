"""The multirotor controller's laws, compiled with numba: position -> thrust vector -> attitude
reference, attitude error -> rate reference, rate loop -> torques, torques -> motor commands.

:class:`tepinn_flight.sim.multirotor.QuadController` reads the state from JSBSim, calls one of the
three entry points below (one per reference mode) through :func:`control_update` and writes the
returned motor commands; the maneuvers write the reference vector (``REF_*``) and read the observation
vector (``OBS_*``) that :func:`control_update` fills. Pure math: floats in, a tuple of
floats out; the rate-loop integrators live in a 4-vector ``st`` updated in place and the vehicle's
constants in the vector ``par`` made by :func:`pack_params`. The arithmetic is that of the former
pure-Python controller, operation for operation.

Frames: body FRD, earth NED, angles in rad, rates in rad/s, forces in N, torques in N*m; motor
order FR, AL, FL, AR. Each entry point returns the attitude quaternion ``q_nb_wxyz`` it computed from
the Euler angles (the maneuvers read it) and the four normalised motor commands.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tepinn_flight.conventions import FT_TO_M
from tepinn_flight.conventions import GRAVITY_M_S2 as G0
from tepinn_flight.quat_scalar import down_in_body, euler_zyx_half_angles, qmul, rotmat_to_quat

#: the reference modes: velocity/position reference -> thrust vector -> attitude; attitude quaternion
#: reference + collective thrust; body-rate reference + collective thrust
MODE_POS, MODE_ATT, MODE_RATE = 0, 1, 2
#: the reference vector the maneuvers write (the mode, position NED from the start in m, velocity and
#: acceleration feed-forward, heading and its rate, attitude quaternion, body rates, collective in N)
REF_MODE, REF_POS, REF_VEL_FF, REF_ACC_FF, REF_YAW, REF_YAW_RATE_FF, REF_Q, REF_RATE, REF_THRUST = (
    0, 1, 4, 7, 10, 11, 12, 16, 19)  # fmt: skip
N_REF = 20
#: the observation vector the maneuvers read: the state at the last control update (attitude
#: ``q_nb_wxyz`` and body rates every update; position, velocity NED and height above ground in position mode)
OBS_Q, OBS_W, OBS_POS, OBS_VEL, OBS_AGL = 0, 4, 7, 10, 13
N_OBS = 14

# layout of the parameter vector (pack_params); the 4x4 inverse mixer follows at MINV, row-major
(POS_KP, VEL_KP, VMAX_H, VMAX_UP, VMAX_DOWN, MAX_ACC_H, MASS_KG, HOVER_N, DT_S, MAX_RATE, MAX_YAW_RATE,
 ATT_KP, ATT_KP_YAW, RATE_KP, RATE_KD, RATE_KI, IXX, IYY, IZZ, YAW_A, TMAX_N, INV_TMAX, CMD_EX,
 MINV) = range(24)  # fmt: skip
N_PARAMS = MINV + 16


def pack_params(p, dt_s: float, vmax_h: float, vmax_up: float, vmax_down: float,
                minv: tuple[tuple[float, ...], ...]) -> np.ndarray:
    """The parameter vector of a :class:`~tepinn_flight.sim.multirotor.QuadParams` vehicle whose
    controller updates every ``dt_s``, with velocity limits in m/s and the inverse mixer."""
    par = np.zeros(N_PARAMS)
    ixx, iyy, izz = p.inertia_kg_m2
    values = {
        POS_KP: p.pos_kp, VEL_KP: p.vel_kp, VMAX_H: vmax_h, VMAX_UP: vmax_up, VMAX_DOWN: vmax_down,
        MAX_ACC_H: G0 * math.tan(p.max_tilt_rad), MASS_KG: p.mass_kg, HOVER_N: p.mass_kg * G0,
        DT_S: dt_s, MAX_RATE: p.max_rate_rad_s, MAX_YAW_RATE: p.max_yaw_rate_rad_s, ATT_KP: p.att_kp,
        ATT_KP_YAW: p.att_kp_yaw, RATE_KP: p.rate_kp, RATE_KD: p.rate_kd, RATE_KI: p.rate_ki,
        IXX: ixx, IYY: iyy, IZZ: izz, YAW_A: dt_s / (p.yaw_lpf_s + dt_s), TMAX_N: p.thrust_max_n,
        INV_TMAX: 1.0 / p.thrust_max_n, CMD_EX: 1.0 / p.cmd_exponent,
    }  # fmt: skip
    for i, v in values.items():
        par[i] = v
    par[MINV:] = np.asarray(minv, dtype=np.float64).ravel()
    return par


@njit(cache=True)
def _attitude(phi, theta, psi):
    return euler_zyx_half_angles(math.cos(0.5 * phi), math.sin(0.5 * phi), math.cos(0.5 * theta),
                                 math.sin(0.5 * theta), math.cos(0.5 * psi), math.sin(0.5 * psi))  # fmt: skip


@njit(cache=True)
def attitude_from_thrust(tn, te, td, yaw):
    """Body->NED quaternion whose -z axis is along the thrust vector (tn, te, td), heading yaw."""
    nrm = math.sqrt(tn * tn + te * te + td * td)
    zx, zy, zz = -tn / nrm, -te / nrm, -td / nrm
    cx, cy = math.cos(yaw), math.sin(yaw)
    # y_b = z_b x x_c
    yx, yy, yz = zy * 0.0 - zz * cy, zz * cx - zx * 0.0, zx * cy - zy * cx
    yn = math.sqrt(yx * yx + yy * yy + yz * yz)
    yx, yy, yz = yx / yn, yy / yn, yz / yn
    # x_b = y_b x z_b
    xx, xy, xz = yy * zz - yz * zy, yz * zx - yx * zz, yx * zy - yy * zx
    # rotation matrix columns x_b, y_b, z_b
    return rotmat_to_quat(xx, yx, zx, xy, yy, zy, xz, yz, zz)


@njit(cache=True)
def _clamp(v, lo, hi):
    return lo if v < lo else (hi if v > hi else v)


@njit(cache=True)
def _rate_reference(par, qw, qx, qy, qz, rw, rx, ry, rz, yaw_rate_ff):
    """Rate reference ~ gain * rotation vector of the error conj(q) * q_ref, limited."""
    ew, ex, ey, ez = qmul(qw, -qx, -qy, -qz, rw, rx, ry, rz)
    sg = 2.0 if ew >= 0.0 else -2.0
    lim, limz = par[MAX_RATE], par[MAX_YAW_RATE]
    ka = par[ATT_KP] * sg
    return (_clamp(ka * ex, -lim, lim), _clamp(ka * ey, -lim, lim),
            _clamp(par[ATT_KP_YAW] * sg * ez + yaw_rate_ff, -limz, limz))  # fmt: skip


@njit(cache=True)
def _rate_loop_and_mix(par, st, thrust, pr, qr, rr, wp, wq, wr, pd, qd):
    """Rate loop (PI + damping on the measured angular acceleration) then the mixer."""
    kp, kd, ki, dt = par[RATE_KP], par[RATE_KD], par[RATE_KI], par[DT_S]
    e_p, e_q, e_r = pr - wp, qr - wq, rr - wr
    st[0] = _clamp(st[0] + e_p * dt, -2.0, 2.0)
    st[1] = _clamp(st[1] + e_q * dt, -2.0, 2.0)
    st[2] = _clamp(st[2] + e_r * dt, -2.0, 2.0)
    ixx, iyy, izz = par[IXX], par[IYY], par[IZZ]
    tl = ixx * (kp * e_p + ki * st[0] - kd * kp * pd) + (izz - iyy) * wq * wr
    tm = iyy * (kp * e_q + ki * st[1] - kd * kp * qd) + (ixx - izz) * wp * wr
    tnf = st[3] + par[YAW_A] * (izz * (kp * e_r + ki * st[2]) - st[3])
    st[3] = tnf
    return mix(par, thrust, tl, tm, tnf)


@njit(cache=True)
def mix(par, thrust, tl, tm, tn):
    """Normalised motor commands from collective and torques; roll/pitch first, yaw within the headroom."""
    m = MINV
    tmax = par[TMAX_N]
    f0 = par[m + 0] * thrust + par[m + 1] * tl + par[m + 2] * tm
    f1 = par[m + 4] * thrust + par[m + 5] * tl + par[m + 6] * tm
    f2 = par[m + 8] * thrust + par[m + 9] * tl + par[m + 10] * tm
    f3 = par[m + 12] * thrust + par[m + 13] * tl + par[m + 14] * tm
    hi = max(f0, f1, f2, f3)
    lo = min(f0, f1, f2, f3)
    if hi - lo > tmax:  # cannot honour roll/pitch fully: scale the differential part
        mean = 0.25 * (f0 + f1 + f2 + f3)
        k = tmax / (hi - lo)
        f0, f1 = mean + (f0 - mean) * k, mean + (f1 - mean) * k
        f2, f3 = mean + (f2 - mean) * k, mean + (f3 - mean) * k
        hi, lo = mean + (hi - mean) * k, mean + (lo - mean) * k
    if hi > tmax:
        s = hi - tmax
        f0, f1, f2, f3, hi, lo = f0 - s, f1 - s, f2 - s, f3 - s, tmax, lo - s
    elif lo < 0.0:
        f0, f1, f2, f3, hi, lo = f0 - lo, f1 - lo, f2 - lo, f3 - lo, hi - lo, 0.0
    # yaw: motor i gets d_i * tn; scale so that no motor leaves [0, tmax]
    y0, y1, y2, y3 = par[m + 3] * tn, par[m + 7] * tn, par[m + 11] * tn, par[m + 15] * tn
    ymax = abs(y0)  # symmetric quad: |d_i| are equal
    if ymax > 0.0:
        room = tmax - hi if tmax - hi < lo else lo
        if ymax > room:
            k = room / ymax if room > 0.0 else 0.0
            y0, y1, y2, y3 = y0 * k, y1 * k, y2 * k, y3 * k
        f0, f1, f2, f3 = f0 + y0, f1 + y1, f2 + y2, f3 + y3
    it, ex = par[INV_TMAX], par[CMD_EX]
    return (_command(f0 * it, ex), _command(f1 * it, ex), _command(f2 * it, ex), _command(f3 * it, ex))


@njit(cache=True)
def _command(v, ex):
    """Fraction of full static thrust -> normalised command (thrust = tmax * cmd ** (1 / ex))."""
    return 0.0 if v <= 0.0 else (1.0 if v >= 1.0 else (v if ex == 1.0 else v**ex))


@njit(cache=True)
def position_step(par, st, x):
    """Position mode. ``x``: (phi, theta, psi, p, q, r, pdot, qdot, pos_ned (3), vel_ned (3),
    pos_ref (3), vel_ff (3), acc_ff (3), yaw_ref, yaw_rate_ff) -> (q_nb_wxyz (4), yaw_ref, 4 commands)."""
    (phi, theta, psi, wp, wq, wr, pd, qd, pn, pe, pdn, vn, ve, vd,
     rn, re, rdn, fn, fe, fd, an0, ae0, ad0, yaw_ref, yaw_rate_ff) = x  # fmt: skip
    qw, qx, qy, qz = _attitude(phi, theta, psi)
    kp, kv, vmax = par[POS_KP], par[VEL_KP], par[VMAX_H]
    # velocity command: feed-forward + position error, limited
    cn = fn + kp * (rn - pn)
    ce = fe + kp * (re - pe)
    cd = fd + kp * (rdn - pdn)
    ch = math.sqrt(cn * cn + ce * ce)
    if ch > vmax:
        cn, ce = cn * vmax / ch, ce * vmax / ch
    cd = _clamp(cd, -par[VMAX_UP], par[VMAX_DOWN])
    an = an0 + kv * (cn - vn)
    ae = ae0 + kv * (ce - ve)
    ad = ad0 + kv * (cd - vd)
    ah = math.sqrt(an * an + ae * ae)
    amax = par[MAX_ACC_H]
    if ah > amax:
        an, ae = an * amax / ah, ae * amax / ah
    ad = _clamp(ad, -1.2 * G0, 0.7 * G0)
    m = par[MASS_KG]
    tn, te, td = m * an, m * ae, m * (ad - G0)
    rw, rx, ry, rz = attitude_from_thrust(tn, te, td, yaw_ref)
    # collective: thrust vector projected on the current body -z axis
    thrust = -(tn * 2.0 * (qx * qz + qw * qy) + te * 2.0 * (qy * qz - qw * qx)
               + td * (1.0 - 2.0 * (qx * qx + qy * qy)))
    tmin = 0.15 * par[HOVER_N]
    if thrust < tmin:
        thrust = tmin
    yaw_ref = yaw_ref + yaw_rate_ff * par[DT_S]
    pr, qr, rr = _rate_reference(par, qw, qx, qy, qz, rw, rx, ry, rz, yaw_rate_ff)
    c0, c1, c2, c3 = _rate_loop_and_mix(par, st, thrust, pr, qr, rr, wp, wq, wr, pd, qd)
    return (qw, qx, qy, qz, yaw_ref, c0, c1, c2, c3)


@njit(cache=True)
def attitude_step(par, st, x):
    """Attitude mode. ``x``: (phi, theta, psi, p, q, r, pdot, qdot, q_ref (4), yaw_rate_ff,
    thrust_n) -> (q_nb_wxyz (4), 4 commands)."""
    phi, theta, psi, wp, wq, wr, pd, qd, rw, rx, ry, rz, yaw_rate_ff, thrust = x
    qw, qx, qy, qz = _attitude(phi, theta, psi)
    pr, qr, rr = _rate_reference(par, qw, qx, qy, qz, rw, rx, ry, rz, yaw_rate_ff)
    c0, c1, c2, c3 = _rate_loop_and_mix(par, st, thrust, pr, qr, rr, wp, wq, wr, pd, qd)
    return (qw, qx, qy, qz, c0, c1, c2, c3)


@njit(cache=True)
def rate_step(par, st, x):
    """Rate mode. ``x``: (phi, theta, psi, p, q, r, pdot, qdot, rate_ref (3), thrust_n)
    -> (q_nb_wxyz (4), 4 commands)."""
    phi, theta, psi, wp, wq, wr, pd, qd, pr, qr, rr, thrust = x
    qw, qx, qy, qz = _attitude(phi, theta, psi)
    c0, c1, c2, c3 = _rate_loop_and_mix(par, st, thrust, pr, qr, rr, wp, wq, wr, pd, qd)
    return (qw, qx, qy, qz, c0, c1, c2, c3)


@njit(cache=True)
def control_update(par, st, ref, obs, start_agl_m, phi, theta, psi, wp, wq, wr, pd, qd, h_ft, vn_fps, ve_fps, vd_fps,
                   pn_ft, pe_ft):  # fmt: skip
    """One control update from JSBSim's state (Euler angles, inertial body rates and the roll and pitch
    accelerations in rad, rad/s, rad/s²; height above ground, NED velocity and the position north and east
    from the start in ft, ft/s) and the reference vector ``ref`` in the mode it names: the four motor
    commands. Writes the attitude and rates to ``obs`` (and in position mode the position, velocity and
    height, and the heading reference it moved along its rate to ``ref``); ``start_agl_m``: the height
    above ground that position down = 0 means."""
    mode = ref[REF_MODE]
    if mode == MODE_POS:
        h = h_ft * FT_TO_M
        pn, pe, pdn = pn_ft * FT_TO_M, pe_ft * FT_TO_M, start_agl_m - h
        vn, ve, vd = vn_fps * FT_TO_M, ve_fps * FT_TO_M, vd_fps * FT_TO_M
        obs[OBS_AGL] = h
        obs[OBS_POS], obs[OBS_POS + 1], obs[OBS_POS + 2] = pn, pe, pdn
        obs[OBS_VEL], obs[OBS_VEL + 1], obs[OBS_VEL + 2] = vn, ve, vd
        r, f, a = REF_POS, REF_VEL_FF, REF_ACC_FF
        qw, qx, qy, qz, yaw_ref, c0, c1, c2, c3 = position_step(par, st, (
            phi, theta, psi, wp, wq, wr, pd, qd, pn, pe, pdn, vn, ve, vd, ref[r], ref[r + 1], ref[r + 2],
            ref[f], ref[f + 1], ref[f + 2], ref[a], ref[a + 1], ref[a + 2], ref[REF_YAW], ref[REF_YAW_RATE_FF]))
        ref[REF_YAW] = yaw_ref
    elif mode == MODE_ATT:
        k = REF_Q
        qw, qx, qy, qz, c0, c1, c2, c3 = attitude_step(par, st, (
            phi, theta, psi, wp, wq, wr, pd, qd, ref[k], ref[k + 1], ref[k + 2], ref[k + 3], ref[REF_YAW_RATE_FF],
            ref[REF_THRUST]))
    else:
        k = REF_RATE
        qw, qx, qy, qz, c0, c1, c2, c3 = rate_step(par, st, (
            phi, theta, psi, wp, wq, wr, pd, qd, ref[k], ref[k + 1], ref[k + 2], ref[REF_THRUST]))
    obs[OBS_Q], obs[OBS_Q + 1], obs[OBS_Q + 2], obs[OBS_Q + 3] = qw, qx, qy, qz
    obs[OBS_W], obs[OBS_W + 1], obs[OBS_W + 2] = wp, wq, wr
    return c0, c1, c2, c3


@njit(cache=True)
def tilt(obs):
    """Angle between body z and earth down of the observed attitude, rad."""
    c = down_in_body(obs[OBS_Q], obs[OBS_Q + 1], obs[OBS_Q + 2], obs[OBS_Q + 3])[2]
    return math.acos(max(-1.0, min(1.0, c)))


def load_compiled(p) -> None:
    """Compile, or load from numba's cache, the three entry points now (numba's start-up in a
    process: ≈ 0.5 s with a warm cache). ``p``: any QuadParams; one hover update in each mode."""
    par = pack_params(p, 0.005, 10.0, 6.0, 4.0, np.eye(4))
    hover = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    st = np.zeros(4)
    ref, obs = np.zeros(N_REF), np.zeros(N_OBS)
    ref[REF_Q], ref[REF_THRUST] = 1.0, par[HOVER_N]
    for mode in (MODE_POS, MODE_ATT, MODE_RATE):
        ref[REF_MODE] = mode
        control_update(par, st, ref, obs, 0.0, *hover, 100.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    tilt(obs)
