"""tlog ingestion speed: our reader vs a plain pymavlink ``recv_match`` loop, same run.

Builds >= 42 MB tlogs in a temporary folder and extracts the IMU and attitude messages
(RAW_IMU, SCALED_IMU*, HIGHRES_IMU, ATTITUDE, ATTITUDE_QUATERNION) from each with

  (a) pymavlink: ``mavutil.mavlink_connection(path)`` + ``recv_match(type=[...])`` until None,
      keeping the fields of every message (the usual way to read a tlog);
  (b) ours: ``tepinn_flight.ingest.tlog.read(path)`` (scan + decode + units + streams), and
      the frame scan alone (``mavlink_scan.scan_tlog``).

Files (``--source``):

* ``real`` (default): each shared real tlog (``ardusub_small``, ``ardusub_2023-04-18_11-03-34``,
  ``uavlv_vtol``, ``uavlv_pr437_flight_logs``) concatenated with itself, byte for byte, up to
  ``--mb``: real content (their junk, CRC failures, other components), and each copy starts a new
  boot (boot and receive times jump back, as in a file of several flights).
* ``synth``: a synthetic flight encoded with pymavlink's own encoder: HIGHRES_IMU 200 Hz,
  ATTITUDE and ATTITUDE_QUATERNION 50 Hz, a companion computer's ATTITUDE 50 Hz (component 191,
  must be ignored), SERVO_OUTPUT_RAW 50 Hz, GLOBAL_POSITION_INT, VFR_HUD 10 Hz, SYS_STATUS 2 Hz,
  HEARTBEATs 1 Hz; one frame in 10,000 with a flipped payload byte (CRC failure) and a few junk
  bytes every 50,000 records. Mostly IMU/attitude traffic: pymavlink's decoding dominates.

Prints msg/s of both and the ratio (wall time; the CPU-time ratio too: this machine is shared); our peak traced memory (tracemalloc, after a warm-up) next
to the output arrays' size; the one-time cost of a fresh process's first read (numba loads the
compiled frame sync from its cache) is printed apart. Values are checked equal (counts per type,
time fields) so the comparison is fair.

    python benchmarks/ingest_speed_tlog.py [--mb 42] [--source real|synth|all]
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

os.environ["MAVLINK20"] = "1"

import numpy as np  # noqa: E402

from tepinn_flight.ingest import tlog  # noqa: E402
from tepinn_flight.ingest.mavlink_scan import _id_tables, layout, scan_tlog  # noqa: E402

WANTED = [*tlog.IMU_MESSAGES, *tlog.REF_MESSAGES]
REAL_LOGS = Path(__file__).resolve().parents[2] / "shared" / "real-logs"
REAL = ("ardusub_small.tlog", "ardusub_2023-04-18_11-03-34.tlog", "uavlv_vtol.tlog", "uavlv_pr437_flight_logs.tlog")


def make_synth(path: Path, mb: float) -> None:
    from pymavlink.dialects.v20 import all as mavlink2

    ap = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    cc = mavlink2.MAVLink(None, srcSystem=1, srcComponent=191)
    gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    rng = np.random.default_rng(1)
    target = int(mb * 1e6)
    t0_unix = 1_700_000_000.0
    n_rec = 0
    written = 0
    step = 0  # 200 Hz ticks
    with open(path, "wb", buffering=1 << 20) as f:

        def put(mav, msg, t_s):
            nonlocal n_rec, written
            buf = bytearray(msg.pack(mav))
            mav.seq = (mav.seq + 1) % 256
            n_rec += 1
            if n_rec % 10_000 == 0:
                buf[12] ^= 0x5A  # CRC failure
            rec = struct.pack(">Q", int((t0_unix + t_s) * 1e6)) + bytes(buf)
            if n_rec % 50_000 == 0:
                rec = b"\x00\x13\x37" + rec  # junk
            f.write(rec)
            written += len(rec)

        while written < target:
            t = step / 200.0
            boot_us = int(5e6 + t * 1e6)
            roll, pitch, yaw = 0.3 * math.sin(0.5 * t), 0.2 * math.sin(0.3 * t), math.remainder(0.1 * t, 2 * math.pi)
            g = rng.normal(0, 0.01, 3)
            a = rng.normal(0, 0.05, 3) + (0.0, 0.0, -9.80665)
            put(ap, mavlink2.MAVLink_highres_imu_message(
                boot_us, *a, *g, 0.2, 0.01, 0.4, 1013.0, 0.0, 100.0, 25.0, 0x1FFF, 0), t)  # fmt: skip
            if step % 4 == 0:
                tb = boot_us // 1000
                cr, sr = math.cos(roll / 2), math.sin(roll / 2)
                cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
                cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
                q = [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy]  # fmt: skip
                put(ap, mavlink2.MAVLink_attitude_message(tb, roll, pitch, yaw, *g), t)
                put(ap, mavlink2.MAVLink_attitude_quaternion_message(tb, *q, *g, [0, 0, 0, 0]), t)
                put(cc, mavlink2.MAVLink_attitude_message(tb, roll + 0.01, pitch, yaw, *g), t)
                put(ap, mavlink2.MAVLink_servo_output_raw_message(boot_us & 0xFFFFFFFF, 0, *([1500] * 8)), t)
            if step % 20 == 0:
                put(ap, mavlink2.MAVLink_global_position_int_message(tb, 473977420, 85455940, 500000, 20000, 10, 0, 0, 0), t)
                put(ap, mavlink2.MAVLink_vfr_hud_message(12.0, 12.5, 90, 50, 500.0, 0.1), t)
            if step % 100 == 0:
                put(ap, mavlink2.MAVLink_sys_status_message(0, 0, 0, 500, 12600, 500, 80, 0, 0, 0, 0, 0, 0), t)
            if step % 200 == 0:
                put(ap, mavlink2.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3), t)  # quadrotor, PX4
                put(cc, mavlink2.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3), t)
                put(gcs, mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3), t)
            step += 1


def make_repeat(path: Path, mb: float, src: Path) -> None:
    data = src.read_bytes()
    with open(path, "wb") as f:
        for _ in range(math.ceil(mb * 1e6 / len(data))):
            f.write(data)


def run_pymavlink(path: Path):
    from pymavlink import mavutil

    t0, c0 = time.perf_counter(), time.process_time()
    conn = mavutil.mavlink_connection(str(path))
    out = {n: [] for n in WANTED}
    while True:
        m = conn.recv_match(type=WANTED)
        if m is None:
            break
        d = m.to_dict()
        out[m.get_type()].append(d)
    return (time.perf_counter() - t0, time.process_time() - c0), out


def output_nbytes(raw) -> int:
    """Bytes of every array a read() returns: its streams (IMU, magnetometer, reference, GNSS velocity), the
    valid mask and the extra columns (before session 30 the GNSS stream, added in session 14, was left out)."""
    arrays = [a for s in (raw.imu, raw.mag, raw.ref, raw.gnss) if s is not None for a in vars(s).values()
              if isinstance(a, np.ndarray)]  # fmt: skip
    arrays += [raw.valid] if isinstance(raw.valid, np.ndarray) else []
    arrays += [a for a in raw.extra.values() if isinstance(a, np.ndarray)]
    return sum(a.nbytes for a in arrays)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mb", type=float, default=42.0, help="size of each test tlog in MB (default 42)")
    ap.add_argument("--source", choices=["all", "synth", "real"], default="real")
    ap.add_argument("--keep", metavar="DIR", help="build the tlogs here and keep them")
    args = ap.parse_args()

    tmp = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="tlogbench_"))
    tmp.mkdir(parents=True, exist_ok=True)
    sources = []
    if args.source in ("all", "synth"):
        sources.append(("synth", None))
    if args.source in ("all", "real"):
        for name in REAL:
            if (REAL_LOGS / name).exists():
                sources.append((name.split(".")[0], REAL_LOGS / name))
            else:
                print(f"skipping {name}: not in {REAL_LOGS}", file=sys.stderr)
    first = first_read_cost(REAL_LOGS / REAL[-1] if (REAL_LOGS / REAL[-1]).exists() else None)
    # warm-up outside the timings: the dialect tables and the compiled frame sync (pymavlink is
    # imported inside run_pymavlink before its clock starts)
    _id_tables()
    for n in WANTED:
        layout(n)
    if first is not None:
        tlog.read(REAL_LOGS / REAL[-1])
    rows = []
    try:
        for src, real in sources:
            path = tmp / f"bench_{src}.tlog"
            if not path.exists():
                t = time.perf_counter()
                make_synth(path, args.mb) if real is None else make_repeat(path, args.mb, real)
                print(f"[{src}] built {path.stat().st_size / 1e6:.1f} MB in {time.perf_counter() - t:.1f} s", flush=True)
            size_mb = path.stat().st_size / 1e6

            t = time.perf_counter()
            scan = scan_tlog(path, WANTED)
            t_scan = time.perf_counter() - t
            t, c = time.perf_counter(), time.process_time()
            raw = tlog.read(path)
            t_read, c_read = time.perf_counter() - t, time.process_time() - c

            tracemalloc.start()
            raw2 = tlog.read(path)
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            out_bytes = output_nbytes(raw2)
            del raw2

            (t_pm, c_pm), pm = run_pymavlink(path)
            n_pm = sum(len(v) for v in pm.values())
            n_ours = sum(len(scan.frames[n].offset) for n in WANTED)
            # fairness: same messages, same values (counts per type and the time fields)
            for n in WANTED:
                assert len(pm[n]) == len(scan.frames[n].offset), (n, len(pm[n]), len(scan.frames[n].offset))
                if pm[n]:
                    tf = "time_usec" if "time_usec" in pm[n][0] else "time_boot_ms"
                    assert np.array_equal([d[tf] for d in pm[n]], scan.frames[n].fields[tf]), n
            rows.append((src, size_mb, n_pm, t_pm, t_scan, t_read, peak, out_bytes, len(raw.imu.t_s), scan))
            print(f"[{src}] pymavlink {t_pm:.1f} s, ours read() {t_read:.2f} s (scan {t_scan:.2f} s); "
                  f"CPU time: pymavlink {c_pm:.1f} s, ours read() {c_read:.2f} s, ratio {c_pm / c_read:.1f}x", flush=True)
    finally:
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)

    print()
    print(f"{'file':32} {'MB':>6} {'msgs':>9} {'pymavlink msg/s':>16} {'ours read() msg/s':>18} "
          f"{'scan msg/s':>11} {'ratio read':>10} {'ratio scan':>10} {'MB/s read':>9}")  # fmt: skip
    for src, mb, n, t_pm, t_scan, t_read, peak, out_b, n_imu, scan in rows:
        print(f"{src:32} {mb:6.1f} {n:9d} {n / t_pm:16,.0f} {n / t_read:18,.0f} {n / t_scan:11,.0f} "
              f"{t_pm / t_read:9.1f}x {t_pm / t_scan:9.1f}x {mb / t_read:9.1f}")  # fmt: skip
    print()
    for src, mb, n, t_pm, t_scan, t_read, peak, out_b, n_imu, scan in rows:
        print(f"[{src}] frames scanned {scan.good_frames:,} ({scan.good_frames / t_scan:,.0f} frames/s), "
              f"corrupt {scan.corrupt_frames}, junk bytes {scan.junk_bytes}; IMU samples kept {n_imu:,}")  # fmt: skip
        print(f"[{src}] peak traced memory of read(): {peak / 1e6:.1f} MB; output arrays {out_b / 1e6:.1f} MB "
              f"(ratio {peak / out_b:.2f}); file {mb:.1f} MB")  # fmt: skip
    if first is not None:
        print(f"\nfirst read in a fresh process (imports, dialect, numba cache load), {REAL[-1]}: "
              f"{first[0]:.2f} s, of which the read() call {first[1]:.2f} s; later reads of it: {first[2]:.3f} s")  # fmt: skip
    return 0


def first_read_cost(path: Path | None):
    """(fresh process total, its first read() call, a second read() call) in seconds."""
    if path is None:
        return None
    code = (
        "import time; t0 = time.perf_counter()\n"
        "from tepinn_flight.ingest import tlog\n"
        "t1 = time.perf_counter(); tlog.read(%r); t2 = time.perf_counter(); tlog.read(%r)\n"
        "print(t2 - t0, t2 - t1, time.perf_counter() - t2)" % (str(path), str(path))
    )
    tlog.read(path)  # make sure the compiled frame sync is in numba's cache
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=os.environ)
    return tuple(float(x) for x in out.stdout.split())


if __name__ == "__main__":
    sys.exit(main())
