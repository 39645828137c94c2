"""PX4 ULog (``.ulg``) → :class:`~tepinn_flight.ingest.streams.RawLog`, parsed with pyulog.

IMU
    Default (``imu=None``): ``sensor_combined``, the IMU PX4 selected, at the logged rate. Its
    ``gyro_rad`` is the *average* rate over ``gyro_integral_dt`` ending at ``timestamp``; that
    time is the row time (the record's convention: sample k is the mean over the step before it).
    The accelerometer's own time is ``timestamp + accelerometer_timestamp_relative``; where that
    offset is non-zero the accelerometer is linearly interpolated onto the gyro times (it is 0 in
    every shared log; the "invalid" marker 2147483647 counts as missing).
    ``gyro_integral_dt`` is seconds in 2016-era logs (0.004) and µs later (4000); we only use it to
    detect decimated logging (samples much further apart than the integration interval).

Instance numbering (``imu=N``)
    N is the physical IMU: the multi-instance index of ``vehicle_imu`` (or of ``sensor_gyro`` /
    ``sensor_accel`` when no ``vehicle_imu`` is logged). The instance PX4 selected (matched by
    ``sensor_selection.gyro_device_id``, else assumed 0) is read from ``sensor_combined``, the
    highest-rate copy (from its ``vehicle_imu[N]`` where a custom topic list logs that at over 1.5× the rate of a
    decimated ``sensor_combined``, session 59); other instances from ``vehicle_imu[N]`` (``delta_angle`` /
    ``delta_angle_dt``, ``delta_velocity`` / ``delta_velocity_dt``: calibrated, body frame) or,
    failing that, from ``sensor_gyro[N]`` + ``sensor_accel[N]`` (driver output, not calibrated).
    Logs with only ``sensor_combined`` (PX4 ≤ 1.9) have one instance, 0. Default logging profiles
    write the per-instance topics at 1–2 Hz only: usable for inspection, not for estimation.

Magnetometer (gauss → µT, ×100): ``vehicle_magnetometer`` (calibrated, body), else the 2016-era
``sensor_combined.magnetometer_ga`` at ``timestamp + magnetometer_timestamp_relative``, else
``sensor_mag[0]`` (uncalibrated).

Reference: ``vehicle_attitude_groundtruth`` (simulator truth) when present, else
``vehicle_attitude`` (the EKF), else ``estimator_attitude`` / ``control_state``; ``reference``
selects one by topic name (``name`` or ``name[k]`` for instance k). ``q`` is w, x, y, z body FRD
→ NED. Its time is ``timestamp_sample`` where that field holds plausible values (the v1.13 SITL
groundtruth logs it as 0), else ``timestamp``.

GNSS velocity: ``vehicle_gps_position`` instance 0 (else ``sensor_gps`` instance 0), rows with
``fix_type`` ≥ 3 and ``vel_ned_valid``: ``vel_n_m_s``, ``vel_e_m_s`` at ``timestamp`` (the clock of
sensor_combined).

Reference resets: an EKF quaternion reset (``quat_reset_counter`` changes) makes the attitude
jump; the samples right after it are dropped so that the reference is left uncovered (NaN) across
the jump instead of being slerped through it.

Time: µs since boot, or UNIX µs (above 1e15, PX4 v1.15 SITL) → seconds (``meta["time_base"]``);
UNIX stamps are counted from their first whole second (``meta["time_origin_unix_s"]``) to keep µs
resolution in float64. A ULog has one boot, so no epochs; durations come from the samples, never
from the header (``pyulog_sample_log_small.ulg``'s last timestamp is 1174 s after its data).
Logging dropouts (``ulog.dropouts``): the IMU's own stamps say what each cost it (``meta["ulog_dropouts"]``, and a
note: the samples lost there, or none); a lost sample is a longer step, which the estimators integrate over its own
time or, past 2.5 periods, bridge or restart at (:mod:`tepinn_flight.record_gaps`). Until session 53 samples were
dropped after a dropout to force a segment break even where the IMU had lost none. pyulog stamps a dropout with the
latest timestamp it has read, so only topics we parse can move that stamp.

Errors: anything pyulog cannot parse (truncated header, garbage after the magic, a definitions
section it would loop on forever) becomes a one-line :class:`CorruptLog`; a log that parses
but has no IMU topic gives :class:`NoImuData`, an unknown ``reference`` a :class:`ConfigError`
listing the attitude topics present.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import re
from typing import Any

import numpy as np

from ..conventions import GAUSS_TO_UT, UNIX_TIME_THRESHOLD_US
from ..errors import ConfigError, CorruptLog, NoImuData, TepinnError
from .assemble import GAP_PERIODS
from .saturation import accel_saturated, credible_gyro_clipping, gyro_saturated
from .streams import PREFER_FACTOR, GnssVelStream, ImuStream, MagStream, RawLog, RefStream, nominal_period_s

#: Attitude topics with ``q[0..3]`` = w, x, y, z body FRD → NED, in default-preference order.
REFERENCE_TOPICS = ("vehicle_attitude_groundtruth", "vehicle_attitude", "estimator_attitude", "control_state")
IMU_TOPICS = ("sensor_combined", "vehicle_imu", "sensor_gyro", "sensor_accel", "sensor_selection")
MAG_TOPICS = ("vehicle_magnetometer", "sensor_mag")
#: The receiver's solution, preferred first (instance 0 of the first one logged).
GNSS_TOPICS = ("vehicle_gps_position", "sensor_gps")
GNSS_FIELDS = ("fix_type", "vel_ned_valid", "vel_n_m_s", "vel_e_m_s")
MIN_3D_FIX = 3  # fix_type: 3 = 3-D fix (4..8: RTCM/DGPS, RTK float/fixed, extrapolated)

#: uORB's marker for an invalid relative timestamp (``RELATIVE_TIMESTAMP_INVALID``).
RELATIVE_TIMESTAMP_INVALID = 2147483647

#: MAV_TYPE → vehicle type (PX4 writes 22 for a standard VTOL, MAVLink's VTOL_FIXEDROTOR).
MAV_TYPES = {
    0: "generic", 1: "fixed-wing", 2: "quadrotor", 3: "coaxial", 4: "helicopter", 7: "airship",
    10: "ground-rover", 11: "surface-boat", 12: "submarine", 13: "hexarotor", 14: "octorotor",
    15: "tricopter", 19: "vtol-duorotor", 20: "vtol-quadrotor", 21: "vtol-tiltrotor",
    22: "vtol-fixedrotor", 23: "vtol-tailsitter", 24: "vtol-tiltwing", 29: "dodecarotor",
    35: "decarotor", 43: "multirotor",
}  # fmt: skip

_RELEASE_TYPES = {0: "dev", 64: "alpha", 128: "beta", 192: "rc", 255: ""}


# --------------------------------------------------------------------------- pure helpers


def us_to_s(t_us: np.ndarray) -> np.ndarray:
    """µs (already counted from the log's time origin, see :func:`_datasets`) → float64 seconds."""
    return np.asarray(t_us, np.float64) * 1e-6


def integral_dt_s(values: np.ndarray) -> tuple[float, str]:
    """Median ``*_integral_dt`` in seconds and its unit: seconds in 2016 logs, µs later."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v) & (v > 0)]
    if len(v) == 0:
        return float("nan"), "unknown"
    med = float(np.median(v))
    return (med, "s") if med < 1.0 else (med * 1e-6, "us")


def firmware_string(info: dict[str, Any]) -> str:
    """'PX4 v1.11.2 dev (git 8583f1da)' from ``ver_sw_release`` (0xMMmmpp<type>) and ``ver_sw``."""
    parts = []
    rel = info.get("ver_sw_release")
    if isinstance(rel, (int, np.integer)) and rel > 0:
        rel = int(rel)
        kind = _RELEASE_TYPES.get(rel & 0xFF, f"type {rel & 0xFF}")
        version = f"v{(rel >> 24) & 0xFF}.{(rel >> 16) & 0xFF}.{(rel >> 8) & 0xFF}"
        parts.append(f"{version} {kind}" if kind else version)
    sw = info.get("ver_sw")
    if isinstance(sw, str) and sw:
        parts.append(f"(git {sw[:8]})")
    name = info.get("sys_name") if isinstance(info.get("sys_name"), str) else "PX4"
    return " ".join([name, *parts]) if parts else "unknown"


def vehicle_type(params: dict[str, Any]) -> str:
    """Vehicle type from the ``MAV_TYPE`` parameter ('unknown' without it)."""
    mav_type = params.get("MAV_TYPE")
    if mav_type is not None:
        try:
            return MAV_TYPES.get(int(mav_type), f"mav-type-{int(mav_type)}")
        except (TypeError, ValueError):
            pass
    return "unknown"


def parse_topic_name(name: str) -> tuple[str, int]:
    """'estimator_attitude[1]' → ('estimator_attitude', 1); 'vehicle_attitude' → (..., 0)."""
    m = re.fullmatch(r"\s*([A-Za-z0-9_]+)\s*(?:\[\s*(\d+)\s*\])?\s*", name)
    if not m:
        raise ConfigError(
            f"reference {name!r} is not a topic name like 'vehicle_attitude' or 'estimator_attitude[1]'"
        )
    return m.group(1), int(m.group(2) or 0)


def topic_label(name: str, multi_id: int) -> str:
    return name if multi_id == 0 else f"{name}[{multi_id}]"


def rate_hz(t_s: np.ndarray) -> float | None:
    p = nominal_period_s(t_s)
    return float(1.0 / p) if np.isfinite(p) and p > 0 else None


def vec(data: dict[str, np.ndarray], prefix: str, n: int = 3) -> np.ndarray:
    """Stack pyulog's flattened array fields ``prefix[0]``..``prefix[n-1]`` into ``(N, n)`` float64. (A corrupt
    value — a signalling NaN in a damaged file — is cast without numpy's warning: the readers judge non-finite rows.)"""
    with np.errstate(invalid="ignore", over="ignore"):
        return np.column_stack([np.asarray(data[f"{prefix}[{i}]"], np.float64) for i in range(n)])


def sample_times_us(data: dict[str, np.ndarray]) -> tuple[np.ndarray, bool]:
    """``timestamp_sample`` where plausible (positive, ≤ timestamp, < 1 s before it), else ``timestamp``."""
    t = np.asarray(data["timestamp"], np.int64)
    ts = data.get("timestamp_sample")
    if ts is None or len(ts) == 0:
        return t, False
    ts = np.asarray(ts, np.int64)
    lag = t - ts
    if np.all(ts > 0) and np.all(lag >= 0) and np.median(lag) < 1_000_000:
        return ts, True
    return t, False


def ensure_breaks(t_s: np.ndarray, break_t_s: np.ndarray) -> tuple[np.ndarray, list[dict]]:
    """Keep-mask on samples so that a segment (or reference coverage) ends at each break time.

    The assembler starts a new IMU segment, and leaves the reference uncovered, where a step
    exceeds ``GAP_PERIODS`` nominal periods. For each break time (a dropout, stamped by pyulog with
    the latest timestamp seen before it; or the last sample before an EKF reset) we find the step
    across it; if that step is not already such a gap, the samples after the break are dropped
    until it is. Returns the mask and, per break, ``{"t_s", "inside_span", "samples_dropped"}``.
    """
    t_s = np.asarray(t_s, np.float64)
    keep = np.ones(len(t_s), bool)
    info = []
    period = nominal_period_s(t_s)
    for tb in np.sort(np.asarray(break_t_s, np.float64)):
        rec = {"t_s": float(tb), "inside_span": bool(len(t_s) and t_s[0] <= tb < t_s[-1]), "samples_dropped": 0}
        if rec["inside_span"] and np.isfinite(period):
            i = int(np.searchsorted(t_s, tb, side="right")) - 1  # last sample at or before the break
            while i > 0 and not keep[i]:
                i -= 1
            kept_before = int(keep.sum())
            j = i + 1
            # 5 % margin: the assembler re-estimates the period (median step) after this drop
            while j < len(t_s) and t_s[j] - t_s[i] <= GAP_PERIODS * period * 1.05:
                keep[j] = False
                j += 1
            rec["samples_dropped"] = kept_before - int(keep.sum())
        info.append(rec)
    return keep, info


# --------------------------------------------------------------------------- parsing


class _ParseStalled(Exception):
    """pyulog stopped making progress (it can seek back and forth forever on garbled definitions)."""


class _GuardedFile:
    """The file object pyulog reads, with a budget on ``read`` calls.

    A healthy parse needs about two reads per message (≥ 4 bytes each), and pyulog's corruption
    recovery advances at least one byte per two reads, so ``4 × size + 10000`` reads is never hit
    by a parse that makes progress; pyulog 1.3's definitions loop can otherwise spin forever.
    """

    def __init__(self, path: str | os.PathLike):
        self._f = open(path, "rb")
        self._budget = 4 * os.fstat(self._f.fileno()).st_size + 10_000
        self.short_reads = 0  # reads that got fewer bytes than asked for, not at a message boundary

    def read(self, n: int = -1) -> bytes:
        self._budget -= 1
        if self._budget < 0:
            raise _ParseStalled("parser stopped advancing through the file")
        data = self._f.read(n)
        if 0 <= len(data) < n and not (n == 3 and not data):
            self.short_reads += 1  # only a clean end of the file ends on an empty 3-byte header read
        return data

    @property
    def truncated(self) -> bool:
        """Some read ended inside a message (fewer bytes than asked for): the file is cut."""
        return self.short_reads > 0

    def seek(self, *args):
        return self._f.seek(*args)

    def tell(self) -> int:
        return self._f.tell()

    def close(self) -> None:
        self._f.close()


def _parse(path: str | os.PathLike):
    """pyulog parse restricted to the topics we use; its prints are captured, errors → CorruptLog."""
    from pyulog import ULog

    topics = list(IMU_TOPICS + MAG_TOPICS + REFERENCE_TOPICS + GNSS_TOPICS)
    out = io.StringIO()
    fh = _GuardedFile(path)
    try:
        with contextlib.redirect_stdout(out):
            ulog = ULog(fh, message_name_filter_list=topics)
    except MemoryError:
        raise CorruptLog("not a readable ULog (garbled header: implausible message sizes)", path) from None
    except _ParseStalled:
        reason = "garbled definitions: the parser stopped advancing"
        raise CorruptLog(f"not a readable ULog ({reason})", path) from None
    except OSError:  # a garbled size or offset made pyulog seek before the start of the file
        reason = "garbled header or definitions: offsets outside the file"
        raise CorruptLog(f"not a readable ULog ({reason})", path) from None
    except Exception as exc:  # pyulog raises ULogException, struct.error, IndexError, ...
        raise CorruptLog(f"not a readable ULog ({type(exc).__name__}: {_first_line(exc)})", path) from None
    finally:
        fh.close()
    ulog._tepinn_truncated = fh.truncated
    n_subscribed = len(getattr(ulog, "_subscriptions", {})) + len(getattr(ulog, "_filtered_message_ids", ()))
    if not ulog.data_list and n_subscribed == 0:
        raise CorruptLog("ULog without any logged data (truncated inside the definitions, or garbled)", path)
    return ulog, out.getvalue()


def _first_line(exc: BaseException) -> str:
    s = str(exc).strip().splitlines()
    return s[0] if s else "no message"


def _datasets(ulog) -> tuple[dict[tuple[str, int], dict[str, np.ndarray]], int]:
    """Topics by (name, instance), with ``timestamp``/``timestamp_sample`` as int64 µs minus an origin.

    The origin is 0 for boot time; for UNIX time (> 1e15 µs) it is the first whole second, so the
    seconds we hand on keep µs resolution (1.7e9 s in float64 would only resolve 0.24 µs and bias
    rates by ~1e-5). A zero ``timestamp_sample`` ends up negative and is then rejected as implausible.
    """
    ds = {(d.name, d.multi_id): d.data for d in ulog.data_list if len(d.data.get("timestamp", ())) > 0}
    firsts = [int(d["timestamp"][0]) for d in ds.values()]
    unix = [f for f in firsts if f > UNIX_TIME_THRESHOLD_US]
    origin = (min(unix) // 1_000_000) * 1_000_000 if unix and len(unix) * 2 > len(firsts) else 0
    out = {}
    for key, d in ds.items():
        d = dict(d)
        for f in ("timestamp", "timestamp_sample"):
            if f in d:
                d[f] = d[f].astype(np.int64) - origin
        out[key] = d
    return out, origin


# --------------------------------------------------------------------------- IMU


def _imu_from_sensor_combined(d: dict[str, np.ndarray], notes: list[str]) -> tuple[ImuStream, dict]:
    t_us = np.asarray(d["timestamp"], np.int64)
    gyr = vec(d, "gyro_rad")
    acc = vec(d, "accelerometer_m_s2")
    info: dict[str, Any] = {}
    rel = d.get("accelerometer_timestamp_relative")
    if rel is not None:
        rel = np.asarray(rel, np.int64)
        valid = rel != RELATIVE_TIMESTAMP_INVALID
        if not valid.any():
            raise NoImuData("sensor_combined: every accelerometer sample is marked invalid "
                            "(accelerometer_timestamp_relative): no accelerometer to estimate from")  # fmt: skip
        if not np.all(valid) or np.any(rel[valid] != 0):
            t_acc = (t_us + rel)[valid].astype(np.float64)
            order = np.argsort(t_acc, kind="stable")
            a_valid = acc[valid][order]
            acc = np.column_stack([np.interp(t_us.astype(np.float64), t_acc[order], a_valid[:, k]) for k in range(3)])
            med = float(np.median(rel[valid])) if valid.any() else float("nan")
            notes.append(f"sensor_combined: accelerometer interpolated onto the gyro times "
                         f"(accelerometer_timestamp_relative median {med:.0f} us)")  # fmt: skip
    clipped, gyr_clipped = _clip_flags(d, "gyro_clipping", "accelerometer_clipping", slice(None), len(t_us))
    if "gyro_integral_dt" in d:
        dt_int, unit = integral_dt_s(d["gyro_integral_dt"])
        info["gyro_integral_dt_unit"] = unit
        info["gyro_integral_dt_s"] = dt_int
        period = nominal_period_s(us_to_s(t_us))
        if np.isfinite(dt_int) and np.isfinite(period) and dt_int < 0.5 * period:
            notes.append(
                f"sensor_combined is decimated: samples {1e3 * period:.1f} ms apart but each averages only "
                f"{1e3 * dt_int:.1f} ms (gyro_integral_dt): vibration and fast motion alias; "
                "log sensor_combined at full rate (SDLOG_PROFILE high rate) for estimation"
            )
    return ImuStream(us_to_s(t_us), gyr, acc, clipped, gyr_clipped=gyr_clipped), info


def _clip_flags(d: dict[str, np.ndarray], gyro_field: str, accel_field: str, rows, n: int):
    """(clipped, gyr_clipped) from PX4's per-axis clipping bit fields: absent fields mark nothing (older
    PX4 logs the accelerometer's field alone: none of its marks is the gyro's)."""
    flag = {f: np.asarray(d[f]).astype(np.int64)[rows] != 0 for f in (gyro_field, accel_field) if f in d}
    gyr_clipped = flag.get(gyro_field, np.zeros(n, bool))
    clipped = np.zeros(n, bool)
    for v in flag.values():
        clipped |= v
    return clipped, gyr_clipped


def _imu_from_vehicle_imu(d: dict[str, np.ndarray]) -> ImuStream:
    t_us, _ = sample_times_us(d)
    da_dt = np.asarray(d["delta_angle_dt"], np.float64) * 1e-6
    dv_dt = np.asarray(d["delta_velocity_dt"], np.float64) * 1e-6
    ok = (da_dt > 0) & (dv_dt > 0)
    gyr = vec(d, "delta_angle")[ok] / da_dt[ok, None]
    acc = vec(d, "delta_velocity")[ok] / dv_dt[ok, None]
    clipped, gyr_clipped = _clip_flags(d, "delta_angle_clipping", "delta_velocity_clipping", ok, int(ok.sum()))
    return ImuStream(us_to_s(t_us[ok]), gyr, acc, clipped, gyr_clipped=gyr_clipped)


def _imu_from_sensor_topics(g: dict[str, np.ndarray], a: dict[str, np.ndarray]) -> ImuStream:
    tg, _ = sample_times_us(g)
    ta, _ = sample_times_us(a)
    gyr = np.column_stack([np.asarray(g[k], np.float64) for k in "xyz"])
    acc_raw = np.column_stack([np.asarray(a[k], np.float64) for k in "xyz"])
    order = np.argsort(ta, kind="stable")
    tq = tg.astype(np.float64)
    acc = np.column_stack([np.interp(tq, ta[order].astype(np.float64), acc_raw[order][:, k]) for k in range(3)])
    inside = (tg >= ta.min()) & (tg <= ta.max())
    return ImuStream(us_to_s(tg[inside]), gyr[inside], acc[inside], np.zeros(int(inside.sum()), bool))


def _selected_instance(ds, n_instances: int, notes: list[str]) -> tuple[int, bool]:
    """Physical instance that ``sensor_combined`` carries: by gyro device id, else assume 0."""
    sel = ds.get(("sensor_selection", 0))
    if sel is None or "gyro_device_id" not in sel:
        return 0, False
    ids = np.unique(np.asarray(sel["gyro_device_id"]))
    if len(ids) > 1:
        notes.append(f"PX4 switched the selected gyro during the log (device ids {ids.tolist()}): "
                     "sensor_combined mixes IMUs")  # fmt: skip
    target = int(np.asarray(sel["gyro_device_id"])[0])
    for topic, field in (("vehicle_imu", "gyro_device_id"), ("sensor_gyro", "device_id")):
        for k in range(n_instances):
            d = ds.get((topic, k))
            if d is not None and field in d and len(d[field]) and int(d[field][0]) == target:
                return k, True
    return 0, False


def _imu_instances(ds) -> tuple[list[int], str | None]:
    """Physical instance numbers and the per-instance topic family that lists them."""
    for topic in ("vehicle_imu", "sensor_gyro"):
        ks = sorted(k for (name, k) in ds if name == topic)
        if ks:
            return ks, topic
    return ([0] if ("sensor_combined", 0) in ds else []), None


def _vehicle_imu_faster(ds, k: int) -> bool:
    """Whether ``vehicle_imu[k]`` is logged at over 1.5× the rate of ``sensor_combined`` (the same IMU, decimated by the
    logging profile while a custom topic list logs the other at full rate; review59: the 200-Hz copy was neither
    listed nor read, and the log was called too slow to estimate)."""
    vi = ds.get(("vehicle_imu", k))
    if vi is None or not len(vi.get("timestamp", ())):
        return False
    sc = rate_hz(us_to_s(ds[("sensor_combined", 0)]["timestamp"])) or 0.0
    own = rate_hz(us_to_s(sample_times_us(vi)[0])) or 0.0
    return own > PREFER_FACTOR * sc


def _select_imu(ds, imu: int | None, notes: list[str]) -> tuple[ImuStream, dict]:
    instances, family = _imu_instances(ds)
    if not instances:
        have = sorted({topic_label(n, k) for (n, k) in ds})
        raise NoImuData(
            "no IMU topic with data (sensor_combined, vehicle_imu, sensor_gyro/sensor_accel); "
            f"topics read: {', '.join(have) if have else 'none'}"
        )
    has_sc = ("sensor_combined", 0) in ds
    selected, matched = _selected_instance(ds, max(instances) + 1, notes) if family else (0, True)

    def source_of(k: int) -> str:
        if has_sc and k == selected and not _vehicle_imu_faster(ds, k):
            return "sensor_combined"
        if ("vehicle_imu", k) in ds:
            return topic_label("vehicle_imu", k)
        if ("sensor_gyro", k) in ds and ("sensor_accel", k) in ds:
            return f"sensor_gyro[{k}]+sensor_accel[{k}]"
        return ""

    table = []
    for k in instances:
        name = source_of(k)
        if not name:
            continue
        if name == "sensor_combined":
            t = us_to_s(ds[("sensor_combined", 0)]["timestamp"])
        elif name.startswith("vehicle_imu"):
            t = us_to_s(sample_times_us(ds[("vehicle_imu", k)])[0])
        else:
            t = us_to_s(sample_times_us(ds[("sensor_gyro", k)])[0])
        table.append({"instance": k, "name": name, "samples": int(len(t)), "rate_hz": rate_hz(t),
                      "selected": bool(k == selected)})  # fmt: skip
    listing = ", ".join(f"{r['instance']} ({r['name']}, {r['rate_hz'] or 0:.1f} Hz)" for r in table)
    want = selected if imu is None else int(imu)
    row = next((r for r in table if r["instance"] == want), None)
    if row is None:
        if imu is None:
            row = table[0]
        else:
            raise NoImuData(f"IMU instance {imu} is not in the log; instances: {listing or 'none'}")
    meta: dict[str, Any] = {"imu_instance": row["instance"], "imu_topic": row["name"], "imu_instances": table}
    if family and not matched and row["name"] == "sensor_combined":
        notes.append("sensor_selection missing or unmatched: assuming sensor_combined is IMU instance 0")
    k = row["instance"]
    if row["name"] == "sensor_combined":
        stream, info = _imu_from_sensor_combined(ds[("sensor_combined", 0)], notes)
        meta.update(info)
    elif row["name"].startswith("vehicle_imu"):
        stream = _imu_from_vehicle_imu(ds[("vehicle_imu", k)])
        notes.append(f"IMU from vehicle_imu[{k}] (delta_angle/delta_velocity over their dt): only the "
                     "snapshots the logger kept, not a continuous stream")  # fmt: skip
    else:
        stream = _imu_from_sensor_topics(ds[("sensor_gyro", k)], ds[("sensor_accel", k)])
        notes.append(f"IMU from sensor_gyro[{k}]/sensor_accel[{k}]: raw driver output, not calibrated")
    return _with_value_clipping(stream, notes), meta


def _with_value_clipping(stream: ImuStream, notes: list[str]) -> ImuStream:
    """``stream`` with the samples at their range by value marked too (:mod:`.saturation`, the rule of every
    reader): PX4 logs its own clipping flags for the accelerometer at most before v1.15, so a flip past the gyro's
    range left ``gyr_clipped`` empty (session 53). PX4's own gyro clipping bits are kept as the gyro's saturation only
    where the logged rate shows one (:func:`~.saturation.credible_gyro_clipping`, rule 35); the others stay in
    ``clipped`` (a sensor clipped) and are said."""
    if stream.gyr_clipped is not None and np.any(stream.gyr_clipped):
        bits = np.asarray(stream.gyr_clipped, bool)
        kept = credible_gyro_clipping(stream.gyr_rad_s, bits)
        if int(bits.sum()) > int(kept.sum()):
            notes.append(f"{int(bits.sum() - kept.sum())} of {int(bits.sum())} sample(s) with PX4's gyro clipping bit "
                         "set show a logged rate under half the gyro's range (a raw sample clipped by vibration): "
                         "not taken as the gyro's saturation")  # fmt: skip
            stream = dataclasses.replace(stream, gyr_clipped=kept)
    g = gyro_saturated(stream.gyr_rad_s)
    c = g | accel_saturated(stream.acc_m_s2)
    if not c.any():
        return stream
    had = np.zeros(len(c), bool) if stream.clipped is None else np.asarray(stream.clipped, bool)
    had_g = np.zeros(len(c), bool) if stream.gyr_clipped is None else np.asarray(stream.gyr_clipped, bool)
    notes.append(f"{int(c.sum())} IMU sample(s) at ≥98 % of the sensor's range (gyro {int(g.sum())}): marked "
                 "clipped")  # fmt: skip
    return dataclasses.replace(stream, clipped=had | c, gyr_clipped=had_g | g)


# --------------------------------------------------------------------------- magnetometer, reference


def _mag(ds, notes: list[str]) -> tuple[MagStream | None, str]:
    d = ds.get(("vehicle_magnetometer", 0))
    if d is not None and "magnetometer_ga[0]" in d:
        t_us, _ = sample_times_us(d)
        return MagStream(us_to_s(t_us), vec(d, "magnetometer_ga") * GAUSS_TO_UT), "vehicle_magnetometer"
    d = ds.get(("sensor_combined", 0))
    if d is not None and "magnetometer_ga[0]" in d:
        t_us = np.asarray(d["timestamp"], np.int64)
        rel = np.asarray(d.get("magnetometer_timestamp_relative", np.zeros(len(t_us))), np.int64)
        ok = rel != RELATIVE_TIMESTAMP_INVALID
        tm = (t_us + rel)[ok]
        m = vec(d, "magnetometer_ga")[ok]
        # the 2016 topic repeats the latest magnetometer sample on every IMU row: keep new samples
        new = np.concatenate([[True], np.diff(tm) != 0]) if len(tm) else np.zeros(0, bool)
        return MagStream(us_to_s(tm[new]), m[new] * GAUSS_TO_UT), "sensor_combined.magnetometer_ga"
    d = ds.get(("sensor_mag", 0))
    if d is not None and "x" in d:
        t_us, _ = sample_times_us(d)
        notes.append("magnetometer from sensor_mag[0]: raw driver output, not calibrated")
        mag_ga = np.column_stack([np.asarray(d[k], np.float64) for k in "xyz"])
        return MagStream(us_to_s(t_us), mag_ga * GAUSS_TO_UT), "sensor_mag"
    return None, "none"


def _reference_candidates(ds) -> list[tuple[str, int]]:
    out = []
    for name in REFERENCE_TOPICS:
        for k in sorted(k for (n, k) in ds if n == name):
            if "q[0]" in ds[(name, k)]:
                out.append((name, k))
    return out


def _reference(ds, reference: str | None, notes: list[str]) -> tuple[RefStream | None, list[str]]:
    cands = _reference_candidates(ds)
    labels = [topic_label(n, k) for n, k in cands]
    if reference is not None:
        key = parse_topic_name(reference)
        if key not in cands:
            raise ConfigError(
                f"reference {reference!r} is not in this log; attitude topics available: "
                f"{', '.join(labels) if labels else 'none'}"
            )
    elif cands:
        key = cands[0]
    else:
        notes.append("no attitude topic (vehicle_attitude[_groundtruth], estimator_attitude) in the log")
        return None, labels
    d = ds[key]
    t_us, used_sample = sample_times_us(d)
    q = vec(d, "q", 4)
    norm = np.linalg.norm(q, axis=1)
    ok = np.isfinite(norm) & (norm > 0.5)
    if not np.all(ok):
        notes.append(f"{topic_label(*key)}: {int((~ok).sum())} invalid quaternions dropped")
    if "timestamp_sample" in d and not used_sample:
        notes.append(f"{topic_label(*key)}: timestamp_sample not usable (e.g. all 0): timed by timestamp")
    t_s, q = us_to_s(t_us[ok]), q[ok]
    if "quat_reset_counter" in d:
        counter = np.asarray(d["quat_reset_counter"], np.int64)[ok]
        after = np.flatnonzero(np.diff(counter) != 0) + 1  # first sample after each reset
        if len(after):
            keep, _ = ensure_breaks(t_s, t_s[after - 1])
            t_s, q = t_s[keep], q[keep]
            notes.append(
                f"{topic_label(*key)}: {len(after)} EKF quaternion reset(s) (attitude jumps): the reference "
                f"is left uncovered across each ({int((~keep).sum())} sample(s) dropped)"
            )
    return RefStream(t_s, q, topic_label(*key)), labels


def _gnss(ds, notes: list[str]) -> GnssVelStream | None:
    """The receiver's horizontal velocity (3-D fixes, valid NED velocity) on the log's clock, or
    None (with a note where the topic is logged but none of its rows is usable)."""
    name = next((n for n in GNSS_TOPICS if (n, 0) in ds), None)
    if name is None:
        return None
    d = ds[(name, 0)]
    if not all(f in d for f in GNSS_FIELDS):
        notes.append(f"{name} lacks {', '.join(f for f in GNSS_FIELDS if f not in d)}: no GNSS velocity")
        return None
    ok = (np.asarray(d["fix_type"]) >= MIN_3D_FIX) & (np.asarray(d["vel_ned_valid"]) != 0)
    vel_ne = np.column_stack([np.asarray(d["vel_n_m_s"], np.float64), np.asarray(d["vel_e_m_s"], np.float64)])
    ok &= np.all(np.isfinite(vel_ne), axis=1)
    if not ok.any():
        notes.append(f"{name}: none of its {len(ok)} row(s) has a 3-D fix with a valid velocity: no GNSS velocity")
        return None
    return GnssVelStream(us_to_s(np.asarray(d["timestamp"], np.int64)[ok]), vel_ne[ok], name)


# --------------------------------------------------------------------------- entry point


def read(path: str | os.PathLike, imu: int | None = None, reference: str | None = None) -> RawLog:
    """Parse a PX4 ULog into raw streams (see the module docstring for the rules)."""
    if reference is not None:
        parse_topic_name(reference)  # a malformed name fails before parsing
    ulog, printed = _parse(path)
    notes: list[str] = []
    if getattr(ulog, "has_data_appended", False):
        keys = sorted(getattr(ulog, "msg_info_multiple_dict", {}) or {})
        notes.append("log has appended data sections" + (f" ({', '.join(keys)})" if keys else ""))
    try:
        ds, origin_us = _datasets(ulog)
        imu_stream, imu_meta = _select_imu(ds, imu, notes)
        mag, mag_source = _mag(ds, notes)
        ref, cands = _reference(ds, reference, notes)
        gnss = _gnss(ds, notes)
    except TepinnError:
        raise
    except (KeyError, ValueError, IndexError) as exc:
        reason = f"ULog topics lack expected fields ({type(exc).__name__}: {_first_line(exc)})"
        raise CorruptLog(reason, path) from None

    base = "unix" if origin_us else "boot"
    # a "dropout" of 0 ms lost nothing (pyulog lists them): not a dropout
    dropouts = [d for d in (getattr(ulog, "dropouts", []) or []) if int(d.duration) > 0]
    drop_t = us_to_s(np.array([int(d.timestamp) - origin_us for d in dropouts], np.int64))
    # the IMU's own stamps say what a dropout cost it: a lost sample is a longer step (integrated over its own time, or a
    # gap bridged or restarted by record_gaps' rules); samples are never dropped to force a break there (before session
    # 53 they were, where the IMU had lost none, and the estimators then bridged the break they made anyway)
    t_imu = imu_stream.t_s
    period = nominal_period_s(t_imu)
    t0 = float(t_imu[0]) if len(t_imu) else 0.0  # notes in record time, as `info` shows it
    drop_info = []
    for tb, d in zip(drop_t, dropouts):
        at = f"t={tb - t0:.3f} s (record time)"
        inside = bool(len(t_imu) and t_imu[0] <= tb < t_imu[-1])
        lost = None
        if not inside:
            notes.append(f"logging dropout of {d.duration} ms stamped {at}, outside the IMU samples")
        elif np.isfinite(period) and period > 0:
            i = int(np.searchsorted(t_imu, tb, side="right")) - 1
            lost = max(0, int(round((t_imu[i + 1] - t_imu[i]) / period)) - 1)
            gap_ms = (t_imu[i + 1] - t_imu[i]) * 1e3  # (the logger's figure is its own: the IMU's stamps say the gap)
            notes.append(f"logging dropout of {d.duration} ms (the logger's figure) at {at}: "
                         + (f"{lost} IMU sample(s) lost there, the IMU's stamps skipping {gap_ms:.0f} ms" if lost
                            else "no IMU sample lost there"))  # fmt: skip
        drop_info.append({"t_s": float(tb), "inside_span": inside, "duration_s": float(d.duration) * 1e-3,
                          "imu_samples_lost": lost})  # fmt: skip
    corrupt = bool(getattr(ulog, "file_corruption", False)) or "corruption" in printed.lower()
    if getattr(ulog, "_tepinn_truncated", False):
        # (a garbled length in a damaged file reads short too: said so where pyulog found corruption; review60)
        notes.append("the log ends inside a message (" + ("cut, or a damaged message's length read past its end"
                     if corrupt else "the logger stopped mid-write or the file was cut") + "); the samples before "
                     "are kept")  # fmt: skip
    if corrupt:
        notes.append("pyulog detected file corruption and resynchronised: some messages were lost")

    info = dict(getattr(ulog, "msg_info_dict", {}) or {})
    params = dict(getattr(ulog, "initial_parameters", {}) or {})
    meta = {
        "source_kind": "ulog",
        "autopilot": "px4",
        "vehicle_type": vehicle_type(params),
        "firmware": firmware_string(info),
        "hardware": str(info.get("ver_hw", "unknown")),
        **imu_meta,
        "reference_candidates": cands,
        "magnetometer_source": mag_source,
        "time_base": base,
        "time_origin_unix_s": origin_us * 1e-6,  # source clock = t_s + this (0 for boot time)
        "skipped_frames": len(dropouts),
        "corrupt_frames": int(corrupt),
        "ulog_dropouts": drop_info,
        "notes": notes,
    }
    return RawLog(imu=imu_stream, mag=mag, ref=ref, meta=meta, gnss=gnss)
