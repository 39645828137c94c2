"""``tepinn-flight benchmark broad DIR``: the BROAD protocol with its published-Madgwick harness check."""

from __future__ import annotations

import sys

from .argtypes import add_runtime
from .helptext import add_examples

HELP = "run a published benchmark protocol (BROAD) after checking the harness against published numbers"
DESCRIPTION = (
    "broad DIR: ingest every BROAD trial (*.hdf5) in DIR, first recompute BROAD's published Madgwick "
    "errors (original C code, beta = 0.12, 9-D) on the same trials as a check of the harness, then "
    "score TE-PINN, the baseline filters and the installed peers with BROAD's total / heading / "
    "inclination RMSE over the movement samples (6-D: one constant heading offset per trial). "
    "Exit code 3 when the check fails (TE-PINN numbers are then marked UNTRUSTED)."
)


def add_arguments(p) -> None:
    sub = p.add_subparsers(dest="suite", metavar="SUITE", required=True)
    b = sub.add_parser("broad", help="BROAD (Laidig et al. 2021), trials as HDF5", description=DESCRIPTION)
    add_examples(b,
                 'tepinn-flight benchmark broad broad/ --json broad.json',
                 'tepinn-flight benchmark broad broad/ --check-only   # only the published-Madgwick reproduction')
    add_examples(p,
                 'tepinn-flight benchmark broad broad/ --json broad.json',
                 'tepinn-flight benchmark broad broad/ --check-only   # only the published-Madgwick reproduction')
    b.add_argument("folder", metavar="DIR", help="folder with BROAD trial files (and published_madgwick_average_rmse.json)")
    b.add_argument("--published", metavar="JSON", help="BROAD's results_madgwick_average_rmse.json (default: DIR/published_madgwick_average_rmse.json)")
    b.add_argument("--pattern", default="*.hdf5", metavar="GLOB", help="trial files to use (default *.hdf5)")
    b.add_argument("--model", action="append", default=[], metavar="CKPT", help="TE-PINN checkpoint or .onnx export (repeatable); default: the shipped model")
    add_runtime(b)
    b.add_argument("--no-model", action="store_true", help="baselines and peers only")
    b.add_argument("--no-peers", action="store_true", help="skip VQF, RIANN, Fusion")
    b.add_argument("--check-only", action="store_true", help="only the published-Madgwick reproduction")
    b.add_argument("--config", metavar="TOML", help="filter parameters ([madgwick], [complementary], [ekf], peers)")
    b.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config value")
    b.add_argument("--json", metavar="FILE", help="write all per-trial results as JSON (atomically)")
    b.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    import json
    from pathlib import Path

    from ..evaluation.broad_benchmark import format_broad, run_broad_benchmark
    from ..evaluation.estimators import learned_estimators
    from ..evaluation.harness import _jsonable
    from ..evaluation.suite import baseline_estimators, load_suite_config, peer_estimators
    from ..record import atomic_write, check_output

    if args.json:  # before the (long) run: the JSON is named as JSON, can be written and is none of the files it reads
        from .paths import check_suffix, refuse_overwriting_inputs

        check_suffix("--json", args.json, (".json",), "JSON")
        check_output(args.json)
        inputs = [p for p in Path(args.folder).glob("*") if p.is_file()] if Path(args.folder).is_dir() else []
        refuse_overwriting_inputs([("--json", args.json)], [*inputs, *([args.published] if args.published else [])])
    cfg = load_suite_config(args.config, args.set)
    if not args.check_only and not args.no_model:
        from .argtypes import check_runtime

        check_runtime(args.model, args.runtime)
    notes: list[str] = []
    estimators = []
    if not args.check_only:
        if not args.no_model:
            estimators += learned_estimators(args.model, notes, args.runtime)
        estimators += baseline_estimators(cfg, with_mag=True)
        if not args.no_peers:
            estimators += peer_estimators(cfg, with_mag=True, notes=notes)
    result = run_broad_benchmark(args.folder, estimators, args.published, args.pattern, progress=not args.quiet, notes=notes)
    print(format_broad(result))
    if args.json:
        js = json.dumps(_jsonable(result), indent=1, allow_nan=False)
        atomic_write(args.json, lambda tmp: Path(tmp).write_text(js, encoding="utf-8"))
    if not result["trusted"]:
        sys.stderr.write("tepinn-flight benchmark: harness check failed or impossible; numbers are not trusted\n")
        return 3
    return 0
