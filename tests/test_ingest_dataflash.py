"""DataFlash ingestion: shared real logs cross-checked with pymavlink, synthetic logs with known values.

pymavlink's DFReader is the slow, independent reference for decoded values; scipy's Rotation for
Euler → quaternion; the synthetic logs below are written byte by byte from known values.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.consistency import rate_consistency
from tepinn_flight.errors import ConfigError, CorruptLog, NoImuData, TepinnError
from tepinn_flight.ingest import ingest_log, load_record, read_raw
from tepinn_flight.ingest import dataflash_scan as dfs
from tepinn_flight.ingest.dataflash import _merged_epochs, read
from tepinn_flight.ingest.streams import detect_epochs
from tepinn_flight.record import GYR_COLS, FlightRecord

from .conftest import real_log

pymavlink_df = pytest.importorskip("pymavlink.DFReader")

ERLE = "erle_pxf_copter_15-12-2014_16.BIN"
SUB = "ardusub_small.BIN"


def _pymavlink_rows(path, types, text=False):
    """{type: list of field dicts} read with pymavlink (the slow reference)."""
    r = pymavlink_df.DFReader_text(str(path)) if text else pymavlink_df.DFReader_binary(str(path))
    out = {t: [] for t in types}
    while True:
        m = r.recv_match(type=types)
        if m is None:
            break
        out[m.get_type()].append(m.to_dict())
    return out


def _col(rows, *names):
    return np.array([[r[n] for n in names] for r in rows], dtype=np.float64)


def _same_rotation(q1, q2, atol=1e-9):
    """q ≡ -q: compare |<q1, q2>| with 1."""
    dot = np.abs(np.sum(q1 * q2, axis=1))
    return np.all(np.abs(dot - 1.0) < atol)


def _scipy_q_from_att(rows, trim_x_rad=0.0, trim_y_rad=0.0):
    """ATT (the vehicle's attitude) → quaternions; with a level trim, turned into the board's frame:
    R_board = R_vehicle · R(trim_x, trim_y, 0)."""
    e = _col(rows, "Yaw", "Pitch", "Roll")
    r = Rotation.from_euler("ZYX", e, degrees=True) * Rotation.from_euler("ZYX", [0.0, trim_y_rad, trim_x_rad])
    return r.as_quat()[:, [3, 0, 1, 2]]


# --------------------------------------------------------------------------- real logs


@pytest.fixture(scope="module")
def erle_pm():
    return _pymavlink_rows(real_log(ERLE), ["IMU", "ATT", "MAG", "PARM"])


@pytest.fixture(scope="module")
def erle_rec():
    return ingest_log(real_log(ERLE))


def test_erle_values_equal_pymavlink(erle_pm):
    raw = read(real_log(ERLE))
    imu = erle_pm["IMU"]
    assert len(raw.imu.t_s) == len(imu) == 7600
    np.testing.assert_array_equal(raw.imu.t_s, _col(imu, "TimeMS")[:, 0] / 1000.0)
    np.testing.assert_array_equal(raw.imu.gyr_rad_s, _col(imu, "GyrX", "GyrY", "GyrZ"))
    np.testing.assert_array_equal(raw.imu.acc_m_s2, _col(imu, "AccX", "AccY", "AccZ"))
    mag = erle_pm["MAG"]
    np.testing.assert_allclose(raw.mag.mag_ut, _col(mag, "MagX", "MagY", "MagZ") * 0.1, rtol=0, atol=1e-12)
    att = erle_pm["ATT"]
    assert raw.ref.source == "ATT" and len(raw.ref.t_s) == len(att) == 9120
    trim = {r["Name"]: r["Value"] for r in erle_pm["PARM"] if r["Name"] in ("AHRS_TRIM_X", "AHRS_TRIM_Y")}
    assert trim["AHRS_TRIM_X"] != 0  # ATT is the vehicle's attitude: turned by the level trim into the IMU's frame
    assert _same_rotation(raw.ref.q_nb_wxyz, _scipy_q_from_att(att, trim["AHRS_TRIM_X"], trim["AHRS_TRIM_Y"]))
    assert not _same_rotation(raw.ref.q_nb_wxyz, _scipy_q_from_att(att), atol=1e-7)
    assert raw.meta["ahrs_trim_rad"] == [trim["AHRS_TRIM_X"], trim["AHRS_TRIM_Y"]]
    # accelerometer is specific force: level at rest reads z ≈ -g
    assert -10.5 < np.median(raw.imu.acc_m_s2[:200, 2]) < -9.0


def test_erle_golden_summary(erle_pm, erle_rec):
    t = _col(erle_pm["IMU"], "TimeMS")[:, 0] / 1000.0
    rate = 1.0 / np.median(np.diff(t))
    m = erle_rec.meta
    assert len(erle_rec) == len(t)
    assert m["imu_rate_hz"] == pytest.approx(rate, rel=1e-6)
    assert erle_rec.t_s[-1] == pytest.approx(t[-1] - t[0], abs=1e-9)
    assert m["source_kind"] == "dataflash" and m["autopilot"] == "ardupilot"
    assert m["firmware"] == "ArduCopter V3.3-dev" and m["vehicle_type"] == "copter"
    rate_hz = pytest.approx(rate, rel=1e-3)
    assert m["imu_instances"] == [{"instance": 0, "name": "IMU", "samples": 7600, "rate_hz": rate_hz}]
    assert m["reference_candidates"] == ["ATT", "AHR2", "EKF1"]
    assert m["reference_source"] == "ATT" and m["reference_coverage"] > 0.99
    assert m["corrupt_frames"] == 0 and m["skipped_frames"] == 0 and m["boot_epochs"] == 1


def _with_gyro(rec, gyr):
    df = rec.data.copy()
    df[GYR_COLS] = gyr
    return FlightRecord(df, dict(rec.meta))


def test_erle_rate_consistency_and_its_failures(erle_rec):
    rc = rate_consistency(erle_rec)
    assert rc.moving.all()
    assert np.all(rc.corr >= 0.9), rc.corr
    assert np.all(np.abs(rc.gain - 1.0) <= 0.1), rc.gain
    gyr = erle_rec.gyr_rad_s
    # wrong units (deg/s read as rad/s): gain ~ 1/57
    bad_units = rate_consistency(_with_gyro(erle_rec, np.degrees(gyr)))
    assert np.all(np.abs(bad_units.gain - 1.0) > 0.5)
    # swapped x/y axes: the swapped axes no longer correlate
    swapped = rate_consistency(_with_gyro(erle_rec, gyr[:, [1, 0, 2]]))
    assert np.all(swapped.corr[:2] < 0.9) and np.all(np.abs(swapped.gain[:2] - 1.0) > 0.1)


def test_erle_other_references(erle_pm):
    raw = read(real_log(ERLE), reference="ahr2")
    assert raw.ref.source == "AHR2" and len(raw.ref.t_s) == 9120
    with pytest.raises(ConfigError, match=r"reference 'XKQ' not in this log; available: ATT, AHR2, EKF1"):
        read(real_log(ERLE), reference="XKQ")


def test_ardusub_4x_instance_fields():
    path = real_log(SUB)
    pm = _pymavlink_rows(path, ["IMU", "XKQ", "MAG"])
    raw = read(path)
    imu0 = [r for r in pm["IMU"] if r["I"] == 0]
    np.testing.assert_array_equal(raw.imu.t_s, _col(imu0, "TimeUS")[:, 0] / 1e6)
    np.testing.assert_array_equal(raw.imu.gyr_rad_s, _col(imu0, "GyrX", "GyrY", "GyrZ"))
    xkq0 = [r for r in pm["XKQ"] if r["C"] == 0]
    q = _col(xkq0, "Q1", "Q2", "Q3", "Q4")
    assert raw.ref.source == "XKQ"
    np.testing.assert_allclose(raw.ref.q_nb_wxyz, q / np.linalg.norm(q, axis=1, keepdims=True), atol=1e-12)
    mag0 = [r for r in pm["MAG"] if r["I"] == 0]
    assert len(mag0) < len(pm["MAG"])  # two compasses: instance 0 (the IMU's) is taken
    np.testing.assert_allclose(raw.mag.mag_ut, _col(mag0, "MagX", "MagY", "MagZ") * 0.1, atol=1e-12)
    m = raw.meta
    assert m["imu_time_field"] == "TimeUS" and m["mag_instance"] == 0
    assert m["firmware"] == "ArduSub V4.1.0" and m["vehicle_type"] == "sub"
    assert m["reference_candidates"] == ["XKQ", "ATT", "AHR2", "XKF1"]
    t = raw.imu.t_s
    assert m["imu_instances"][0]["rate_hz"] == pytest.approx(1 / np.median(np.diff(t)), rel=1e-3)
    rec = ingest_log(path, reference="ATT")
    assert rec.meta["reference_source"] == "ATT" and len(rec) == len(imu0)


def test_text_log_with_nan_params():
    path = real_log("aplogan_nan.log")
    pm = _pymavlink_rows(path, ["IMU", "IMU2", "ATT", "PARM"], text=True)
    rec = ingest_log(path)
    assert rec.meta["dataflash_encoding"] == "text" and rec.meta["firmware"] == "ArduCopter V3.1.1"
    assert [(i["name"], i["samples"]) for i in rec.meta["imu_instances"]] == [("IMU", 705), ("IMU2", 705)]
    raw = read(path, imu=1)
    np.testing.assert_array_equal(raw.imu.gyr_rad_s, _col(pm["IMU2"], "GyrX", "GyrY", "GyrZ"))
    np.testing.assert_array_equal(raw.imu.t_s, _col(pm["IMU2"], "TimeMS")[:, 0] / 1000.0)
    raw0 = read(path)
    np.testing.assert_array_equal(raw0.imu.acc_m_s2, _col(pm["IMU"], "AccX", "AccY", "AccZ"))
    trim = {r["Name"]: r["Value"] for r in pm["PARM"] if r["Name"] in ("AHRS_TRIM_X", "AHRS_TRIM_Y")}
    assert _same_rotation(raw0.ref.q_nb_wxyz, _scipy_q_from_att(pm["ATT"], trim["AHRS_TRIM_X"], trim["AHRS_TRIM_Y"]))
    with pytest.raises(NoImuData, match="IMU instance 2 has no samples; instances with data: 0, 1"):
        read(path, imu=2)


def test_text_log_line_endings_and_bad_lines(tmp_path):
    src = real_log("aplogan_nan.log").read_bytes()
    crlf = tmp_path / "crlf.log"
    crlf.write_bytes(src.replace(b"\n", b"\r\n"))
    a, b = read(real_log("aplogan_nan.log")), read(crlf)
    np.testing.assert_array_equal(a.imu.gyr_rad_s, b.imu.gyr_rad_s)
    np.testing.assert_array_equal(a.ref.q_nb_wxyz, b.ref.q_nb_wxyz)
    lines = src.decode().splitlines()
    imu_lines = [i for i, ln in enumerate(lines) if ln.startswith("IMU,")]
    lines[imu_lines[10]] += ", 1.0"  # one field too many: dropped as corrupt
    lines[imu_lines[20]] = "IMU, 95892, 0.1, oops, 0.2, 0.3, 0.4, -9.8"  # a bad number: NaN, row dropped
    lines.insert(imu_lines[30], "ZZZ, 1, 2, 3")  # no FMT for ZZZ: skipped
    bad = tmp_path / "bad.log"
    bad.write_text("\n".join(lines) + "\n")
    raw = read(bad)
    assert len(raw.imu.t_s) == 703 and raw.meta["corrupt_frames"] == 1 and raw.meta["skipped_frames"] == 1
    keep = np.ones(705, bool)
    keep[[10, 20]] = False
    np.testing.assert_array_equal(raw.imu.gyr_rad_s, a.imu.gyr_rad_s[keep])


def test_text_log_with_corrupted_bytes(tmp_path):
    """Corrupted bytes inside a text log's numbers (an SD card write gone wrong) spoil their rows, not the log: a
    byte that is no UTF-8 had raised UnicodeDecodeError from pandas' parser, a stray carriage return or quote had
    made it see another number of lines (a shape error) — tracebacks, both (found by truncating and garbling the
    shared logs)."""
    src = real_log("aplogan_nan.log").read_bytes()
    lines = src.split(b"\n")
    imu_lines = [i for i, ln in enumerate(lines) if ln.startswith(b"IMU,")]
    for k, cell in ((15, b"\xdc\x901"), (40, b" 0.1\r2"), (41, b' "0.2'), (42, b" 0.3")):  # the gyro's y reading
        row = lines[imu_lines[k]].split(b",")
        row[3] = cell
        lines[imu_lines[k]] = b",".join(row)
    bad = tmp_path / "garbled.log"
    bad.write_bytes(b"\n".join(lines))
    a, raw = read(real_log("aplogan_nan.log")), read(bad)
    keep = np.ones(705, bool)
    keep[[15, 40, 41]] = False  # the three spoiled readings; row 42 reads 0.3 where it was written
    assert len(raw.imu.t_s) == 702
    got = raw.imu.gyr_rad_s
    want = a.imu.gyr_rad_s[keep].copy()
    want[np.flatnonzero(keep)[:].tolist().index(42), 1] = 0.3
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize(
    "name, exc, pattern",
    [
        ("pfc_center_0003.bin", NoImuData, r"defines IMU but holds no IMU rows .*LOG_BITMASK=1029"),
        ("aplogan_tradheli_brownout.log", NoImuData, r"without a time field"),
        ("apex_AP_Logger_AllTypes_output.BIN", NoImuData, r"no IMU message defined"),
    ],
)
def test_logs_without_usable_imu_give_one_line_errors(name, exc, pattern):
    with pytest.raises(exc, match=pattern) as info:
        ingest_log(real_log(name))
    assert "\n" not in str(info.value) and name in str(info.value)


def test_all_field_types_decode_like_pymavlink():
    path = real_log("apex_AP_Logger_AllTypes_output.BIN")
    mm, buf = dfs.open_buffer(path)
    table = dfs.find_formats(mm)
    res = dfs.scan(buf, table.lengths(), set(table.by_id))
    r = pymavlink_df.DFReader_binary(str(path))
    checked = set()
    while True:
        m = r.recv_match()
        if m is None:
            break
        name = m.get_type()
        if name == "FMT":
            continue
        mf = table.by_name[name]
        rows = dfs.decode_rows(buf, mf, res.offsets[mf.type_id])
        assert len(rows) == 1
        for col, ch in zip(mf.columns, mf.fmt):
            ref = getattr(m, col)
            if ch in dfs.STRING_CHARS:
                assert dfs._null_term(bytes(rows[col][0])) == ref
            else:
                got = dfs.scaled(rows[col], mf.multiplier(col))[0]
                assert got == ref or (np.isnan(got) and np.isnan(ref)), (name, col, got, ref)
            checked.add(ch)
    assert checked >= set("QZcCeELMqfd")  # the types with rows here; B, h, H, I, a, g: synthetic log


# --------------------------------------------------------------------------- damaged files


def test_truncated_and_garbled_bin(tmp_path):
    src = real_log(ERLE).read_bytes()
    cut = tmp_path / "cut.BIN"
    cut.write_bytes(src[:1_000_003])  # ends inside a message
    pm = _pymavlink_rows(cut, ["IMU"])
    raw = read(cut)
    assert len(raw.imu.t_s) == len(pm["IMU"]) > 3000
    np.testing.assert_array_equal(raw.imu.gyr_rad_s, _col(pm["IMU"], "GyrX", "GyrY", "GyrZ"))
    assert raw.meta["skipped_frames"] == 1 and any("truncated tail" in n for n in raw.meta["notes"])

    junk = np.random.default_rng(3).integers(0, 256, 4000, dtype=np.uint8).tobytes()
    bad = tmp_path / "garbled.BIN"
    bad.write_bytes(src[:600_000] + junk + src[600_000:])
    pm = _pymavlink_rows(bad, ["IMU"])
    raw = read(bad)
    assert len(raw.imu.t_s) == len(pm["IMU"]) == 7600
    assert raw.meta["corrupt_frames"] >= 1


def test_random_bytes_with_dataflash_header(tmp_path):
    p = tmp_path / "noise.bin"
    p.write_bytes(b"\xa3\x95\x80" + np.random.default_rng(7).integers(0, 256, 50_000, dtype=np.uint8).tobytes())
    with pytest.raises(CorruptLog, match="no valid FMT records"):
        read_raw(p)
    empty_fmt = tmp_path / "header_only.bin"
    empty_fmt.write_bytes(b"\xa3\x95")
    with pytest.raises(TepinnError):
        ingest_log(empty_fmt)


# --------------------------------------------------------------------------- synthetic logs


def _fmt(tid, name, fmt, cols):
    length = struct.calcsize("<" + "".join(_ST[c] for c in fmt)) + 3
    return struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, tid, length, name.encode(), fmt.encode(), cols.encode())


_ST = {"Q": "Q", "B": "B", "f": "f", "I": "I", "H": "H", "h": "h", "c": "h", "C": "H", "Z": "64s", "a": "32h", "g": "e"}


def _msg(tid, fmt, *vals):
    return bytes([0xA3, 0x95, tid]) + struct.pack("<" + "".join(_ST[c] for c in fmt), *vals)


IMU_F = "QBffffffIIfBBHH"
XKQ_F = "QBffff"
MAG_F = "QBhhhhhhhhhBI"
VIBE_F = "QBfffI"


def _synthetic_log(path, n=400, reboot_at=250, truncate=0):
    """4.x-style log: IMU[I=0,1] 100 Hz, XKQ[C=0,1] 50 Hz, MAG with false headers, VIBE, a reboot."""
    out = [
        struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, 0x80, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns"),
        _fmt(10, "IMU", IMU_F, "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
        _fmt(11, "XKQ", XKQ_F, "TimeUS,C,Q1,Q2,Q3,Q4"),
        _fmt(12, "MAG", MAG_F, "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S"),
        _fmt(13, "VIBE", VIBE_F, "TimeUS,IMU,VibeX,VibeY,VibeZ,Clip"),
        _fmt(14, "ARR", "QagcC", "TimeUS,Arr,Half,Cs,Cu"),
        _fmt(15, "MSG", "QZ", "TimeUS,Message"),
    ]
    out.append(_msg(15, "QZ", 1, b"ArduCopter V4.3.0 (abcdef01)"))
    # clipped: IMU0 k=100 saturates; IMU1 k=50 unhealthy (GH=0); the VIBE clip counter of IMU0
    # rises at the VIBE row written after IMU k=69, so IMU0 rows 60..69 (after the previous VIBE row);
    # the gyro's part (gyr_clipped): the saturated and the unhealthy gyro, not the VIBE (accel) rows
    truth = {"t": [], "gyr": {0: [], 1: []}, "q": {0: [], 1: []}, "epoch": [],
             "clip": {0: set(range(60, 70)) | {100}, 1: {50}}, "gyr_clip": {0: {100}, 1: {50}}}  # fmt: skip
    clip_count = 0
    for k in range(n):
        t_us = 10_000_000 + k * 10_000 if k < reboot_at else 2_000_000 + (k - reboot_at) * 10_000
        truth["t"].append(t_us / 1e6)
        truth["epoch"].append(0 if k < reboot_at else 1)
        for inst in (0, 1):
            g = np.float32([0.5 * np.sin(0.05 * k + inst), 0.3 * np.cos(0.03 * k), 0.1 * inst + 0.001 * k])
            if inst == 0 and k == 100:
                g[0] = 35.0  # beyond 98 % of 2000 deg/s
            gh = 0 if (inst == 1 and k == 50) else 1
            truth["gyr"][inst].append(g.astype(np.float64))
            out.append(_msg(10, IMU_F, t_us, inst, *g, 0.1, 0.2, -9.8, 0, 0, 25.0, gh, 1, 1000, 1000))
        if k % 10 == 9:
            clip_count += 1 if k == 69 else 0
            out.append(_msg(13, VIBE_F, t_us, 0, 1.0, 1.0, 1.0, clip_count))
        if k % 2 == 0:
            for core in (0, 1):
                ang = 0.01 * k + 0.5 * core
                q = np.float32([np.cos(ang / 2), np.sin(ang / 2) * 0.6, 0.0, np.sin(ang / 2) * 0.8])
                truth["q"][core].append(q.astype(np.float64))
                out.append(_msg(11, XKQ_F, t_us + 50, core, *q))
        if k % 10 == 0:
            # MagX = 0x95A3 little endian bytes A3 95, MagY low byte 10 (IMU id): a false IMU header
            out.append(_msg(12, MAG_F, t_us + 70, 0, -27229, 10 + 256 * 7, 300, 0, 0, 0, 0, 0, 0, 1, 0))
            out.append(_msg(14, "QagcC", t_us, *range(-16, 16), 1.5, -123, 456))
    data = b"".join(out)
    if truncate:
        data = data[:-truncate]
    path.write_bytes(data)
    return truth


def test_synthetic_log_instances_clipping_epochs(tmp_path):
    p = tmp_path / "synth.bin"
    truth = _synthetic_log(p)
    raw = read(p)
    m = raw.meta
    assert m["imu_instances"] == [
        {"instance": 0, "name": "IMU", "samples": 400, "rate_hz": pytest.approx(100.0)},
        {"instance": 1, "name": "IMU", "samples": 400, "rate_hz": pytest.approx(100.0)},
    ]
    assert m["reference_candidates"] == ["XKQ", "XKQ[1]"] and raw.ref.source == "XKQ"
    assert m["vehicle_type"] == "copter" and m["corrupt_frames"] == 0
    np.testing.assert_array_equal(raw.imu.t_s, truth["t"])
    np.testing.assert_array_equal(raw.imu.gyr_rad_s, np.array(truth["gyr"][0]))
    np.testing.assert_array_equal(raw.imu.epoch, truth["epoch"])
    assert set(np.flatnonzero(raw.imu.clipped)) == truth["clip"][0]
    assert set(np.flatnonzero(raw.imu.gyr_clipped)) == truth["gyr_clip"][0]
    assert len(raw.mag.t_s) == 40 and np.allclose(raw.mag.mag_ut[0], [-2722.9, 180.2, 30.0])
    q0 = np.array(truth["q"][0])
    np.testing.assert_allclose(raw.ref.q_nb_wxyz, q0 / np.linalg.norm(q0, axis=1, keepdims=True), atol=1e-12)
    assert np.array_equal(raw.ref.epoch, (raw.ref.t_s < 9.0).astype(int))

    raw1 = read(p, imu=1, reference="XKQ[1]")
    np.testing.assert_array_equal(raw1.imu.gyr_rad_s, np.array(truth["gyr"][1]))
    assert set(np.flatnonzero(raw1.imu.clipped)) == truth["clip"][1]
    assert set(np.flatnonzero(raw1.imu.gyr_clipped)) == truth["gyr_clip"][1]
    q1 = np.array(truth["q"][1])
    assert raw1.ref.source == "XKQ[1]"
    np.testing.assert_allclose(raw1.ref.q_nb_wxyz, q1 / np.linalg.norm(q1, axis=1, keepdims=True), atol=1e-12)

    rec = ingest_log(p)
    assert rec.meta["boot_epochs"] == 2 and rec.meta["segments"] == 2 and len(rec) == 400
    assert set(np.flatnonzero(rec.clipped)) == truth["clip"][0]  # the record carries both flags
    assert set(np.flatnonzero(rec.gyr_clipped)) == truth["gyr_clip"][0]


def test_synthetic_log_matches_pymavlink_and_chunking(tmp_path):
    p = tmp_path / "synth.bin"
    _synthetic_log(p, truncate=7)
    pm = _pymavlink_rows(p, ["IMU", "ARR", "MAG"])
    raw = read(p)
    imu0 = [r for r in pm["IMU"] if r["I"] == 0]
    np.testing.assert_array_equal(raw.imu.gyr_rad_s, _col(imu0, "GyrX", "GyrY", "GyrZ"))
    assert raw.meta["skipped_frames"] == 1  # the cut last message
    # 'a' (int16[32]), 'g' (half), 'c'/'C' (x0.01) against pymavlink
    mm, buf = dfs.open_buffer(p)
    table = dfs.find_formats(mm)
    mf = table.by_name["ARR"]
    res = dfs.scan(buf, table.lengths(), {mf.type_id, table.by_name["IMU"].type_id})
    rows = dfs.decode_rows(buf, mf, res.offsets[mf.type_id])
    assert len(rows) == len(pm["ARR"]) == 40
    np.testing.assert_array_equal(rows["Arr"], np.array([list(r["Arr"]) for r in pm["ARR"]]))
    for col in ("Half", "Cs", "Cu"):
        np.testing.assert_array_equal(dfs.scaled(rows[col], mf.multiplier(col)), _col(pm["ARR"], col)[:, 0])
    # chunk size does not change the chain (false A3 95 0A headers sit inside every MAG payload)
    for chunk in (61, 1000, 1 << 20):
        r2 = dfs.scan(buf, table.lengths(), {mf.type_id, table.by_name["IMU"].type_id}, chunk_bytes=chunk)
        assert all(np.array_equal(r2.offsets[i], res.offsets[i]) for i in res.offsets)
        assert np.array_equal(r2.counts, res.counts) and r2.corrupt_regions == 0


def test_merged_epochs_follow_detect_epochs():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0, 0.02, 3000))
    t[900:] -= 40.0
    t[2100:] -= 30.0
    t[1500] -= 0.5  # jitter, not a reboot
    order = np.arange(3000) * 5
    lab = rng.integers(0, 3, 3000)
    eps = _merged_epochs([(t[lab == k], order[lab == k]) for k in range(3)])
    expected = detect_epochs(t)
    assert expected.max() == 2
    for k in range(3):
        np.testing.assert_array_equal(eps[k], expected[lab == k])


def test_the_text_kernels_split_lines_and_fields_as_python_does():
    """`dataflash_text_kernels`: lines, first commas and comma counts, and one field's bounds, against Python's own
    split on crafted bytes — empty lines, lines without a comma, a trailing comma, carriage returns, no newline at
    the end, and fields asked past a line's end."""
    from tepinn_flight.ingest.dataflash_text_kernels import field_bounds, line_table

    text = b"FMT, 1, 2, IMU\n\nPARM, AHRS_TRIM_X , 0.02\r\nNOCOMMA\nMSG, a,b, c,\nMODE,,x\nLAST, 1, 2"
    data = np.frombuffer(text, np.uint8)
    lines = text.split(b"\n")
    n = text.count(b"\n") + 1
    starts, ends, first, commas = (np.empty(n, np.int64) for _ in range(4))
    assert line_table(data, starts, ends, first, commas) == n == len(lines)
    for k, ln in enumerate(lines):
        assert text[starts[k] : ends[k]] == ln
        assert first[k] == (starts[k] + ln.index(b",") if b"," in ln else -1)
        assert commas[k] == ln.count(b",")
    rows = np.flatnonzero(first >= 0)
    for i in range(5):
        for last in (False, True):
            lo, hi = np.empty(len(rows), np.int64), np.empty(len(rows), np.int64)
            field_bounds(data, first[rows], ends[rows], i, last, lo, hi)
            for r, a, b in zip(rows, lo, hi):
                rest = lines[r][lines[r].index(b",") + 1 :]
                parts = rest.split(b",", i if last else i + 1)
                assert text[a:b] == (parts[i] if len(parts) > i else b""), (lines[r], i, last)


def test_log_cut_before_its_first_imu_row_says_so(tmp_path):
    """A text log cut short (logging stopped, a partial download) after its formats and parameters but before
    any IMU row: the error names that possibility, not only a logging bitmask."""
    src = real_log("aplogan_nan.log").read_bytes()
    cut = tmp_path / "cut.log"
    cut.write_bytes(src[: src.index(b"\nIMU,") + 1])  # everything before the first IMU row
    with pytest.raises(NoImuData, match=r"holds no IMU rows \(.*ends before its first IMU row"):
        ingest_log(cut)


@pytest.mark.parametrize("corrupt", ["XKQ", "MAG"])
def test_dataflash_one_corrupt_reference_or_mag_time_is_no_reboot(tmp_path, corrupt):
    """DataFlash has no checksums: one XKQ or MAG row whose TimeUS reads 0 is dropped, not taken for a reboot that
    splits the flight into two segments (session 53; a corrupt IMU stamp was already handled)."""
    from .test_ingest_gnss import IMU_F, _df, _df_fmt

    xkq_f, mag_f = "QBffff", "QBhhhhhhhhhBI"
    out = [
        struct.pack("<BBBBB4s16s64s", 0xA3, 0x95, 0x80, 0x80, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns"),
        _df_fmt(10, "IMU", IMU_F, "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
        _df_fmt(12, "XKQ", xkq_f, "TimeUS,C,Q1,Q2,Q3,Q4"),
        _df_fmt(13, "MAG", mag_f, "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S"),
    ]
    for k in range(2000):
        t = 50_000_000 + 10_000 * k
        out.append(_df(10, IMU_F, t, 0, 0.01, 0.02, 0.03, 0.0, 0.0, -9.8, 0, 0, 25.0, 1, 1, 1000, 1000))
        if k % 2 == 0:
            out.append(_df(12, xkq_f, 0 if (corrupt == "XKQ" and k == 1000) else t + 50, 0, 1.0, 0.0, 0.0, 0.0))
        if k % 10 == 0:
            out.append(_df(13, mag_f, 0 if (corrupt == "MAG" and k == 1000) else t + 70, 0, 200, -100, 400,
                           0, 0, 0, 0, 0, 0, 1, 0))  # fmt: skip
    path = tmp_path / f"corrupt_{corrupt}.bin"
    path.write_bytes(b"".join(out))
    rec = load_record(path)
    assert rec.meta["boot_epochs"] == 1 and rec.meta["segments"] == 1 and len(rec) == 2000
    assert any(f"1 {corrupt} row(s) with a corrupt time stamp dropped" in n for n in rec.meta["notes"])
    assert np.isfinite(rec.q_ref_wxyz[100:-100]).all()


@pytest.mark.parametrize("edit, want", [
    (lambda s: s, "copter"),
    (lambda s: s.replace("PARM, SYSID_SW_MREV, 120", "MSG, Frame: HELI\nPARM, SYSID_SW_MREV, 120", 1), "helicopter"),
    (lambda s: s.replace("ArduCopter V3.1", "ArduPlane V3.9.0")
             .replace("PARM, SYSID_SW_MREV, 120", "PARM, Q_ENABLE, 1\nPARM, SYSID_SW_MREV, 120", 1), "vtol"),
])  # fmt: skip
def test_dataflash_names_the_vehicle_as_its_heartbeat_would(tmp_path, edit, want):
    """A helicopter runs ArduCopter and a QuadPlane ArduPlane: their DataFlash logs name them as their tlogs' MAV_TYPE
    does (session 53: a heli's .bin said "copter", a multirotor, and its tlog "helicopter": another vehicle class)."""
    from tepinn_flight.vehicle_class import OTHER, vehicle_class

    p = tmp_path / "v.log"
    p.write_text(edit(real_log("aplogan_nan.log").read_text()))
    vt = read_raw(p).meta["vehicle_type"]
    assert vt == want
    if want != "copter":
        assert vehicle_class(vt) == OTHER == vehicle_class("helicopter") == vehicle_class("vtol_quadrotor")
