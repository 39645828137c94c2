"""DataFlash ingest speed: our numpy fast path vs a plain pymavlink ``recv_match`` loop.

Builds a ≥ 100 MB binary log in a temporary folder by repeating the body of the shared
``erle_pxf_copter_15-12-2014_16.BIN`` (FMT records kept once at the start, every ``TimeMS`` or ``TimeUS`` field —
ArduPilot before and since 3.4 — shifted per copy so time keeps increasing), then times in one run:

(a) pymavlink: ``mavutil.mavlink_connection(path)`` + ``recv_match(type=["IMU", "ATT", "MAG"])``,
    reading every field we extract into lists (what a plain script does);
(b) ours: ``tepinn_flight.ingest.dataflash.read(path)`` (IMU, MAG, ATT reference, firmware
    messages, parameters, epochs, clipping).

Prints messages/s for each, the ratio, and the peak traced memory (tracemalloc, a second run)
of ours next to the size of the arrays it returns.

The same comparison runs on a text log built from ``aplogan_nan.log`` (pymavlink ``DFReader_text``). Each
reader reads the small source log once before it is timed (imports, first-call costs: since session 30).

    python benchmarks/ingest_speed_dataflash.py [--mb 100] [--text-mb 20] [--log PATH] [--keep]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DEFAULT_LOG = REPO.parent / "shared" / "real-logs" / "erle_pxf_copter_15-12-2014_16.BIN"
DEFAULT_TEXT_LOG = REPO.parent / "shared" / "real-logs" / "aplogan_nan.log"
FIELDS = {  # (each message's time first: TimeUS or TimeMS, whichever the log has)
    "IMU": ("GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"),
    "ATT": ("Roll", "Pitch", "Yaw"),
    "MAG": ("MagX", "MagY", "MagZ"),
}
#: a message's time field: (its DataFlash type, bytes, seconds per count); review61: only TimeMS had been shifted, so
#: a log of ArduPilot 3.4 on (TimeUS) failed to build
TIME_FIELDS = {"TimeUS": ("Q", 8, 1e-6), "TimeMS": ("I", 4, 1e-3)}


def build_big_log(src: Path, dst: Path, target_mb: float) -> int:
    """Write ``dst`` (≥ target_mb) from ``src``: FMT block once, then shifted copies of the body."""
    from tepinn_flight.ingest import dataflash_scan as dfs

    data = np.fromfile(src, np.uint8)
    mm, buf = dfs.open_buffer(src)
    table = dfs.find_formats(mm)
    res = dfs.scan(buf, table.lengths(), set(table.by_id))
    fmt_offs = res.offsets[dfs.FMT_ID]
    body_start = int(fmt_offs.max()) + dfs.FMT_LEN
    body_end = res.data_end
    # positions and values of every time field in the body, per field kind
    found = {name: ([], []) for name in TIME_FIELDS}
    for tid, offs in res.offsets.items():
        mf = table.by_id[tid]
        for name, (tc, nb, _) in TIME_FIELDS.items():
            if name in mf.columns and mf.type_char(name) == tc:
                p = offs[offs >= body_start] + mf.field_offset(name)
                found[name][0].append(p - body_start)
                found[name][1].append(data[p[:, None] + np.arange(nb)].copy().view(f"<u{nb}").ravel())
                break
    imu = table.by_name["IMU"]
    rows = dfs.decode_rows(buf, imu, res.offsets[imu.type_id])
    name = next((n for n in TIME_FIELDS if n in imu.columns), None)
    if name is None:
        raise SystemExit(f"{src}: its IMU message has neither TimeUS nor TimeMS")
    imu_t = rows[name].astype(np.float64) * TIME_FIELDS[name][2]
    shift_s = float(imu_t.max() - imu_t.min()) + 0.02  # the next copy continues one IMU period later
    body = data[body_start:body_end].copy()
    copies = int(np.ceil(target_mb * 1e6 / len(body)))
    found = {name: (np.concatenate(p), np.concatenate(v)) for name, (p, v) in found.items() if p}
    with open(dst, "wb") as f:
        f.write(data[:body_start].tobytes())
        for k in range(copies):
            for name, (pos, vals) in found.items():
                _, nb, unit = TIME_FIELDS[name]
                shifted = (vals.astype(np.int64) + k * round(shift_s / unit)).astype(f"<u{nb}")
                body[pos[:, None] + np.arange(nb)] = shifted.view(np.uint8).reshape(-1, nb)
            f.write(body.tobytes())
    del mm
    return copies


def build_big_text_log(src: Path, dst: Path, target_mb: float) -> int:
    """Text variant: FMT lines once, then copies of the body with every TimeMS or TimeUS field shifted."""
    lines = src.read_text(errors="replace").splitlines()
    fmt_idx = [i for i, ln in enumerate(lines) if ln.startswith("FMT,")]
    time_col, unit = {}, {}
    for i in fmt_idx:
        parts = [p.strip() for p in lines[i].split(",")]
        cols = parts[5:]
        name = next((n for n in TIME_FIELDS if n in cols), None)
        if name is not None and parts[3] != "GPS":
            time_col[parts[3]], unit[parts[3]] = cols.index(name) + 1, TIME_FIELDS[name][2]
    head, body = lines[: fmt_idx[-1] + 1], lines[fmt_idx[-1] + 1 :]
    split = [ln.split(",") for ln in body]
    times = [int(p[time_col[p[0]]]) * unit[p[0]] for p in split if p[0] in time_col and len(p) > time_col[p[0]]]
    shift_s = max(times) - min(times) + 0.02
    copies = int(np.ceil(target_mb * 1e6 / sum(len(ln) + 1 for ln in body)))
    with open(dst, "w") as f:
        f.write("\n".join(head) + "\n")
        for k in range(copies):
            out = []
            for p in split:
                c = time_col.get(p[0])
                if c is not None and len(p) > c:
                    p = p[:c] + [f" {int(p[c]) + k * round(shift_s / unit[p[0]])}"] + p[c + 1 :]
                out.append(",".join(p))
            f.write("\n".join(out) + "\n")
    return copies


def streams_of(raw) -> tuple[str, int | None, str, int | None]:
    """The IMU message and instance, and the reference message and core, our reader took from a log (what the plain
    loop reads too: review61 — a 4.x log's two IMU instances and its XKQ reference had been counted against IMU 0 and
    ATT). A message with an instance field (``I``) or core field (``C``) is read for that one only."""
    imu = raw.meta.get("imu_message", "IMU")
    name, _, core = raw.ref.source.partition("[")
    return (imu, int(raw.meta.get("imu_instance", 0)) if imu == "IMU" else None, name,
            int(core.rstrip("]")) if core else (0 if name in ("XKQ", "NKQ") else None))


def pymavlink_loop(path: Path, text: bool = False, streams=("IMU", None, "ATT", None)) -> tuple[int, dict]:
    from pymavlink import DFReader, mavutil

    imu, inst, ref, core = streams
    want = {imu: ("I", inst, FIELDS["IMU"]), ref: ("C", core, FIELDS["ATT"] if ref == "ATT" else ()),
            "MAG": ("I", 0, FIELDS["MAG"])}  # fmt: skip
    # mavlink_connection picks DFReader_text for a .log name; say so explicitly for clarity
    conn = DFReader.DFReader_text(str(path)) if text else mavutil.mavlink_connection(str(path))
    out = {t: [] for t in want}
    n = 0
    while True:
        m = conn.recv_match(type=list(want))
        if m is None:
            break
        t = m.get_type()
        key, k, fields = want[t]
        if k is not None and getattr(m, key, k) != k:
            continue
        time = getattr(m, "TimeUS", None)
        out[t].append([getattr(m, "TimeMS") if time is None else time, *(getattr(m, f) for f in fields)])
        n += 1
    return n, {label: np.asarray(out[t]) for label, t in (("IMU", imu), ("ATT", ref), ("MAG", "MAG"))}


def ours(path: Path):
    from tepinn_flight.ingest.dataflash import read

    return read(path)


def output_bytes(raw) -> int:
    arrays = [raw.imu.t_s, raw.imu.gyr_rad_s, raw.imu.acc_m_s2, raw.imu.clipped, raw.imu.epoch]
    for s in (raw.mag, raw.ref):
        if s is not None:
            arrays += [s.t_s, getattr(s, "mag_ut", None), getattr(s, "q_nb_wxyz", None), s.epoch]
    return sum(a.nbytes for a in arrays if a is not None)


def _compare(label: str, path: Path, size_mb: float, text: bool, warm: Path | None = None) -> None:
    streams = streams_of(ours(warm if warm is not None else path))  # the messages both read
    if warm is not None:  # both readers once on the small source log first: their imports and first-call costs
        ours(warm)  # (the binary reader's are paid by whichever runs first; session 30)
        pymavlink_loop(warm, text, streams)
    t0, c0 = time.perf_counter(), time.process_time()
    raw = ours(path)
    t_ours, c_ours = time.perf_counter() - t0, time.process_time() - c0
    n_imu, n_att = len(raw.imu.t_s), len(raw.ref.t_s)
    n_mag = 0 if raw.mag is None else len(raw.mag.t_s)
    t0, c0 = time.perf_counter(), time.process_time()
    n_pm, pm = pymavlink_loop(path, text, streams)
    t_pm, c_pm = time.perf_counter() - t0, time.process_time() - c0
    n_ours = n_imu + n_att + n_mag
    same = len(pm["IMU"]) == n_imu and len(pm["ATT"]) == n_att and len(pm["MAG"]) == n_mag
    gyro_equal = same and np.array_equal(pm["IMU"][:, 1:4], raw.imu.gyr_rad_s)
    print(f"[{label}] messages extracted: {streams[0]} {n_imu}, {streams[2]} {n_att}, MAG {n_mag} "
          f"(pymavlink: {n_pm}; counts equal: {same}; gyro values equal: {gyro_equal}; "
          f"boot epochs: {int(raw.imu.epoch.max()) + 1})")  # fmt: skip
    print(f"{'reader':<28}{'time s':>10}{'msg/s':>14}{'MB/s':>10}")
    print(f"{'pymavlink recv_match loop':<28}{t_pm:>10.2f}{n_pm / t_pm:>14,.0f}{size_mb / t_pm:>10.1f}")
    print(f"{'tepinn dataflash.read':<28}{t_ours:>10.2f}{n_ours / t_ours:>14,.0f}{size_mb / t_ours:>10.1f}")
    print(f"[{label}] speed-up: {t_pm / t_ours:.1f}x (CPU time: {c_pm / c_ours:.1f}x; this machine is shared)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=100.0, help="size of the generated log (MB)")
    ap.add_argument("--log", type=Path, default=DEFAULT_LOG, help="DataFlash .BIN to repeat")
    ap.add_argument("--text-mb", type=float, default=20.0, help="size of the generated text log (MB; 0: skip)")
    ap.add_argument("--text-log", type=Path, default=DEFAULT_TEXT_LOG, help="text DataFlash log to repeat")
    ap.add_argument("--keep", action="store_true", help="keep the generated logs and print their folder")
    args = ap.parse_args(argv)
    if not args.log.exists():
        print(f"source log {args.log} not found", file=sys.stderr)
        return 2
    tmp = Path(tempfile.mkdtemp(prefix="df_bench_"))
    try:
        big = tmp / "big.BIN"
        copies = build_big_log(args.log, big, args.mb)
        size_mb = big.stat().st_size / 1e6
        print(f"log: {big.name}, {size_mb:.1f} MB ({copies} copies of {args.log.name})")

        _compare("binary", big, size_mb, text=False, warm=args.log)
        tracemalloc.start()
        raw = ours(big)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        out_mb = output_bytes(raw) / 1e6
        print(f"ours peak traced memory: {peak / 1e6:.1f} MB for {out_mb:.1f} MB of output arrays "
              f"(ratio {peak / 1e6 / out_mb:.2f}; file {size_mb:.0f} MB is mmapped, not copied)")
        if args.text_mb > 0 and args.text_log.exists():
            txt = tmp / "big.log"
            copies = build_big_text_log(args.text_log, txt, args.text_mb)
            tmb = txt.stat().st_size / 1e6
            print(f"\ntext log: {txt.name}, {tmb:.1f} MB ({copies} copies of {args.text_log.name})")
            _compare("text", txt, tmb, text=True, warm=args.text_log)
        if args.keep:
            print(f"kept: {tmp}")
            return 0
    finally:
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
