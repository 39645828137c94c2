"""Multirotor vehicles and our own cascaded flight controller (position -> attitude -> rate -> mixer).

The controller runs at ``QuadVehicle.control_hz`` (200 Hz), its laws compiled with numba in
:mod:`tepinn_flight.sim.quad_control_law`, and bypasses any controller inside the JSBSim
model (the F450's rate SCAS limits rates to 43 deg/s; we switch it off and drive the ESC inputs
``fcs/cmd*_ext_nd`` directly), so the vehicle can flip and roll at more than 600 deg/s.

Per-step Python only moves floats between JSBSim, the maneuvers' references and the compiled laws:
it is the speed-critical path.

Frames: body FRD, earth NED; motor order FR, AL, FL, AR for both quads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tepinn_flight.quat import gravity_body_f, quat_from_euler_zyx_f
from tepinn_flight.sim.jsbsim_env import FT_TO_M, getter, setter
from tepinn_flight.sim.lean_model import LeanModel
from tepinn_flight.sim.quad_control_law import G0, attitude_step, pack_params, position_step, rate_step


MODE_POS = 0  # velocity/position reference -> thrust vector -> attitude
MODE_ATT = 1  # attitude quaternion reference + collective thrust
MODE_RATE = 2  # body-rate reference + collective thrust


@dataclass(frozen=True)
class QuadParams:
    """A quad X vehicle as our controller sees it."""

    model: str  # JSBSim model name
    own_aircraft: bool  # True: flight_sims/aircraft/<model>
    mass_kg: float
    inertia_kg_m2: tuple[float, float, float]
    motor_xy_m: tuple[tuple[float, float], ...]  # body FRD (x fwd, y right) of motors FR, AL, FL, AR
    yaw_sense: tuple[float, ...]  # +1: that motor's reaction torque yaws the nose right
    yaw_arm_m: float  # reaction torque / thrust
    thrust_max_n: float  # per motor, static
    cmd_paths: tuple[str, ...]  # properties written with the normalised motor command
    cmd_exponent: float  # static thrust = thrust_max * cmd ** exponent
    rpm_paths: tuple[str, ...]  # propeller rpm properties ("" -> rpm from the thrust command)
    rpm_max: float  # rpm at full thrust (used when rpm_paths are empty)
    setup: tuple[tuple[str, float], ...]  # properties written once after the initial conditions
    rate_kp: float  # 1/s, rate loop proportional gain (angular acceleration per rate error)
    rate_kd: float  # rate loop damping on angular acceleration (s)
    rate_ki: float
    yaw_lpf_s: float  # low-pass on the yaw torque command (the F450's motor torque reacts instantly)
    att_kp: float  # 1/s roll/pitch attitude gain
    att_kp_yaw: float
    vel_kp: float  # 1/s
    pos_kp: float  # 1/s
    max_tilt_rad: float
    max_rate_rad_s: float  # attitude-mode rate limit (roll/pitch)
    max_yaw_rate_rad_s: float
    flip_rate_rad_s: tuple[float, float]  # range drawn for flips and rolls
    spin_rate_rad_s: tuple[float, float]  # range drawn for yaw spins
    start_agl_m: tuple[float, float]
    #: a stock JSBSim model's parts our simulation never reads, left out (None: the model as is)
    lean: LeanModel | None = None


F450 = QuadParams(
    model="F450",
    own_aircraft=False,
    mass_kg=1.4,
    inertia_kg_m2=(0.0190, 0.0190, 0.0252),
    motor_xy_m=((0.1651, 0.1651), (-0.1651, -0.1651), (0.1651, -0.1651), (-0.1651, 0.1651)),
    yaw_sense=(1.0, 1.0, -1.0, -1.0),
    yaw_arm_m=0.0196,
    thrust_max_n=15.64,
    cmd_paths=("fcs/cmdFR_ext_nd", "fcs/cmdAL_ext_nd", "fcs/cmdFL_ext_nd", "fcs/cmdAR_ext_nd"),
    cmd_exponent=1.72,
    rpm_paths=tuple(f"propulsion/engine[{i}]/propeller-rpm" for i in range(4)),
    rpm_max=10500.0,
    setup=(("fcs/ScasEngage", 0.0), ("fcs/throttle-cmd-norm", 0.0)),
    rate_kp=20.0,
    rate_kd=0.05,
    rate_ki=2.0,
    yaw_lpf_s=0.04,
    att_kp=4.0,
    att_kp_yaw=2.5,
    vel_kp=2.0,
    pos_kp=0.8,
    max_tilt_rad=math.radians(60.0),
    max_rate_rad_s=math.radians(300.0),
    max_yaw_rate_rad_s=math.radians(200.0),
    flip_rate_rad_s=(math.radians(700.0), math.radians(900.0)),
    spin_rate_rad_s=(math.radians(120.0), math.radians(200.0)),
    start_agl_m=(80.0, 150.0),
    # its own IMU/barometer/GPS models (ours are applied to the truth), the disengaged SCAS, whose
    # mixer adds 0.0 to each external command, and the ground contacts (0.15 m below the CG; a flight
    # stops at QuadVehicle.min_agl_m): 40 % of each run(), the flights unchanged
    lean=LeanModel(
        drop=tuple(f'<system file="Sensor{x}.xml"/>' for x in ("Imu", "Baro", "Gps")),
        fcs_file="FlightControl.xml",
        external_commands=tuple((f"fcs/cmd{m}_ext_nd", f"fcs/cmdEsc{m}_nd") for m in ("FR", "AL", "FL", "AR")),
        empty=(('<ground_reactions file="Gear.xml"/>', "Gear.xml"),),
    ),
)

AGILE_QUAD = QuadParams(
    model="agile_quad",
    own_aircraft=True,
    mass_kg=0.8,
    inertia_kg_m2=(0.0030, 0.0032, 0.0055),
    motor_xy_m=((0.08839, 0.08839), (-0.08839, -0.08839), (0.08839, -0.08839), (-0.08839, 0.08839)),
    yaw_sense=(1.0, 1.0, -1.0, -1.0),
    yaw_arm_m=0.016,
    thrust_max_n=9.0,
    cmd_paths=tuple(f"fcs/motor-cmd[{i}]" for i in range(4)),
    cmd_exponent=1.0,
    rpm_paths=(),
    rpm_max=26000.0,
    setup=(),
    rate_kp=30.0,
    rate_kd=0.03,
    rate_ki=5.0,
    yaw_lpf_s=0.0,
    att_kp=8.0,
    att_kp_yaw=4.0,
    vel_kp=2.5,
    pos_kp=1.0,
    max_tilt_rad=math.radians(65.0),
    max_rate_rad_s=math.radians(500.0),
    max_yaw_rate_rad_s=math.radians(500.0),
    flip_rate_rad_s=(math.radians(800.0), math.radians(1200.0)),
    spin_rate_rad_s=(math.radians(300.0), math.radians(600.0)),
    start_agl_m=(60.0, 120.0),
    # its four ground contacts (0.04 m below the CG; a flight stops at QuadVehicle.min_agl_m): 20 % of
    # each run(), the flights unchanged
    lean=LeanModel(empty=(("<ground_reactions>", "<contact"),)),
)


def _mixer_inverse(p: QuadParams) -> list[list[float]]:
    """Inverse of [T, L, M, N] = A @ thrusts for the four motors."""
    rows = [
        [1.0] * 4,
        [-y for _, y in p.motor_xy_m],  # roll: thrust on the right side rolls left
        [x for x, _ in p.motor_xy_m],  # pitch: thrust at the front pitches up
        [s * p.yaw_arm_m for s in p.yaw_sense],
    ]
    inv = np.linalg.inv(np.array(rows))
    return [[float(v) for v in r] for r in inv]


class QuadController:
    """Cascaded controller bound to one FGFDMExec. Maneuvers write the public reference fields."""

    def __init__(self, fdm, p: QuadParams, dt_s: float):
        self.p = p
        self.dt = dt_s
        g = lambda path: getter(fdm, path)  # noqa: E731
        self._phi, self._theta, self._psi = g("attitude/phi-rad"), g("attitude/theta-rad"), g("attitude/psi-rad")
        self._p, self._q, self._r = g("velocities/pi-rad_sec"), g("velocities/qi-rad_sec"), g("velocities/ri-rad_sec")
        self._pd, self._qd = g("accelerations/pidot-rad_sec2"), g("accelerations/qidot-rad_sec2")
        self._vn, self._ve, self._vd = (
            g("velocities/v-north-fps"), g("velocities/v-east-fps"), g("velocities/v-down-fps"))
        self._pn, self._pe = g("position/from-start-neu-n-ft"), g("position/from-start-neu-e-ft")
        self._h = g("position/h-agl-ft")
        self._cmd = tuple(setter(fdm, path) for path in p.cmd_paths)
        self.vmax_h, self.vmax_up, self.vmax_down = 10.0, 6.0, 4.0  # m/s, fixed (packed below)
        self._par = pack_params(p, dt_s, self.vmax_h, self.vmax_up, self.vmax_down, _mixer_inverse(p))
        self._st = np.zeros(4)  # rate-loop integrators (roll, pitch, yaw) and the filtered yaw torque
        self.hover_thrust_n = p.mass_kg * G0
        # reference set by maneuvers
        self.mode = MODE_POS
        self.pos_ref = [0.0, 0.0, 0.0]  # NED from start, m (down = -height above start)
        self.vel_ff = [0.0, 0.0, 0.0]
        self.acc_ff = [0.0, 0.0, 0.0]
        self.yaw_ref = 0.0
        self.yaw_rate_ff = 0.0
        self.q_ref = (1.0, 0.0, 0.0, 0.0)
        self.rate_ref = [0.0, 0.0, 0.0]
        self.thrust_n = self.hover_thrust_n
        self.max_tilt = p.max_tilt_rad
        self.max_acc_h = G0 * math.tan(p.max_tilt_rad)
        # state exposed to maneuvers (attitude and rates every update, position in position mode)
        self.q = (1.0, 0.0, 0.0, 0.0)
        self.w = (0.0, 0.0, 0.0)
        self.pos = [0.0, 0.0, 0.0]
        self.vel = [0.0, 0.0, 0.0]
        self.agl_m = 0.0
        self.start_agl_m = 0.0

    def setup(self, fdm) -> None:
        for path, value in self.p.setup:
            fdm[path] = value
        self._write_motors(0.0, 0.0, 0.0, 0.0)
        self.start_agl_m = self._h() * FT_TO_M
        self.yaw_ref = self._psi()
        self.hold_here()

    # -------------------------------------------------------------- helpers for maneuvers
    def read_state(self) -> None:
        self.q = quat_from_euler_zyx_f(self._phi(), self._theta(), self._psi())
        self.w = (self._p(), self._q(), self._r())
        h = self._h() * FT_TO_M
        self.agl_m = h
        self.pos = [self._pn() * FT_TO_M, self._pe() * FT_TO_M, self.start_agl_m - h]
        self.vel = [self._vn() * FT_TO_M, self._ve() * FT_TO_M, self._vd() * FT_TO_M]

    def hold_here(self) -> None:
        """Position mode: stop and hold the current position and heading."""
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
        """Angle between body z and earth down, rad."""
        c = gravity_body_f(self.q)[2]
        return math.acos(max(-1.0, min(1.0, c)))

    def level_quat(self, yaw: float) -> tuple[float, float, float, float]:
        return (math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw))

    # -------------------------------------------------------------- control
    def step(self, state: tuple | None = None) -> None:
        """One control update: read the state, run the compiled laws for the mode, write the motors.

        The laws are :mod:`tepinn_flight.sim.quad_control_law`; this method only moves floats
        between JSBSim, the references the maneuvers wrote and the compiled code (about 2 us).
        ``state``: the values :func:`~tepinn_flight.sim.flight.fly` read after the last ``run()``
        (:data:`~tepinn_flight.sim.flight.STATE_PATHS`), the same numbers this would read; None:
        read here.
        """
        if state is None:
            phi, theta, psi = self._phi(), self._theta(), self._psi()
            wp, wq, wr = self._p(), self._q(), self._r()
            h_ft = None
        else:
            phi, theta, psi, wp, wq, wr, h_ft, vn, ve, vd = state
        pd, qd = self._pd(), self._qd()
        mode = self.mode
        if mode == MODE_POS:
            if h_ft is None:
                h_ft, vn, ve, vd = self._h(), self._vn(), self._ve(), self._vd()
            h = h_ft * FT_TO_M
            self.agl_m = h
            pos = self.pos = [self._pn() * FT_TO_M, self._pe() * FT_TO_M, self.start_agl_m - h]
            vel = self.vel = [vn * FT_TO_M, ve * FT_TO_M, vd * FT_TO_M]
            pr, vf, af = self.pos_ref, self.vel_ff, self.acc_ff
            qw, qx, qy, qz, self.yaw_ref, c0, c1, c2, c3 = position_step(self._par, self._st, (
                phi, theta, psi, wp, wq, wr, pd, qd, pos[0], pos[1], pos[2], vel[0], vel[1], vel[2],
                pr[0], pr[1], pr[2], vf[0], vf[1], vf[2], af[0], af[1], af[2], self.yaw_ref, self.yaw_rate_ff))
        elif mode == MODE_ATT:
            rw, rx, ry, rz = self.q_ref
            qw, qx, qy, qz, c0, c1, c2, c3 = attitude_step(self._par, self._st, (
                phi, theta, psi, wp, wq, wr, pd, qd, rw, rx, ry, rz, self.yaw_rate_ff, self.thrust_n))
        else:
            rp, rq, rr = self.rate_ref
            qw, qx, qy, qz, c0, c1, c2, c3 = rate_step(self._par, self._st, (
                phi, theta, psi, wp, wq, wr, pd, qd, rp, rq, rr, self.thrust_n))
        self.q = (qw, qx, qy, qz)
        self.w = (wp, wq, wr)
        self._write_motors(c0, c1, c2, c3)

    def _write_motors(self, c0: float, c1: float, c2: float, c3: float) -> None:
        """Normalised commands of motors FR, AL, FL, AR to JSBSim."""
        s0, s1, s2, s3 = self._cmd
        s0(c0)
        s1(c1)
        s2(c2)
        s3(c3)


class QuadVehicle:
    """A quad in JSBSim plus our controller; what :func:`tepinn_flight.sim.flight.fly` needs."""

    vehicle_type = "multirotor"
    control_hz = 200.0

    def __init__(self, params: QuadParams):
        self.p = params
        self.model = params.model
        self.own_aircraft = params.own_aircraft
        self.lean = params.lean
        self.min_agl_m = 2.0  # the flight stops here (the lean models have no ground contacts: keep it >= 0.5 m)
        self.ctl: QuadController | None = None

    @property
    def log_paths(self) -> tuple[str, ...]:
        """Extra properties logged every step (rotor speed, for the vibration model)."""
        if self.p.rpm_paths:
            return self.p.rpm_paths
        return tuple(f"fcs/motor-out[{i}]" for i in range(4))

    def rotor_hz(self, logged):
        """(N, 4) rotor frequency in Hz from the logged extra columns."""
        x = np.asarray(logged, dtype=float)
        if self.p.rpm_paths:
            return np.abs(x) / 60.0
        return self.p.rpm_max / 60.0 * np.sqrt(np.clip(x, 0.0, 1.0))

    def start(self, fdm, site: dict, rng, dt_s: float) -> QuadController:
        lo, hi = self.p.start_agl_m
        fdm["ic/lat-geod-deg"] = site["lat_deg"]  # P2: position first, then altitude, then speed
        fdm["ic/long-gc-deg"] = site["lon_deg"]
        fdm["ic/terrain-elevation-ft"] = site["elevation_m"] / FT_TO_M
        fdm["ic/h-agl-ft"] = float(rng.uniform(lo, hi)) / FT_TO_M
        fdm["ic/u-fps"] = 0.0
        fdm["ic/v-fps"] = 0.0
        fdm["ic/w-fps"] = 0.0
        fdm["ic/psi-true-deg"] = float(rng.uniform(0.0, 360.0))
        fdm["ic/phi-deg"] = 0.0
        fdm["ic/theta-deg"] = 0.0
        fdm.run_ic()
        fdm.get_propulsion().init_running(-1)
        ctl = QuadController(fdm, self.p, dt_s)
        ctl.setup(fdm)
        self.ctl = ctl
        return ctl
