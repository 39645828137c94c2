"""Pure encoders of every MAVLink 2 message the bridge and the emulator send.

Each ``*_msg`` function maps values in our conventions (``q_nb_wxyz`` body FRD → NED, rad, rad/s,
m/s², µT, s) to one pymavlink message object; :class:`Encoder` packs messages into frames with a
given system/component id and a running sequence number. No sockets here: the tests pack with
:class:`Encoder` and decode with pymavlink's own parser.

What the bridge sends, from (autopilot sysid, 191 = ``MAV_COMP_ID_ONBOARD_COMPUTER``):

=====================  =================================================================================
HEARTBEAT              ``MAV_TYPE_ONBOARD_CONTROLLER``, ``MAV_AUTOPILOT_INVALID``, ``MAV_STATE_ACTIVE``, 1 Hz
the estimate           one of (``--estimate-as``, :func:`estimate_msgs`; ``time_boot_ms`` = the autopilot's
                       time of the IMU sample it belongs to): NAMED_VALUE_FLOAT ``tp_roll/tp_pitch/tp_yaw``
                       (deg, the default), DEBUG_VECT ``TP_RPY`` (deg), or ATTITUDE (Z-Y-X, rad; rates =
                       gyro − estimated bias) plus ATTITUDE_QUATERNION (q1..q4 = w, x, y, z)
NAMED_VALUE_FLOAT      diagnostics (names ≤ 10 characters, see :data:`DIAG_NAMES`)
DEBUG_VECT             ``TP_RPY`` estimate roll/pitch/yaw (deg; here only when it is not the estimate), ``TP_DIFF`` estimate − EKF roll/pitch (deg)
                       and the inclination difference (deg), ``TP_BIAS`` gyro bias (rad/s)
COMMAND_LONG           ``MAV_CMD_SET_MESSAGE_INTERVAL`` asking the autopilot for an IMU stream
=====================  =================================================================================

The emulator (``replay``) sends, as an autopilot (sysid 1, compid 1): HEARTBEAT, HIGHRES_IMU or
SCALED_IMU, ATTITUDE and ATTITUDE_QUATERNION.
"""

from __future__ import annotations

import math

from ..conventions import GRAVITY_M_S2
from . import MAV_COMP_ID_ONBOARD_COMPUTER, dialect

#: NAMED_VALUE_FLOAT diagnostics: name → meaning (all ≤ 10 characters, the field's size).
DIAG_NAMES = {
    "tp_dincl": "inclination difference TE-PINN vs autopilot EKF, deg (heading is relative in 6-D)",
    "tp_dhead": "heading difference TE-PINN vs autopilot EKF, deg (absolute in 9-D; in 6-D only its drift means something)",
    "tp_sigma": "TE-PINN tilt uncertainty σ, deg",
    "tp_lat_ms": "latency IMU message in → estimate out (wall clock), ms",
    "tp_imu_hz": "IMU messages per second received from the autopilot",
}

_HIGHRES_ACC_GYRO = 0x003F
_HIGHRES_MAG = 0x01C0


class Encoder:
    """Packs messages as one MAVLink 2 source (sysid, compid) with its own sequence counter."""

    def __init__(self, sysid: int, compid: int = MAV_COMP_ID_ONBOARD_COMPUTER):
        if not (1 <= int(sysid) <= 255 and 0 <= int(compid) <= 255):
            raise ValueError(f"bad MAVLink source {sysid}/{compid}")
        self.m = dialect()
        self.mav = self.m.MAVLink(None, srcSystem=int(sysid), srcComponent=int(compid))
        self.sysid = int(sysid)
        self.compid = int(compid)

    def pack(self, msg) -> bytes:
        buf = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256  # pack() does not advance the sequence (send() would)
        return bytes(buf)


def _name(name: str) -> bytes:
    b = name.encode("ascii")
    if len(b) > 10:
        raise ValueError(f"MAVLink debug names hold 10 characters: {name!r}")
    return b


def euler_zyx(q_nb_wxyz) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in rad of a unit quaternion (scalar math, Z-Y-X as in ``quat.py``)."""
    w, x, y, z = (float(v) for v in q_nb_wxyz)
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def _u32(v: int) -> int:
    return int(v) & 0xFFFFFFFF


# ---------------------------------------------------------------------------- bridge (compid 191)
def heartbeat_onboard_msg():
    m = dialect()
    return m.MAVLink_heartbeat_message(
        m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID, 0, 0, m.MAV_STATE_ACTIVE, 3
    )


def attitude_msg(time_boot_ms: int, q_nb_wxyz, rates_rad_s=(0.0, 0.0, 0.0)):
    roll, pitch, yaw = euler_zyx(q_nb_wxyz)
    r = [float(v) for v in rates_rad_s]
    return dialect().MAVLink_attitude_message(_u32(time_boot_ms), roll, pitch, yaw, r[0], r[1], r[2])


def attitude_quaternion_msg(time_boot_ms: int, q_nb_wxyz, rates_rad_s=(0.0, 0.0, 0.0)):
    q = [float(v) for v in q_nb_wxyz]
    r = [float(v) for v in rates_rad_s]
    return dialect().MAVLink_attitude_quaternion_message(
        _u32(time_boot_ms), q[0], q[1], q[2], q[3], r[0], r[1], r[2], [0.0, 0.0, 0.0, 0.0]
    )


def named_value_float_msg(time_boot_ms: int, name: str, value: float):
    return dialect().MAVLink_named_value_float_message(_u32(time_boot_ms), _name(name), float(value))


def debug_vect_msg(name: str, time_usec: int, x: float, y: float, z: float):
    return dialect().MAVLink_debug_vect_message(_name(name), int(time_usec), float(x), float(y), float(z))


def set_message_interval_msg(target_system: int, target_component: int, message_id: int, rate_hz: float):
    """COMMAND_LONG ``MAV_CMD_SET_MESSAGE_INTERVAL``: param1 = message id, param2 = interval in µs."""
    m = dialect()
    interval_us = float(round(1e6 / rate_hz)) if rate_hz > 0 else -1.0
    return m.MAVLink_command_long_message(
        int(target_system), int(target_component), m.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
        float(message_id), interval_us, 0.0, 0.0, 0.0, 0.0, 0.0,
    )  # fmt: skip


def param_request_read_msg(target_system: int, target_component: int, name: str):
    """PARAM_REQUEST_READ of one parameter by name (param_index −1)."""
    return dialect().MAVLink_param_request_read_message(int(target_system), int(target_component), name.encode(), -1)


#: How the estimate itself can be sent (``bridge --estimate-as``; see :func:`estimate_msgs`).
ESTIMATE_AS = ("named_value", "debug_vect", "attitude_quaternion")
#: The default never drives a ground station's HUD: QGroundControl versions that accept ATTITUDE /
#: ATTITUDE_QUATERNION from any component of the vehicle's system may flip the HUD between the
#: autopilot and us; NAMED_VALUE_FLOAT is only ever shown as a named value (QGC's MAVLink
#: Inspector; Mission Planner's Quick/Status view with its ``propagateNamedFloats`` option).
DEFAULT_ESTIMATE_AS = "named_value"
#: NAMED_VALUE_FLOAT names of ``named_value`` (degrees, Z-Y-X Euler angles of the estimate).
ESTIMATE_VALUE_NAMES = ("tp_roll", "tp_pitch", "tp_yaw")
#: DEBUG_VECT name of ``debug_vect`` (x, y, z = roll, pitch, yaw in degrees).
ESTIMATE_VECT_NAME = "TP_RPY"


def estimate_msgs(time_boot_ms: int, q_nb_wxyz, rates_rad_s, kind: str = "attitude_quaternion",
                  time_usec: int | None = None) -> list:  # fmt: skip
    """The messages that carry one estimate, by ``kind`` (one of :data:`ESTIMATE_AS`):

    ``attitude_quaternion``  ATTITUDE (rad) and ATTITUDE_QUATERNION (w, x, y, z), the standard pair
    ``named_value``          NAMED_VALUE_FLOAT ``tp_roll``, ``tp_pitch``, ``tp_yaw`` (deg)
    ``debug_vect``           DEBUG_VECT ``TP_RPY``: x, y, z = roll, pitch, yaw (deg)

    ``time_usec`` (DEBUG_VECT) defaults to ``time_boot_ms`` × 1000.
    """
    if kind == "attitude_quaternion":
        return [attitude_msg(time_boot_ms, q_nb_wxyz, rates_rad_s),
                attitude_quaternion_msg(time_boot_ms, q_nb_wxyz, rates_rad_s)]  # fmt: skip
    rpy = [math.degrees(a) for a in euler_zyx(q_nb_wxyz)]
    if kind == "named_value":
        return [named_value_float_msg(time_boot_ms, n, v) for n, v in zip(ESTIMATE_VALUE_NAMES, rpy)]
    if kind == "debug_vect":
        us = int(time_usec) if time_usec is not None else int(time_boot_ms) * 1000
        return [debug_vect_msg(ESTIMATE_VECT_NAME, us, *rpy)]
    raise ValueError(f"estimate kind must be one of {', '.join(ESTIMATE_AS)}, not {kind!r}")


def diagnostic_msgs(time_boot_ms: int, time_usec: int, q_nb_wxyz, *, sigma_rad: float, latency_s: float,
                    imu_rate_hz: float, bias_rad_s, diff=None, rpy: bool = True) -> list:  # fmt: skip
    """NAMED_VALUE_FLOATs and DEBUG_VECTs of one estimate. ``diff`` = (droll, dpitch, dincl[, dheading]) in rad or None;
    ``rpy=False`` leaves out ``TP_RPY`` (when the estimate itself is sent as that DEBUG_VECT)."""
    roll, pitch, yaw = euler_zyx(q_nb_wxyz)
    d = math.degrees
    out = [
        named_value_float_msg(time_boot_ms, "tp_sigma", d(sigma_rad) if math.isfinite(sigma_rad) else float("nan")),
        named_value_float_msg(time_boot_ms, "tp_lat_ms", latency_s * 1e3),
        named_value_float_msg(time_boot_ms, "tp_imu_hz", imu_rate_hz),
        debug_vect_msg("TP_BIAS", time_usec, *bias_rad_s),
    ]
    if rpy:
        out.insert(3, debug_vect_msg(ESTIMATE_VECT_NAME, time_usec, d(roll), d(pitch), d(yaw)))
    if diff is not None:
        out.insert(0, named_value_float_msg(time_boot_ms, "tp_dincl", d(diff[2])))
        if len(diff) > 3:
            out.insert(1, named_value_float_msg(time_boot_ms, "tp_dhead", d(diff[3])))
        out.append(debug_vect_msg("TP_DIFF", time_usec, d(diff[0]), d(diff[1]), d(diff[2])))
    return out


# ---------------------------------------------------------------------------- emulator (compid 1)
def heartbeat_autopilot_msg(mav_type: int, autopilot: int):
    m = dialect()
    base = m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | m.MAV_MODE_FLAG_SAFETY_ARMED
    return m.MAVLink_heartbeat_message(int(mav_type), int(autopilot), base, 0, m.MAV_STATE_ACTIVE, 3)


def highres_imu_msg(time_usec: int, gyr_rad_s, acc_m_s2, mag_ut=None, temperature_c: float = 25.0):
    """HIGHRES_IMU: m/s², rad/s, gauss (µT / 100); ``fields_updated`` says which are valid."""
    a = [float(v) for v in acc_m_s2]
    g = [float(v) for v in gyr_rad_s]
    flags = _HIGHRES_ACC_GYRO
    mg = [0.0, 0.0, 0.0]
    if mag_ut is not None and all(math.isfinite(float(v)) for v in mag_ut):
        mg = [float(v) / 100.0 for v in mag_ut]
        flags |= _HIGHRES_MAG
    return dialect().MAVLink_highres_imu_message(
        int(time_usec), a[0], a[1], a[2], g[0], g[1], g[2], mg[0], mg[1], mg[2],
        0.0, 0.0, 0.0, float(temperature_c), flags, 0,
    )  # fmt: skip


def _i16(v: float) -> int:
    if not math.isfinite(v):
        return 0
    return int(max(-32768, min(32767, round(v))))


def scaled_imu_msg(time_boot_ms: int, gyr_rad_s, acc_m_s2, mag_ut=None, temperature_c: float = 25.0):
    """SCALED_IMU: int16 mG, mrad/s, mGauss (saturating), temperature in cdegC."""
    a = [_i16(float(v) * 1000.0 / GRAVITY_M_S2) for v in acc_m_s2]
    g = [_i16(float(v) * 1000.0) for v in gyr_rad_s]
    mg = [0, 0, 0]
    if mag_ut is not None and all(math.isfinite(float(v)) for v in mag_ut):
        mg = [_i16(float(v) * 10.0) for v in mag_ut]
    return dialect().MAVLink_scaled_imu_message(
        _u32(time_boot_ms), a[0], a[1], a[2], g[0], g[1], g[2], mg[0], mg[1], mg[2], _i16(temperature_c * 100)
    )
