"""Multirotor maneuver library: hover, rate steps, flips, rolls, yaw spins, figure-eights, vibration.

Each maneuver writes references into :class:`tepinn_flight.sim.multirotor.QuadController`;
parameters are drawn from the flight's generator at the maneuver's start and kept in the maneuver's
vector ``v``, which its compiled law (:mod:`tepinn_flight.sim.quad_maneuver_law`) reads at each control
update. What needs the generator mid-maneuver (a hover's next target, the next rate step) is the
``event`` method here, which finishes the update where the law returned ``EVENT``.
"""

from __future__ import annotations

import math

import numpy as np

from tepinn_flight.sim import quad_maneuver_law as law
from tepinn_flight.sim.maneuvers import RECOVERY, Maneuver
from tepinn_flight.sim.multirotor import MODE_POS

TWO_PI = 2.0 * math.pi


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _sign(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


class QuadManeuver(Maneuver):
    """A multirotor maneuver: its parameters and progress in ``v`` (``law.M_*`` and its kind's slots), its
    per-update law compiled (:func:`~tepinn_flight.sim.quad_maneuver_law.maneuver_update`)."""

    kind = -1

    def __init__(self):
        self.v = np.zeros(law.N_SLOTS)
        self.v[law.M_KIND] = self.kind

    def update(self, ctl, t):
        return self.resolve(ctl, t, law.maneuver_update(self.v, ctl.ref, ctl.obs, ctl.par, t))

    def resolve(self, ctl, t: float, code: int) -> bool:
        """Whether the maneuver has finished, given its law's ``code`` at this update (``EVENT``: Python's
        part of the update runs here)."""
        return self.event(ctl, t) if code == law.EVENT else code == law.DONE

    def event(self, ctl, t: float) -> bool:  # pragma: no cover - maneuvers whose law returns EVENT override it
        raise NotImplementedError(f"{self.name}: no event")


class Recovery(QuadManeuver):
    name = RECOVERY
    description = "level, brake to a stop and climb back towards the start altitude"
    kind = law.KIND_RECOVERY

    def start(self, ctl, t, rng):
        ctl.read_state()
        ctl.mode = MODE_POS
        ctl.pos_ref = [ctl.pos[0] + 0.4 * ctl.vel[0], ctl.pos[1] + 0.4 * ctl.vel[1], min(ctl.pos[2], 0.0)]
        ctl.vel_ff = [0.0, 0.0, 0.0]
        ctl.acc_ff = [0.0, 0.0, 0.0]
        ctl.yaw_ref = ctl.heading()
        ctl.yaw_rate_ff = 0.0
        self.v[law.M_T0] = t
        self.v[law.REC_T_MIN] = _u(rng, 0.6, 1.5)


class Hover(QuadManeuver):
    name = "hover"
    description = "station keeping: position hold with small target moves (+-0.5 m) and heading changes"
    kind = law.KIND_HOVER

    def start(self, ctl, t, rng):
        ctl.hold_here()
        self.c = list(ctl.pos_ref)
        self.yaw0 = ctl.yaw_ref
        self.v[law.M_T0] = t
        self.v[law.M_DUR] = _u(rng, 3.0, 6.0)
        self.rng = rng
        self.v[law.HOV_NEXT_MOVE] = t

    def event(self, ctl, t):
        """The next target: a small move and heading change, held for 1-2 s."""
        r = self.rng
        ctl.pos_ref = [self.c[0] + _u(r, -0.5, 0.5), self.c[1] + _u(r, -0.5, 0.5), self.c[2] + _u(r, -0.3, 0.3)]
        ctl.yaw_ref = self.yaw0 + _u(r, -0.5, 0.5)
        self.v[law.HOV_NEXT_MOVE] = t + _u(r, 1.0, 2.0)
        return t - self.v[law.M_T0] >= self.v[law.M_DUR]


class Vibration(Hover):
    name = "vibration"
    description = "hover with strong motor vibration (an unbalanced propeller: x3-x6 amplitude)"

    def start(self, ctl, t, rng):
        super().start(ctl, t, rng)
        self.vibration_gain = _u(rng, 3.0, 6.0)


class RateSteps(QuadManeuver):
    name = "rate_steps"
    description = "aggressive body-rate doublets on random axes, re-levelled between steps"
    kind = law.KIND_RATE_STEPS

    def start(self, ctl, t, rng):
        ctl.hold_here()
        p = ctl.p
        self.rng = rng
        self.v[law.M_T0] = t
        self.v[law.M_DUR] = _u(rng, 2.0, 4.0)
        self.lo, self.hi = 0.35 * p.flip_rate_rad_s[1], 0.8 * p.flip_rate_rad_s[1]
        self._new_step(ctl, t)

    def _new_step(self, ctl, t):
        r, v = self.rng, self.v
        axis = int(r.integers(0, 3))
        amp = _u(r, self.lo, self.hi) * _sign(r)
        if axis == 2:
            amp *= 0.5
        v[law.RS_AXIS], v[law.RS_AMP] = axis, amp
        v[law.RS_STEP_DUR] = _u(r, 0.06, 0.16)
        v[law.RS_TS] = t
        ctl.read_state()
        v[law.RS_LEVEL : law.RS_LEVEL + 4] = law.level_quat(ctl.heading())

    def event(self, ctl, t):
        """The next doublet (its axis, rate and length drawn) once the last one has been levelled."""
        self._new_step(ctl, t)
        return False

    def finish(self, ctl, t):
        ctl.hold_here()


class Flip(QuadManeuver):
    """A full rotation about the pitch axis (``flip``) or roll axis (``roll``)."""

    name = "flip"
    description = "360 deg (sometimes 720 deg) pitch flip at the vehicle's flip rate (>= 600 deg/s)"
    axis = 1
    min_agl_m = 20.0
    kind = law.KIND_FLIP

    def start(self, ctl, t, rng):
        ctl.hold_here()
        p, v = ctl.p, self.v
        v[law.FL_AXIS] = self.axis
        v[law.FL_RATE] = _u(rng, *p.flip_rate_rad_s) * _sign(rng)
        v[law.FL_TURNS] = 2 if rng.random() < 0.2 else 1
        self.alt_ref = ctl.pos[2]
        v[law.FL_YAW] = ctl.heading()
        t_punch = v[law.FL_T_PUNCH] = _u(rng, 0.25, 0.5)
        v_up = _u(rng, 2.0, 5.0)  # punch up before rotating
        ctl.vel_ff = [0.0, 0.0, -v_up]
        ctl.pos_ref[2] = ctl.pos[2] - v_up * t_punch
        v[law.M_T0] = t
        v[law.FL_PHASE] = 0.0
        v[law.FL_ANGLE] = 0.0
        v[law.FL_CUT] = _u(rng, 0.25, 0.6)  # collective during the rotation, fraction of hover

    def finish(self, ctl, t):
        ctl.hold_here()
        ctl.pos_ref[2] = min(ctl.pos[2], self.alt_ref)


class Roll(Flip):
    name = "roll"
    description = "360 deg (sometimes 720 deg) roll at the vehicle's flip rate (>= 600 deg/s)"
    axis = 0


class YawSpin(QuadManeuver):
    name = "yaw_spin"
    description = "position hold while spinning about the vertical axis"
    kind = law.KIND_YAW_SPIN

    def start(self, ctl, t, rng):
        ctl.hold_here()
        v = self.v
        v[law.M_T0] = t
        v[law.M_DUR] = _u(rng, 1.5, 4.0)
        v[law.YS_RATE] = _u(rng, *ctl.p.spin_rate_rad_s) * _sign(rng)
        v[law.YS_RAMP] = 0.4

    def finish(self, ctl, t):
        ctl.hold_here()


class FigureEight(QuadManeuver):
    name = "figure_eight"
    description = "horizontal figure-eight with strong lateral acceleration (0.6-1.4 g)"
    kind = law.KIND_FIGURE_EIGHT

    def start(self, ctl, t, rng):
        ctl.hold_here()
        v = self.v
        v[law.FE_C : law.FE_C + 3] = ctl.pos
        amax = ctl.max_acc_h / math.sqrt(2.0)
        a_peak = _u(rng, 0.6 * G0_, min(1.4 * G0_, amax))
        period = _u(rng, 3.5, 7.0)
        om = v[law.FE_OM] = TWO_PI / period
        v[law.FE_A] = a_peak / om**2
        v[law.FE_AZ] = _u(rng, 0.0, 2.0)
        v[law.FE_ROT] = _u(rng, -math.pi, math.pi)
        v[law.FE_FACE] = rng.random() < 0.5
        dur = v[law.M_DUR] = period * (1 if rng.random() < 0.5 else 2)
        v[law.FE_RAMP] = min(1.0, 0.25 * dur)
        v[law.M_T0] = t

    def finish(self, ctl, t):
        ctl.hold_here()


G0_ = 9.80665

LIBRARY: dict[str, type[Maneuver]] = {
    m.name: m for m in (Hover, RateSteps, Flip, Roll, YawSpin, FigureEight, Vibration)
}
#: relative frequency of each maneuver in a random flight
WEIGHTS = {"hover": 0.6, "vibration": 0.5, "rate_steps": 1.0, "flip": 1.0, "roll": 1.0,
           "yaw_spin": 0.8, "figure_eight": 1.0}
