"""``tepinn-flight info FILE|DIR...``: what is in a raw log or a flight record (a folder: each record in it)."""

from __future__ import annotations

import json

from .helptext import add_examples
from .paths import add_recursive

HELP = ("describe raw logs or flight records, or every one in a folder (format, rates, reference, segments, clipping); "
        "or a model file (.pt checkpoint, .onnx export)")


def add_arguments(p) -> None:
    add_examples(p,
                 'tepinn-flight info 00000042.BIN',
                 'tepinn-flight info APM/LOGS/                    # every log or record in a folder',
                 'tepinn-flight info flight.parquet --json',
                 'tepinn-flight info runs/mine/model.pt           # a model: its network, estimator, training, export')
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="raw log or flight record (.parquet), or a model (.pt checkpoint, .onnx export); a folder stands for the logs "
                        "and records in it (told by content)")
    p.add_argument("--imu", type=int, default=None, metavar="N", help="IMU instance (raw logs)")
    p.add_argument("--reference", default=None, metavar="SOURCE", help="reference source (raw logs)")
    p.add_argument("--json", action="store_true", help="print machine-readable JSON")
    add_recursive(p)


def run(args) -> int:
    import sys
    from pathlib import Path

    from ..errors import TepinnError
    from ..ingest import load_record
    from ..ingest.inputs import RECORD_OR_LOG_FORMATS, files_in
    from ..ingest.sniff import sniff
    from ..record_stats import summarize
    from .summary import render_info, render_model_info

    failures = 0
    results = {}
    files = []
    for item in args.files:
        p = Path(item)
        if p.is_dir():
            left_out: list[str] = []
            found = files_in(p, RECORD_OR_LOG_FORMATS, recursive=args.recursive, notes=left_out)
            for line in left_out:
                sys.stderr.write(f"tepinn-flight info: note: {line}\n")
            if not found:
                failures += 1
                sys.stderr.write(f"tepinn-flight info: error: {TepinnError('folder holds no flight records or logs', p)}\n")
            files += [str(f) for f in found]
        else:
            files.append(item)
    for path in files:
        if _is_model_file(path):  # a checkpoint or an export: what model it is (session 61: "not a ULog, ...")
            try:
                from ..model.describe import describe_model

                d = describe_model(path)
            except TepinnError as exc:
                failures += 1
                named = exc.path or str(exc).startswith(f"{path}:")  # (review61: an export's error named it twice)
                sys.stderr.write(f"tepinn-flight info: error: {exc if named else f'{path}: {exc}'}\n")
                continue
            if args.json:
                results[str(path)] = d
            else:
                print(render_model_info(d))
            continue
        try:
            fmt = sniff(path)
            if fmt == "parquet" and (args.imu is not None or args.reference is not None):  # (a record is ingested)
                sys.stderr.write(f"tepinn-flight info: note: {path}: a flight record: --imu and --reference choose among "
                                 "a raw log's streams, not a record's; ignored\n")  # fmt: skip
            rec = load_record(path, imu=args.imu, reference=args.reference)
            s = summarize(rec)
            if fmt != "parquet":
                s["format"] = fmt
        except TepinnError as exc:
            failures += 1
            sys.stderr.write(f"tepinn-flight info: error: {exc if exc.path else f'{path}: {exc}'}\n")
            continue
        if args.json:
            results[str(path)] = s
        else:
            print(render_info(path, s))
    if args.json:
        from ..evaluation.harness import _jsonable

        print(json.dumps(_jsonable(results), indent=2, default=str, allow_nan=False))  # NaN: null (JSON has no NaN)
    return 2 if failures else 0


def _is_model_file(path) -> bool:
    """A model file named as one: an ``.onnx`` export or a ``.pt`` / ``.pth`` checkpoint (a folder's logs are told by
    content; a model is named by the user — one that is none is told so, not "not a ULog, ...": review61)."""
    from pathlib import Path

    from ..model.runtime import is_onnx_path

    p = Path(path)
    return p.is_file() and (is_onnx_path(p) or p.suffix.lower() in (".pt", ".pth"))
