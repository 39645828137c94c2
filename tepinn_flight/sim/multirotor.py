"""Multirotor vehicles and our own cascaded flight controller (position -> attitude -> rate -> mixer).

The controller runs at ``QuadVehicle.control_hz`` (200 Hz), its laws compiled with numba in
:mod:`tepinn_flight.sim.quad_control_law`, and bypasses any controller inside the JSBSim
model (the F450's rate SCAS limits rates to 43 deg/s; we switch it off and drive the ESC inputs
``fcs/cmd*_ext_nd`` directly), so the vehicle can flip and roll at more than 600 deg/s.

The maneuvers write the controller's reference vector and read its observation vector (the layouts:
:mod:`tepinn_flight.sim.quad_control_law`; the fields are also properties here). Where JSBSim's C++ can
be called from compiled code, the flight's control updates, its maneuvers' laws and JSBSim's steps run
in one compiled loop (:meth:`QuadController.native_runner`, :mod:`tepinn_flight.sim.quad_flight_kernel`)
and Python acts only where a maneuver ends or draws; elsewhere :meth:`QuadController.step` runs the
same laws once per update from Python.

Frames: body FRD, earth NED; motor order FR, AL, FL, AR for both quads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tepinn_flight.quat import quat_from_euler_zyx_f
from tepinn_flight.sim.jsbsim_env import FT_TO_M, getter, setter
from tepinn_flight.sim.lean_model import LeanModel
from tepinn_flight.sim.flight import STATE_PATHS
from tepinn_flight.sim.quad_control_law import (G0, HOVER_N, MODE_POS, N_OBS, N_REF, OBS_AGL, OBS_POS, OBS_Q, OBS_VEL,
                                                OBS_W, REF_ACC_FF, REF_MODE, REF_POS, REF_Q, REF_RATE, REF_THRUST,
                                                REF_VEL_FF, REF_YAW, REF_YAW_RATE_FF, control_update,
                                                pack_params)  # fmt: skip


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


def _vector(array: str, at: int, n: int) -> property:
    """A field of n floats in one of the controller's vectors: read as a view (item writes go through),
    assigned from any sequence."""

    def get(self):
        return getattr(self, array)[at : at + n]

    def put(self, value) -> None:
        getattr(self, array)[at : at + n] = value

    return property(get, put)


def _scalar(array: str, at: int, kind=float) -> property:
    def get(self):
        return kind(getattr(self, array)[at])

    def put(self, value) -> None:
        getattr(self, array)[at] = value

    return property(get, put)


#: the properties the compiled loop reads: fly()'s state (its STATE_PATHS, in that order), then roll and pitch
#: acceleration and the position north and east from the start (quad_flight_kernel's C_* layout)
NATIVE_READS = (*STATE_PATHS, "accelerations/pidot-rad_sec2", "accelerations/qidot-rad_sec2",
                "position/from-start-neu-n-ft", "position/from-start-neu-e-ft")  # fmt: skip


class QuadController:
    """Cascaded controller bound to one FGFDMExec. Maneuvers write the reference fields (``ref``) and read
    the observed ones (``obs``)."""

    # the reference the maneuvers write (quad_control_law's REF_* layout)
    mode = _scalar("ref", REF_MODE, int)
    pos_ref = _vector("ref", REF_POS, 3)  # NED from start, m (down = -height above start)
    vel_ff = _vector("ref", REF_VEL_FF, 3)
    acc_ff = _vector("ref", REF_ACC_FF, 3)
    yaw_ref = _scalar("ref", REF_YAW)
    yaw_rate_ff = _scalar("ref", REF_YAW_RATE_FF)
    q_ref = _vector("ref", REF_Q, 4)
    rate_ref = _vector("ref", REF_RATE, 3)
    thrust_n = _scalar("ref", REF_THRUST)
    # the state the maneuvers read: attitude and rates every update, position in position mode (OBS_*)
    q = _vector("obs", OBS_Q, 4)
    w = _vector("obs", OBS_W, 3)
    pos = _vector("obs", OBS_POS, 3)
    vel = _vector("obs", OBS_VEL, 3)
    agl_m = _scalar("obs", OBS_AGL)

    def __init__(self, fdm, p: QuadParams, dt_s: float):
        self.p = p
        self.dt = dt_s
        g = lambda path: getter(fdm, path)  # noqa: E731
        (self._phi, self._theta, self._psi, self._p, self._q, self._r, self._h, self._vn, self._ve, self._vd,
         self._pd, self._qd, self._pn, self._pe) = (g(path) for path in NATIVE_READS)  # fmt: skip
        self._cmd = tuple(setter(fdm, path) for path in p.cmd_paths)
        self.vmax_h, self.vmax_up, self.vmax_down = 10.0, 6.0, 4.0  # m/s, fixed (packed below)
        self.par = pack_params(p, dt_s, self.vmax_h, self.vmax_up, self.vmax_down, _mixer_inverse(p))
        self._st = np.zeros(4)  # rate-loop integrators (roll, pitch, yaw) and the filtered yaw torque
        self.ref = np.zeros(N_REF)
        self.obs = np.zeros(N_OBS)
        self.mode = MODE_POS
        self.q_ref = (1.0, 0.0, 0.0, 0.0)
        self.thrust_n = self.par[HOVER_N]
        self.q = (1.0, 0.0, 0.0, 0.0)
        self.max_acc_h = G0 * math.tan(p.max_tilt_rad)
        self.start_agl_m = 0.0

    @property
    def native_paths(self) -> tuple[str, ...]:
        """What the compiled loop reads and writes (:data:`NATIVE_READS`, then the motor commands)."""
        return (*NATIVE_READS, *self.p.cmd_paths)

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
        self.pos = (self._pn() * FT_TO_M, self._pe() * FT_TO_M, self.start_agl_m - h)
        self.vel = (self._vn() * FT_TO_M, self._ve() * FT_TO_M, self._vd() * FT_TO_M)

    def hold_here(self) -> None:
        """Position mode: stop and hold the current position and heading."""
        self.read_state()
        self.mode = MODE_POS
        self.pos_ref = self.pos
        self.vel_ff = (0.0, 0.0, 0.0)
        self.acc_ff = (0.0, 0.0, 0.0)
        self.yaw_ref = self.heading()
        self.yaw_rate_ff = 0.0

    def heading(self) -> float:
        w, x, y, z = self.q.tolist()
        return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))

    # -------------------------------------------------------------- control
    def step(self, state: tuple | None = None) -> None:
        """One control update from Python: read the state, run the compiled laws for the mode, write the motors.

        The laws are :mod:`tepinn_flight.sim.quad_control_law`'s :func:`control_update`; this method only
        moves floats between JSBSim and the compiled code. ``state``: the values
        :func:`~tepinn_flight.sim.flight.fly` read after the last ``run()``
        (:data:`~tepinn_flight.sim.flight.STATE_PATHS`), the same numbers this would read; None: read here.
        """
        if state is None:
            state = (self._phi(), self._theta(), self._psi(), self._p(), self._q(), self._r(), self._h(), self._vn(),
                     self._ve(), self._vd())  # fmt: skip
        phi, theta, psi, wp, wq, wr, h_ft, vn, ve, vd = state
        c0, c1, c2, c3 = control_update(self.par, self._st, self.ref, self.obs, self.start_agl_m, phi, theta, psi,
                                        wp, wq, wr, self._pd(), self._qd(), h_ft, vn, ve, vd, self._pn(),
                                        self._pe())  # fmt: skip
        self._write_motors(c0, c1, c2, c3)

    def native_runner(self, steps, n_sim: int, div: int, dt_sim: float):
        """Where ``steps`` (a :class:`~tepinn_flight.sim.jsbsim_native.Stepper` made with
        :attr:`native_paths` as its extra paths) calls JSBSim natively: ``run(i, skip_first, maneuver_vector)
        -> (i, code)``, the compiled loop of the flight's steps below ``n_sim`` with a control update every
        ``div`` (:func:`~tepinn_flight.sim.quad_flight_kernel.fly_quad`); else None."""
        if not steps.native:
            return None
        from tepinn_flight.sim.quad_flight_kernel import fly_quad

        ctx, rows, state = steps.kernel_args
        cctx = np.array([steps.handles.set_fn, *steps.extra_ptrs], dtype=np.int64)
        floor, par, st, ref, obs = steps.min_agl_ft, self.par, self._st, self.ref, self.obs

        def run(i: int, skip_first: bool, man: np.ndarray) -> tuple[int, int]:
            return fly_quad(ctx, cctx, i, n_sim, div, dt_sim, floor, self.start_agl_m, skip_first, par, st, ref, obs,
                            man, rows, state)  # fmt: skip

        return run

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
