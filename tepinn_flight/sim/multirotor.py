"""Multirotor vehicles and our own cascaded flight controller (position -> attitude -> rate -> mixer).

The controller runs in Python (at ``QuadVehicle.control_hz``, 200 Hz) and bypasses any controller inside the JSBSim
model (the F450's rate SCAS limits rates to 43 deg/s; we switch it off and drive the ESC inputs
``fcs/cmd*_ext_nd`` directly), so the vehicle can flip and roll at more than 600 deg/s.

Per-step code is plain Python on floats (no numpy, no dict building): it is the speed-critical path.
Frames: body FRD, earth NED; motor order FR, AL, FL, AR for both quads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tepinn_flight.quat import gravity_body_f, quat_from_euler_zyx_f
from tepinn_flight.sim.jsbsim_env import FT_TO_M, getter, setter

G0 = 9.80665
_sin, _cos, _sqrt = math.sin, math.cos, math.sqrt

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
        self._pd, self._qd, self._rd = (
            g("accelerations/pidot-rad_sec2"),
            g("accelerations/qidot-rad_sec2"),
            g("accelerations/ridot-rad_sec2"),
        )
        self._vn, self._ve, self._vd = (
            g("velocities/v-north-fps"), g("velocities/v-east-fps"), g("velocities/v-down-fps"))
        self._pn, self._pe = g("position/from-start-neu-n-ft"), g("position/from-start-neu-e-ft")
        self._h = g("position/h-agl-ft")
        self._cmd = [setter(fdm, path) for path in p.cmd_paths]
        self._minv = tuple(tuple(r) for r in _mixer_inverse(p))
        self._tmax = p.thrust_max_n
        self._inv_tmax = 1.0 / p.thrust_max_n
        self._cmd_ex = 1.0 / p.cmd_exponent
        self.vmax_h, self.vmax_up, self.vmax_down = 10.0, 6.0, 4.0
        self._ixx, self._iyy, self._izz = p.inertia_kg_m2
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
        # integrators
        self._ip = self._iq = self._ir = 0.0
        self._tn_f = 0.0
        self._yaw_a = dt_s / (p.yaw_lpf_s + dt_s)
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
        for c in self._cmd:
            c(0.0)
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
    def _attitude_from_thrust(self, tn, te, td, yaw):
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
        # rotation matrix columns x_b, y_b, z_b -> quaternion (Shepperd)
        m00, m01, m02 = xx, yx, zx
        m10, m11, m12 = xy, yy, zy
        m20, m21, m22 = xz, yz, zz
        tr = m00 + m11 + m22
        if tr > 0.0:
            s = 2.0 * math.sqrt(tr + 1.0)
            return (0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s)
        if m00 > m11 and m00 > m22:
            s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
            return ((m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s)
        if m11 > m22:
            s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
            return ((m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s)
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        return ((m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s)

    def step(self) -> None:
        """One control update at the simulation rate: read state, compute, write motor commands.

        Written for speed (about 8 us): locals only, no containers built, no builtin min/max.
        """
        p = self.p
        phi, theta, psi = self._phi(), self._theta(), self._psi()
        cr, sr = _cos(0.5 * phi), _sin(0.5 * phi)
        cp, sp = _cos(0.5 * theta), _sin(0.5 * theta)
        cy, sy = _cos(0.5 * psi), _sin(0.5 * psi)
        qw = cr * cp * cy + sr * sp * sy
        qx = sr * cp * cy - cr * sp * sy
        qy = cr * sp * cy + sr * cp * sy
        qz = cr * cp * sy - sr * sp * cy
        self.q = (qw, qx, qy, qz)
        wp, wq, wr = self._p(), self._q(), self._r()
        self.w = (wp, wq, wr)
        mode = self.mode
        if mode == MODE_POS:
            h = self._h() * FT_TO_M
            self.agl_m = h
            pos = self.pos = [self._pn() * FT_TO_M, self._pe() * FT_TO_M, self.start_agl_m - h]
            vel = self.vel = [self._vn() * FT_TO_M, self._ve() * FT_TO_M, self._vd() * FT_TO_M]
            pr, vf, af = self.pos_ref, self.vel_ff, self.acc_ff
            kp, kv, vmax = p.pos_kp, p.vel_kp, self.vmax_h
            # velocity command: feed-forward + position error, limited
            cn = vf[0] + kp * (pr[0] - pos[0])
            ce = vf[1] + kp * (pr[1] - pos[1])
            cd = vf[2] + kp * (pr[2] - pos[2])
            ch = _sqrt(cn * cn + ce * ce)
            if ch > vmax:
                cn, ce = cn * vmax / ch, ce * vmax / ch
            cd = -self.vmax_up if cd < -self.vmax_up else (self.vmax_down if cd > self.vmax_down else cd)
            an = af[0] + kv * (cn - vel[0])
            ae = af[1] + kv * (ce - vel[1])
            ad = af[2] + kv * (cd - vel[2])
            ah = _sqrt(an * an + ae * ae)
            amax = self.max_acc_h
            if ah > amax:
                an, ae = an * amax / ah, ae * amax / ah
            ad = -1.2 * G0 if ad < -1.2 * G0 else (0.7 * G0 if ad > 0.7 * G0 else ad)
            m = p.mass_kg
            tn, te, td = m * an, m * ae, m * (ad - G0)
            rw, rx, ry, rz = self._attitude_from_thrust(tn, te, td, self.yaw_ref)
            # collective: thrust vector projected on the current body -z axis
            thrust = -(tn * 2.0 * (qx * qz + qw * qy) + te * 2.0 * (qy * qz - qw * qx)
                       + td * (1.0 - 2.0 * (qx * qx + qy * qy)))
            tmin = 0.15 * self.hover_thrust_n
            if thrust < tmin:
                thrust = tmin
            self.yaw_ref += self.yaw_rate_ff * self.dt
            use_att = True
        elif mode == MODE_ATT:
            rw, rx, ry, rz = self.q_ref
            thrust = self.thrust_n
            use_att = True
        else:
            thrust = self.thrust_n
            use_att = False
        if use_att:
            # q_e = conj(q) * q_ref -> rate reference ~ gain * rotation vector of the error
            ew = qw * rw + qx * rx + qy * ry + qz * rz
            sg = 2.0 if ew >= 0.0 else -2.0
            lim, limz = p.max_rate_rad_s, p.max_yaw_rate_rad_s
            ka = p.att_kp * sg
            pr_ = ka * (qw * rx - qx * rw - qy * rz + qz * ry)
            qr_ = ka * (qw * ry + qx * rz - qy * rw - qz * rx)
            rr_ = p.att_kp_yaw * sg * (qw * rz - qx * ry + qy * rx - qz * rw) + self.yaw_rate_ff
            pr_ = -lim if pr_ < -lim else (lim if pr_ > lim else pr_)
            qr_ = -lim if qr_ < -lim else (lim if qr_ > lim else qr_)
            rr_ = -limz if rr_ < -limz else (limz if rr_ > limz else rr_)
        else:
            pr_, qr_, rr_ = self.rate_ref
        # rate loop (PI + damping on measured angular acceleration), torques in N*m
        kp, kd, ki, dt = p.rate_kp, p.rate_kd, p.rate_ki, self.dt
        e_p, e_q, e_r = pr_ - wp, qr_ - wq, rr_ - wr
        ip, iq, ir = self._ip + e_p * dt, self._iq + e_q * dt, self._ir + e_r * dt
        self._ip = -2.0 if ip < -2.0 else (2.0 if ip > 2.0 else ip)
        self._iq = -2.0 if iq < -2.0 else (2.0 if iq > 2.0 else iq)
        self._ir = -2.0 if ir < -2.0 else (2.0 if ir > 2.0 else ir)
        ixx, iyy, izz = self._ixx, self._iyy, self._izz
        tl = ixx * (kp * e_p + ki * self._ip - kd * kp * self._pd()) + (izz - iyy) * wq * wr
        tm = iyy * (kp * e_q + ki * self._iq - kd * kp * self._qd()) + (ixx - izz) * wp * wr
        tnf = self._tn_f + self._yaw_a * (izz * (kp * e_r + ki * self._ir) - self._tn_f)
        self._tn_f = tnf
        self._mix(thrust, tl, tm, tnf)

    def _mix(self, thrust: float, tl: float, tm: float, tn: float) -> None:
        """Motor thrusts from collective and torques; roll/pitch first, yaw within the headroom."""
        (a0, b0, c0, d0), (a1, b1, c1, d1), (a2, b2, c2, d2), (a3, b3, c3, d3) = self._minv
        tmax = self._tmax
        f0 = a0 * thrust + b0 * tl + c0 * tm
        f1 = a1 * thrust + b1 * tl + c1 * tm
        f2 = a2 * thrust + b2 * tl + c2 * tm
        f3 = a3 * thrust + b3 * tl + c3 * tm
        hi = f0 if f0 > f1 else f1
        hi = hi if hi > f2 else f2
        hi = hi if hi > f3 else f3
        lo = f0 if f0 < f1 else f1
        lo = lo if lo < f2 else f2
        lo = lo if lo < f3 else f3
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
        y0, y1, y2, y3 = d0 * tn, d1 * tn, d2 * tn, d3 * tn
        ymax = y0 if y0 > -y0 else -y0  # symmetric quad: |d_i| are equal
        if ymax > 0.0:
            room = tmax - hi if tmax - hi < lo else lo
            if ymax > room:
                k = room / ymax if room > 0.0 else 0.0
                y0, y1, y2, y3 = y0 * k, y1 * k, y2 * k, y3 * k
            f0, f1, f2, f3 = f0 + y0, f1 + y1, f2 + y2, f3 + y3
        ex, c = self._cmd_ex, self._cmd
        it = self._inv_tmax
        for i, v in ((0, f0), (1, f1), (2, f2), (3, f3)):
            v *= it
            c[i](0.0 if v <= 0.0 else (1.0 if v >= 1.0 else (v if ex == 1.0 else v**ex)))


class QuadVehicle:
    """A quad in JSBSim plus our controller; what :func:`tepinn_flight.sim.flight.fly` needs."""

    vehicle_type = "multirotor"
    control_hz = 200.0

    def __init__(self, params: QuadParams):
        self.p = params
        self.model = params.model
        self.own_aircraft = params.own_aircraft
        self.min_agl_m = 2.0
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
