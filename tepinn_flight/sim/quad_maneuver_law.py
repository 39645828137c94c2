"""The multirotor maneuvers' per-update laws, compiled with numba: what each maneuver writes into the
controller's reference vector at a control update, and whether it has finished.

A maneuver of :mod:`tepinn_flight.sim.multirotor_maneuvers` keeps its parameters and its progress in a
float vector (``M_*`` and each kind's own slots below); its ``start`` draws them from the flight's
random generator and writes them there. :func:`maneuver_update` then runs once per control update:
from Python where JSBSim is stepped through its binding, inside the compiled flight loop
(:mod:`tepinn_flight.sim.quad_flight_kernel`) elsewhere. It returns ``CONTINUE``, ``DONE``, or
``EVENT`` where the maneuver needs the random generator (a hover's next target, the next rate step):
Python's ``event`` method finishes that update. The arithmetic is that of the former pure-Python
maneuvers, operation for operation (the flights are the same bits).

Frames: earth NED, body FRD; angles in rad, rates in rad/s, times in s.
"""

from __future__ import annotations

import math

from numba import njit

from tepinn_flight.sim.quad_control_law import (DT_S, HOVER_N, MODE_ATT, MODE_RATE, OBS_W, REF_ACC_FF, REF_MODE,
                                                REF_POS, REF_Q, REF_RATE, REF_THRUST, REF_VEL_FF, REF_YAW,
                                                REF_YAW_RATE_FF, tilt)  # fmt: skip

TWO_PI = 2.0 * math.pi
#: what :func:`maneuver_update` returns
CONTINUE, DONE, EVENT = 0, 1, 2
#: the maneuver kinds
KIND_RECOVERY, KIND_HOVER, KIND_RATE_STEPS, KIND_FLIP, KIND_YAW_SPIN, KIND_FIGURE_EIGHT = range(6)
#: the slots every maneuver's vector has: its kind, start time and duration
M_KIND, M_T0, M_DUR = 0, 1, 2
N_SLOTS = 16
#: recovery: the least time it flies
REC_T_MIN = 3
#: hover: when the next target is drawn
HOV_NEXT_MOVE = 3
#: rate steps: the step's start, half-length, axis (0 roll, 1 pitch, 2 yaw), rate, level attitude (4)
RS_TS, RS_STEP_DUR, RS_AXIS, RS_AMP, RS_LEVEL = 3, 4, 5, 6, 7
#: flip and roll: axis, rate, turns, heading, punch time, phase (0 punch, 1 rotate, 2 level), angle turned,
#: collective during the rotation (fraction of hover), the rotation's and the levelling's starts
FL_AXIS, FL_RATE, FL_TURNS, FL_YAW, FL_T_PUNCH, FL_PHASE, FL_ANGLE, FL_CUT, FL_T1, FL_T2 = range(3, 13)
#: yaw spin: rate and ramp time
YS_RATE, YS_RAMP = 3, 4
#: figure-eight: centre (3, NED), angular rate, amplitude, vertical amplitude, rotation, facing the
#: velocity (1) or not (0), ramp time
FE_C, FE_OM, FE_A, FE_AZ, FE_ROT, FE_FACE, FE_RAMP = 3, 6, 7, 8, 9, 10, 11


@njit(cache=True)
def py_min(a, b):
    """Python's ``min(a, b)``: ``a`` unless ``b < a``."""
    return b if b < a else a


@njit(cache=True)
def py_max(a, b):
    """Python's ``max(a, b)``: ``a`` unless ``b > a``."""
    return b if b > a else a


@njit(cache=True)
def level_quat(yaw):
    """``q_nb_wxyz`` of the level attitude with heading ``yaw``."""
    return math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)


@njit(cache=True)
def _ramp(el, dur, ramp):
    """1 inside, rising over ``ramp`` from the start and falling over ``ramp`` to the end."""
    return py_min(py_min(1.0, el / ramp), py_max(0.0, (dur - el) / ramp))


@njit(cache=True)
def _levelling_thrust(par, obs):
    """Collective that holds the height while the attitude loop levels a tilted vehicle."""
    return par[HOVER_N] / py_max(0.5, math.cos(py_min(tilt(obs), 1.0)))


@njit(cache=True)
def _rate_ref(ref, axis, rate):
    ref[REF_RATE], ref[REF_RATE + 1], ref[REF_RATE + 2] = 0.0, 0.0, 0.0
    ref[REF_RATE + axis] = rate


@njit(cache=True)
def _recovery(v, obs, t):
    el = t - v[M_T0]
    if el < v[REC_T_MIN]:
        return CONTINUE
    settled = tilt(obs) < 0.25 and abs(obs[OBS_W]) + abs(obs[OBS_W + 1]) + abs(obs[OBS_W + 2]) < 1.0
    return DONE if settled or el > 4.0 else CONTINUE


@njit(cache=True)
def _hover(v, t):
    if t >= v[HOV_NEXT_MOVE]:
        return EVENT
    return DONE if t - v[M_T0] >= v[M_DUR] else CONTINUE


@njit(cache=True)
def _rate_steps(v, ref, obs, par, t):
    el = t - v[RS_TS]
    d = v[RS_STEP_DUR]
    if el < 2.0 * d:
        ref[REF_MODE] = MODE_RATE
        amp = v[RS_AMP]
        _rate_ref(ref, int(v[RS_AXIS]), amp if el < d else -amp)
        ref[REF_THRUST] = par[HOVER_N]
    elif el < 2.0 * d + 0.35:
        ref[REF_MODE] = MODE_ATT
        for k in range(4):
            ref[REF_Q + k] = v[RS_LEVEL + k]
        ref[REF_THRUST] = _levelling_thrust(par, obs)
    else:
        return DONE if t - v[M_T0] >= v[M_DUR] else EVENT  # the next step: drawn in Python
    return CONTINUE


@njit(cache=True)
def _flip(v, ref, obs, par, t):
    ph = v[FL_PHASE]
    axis = int(v[FL_AXIS])
    if ph == 0.0:
        if t - v[M_T0] >= v[FL_T_PUNCH]:
            v[FL_PHASE] = 1.0
            ref[REF_MODE] = MODE_RATE
            _rate_ref(ref, axis, v[FL_RATE])
            ref[REF_THRUST] = v[FL_CUT] * par[HOVER_N]
            v[FL_T1] = t
    elif ph == 1.0:
        w = obs[OBS_W + axis]
        v[FL_ANGLE] += w * par[DT_S]
        remaining = v[FL_TURNS] * TWO_PI - abs(v[FL_ANGLE])
        # hand over to the attitude loop early enough to brake
        if remaining <= 0.12 * abs(w) or t - v[FL_T1] > 3.0:
            v[FL_PHASE] = 2.0
            ref[REF_MODE] = MODE_ATT
            ref[REF_Q], ref[REF_Q + 1], ref[REF_Q + 2], ref[REF_Q + 3] = level_quat(v[FL_YAW])
            ref[REF_THRUST] = par[HOVER_N]
            v[FL_T2] = t
    elif ph == 2.0:
        ref[REF_THRUST] = _levelling_thrust(par, obs)
        if tilt(obs) < 0.3 or t - v[FL_T2] > 1.0:
            return DONE
    return CONTINUE


@njit(cache=True)
def _yaw_spin(v, ref, t):
    el = t - v[M_T0]
    ref[REF_YAW_RATE_FF] = _ramp(el, v[M_DUR], v[YS_RAMP]) * v[YS_RATE]
    return DONE if el >= v[M_DUR] else CONTINUE


@njit(cache=True)
def _figure_eight(v, ref, t):
    el = t - v[M_T0]
    k = _ramp(el, v[M_DUR], v[FE_RAMP])
    om, A = v[FE_OM], v[FE_A]
    s1, c1 = math.sin(om * el), math.cos(om * el)
    s2, c2 = math.sin(2 * om * el), math.cos(2 * om * el)
    # lemniscate-like: x = A sin(wt), y = A/4 sin(2wt)  -> both peak accelerations A w^2
    x, vx, ax = A * s1, A * om * c1, -A * om * om * s1
    y, vy, ay = 0.25 * A * s2, 0.5 * A * om * c2, -A * om * om * s2
    cr, sr = math.cos(v[FE_ROT]), math.sin(v[FE_ROT])
    n, e = cr * x - sr * y, sr * x + cr * y
    vn, ve = cr * vx - sr * vy, sr * vx + cr * vy
    an, ae = cr * ax - sr * ay, sr * ax + cr * ay
    az_ = v[FE_AZ]
    z, vz, az = az_ * s1, az_ * om * c1, -az_ * om * om * s1
    ref[REF_POS], ref[REF_POS + 1], ref[REF_POS + 2] = v[FE_C] + k * n, v[FE_C + 1] + k * e, v[FE_C + 2] + k * z
    ref[REF_VEL_FF], ref[REF_VEL_FF + 1], ref[REF_VEL_FF + 2] = k * vn, k * ve, k * vz
    ref[REF_ACC_FF], ref[REF_ACC_FF + 1], ref[REF_ACC_FF + 2] = k * an, k * ae, k * az
    if v[FE_FACE] != 0.0:
        v2 = vn * vn + ve * ve
        if k > 0.5 and v2 > 1.0:
            ref[REF_YAW] = math.atan2(ve, vn)
            ref[REF_YAW_RATE_FF] = k * (vn * ae - ve * an) / v2
        else:
            ref[REF_YAW_RATE_FF] = 0.0
    return DONE if el >= v[M_DUR] else CONTINUE


@njit(cache=True)
def maneuver_update(v, ref, obs, par, t):
    """One control update of the maneuver whose vector is ``v`` at time ``t``: writes the controller's
    reference vector ``ref`` from its observation ``obs`` and parameters ``par``
    (:func:`~tepinn_flight.sim.quad_control_law.pack_params`); ``CONTINUE``, ``DONE`` or ``EVENT``."""
    kind = int(v[M_KIND])
    if kind == KIND_RECOVERY:
        return _recovery(v, obs, t)
    if kind == KIND_HOVER:
        return _hover(v, t)
    if kind == KIND_RATE_STEPS:
        return _rate_steps(v, ref, obs, par, t)
    if kind == KIND_FLIP:
        return _flip(v, ref, obs, par, t)
    if kind == KIND_YAW_SPIN:
        return _yaw_spin(v, ref, t)
    return _figure_eight(v, ref, t)
