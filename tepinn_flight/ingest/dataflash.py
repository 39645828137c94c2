"""ArduPilot DataFlash logs (binary ``.bin`` and text ``.log``) → :class:`RawLog`.

Binary logs are read by :mod:`.dataflash_binary` (mmap, bulk decode of the wanted message ids
only), text logs by :mod:`.dataflash_text` (numpy line classification, pandas' C CSV parser).
Both implement the small interface of :mod:`.dataflash_source`, so the stream rules below are
written once.

Streams
    IMU   ``IMU``/``IMU2``/``IMU3`` (old logs: instances 0/1/2) or 4.x ``IMU`` with instance
          column ``I``. Gyro rad/s, accel m/s² FRD, already SI. Default: the lowest instance with rows,
          unless another holds over 1.5× its samples (``streams.covering_instance``).
    MAG   ``MAG``/``MAG2``/``MAG3`` or ``MAG[I]``, milliGauss × 0.1 → µT; chosen as the IMU is, on its
          own (compasses and IMUs are numbered apart).
    ref   quaternions ``XKQ[C]`` (EKF3), ``NKQ1``/``NKQ2``/``NKQ[C]`` (EKF2) or ``AHR2`` with
          Q1..Q4 (w, x, y, z body→NED); Euler ``ATT``/``AHR2``/``EKF1``/``NKF1``/``XKF1``
          (degrees, Z-Y-X, yaw 0–360). Default: XKQ core 0, else NKQ1, else NKQ core 0, else
          XKQ1 (EKF3 of 3.6–4.0), else ATT. ``reference=`` picks any candidate by name, case-
          insensitive, with ``[k]`` for core/instance k (``XKQ[1]``); an absent one is a
          :class:`ConfigError` listing the candidates. XKQ/NKQ (the EKF cores' quaternions) are in
          the IMU board's frame; the others are the vehicle's attitude, turned into the board's by
          the level trim ``AHRS_TRIM_X/Y`` (:mod:`.ahrs_trim`; meta ``ahrs_trim_rad``).
    GNSS  ``GPS`` (4.x: its lowest instance ``I``, the first receiver, unless another has over 1.5× its rows with a
          3-D fix; never ``GPS2``), rows with
          ``Status`` ≥ 3 (3-D fix): north, east = ``Spd`` · (cos, sin) ``GCrs`` (m/s, degrees).
    time  ``TimeUS`` (µs) or ``TimeMS`` (ms) since boot. Messages without either (Copter 3.0.x)
          cannot be timed. The ``GPS`` of old logs (ArduCopter ≤ 3.3) has ``TimeMS`` = GPS time
          of week and its boot time (ms) in ``T``: GPS is timed by ``TimeUS``, else ``T``, else a
          ``TimeMS`` that lies within the IMU's span (otherwise no GNSS stream, and a note).
          Boot epochs follow the rule of :func:`detect_epochs` (time jumps back > 1 s) on the
          merged clock of the IMU, MAG and reference, in file order (a reboot makes time jump
          back); each GPS row takes the epoch of the IMU row written before it, so a late GPS
          time stamp cannot pass for a reboot.

Clipping rule (``ImuStream.clipped``), a sample is marked when any of:
    * a gyro axis reaches 98 % of the ±2000 °/s full scale (|ω| ≥ 34.2 rad/s) — the logged IMU is
      a 20 Hz low-pass snapshot, so a saturated sensor shows slightly below full scale;
    * an accel axis reaches 98 % of ±16 g (|a| ≥ 153.8 m/s²);
    * the ``VIBE`` accel clip counter of that IMU (``Clip`` in 4.x, ``Clip0..2`` in 3.3+) increased
      since the previous VIBE row: all IMU rows written between the two VIBE rows are marked;
    * 4.x health flags ``GH``/``AH`` are 0, or the error counters ``EG``/``EA`` increased.
The gyro's part (``ImuStream.gyr_clipped``: its full scale, ``GH``, ``EG``) is kept apart: only a
saturated or failing gyro makes the integrated rate wrong (the anchored estimator's saturation gate);
the VIBE counters count accelerometer clipping alone.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from ..conventions import DEG_TO_RAD, MILLIGAUSS_TO_UT
from ..errors import ConfigError, CorruptLog, NoImuData
from ..quat import quat_from_euler_zyx, quat_normalize
from . import dataflash_scan as dfs
from .ahrs_trim import TRIM_PARAMS, trim_note, usable_trim, vehicle_to_board
from .assemble import time_spikes
from .dataflash_binary import BinarySource
from .dataflash_source import DECODE_BLOCK_ROWS, DataflashSource, instance_col
from .dataflash_text import TextSource
from .saturation import accel_saturated, gyro_saturated
from .sniff import sniff
from .streams import (GnssVelStream, ImuStream, MagStream, RawLog, RefStream, covering_instance, covering_note,
                      detect_epochs, nominal_period_s)


TIME_FIELDS = {"TimeUS": 1e6, "TimeMS": 1e3}  # ticks per second (divide: exact for whole ms)
GYR = ("GyrX", "GyrY", "GyrZ")
ACC = ("AccX", "AccY", "AccZ")
MAGC = ("MagX", "MagY", "MagZ")
QUAT = ("Q1", "Q2", "Q3", "Q4")
EULER = ("Roll", "Pitch", "Yaw")
GPS_VEL = ("Status", "Spd", "GCrs")  # fix type, ground speed m/s, course over ground degrees from north
GPS_TIME_FIELDS = {"TimeUS": 1e6, "T": 1e3, "TimeMS": 1e3}  # in this order; TimeMS may be GPS time of week
MIN_3D_FIX = 3  # GPS Status: 3 = 3-D fix (4, 5, 6: DGPS, RTK float, RTK fixed)
REBOOT_BACKSTEP_S = 1.0  # time jumping back more than this (s) is a reboot (streams.detect_epochs)

#: Reference message families (listing order of ``reference_candidates``) and the default choice.
QUAT_REFS = ("XKQ", "NKQ1", "NKQ", "NKQ2", "XKQ1", "XKQ2")
EULER_REFS = ("ATT", "AHR2", "XKF1", "NKF1", "EKF1")
DEFAULT_ORDER = ("XKQ", "NKQ1", "NKQ", "XKQ1", "ATT")
#: ... where the log's AHRS_EKF_TYPE names the EKF the autopilot flies on, that EKF's quaternions first (review59: a
#: 4.0 log flying EKF3 took the shadow EKF2's NKQ1, 4° off the attitude the autopilot used)
EKF_FAMILIES = {2: ("NKQ1", "NKQ"), 3: ("XKQ", "XKQ1")}

_FIRMWARE_RE = re.compile(r"^\s*((Ardu\w+|APM:\w+|APMrover2|AntennaTracker|Blimp)\s+V?\d[^\s]*)")
#: a firmware string's family → the record's ``vehicle_type`` (a helicopter build first: its name holds "copter" too)
_VEHICLES = (("heli", "helicopter"), ("copter", "copter"), ("plane", "plane"), ("sub", "sub"),
             ("rover", "rover"), ("tracker", "antenna_tracker"), ("blimp", "blimp"))  # fmt: skip


# --------------------------------------------------------------------------- streams


@dataclass
class _Instance:
    name: str  # message name
    instance: int
    samples: int
    rows: np.ndarray | None = None  # row indices into that message (None: all rows)


def _time_field(mf: dfs.MsgFormat) -> str | None:
    for f in TIME_FIELDS:
        if f in mf.columns:
            return f
    return None


def _has(src: DataflashSource, name: str, cols: tuple[str, ...]) -> bool:
    return set(cols) <= set(src.formats[name].columns)


def _instances(src: DataflashSource, base: str, numbered: tuple[str, ...] = (), rows: bool = True) -> list[_Instance]:
    """Instances with rows of a multi-instance message: ``NAME[I]`` columns or NAME, NAME2, NAME3.

    ``rows=False`` only counts (no decoding where the scan counted instances already).
    """
    out: list[_Instance] = []
    mf = src.formats.get(base)
    if mf is not None and src.count(base) and _time_field(mf) is not None:
        col = instance_col(mf)
        if col is None:
            out.append(_Instance(base, 0, src.count(base)))
        elif rows:
            inst = src.instance_column(base, col)
            for v in np.unique(inst[np.isfinite(inst)]).astype(int):
                r = np.flatnonzero(inst == v)
                out.append(_Instance(base, int(v), len(r), r))
        else:
            out += [_Instance(base, v, n) for v, n in sorted(src.instance_counts(base, col).items())]
    for k, name in enumerate(numbered, start=1):
        f = src.formats.get(name)
        if f is not None and src.count(name) and _time_field(f) is not None and not any(i.instance == k for i in out):
            out.append(_Instance(name, k, src.count(name)))
    return sorted(out, key=lambda i: i.instance)


def _with_rows(src: DataflashSource, inst: _Instance) -> _Instance:
    """The instance with its row indices resolved (for messages with an instance column)."""
    col = instance_col(src.formats[inst.name])
    if col is None or inst.rows is not None:
        return inst
    r = np.flatnonzero(src.instance_column(inst.name, col) == inst.instance)
    return _Instance(inst.name, inst.instance, len(r), r)


def _timed(src: DataflashSource, inst: _Instance, cols: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(t_s, values (n, len(cols))) of one instance, time field scaled to seconds."""
    tf = _time_field(src.formats[inst.name])
    arr = src.table(inst.name, (tf, *cols), inst.rows)
    return arr[:, 0] / TIME_FIELDS[tf], arr[:, 1:]


def _order(src: DataflashSource, inst: _Instance) -> np.ndarray:
    o = src.order(inst.name)
    return o if inst.rows is None else o[inst.rows]


def _reference_candidates(src: DataflashSource) -> dict[str, _Instance]:
    """Reference streams with rows and a time field, by label (``XKQ``, ``XKQ[1]``, ``ATT``...)."""
    out: dict[str, _Instance] = {}
    for name in QUAT_REFS + EULER_REFS:
        mf = src.formats.get(name)
        if mf is None or not (set(QUAT) <= set(mf.columns) or set(EULER) <= set(mf.columns)):
            continue
        for inst in _instances(src, name, rows=False):
            out[name if inst.instance == 0 else f"{name}[{inst.instance}]"] = inst
    return out


def _requested_family(requested: str | None) -> str | None:
    if requested is None:
        return None
    m = re.match(r"\s*([A-Za-z0-9]+)", requested)
    return m.group(1).upper() if m else None


def _default_order(ekf_type: float | None) -> tuple[str, ...]:
    """The reference families in the order taken by default (:data:`DEFAULT_ORDER`, the flying EKF's first)."""
    first = EKF_FAMILIES.get(int(ekf_type)) if ekf_type is not None and np.isfinite(ekf_type) else None
    return tuple(dict.fromkeys((*first, *DEFAULT_ORDER))) if first else DEFAULT_ORDER


def _pick_reference(cands: dict[str, _Instance], requested: str | None,
                    order: tuple[str, ...] = DEFAULT_ORDER) -> tuple[str, _Instance] | None:  # fmt: skip
    if requested is None:
        for fam in order:
            hits = sorted((i.instance, lab) for lab, i in cands.items() if i.name == fam)
            if hits:
                return hits[0][1], cands[hits[0][1]]
        return None
    req = re.sub(r"\s+", "", requested).upper().replace("C=", "").replace("I=", "")
    for lab, inst in cands.items():
        if lab.upper() == req:
            return lab, inst
    m = re.fullmatch(r"([A-Z0-9]+)\[(\d+)\]", req)
    if m:
        for lab, inst in cands.items():
            if inst.name.upper() == m.group(1) and inst.instance == int(m.group(2)):
                return lab, inst
    avail = ", ".join(cands) if cands else "none"
    raise ConfigError(f"reference {requested!r} not in this log; available: {avail}")


def _ref_quaternions(src: DataflashSource, inst: _Instance) -> tuple[np.ndarray, np.ndarray]:
    mf = src.formats[inst.name]
    if set(QUAT) <= set(mf.columns):
        t, q = _timed(src, inst, QUAT)
        norm = np.linalg.norm(q, axis=-1)
        bad = ~(np.isfinite(norm) & (norm > 0.5) & (norm < 1.5))
        q[bad] = 1.0
        q = quat_normalize(q)
        q[bad] = np.nan
        return t, q
    # Euler degrees → quaternions block by block: the temporaries stay one block in size
    tf = _time_field(mf)
    rows = np.arange(src.count(inst.name)) if inst.rows is None else inst.rows
    t = np.empty(len(rows))
    q = np.empty((len(rows), 4))
    for i in range(0, len(rows), DECODE_BLOCK_ROWS):
        b = src.table(inst.name, (tf, *EULER), rows[i : i + DECODE_BLOCK_ROWS])
        t[i : i + DECODE_BLOCK_ROWS] = b[:, 0] / TIME_FIELDS[tf]
        e = b[:, 1:] * DEG_TO_RAD
        q[i : i + DECODE_BLOCK_ROWS] = quat_from_euler_zyx(e[:, 0], e[:, 1], e[:, 2])
    return t, q


def _clipped(src: DataflashSource, inst: _Instance, gyr: np.ndarray, acc: np.ndarray,
             order: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(clipped, gyr_clipped, notes): any sensor at its range or unhealthy, and the gyro's part of
    it (its range, ``GH`` unhealthy, ``EG`` errors)."""
    notes = []
    gyr_sat = gyro_saturated(gyr)
    sat = gyr_sat | accel_saturated(acc)
    clipped = sat.copy()
    gyr_clipped = gyr_sat.copy()
    mf = src.formats[inst.name]
    health = [c for c in ("GH", "AH") if c in mf.columns]
    errs = [c for c in ("EG", "EA") if c in mf.columns]
    if health or errs:
        d = src.table(inst.name, tuple(health + errs), inst.rows)
        bad = np.zeros(len(gyr), bool)
        for k, name in enumerate(health + errs):
            b = d[:, k] == 0 if name in health else np.r_[False, np.diff(d[:, k]) > 0]
            bad |= b
            if name in ("GH", "EG"):
                gyr_clipped |= b
        if bad.any():
            notes.append(
                f"{int(bad.sum())} IMU sample(s) unhealthy or with sensor errors (GH/AH/EG/EA): marked clipped"
            )
        clipped |= bad
    vibe = src.formats.get("VIBE")
    if vibe is not None and src.count("VIBE"):
        col, rows = None, None
        if "Clip" in vibe.columns and "IMU" in vibe.columns:
            col = "Clip"
            rows = np.flatnonzero(src.instance_column("VIBE", "IMU") == inst.instance)
        elif f"Clip{inst.instance}" in vibe.columns:
            col = f"Clip{inst.instance}"
        if col is not None:
            clip = src.table("VIBE", (col,), rows)[:, 0]
            v_order = src.order("VIBE") if rows is None else src.order("VIBE")[rows]
            inc = np.flatnonzero(np.diff(clip) > 0) + 1
            vmark = np.zeros(len(gyr), bool)
            for k in inc:  # IMU rows written between the two VIBE rows (file order)
                lo, hi = np.searchsorted(order, v_order[k - 1 : k + 1], "right")
                vmark[lo:hi] = True
            if vmark.any():
                notes.append(f"VIBE accel clip counter rose: {int(vmark.sum())} IMU sample(s) marked clipped")
            clipped |= vmark
    if sat.any():
        notes.append(f"{int(sat.sum())} IMU sample(s) at ≥98 % of the ±2000 °/s or ±16 g range: marked clipped")
    return clipped, gyr_clipped, notes


def _firmware(src: DataflashSource, messages: list[str]) -> tuple[str, str | None]:
    for s in [*messages, src.banner]:
        m = _FIRMWARE_RE.match(s or "")
        if m:
            return m.group(1), s
    if "VER" in src.formats and src.count("VER") and "FWS" in src.formats["VER"].columns:
        for s in src.strings("VER", "FWS"):
            if s:
                return s, s
    return "unknown", None


def _vehicle_type(firmware: str, param_names) -> str:
    """Vehicle family from the firmware string, else guessed from parameter names (callable: lazy)."""
    low = firmware.lower()
    for key, kind in _VEHICLES:
        if key in low:
            return kind
    params = param_names()
    if any(p.startswith(("WPNAV_", "PILOT_")) for p in params):
        return "copter"
    if any(p.startswith(("ARSPD_", "TECS_")) for p in params):
        return "plane"
    if "SURFACE_DEPTH" in params:
        return "sub"
    if "CRUISE_SPEED" in params:
        return "rover"
    return "unknown"


def _param(src: DataflashSource, name: str) -> float | None:
    """Last logged value of a parameter (None if absent)."""
    if "PARM" not in src.formats or not src.count("PARM") or not _has(src, "PARM", ("Name", "Value")):
        return None
    names = src.strings("PARM", "Name")
    if name not in names:
        return None
    vals = src.table("PARM", ("Value",))[:, 0]
    return float(vals[len(names) - 1 - names[::-1].index(name)])


def _rate(t: np.ndarray) -> float | None:
    p = nominal_period_s(t, detect_epochs(t))
    return round(1.0 / p, 3) if np.isfinite(p) and p > 0 else None


def _unspiked(name: str, t: np.ndarray, cols: tuple, order: np.ndarray, notes: list[str]):
    """((t, *cols), order) without the rows whose time stamp is a lone corrupt spike (:func:`.assemble.time_spikes`,
    the IMU's rule): DataFlash has no checksums, and one such reference or magnetometer row had been taken for a
    reboot on the merged clock (a restart of the estimators mid-flight; session 53)."""
    bad = time_spikes(t)
    if not bad.any():
        return (t, *cols), order
    notes.append(f"{int(bad.sum())} {name} row(s) with a corrupt time stamp dropped")
    keep = ~bad
    return (t[keep], *(c[keep] for c in cols)), order[keep]


def _merged_epochs(parts: list[tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
    """Boot epochs of several streams from their merged clock in file order.

    Each part is ``(t_s, file_position)`` with positions increasing; the merged order comes from
    ``searchsorted`` on the other parts' positions (no argsort, no merged position array).
    """
    total = sum(len(t) for t, _ in parts)
    t_merged = np.empty(total)
    where = []
    for a, (t_a, o_a) in enumerate(parts):
        pos = np.arange(len(o_a), dtype=np.int64)
        for b, (_, o_b) in enumerate(parts):
            if b != a:
                pos += np.searchsorted(o_b, o_a, side="right" if b < a else "left")
        t_merged[pos] = t_a
        where.append(pos)
    # the rule of streams.detect_epochs (new epoch where time jumps back more than 1 s), applied
    # through the jump positions so that no second merged-size array is needed
    jumps = np.flatnonzero(np.diff(t_merged) < -REBOOT_BACKSTEP_S)
    del t_merged
    return [np.searchsorted(jumps, pos, side="left").astype(np.int64) for pos in where]


# --------------------------------------------------------------------------- reader

_BASE_NAMES = {"IMU", "IMU2", "IMU3", "MAG", "MAG2", "MAG3", "VIBE", "MSG", "VER", "PARM", "GPS"}


def _gnss(src: DataflashSource, t_imu: np.ndarray, o_imu: np.ndarray, ep_imu: np.ndarray,
          notes: list[str]) -> tuple[GnssVelStream | None, str | None]:
    """(the first GPS's velocity over ground on the IMU's clock and epochs, its time field) or
    (None, None): no GPS rows, no boot time, or no 3-D fix (the last two with a note)."""
    mf = src.formats.get("GPS")
    if mf is None or not src.count("GPS") or not _has(src, "GPS", GPS_VEL):
        return None, None
    tf = next((f for f in GPS_TIME_FIELDS if f in mf.columns), None)
    if tf is None:
        notes.append("GPS carries no boot time (TimeUS, T or TimeMS): no GNSS velocity")
        return None, None
    col = instance_col(mf)
    rows = None
    if col is not None:  # 4.x: GPS[I]; the first receiver, unless another has over 1.5× its 3-D fixes (review59:
        inst = src.instance_column("GPS", col)  # a first receiver without a fix left a log with a second no velocity)
        fin = np.isfinite(inst)
        if fin.any():
            with np.errstate(invalid="ignore"):
                fixed = src.table("GPS", ("Status",), None)[:, 0] >= MIN_3D_FIX
            fixes = {int(k): int(np.sum(fixed & (inst == k))) for k in np.unique(inst[fin])}
            pick = covering_instance(fixes)
            if pick != min(fixes):
                notes.append(f"GPS: receiver {pick} read ({fixes[pick]} rows with a 3-D fix; receiver {min(fixes)}: "
                             f"{fixes[min(fixes)]})")  # fmt: skip
            rows = np.flatnonzero(inst == pick)
        else:
            rows = np.zeros(0, np.int64)
    g = src.table("GPS", (tf, *GPS_VEL), rows)
    order = src.order("GPS") if rows is None else src.order("GPS")[rows]
    t = g[:, 0] / GPS_TIME_FIELDS[tf]
    with np.errstate(invalid="ignore"):
        ok = (g[:, 1] >= MIN_3D_FIX) & np.all(np.isfinite(g), axis=1)
    if not ok.any():
        notes.append(f"GPS: none of its {len(g)} row(s) has a 3-D fix (Status ≥ {MIN_3D_FIX}): no GNSS velocity")
        return None, None
    if tf == "TimeMS":  # boot time in old logs without T, GPS time of week in others: the IMU's span tells
        inside = ok & (t >= t_imu.min() - 1.0) & (t <= t_imu.max() + 1.0)
        if inside.sum() < 0.9 * ok.sum():
            notes.append("GPS TimeMS is not on the IMU's boot clock (GPS time of week?): no GNSS velocity")
            return None, None
        ok = inside
    t, g, order = t[ok], g[ok], order[ok]
    crs = g[:, 3] * DEG_TO_RAD
    vel_ne = g[:, 2:3] * np.column_stack([np.cos(crs), np.sin(crs)])
    before = np.searchsorted(o_imu, order, side="right") - 1  # the IMU row written before each GPS row
    return GnssVelStream(t, vel_ne, "GPS", ep_imu[np.maximum(before, 0)]), tf


def read(path: str | os.PathLike, imu: int | None = None, reference: str | None = None) -> RawLog:
    """Parse a binary or text DataFlash log (see the module docstring for the rules)."""
    kind = sniff(path)
    if kind not in ("dataflash-bin", "dataflash-text"):
        raise CorruptLog(f"not a DataFlash log (sniffed as {kind})", path)
    # rows are kept only for what may be decoded; the other reference candidates are only counted
    wanted = _BASE_NAMES | set(DEFAULT_ORDER) | {_requested_family(reference) or "ATT"}
    counted = set(QUAT_REFS) | set(EULER_REFS)
    src: DataflashSource = (BinarySource if kind == "dataflash-bin" else TextSource)(path, wanted, counted)
    if not src.formats:
        raise CorruptLog("no valid FMT records: not a readable DataFlash log", path)

    messages = src.strings("MSG", "Message")
    firmware, fw_msg = _firmware(src, messages)
    frame = next((s.split(":", 1)[1].strip() for s in messages if s.startswith("Frame:")), None)
    meta: dict = {
        "source_kind": "dataflash",
        "dataflash_encoding": src.kind,
        "autopilot": "ardupilot",
        "firmware": firmware,
        "vehicle_type": _vehicle_type(fw_msg or firmware, lambda: set(src.strings("PARM", "Name"))),
    }
    if frame:
        meta["frame"] = frame
    # what the vehicle is, as its heartbeat would say it (a tlog's MAV_TYPE: vehicle_class.py): ArduCopter's
    # helicopter frames and ArduPlane's QuadPlanes run the copter and plane firmware (session 53)
    if meta["vehicle_type"] == "copter" and frame and frame.upper().startswith("HELI"):
        meta["vehicle_type"] = "helicopter"
    elif meta["vehicle_type"] == "plane" and (_param(src, "Q_ENABLE") or 0) >= 1:
        meta["vehicle_type"] = "vtol"
    notes: list[str] = []

    # ---- IMU
    imu_fmt = src.formats.get("IMU")
    numbered = [n for n in ("IMU2", "IMU3") if n in src.formats and src.count(n)]
    if imu_fmt is None and not numbered:
        present = ", ".join(sorted(n for n in src.counts if n != "FMT")) or "none"
        raise NoImuData(f"no IMU message defined in the log (messages with rows: {present})", path)
    if imu_fmt is None:  # its FMT lost or damaged, the others' whole: they are read (review60: the log was refused)
        notes.append(f"no usable definition (FMT) of IMU: {', '.join(numbered)} read (a damaged log?)")
    elif _time_field(imu_fmt) is None:
        if not any(src.count(n) for n in ("IMU", "IMU2", "IMU3")):
            raise NoImuData(
                "IMU is defined without a time field (TimeUS/TimeMS) and the log holds no IMU rows "
                "(ArduCopter 3.0.x-style log)", path)  # fmt: skip
        raise CorruptLog("IMU rows carry no time field (TimeUS/TimeMS): samples cannot be placed in time", path)
    every = _instances(src, "IMU", ("IMU2", "IMU3"))
    insts = [i for i in every if _has(src, i.name, GYR + ACC)]
    lacking = [i for i in every if i not in insts]
    if insts and lacking:  # (review60: left out unsaid)
        notes.append(f"IMU {', '.join(str(i.instance) for i in lacking)} left out: its definition (FMT) lacks "
                     f"{'/'.join(GYR + ACC)} (a damaged log?)")
    if not insts and any(src.count(n) for n in ("IMU", "IMU2", "IMU3")):
        raise CorruptLog(f"IMU messages lack the columns {', '.join(GYR + ACC)} (malformed FMT)", path)
    if not insts:
        bitmask = _param(src, "LOG_BITMASK")
        if bitmask is not None and np.isfinite(bitmask) and -(1 << 15) <= bitmask < 0:
            bitmask += 1 << 16  # ArduCopter 3.1's int16 parameter, read as the bits it sets (review60: shown negative)
        extra = f"; LOG_BITMASK={bitmask:g}" if bitmask is not None and np.isfinite(bitmask) else ""
        raise NoImuData(f"the log defines IMU but holds no IMU rows (IMU logging disabled, or the log ends before its "
                        f"first IMU row{extra})", path)  # fmt: skip
    if imu is None:
        cover = covering_instance({i.instance: i.samples for i in insts})
        first, sel = insts[0], next(i for i in insts if i.instance == cover)
        if sel is not first:
            notes.append(covering_note(sel.instance, sel.samples, first.instance, first.samples))
    else:
        hits = [i for i in insts if i.instance == imu]
        if not hits:
            have = ", ".join(str(i.instance) for i in insts)
            raise NoImuData(f"IMU instance {imu} has no samples; instances with data: {have}", path)
        sel = hits[0]
    t_imu, v = _timed(src, sel, (*GYR, *ACC))
    gyr, acc = v[:, :3], v[:, 3:]
    o_imu = _order(src, sel)
    clipped, gyr_clipped, clip_notes = _clipped(src, sel, gyr, acc, o_imu)
    notes += clip_notes
    ok = np.isfinite(t_imu) & np.all(np.isfinite(v), axis=1)
    if not ok.all():
        notes.append(f"{int((~ok).sum())} IMU row(s) with non-finite values dropped")
        t_imu, gyr, acc, o_imu, clipped, gyr_clipped = t_imu[ok], gyr[ok], acc[ok], o_imu[ok], clipped[ok], gyr_clipped[ok]
    if len(t_imu) == 0:
        raise NoImuData("no IMU rows with finite values", path)
    meta["imu_instance"] = sel.instance
    meta["imu_message"] = sel.name
    meta["imu_time_field"] = _time_field(src.formats[sel.name])
    meta["imu_instances"] = [
        {"instance": i.instance, "name": i.name, "samples": i.samples,
         "rate_hz": _rate(t_imu) if i is sel else _rate(_timed(src, i, ())[0])}
        for i in insts
    ]  # fmt: skip

    # ---- magnetometer: the first (the autopilot's primary compass) unless another covers the log, as the IMU —
    # not the IMU's instance number: compasses and IMUs are numbered apart (session 60: the IMU 1 read where IMU 0
    # stopped had taken compass 1 with it)
    parts = [(t_imu, o_imu)]
    mag = None
    mags = [i for i in _instances(src, "MAG", ("MAG2", "MAG3")) if _has(src, i.name, MAGC)]
    if mags:
        mcover = covering_instance({i.instance: i.samples for i in mags})
        msel = next(i for i in mags if i.instance == mcover)
        t_mag, m = _timed(src, msel, MAGC)
        (t_mag, m), o_mag = _unspiked("MAG", t_mag, (m,), _order(src, msel), notes)
        mag = MagStream(t_mag, m * MILLIGAUSS_TO_UT)
        parts.append((t_mag, o_mag))
        meta["mag_instance"] = msel.instance

    # ---- reference
    cands = _reference_candidates(src)
    meta["reference_candidates"] = list(cands)
    try:
        ekf_type = _param(src, "AHRS_EKF_TYPE")
        pick = _pick_reference(cands, reference, _default_order(ekf_type))
        if reference is None and pick is not None and pick != _pick_reference(cands, None):
            notes.append(f"reference {pick[0]}: the EKF the autopilot flies on (AHRS_EKF_TYPE {ekf_type:g})")
    except ConfigError as exc:
        raise ConfigError(exc.reason, path) from None
    ref = None
    trim = usable_trim(*(_param(src, n) for n in TRIM_PARAMS))
    if trim is not None:  # the board's attitude (estimates, the reference) is this far from ATT's vehicle attitude
        meta["level_trim_rad"] = list(trim)
    if pick is not None:
        label, rinst = pick
        rinst = _with_rows(src, rinst)
        t_ref, q = _ref_quaternions(src, rinst)
        (t_ref, q), o_ref = _unspiked(rinst.name, t_ref, (q,), _order(src, rinst), notes)
        if rinst.name not in QUAT_REFS and trim is not None:  # reported in the vehicle's frame (.ahrs_trim)
            q = vehicle_to_board(q, *trim)
            meta["ahrs_trim_rad"] = list(trim)
            notes.append(trim_note(label, trim))
        ref = RefStream(t_ref, q, label)
        parts.append((t_ref, o_ref))
    else:
        notes.append("no reference attitude (XKQ/NKQ/ATT/AHR2/EKF1 with a time field) in the log")

    # ---- boot epochs on the merged clock, in file order
    eps = _merged_epochs(parts)
    n_boots = int(max(e.max() for e in eps)) + 1
    if n_boots > 1:
        notes.append(f"time jumps back {n_boots - 1} time(s) (reboot): {n_boots} boot epochs")
    k = 1
    if mag is not None:
        mag.epoch = eps[k]
        k += 1
    if ref is not None:
        ref.epoch = eps[k]

    # ---- GNSS velocity (the first receiver, 3-D fixes), on the IMU's clock and epochs
    gnss, gnss_tf = _gnss(src, t_imu, o_imu, eps[0], notes)
    if gnss is not None:
        meta["gnss_time_field"] = gnss_tf

    # text tables are parsed lazily: their malformed lines are known only now
    meta["corrupt_frames"] = int(src.corrupt_frames)
    meta["skipped_frames"] = int(src.skipped_frames)
    meta["notes"] = list(src.notes) + notes
    return RawLog(ImuStream(t_imu, gyr, acc, clipped, eps[0], gyr_clipped), mag, ref, meta, gnss=gnss)
