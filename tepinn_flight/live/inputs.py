"""Pure decoders of what the bridge reads, the live EKF-vs-estimate comparison, and the bridge's
own estimate read back from its messages (:class:`EstimateDecoder`, for the emulator's view).

IMU messages and their units follow the tlog reader (:mod:`tepinn_flight.ingest.tlog`): the same
message table (``IMU_MESSAGES``: time field and instance), the same preference
(``IMU_PREFERENCE``: HIGHRES_IMU, RAW_IMU, SCALED_IMU*) and the same unit rules:

* ``HIGHRES_IMU``: m/s², rad/s, gauss (any autopilot); ``fields_updated`` must mark acc and gyro
  (or be 0, "not filled in"), mag counts when marked.
* ``SCALED_IMU*``: mG, mrad/s, mGauss (by the MAVLink definition).
* ``RAW_IMU``: ArduPilot sends the scaled units above; from any other autopilot its scale is
  unknown (raw counts are allowed by the spec), so it is refused (:func:`imu_scale_known`).
* All-zero accelerometer and gyro: a missing IMU (ArduPilot's unused ``SCALED_IMU2/3``), skipped.
* ``time_usec`` above 1e15 µs is UNIX time, else time since boot; ``time_boot_ms`` is boot time.
* Clipping: the reader's rule (:mod:`tepinn_flight.ingest.saturation`), sample by sample.

The reader works on whole arrays; here one message at a time (the conversion factors come from
:mod:`tepinn_flight.conventions`, the tables from the reader).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..conventions import GAUSS_TO_UT, MILLI_G_TO_M_S2, MILLIGAUSS_TO_UT, MRAD_S_TO_RAD_S, UNIX_TIME_THRESHOLD_US
from ..ingest.saturation import gyro_full_scale_rad_s, saturated_f
from ..ingest.tlog import IMU_MESSAGES, IMU_PREFERENCE, imu_scale_known
from ..quat import gravity_body_f, quat_from_euler_zyx, slerp
from .messages import ESTIMATE_VALUE_NAMES, ESTIMATE_VECT_NAME, euler_zyx

_HIGHRES_ACC_GYRO = 0x003F
_HIGHRES_MAG = 0x01C0


@dataclass(frozen=True)
class ImuSample:
    t_s: float  # the message's own clock, s (boot time, or UNIX time when clock == "unix")
    time_usec: int  # the same instant in µs
    time_boot_ms: int | None  # ms since boot, None when the message carries UNIX time
    gyr_rad_s: tuple
    acc_m_s2: tuple
    mag_ut: tuple | None
    message: str
    instance: int
    clipped: bool = False  # a gyro or accelerometer axis at what the message can show (ingest.saturation)
    gyr_clipped: bool = False  # ... a gyro axis


def imu_preference(name: str) -> int:
    """Rank of an IMU message (0 = preferred), as in the tlog reader."""
    return IMU_PREFERENCE.index(name)


def imu_sample(msg, autopilot: int | None) -> ImuSample | None:
    """The IMU sample in SI units carried by ``msg``, or None (not an IMU message, unusable)."""
    name = msg.get_type()
    spec = IMU_MESSAGES.get(name)
    if spec is None or not imu_scale_known(name, autopilot):
        return None
    tfield, fixed = spec
    instance = fixed if fixed is not None else int(getattr(msg, "id", 0) or 0)
    acc = (float(msg.xacc), float(msg.yacc), float(msg.zacc))
    gyr = (float(msg.xgyro), float(msg.ygyro), float(msg.zgyro))
    mag = (float(msg.xmag), float(msg.ymag), float(msg.zmag))
    if not any(acc) and not any(gyr):
        return None  # a missing IMU arrives as all zeros
    if name == "HIGHRES_IMU":
        fu = int(msg.fields_updated)
        if fu and (fu & _HIGHRES_ACC_GYRO) != _HIGHRES_ACC_GYRO:
            return None  # a partial update without fresh acc/gyro
        mag_ok = any(mag) and (fu == 0 or (fu & _HIGHRES_MAG) == _HIGHRES_MAG)
        mag_ut = tuple(v * GAUSS_TO_UT for v in mag) if mag_ok else None
    else:
        acc = tuple(v * MILLI_G_TO_M_S2 for v in acc)
        gyr = tuple(v * MRAD_S_TO_RAD_S for v in gyr)
        mag_ut = tuple(v * MILLIGAUSS_TO_UT for v in mag) if any(mag) else None
    if not all(math.isfinite(v) for v in acc + gyr):
        return None
    if mag_ut is not None and not all(math.isfinite(v) for v in mag_ut):
        mag_ut = None
    if tfield == "time_usec":
        us = int(msg.time_usec)
        boot_ms = None if us > UNIX_TIME_THRESHOLD_US else us // 1000
        t_s = us / 1e6
    else:
        boot_ms = int(msg.time_boot_ms)
        us = boot_ms * 1000
        t_s = boot_ms / 1e3
    clipped, gyr_clipped = saturated_f(gyr, acc, gyro_full_scale_rad_s(name))
    return ImuSample(t_s, us, boot_ms, gyr, acc, mag_ut, name, instance, clipped, gyr_clipped)


def ekf_attitude(msg) -> tuple[float, int, tuple] | None:
    """(t_s, time_boot_ms, q_nb_wxyz) from ATTITUDE_QUATERNION or ATTITUDE, else None."""
    name = msg.get_type()
    if name == "ATTITUDE_QUATERNION":
        q = (float(msg.q1), float(msg.q2), float(msg.q3), float(msg.q4))
    elif name == "ATTITUDE":
        r, p, y = float(msg.roll), float(msg.pitch), float(msg.yaw)
        cr, sr = math.cos(r / 2), math.sin(r / 2)
        cp, sp = math.cos(p / 2), math.sin(p / 2)
        cy, sy = math.cos(y / 2), math.sin(y / 2)
        q = (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
             cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)  # fmt: skip
    else:
        return None
    n = math.sqrt(sum(v * v for v in q))
    if not math.isfinite(n) or n < 0.5:  # a zero quaternion means "not set"
        return None
    ms = int(msg.time_boot_ms)
    return ms / 1e3, ms, tuple(v / n for v in q)


# ---------------------------------------------------------------------------- comparison
def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def tilt_difference(q_est, q_ref) -> tuple[float, float, float, float]:
    """(roll, pitch, inclination, heading) differences in rad; inclination = angle between the
    gravity directions in the body frame, which ignores heading; heading = yaw difference wrapped
    to ±π (absolute with a 9-D estimate; in 6-D the estimate's heading origin is arbitrary, so only
    its changes mean something)."""
    ge, gr = gravity_body_f(q_est), gravity_body_f(q_ref)
    cx = ge[1] * gr[2] - ge[2] * gr[1]
    cy = ge[2] * gr[0] - ge[0] * gr[2]
    cz = ge[0] * gr[1] - ge[1] * gr[0]
    dincl = math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), ge[0] * gr[0] + ge[1] * gr[1] + ge[2] * gr[2])
    re, pe, ye = euler_zyx(q_est)
    rr, pr, yr = euler_zyx(q_ref)
    return _wrap(re - rr), pe - pr, dincl, _wrap(ye - yr)


class EkfComparator:
    """Pairs estimates with the autopilot's attitude at the same autopilot time.

    The EKF attitude for an estimate's time may arrive before or after the estimate; estimates
    wait (bounded) until an EKF sample at or after their time brackets them, then the EKF
    attitude is slerped onto the estimate's time (brackets longer than ``max_span_s`` are not
    used). A backward jump of the EKF clock (a reboot) clears the state.
    """

    def __init__(self, max_span_s: float = 0.25, max_pending: int = 256, keep: int = 64):
        self.max_span_s = max_span_s
        self.ekf: deque = deque(maxlen=keep)
        self.pending: deque = deque(maxlen=max_pending)

    def add_ekf(self, t_s: float, q) -> list[tuple[float, float, float, float]]:
        if self.ekf and t_s < self.ekf[-1][0] - 1.0:
            self.ekf.clear()
            self.pending.clear()
        if self.ekf and t_s <= self.ekf[-1][0]:
            return []
        self.ekf.append((t_s, tuple(q)))
        return self._resolve()

    def add_estimate(self, t_s: float, q) -> list[tuple[float, float, float, float]]:
        self.pending.append((t_s, tuple(q)))
        return self._resolve()

    def _resolve(self):
        out = []
        if not self.ekf:
            return out
        t_first, t_last = self.ekf[0][0], self.ekf[-1][0]
        while self.pending and self.pending[0][0] <= t_last:
            t, q = self.pending.popleft()
            if t < t_first:
                continue
            ref = self._at(t)
            if ref is not None:
                out.append((t, *tilt_difference(q, ref)))
        return out

    def _at(self, t: float):
        ts = [e[0] for e in self.ekf]
        i = int(np.searchsorted(ts, t, side="right")) - 1
        if i >= len(ts) - 1:
            return self.ekf[-1][1] if ts[-1] == t else None
        t0, t1 = ts[i], ts[i + 1]
        if t == t0:
            return self.ekf[i][1]
        if t1 - t0 > self.max_span_s:
            return None
        q = slerp(np.array([t]), np.array([t0, t1]), np.array([self.ekf[i][1], self.ekf[i + 1][1]]))[0]
        return tuple(float(v) for v in q)


# ---------------------------------------------------------------------------- the bridge's estimate, read back
class EstimateDecoder:
    """TE-PINN's estimate read back from the messages the bridge sends it in (what a vehicle
    emulator gets with ``bridge --estimates-to-master``), whatever ``--estimate-as`` was:
    ATTITUDE_QUATERNION, DEBUG_VECT ``TP_RPY`` (also a diagnostic) or NAMED_VALUE_FLOAT ``tp_roll``,
    ``tp_pitch``, ``tp_yaw`` (the three with one ``time_boot_ms``). Messages of the autopilot's own
    component (1) are not estimates. Times are whole milliseconds since boot (DEBUG_VECT's
    ``time_usec`` cut to them). Only estimates newer than the last one come out (the same estimate
    in two forms once); a clock more than 1 s back (a reboot, a replay loop) starts over."""

    def __init__(self, autopilot_compid: int = 1):
        self.autopilot_compid = autopilot_compid
        self.last_t: float | None = None
        self._named: dict[int, dict[str, float]] = {}

    def add(self, msg) -> tuple[float, tuple] | None:
        """(t_s, q_nb_wxyz) of a new estimate carried by ``msg``, else None."""
        if msg.get_srcComponent() == self.autopilot_compid:
            return None
        name = msg.get_type()
        if name == "ATTITUDE_QUATERNION":
            out = ekf_attitude(msg)
            got = None if out is None else (out[0], out[2])
        elif name == "DEBUG_VECT" and mavlink_text(msg.name) == ESTIMATE_VECT_NAME:
            us = int(msg.time_usec)
            if us >= UNIX_TIME_THRESHOLD_US:
                return None
            got = ((us // 1000) / 1e3, _rpy_deg_to_q(msg.x, msg.y, msg.z))  # on the ms grid of the other forms
        elif name == "NAMED_VALUE_FLOAT" and mavlink_text(msg.name) in ESTIMATE_VALUE_NAMES:
            ms = int(msg.time_boot_ms)
            vals = self._named.setdefault(ms, {})
            vals[mavlink_text(msg.name)] = float(msg.value)
            if len(self._named) > 8:
                self._named.pop(next(iter(self._named)))
            if len(vals) < len(ESTIMATE_VALUE_NAMES):
                return None
            del self._named[ms]
            got = (ms / 1e3, _rpy_deg_to_q(*(vals[n] for n in ESTIMATE_VALUE_NAMES)))
        else:
            return None
        t = got[0]
        if self.last_t is not None and t <= self.last_t and t >= self.last_t - 1.0:
            return None
        self.last_t = t
        return got


def mavlink_text(v) -> str:
    """A MAVLink char-array field (bytes or str, NUL-padded) as text."""
    return (v.decode(errors="replace") if isinstance(v, bytes) else str(v)).rstrip("\x00")


def _rpy_deg_to_q(roll_deg: float, pitch_deg: float, yaw_deg: float) -> tuple:
    q = quat_from_euler_zyx(np.radians(float(roll_deg)), np.radians(float(pitch_deg)), np.radians(float(yaw_deg)))
    return tuple(float(v) for v in q)
