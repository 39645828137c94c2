"""The multirotor maneuvers and the controller fields they use as pure Python, as they were before their
per-update laws were compiled (session 48): the reference ``tests/test_quad_flight_kernel.py`` holds the
compiled laws (:mod:`tepinn_flight.sim.quad_maneuver_law`) and the maneuvers built on them to, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

from tepinn_flight.quat import gravity_body_f, quat_from_euler_zyx_f
from tepinn_flight.sim.jsbsim_env import FT_TO_M, getter
from tepinn_flight.sim.maneuvers import RECOVERY, Maneuver
from tepinn_flight.sim.quad_control_law import G0, MODE_ATT, MODE_POS, MODE_RATE

TWO_PI = 2.0 * math.pi


class ReferenceController:
    """The former ``QuadController``'s fields and helpers for maneuvers (no control law): plain lists and
    tuples, read from the same properties."""

    def __init__(self, fdm, p, dt_s: float):
        self.p = p
        self.dt = dt_s
        g = lambda path: getter(fdm, path)  # noqa: E731
        self._phi, self._theta, self._psi = g("attitude/phi-rad"), g("attitude/theta-rad"), g("attitude/psi-rad")
        self._p, self._q, self._r = g("velocities/pi-rad_sec"), g("velocities/qi-rad_sec"), g("velocities/ri-rad_sec")
        self._vn, self._ve, self._vd = (
            g("velocities/v-north-fps"), g("velocities/v-east-fps"), g("velocities/v-down-fps"))
        self._pn, self._pe = g("position/from-start-neu-n-ft"), g("position/from-start-neu-e-ft")
        self._h = g("position/h-agl-ft")
        self.hover_thrust_n = p.mass_kg * G0
        self.mode = MODE_POS
        self.pos_ref = [0.0, 0.0, 0.0]
        self.vel_ff = [0.0, 0.0, 0.0]
        self.acc_ff = [0.0, 0.0, 0.0]
        self.yaw_ref = 0.0
        self.yaw_rate_ff = 0.0
        self.q_ref = (1.0, 0.0, 0.0, 0.0)
        self.rate_ref = [0.0, 0.0, 0.0]
        self.thrust_n = self.hover_thrust_n
        self.max_tilt = p.max_tilt_rad
        self.max_acc_h = G0 * math.tan(p.max_tilt_rad)
        self.q = (1.0, 0.0, 0.0, 0.0)
        self.w = (0.0, 0.0, 0.0)
        self.pos = [0.0, 0.0, 0.0]
        self.vel = [0.0, 0.0, 0.0]
        self.agl_m = 0.0
        self.start_agl_m = 0.0

    def setup(self) -> None:
        self.start_agl_m = self._h() * FT_TO_M
        self.yaw_ref = self._psi()
        self.hold_here()

    def read_state(self) -> None:
        self.q = quat_from_euler_zyx_f(self._phi(), self._theta(), self._psi())
        self.w = (self._p(), self._q(), self._r())
        h = self._h() * FT_TO_M
        self.agl_m = h
        self.pos = [self._pn() * FT_TO_M, self._pe() * FT_TO_M, self.start_agl_m - h]
        self.vel = [self._vn() * FT_TO_M, self._ve() * FT_TO_M, self._vd() * FT_TO_M]

    def hold_here(self) -> None:
        self.read_state()
        self.mode = MODE_POS
        self.pos_ref = list(self.pos)
        self.vel_ff = [0.0, 0.0, 0.0]
        self.acc_ff = [0.0, 0.0, 0.0]
        self.yaw_ref = self.heading()
        self.yaw_rate_ff = 0.0

    def heading(self) -> float:
        w, x, y, z = self.q
        return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))

    def tilt(self) -> float:
        c = gravity_body_f(self.q)[2]
        return math.acos(max(-1.0, min(1.0, c)))

    def level_quat(self, yaw: float) -> tuple[float, float, float, float]:
        return (math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw))


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _sign(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


class Recovery(Maneuver):
    name = RECOVERY
    description = "level, brake to a stop and climb back towards the start altitude"

    def start(self, ctl, t, rng):
        ctl.read_state()
        ctl.mode = MODE_POS
        ctl.pos_ref = [ctl.pos[0] + 0.4 * ctl.vel[0], ctl.pos[1] + 0.4 * ctl.vel[1], min(ctl.pos[2], 0.0)]
        ctl.vel_ff = [0.0, 0.0, 0.0]
        ctl.acc_ff = [0.0, 0.0, 0.0]
        ctl.yaw_ref = ctl.heading()
        ctl.yaw_rate_ff = 0.0
        self.t0 = t
        self.t_min = _u(rng, 0.6, 1.5)

    def update(self, ctl, t):
        el = t - self.t0
        if el < self.t_min:
            return False
        w = ctl.w
        settled = ctl.tilt() < 0.25 and abs(w[0]) + abs(w[1]) + abs(w[2]) < 1.0
        return settled or el > 4.0


class Hover(Maneuver):
    name = "hover"
    description = "station keeping: position hold with small target moves (+-0.5 m) and heading changes"

    def start(self, ctl, t, rng):
        ctl.hold_here()
        self.c = list(ctl.pos_ref)
        self.yaw0 = ctl.yaw_ref
        self.t0 = t
        self.dur = _u(rng, 3.0, 6.0)
        self.rng = rng
        self.next_move = t

    def update(self, ctl, t):
        if t >= self.next_move:
            r = self.rng
            ctl.pos_ref = [self.c[0] + _u(r, -0.5, 0.5), self.c[1] + _u(r, -0.5, 0.5),
                           self.c[2] + _u(r, -0.3, 0.3)]
            ctl.yaw_ref = self.yaw0 + _u(r, -0.5, 0.5)
            self.next_move = t + _u(r, 1.0, 2.0)
        return t - self.t0 >= self.dur


class Vibration(Hover):
    name = "vibration"
    description = "hover with strong motor vibration (an unbalanced propeller: x3-x6 amplitude)"

    def start(self, ctl, t, rng):
        super().start(ctl, t, rng)
        self.vibration_gain = _u(rng, 3.0, 6.0)


class RateSteps(Maneuver):
    name = "rate_steps"
    description = "aggressive body-rate doublets on random axes, re-levelled between steps"

    def start(self, ctl, t, rng):
        ctl.hold_here()
        p = ctl.p
        self.rng = rng
        self.t0 = t
        self.dur = _u(rng, 2.0, 4.0)
        self.lo, self.hi = 0.35 * p.flip_rate_rad_s[1], 0.8 * p.flip_rate_rad_s[1]
        self._new_step(ctl, t)

    def _new_step(self, ctl, t):
        r = self.rng
        self.axis = int(r.integers(0, 3))
        amp = _u(r, self.lo, self.hi) * _sign(r)
        if self.axis == 2:
            amp *= 0.5
        self.amp = amp
        self.step_dur = _u(r, 0.06, 0.16)
        self.ts = t
        ctl.read_state()
        self.level = ctl.level_quat(ctl.heading())

    def update(self, ctl, t):
        el = t - self.ts
        d = self.step_dur
        if el < 2.0 * d:
            ctl.mode = MODE_RATE
            rr = [0.0, 0.0, 0.0]
            rr[self.axis] = self.amp if el < d else -self.amp
            ctl.rate_ref = rr
            ctl.thrust_n = ctl.hover_thrust_n
        elif el < 2.0 * d + 0.35:
            ctl.mode = MODE_ATT
            ctl.q_ref = self.level
            ctl.thrust_n = ctl.hover_thrust_n / max(0.5, math.cos(min(ctl.tilt(), 1.0)))
        else:
            if t - self.t0 >= self.dur:
                return True
            self._new_step(ctl, t)
        return False

    def finish(self, ctl, t):
        ctl.hold_here()


class Flip(Maneuver):
    """A full rotation about the pitch axis (``flip``) or roll axis (``roll``)."""

    name = "flip"
    description = "360 deg (sometimes 720 deg) pitch flip at the vehicle's flip rate (>= 600 deg/s)"
    axis = 1
    min_agl_m = 20.0

    def start(self, ctl, t, rng):
        ctl.hold_here()
        p = ctl.p
        self.rate = _u(rng, *p.flip_rate_rad_s) * _sign(rng)
        self.turns = 2 if rng.random() < 0.2 else 1
        self.alt_ref = ctl.pos[2]
        self.yaw = ctl.heading()
        self.t_punch = _u(rng, 0.25, 0.5)
        v_up = _u(rng, 2.0, 5.0)  # punch up before rotating
        ctl.vel_ff = [0.0, 0.0, -v_up]
        ctl.pos_ref[2] = ctl.pos[2] - v_up * self.t_punch
        self.t0 = t
        self.phase = 0
        self.angle = 0.0
        self.cut = _u(rng, 0.25, 0.6)  # collective during the rotation, fraction of hover

    def update(self, ctl, t):
        ph = self.phase
        if ph == 0:
            if t - self.t0 >= self.t_punch:
                self.phase = 1
                ctl.mode = MODE_RATE
                rr = [0.0, 0.0, 0.0]
                rr[self.axis] = self.rate
                ctl.rate_ref = rr
                ctl.thrust_n = self.cut * ctl.hover_thrust_n
                self.t1 = t
        elif ph == 1:
            w = ctl.w[self.axis]
            self.angle += w * ctl.dt
            remaining = self.turns * TWO_PI - abs(self.angle)
            # hand over to the attitude loop early enough to brake
            if remaining <= 0.12 * abs(w) or t - self.t1 > 3.0:
                self.phase = 2
                ctl.mode = MODE_ATT
                ctl.q_ref = ctl.level_quat(self.yaw)
                ctl.thrust_n = ctl.hover_thrust_n
                self.t2 = t
        elif ph == 2:
            ctl.thrust_n = ctl.hover_thrust_n / max(0.5, math.cos(min(ctl.tilt(), 1.0)))
            if ctl.tilt() < 0.3 or t - self.t2 > 1.0:
                return True
        return False

    def finish(self, ctl, t):
        ctl.hold_here()
        ctl.pos_ref[2] = min(ctl.pos[2], self.alt_ref)


class Roll(Flip):
    name = "roll"
    description = "360 deg (sometimes 720 deg) roll at the vehicle's flip rate (>= 600 deg/s)"
    axis = 0


class YawSpin(Maneuver):
    name = "yaw_spin"
    description = "position hold while spinning about the vertical axis"

    def start(self, ctl, t, rng):
        ctl.hold_here()
        self.t0 = t
        self.dur = _u(rng, 1.5, 4.0)
        self.rate = _u(rng, *ctl.p.spin_rate_rad_s) * _sign(rng)
        self.ramp = 0.4

    def update(self, ctl, t):
        el = t - self.t0
        k = min(1.0, el / self.ramp, max(0.0, (self.dur - el) / self.ramp))
        ctl.yaw_rate_ff = k * self.rate
        return el >= self.dur

    def finish(self, ctl, t):
        ctl.hold_here()


class FigureEight(Maneuver):
    name = "figure_eight"
    description = "horizontal figure-eight with strong lateral acceleration (0.6-1.4 g)"

    def start(self, ctl, t, rng):
        ctl.hold_here()
        self.c = list(ctl.pos)
        amax = ctl.max_acc_h / math.sqrt(2.0)
        self.a_peak = _u(rng, 0.6 * G0_, min(1.4 * G0_, amax))
        self.period = _u(rng, 3.5, 7.0)
        self.om = TWO_PI / self.period
        self.A = self.a_peak / self.om**2
        self.Az = _u(rng, 0.0, 2.0)
        self.rot = _u(rng, -math.pi, math.pi)
        self.face = rng.random() < 0.5
        self.dur = self.period * (1 if rng.random() < 0.5 else 2)
        self.ramp = min(1.0, 0.25 * self.dur)
        self.t0 = t

    def update(self, ctl, t):
        el = t - self.t0
        k = min(1.0, el / self.ramp, max(0.0, (self.dur - el) / self.ramp))
        om, A = self.om, self.A
        s1, c1 = math.sin(om * el), math.cos(om * el)
        s2, c2 = math.sin(2 * om * el), math.cos(2 * om * el)
        # lemniscate-like: x = A sin(wt), y = A/4 sin(2wt)  -> both peak accelerations A w^2
        x, vx, ax = A * s1, A * om * c1, -A * om * om * s1
        y, vy, ay = 0.25 * A * s2, 0.5 * A * om * c2, -A * om * om * s2
        cr, sr = math.cos(self.rot), math.sin(self.rot)
        n, e = cr * x - sr * y, sr * x + cr * y
        vn, ve = cr * vx - sr * vy, sr * vx + cr * vy
        an, ae = cr * ax - sr * ay, sr * ax + cr * ay
        z, vz, az = self.Az * s1, self.Az * om * c1, -self.Az * om * om * s1
        c = self.c
        ctl.pos_ref = [c[0] + k * n, c[1] + k * e, c[2] + k * z]
        ctl.vel_ff = [k * vn, k * ve, k * vz]
        ctl.acc_ff = [k * an, k * ae, k * az]
        if self.face:
            v2 = vn * vn + ve * ve
            if k > 0.5 and v2 > 1.0:
                ctl.yaw_ref = math.atan2(ve, vn)
                ctl.yaw_rate_ff = k * (vn * ae - ve * an) / v2
            else:
                ctl.yaw_rate_ff = 0.0
        return el >= self.dur

    def finish(self, ctl, t):
        ctl.hold_here()


G0_ = 9.80665

REF_LIBRARY: dict[str, type[Maneuver]] = {
    m.name: m for m in (Hover, RateSteps, Flip, Roll, YawSpin, FigureEight, Vibration)
}
