"""Fixed-wing maneuver library: steep turns, aileron rolls, loops, split-S, dives and pull-ups,
rudder reversals and a turbulence/gust segment. References go to
:class:`tepinn_flight.sim.fixed_wing.FixedWingController`; parameters come from the flight's seed.
"""

from __future__ import annotations

import math

import numpy as np

from tepinn_flight.sim import fixed_wing as fw
from tepinn_flight.sim.jsbsim_env import FT_TO_M
from tepinn_flight.sim.maneuvers import RECOVERY, Maneuver

G0 = 9.80665
TWO_PI = 2.0 * math.pi
D2R = math.pi / 180.0


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _sign(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


def _pull_rate(ctl, n_g: float) -> float:
    """Body pitch rate (rad/s) that gives about ``n_g`` of load factor at the current speed."""
    v = max(ctl.vc_kt * fw.KT_TO_M_S, 25.0)
    return (n_g - math.cos(ctl.theta) * math.cos(ctl.phi)) * G0 / v


class Recovery(Maneuver):
    name = RECOVERY
    description = "roll wings level (shortest way), level or climb back above the floor, cruise speed"

    def start(self, ctl, t, rng):
        ctl.read_state()
        ctl.roll_mode, ctl.yaw_mode, ctl.thr_mode = fw.ROLL_BANK, fw.YAW_COORD, fw.THR_SPEED
        ctl.phi_ref = 0.0
        ctl.speed_ref_kt = ctl.cruise_kt
        ctl.max_roll_rate = ctl.p.max_roll_rate
        # below the floor, climb well above it (c172: ~3.5 m/s at full power)
        floor = ctl.p.floor_agl_m
        self.target = max(getattr(self, "target_agl_m", 0.0), floor + 300.0 if ctl.agl_m < floor else 0.0)
        ctl.pitch_mode = fw.PITCH_THETA
        ctl.theta_ref = 0.0
        self.t0 = t
        self.t_min = _u(rng, 1.5, 3.0)
        self.phase = 0

    def update(self, ctl, t):
        el = t - self.t0
        ctl.read_state()
        if self.phase == 0:  # attitude first: wings level, nose to the horizon
            ctl.theta_ref = 0.0 if ctl.vc_kt > ctl.p.stall_kt + 20.0 else -0.25
            if abs(ctl.phi) < 0.35 and abs(ctl.theta) < 0.3 or el > 6.0:
                self.phase = 1
                ctl.pitch_mode = fw.PITCH_ALT
                ctl.alt_ref_m = max(ctl.agl_m, self.target)
            return False
        if ctl.agl_m < self.target - 30.0:  # climbing: full power
            ctl.thr_mode, ctl.throttle = fw.THR_FIXED, 1.0
            return el > 300.0
        ctl.thr_mode = fw.THR_SPEED
        return el >= self.t_min


class SteepTurn(Maneuver):
    name = "steep_turn"
    description = "level turn at 45-70 deg of bank (1.4-2.9 g), 180-360 deg of heading change"
    min_agl_m = 250.0

    def start(self, ctl, t, rng):
        ctl.hold_level()
        self.bank = _u(rng, 45.0, 70.0) * D2R * _sign(rng)
        self.turn = _u(rng, 180.0, 360.0) * D2R
        ctl.speed_ref_kt = ctl.cruise_kt + 10.0
        ctl.max_roll_rate = _u(rng, 30.0, 60.0) * D2R
        self.psi_prev = ctl._psi()
        self.turned = 0.0
        self.t0 = t
        self.rolled_out = None

    def update(self, ctl, t):
        psi = ctl._psi()
        d = (psi - self.psi_prev + math.pi) % TWO_PI - math.pi
        self.psi_prev = psi
        self.turned += abs(d)
        if self.rolled_out is None:
            ctl.phi_ref = self.bank
            if self.turned >= self.turn or t - self.t0 > 60.0:
                self.rolled_out = t
                ctl.phi_ref = 0.0
            return False
        return t - self.rolled_out > 1.5

    def finish(self, ctl, t):
        ctl.max_roll_rate = ctl.p.max_roll_rate


class AileronRoll(Maneuver):
    name = "aileron_roll"
    description = "gain speed, pull the nose 5-20 deg up, full aileron and rudder through 360 (or 720) deg of roll"
    min_agl_m = 350.0

    def start(self, ctl, t, rng):
        ctl.hold_level()
        ctl.pitch_mode, ctl.theta_ref = fw.PITCH_THETA, -15.0 * D2R
        ctl.thr_mode, ctl.throttle = fw.THR_FIXED, 1.0
        self.entry_kt = _u(rng, 130.0, 145.0)
        self.nose_up = _u(rng, 5.0, 20.0) * D2R
        self.dir = _sign(rng)
        self.rudder = -self.dir * _u(rng, 0.3, 0.8)  # rudder into the roll (+ rudder = nose left)
        self.amount = TWO_PI * (2 if rng.random() < 0.25 else 1)
        self.phase = 0
        self.t0 = t
        self.rolled = 0.0

    def update(self, ctl, t):
        if self.phase == 0:  # shallow dive for speed (roll rate grows with speed)
            if ctl.vc_kt >= self.entry_kt or t - self.t0 > 15.0:
                self.phase = 1
                ctl.pitch_mode = fw.PITCH_RATE
                ctl.q_ref = _pull_rate(ctl, 2.5)
            return False
        if self.phase == 1:  # pull up to the roll attitude
            if ctl.theta >= self.nose_up or t - self.t0 > 25.0:
                self.phase = 2
                ctl.roll_mode, ctl.aileron = fw.ROLL_AILERON, self.dir
                ctl.pitch_mode, ctl.elevator = fw.PITCH_ELEVATOR, 0.0
                ctl.yaw_mode, ctl.rudder = fw.YAW_RUDDER, self.rudder
            return False
        if self.phase == 2:
            self.rolled += ctl.w[0] * ctl.dt
            if abs(self.rolled) >= self.amount - 0.35 or t - self.t0 > 35.0:
                self.phase = 3
                ctl.roll_mode, ctl.phi_ref = fw.ROLL_BANK, 0.0
                ctl.max_roll_rate = 90.0 * D2R
                ctl.pitch_mode, ctl.theta_ref = fw.PITCH_THETA, 0.0
                ctl.yaw_mode = fw.YAW_COORD
                ctl.thr_mode = fw.THR_SPEED
                self.t3 = t
            return False
        return abs(ctl.phi) < 0.2 or t - self.t3 > 4.0

    def finish(self, ctl, t):
        ctl.max_roll_rate = ctl.p.max_roll_rate
        ctl.thr_mode = fw.THR_SPEED


class Loop(Maneuver):
    name = "loop"
    description = "dive to entry speed, then a 3-4.5 g inside loop, wings held level throughout"
    min_agl_m = 600.0

    def start(self, ctl, t, rng):
        ctl.hold_level()
        ctl.pitch_mode, ctl.theta_ref = fw.PITCH_THETA, -_u(rng, 15.0, 25.0) * D2R
        ctl.thr_mode, ctl.throttle = fw.THR_FIXED, 1.0
        self.entry_kt = _u(rng, 125.0, 140.0)
        self.g = _u(rng, 3.0, 4.5)
        self.phase = 0
        self.t0 = t
        self.pitched = 0.0

    def update(self, ctl, t):
        if self.phase == 0:  # dive for speed
            if ctl.vc_kt >= self.entry_kt or t - self.t0 > 15.0:
                self.phase = 1
                ctl.roll_mode = fw.ROLL_LEVEL_ANY
                ctl.pitch_mode = fw.PITCH_RATE
            return False
        if self.phase == 1:  # pull through 360 deg of pitch
            self.pitched += ctl.w[1] * ctl.dt
            # keep the pull but never below 1.5 g-equivalent pitch rate near the top (slow)
            ctl.q_ref = max(_pull_rate(ctl, self.g), 0.35)
            if self.pitched >= TWO_PI - 0.5 or t - self.t0 > 40.0:
                self.phase = 2
                ctl.roll_mode, ctl.phi_ref = fw.ROLL_BANK, 0.0
                ctl.pitch_mode, ctl.theta_ref = fw.PITCH_THETA, 0.0
                ctl.thr_mode = fw.THR_SPEED
                self.t2 = t
            return False
        return (abs(ctl.theta) < 0.1 and abs(ctl.phi) < 0.2) or t - self.t2 > 5.0


class SplitS(Maneuver):
    name = "split_s"
    description = "half aileron roll to inverted, idle power, pull through the half loop, heading reversed"
    min_agl_m = 800.0

    def start(self, ctl, t, rng):
        ctl.hold_level()
        ctl.pitch_mode, ctl.theta_ref = fw.PITCH_THETA, _u(rng, 5.0, 15.0) * D2R
        ctl.speed_ref_kt = _u(rng, 90.0, 105.0)
        self.g = _u(rng, 2.5, 4.0)
        self.ail = _u(rng, 0.8, 1.0) * _sign(rng)
        self.phase = 0
        self.t0 = t
        self.rolled = 0.0
        self.pitched = 0.0

    def update(self, ctl, t):
        if self.phase == 0:  # nose a little up, then half roll with the stick
            if ctl.theta > ctl.theta_ref - 3.0 * D2R or t - self.t0 > 8.0:
                self.phase = 1
                ctl.roll_mode, ctl.aileron = fw.ROLL_AILERON, self.ail
                ctl.pitch_mode, ctl.elevator = fw.PITCH_ELEVATOR, 0.0
                ctl.thr_mode, ctl.throttle = fw.THR_FIXED, 0.0
            return False
        if self.phase == 1:
            self.rolled += ctl.w[0] * ctl.dt
            if abs(self.rolled) >= math.pi - 0.3 or t - self.t0 > 15.0:
                self.phase = 2
                ctl.roll_mode = fw.ROLL_LEVEL_ANY
                ctl.pitch_mode = fw.PITCH_RATE
            return False
        if self.phase == 2:  # pull through 180 deg of pitch
            self.pitched += ctl.w[1] * ctl.dt
            ctl.q_ref = max(_pull_rate(ctl, self.g), 0.3)
            if self.pitched >= math.pi - 0.35 or t - self.t0 > 40.0:
                self.phase = 3
                ctl.roll_mode, ctl.phi_ref = fw.ROLL_BANK, 0.0
                ctl.pitch_mode, ctl.theta_ref = fw.PITCH_THETA, 0.0
                ctl.thr_mode = fw.THR_SPEED
                ctl.speed_ref_kt = ctl.cruise_kt
                self.t3 = t
            return False
        return (abs(ctl.theta) < 0.1 and abs(ctl.phi) < 0.2) or t - self.t3 > 5.0

    def finish(self, ctl, t):
        ctl.thr_mode = fw.THR_SPEED


class DivePullup(Maneuver):
    name = "dive_pullup"
    description = "push over into a 30-60 deg dive, then a 3-5.5 g pull-up into a 20-40 deg climb"
    min_agl_m = 700.0

    def start(self, ctl, t, rng):
        ctl.hold_level()
        ctl.pitch_mode, ctl.theta_ref = fw.PITCH_THETA, -_u(rng, 30.0, 60.0) * D2R
        ctl.thr_mode, ctl.throttle = fw.THR_FIXED, _u(rng, 0.0, 1.0)
        self.exit_kt = _u(rng, 140.0, 165.0)
        self.g = _u(rng, 3.0, ctl.p.max_g)
        self.climb = _u(rng, 20.0, 40.0) * D2R
        self.lost_max = _u(rng, 250.0, 400.0)
        self.h0 = ctl.agl_m
        self.phase = 0
        self.t0 = t

    def update(self, ctl, t):
        if self.phase == 0:
            ctl.read_state()
            if ctl.vc_kt >= self.exit_kt or self.h0 - ctl.agl_m > self.lost_max or t - self.t0 > 20.0:
                self.phase = 1
                ctl.pitch_mode = fw.PITCH_RATE
                ctl.thr_mode, ctl.throttle = fw.THR_FIXED, 1.0
            return False
        if self.phase == 1:
            ctl.q_ref = max(_pull_rate(ctl, self.g), 0.2)
            if ctl.theta >= self.climb or t - self.t0 > 40.0:
                self.phase = 2
                ctl.pitch_mode, ctl.theta_ref = fw.PITCH_THETA, 0.0
                ctl.thr_mode = fw.THR_SPEED
                self.t2 = t
            return False
        return abs(ctl.theta) < 0.1 or t - self.t2 > 6.0


class RudderReversal(Maneuver):
    name = "rudder_reversal"
    description = "full-rudder reversals (Dutch roll excitation), loose wings-level hold"
    min_agl_m = 250.0

    def start(self, ctl, t, rng):
        ctl.hold_level()
        self.amp = _u(rng, 0.6, 1.0)
        self.half = _u(rng, 0.6, 1.5)
        self.dur = _u(rng, 3.0, 8.0)
        self.sign = _sign(rng)
        ctl.yaw_mode = fw.YAW_RUDDER
        ctl.max_roll_rate = 20.0 * D2R
        self.t0 = t

    def update(self, ctl, t):
        el = t - self.t0
        k = int(el / self.half)
        ctl.rudder = self.amp * self.sign * (1.0 if k % 2 == 0 else -1.0)
        return el >= self.dur

    def finish(self, ctl, t):
        ctl.yaw_mode = fw.YAW_COORD
        ctl.max_roll_rate = ctl.p.max_roll_rate


class Turbulence(Maneuver):
    name = "turbulence"
    description = "cruise through severe MIL-SPEC (Dryden) turbulence with discrete 1-cosine gusts"
    min_agl_m = 250.0

    def start(self, ctl, t, rng):
        ctl.hold_level()
        self.fdm = ctl.fdm
        self.rng = rng
        self.dur = _u(rng, 6.0, 15.0)
        fdm = self.fdm
        fdm["atmosphere/turb-type"] = 3
        fdm["atmosphere/turbulence/milspec/windspeed_at_20ft_AGL-fps"] = _u(rng, 50.0, 80.0)
        fdm["atmosphere/turbulence/milspec/severity"] = int(rng.integers(5, 8))
        self.t0 = t
        self._gust = None
        self.next_gust = t + _u(rng, 0.5, 2.0)
        ctl.phi_ref = _u(rng, -20.0, 20.0) * D2R

    def update(self, ctl, t):
        fdm = self.fdm
        if self._gust is None and t >= self.next_gust:
            r = self.rng
            mag = _u(r, 2.0, 10.0) / FT_TO_M
            d = r.normal(size=3)
            d[2] *= 0.6
            d /= np.linalg.norm(d)
            self._gust = (t, _u(r, 0.4, 2.0), float(mag * d[0]), float(mag * d[1]), float(mag * d[2]))
        if self._gust is not None:
            t0, length, gn, ge, gd = self._gust
            x = (t - t0) / length
            if x >= 1.0:
                k = 0.0
                self._gust = None
                self.next_gust = t + _u(self.rng, 0.5, 2.5)
            else:
                k = 0.5 * (1.0 - math.cos(TWO_PI * x))
            fdm["atmosphere/gust-north-fps"] = k * gn
            fdm["atmosphere/gust-east-fps"] = k * ge
            fdm["atmosphere/gust-down-fps"] = k * gd
        return t - self.t0 >= self.dur

    def finish(self, ctl, t):
        fdm = self.fdm
        ws, sev = ctl.turbulence_baseline
        fdm["atmosphere/turb-type"] = 3 if ws > 0.0 else 0
        fdm["atmosphere/turbulence/milspec/windspeed_at_20ft_AGL-fps"] = ws
        fdm["atmosphere/turbulence/milspec/severity"] = sev
        for a in ("north", "east", "down"):
            fdm[f"atmosphere/gust-{a}-fps"] = 0.0


LIBRARY: dict[str, type[Maneuver]] = {
    m.name: m for m in (SteepTurn, AileronRoll, Loop, SplitS, DivePullup, RudderReversal, Turbulence)
}
WEIGHTS = {"steep_turn": 1.0, "aileron_roll": 1.2, "loop": 1.0, "split_s": 0.8, "dive_pullup": 1.0,
           "rudder_reversal": 0.8, "turbulence": 0.7}
