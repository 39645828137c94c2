"""The compiled tlog frame sync and the reader's streams, against slow references.

* :func:`mavlink_sync.good_frames` against a plain-Python statement of its rules, using the scalar
  CRC (itself checked against pymavlink's ``x25crc`` in ``test_ingest_tlog.py``), on damaged
  synthetic tlogs and on chunks of the shared real tlogs;
* CRC failures (each one a gap of exactly one record, counted in bulk) against pymavlink's
  ``BAD_DATA`` count on a real tlog with frames damaged on purpose;
* the streams of ``tlog.read`` (IMU in SI units, reference quaternions, sample times) against
  pymavlink's decoded messages with the units applied by hand and scipy's Euler conversion.
"""

from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tepinn_flight.ingest import mavlink_scan as ms
from tepinn_flight.ingest import tlog as tlog_reader
from tepinn_flight.ingest.mavlink_sync import _median, good_frames
from tests.conftest import real_log
from tests.test_ingest_tlog import TLOGS, _pymavlink_bad_crc, _pymavlink_messages, _synthetic

G = 9.80665


def _slow_good_frames(buf: bytes, m: int, h_lo: int, h_hi: int, a: int, size: int):
    """The frame-sync rules, one candidate at a time in plain Python."""
    known, extra = ms._id_tables()

    def header(h):
        if buf[h] == 0xFD:
            inc, msgid, hdr = buf[h + 2], buf[h + 7] | buf[h + 8] << 8 | buf[h + 9] << 16, 10
        else:
            inc, msgid, hdr = 0, buf[h + 5], 6
        return 8 + hdr + buf[h + 1] + 2 + (13 if inc & 1 else 0), msgid, inc, hdr

    def chained(h):
        nxt = h - 8 + header(h)[0]
        return buf[min(nxt + 8, len(buf) - 1)] in (0xFD, 0xFE) or a + nxt == size

    cands = [h for h in range(h_lo, h_hi) if buf[h] in (0xFD, 0xFE)]
    chain = [h for h in cands if chained(h)]
    ts = [int.from_bytes(buf[h - 8 : h], "big") for h in chain[:: max(1, len(chain) // 257)]]
    med = float(np.median(np.array(ts, np.float64))) if ts else None
    out = []
    for h in cands:
        rl, msgid, inc, hdr = header(h)
        if h - 8 + rl > m or inc & 0xFE or msgid >= len(known) or not known[msgid]:
            continue
        if not chained(h) and (med is None or not abs(float(int.from_bytes(buf[h - 8 : h], "big")) - med) < 86_400e6):
            continue
        end = h + hdr + buf[h + 1]
        crc = ms.x25_crc(bytes([int(extra[msgid]) & 0xFF]), ms.x25_crc(buf[h + 1 : end]))
        if crc == buf[end] | buf[end + 1] << 8:
            out.append((h - 8, msgid))
    return out


def _kernel(data: bytes, h_lo: int, a: int, size: int):
    buf = np.zeros(len(data) + ms._PAD + 32, np.uint8)
    buf[: len(data)] = np.frombuffer(data, np.uint8)
    known, extra = ms._id_tables()
    n_starts = max(0, len(data) - ms._PAD) if a + len(data) < size else len(data)
    n_max = int(np.count_nonzero(buf[h_lo : 8 + n_starts] >= 0xFD))
    i, ids = good_frames(buf, len(data), h_lo, 8 + n_starts, n_max, a, size, known, extra,
                         ms._CRC_TABLE, ms._CRC_SLICES, ms._MAX_ID, float(ms._TS_WINDOW_US))  # fmt: skip
    slow = _slow_good_frames(bytes(buf), len(data), h_lo, 8 + n_starts, a, size)
    return list(zip(i.tolist(), ids.tolist())), slow


def _damaged_synthetic(tmp_path, seed: int) -> bytes:
    path = tmp_path / f"damaged{seed}.tlog"
    _synthetic(path, n=250, junk=True)
    rec = np.sort(np.concatenate([f.offset for f in ms.scan_tlog(path, ["HIGHRES_IMU", "ATTITUDE"]).frames.values()]))
    d = bytearray(path.read_bytes())
    rng = np.random.default_rng(seed)
    for k in sorted(rng.choice(rec[5:-5], 6, replace=False).tolist(), reverse=True):
        nxt = int(rec[np.searchsorted(rec, k) + 1])
        late = bytearray(d[k:nxt])  # a copy of a good record, received 3 days later, then junk:
        late[:8] = (int.from_bytes(late[:8], "big") + 3 * 86_400_000_000).to_bytes(8, "big")
        d[nxt:nxt] = bytes(late) + b"\x01\x02\x03" + bytes(d[k:nxt]) + b"\x07\x07"  # not a frame; a sane one is
    for k in rng.integers(800, len(d) - 100, 12):
        d[k] ^= 0x55  # CRC failures, broken headers, false start bytes
    for k in sorted(rng.integers(800, len(d) - 100, 4).tolist(), reverse=True):
        d[k:k] = rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes()  # junk runs
    return bytes(d[:-5])  # and a cut last record


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 2**52), min_size=1, max_size=600), st.booleans())
def test_frame_sync_median_equals_numpy(ts_us, few_distinct):
    """The sync's own median of receive timestamps (µs, as float64) is numpy's, odd and even
    lengths, with and without ties; its input is left unsorted."""
    x = np.array(ts_us, np.float64)
    if few_distinct:
        x = x % 7 + 1.7e15
    before = x.copy()
    assert _median(x) == np.median(x)
    np.testing.assert_array_equal(x, before)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_frame_sync_equals_the_plain_python_rules_on_damaged_tlogs(tmp_path, seed):
    data = _damaged_synthetic(tmp_path, seed)
    fast, slow = _kernel(data, 8, 0, len(data))
    assert len(slow) > 500
    assert fast == slow
    # a chunk in the middle of the file, starting after an earlier chunk's coverage
    a = 4000
    fast, slow = _kernel(data[a : a + 6000 + ms._PAD], 8 + 37, a, len(data))
    assert fast == slow and len(slow) > 50


@pytest.mark.parametrize("name", TLOGS)
def test_frame_sync_equals_the_plain_python_rules_on_real_tlogs(name):
    data = real_log(name).read_bytes()
    size = len(data)
    for a in (0, size // 2):
        fast, slow = _kernel(data[a : a + 40_000 + ms._PAD], 8, a, size)
        assert fast == slow and len(slow) > 20


def test_crc_failures_counted_in_bulk_like_pymavlink(tmp_path):
    src = real_log("ardusub_small.tlog")  # 4 CRC failures of its own
    scan = ms.scan_tlog(src, ["RAW_IMU", "ATTITUDE"])
    rng = np.random.default_rng(7)
    hit = {t: np.sort(rng.choice(len(scan.frames[t].offset), 15, replace=False)) for t in ("RAW_IMU", "ATTITUDE")}
    d = bytearray(src.read_bytes())
    for t, rows in hit.items():
        for off in scan.frames[t].offset[rows].tolist():
            hdr = 10 if d[off + 8] == 0xFD else 6
            d[off + 8 + hdr + 1] ^= 0x5A  # a payload byte: the frame stays in place, its CRC fails
    path = tmp_path / "damaged.tlog"
    path.write_bytes(bytes(d))
    damaged = ms.scan_tlog(path, ["RAW_IMU", "ATTITUDE"])
    assert damaged.corrupt_frames == scan.corrupt_frames + 30 == _pymavlink_bad_crc(path)
    assert damaged.junk_bytes == scan.junk_bytes and damaged.unknown_frames == scan.unknown_frames
    ref = _pymavlink_messages(path, ["RAW_IMU", "ATTITUDE"])
    for t, rows in hit.items():
        keep = np.setdiff1d(np.arange(len(scan.frames[t].offset)), rows)
        np.testing.assert_array_equal(damaged.frames[t].offset, scan.frames[t].offset[keep])
        assert len(ref[t]) == len(keep)
        tf = "time_usec" if t == "RAW_IMU" else "time_boot_ms"
        assert damaged.frames[t].fields[tf].tolist() == [getattr(m, tf) for m in ref[t]]


def _rows(*cols) -> np.ndarray:
    """Rows sorted lexicographically (the same samples in any order compare equal)."""
    a = np.column_stack(cols)
    return a[np.lexsort(a.T[::-1])]


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in TLOGS if n != "dkla_fs-batt.log"])
def test_reader_streams_equal_pymavlink_decoding(name):
    path = real_log(name)
    raw = tlog_reader.read(path)
    m = raw.meta
    imu_name, sysid = m["imu_message"], m["autopilot_sysid"]
    ref_name = raw.ref.source
    msgs = _pymavlink_messages(path, [imu_name, ref_name])

    def mine(x):
        return x.get_srcSystem() == sysid and x.get_srcComponent() == 1

    imu = [x for x in msgs[imu_name] if mine(x) and getattr(x, "id", 0) == m["imu_instance"]]
    assert imu_name in ("RAW_IMU", "SCALED_IMU2") and len(imu) == len(raw.imu.t_s) > 100
    tf = "time_usec" if imu_name == "RAW_IMU" else "time_boot_ms"
    t = np.array([getattr(x, tf) for x in imu], np.float64) / (1e6 if tf == "time_usec" else 1e3)
    acc = np.array([[x.xacc, x.yacc, x.zacc] for x in imu], np.float64) * (G / 1000)  # mG
    gyr = np.array([[x.xgyro, x.ygyro, x.zgyro] for x in imu], np.float64) * 1e-3  # mrad/s
    mag = np.array([[x.xmag, x.ymag, x.zmag] for x in imu], np.float64) * 0.1  # mGauss → µT
    np.testing.assert_array_equal(
        _rows(raw.imu.t_s, raw.imu.acc_m_s2, raw.imu.gyr_rad_s, raw.mag.mag_ut), _rows(t, acc, gyr, mag)
    )
    # inside each boot epoch, time order
    same = np.diff(raw.imu.epoch) == 0
    assert np.all(np.diff(raw.imu.t_s)[same] >= 0) and np.all(np.diff(raw.imu.epoch) >= 0)

    assert ref_name == "ATTITUDE"
    att = [x for x in msgs[ref_name] if mine(x)]
    assert len(att) == len(raw.ref.t_s)
    t_att = np.array([x.time_boot_ms for x in att], np.float64) / 1e3
    ypr = np.array([[x.yaw, x.pitch, x.roll] for x in att], np.float64)
    r = Rotation.from_euler("ZYX", ypr)
    if "ahrs_trim_rad" in raw.meta:  # ArduPilot's vehicle attitude turned into the board's frame (test_ahrs_trim)
        tx, ty = raw.meta["ahrs_trim_rad"]
        r = r * Rotation.from_euler("ZYX", [0.0, ty, tx])
    q = r.as_quat(scalar_first=True)

    def by_time(t_s, q_wxyz):  # q and -q are one attitude: w >= 0; rows in (time, q) order
        q_wxyz = q_wxyz * np.where(q_wxyz[:, :1] < 0, -1.0, 1.0)
        k = np.lexsort((*np.round(q_wxyz.T[::-1], 9), t_s))
        return t_s[k], q_wxyz[k]

    t_ours, q_ours = by_time(raw.ref.t_s, raw.ref.q_nb_wxyz)
    t_ref, q_ref = by_time(t_att, q)
    np.testing.assert_array_equal(t_ours, t_ref)
    np.testing.assert_allclose(q_ours, q_ref, rtol=0, atol=1e-12)
