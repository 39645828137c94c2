"""The flight record: one Parquet file, one row per IMU sample, every part reads and writes it.

Columns (exact names; frames and units in :mod:`tepinn_flight.conventions`):

====================================  ==========  ===============================================
``t_s``                               float64     seconds from the start of the record
``segment``                           int32       contiguous piece (new at gap > 2.5 periods,
                                                  time reversal or reboot); ``t_s`` strictly
                                                  increases inside a segment; estimators bridge
                                                  gaps ≤ 100 ms (:mod:`.record_gaps`)
``gyr_{x,y,z}_rad_s``                 float64     angular rate, body FRD
``acc_{x,y,z}_m_s2``                  float64     specific force, body FRD (level at rest z≈-9.81)
``mag_{x,y,z}_ut``                    float64     magnetometer µT, NaN where none
``q_ref_{w,x,y,z}``                   float64     reference attitude body→NED (slerp onto IMU
                                                  times), NaN where no reference covers the sample
``clipped``                           bool        a sensor axis at its range limit
====================================  ==========  ===============================================

Optional columns: ``valid`` (bool, BROAD's movement mask), ``gyr_clipped`` (bool, the samples of
``clipped`` where a gyro axis is at its range or unhealthy — where the reader can tell the sensors
apart; absent: every ``clipped`` sample counts), simulated truths ``gyr_bias_{x,y,z}_rad_s`` and
``acc_bias_{x,y,z}_m_s2``, and the GNSS receiver's horizontal velocity over ground
``gnss_vel_{n,e}_m_s`` (float64, NED, m/s; linear between fixes, NaN where no fix covers the
sample — what the GNSS-aided tilt reads, :mod:`tepinn_flight.model.gnss_aid`).

Key-value metadata: every key of :attr:`FlightRecord.meta` is stored as its own Parquet key with a
JSON value; ``format_version`` is mandatory and checked on read.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from glob import escape as glob_escape
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .errors import OutputError, RecordFormatError

FORMAT_VERSION = 1

GYR_COLS = ["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"]
ACC_COLS = ["acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2"]
MAG_COLS = ["mag_x_ut", "mag_y_ut", "mag_z_ut"]
QREF_COLS = ["q_ref_w", "q_ref_x", "q_ref_y", "q_ref_z"]
GYR_BIAS_COLS = ["gyr_bias_x_rad_s", "gyr_bias_y_rad_s", "gyr_bias_z_rad_s"]
ACC_BIAS_COLS = ["acc_bias_x_m_s2", "acc_bias_y_m_s2", "acc_bias_z_m_s2"]
GNSS_VEL_COLS = ["gnss_vel_n_m_s", "gnss_vel_e_m_s"]
# an estimate's columns (``estimate`` writes them, the harness reads them): attitude body FRD → NED and gyro bias
EST_Q_COLS = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]
EST_BIAS_COLS = ["gyr_bias_est_x_rad_s", "gyr_bias_est_y_rad_s", "gyr_bias_est_z_rad_s"]

REQUIRED_COLUMNS = ["t_s", "segment", *GYR_COLS, *ACC_COLS, *MAG_COLS, *QREF_COLS, "clipped"]
OPTIONAL_COLUMNS = ["valid", "gyr_clipped", *GYR_BIAS_COLS, *ACC_BIAS_COLS, *GNSS_VEL_COLS]
_DTYPES = {"t_s": "float64", "segment": "int32", "clipped": "bool", "valid": "bool", "gyr_clipped": "bool"}

SOURCE_KINDS = ("tlog", "dataflash", "ulog", "broad", "jsbsim", "synthetic")
#: the kinds whose reference is a simulator's truth; the others are real recordings
SIMULATED_KINDS = ("jsbsim", "synthetic")

# Physical limits, beyond the range of any sensor a drone or aircraft carries (the one home of these limits): the
# readers drop a sample outside them as a corrupt row (``ingest/assemble.drop_implausible``), and a record holding
# one is refused (:meth:`FlightRecord.validate`: a damaged file, or one written in other units).
#: |gyro| per axis (rad/s): ±4000 °/s, the widest MEMS range, is 70 rad/s
MAX_GYRO_RAD_S = 100.0
#: |specific force| per axis (m/s²): about 200 g (high-g accelerometers reach ±200 g)
MAX_ACC_M_S2 = 2000.0
#: |magnetic field| per axis (µT): the Earth's is 25–65 µT; a motor or magnet next to the sensor
#: saturates magnetometers at a few thousand µT
MAX_MAG_UT = 5000.0
#: |GNSS velocity| per axis (m/s): beyond any aircraft these tools serve (a corrupt row)
MAX_GNSS_SPEED_M_S = 600.0
#: |sample time| (s): boot times and UNIX times (1.7e9 s) alike are below this
MAX_ABS_TIME_S = 1e10
#: |quaternion component| of a reference: a unit quaternion's are ≤ 1 (a zero one means "none")
MAX_QUAT_COMPONENT = 1.5
#: a reference quaternion whose norm is off 1 by more than this is no attitude: the readers drop it as a corrupt row,
#: and :attr:`FlightRecord.q_ref_wxyz` gives NaN for it (a zero quaternion, as a broken logger writes "none", too)
MAX_QUAT_NORM_ERR = 0.1

#: Below this IMU rate windowed estimation is not meaningful; records are still written.
MIN_ESTIMATION_RATE_HZ = 20.0



def no_imu_reason(rec: "FlightRecord") -> str | None:
    """Why a record gives nothing to estimate — no sample, no finite gyro or accelerometer sample (nothing to
    bridge a hole with: a constant attitude, not an estimate), or an accelerometer that never reads gravity — or None
    where it does. ``estimate`` refuses such a
    record and ``evaluate`` too (it had scored every estimator on a record without an accelerometer sample)."""
    if len(rec) == 0:
        return "the record holds no IMU sample"
    for what, v in (("gyro", rec.gyr_rad_s), ("accelerometer", rec.acc_m_s2)):
        if not np.all(np.isfinite(v), 1).any():
            return f"no finite {what} sample in the record"
    acc = rec.acc_m_s2
    if np.linalg.norm(acc[np.all(np.isfinite(acc), 1)], axis=1).max() < MIN_ACC_SIGNAL_M_S2:
        return (f"the accelerometer reads under {MIN_ACC_SIGNAL_M_S2:g} m/s² on every sample (a sensor not logged, "
                "written as zeros?): no gravity to estimate a tilt from")
    return None


#: an accelerometer that never reads more than this (m/s²) shows no gravity: :func:`no_imu_reason` (a dead sensor's
#: zeros; a real one at rest reads 9.8 — 1.0 if written in g, which the scale
#: self-calibration divides out —, in free fall its noise, never a whole record of it)
MIN_ACC_SIGNAL_M_S2 = 0.5


def estimation_ok(meta: dict) -> bool:
    """Whether a record's IMU is fast enough for windowed estimation: the ``estimation_ok`` flag
    ``ingest`` writes (False: "IMU rate too low for estimation"), else ``imu_rate_hz`` ≥
    :data:`MIN_ESTIMATION_RATE_HZ`; True when neither is known."""
    flag = meta.get("estimation_ok")
    if flag is not None:
        return str(flag).lower() not in ("false", "0", "no")
    rate = meta.get("imu_rate_hz")
    return rate is None or float(rate) >= MIN_ESTIMATION_RATE_HZ


#: Metadata every record carries (others may be added freely).
REQUIRED_META = ("format_version", "source_file", "source_kind", "imu_rate_hz", "reference_source")


@dataclass
class FlightRecord:
    """A flight record in memory: the sample table and its metadata."""

    data: pd.DataFrame
    meta: dict[str, Any] = field(default_factory=dict)

    # ---- convenient typed views (numpy, float64)
    @property
    def t_s(self) -> np.ndarray:
        return self.data["t_s"].to_numpy(np.float64)

    @property
    def gyr_rad_s(self) -> np.ndarray:
        return self.data[GYR_COLS].to_numpy(np.float64)

    @property
    def acc_m_s2(self) -> np.ndarray:
        return self.data[ACC_COLS].to_numpy(np.float64)

    @property
    def mag_ut(self) -> np.ndarray:
        return self.data[MAG_COLS].to_numpy(np.float64)

    @property
    def q_ref_wxyz(self) -> np.ndarray:
        """(N, 4) the reference attitude; NaN where there is none — NaN in the file, or a quaternion that is no
        rotation (its norm off 1 by more than :data:`MAX_QUAT_NORM_ERR`: zeros, a damaged row), which every
        scorer had taken for an attitude (an all-zero reference scored 180° for every estimator)."""
        q = self.data[QREF_COLS].to_numpy(np.float64)
        with np.errstate(invalid="ignore"):
            none = np.abs(np.sqrt(np.einsum("ij,ij->i", q, q)) - 1.0) > MAX_QUAT_NORM_ERR
        if none.any():
            q = q.copy()
            q[none] = np.nan
        return q

    @property
    def gnss_vel_ne_m_s(self) -> np.ndarray | None:
        """(N, 2) the GNSS horizontal velocity (north, east) on the IMU samples, NaN between covered
        stretches; None when the record has none."""
        if GNSS_VEL_COLS[0] not in self.data:
            return None
        return self.data[GNSS_VEL_COLS].to_numpy(np.float64)

    @property
    def segment(self) -> np.ndarray:
        return self.data["segment"].to_numpy()

    @property
    def clipped(self) -> np.ndarray:
        return self.data["clipped"].to_numpy(bool)

    @property
    def gyr_clipped(self) -> np.ndarray:
        """Samples with a gyro axis at its range limit (or unhealthy): the ``gyr_clipped`` column where
        the reader could tell the gyro from the accelerometer, else every ``clipped`` sample."""
        if "gyr_clipped" in self.data:
            return self.data["gyr_clipped"].to_numpy(bool)
        return self.clipped

    @property
    def valid(self) -> np.ndarray:
        """BROAD's movement mask where present, else all True."""
        if "valid" in self.data:
            return self.data["valid"].to_numpy(bool)
        return np.ones(len(self.data), bool)

    def __len__(self) -> int:
        return len(self.data)

    def validate(self) -> None:
        """Raise :class:`RecordFormatError` unless columns, dtypes and segments are consistent."""
        missing = [c for c in REQUIRED_COLUMNS if c not in self.data.columns]
        if missing:
            raise RecordFormatError(f"missing columns {missing}")
        unknown = [c for c in self.data.columns if c not in REQUIRED_COLUMNS + OPTIONAL_COLUMNS]
        if unknown:
            raise RecordFormatError(f"unknown columns {unknown}")
        for key in REQUIRED_META:
            if key not in self.meta:
                raise RecordFormatError(f"metadata lacks '{key}'")
        if self.meta["source_kind"] not in SOURCE_KINDS:
            raise RecordFormatError(f"unknown source_kind {self.meta['source_kind']!r}")
        t, seg = self.t_s, self.segment
        if not np.all(np.isfinite(t)):  # (a NaN passes the comparisons below)
            raise RecordFormatError(f"t_s holds {int(np.count_nonzero(~np.isfinite(t)))} non-finite time stamp(s)")
        if len(t) > 1:
            same = seg[1:] == seg[:-1]
            if np.any(np.diff(seg) < 0):
                raise RecordFormatError("segment numbers decrease (rows out of time order?)")
            if np.any(np.diff(t)[same] <= 0):
                raise RecordFormatError("t_s does not strictly increase inside a segment")
        if "gyr_clipped" in self.data and np.any(self.gyr_clipped & ~self.clipped):
            raise RecordFormatError("gyr_clipped marks samples that clipped does not")
        if np.any(np.abs(t) > MAX_ABS_TIME_S):
            raise RecordFormatError(f"t_s holds times beyond {MAX_ABS_TIME_S:g} s (a damaged file?)")
        for cols, limit, unit, hint in ((GYR_COLS, MAX_GYRO_RAD_S, "rad/s", " (degrees per second written as rad/s?)"),
                                        (ACC_COLS, MAX_ACC_M_S2, "m/s²", " (milli-g written as m/s²?)"),
                                        (MAG_COLS, MAX_MAG_UT, "µT", " (nanotesla or milligauss written as µT?)"),
                                        (GNSS_VEL_COLS, MAX_GNSS_SPEED_M_S, "m/s", ""),
                                        (QREF_COLS, MAX_QUAT_COMPONENT, "", " (not a quaternion)")):  # fmt: skip
            if cols[0] not in self.data:
                continue
            v = self.data[cols].to_numpy(np.float64)
            inf = np.isinf(v)
            if inf.any():  # (review60: said to be "beyond ±100 rad/s ... degrees per second written as rad/s?")
                j = int(np.argmax(inf.any(axis=0)))
                raise RecordFormatError(f"{cols[j]} holds {int(inf[:, j].sum())} infinite value(s): a damaged file "
                                        "(a sample with no value is NaN in a record, a hole the estimators bridge)")  # fmt: skip
            with np.errstate(invalid="ignore"):
                over = np.abs(v) > limit  # (NaN: a hole, allowed)
            if over.any():
                j = int(np.argmax(over.any(axis=0)))
                raise RecordFormatError(f"{cols[j]} holds {int(over[:, j].sum())} value(s) beyond ±{limit:g} {unit}".rstrip()
                                        + f", past any sensor: a damaged file{hint}")  # fmt: skip


def segment_slices(segment: np.ndarray) -> list[slice]:
    """The rows of each segment (``segment`` is non-decreasing), in order; none for no rows."""
    if len(segment) == 0:
        return []
    bounds = np.flatnonzero(np.diff(segment)) + 1
    return [slice(int(a), int(b)) for a, b in zip(np.r_[0, bounds], np.r_[bounds, len(segment)])]


def make_frame(
    t_s: np.ndarray,
    segment: np.ndarray,
    gyr_rad_s: np.ndarray,
    acc_m_s2: np.ndarray,
    mag_ut: np.ndarray | None = None,
    q_ref_wxyz: np.ndarray | None = None,
    clipped: np.ndarray | None = None,
    **optional: np.ndarray,
) -> pd.DataFrame:
    """Build the column table in the canonical order from arrays (missing parts become NaN/False).

    ``optional`` takes ``valid`` (N,), ``gyr_clipped`` (N,; a subset of ``clipped``), ``gyr_bias_rad_s``
    (N, 3), ``acc_bias_m_s2`` (N, 3), ``gnss_vel_ne_m_s`` (N, 2).
    """
    n = len(t_s)
    nan3 = np.full((n, 3), np.nan)
    cols: dict[str, np.ndarray] = {
        "t_s": np.asarray(t_s, np.float64),
        "segment": np.asarray(segment, np.int32),
    }
    for names, arr in (
        (GYR_COLS, gyr_rad_s),
        (ACC_COLS, acc_m_s2),
        (MAG_COLS, nan3 if mag_ut is None else mag_ut),
        (QREF_COLS, np.full((n, 4), np.nan) if q_ref_wxyz is None else q_ref_wxyz),
    ):
        arr = np.asarray(arr, np.float64)
        for i, name in enumerate(names):
            cols[name] = arr[:, i]
    cols["clipped"] = np.zeros(n, bool) if clipped is None else np.asarray(clipped, bool)
    for key in ("valid", "gyr_clipped"):
        if optional.get(key) is not None:
            cols[key] = np.asarray(optional[key], bool)
        optional.pop(key, None)
    if "gyr_clipped" in cols:
        cols["clipped"] = cols["clipped"] | cols["gyr_clipped"]
    for key, names in (("gyr_bias_rad_s", GYR_BIAS_COLS), ("acc_bias_m_s2", ACC_BIAS_COLS),
                       ("gnss_vel_ne_m_s", GNSS_VEL_COLS)):
        arr = optional.pop(key, None)
        if arr is not None:
            arr = np.asarray(arr, np.float64)
            for i, name in enumerate(names):
                cols[name] = arr[:, i]
    if optional:
        raise ValueError(f"unknown optional columns {sorted(optional)}")
    return pd.DataFrame(cols)


# --------------------------------------------------------------------------- I/O


def _why(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


def check_output(path: str | os.PathLike, folder: bool = False) -> Path:
    """Refuse, before any work, an output that cannot be written: an :class:`OutputError` (one
    line, exit code 2) when ``path`` (a file, or a folder with ``folder``) is the wrong kind of
    thing, or when the nearest existing folder above it is a file or not writable (probed with a
    temporary file). Creates nothing that stays."""
    path = Path(path)
    if folder and path.exists() and not path.is_dir():
        raise OutputError("exists and is not a folder", path)
    if not folder and path.is_dir():
        raise OutputError("is a folder; give a file name", path)
    base = path if folder else path.parent
    anc = base
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if not anc.is_dir():
        raise OutputError(f"cannot create it: {anc} is a file, not a folder", path)
    try:
        fd, probe = tempfile.mkstemp(prefix=".tepinn-write-test.", suffix=".tmp", dir=anc)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise OutputError(f"cannot write in {anc} ({_why(exc)})", path) from None
    return path


def file_key(path) -> tuple[int, int] | None:
    """What makes a file itself, whatever path names it (links, ``./``, a folder's name for it): its device and
    inode; None where there is no such file."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def atomic_write(path: str | os.PathLike, write_fn) -> None:
    """Call ``write_fn(tmp_path)`` then rename onto ``path``; no partial file survives a crash.

    A place that cannot be written is an :class:`OutputError` (one line, exit code 2), as is an
    ``OSError`` while writing (disk full, ...). Temporaries of the same output left by a killed
    writer (its process gone) are removed first.

    A symbolic link is followed: its target is replaced, the link stays. A device or a pipe (``-o /dev/null``, a
    FIFO) gets the bytes copied into it from a file written in a temporary folder: renaming onto it would put a
    plain file in its place, and a writer handed its path may delete it on failure (pyarrow's ``write_table``
    does: it removed ``/dev/full``)."""
    path = Path(path)
    if path.is_symlink():
        path = Path(os.path.realpath(path))
    if path.exists() and not path.is_file() and not path.is_dir():
        import shutil

        with tempfile.TemporaryDirectory(prefix="tepinn-out.") as d:
            tmp = os.path.join(d, path.name)
            write_fn(tmp)
            try:
                with open(tmp, "rb") as src, open(path, "wb") as dst:
                    shutil.copyfileobj(src, dst)
            except OSError as exc:
                raise OutputError(f"cannot write ({_why(exc)})", path) from None
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        check_output(path)  # names the file in the way, if that is what it is
        raise OutputError(f"cannot create its folder ({_why(exc)})", path) from None
    _remove_stale_temporaries(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise OutputError(f"cannot write here ({_why(exc)})", path) from None
    os.close(fd)
    try:
        write_fn(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the usual permissions
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError):
            raise OutputError(f"cannot write ({_why(exc)})", path) from None
        raise


def _remove_stale_temporaries(path: Path) -> None:
    """Remove ``.NAME.PID.*.tmp`` files of this output whose writer process no longer runs (and
    older-style ``.NAME.*.tmp`` ones untouched for an hour): left behind by a killed write."""
    try:
        candidates = list(path.parent.glob(f".{glob_escape(path.name)}.*.tmp"))
    except OSError:
        return
    for tmp in candidates:
        rest = tmp.name[len(path.name) + 2:]
        pid_text = rest.split(".", 1)[0]
        try:
            if pid_text.isdigit() and "." in rest:
                if _pid_alive(int(pid_text)):
                    continue
            elif time.time() - tmp.stat().st_mtime < 3600:
                continue
            tmp.unlink()
        except OSError:
            pass


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True  # another write of ours may be under way in this process (threads)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_record(record: FlightRecord, path: str | os.PathLike) -> None:
    """Validate and write atomically (temp file + rename)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    meta = dict(record.meta)
    meta["format_version"] = FORMAT_VERSION
    rec = FlightRecord(record.data, meta)
    rec.validate()
    cols = [c for c in REQUIRED_COLUMNS + OPTIONAL_COLUMNS if c in rec.data.columns]
    df = rec.data[cols].reset_index(drop=True)
    for c, dt in _DTYPES.items():
        if c in df:
            df[c] = df[c].astype(dt)
    table = pa.Table.from_pandas(df, preserve_index=False)
    kv = {k.encode(): json.dumps(v, default=_json_default).encode() for k, v in meta.items()}
    table = table.replace_schema_metadata({**(table.schema.metadata or {}), **kv})
    # dictionary encoding only where values repeat (segment, flags): tried on float columns it costs
    # 40 % of the write and gives larger files (a 60-s 400 Hz flight: 21 -> 12 ms, 3.07 -> 2.59 MB)
    dict_cols = [f.name for f in table.schema if not pa.types.is_floating(f.type)]
    atomic_write(path, lambda tmp: pq.write_table(table, tmp, compression="zstd", use_dictionary=dict_cols))


def read_record(path: str | os.PathLike) -> FlightRecord:
    """Read and validate a record; refuse unknown ``format_version`` and non-records clearly."""
    import pyarrow.parquet as pq

    path = Path(path)
    if not path.exists():
        raise RecordFormatError("no such file", path)
    try:
        table = pq.read_table(path)
    except Exception as exc:  # pyarrow raises several types for non-Parquet input
        with open(path, "rb") as f:
            parquet = f.read(4) == b"PAR1"
        if not parquet:  # pyarrow's footer talk would only confuse: say what the file is not
            raise RecordFormatError("not a Parquet flight record (a raw log? run `tepinn-flight ingest` on it first)",
                                    path) from None  # fmt: skip
        raise RecordFormatError(f"damaged Parquet file ({_first_line(exc)})", path) from None
    meta = _decode_meta(table.schema.metadata or {})
    if "format_version" not in meta:
        if "estimate_key" in meta or "q_est_w" in table.column_names:  # a user's easy mix-up: say which file it is
            raise RecordFormatError("an estimate written by `tepinn-flight estimate`, not a flight record: give the "
                                    "record or log it was estimated from", path)  # fmt: skip
        raise RecordFormatError("Parquet file without 'format_version': not a flight record", path)
    if meta["format_version"] != FORMAT_VERSION:
        raise RecordFormatError(
            f"unknown format_version {meta['format_version']!r} (this tepinn-flight reads "
            f"version {FORMAT_VERSION}); upgrade tepinn-flight or re-create the record",
            path,
        )
    rec = FlightRecord(table.to_pandas(), meta)
    try:
        rec.validate()
    except RecordFormatError as exc:
        raise RecordFormatError(exc.reason, path) from None
    return rec


def is_record(path: str | os.PathLike) -> bool:
    """True for a Parquet file (magic ``PAR1``) — the only container a record can be."""
    try:
        with open(path, "rb") as f:
            return f.read(4) == b"PAR1"
    except OSError:
        return False


def parquet_meta(path: str | os.PathLike) -> dict[str, Any] | None:
    """A Parquet file's key-value metadata, each value JSON-decoded where it is JSON (pandas' own key left out),
    read from its schema alone; None where the file is not a readable Parquet file."""
    import pyarrow.parquet as pq

    if not is_record(path):
        return None
    try:
        return _decode_meta(pq.read_schema(path).metadata or {})
    except Exception:  # noqa: BLE001 - pyarrow raises several types for a damaged file
        return None


def _decode_meta(raw: dict) -> dict[str, Any]:
    meta: dict[str, Any] = {}
    for k, v in raw.items():
        key = k.decode(errors="replace")
        if key == "pandas":
            continue
        try:
            meta[key] = json.loads(v)
        except ValueError:
            meta[key] = v.decode(errors="replace")
    return meta


def is_flight_record(path: str | os.PathLike) -> bool:
    """True for a Parquet file whose metadata says it is a flight record (``format_version``): not an estimate's
    output or another table (a damaged one counts: whoever reads it says what is wrong). Reads the schema only."""
    if not is_record(path):
        return False
    meta = parquet_meta(path)
    return meta is None or "format_version" in meta


def _json_default(v):
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, Path):
        return str(v)
    raise TypeError(f"not JSON serialisable: {type(v).__name__}")


def _first_line(exc: BaseException) -> str:
    s = str(exc).strip().splitlines()
    return s[0] if s else type(exc).__name__
