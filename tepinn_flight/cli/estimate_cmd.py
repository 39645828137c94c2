"""``tepinn-flight estimate [--model CKPT|MODEL.onnx] [--runtime torch|onnx|auto] RECORD... -o OUT``."""

from __future__ import annotations

import dataclasses

from .argtypes import add_runtime, busy_stride, threads, workers
from .helptext import add_examples
from .paths import add_recursive

HELP = "estimate attitude over flight records with TE-PINN (the shipped model by default)"
DESCRIPTION = (
    "Runs over whole records: the network on its windows (batched; once a second where no gate can open), then "
    "the VQF filter it corrects where the evidence says so (flight speed, gyro saturation, an uncalibrated gyro; never "
    "below a 20 Hz IMU, slower than the network learned); "
    "offline only, where the record shows them, the accelerometer's and the gyro's scale and the motion "
    "acceleration a GNSS receiver measured are taken out first, and where no gate acts for 30 s or more (5 s where "
    "none acts next to it: a short log) the tilt is VQF's run forward and backward (--no-smooth: the causal tilt; with --no-gnss-aid "
    "--no-gyro-selfcal too, what the live bridge gives). Writes one row per "
    "input row: t_s (s from the record's first sample), t_log_s (a real log's own clock: DataFlash TimeUS, MAVLink "
    "time_boot_ms, ULog timestamp, in s), q_est_w..z (Hamilton, scalar first, body FRD -> NED), sigma_rad (the "
    "1-sigma tilt uncertainty per horizontal axis, rad), gyr_bias_est_*_rad_s (body FRD), and says per record what each "
    "step did. In 6-D the heading is relative: it starts at 90 deg (VQF's own origin, its x axis taken as east) and "
    "follows the gyro. Short logging dropouts (<= 100 ms) are propagated through, longer gaps restart the estimator. A "
    "raw log is ingested on the fly."
)


def add_arguments(p) -> None:
    add_examples(p,
                 'tepinn-flight estimate flight.parquet -o flight_est.parquet',
                 'tepinn-flight estimate flight.ulg -o flight_est.csv   # CSV: t_s, t_log_s, q_est_w..z, sigma_rad, gyro bias',
                 'tepinn-flight estimate 00000042.BIN -o est.parquet --mode auto   # a log: ingested on the fly',
                 'tepinn-flight estimate flight.tlog -o est.parquet --tlog flight_est.tlog   # overlay on ATT in MAVExplorer',
                 'tepinn-flight estimate records/*.parquet -o estimates/ --model runs/mine/model.pt',
                 'tepinn-flight estimate APM/LOGS/ -o estimates/     # every log in a folder')
    p.add_argument("records", nargs="+", metavar="RECORD",
                   help="flight records (.parquet) or logs (.tlog, .bin, .log, .ulg: ingested on the fly, as `ingest` would); "
                        "a folder stands for the records and logs in it")
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="output file (one record): Parquet (.parquet) or CSV (.csv: the same columns, for spreadsheets "
                        "and MATLAB); or a folder (a .parquet per record)")
    p.add_argument("--model", default=None, metavar="CKPT",
                   help="checkpoint or .onnx export (`tepinn-flight export`; default: the shipped model)")
    add_runtime(p)
    p.add_argument("--yaw", choices=["gyro", "zero"], default=None,
                   help="heading of the output: integrated gyro (default) or 0 (the paper's 6-D correction)")
    p.add_argument("--mode", choices=["6d", "9d", "auto"], default=None,
                   help="6d: gyro + accelerometer, heading relative (90 deg at the start, then the gyro's); 9d: with the magnetometer, heading from magnetic "
                        "north (no declination applied); auto: 9d where the record has a magnetometer "
                        "(default: the model's, 6d for the shipped one)")
    p.add_argument("--threads", type=threads, default=0, metavar="N", help="CPU threads of the runtime (default: its own choice)")
    p.add_argument("--workers", type=workers, default=1, metavar="N",
                   help="estimate N records at a time in N processes, each running the network on one thread (many logs "
                        "on a multi-core machine: docs/results.md, Speed); default 1")
    p.add_argument("--busy-stride", type=busy_stride, default=0, metavar="N",
                   help="where the network stays busy (fixed wing: flight-speed evidence), run every N-th window "
                        "after a segment's first 10 s (windows holding a saturated sample always run): about N "
                        "times less network time there, at some accuracy (held-out simulated fixed wing 6.76 -> "
                        "7.40 deg at 6; docs/results.md, Speed); default: the model's (1: every window)")
    p.add_argument("--no-accel-scale", action="store_true",
                   help="do not read the accelerometer's scale from the record's quiet, steady samples (by default it is "
                        "divided out where it reads 10 %% or more off 1 g; the live bridge reads it causally: docs/estimator.md)")
    p.add_argument("--no-gyro-selfcal", action="store_true",
                   help="do not read the gyro's per-axis scale from the record's rests (the estimate the live bridge "
                        "gives; by default it is read and applied where the record shows one: docs/estimator.md)")
    p.add_argument("--no-gnss-aid", action="store_true",
                   help="do not take the motion acceleration the record's GNSS velocity shows out of the accelerometer "
                        "(the estimate the live bridge gives; by default it is, where the record has a receiver's "
                        "velocity and it agrees with the accelerometer: docs/estimator.md)")
    smooth = p.add_mutually_exclusive_group()
    smooth.add_argument("--no-smooth", action="store_true",
                        help="do not smooth the tilt offline (the causal estimate; the live bridge's with --no-gnss-aid and "
                             "--no-gyro-selfcal too; by default every "
                             "stretch of 30 s or more where no gate of the network acts (5 s where none acts next to it) takes "
                             "the tilt of VQF run forward and backward on the same inputs, heading kept: nearer the true "
                             "attitude, farther from an autopilot's own causal estimate: docs/estimator.md)")
    smooth.add_argument("--smooth", action="store_true",
                        help="smooth the tilt offline with a checkpoint that does not (one written before session 25)")
    p.add_argument("--tlog", default=None, metavar="FILE|DIR",
                   help="also write a tlog (file for one record, folder for several): the source tlog's messages (or, for "
                        "other sources, the record's IMU and reference attitude) plus the estimate from component 191, "
                        "for MAVExplorer, UAV Log Viewer, QGroundControl or PlotJuggler")
    p.add_argument("--source-log", default=None, metavar="TLOG",
                   help="the .tlog the record was ingested from (default: the record's source_file next to the record)")
    p.add_argument("--tlog-messages", default="attitude_quaternion,debug_vect", metavar="KINDS",
                   help="estimate messages in the tlog, comma-separated: attitude_quaternion, attitude, debug_vect "
                        "(TP_RPY, deg), named_value (tp_roll/tp_pitch/tp_yaw, deg); default attitude_quaternion,debug_vect")
    p.add_argument("--tlog-rate", type=float, default=50.0, metavar="HZ", help="estimates per second of log time in the tlog (default 50)")
    p.add_argument("--resume", action="store_true",
                   help="skip a record whose output is already there, made from the same source file (size and time) "
                        "by the same model and settings (each output carries that key): a killed run over a folder "
                        "of logs goes on where it stopped")
    add_recursive(p)
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors and warnings (no progress bar)")


def run(args) -> int:
    from .notes import run_noting_compiles

    return run_noting_compiles("estimate", args, _run)  # the first run after installing compiles the loops: say so, once


def _run(args) -> int:
    import sys
    from pathlib import Path

    from ..errors import ConfigError, TepinnError
    from ..model.anchor import with_busy_stride
    from ..model.checkpoint import default_model_path, is_training_checkpoint
    from ..model.runtime import default_onnx_path, load_runner, resolve_runtime
    from ..record import check_output
    from .paths import collect_records, output_format, output_paths, refuse_overwriting_inputs

    ckpt_path = Path(args.model) if args.model else default_model_path()
    if not args.model and resolve_runtime(ckpt_path, args.runtime) == "onnx" and default_onnx_path().is_file():
        ckpt_path = default_onnx_path()  # the shipped model, exported
    if not args.model and not ckpt_path.exists():
        raise TepinnError("the shipped default model is missing from this installation; pass --model CKPT")
    model, fusion, ck = load_runner(ckpt_path, args.runtime, args.threads or None)
    if is_training_checkpoint(ck) and not args.quiet:
        sys.stderr.write(f"tepinn-flight estimate: note: {ckpt_path} is a checkpoint a training run writes as it goes "
                         "(best.pt, last.pt): it runs the network-centred fusion uncalibrated; the run's estimator is "
                         "its model.pt\n")  # fmt: skip
    if args.mode:
        if not hasattr(fusion, "mode"):
            raise TepinnError(f"--mode {args.mode}: {ckpt_path.name} runs the older network-centred fusion, 6-D only")
        fusion = dataclasses.replace(fusion, mode=args.mode)
    fusion = with_busy_stride(fusion, args.busy_stride, ckpt_path.name)
    if args.no_accel_scale and getattr(fusion, "accel_scale_selfcal", False):
        fusion = dataclasses.replace(fusion, accel_scale_selfcal=False)
    if args.no_gyro_selfcal and getattr(fusion, "gyro_selfcal", False):
        fusion = dataclasses.replace(fusion, gyro_selfcal=False)
    if args.no_gnss_aid and getattr(fusion, "gnss_aid", False):
        fusion = dataclasses.replace(fusion, gnss_aid=False)
    if args.smooth:
        if not hasattr(fusion, "smoother"):
            raise TepinnError(f"--smooth: {ckpt_path.name} runs the older network-centred fusion, which has no offline smoothing")
        fusion = dataclasses.replace(fusion, smoother=True)
    if args.no_smooth and getattr(fusion, "smoother", False):
        fusion = dataclasses.replace(fusion, smoother=False)
    if args.yaw and hasattr(fusion, "yaw"):  # the network-centred fusion's own setting
        fusion = dataclasses.replace(fusion, yaw=args.yaw)
    # the anchored estimator's heading is VQF's: --yaw zero takes it out of the output (it was ignored)
    yaw_zero = args.yaw == "zero" and not hasattr(fusion, "yaw")
    left_out: list[str] = []
    paths = collect_records(args.records, args.recursive, left_out)
    for line in left_out:
        sys.stderr.write(f"tepinn-flight estimate: note: {line}\n")
    # a folder's outputs go to a folder, and so do those of several inputs (one file named twice is read once)
    from_folder = len(args.records) > 1 or any(Path(i).is_dir() for i in args.records)
    outs = output_paths(paths, args.output, from_folder)
    if any(output_format(dst, "estimate", csv=True) == "csv" for dst in outs) and args.resume:
        raise ConfigError("--resume reads the key a Parquet output carries (its source, model and settings); a CSV "
                          "output has none: write .parquet to resume")  # fmt: skip
    tlogs = _tlog_paths(args, paths, from_folder)
    refuse_overwriting_inputs([*(("-o", o) for o in outs), *(("--tlog", t) for t in tlogs)],
                              [*paths, *([args.source_log] if args.source_log else [])])  # fmt: skip
    for dst in [*outs, *tlogs]:  # before any work: an output that cannot be written is a one-line error
        check_output(dst)
    from tqdm import tqdm

    opts = _Options(args.quiet, args.tlog_messages, args.tlog_rate, args.source_log, ckpt_path.name,
                    _settings_key(ckpt_path, fusion) + ("|yaw=zero" if yaw_zero else ""), args.resume, yaw_zero)  # fmt: skip
    jobs = [(src, dst, tlogs[i] if tlogs else None) for i, (src, dst) in enumerate(zip(paths, outs))]
    if jobs:  # a cold numba cache (the first run after installing): its loops compiled in two processes at once
        from ..jit_warmup import warm_up

        warm_up()
    n_workers = min(args.workers, len(jobs))
    if n_workers > 1:  # one record per worker process at a time, each with its own runtime on one thread
        results = _in_workers(jobs, opts, ckpt_path, args.runtime, fusion, n_workers)
    else:
        results = (_estimate_one(model, fusion, opts, *job) for job in jobs)
    failures = 0
    # (no bar where stderr is no terminal: a batch job's log had held its redraws between the error lines; review60)
    bar = tqdm(results, total=len(jobs), unit="record", file=sys.stderr,
               disable=args.quiet or len(jobs) < 2 or not sys.stderr.isatty())  # fmt: skip
    for out_lines, err_lines, failed in bar:
        for line in err_lines:  # each on a line of its own, not after the bar's (stderr to a file: one line each)
            bar.write(line, file=sys.stderr)
        for line in out_lines:
            bar.write(line, file=sys.stdout)
        failures += failed
    if failures and len(jobs) > 1:  # the count at the end of a folder's run (review60: the errors had to be counted)
        sys.stderr.write(f"tepinn-flight estimate: {failures} of {len(jobs)} input(s) failed (the lines above); "
                         f"{len(jobs) - failures} estimated or up to date\n")  # fmt: skip
    return 2 if failures else 0


@dataclasses.dataclass(frozen=True)
class _Options:
    """What a record's estimate needs of the command line (picklable, for the worker processes)."""

    quiet: bool
    tlog_messages: str
    tlog_rate: float
    source_log: str | None
    model_name: str
    settings_key: str = ""  # the model file and the estimator's settings (:func:`_settings_key`)
    resume: bool = False
    yaw_zero: bool = False  # the output's heading set to 0 (--yaw zero with the anchored estimator)


def _settings_key(ckpt_path, fusion) -> str:
    """What an output depends on besides its source: the model file's bytes, every estimator setting and the
    offline steps' own settings (their defaults, which no checkpoint carries: a new rule changes them)."""
    import hashlib

    from .. import __version__
    from ..model.accel_scale import AccelScaleConfig
    from ..model.gnss_aid import GnssAidConfig
    from ..model.gyro_selfcal import GyroSelfCalConfig
    from ..model.runtime import file_sha256
    from ..model.smoother import SmootherConfig

    steps = f"{AccelScaleConfig()!r}|{GyroSelfCalConfig()!r}|{GnssAidConfig()!r}|{SmootherConfig()!r}"
    return hashlib.sha256(f"{__version__}|{file_sha256(ckpt_path)}|{fusion!r}|{steps}".encode()).hexdigest()


def _output_key(opts: _Options, src, tlog: bool = False) -> str:
    """The key an output of ``src`` carries (``estimate_key`` in its metadata): the settings' and the source
    file's name, size and modification time, and with ``tlog`` the tlog's own options (a changed ``--tlog-messages``,
    ``--tlog-rate`` or ``--source-log`` had left a resumed tlog as it was, "up to date")."""
    import hashlib
    from pathlib import Path

    st = Path(src).stat()
    key = f"{OUTPUT_VERSION}|{opts.settings_key}|{Path(src).name}|{st.st_size}|{st.st_mtime_ns}"
    if tlog:
        source = Path(opts.source_log).resolve() if opts.source_log and Path(opts.source_log).exists() else None
        sst = source.stat() if source else None
        key += f"|tlog|{opts.tlog_messages}|{opts.tlog_rate!r}|{source}|{sst and sst.st_size}|{sst and sst.st_mtime_ns}"
    return hashlib.sha256(key.encode()).hexdigest()[:32]


#: the output's own version, in its key: an output written before a change of its columns is not "up to date"
#: (2: t_log_s, session 45)
OUTPUT_VERSION = 2


def _up_to_date(dst, key: str, tlog_dst=None) -> bool:
    """``dst`` exists, is a readable Parquet file and carries ``key`` (written atomically: then it is whole), and where a
    tlog is asked, the file there is the one written with it (its SHA-256 in ``dst``'s metadata; review61: a tlog
    another run had left there, of another rate or heading, was kept as "up to date")."""
    import pyarrow.parquet as pq

    try:
        meta = pq.read_schema(dst).metadata or {}
    except (OSError, ValueError):
        return False
    if meta.get(b"estimate_key") != key.encode():
        return False
    if tlog_dst is None:
        return True
    from ..model.runtime import file_sha256

    try:
        return meta.get(b"tlog_sha256") == file_sha256(tlog_dst).encode()
    except OSError:
        return False


def _estimate_one(model, fusion, opts: _Options, src, dst, tlog_dst) -> tuple[list[str], list[str], int]:
    """One record estimated and written (atomically) → (stdout lines, stderr lines, 1 if it failed)."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    from ..errors import NoImuData, TepinnError
    from ..ingest import load_record
    from ..ingest.sniff import sniff
    from ..log_clock import log_clock_s
    from ..csv_table import write_csv
    from ..model.estimate import REPORTED_STEPS, estimate_record
    from ..quat import quat_zero_yaw
    from ..record import EST_Q_COLS, atomic_write, no_imu_reason
    from .paths import output_format

    out, err = [], []
    key = _output_key(opts, src, tlog=tlog_dst is not None)
    if opts.resume and _up_to_date(dst, key, tlog_dst):
        if not opts.quiet:
            out.append(f"{src} -> {dst}: up to date (the same source, model and settings), skipped (--resume)")
        return out, err, 0
    try:
        rec = load_record(src)
        if not opts.quiet and sniff(src) != "parquet":
            err.append(f"tepinn-flight estimate: note: {src}: a log, ingested on the fly (`tepinn-flight ingest` "
                       "keeps the record)")  # fmt: skip
        if not rec.meta.get("estimation_ok", True):
            rate = rec.meta.get("imu_rate_hz")
            err.append(f"tepinn-flight estimate: warning: {src}: IMU "
                       f"{'rate unknown' if rate is None else f'at {rate:.1f} Hz'} is too slow for windowed "
                       "estimation (estimation_ok is false); estimating anyway with VQF alone where the filter takes it "
                       "below 20 Hz (the network's gates stay shut: min_network_rate_hz), expect a poor attitude")  # fmt: skip
        why = no_imu_reason(rec)
        if why:
            raise NoImuData(f"{why}: nothing to estimate")
        holes = int(np.sum(~(np.all(np.isfinite(rec.gyr_rad_s), 1) & np.all(np.isfinite(rec.acc_m_s2), 1))))
        if holes:
            err.append(f"tepinn-flight estimate: note: {src}: {holes} non-finite IMU sample(s) bridged with "
                       "the previous sample")  # fmt: skip
        with np.errstate(invalid="ignore"):
            df = estimate_record(model, rec, fusion)
        if opts.yaw_zero:  # roll and pitch kept, the heading 0 (the paper's 6-D output)
            q = df[EST_Q_COLS].to_numpy()
            ok = np.all(np.isfinite(q), 1)
            q[ok] = quat_zero_yaw(q[ok])
            df[EST_Q_COLS] = q
        t_log = log_clock_s(df["t_s"].to_numpy(), rec.meta)
        if t_log is not None:  # the log's own clock beside t_s: the estimate laid over the log in the user's viewer
            df.insert(1, "t_log_s", t_log)
    except TepinnError as exc:
        err.append(f"tepinn-flight estimate: error: {exc if exc.path else f'{src}: {exc}'}")
        return out, err, 1
    table = pa.Table.from_pandas(df, preserve_index=False)
    # what the record's own calibration, GNSS velocity and rests gave, and where the network's gates acted
    found = {k: df.attrs[k] for k in REPORTED_STEPS if df.attrs.get(k)}
    table = table.replace_schema_metadata({b"source_record": str(src.name).encode(), b"model": str(opts.model_name).encode(),
                                           b"estimate_key": key.encode(), b"conventions": _conventions_json().encode(),
                                           **{k.encode(): v.encode() for k, v in found.items()}})  # fmt: skip
    tlog_out = []
    if tlog_dst is not None:  # first: a source log that is not this record's is an input error, and leaves no output
        try:
            tlog_out, e = _write_tlog(opts, src, rec, df, tlog_dst)
            err += e
        except TepinnError as exc:
            err.append(f"tepinn-flight estimate: error: {src}: {exc}")
            return out, err, 1
        from ..model.runtime import file_sha256

        meta = dict(table.schema.metadata)
        meta[b"tlog_sha256"] = file_sha256(tlog_dst).encode()  # which tlog this estimate wrote (--resume checks it)
        table = table.replace_schema_metadata(meta)
    if output_format(dst, "estimate", csv=True) == "csv":  # the columns alone (the notes are printed below)
        atomic_write(dst, lambda tmp: write_csv(table, tmp))
    else:
        atomic_write(dst, lambda tmp: pq.write_table(table, tmp))
    if not opts.quiet:
        ok = df["q_est_w"].notna().mean()
        out.append(f"{src} -> {dst}: {len(df)} rows, {100 * ok:.1f}% estimated" + "".join(f"; {v}" for v in found.values()))
    return out + tlog_out, err, 0


def _conventions_json() -> str:
    """The estimate's frames, units and columns, for its Parquet metadata (a CSV carries none: `estimate --help` says
    them)."""
    import json

    from ..conventions import describe

    d = describe()
    d["columns"] = {"t_s": "s from the record's first sample", "t_log_s": "s on the log's own clock",
                    "q_est_w..z": "attitude body -> earth", "sigma_rad": "1-sigma tilt uncertainty per horizontal axis, rad",
                    "gyr_bias_est_*_rad_s": "gyro bias, body frame, rad/s"}  # fmt: skip
    return json.dumps(d)


_WORKER = {}  # in a worker process: the runner and settings its initializer loaded


def _init_worker(main_pid, ckpt_path, runtime, fusion) -> None:
    import os

    from ..model import beside
    from ..model.runtime import load_runner
    from ..worker_processes import worker_init

    worker_init(main_pid)  # Ctrl-C and SIGTERM are the main process's; gone with it, even after a kill -9
    os.environ[beside.ENV] = "0"  # the workers keep the cores busy: no helper process per record beside them

    _WORKER["model"] = load_runner(ckpt_path, runtime, 1)[0]
    _WORKER["fusion"] = fusion


def _worker_one(job):
    opts, src, dst, tlog_dst = job
    return _estimate_one(_WORKER["model"], _WORKER["fusion"], opts, src, dst, tlog_dst)


def _in_workers(jobs, opts, ckpt_path, runtime, fusion, workers):
    """The records' results in order, estimated by ``workers`` processes (``forkserver`` where there is one). Ctrl-C
    or SIGTERM (``main`` turns it into a KeyboardInterrupt) terminates them at once: outputs are written atomically,
    so those finished stay and ``--resume`` goes on from there."""
    import multiprocessing
    import os

    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
    from ..worker_processes import quiet_tracker_after_kill, signals_held, start_forkserver, stop_pool

    quiet_tracker_after_kill()

    pool = None
    stopping = True
    try:
        with signals_held():  # (a signal while the pool starts: raised once it has, and it is stopped)
            start_forkserver(ctx)
            pool = ctx.Pool(workers, initializer=_init_worker, initargs=(os.getpid(), ckpt_path, runtime, fusion))
        yield from pool.imap(_worker_one, [(opts, *job) for job in jobs])
        pool.close()
        stopping = False
    finally:  # terminated on the way out of an exception (Ctrl-C, SIGTERM), joined either way, out of a second one's reach
        stop_pool(pool, stopping)


def _tlog_paths(args, paths, from_folder: bool = False) -> list:
    """``--tlog``: one file for one record (not from a folder), else a folder of RECORD.tlog (checked before any
    work)."""
    from pathlib import Path

    from ..errors import ConfigError
    from ..estimate_tlog import parse_messages
    from .paths import check_suffix, output_paths

    if args.tlog is None:
        if args.source_log:
            raise ConfigError("--source-log goes with --tlog")
        return []
    if args.source_log and len(paths) > 1:
        raise ConfigError("--source-log names the source of one record; give one record")
    if args.source_log and not Path(args.source_log).is_file():
        raise ConfigError(f"--source-log {args.source_log}: no such file")
    if args.source_log and paths and _source_kind(paths[0]) not in ("tlog", None):  # (before any work, not after it)
        raise ConfigError(f"--source-log: {paths[0]} was not ingested from a tlog ({_source_kind(paths[0])}); a tlog "
                          "with the estimates is made from the tlog the record came from")  # fmt: skip
    try:
        parse_messages(args.tlog_messages)
    except ValueError as exc:
        raise ConfigError(f"--tlog-messages: {exc}") from None
    if not 0 <= args.tlog_rate < float("inf"):
        raise ConfigError("--tlog-rate must be >= 0 and finite (0: every sample)")
    into_folder = from_folder or Path(args.tlog).is_dir() or args.tlog.endswith(("/", "\\"))
    tlogs = [p.with_suffix(".tlog") if into_folder else p for p in output_paths(paths, args.tlog, from_folder)]
    for t in tlogs:
        check_suffix("--tlog", t, ("", ".tlog"), "a MAVLink telemetry log")
    return tlogs


def _source_kind(path) -> str | None:
    """What a record or log came from: a log's own format, a record's ``source_kind`` (None: not told)."""
    from ..errors import TepinnError
    from ..ingest.sniff import sniff
    from ..record import parquet_meta

    try:
        fmt = sniff(path)
    except TepinnError:
        return None  # (whoever reads it says what is wrong)
    if fmt != "parquet":
        return fmt
    kind = (parquet_meta(path) or {}).get("source_kind")
    return None if kind is None else str(kind)


def _write_tlog(opts, src, rec, df, dst) -> tuple[list[str], list[str]]:
    """The estimate's tlog → (stdout lines, stderr lines)."""
    from pathlib import Path

    from ..errors import ConfigError
    from ..estimate_tlog import parse_messages, write_estimate_tlog
    from ..record import file_key

    out, err = [], []
    source = Path(opts.source_log) if opts.source_log else None
    if source is None and rec.meta.get("source_kind") == "tlog":
        cand = Path(src).parent / str(rec.meta.get("source_file", ""))
        if cand.suffix.lower() == ".tlog" and cand.is_file():
            source = cand
        else:
            err.append(f"tepinn-flight estimate: warning: {src}: source tlog {cand.name} not found next to the "
                       "record (pass --source-log); the tlog gets the record's IMU and reference instead")  # fmt: skip
    if source is not None and file_key(source) == file_key(dst):  # (one found next to the record: checked here)
        raise ConfigError(f"--tlog {dst} is the source tlog {source}: writing it would replace it; name another output")
    counts = write_estimate_tlog(dst, rec, df, source=source, messages=parse_messages(opts.tlog_messages),
                                 rate_hz=opts.tlog_rate)  # fmt: skip
    if not opts.quiet:
        what = ", ".join(f"{n} {k}" for k, n in sorted(counts.items()))
        out.append(f"{src} -> {dst}: {source.name if source else 'record IMU + reference'} + component 191: {what}")
    return out, err
