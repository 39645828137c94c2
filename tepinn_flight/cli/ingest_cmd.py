"""``tepinn-flight ingest LOG... [-o OUT] [--imu N] [--reference SOURCE]``."""

from __future__ import annotations

import sys
from pathlib import Path

from .helptext import add_examples
from .paths import add_recursive, output_format, output_paths, refuse_overwriting_inputs

HELP = "turn real logs (tlog, DataFlash .bin/.log, ULog, BROAD .hdf5) into flight records"
DESCRIPTION = (
    "Parse ArduPilot/PX4 logs (MAVLink .tlog, DataFlash binary or text, PX4 .ulg) and BROAD trials "
    "(.hdf5) into flight records (Parquet), with the autopilot's attitude (or optical/simulator "
    "truth) as the reference. The format is sniffed from the content, not the extension."
)


def add_arguments(p) -> None:
    add_examples(p,
                 'tepinn-flight ingest flight.tlog                # -> flight.parquet',
                 'tepinn-flight ingest logs/*.BIN -o records/',
                 'tepinn-flight ingest APM/LOGS/ -o records/      # a folder: every log in it (told by content)',
                 'tepinn-flight ingest -r log/ -o records/        # ... and in its subfolders (a PX4 SD card)',
                 'tepinn-flight ingest 00000042.BIN --imu 1 --reference XKQ')
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="log files; a folder stands for the logs in it, told by content (its subfolders with -r)")
    p.add_argument("-o", "--output", metavar="OUT",
                   help="output file (one log) or folder (several logs); default: LOG name + .parquet in the current folder")
    p.add_argument("--imu", type=int, default=None, metavar="N",
                   help="IMU instance to use (default: the first one with data)")
    p.add_argument("--reference", default=None, metavar="SOURCE",
                   help="reference attitude source, e.g. ATT, XKQ, NKQ1, ATTITUDE_QUATERNION, ATTITUDE, "
                        "vehicle_attitude, vehicle_attitude_groundtruth (default: the best available)")
    add_recursive(p)
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")


def run(args) -> int:
    from ..errors import TepinnError
    from ..ingest import ingest_log
    from ..record import check_output, write_record
    from .summary import record_summary_line

    from ..ingest.inputs import LOG_FORMATS, expand

    left_out: list[str] = []
    logs = expand(args.logs, LOG_FORMATS, recursive=args.recursive, notes=left_out)
    for line in left_out:
        sys.stderr.write(f"tepinn-flight ingest: note: {line}\n")
    outs = output_paths(logs, args.output, from_folder=len(args.logs) > 1 or any(Path(i).is_dir() for i in args.logs))
    for out in outs:  # before any work: a record is Parquet, whatever the name says
        output_format(out, "ingest")
    refuse_overwriting_inputs([("-o", o) for o in outs], logs)
    for out in {Path(o).parent: o for o in outs}.values():  # one per folder, before any work (review60: each log
        check_output(out)  # read, then refused once per log for a read-only -o)
    failures = 0
    progress = None
    if len(logs) > 1 and not args.quiet and sys.stderr.isatty():  # (no bar's redraws in a batch job's log)
        from tqdm import tqdm

        progress = tqdm(total=len(logs), unit="log", file=sys.stderr, leave=False)
    for log, out in zip(logs, outs):
        try:
            rec = ingest_log(log, imu=args.imu, reference=args.reference)
            write_record(rec, out)
        except TepinnError as exc:
            failures += 1
            msg = str(exc) if exc.path else f"{log}: {exc}"
            line = f"tepinn-flight ingest: error: {msg}"  # (on a line of its own, not after the bar's)
            (progress.write(line, file=sys.stderr) if progress else sys.stderr.write(line + "\n"))
        else:
            if not args.quiet:  # with what the reader dropped or chose, as `info` says it (review60: said by info only)
                line = "\n".join([f"{log} -> {out}: {record_summary_line(rec)}",
                                  *(f"  note: {n}" for n in rec.meta.get("notes") or [])])
                (progress.write(line) if progress else print(line))
        if progress:
            progress.update(1)
    if progress:
        progress.close()
    if failures and len(logs) > 1:  # the count at the end of a folder's run (review60: the errors had to be counted)
        sys.stderr.write(f"tepinn-flight ingest: {failures} of {len(logs)} log(s) failed (the lines above); "
                         f"{len(logs) - failures} written\n")  # fmt: skip
    return 2 if failures else 0
