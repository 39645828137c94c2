"""Fixed-wing vehicles and our autopilot (roll, pitch, yaw and speed loops on JSBSim surfaces).

Inner loops are body-rate loops (aileron on p, elevator on q, rudder on r and sideslip) with
integrators that absorb trim; outer loops give the rate commands from a bank angle, a pitch angle
(with the coordinated-turn pitch rate as feed-forward), an altitude, or a commanded pitch rate
(loops, pull-ups). Per-step code is plain Python on floats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tepinn_flight.errors import ConfigError
from tepinn_flight.sim.jsbsim_env import FT_TO_M, getter, jsbsim_module, setter
from tepinn_flight.sim.lean_model import LeanModel

G0 = 9.80665
KT_TO_M_S = 0.514444
PI = math.pi
TWO_PI = 2.0 * math.pi
_sin, _cos = math.sin, math.cos

ROLL_BANK = 0  # phi_ref
ROLL_RATE = 1  # p_ref
ROLL_LEVEL_ANY = 2  # wings level upright or inverted, whichever is nearer (loops)
ROLL_AILERON = 3  # open-loop aileron

PITCH_THETA = 0  # theta_ref (+ coordinated-turn feed-forward)
PITCH_RATE = 1  # q_ref
PITCH_ALT = 2  # hold alt_ref via theta
PITCH_ELEVATOR = 3  # open-loop elevator

YAW_COORD = 0
YAW_RUDDER = 1

THR_SPEED = 0
THR_FIXED = 1


@dataclass(frozen=True)
class FixedWingParams:
    model: str
    own_aircraft: bool
    cruise_kt: tuple[float, float]  # trim speed drawn from this range
    start_agl_m: tuple[float, float]
    max_terrain_m: float
    roll_kp: float  # aileron per rad/s of roll-rate error
    roll_ki: float
    bank_kp: float  # roll-rate command per rad of bank error
    max_roll_rate: float  # rad/s (closed-loop bank changes)
    pitch_kp: float  # elevator per rad/s of pitch-rate error (sign: + elevator = nose down)
    pitch_ki: float
    theta_kp: float  # pitch-rate command per rad of pitch error
    alt_kp: float  # rad of pitch per m of altitude error
    vs_kd: float  # rad of pitch per m/s of vertical speed
    yaw_kr: float  # rudder per rad/s of yaw-rate error (sign: + rudder = nose left)
    yaw_kb: float  # rudder per rad of sideslip
    speed_kp: float  # throttle per kt of speed error
    speed_ki: float
    stall_kt: float
    vne_kt: float  # never-exceed: throttle idle and pull up gently beyond this
    max_g: float  # load factor used for pulls (clamped by maneuvers)
    floor_agl_m: float  # recoveries climb when below this
    #: a stock JSBSim model's parts our simulation never uses, left out (None: the model as is)
    lean: LeanModel | None = None


C172X = FixedWingParams(
    model="c172x",
    own_aircraft=False,
    cruise_kt=(90.0, 110.0),
    start_agl_m=(1500.0, 2300.0),
    max_terrain_m=400.0,
    roll_kp=0.8,
    roll_ki=0.6,
    bank_kp=2.0,
    max_roll_rate=math.radians(60.0),
    pitch_kp=2.0,
    pitch_ki=2.0,
    theta_kp=1.5,
    alt_kp=0.01,
    vs_kd=0.03,
    yaw_kr=1.0,
    yaw_kb=1.5,
    speed_kp=0.05,
    speed_ki=0.02,
    stall_kt=50.0,
    vne_kt=175.0,
    max_g=5.5,
    floor_agl_m=700.0,
    # JSBSim's own autopilot (c172ap, its Autopilot and GNCUtilities systems): disengaged, it adds
    # exactly 0.0 to the surfaces our controller commands — but its attitude sensor draws noise from
    # the generator the turbulence uses, so that one component stays; and the ground contacts (a
    # flight stops at FixedWingVehicle.min_agl_m): 40 % of each run(), the flights unchanged
    lean=LeanModel(
        drop=('<system file="GNCUtilities"/>', '<system file="Autopilot">'),
        zero_properties=("ap/roll-cmd-norm-output",),
        keep_only=(("c172ap.xml", "autopilot", ('<sensor name="fcs/attitude/sensor/phi-rad">',),
                    ("ap/aileron_cmd", "ap/elevator_cmd")),),
        empty=(("<ground_reactions>", "<contact"),),
    ),
)


def wrap_pi(a: float) -> float:
    return (a + PI) % TWO_PI - PI


class FixedWingController:
    """Autopilot bound to one FGFDMExec; maneuvers write the public mode/reference fields."""

    def __init__(self, fdm, p: FixedWingParams, dt_s: float):
        self.p = p
        self.dt = dt_s
        self.fdm = fdm
        g = lambda path: getter(fdm, path)  # noqa: E731
        self._phi, self._theta, self._psi = g("attitude/phi-rad"), g("attitude/theta-rad"), g("attitude/psi-rad")
        self._p, self._q, self._r = g("velocities/pi-rad_sec"), g("velocities/qi-rad_sec"), g("velocities/ri-rad_sec")
        self._vc = g("velocities/vc-kts")
        self._vt = g("velocities/vt-fps")
        self._h = g("position/h-agl-ft")
        self._hdot = g("velocities/h-dot-fps")
        self._beta = g("aero/beta-rad")
        self._nz = g("accelerations/Nz")
        self._ail = setter(fdm, "fcs/aileron-cmd-norm")
        self._ele = setter(fdm, "fcs/elevator-cmd-norm")
        self._rud = setter(fdm, "fcs/rudder-cmd-norm")
        self._thr = setter(fdm, "fcs/throttle-cmd-norm")
        self.roll_mode, self.pitch_mode, self.yaw_mode, self.thr_mode = ROLL_BANK, PITCH_ALT, YAW_COORD, THR_SPEED
        self.phi_ref = 0.0
        self.p_ref = 0.0
        self.aileron = 0.0
        self.theta_ref = 0.0
        self.q_ref = 0.0
        self.elevator = 0.0
        self.alt_ref_m = 0.0
        self.rudder = 0.0
        self.speed_ref_kt = 100.0
        self.throttle = 0.7
        self.max_roll_rate = p.max_roll_rate
        self._ia = self._ie = self._it = 0.0
        # state exposed to maneuvers
        self.phi = self.theta = self.psi = 0.0
        self.w = (0.0, 0.0, 0.0)
        self.vc_kt = 0.0
        self.agl_m = 0.0
        self.start_agl_m = 0.0

    def read_state(self) -> None:
        self.phi, self.theta, self.psi = self._phi(), self._theta(), self._psi()
        self.w = (self._p(), self._q(), self._r())
        self.vc_kt = self._vc()
        self.agl_m = self._h() * FT_TO_M

    def hold_level(self, climb: bool = False) -> None:
        """Wings level, hold (or climb to) altitude at cruise speed."""
        self.read_state()
        self.roll_mode, self.yaw_mode, self.thr_mode = ROLL_BANK, YAW_COORD, THR_SPEED
        self.phi_ref = 0.0
        self.pitch_mode = PITCH_ALT
        self.alt_ref_m = max(self.agl_m, self.p.floor_agl_m) if climb else self.agl_m
        self.speed_ref_kt = self.cruise_kt

    def step(self, state: tuple | None = None) -> None:
        """One control update. ``state``: the values :func:`~tepinn_flight.sim.flight.fly` read
        after the last ``run()`` (:data:`~tepinn_flight.sim.flight.STATE_PATHS`), the same numbers
        this would read; None: read here."""
        p = self.p
        dt = self.dt
        if state is None:
            phi, theta = self._phi(), self._theta()
            wp, wq, wr = self._p(), self._q(), self._r()
            h_ft = None
        else:
            phi, theta, _, wp, wq, wr, h_ft = state[:7]
        self.phi, self.theta = phi, theta
        self.w = (wp, wq, wr)
        vc = self._vc()
        self.vc_kt = vc
        v = self._vt() * FT_TO_M
        if v < 15.0:
            v = 15.0
        sphi, cphi, cth = _sin(phi), _cos(phi), _cos(theta)
        # ---- roll
        rm = self.roll_mode
        if rm == ROLL_AILERON:
            ail = self.aileron
        else:
            if rm == ROLL_BANK:
                e = self.phi_ref - phi
                e = (e + PI) % TWO_PI - PI
                lim = self.max_roll_rate
                pc = p.bank_kp * e * (1.0 if cth > 0.3 else cth / 0.3)  # bank undefined near vertical
                pc = -lim if pc < -lim else (lim if pc > lim else pc)
            elif rm == ROLL_LEVEL_ANY:
                # keep the body y axis horizontal, upright or inverted (loops): y_b.down = cos(th) sin(phi)
                zd = cth * cphi
                sg = zd / 0.2 if -0.2 < zd < 0.2 else (1.0 if zd > 0.0 else -1.0)
                pc = -p.bank_kp * cth * sphi * sg
            else:
                pc = self.p_ref
            ep = pc - wp
            ail = p.roll_kp * ep + self._ia
            if -1.0 < ail < 1.0:  # conditional integration (anti-windup)
                ia = self._ia + p.roll_ki * ep * dt
                self._ia = -0.3 if ia < -0.3 else (0.3 if ia > 0.3 else ia)
        self._ail(-1.0 if ail < -1.0 else (1.0 if ail > 1.0 else ail))
        # ---- pitch
        pm = self.pitch_mode
        if pm == PITCH_ELEVATOR:
            ele = self.elevator
        else:
            if pm == PITCH_RATE:
                qc = self.q_ref
            else:
                if pm == PITCH_ALT:
                    h = (self._h() if h_ft is None else h_ft) * FT_TO_M
                    self.agl_m = h
                    tr = p.alt_kp * (self.alt_ref_m - h) - p.vs_kd * self._hdot() * FT_TO_M
                    tr = -0.2 if tr < -0.2 else (0.25 if tr > 0.25 else tr)
                else:
                    tr = self.theta_ref
                # coordinated-turn pitch rate q = (g/V) tan(phi) sin(phi) cos(theta) when upright;
                # the pitch error acts through cos(phi) (inverted: push to raise the nose)
                qff = G0 / v * sphi * sphi / cphi * cth if cphi > 0.3 else 0.0
                qc = qff + p.theta_kp * (tr - theta) * cphi
            eq = qc - wq
            ele = -(p.pitch_kp * eq + self._ie)
            if -1.0 < ele < 1.0:
                ie = self._ie + p.pitch_ki * eq * dt
                self._ie = -0.4 if ie < -0.4 else (0.4 if ie > 0.4 else ie)
        self._ele(-1.0 if ele < -1.0 else (1.0 if ele > 1.0 else ele))
        # ---- yaw
        if self.yaw_mode == YAW_RUDDER:
            rud = self.rudder
        else:
            rc = G0 / v * sphi * cth
            rud = p.yaw_kr * (wr - rc) - p.yaw_kb * self._beta()
        self._rud(-1.0 if rud < -1.0 else (1.0 if rud > 1.0 else rud))
        # ---- throttle
        if self.thr_mode == THR_SPEED:
            ev = self.speed_ref_kt - vc
            it = self._it + p.speed_ki * ev * dt
            self._it = it = -0.5 if it < -0.5 else (0.5 if it > 0.5 else it)
            thr = self.throttle_trim + p.speed_kp * ev + it
        else:
            thr = self.throttle
        if vc > p.vne_kt:
            thr = 0.0
        self._thr(0.0 if thr < 0.0 else (1.0 if thr > 1.0 else thr))

    def nz(self) -> float:
        """Load factor at the CG, g (+1 in level flight)."""
        return self._nz()


class FixedWingVehicle:
    """A trimmed fixed wing in JSBSim plus our autopilot."""

    vehicle_type = "fixed-wing"
    control_hz = 100.0
    log_paths = ("propulsion/engine/engine-rpm", "aero/alpha-rad", "aero/beta-rad", "velocities/vc-kts")

    def __init__(self, params: FixedWingParams):
        self.p = params
        self.model = params.model
        self.own_aircraft = params.own_aircraft
        self.lean = params.lean
        self.min_agl_m = 60.0  # the flight stops here (the lean c172x has no ground contacts)
        self.ctl: FixedWingController | None = None

    def start(self, fdm, site: dict, rng, dt_s: float) -> FixedWingController:
        p = self.p
        jsbsim = jsbsim_module()
        elev = min(site["elevation_m"], p.max_terrain_m)
        agl = float(rng.uniform(*p.start_agl_m))
        speed = float(rng.uniform(*p.cruise_kt))
        psi = float(rng.uniform(0.0, 360.0))
        for attempt in range(4):  # slower if the engine cannot hold the drawn speed at that height
            fdm["ic/lat-geod-deg"] = site["lat_deg"]  # P2: position, then altitude, then speed
            fdm["ic/long-gc-deg"] = site["lon_deg"]
            fdm["ic/terrain-elevation-ft"] = elev / FT_TO_M
            fdm["ic/h-agl-ft"] = agl / FT_TO_M
            fdm["ic/vc-kts"] = speed
            fdm["ic/psi-true-deg"] = psi
            fdm["ic/gamma-deg"] = 0.0
            fdm.run_ic()
            fdm.get_propulsion().init_running(-1)
            fdm["fcs/mixture-cmd-norm"] = 1.0
            try:
                fdm.do_trim(1)
                break
            except jsbsim.TrimFailureError as exc:
                if attempt == 3:
                    raise ConfigError(f"{p.model}: trim failed at {agl:.0f} m AGL, {speed:.0f} kt ({exc})") from exc
                speed -= 8.0
        ctl = FixedWingController(fdm, p, dt_s)
        ctl.throttle_trim = fdm["fcs/throttle-cmd-norm"]
        ctl.cruise_kt = speed
        ctl._ia = fdm["fcs/aileron-cmd-norm"]
        ctl.read_state()
        ctl.start_agl_m = ctl.agl_m
        ctl.hold_level()
        self.ctl = ctl
        return ctl

    def rotor_hz(self, logged):  # pragma: no cover - fixed wings get no vibration model
        raise NotImplementedError
