"""MAVLink telemetry logs (``.tlog``) → :class:`~tepinn_flight.ingest.streams.RawLog`.

Frames are found and decoded by the chunked walker in :mod:`.mavlink_scan` (CRC-checked,
bit-identical to pymavlink's decoding); this module picks the autopilot's messages, converts
units and builds the streams.

Source
    Only the autopilot's messages count: component 1 (``MAV_COMP_ID_AUTOPILOT1``) of the system
    whose component-1 HEARTBEAT names a real autopilot (``autopilot != MAV_AUTOPILOT_INVALID``;
    the most frequent such sysid), else the sysid with the most component-1 frames. Companion
    computers, cameras, ground stations and radios in the same file are ignored.

IMU instances (``--imu N``)
    ``RAW_IMU`` (its ``id`` field, 0 for frames without it), ``SCALED_IMU`` = 0, ``SCALED_IMU2`` = 1,
    ``SCALED_IMU3`` = 2, ``HIGHRES_IMU`` (its ``id`` field). When several messages carry the same
    instance, HIGHRES_IMU is preferred, then RAW_IMU, then SCALED_IMU. Streams whose accelerometer
    and gyro are zero in every sample are dropped (a missing 2nd/3rd IMU arrives as all-zero
    ``SCALED_IMU2/3``). Default: the lowest instance with data.

Units
    ``SCALED_IMU*``: mG, mrad/s, mGauss (by the MAVLink definition, any autopilot).
    ``RAW_IMU``: ArduPilot sends the same scaled units; other stacks may send raw sensor counts,
    so a RAW_IMU from a non-ArduPilot autopilot is refused (its scale is unknown).
    ``HIGHRES_IMU``: m/s², rad/s, gauss. The axes are body FRD already.

Clipping (:mod:`.saturation`, the rule the live bridge applies too)
    A gyro axis at 98 % of what the message can show (±2000 °/s; the int16 mrad/s of RAW_IMU and
    SCALED_IMU* stops at ±32.767 rad/s) marks the sample ``clipped`` and ``gyr_clipped``; an
    accelerometer axis at 98 % of ±16 g marks it ``clipped``.

Reference (``--reference``)
    ``ATTITUDE_QUATERNION`` (q1..q4 = w, x, y, z, body → NED) preferred, else ``ATTITUDE``
    (roll, pitch, yaw in rad, Z-Y-X). ArduPilot reports the vehicle's attitude: it is turned into
    the IMU board's frame by the level trim ``AHRS_TRIM_X/Y`` from the tlog's ``PARAM_VALUE`` rows
    (:mod:`.ahrs_trim`; meta ``ahrs_trim_rad``), with a note where the tlog holds none.

GNSS velocity
    ``GPS_RAW_INT`` rows with ``fix_type`` ≥ 3 and a known ``vel`` and ``cog`` (65535: unknown):
    north, east = ``vel`` · (cos, sin) ``cog`` (cm/s, centidegrees → m/s, rad). Its ``time_usec`` is
    put on the IMU's clock: as it is when both are boot (or both UNIX) time; UNIX time (above
    1e15 µs, the receiver's GPS time) is mapped to boot time by ``SYSTEM_TIME`` (UNIX − boot =
    the median of ``time_unix_usec − 1000·time_boot_ms`` over the rows since the last reboot,
    the row before each GPS row in file order). With no ``SYSTEM_TIME`` that knows UNIX time,
    ``GLOBAL_POSITION_INT`` (``vx``, ``vy`` cm/s on boot time; the autopilot's fused velocity,
    source "GLOBAL_POSITION_INT") is used instead, where the ``GPS_RAW_INT`` before it has a 3-D fix.
    Each GNSS row takes the boot epoch of the IMU row written before it; same system/component.

Time
    Sample time from ``time_usec`` / ``time_boot_ms`` (since boot; ``time_usec`` above 1e15 is UNIX
    time), never the tlog receive timestamp. ArduPilot's ``RAW_IMU.time_usec`` is a 32-bit µs count that
    wraps 71.6 min after boot: unwrapped against the ``time_boot_ms`` written before each sample
    (:func:`_unwrap_us32`, :mod:`.clock_wrap`). A reboot is the boot clock going back by more than 1 s
    across the autopilot's IMU and attitude messages in file order *and staying back* for the
    next :data:`REBOOT_CONFIRM` messages (a single late message, seen in ``uavlv_vtol.tlog``, is
    not a reboot). Inside a boot epoch each stream is sorted by sample time.
"""

from __future__ import annotations

import os
from collections import Counter

import numpy as np

from ..conventions import (
    GAUSS_TO_UT,
    MILLI_G_TO_M_S2,
    MILLIGAUSS_TO_UT,
    MRAD_S_TO_RAD_S,
    UNIX_TIME_THRESHOLD_US,
)
from ..errors import ConfigError, CorruptLog, NoImuData
from ..mavlink_dialect import dialect
from ..quat import quat_from_euler_zyx
from .ahrs_trim import TRIM_PARAMS, trim_note, usable_trim, vehicle_to_board
from .clock_wrap import US32_WRAP_S, WRAP_MIN_BACKSTEP_S, top_to_bottom, wrap_count
from .mavlink_scan import scan_tlog
from .saturation import accel_saturated, gyro_full_scale_rad_s, gyro_saturated
from .streams import (PREFER_FACTOR, GnssVelStream, ImuStream, MagStream, RawLog, RefStream, covering_instance,
                      covering_note)

MAV_COMP_ID_AUTOPILOT1 = 1
MAV_AUTOPILOT_INVALID = 8
MAV_AUTOPILOT_ARDUPILOTMEGA = 3

#: IMU messages: (time field, fixed instance or None when the ``id`` field numbers it).
IMU_MESSAGES = {
    "HIGHRES_IMU": ("time_usec", None),
    "RAW_IMU": ("time_usec", None),
    "SCALED_IMU": ("time_boot_ms", 0),
    "SCALED_IMU2": ("time_boot_ms", 1),
    "SCALED_IMU3": ("time_boot_ms", 2),
}
#: Preference when several messages carry the same instance (first wins).
IMU_PREFERENCE = ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")
#: Reference messages, preferred first.
REF_MESSAGES = ("ATTITUDE_QUATERNION", "ATTITUDE")
META_MESSAGES = ("HEARTBEAT", "AUTOPILOT_VERSION", "PARAM_VALUE")
#: The receiver's velocity, the clock that maps its UNIX time to boot time, and the fallback.
GNSS_MESSAGES = ("GPS_RAW_INT", "SYSTEM_TIME", "GLOBAL_POSITION_INT")
#: The fields read of the messages besides the IMU's (the scan stores these only: a 42-MB tlog's ATTITUDE at
#: 10× the IMU's rate held 28 bytes a row for the 16 read; session 30: peak memory over 2× the output)
KEEP_FIELDS = {
    "ATTITUDE": ("time_boot_ms", "roll", "pitch", "yaw"),
    "ATTITUDE_QUATERNION": ("time_boot_ms", "q1", "q2", "q3", "q4"),
    "HEARTBEAT": ("type", "autopilot"),
    "AUTOPILOT_VERSION": ("flight_sw_version", "flight_custom_version"),
    "PARAM_VALUE": ("param_id", "param_value"),
    "GPS_RAW_INT": ("time_usec", "fix_type", "vel", "cog"),
    "SYSTEM_TIME": ("time_unix_usec", "time_boot_ms"),
    "GLOBAL_POSITION_INT": ("time_boot_ms", "vx", "vy"),
}
MIN_3D_FIX = 3  # GPS_FIX_TYPE_3D_FIX (4..8: DGPS, RTK float/fixed, static, PPP)
GPS_UNKNOWN_U16 = 65535  # GPS_RAW_INT vel / cog: unknown

#: A back step of the boot clock larger than this (s) may be a reboot ...
REBOOT_BACKSTEP_S = 1.0
#: ... if the next this-many autopilot messages all stay below the time before the step.
REBOOT_CONFIRM = 16

_FW_TYPES = {0: "dev", 64: "alpha", 128: "beta", 192: "rc", 255: "official"}


def read(path: str | os.PathLike, imu: int | None = None, reference: str | None = None) -> RawLog:
    """Parse a MAVLink tlog into raw streams (SI units, the autopilot's own clock)."""
    names = (*IMU_MESSAGES, *REF_MESSAGES, *META_MESSAGES, *GNSS_MESSAGES)
    try:
        scan = scan_tlog(path, names, keep_fields=KEEP_FIELDS)
    except OSError as exc:
        raise CorruptLog(f"cannot read the tlog ({exc.strerror or exc})") from None
    notes: list[str] = []

    if scan.good_frames == 0:
        raise CorruptLog("no valid MAVLink frame (start byte, length and CRC) in the file")
    sysid, hb, others = _autopilot(scan)
    if others:
        notes.append(f"the tlog holds {len(others) + 1} autopilots (systems {', '.join(map(str, sorted([sysid, *others])))}): "
                     f"read system {sysid}, the one with the most IMU messages")  # fmt: skip
    if sysid is None:
        seen = ", ".join(f"{s}/{c}" for s, c in sorted(scan.sources)) or "none"
        raise NoImuData(
            f"no messages from an autopilot (component {MAV_COMP_ID_AUTOPILOT1}) in the tlog; "
            f"sysid/compid seen: {seen}"
        )
    autopilot_id = _mode(hb["autopilot"]) if len(hb) else None
    vehicle_type = _enum_name("MAV_TYPE", _mode(hb["type"])) if len(hb) else "unknown"
    autopilot = _autopilot_name(autopilot_id)

    frames = {}
    other_src = 0
    del scan.frames["HEARTBEAT"]  # used by _autopilot only
    for name in (n for n in names if n != "HEARTBEAT"):
        fr = scan.frames.pop(name)  # drop the scan's copy as we go (memory)
        mine = (fr.sysid == sysid) & (fr.compid == MAV_COMP_ID_AUTOPILOT1)
        if name not in META_MESSAGES + GNSS_MESSAGES:
            other_src += int((~mine).sum())
        frames[name] = (fr.offset, fr.fields) if mine.all() else (fr.offset[mine], fr.fields[mine])
        del fr
    gnss_frames = {n: frames.pop(n) for n in GNSS_MESSAGES}
    firmware = _firmware(frames.pop("AUTOPILOT_VERSION")[1])
    params = _params(frames.pop("PARAM_VALUE")[1], TRIM_PARAMS)
    if other_src:
        notes.append(f"{other_src} IMU/attitude messages from other systems or components ignored")

    # ---- IMU candidate streams
    streams = _imu_streams(frames, autopilot_id)
    for s in streams:
        if s["all_zero"]:
            notes.append(f"{s['name']} (instance {s['instance']}) is all zero (no such IMU): dropped")
    live = [s for s in streams if not s["all_zero"]]
    imu_instances = [
        {"instance": int(s["instance"]), "name": s["name"], "samples": int(len(s["t_s"])),
         "rate_hz": s["rate_hz"], "units_known": bool(s["scale_known"])}
        for s in sorted(live, key=lambda s: (s["instance"], IMU_PREFERENCE.index(s["name"])))
    ]  # fmt: skip
    by_inst: dict[int, dict] = {}
    for s in sorted(live, key=lambda s: IMU_PREFERENCE.index(s["name"])):
        kept = by_inst.setdefault(s["instance"], s)
        if kept is not s and _faster(s, kept):  # a less preferred message of the IMU, much faster (review59: a ground
            by_inst[s["instance"]] = s  # station's 2-Hz HIGHRES_IMU had hidden the 50-Hz RAW_IMU; the bridge's rule)

    # ---- reference candidates
    refs = _ref_streams(frames)
    del frames
    _unwrap_us32(live, refs, notes)

    # ---- select the IMU
    usable = {k: s for k, s in by_inst.items() if s["scale_known"]}
    if imu is None:
        if not usable:
            if by_inst:
                s = by_inst[min(by_inst)]
                raise NoImuData(_unknown_scale_reason(s, autopilot))
            raise NoImuData(
                "no IMU messages (RAW_IMU, SCALED_IMU*, HIGHRES_IMU) with data from the autopilot "
                f"(sysid {sysid}, compid {MAV_COMP_ID_AUTOPILOT1})"
            )
        sel = usable[covering_instance({k: len(s["t_s"]) for k, s in usable.items()})]
        first = usable[min(usable)]
        if sel is not first:
            notes.append(covering_note(sel["instance"], len(sel["t_s"]), first["instance"], len(first["t_s"])))
    else:
        if imu not in by_inst:
            avail = ", ".join(f"{k} ({s['name']})" for k, s in sorted(by_inst.items())) or "none"
            raise NoImuData(f"IMU instance {imu} not in this tlog; instances with data: {avail}")
        sel = by_inst[imu]
        if not sel["scale_known"]:
            raise NoImuData(_unknown_scale_reason(sel, autopilot))
    if sel["clock"] == "unix":
        notes.append(f"{sel['name']} time_usec is UNIX time (above 1e15 µs)")


    # ---- select the reference (by name; its quaternions are made below)
    cand = [n for n in REF_MESSAGES if n in refs]
    if reference is not None:
        want = reference.strip().upper()
        if want not in refs:
            raise ConfigError(
                f"reference {reference!r} not in this tlog; available: {', '.join(cand) or 'none'}"
            )
        rname = want
    else:
        rname = cand[0] if cand else None

    # memory: the rows of the streams not selected are no longer needed (their times are)
    for s in streams:
        if s is not sel:
            s.pop("fields")
    for n, r in refs.items():
        if n != rname:
            r.pop("fields")

    # ---- boot epochs from every boot-clock time stamp of the autopilot's data messages
    clocked = [s for s in live] + list(refs.values())
    _assign_epochs(clocked)

    # ---- GNSS velocity on the IMU's clock and boot epochs
    gnss = _gnss(gnss_frames, sel, notes)
    del gnss_frames

    # ---- the IMU's arrays
    order = _time_order(sel["t_s"], sel["epoch"])
    ff = sel.pop("fields")
    gyr, acc, mag_ut = _imu_si(sel["name"], ff)
    del ff
    gyr_clipped = gyro_saturated(gyr, gyro_full_scale_rad_s(sel["name"]))
    clipped = gyr_clipped | accel_saturated(acc)
    if clipped.any():
        notes.append(f"{int(clipped.sum())} IMU sample(s) at ≥98 % of the range {sel['name']} can show "
                     f"(gyro {int(gyr_clipped.sum())}): marked clipped")  # fmt: skip
    imu_stream = ImuStream(
        t_s=sel["t_s"][order],
        gyr_rad_s=gyr[order],
        acc_m_s2=acc[order],
        clipped=clipped[order],
        epoch=sel["epoch"][order],
        gyr_clipped=gyr_clipped[order],
    )
    del gyr, acc
    mag = None
    if np.any(mag_ut != 0):
        mag = MagStream(t_s=imu_stream.t_s, mag_ut=mag_ut[order], epoch=imu_stream.epoch)
    del streams, live, by_inst, usable, clocked, mag_ut

    # ---- the reference's arrays
    ref = None
    trim_meta = None
    if rname is not None:
        r = refs[rname]
        if r["clock"] != sel["clock"]:
            notes.append(f"{rname} and {sel['name']} use different clocks (boot vs UNIX): no reference")
        else:
            o = _time_order(r["t_s"], r["epoch"])
            f, norm = r.pop("fields"), r["norm"]
            if not isinstance(o, slice):  # in time order before the quaternions are made (memory: a row of the
                f, norm = f[o], norm[o]  # fields is half a quaternion's 32 bytes; the same numbers row by row)
            q = _ref_quaternions(rname, f, norm)
            del f
            if autopilot == "ardupilot":  # ArduPilot reports the vehicle's attitude (.ahrs_trim)
                trim = usable_trim(*(params.get(n) for n in TRIM_PARAMS))
                if trim is not None:
                    for i in range(0, len(q), _BLOCK):  # in place, block by block (row by row the same product)
                        q[i : i + _BLOCK] = vehicle_to_board(q[i : i + _BLOCK], *trim)
                    trim_meta = list(trim)
                    notes.append(trim_note(rname, trim))
                elif not all(n in params for n in TRIM_PARAMS):
                    notes.append(f"reference {rname} is ArduPilot's vehicle attitude and the tlog holds no AHRS_TRIM_X/Y "
                                 "(the ground station fetched no parameters): a level trim, if set, stays in it")  # fmt: skip
            ref = RefStream(t_s=r["t_s"][o], q_nb_wxyz=q, source=rname, epoch=r["epoch"][o])
    del refs

    meta = {
        "source_kind": "tlog",
        "vehicle_type": vehicle_type,
        "autopilot": autopilot,
        "autopilot_sysid": int(sysid),
        "imu_instance": int(sel["instance"]),
        "imu_message": sel["name"],
        "imu_instances": imu_instances,
        "reference_candidates": cand,
        "corrupt_frames": int(scan.corrupt_frames),
        "skipped_frames": int(scan.unknown_frames),
        "junk_bytes": int(scan.junk_bytes),
        "truncated_bytes": int(scan.truncated_bytes),
        "frames": int(scan.good_frames),
        "notes": notes,
    }
    if firmware:
        meta["firmware"] = firmware
    if trim_meta is not None:
        meta["ahrs_trim_rad"] = trim_meta
    level = usable_trim(*(params.get(n) for n in TRIM_PARAMS)) if autopilot == "ardupilot" else None
    if level is not None:  # the board's attitude (estimates, the reference) is this far from ATTITUDE's vehicle attitude
        meta["level_trim_rad"] = list(level)
    if scan.corrupt_frames:
        notes.append(f"{scan.corrupt_frames} frames failed their CRC check: skipped")
    if scan.junk_bytes:
        notes.append(f"{scan.junk_bytes} bytes outside any MAVLink frame skipped")
    if scan.truncated_bytes:
        notes.append(f"the last record is cut after {scan.truncated_bytes} bytes (truncated file)")
    n_epochs = int(imu_stream.epoch.max()) + 1 if len(imu_stream.epoch) else 0
    if n_epochs > 1:
        notes.append(f"{n_epochs - 1} autopilot reboot(s) detected (boot time went back)")
    return RawLog(imu=imu_stream, mag=mag, ref=ref, meta=meta, gnss=gnss)


# ------------------------------------------------------------------------------------------------
def _mode(values) -> int:
    return int(Counter(np.asarray(values).tolist()).most_common(1)[0][0])


def _enum_name(enum: str, value: int | None) -> str:
    if value is None:
        return "unknown"
    entry = dialect().enums.get(enum, {}).get(int(value))
    if entry is None:
        return f"{enum.lower()}_{value}"
    return entry.name.removeprefix(f"{enum}_").lower()


def _faster(s: dict, than: dict) -> bool:
    """Whether stream ``s`` is much faster than ``than`` (:data:`.streams.PREFER_FACTOR`; the bridge's own rule for a
    less preferred message, ``live/imu_stream.py``)."""
    a, b = s.get("rate_hz") or 0.0, than.get("rate_hz") or 0.0
    return bool(s.get("scale_known", True)) and a >= PREFER_FACTOR * b and a > 0


def _autopilot_name(value: int | None) -> str:
    if value is None:
        return "unknown"
    if value == MAV_AUTOPILOT_ARDUPILOTMEGA:
        return "ardupilot"
    return _enum_name("MAV_AUTOPILOT", value)


def _autopilot(scan):
    """(sysid of the autopilot, its component-1 HEARTBEAT fields, the other autopilots' sysids) or (None, ...).
    Where several systems send an autopilot's heartbeat (two vehicles, a tracker), the one with the most IMU messages
    is read: heartbeats come at 1 Hz from each, and their count had chosen by which came first in the file (review59:
    a 2-Hz vehicle's IMU read, the 50-Hz one's unreachable)."""
    hb = scan.frames["HEARTBEAT"]
    comp1 = hb.compid == MAV_COMP_ID_AUTOPILOT1
    real = comp1 & (hb.fields["autopilot"] != MAV_AUTOPILOT_INVALID)
    others: list[int] = []
    if np.any(real):
        systems = np.unique(hb.sysid[real]).tolist()
        sysid = _mode(hb.sysid[real])
        if len(systems) > 1:
            imu = {s: sum(int(np.sum((scan.frames[n].sysid == s) & (scan.frames[n].compid == MAV_COMP_ID_AUTOPILOT1)))
                          for n in IMU_MESSAGES) for s in systems}  # fmt: skip
            sysid = max(systems, key=lambda s: (imu[s], s == sysid))
            others = [s for s in systems if s != sysid]
    else:
        c1 = {s: n for (s, c), n in scan.sources.items() if c == MAV_COMP_ID_AUTOPILOT1}
        if not c1:
            return None, hb.fields[:0], []
        sysid = max(c1, key=lambda s: (c1[s], -s))
    mine = real & (hb.sysid == sysid)
    return int(sysid), hb.fields[mine], others


def imu_scale_known(name: str, autopilot_id: int | None) -> bool:
    """HIGHRES_IMU and SCALED_IMU* have defined units; RAW_IMU is mG / mrad/s only from ArduPilot
    (other stacks may send raw counts, whose scale we do not know)."""
    return name != "RAW_IMU" or autopilot_id == MAV_AUTOPILOT_ARDUPILOTMEGA


def _imu_streams(frames, autopilot_id) -> list[dict]:
    """IMU candidate streams: times, offsets and the raw rows (SI arrays only for the one selected)."""
    out = []
    for name, (tfield, fixed) in IMU_MESSAGES.items():
        off, f = frames.pop(name)
        if len(off) == 0:
            continue
        inst = np.full(len(off), fixed, np.int64) if fixed is not None else f["id"].astype(np.int64)
        for k in np.unique(inst).tolist():
            m = inst == k
            ff, offs = (f, off) if m.all() else (f[m], off[m])
            all_zero = not any(np.any(ff[c] != 0) for c in (*_ACC, *_GYR))
            t_s, clock = _time_s(ff[tfield], tfield)
            out.append({
                "name": name, "instance": int(k), "offset": offs, "t_s": t_s, "clock": clock,
                "fields": None if all_zero else ff, "all_zero": all_zero,
                "scale_known": True if name == "HIGHRES_IMU" else imu_scale_known(name, autopilot_id),
                "rate_hz": _rate_hz(t_s),
            })  # fmt: skip
        del f
    return out


_ACC = ("xacc", "yacc", "zacc")
_GYR = ("xgyro", "ygyro", "zgyro")
_MAG = ("xmag", "ymag", "zmag")


def _imu_si(name: str, ff: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(gyr rad/s, acc m/s², mag µT) of an IMU message's rows (see the module docstring's units)."""
    acc = _columns(ff, _ACC)
    gyr = _columns(ff, _GYR)
    mag = _columns(ff, _MAG)
    if name == "HIGHRES_IMU":
        mag *= GAUSS_TO_UT
    else:
        acc *= MILLI_G_TO_M_S2
        gyr *= MRAD_S_TO_RAD_S
        mag *= MILLIGAUSS_TO_UT
    return gyr, acc, mag


#: Rows converted at a time (Euler angles → quaternions): the temporaries stay one block in size.
_BLOCK = 1 << 12


def _raw_quaternions(name: str, f: np.ndarray) -> np.ndarray:
    """(n, 4) float64 quaternions of ATTITUDE_QUATERNION / ATTITUDE rows, not normalised."""
    if name == "ATTITUDE_QUATERNION":
        return np.stack([f["q1"], f["q2"], f["q3"], f["q4"]], axis=1).astype(np.float64)
    q = np.empty((len(f), 4))
    for i in range(0, len(f), _BLOCK):
        b = f[i : i + _BLOCK]
        q[i : i + _BLOCK] = quat_from_euler_zyx(
            b["roll"].astype(np.float64), b["pitch"].astype(np.float64), b["yaw"].astype(np.float64)
        )
    return q


def _ref_streams(frames) -> dict[str, dict]:
    """Reference candidates: rows whose quaternion is set (norm > 0.5), times and offsets.

    The quaternions themselves are made for the selected one only (:func:`_ref_quaternions`).
    """
    refs = {}
    for name in REF_MESSAGES:
        off, f = frames.pop(name)
        if len(off) == 0:
            continue
        norm = np.empty(len(f))
        for i in range(0, len(f), _BLOCK):
            norm[i : i + _BLOCK] = np.linalg.norm(_raw_quaternions(name, f[i : i + _BLOCK]), axis=1)
        ok = np.isfinite(norm) & (norm > 0.5)  # a zero quaternion means "not set"
        if not np.any(ok):
            continue
        if not ok.all():
            f, off, norm = f[ok], off[ok], norm[ok]
        t_s, clock = _time_s(f["time_boot_ms"], "time_boot_ms")
        refs[name] = {"name": name, "offset": off, "t_s": t_s, "clock": clock, "fields": f, "norm": norm}
    return refs


def _ref_quaternions(name: str, f: np.ndarray, norm: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z, body → NED) of the reference rows, block by block."""
    q = np.empty((len(f), 4))
    for i in range(0, len(f), _BLOCK):
        q[i : i + _BLOCK] = _raw_quaternions(name, f[i : i + _BLOCK]) / norm[i : i + _BLOCK, None]
    return q


def _columns(f: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    out = np.empty((len(f), len(names)), np.float64)
    for k, n in enumerate(names):
        out[:, k] = f[n]
    return out


def _time_order(t_s: np.ndarray, epoch: np.ndarray):
    """Index that sorts by (epoch, time), or a plain slice when already sorted (no copy)."""
    if len(t_s) < 2 or np.all((np.diff(epoch) > 0) | ((np.diff(epoch) == 0) & (np.diff(t_s) >= 0))):
        return slice(None)
    return np.lexsort((t_s, epoch))


def _time_s(raw: np.ndarray, field: str) -> tuple[np.ndarray, str]:
    if field == "time_usec":
        us = raw.astype(np.float64)
        clock = "unix" if len(us) and np.median(us) > UNIX_TIME_THRESHOLD_US else "boot"
        return us / 1e6, clock
    return raw.astype(np.float64) / 1e3, "boot"


def _unwrap_us32(imu_streams: list[dict], refs: dict[str, dict], notes: list[str]) -> None:
    """Put a boot-clock ``time_usec`` IMU stream that wrapped at 2**32 µs back on a running clock, in place
    (:mod:`.clock_wrap`).

    Each sample takes the wrap count that brings it nearest to the ``time_boot_ms`` (of any reference or IMU
    message on that clock) written just before it in the file, where one does; else the count of the sample
    before it. A reboot sets every clock back, so it stays one (the boot epochs are found after this). With no
    ``time_boot_ms`` message, a fall from the top of the 32-bit range to its bottom is counted as a wrap.
    """
    ms_clocks = [s for s in imu_streams if IMU_MESSAGES[s["name"]][0] == "time_boot_ms" and s["clock"] == "boot"]
    ms_clocks += [r for r in refs.values() if r["clock"] == "boot"]
    for s in imu_streams:
        if IMU_MESSAGES[s["name"]][0] != "time_usec" or s["clock"] != "boot" or len(s["t_s"]) < 2:
            continue
        t = s["t_s"]
        if not (np.nanmax(t) < US32_WRAP_S and np.any(np.diff(t) < -WRAP_MIN_BACKSTEP_S)):
            continue
        if ms_clocks:
            off = np.concatenate([c["offset"] for c in ms_clocks])
            tc = np.concatenate([c["t_s"] for c in ms_clocks])
            o = np.argsort(off, kind="stable")
            before = np.searchsorted(off[o], s["offset"], side="right") - 1
            k = np.where(before >= 0, wrap_count(t, tc[o][np.maximum(before, 0)]), -1.0)
        else:  # the stream alone
            k = np.cumsum(np.r_[False, top_to_bottom(t[:-1], t[1:])]).astype(np.float64)
        idx = np.maximum.accumulate(np.where(k >= 0, np.arange(len(t)), -1))  # no match: the count before
        wraps = np.where(idx >= 0, k[np.maximum(idx, 0)], 0.0)
        if np.any(wraps > 0):
            s["t_s"] = t + wraps * US32_WRAP_S
            s["rate_hz"] = _rate_hz(s["t_s"])
            notes.append(f"{s['name']} time_usec wrapped at 2^32 µs ({int(wraps.max())} time(s): ArduPilot's "
                         "32-bit clock, 71.6 min after boot): unwrapped")  # fmt: skip


def _rate_hz(t_s: np.ndarray) -> float | None:
    if len(t_s) < 2:
        return None
    dt = np.diff(np.sort(t_s))
    dt = dt[dt > 0]
    return float(1.0 / np.median(dt)) if len(dt) else None


def boot_epochs(t_s: np.ndarray, backstep_s: float = REBOOT_BACKSTEP_S, confirm: int = REBOOT_CONFIRM) -> np.ndarray:
    """Boot epoch per sample of one boot clock in file order, robust to single late messages.

    A reboot starts at ``k`` when ``t[k]`` lies more than ``backstep_s`` below the latest time of
    the current epoch and the next ``confirm`` samples all stay below it.
    """
    epoch = np.zeros(len(t_s), np.int64)
    for e, start in enumerate(_epoch_starts(t_s, backstep_s, confirm).tolist(), start=1):
        epoch[start:] = e
    return epoch


def _epoch_starts(t_s: np.ndarray, backstep_s: float = REBOOT_BACKSTEP_S, confirm: int = REBOOT_CONFIRM) -> np.ndarray:
    """Indices where a new boot epoch begins (the rule of :func:`boot_epochs`), ascending."""
    t = np.asarray(t_s, np.float64)
    starts = []
    start = 0
    while start < len(t) - 1:
        seg = t[start:]
        cm = np.maximum.accumulate(seg)
        nxt = None
        for b0 in range(0, len(seg) - 1, _SCAN_BLOCK):  # candidates k block by block (memory)
            b1 = min(b0 + _SCAN_BLOCK, len(seg) - 1)
            for j in np.flatnonzero(seg[b0 + 1 : b1 + 1] < cm[b0:b1] - backstep_s):
                k = int(j) + b0 + 1
                if np.max(seg[k : k + confirm]) < cm[k - 1]:  # usually the first candidate
                    nxt = k
                    break
            if nxt is not None:
                break
        del cm
        if nxt is None:
            break
        start += int(nxt)
        starts.append(start)
    return np.asarray(starts, np.int64)


_SCAN_BLOCK = 1 << 14  # samples compared at a time when looking for reboots


def _merge_positions(offsets: list[np.ndarray]) -> list[np.ndarray] | None:
    """Where each element of several sorted offset arrays lands in their merged, stably sorted order.

    Equal offsets keep the order of the arrays (as a stable sort of the concatenation would);
    None when an array is not sorted.
    """
    if any(len(o) > 1 and np.any(o[1:] < o[:-1]) for o in offsets):
        return None
    out = []
    for a, o_a in enumerate(offsets):
        pos = np.arange(len(o_a), dtype=np.int64)
        for b, o_b in enumerate(offsets):
            if b != a:
                pos += np.searchsorted(o_b, o_a, side="right" if b < a else "left")
        out.append(pos)
    return out


def _assign_epochs(streams: list[dict]) -> None:
    """Give every stream an ``epoch`` array from the merged boot clock (file order).

    The merged clock is one float per sample; no argsort and no merged offset array (memory).
    """
    boot = [s for s in streams if s["clock"] == "boot"]
    for s in streams:
        s["epoch"] = np.zeros(len(s["t_s"]), np.int64)
    if not boot:
        return
    pos = _merge_positions([s["offset"] for s in boot])
    if pos is None:  # not in file order: sort the concatenation
        order = np.argsort(np.concatenate([s["offset"] for s in boot]), kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        bounds = np.cumsum([0] + [len(s["t_s"]) for s in boot])
        pos = [rank[bounds[k] : bounds[k + 1]] for k in range(len(boot))]
    t = np.empty(sum(len(p) for p in pos))
    for s, p in zip(boot, pos):
        t[p] = s["t_s"]
    starts = _epoch_starts(t)
    del t
    for s, p in zip(boot, pos):
        s["epoch"] = np.searchsorted(starts, p, side="right").astype(np.int64, copy=False)


def _gnss(frames: dict, sel: dict, notes: list[str]) -> GnssVelStream | None:
    """The receiver's horizontal velocity (``GPS_RAW_INT``, 3-D fixes) on the clock and boot epochs
    of the IMU stream ``sel`` (see the module docstring), or None (with a note where the log has
    GPS_RAW_INT rows but none usable)."""
    off, f = frames["GPS_RAW_INT"]
    if len(off) == 0:
        return None
    good = ((f["fix_type"] >= MIN_3D_FIX) & (f["vel"] != GPS_UNKNOWN_U16) & (f["cog"] != GPS_UNKNOWN_U16)
            & (f["time_usec"] > 0))  # fmt: skip
    if not good.any():
        notes.append(f"GPS_RAW_INT: none of its {len(off)} message(s) has a 3-D fix with a known velocity: "
                     "no GNSS velocity")  # fmt: skip
        return None
    t_us = f["time_usec"][good].astype(np.int64)
    clock = "unix" if np.median(t_us) > UNIX_TIME_THRESHOLD_US else "boot"
    vel = f["vel"][good] * 0.01
    cog = f["cog"][good] * (0.01 * np.pi / 180.0)
    vel_ne = np.column_stack([vel * np.cos(cog), vel * np.sin(cog)])
    g_off, source = off[good], "GPS_RAW_INT"
    if clock != sel["clock"]:
        st_off, st = frames["SYSTEM_TIME"]
        unix_minus_boot_us = _unix_minus_boot_us(st_off, st, g_off)
        if unix_minus_boot_us is not None:
            t_us = t_us - unix_minus_boot_us if clock == "unix" else t_us + unix_minus_boot_us
            notes.append(f"GPS_RAW_INT time_usec is {clock} time, the IMU's {sel['clock']}: mapped by SYSTEM_TIME")
        elif sel["clock"] == "boot":  # the autopilot's fused velocity, on boot time
            gp_off, gp = frames["GLOBAL_POSITION_INT"]
            last_gps = np.searchsorted(off, gp_off, side="right") - 1  # the GPS_RAW_INT before each row
            fixed = (last_gps >= 0) & good[np.maximum(last_gps, 0)]
            if not fixed.any():
                notes.append("GPS_RAW_INT time_usec is UNIX time, no SYSTEM_TIME maps it to boot time and no "
                             "GLOBAL_POSITION_INT follows a 3-D fix: no GNSS velocity")  # fmt: skip
                return None
            notes.append("GPS_RAW_INT time_usec is UNIX time and no SYSTEM_TIME maps it to boot time: GNSS "
                         "velocity from GLOBAL_POSITION_INT (the autopilot's fused velocity)")  # fmt: skip
            gp, g_off, source = gp[fixed], gp_off[fixed], "GLOBAL_POSITION_INT"
            t_us = gp["time_boot_ms"].astype(np.int64) * 1000
            vel_ne = np.column_stack([gp["vx"], gp["vy"]]).astype(np.float64) * 0.01
        else:
            notes.append("GPS_RAW_INT is on boot time, the IMU on UNIX time, and no SYSTEM_TIME relates them: "
                         "no GNSS velocity")  # fmt: skip
            return None
    t_s = t_us / 1e6
    before = np.searchsorted(sel["offset"], g_off, side="right") - 1  # the IMU row written before each
    epoch = sel["epoch"][np.maximum(before, 0)]
    o = _time_order(t_s, epoch)
    return GnssVelStream(t_s=t_s[o], vel_ne_m_s=vel_ne[o], source=source, epoch=epoch[o])


def _unix_minus_boot_us(st_off: np.ndarray, st: np.ndarray, at_off: np.ndarray) -> np.ndarray | None:
    """UNIX − boot time (µs, int64) at the file offsets ``at_off`` from the SYSTEM_TIME rows: the
    median of ``time_unix_usec − 1000·time_boot_ms`` over each run of rows between reboots (a reboot
    moves it by more than 1 s), that of the row before each offset. None without a row that knows
    UNIX time."""
    ok = st["time_unix_usec"] > UNIX_TIME_THRESHOLD_US
    if not ok.any():
        return None
    d_us = st["time_unix_usec"][ok].astype(np.int64) - 1000 * st["time_boot_ms"][ok].astype(np.int64)
    runs = np.split(d_us, np.flatnonzero(np.abs(np.diff(d_us)) > 1_000_000) + 1)
    med_us = np.array([np.median(r) for r in runs]).round().astype(np.int64)
    run_of = np.repeat(np.arange(len(runs)), [len(r) for r in runs])
    before = np.maximum(np.searchsorted(st_off[ok], at_off, side="right") - 1, 0)
    return med_us[run_of[before]]


def _unknown_scale_reason(s: dict, autopilot: str) -> str:
    article = "an" if autopilot[:1].lower() in "aeiou" else "a"
    return (
        f"{s['name']} (IMU instance {s['instance']}) from {article} {autopilot} autopilot may carry raw sensor "
        "counts: its scale is unknown, refusing to guess (only ArduPilot's RAW_IMU is known to be in "
        "mG and mrad/s)"
    )


def _params(pv: np.ndarray, names: tuple[str, ...]) -> dict[str, float]:
    """The last value of each parameter in ``names`` among PARAM_VALUE rows (a ground station's
    parameter download passes through the tlog)."""
    out: dict[str, float] = {}
    if len(pv):
        ids = np.char.rstrip(pv["param_id"], b"\0")
        for n in names:
            hit = np.flatnonzero(ids == n.encode())
            if len(hit):
                out[n] = float(pv["param_value"][hit[-1]])
    return out


def _firmware(av: np.ndarray) -> str | None:
    if len(av) == 0:
        return None
    v = int(av["flight_sw_version"][-1])
    if v == 0:
        return None
    major, minor, patch, kind = (v >> 24) & 0xFF, (v >> 16) & 0xFF, (v >> 8) & 0xFF, v & 0xFF
    s = f"{major}.{minor}.{patch}"
    if kind != 255:
        s += f"-{_FW_TYPES.get(kind, kind)}"
    git = bytes(av["flight_custom_version"][-1].tolist()).split(b"\x00")[0]
    if git and all(32 < c < 127 for c in git):
        s += f" ({git.decode('ascii')})"
    return s
