"""``tepinn-flight evaluate RECORDS... -o DIR [--model CKPT ...] [--noise-sweep]`` (``--report DIR`` is an alias of ``-o``)."""

from __future__ import annotations

import sys

from .argtypes import add_runtime, busy_stride
from .helptext import add_examples
from .paths import add_recursive

HELP = "compare TE-PINN with baseline filters and published peers on flight records; write a report"
DESCRIPTION = (
    "Run every estimator (TE-PINN from a checkpoint, the complementary filter, Madgwick, a "
    "bias-estimating EKF, and VQF / offline VQF / RIANN / Fusion) on the same records "
    "with the same scoring mask and warm-up, and write report.md with tables and PNG figures plus "
    "metrics.json, and report.html, the same results to zoom into in a browser. RECORDS are flight records (.parquet) or logs (ingested on the fly); a folder "
    "stands for the records in it."
)


def add_arguments(p) -> None:
    add_examples(p,
                 'tepinn-flight evaluate records/ -o report/       # report/report.md, report/report.html',
                 'tepinn-flight evaluate flight.tlog 00000042.BIN -o report/ --with-mag',
                 'tepinn-flight evaluate sims/ -o report/ --noise-sweep')
    p.add_argument("records", nargs="+", metavar="RECORD", help="flight records, logs, or folders of them")
    out = p.add_mutually_exclusive_group(required=True)  # (both: refused, not the last one taken)
    out.add_argument("-o", "--output", dest="output", metavar="DIR",
                     help="output folder for report.md, report.html, figures, metrics.json")
    out.add_argument("--report", dest="output", metavar="DIR", help="the same as -o")
    p.add_argument("--model", action="append", default=[], metavar="CKPT",
                   help="TE-PINN checkpoint or .onnx export (repeatable); default: the shipped model (and the shipped LSTM) if there is one")
    add_runtime(p)
    p.add_argument("--no-model", action="store_true", help="evaluate the baselines only")
    p.add_argument("--noise-sweep", action="store_true",
                   help="also re-run on the simulated records with added gyro/acc white noise at several levels")
    p.add_argument("--noise-levels", default="0,1,2,4,8", metavar="L,L,...",
                   help="noise-sweep levels, multiples of the base σ (gyro 0.01 rad/s, acc 0.2 m/s² per sample; default 0,1,2,4,8)")
    p.add_argument("--warmup-s", type=float, default=5.0, metavar="S",
                   help="seconds skipped at the start of every segment, for every estimator (default 5)")
    p.add_argument("--busy-stride", type=busy_stride, default=0, metavar="N",
                   help="add each TE-PINN model once more, running every N-th window where the network stays busy "
                        "(estimate --busy-stride N: the speed knob), to see what it costs on these records")
    p.add_argument("--no-smooth", action="store_true",
                   help="add TE-PINN without the offline tilt smoothing (estimate --no-smooth; the record's GNSS aid and "
                        "gyro/accelerometer self-calibrations still apply) beside the model as it ships")
    p.add_argument("--live", action="store_true",
                   help="add TE-PINN as the bridge runs it live (6-D): every sample pushed through the live estimator, so no "
                        "step that reads the whole record applies (smoothing, GNSS aid, gyro self-calibration) and the "
                        "accelerometer's scale is read from the first quiet seconds on, as the bridge reads it")
    p.add_argument("--smooth", action="store_true",
                   help="add TE-PINN with the offline tilt smoothing beside a model that does not smooth (a checkpoint "
                        "written before session 25)")
    p.add_argument("--with-mag", action="store_true", help="add 9-D variants (magnetometer) of TE-PINN, the filters and the peers: scored without the heading alignment")
    p.add_argument("--no-peers", action="store_true", help="skip the published peers (VQF, RIANN, Fusion)")
    p.add_argument("--config", metavar="TOML", help="filter parameters: [madgwick], [complementary], [ekf] tables, peers = [...]")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config value, e.g. ekf.acc_noise_m_s2=2")
    p.add_argument("--align-reference", action="store_true",
                   help="where a record's reference is refused for being off the IMU's time (> 0.1 s) or frame (> 20°), "
                        "score against it moved by the lag and turned by the rotation its check measures (motion capture "
                        "on another clock or body frame); a note says what was done to which record")
    p.add_argument("--tune-ekf-on", nargs="+", default=[], metavar="RECORD",
                   help="tune the EKF's noise parameters on these TRAINING records first (must not overlap the evaluated ones)")
    add_recursive(p)
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no progress bar and no notes on the estimates (report.md keeps them); inputs left out are still said")


def run(args) -> int:
    from .notes import run_noting_compiles

    return run_noting_compiles("evaluate", args, _run)  # the first run after installing compiles the loops: say so, once


def _run(args) -> int:
    import dataclasses
    from pathlib import Path

    from ..errors import ConfigError, TepinnError
    from ..evaluation.estimators import learned_estimators
    from ..evaluation.harness import HarnessConfig, evaluate, noise_sweep, record_name
    from ..evaluation.names import display_name
    from ..evaluation.report import write_report
    from ..evaluation.suite import baseline_estimators, load_suite_config, peer_estimators
    from ..ingest import load_record
    from ..record import check_output
    from ..evaluation.left_out import kept_out
    from ..evaluation.report import report_files
    from .argtypes import check_runtime
    from .paths import check_folder_name, collect_records, read_records, refuse_overwriting_inputs

    check_folder_name(args.output, "evaluate writes a report folder (report.md, report.html, metrics.json, figures)")
    check_output(args.output, folder=True)  # before the (long) evaluation
    cfg = load_suite_config(args.config, args.set)
    if not args.no_model:
        check_runtime(args.model, args.runtime)  # (--runtime torch without torch, a torch run of an .onnx: one line now)
    try:
        levels = tuple(float(v) for v in args.noise_levels.split(",") if v.strip())
    except ValueError:
        raise ConfigError(f"--noise-levels must be comma-separated numbers, got {args.noise_levels!r}") from None
    if not levels or any(not (lv >= 0) for lv in levels):
        raise ConfigError(f"--noise-levels must be numbers >= 0, got {args.noise_levels!r}")
    hcfg = HarnessConfig(warmup_s=args.warmup_s, noise_levels=levels)
    notes: list[str] = []
    paths = collect_records(args.records, args.recursive, notes)  # (a file named as a log that is none: a note)
    # the report's files replace those of an earlier report in -o: never one of the records read
    refuse_overwriting_inputs([("-o", Path(args.output) / n) for n in report_files()], paths)
    if args.tune_ekf_on:
        from ..evaluation.filters.ekf import tune

        train = collect_records(args.tune_ekf_on)
        overlap = {p.resolve() for p in train} & {p.resolve() for p in paths}
        overlap |= {a.resolve() for a in train for b in paths if _same_content(a, b)}  # a copy under another name too
        if overlap:
            raise ConfigError(f"--tune-ekf-on overlaps the evaluated records ({', '.join(sorted(map(str, overlap)))}): "
                              "never tune on test data")  # fmt: skip
        best, _ = tune([load_record(p) for p in train], base=cfg.ekf, warmup_s=args.warmup_s, progress=not args.quiet)
        cfg = dataclasses.replace(cfg, ekf=best)
        notes.append(f"EKF tuned on {len(train)} training record(s): " + ", ".join(
            f"{k}={getattr(best, k):g}" for k in ("gyro_noise_rad_s_sqrt_hz", "acc_noise_m_s2", "bias_walk_rad_s_sqrt_s")))
    records = read_records(args.records, paths, notes)
    if args.align_reference:
        from ..model.reference_trust import aligned_if_refused

        for i, rec in enumerate(records):
            records[i], what = aligned_if_refused(rec)
            if what:
                notes.append(f"{rec.meta.get('name')}: {what}")
    if len({record_name(r) for r in records}) < len(records):
        notes.append("some records share a name; they are numbered #2, #3, ... in the tables")
    estimators = []
    if not args.no_model:
        base = learned_estimators(args.model, notes, args.runtime)  # each variant below is made from these
        estimators += base
        if args.with_mag:  # TE-PINN 9-D beside VQF 9-D (anchored checkpoints)
            estimators += [e9 for e in base if hasattr(e, "nine_d") and (e9 := e.nine_d()) is not None]
        if args.busy_stride:  # the speed knob beside the model as it ships (6-D)
            strided = [es for e in base if hasattr(e, "strided") and not e.uses_mag
                       and (es := e.strided(args.busy_stride)) is not None]  # fmt: skip
            if not strided:
                notes.append(f"--busy-stride {args.busy_stride}: no model here runs the anchored estimator; nothing added")
            estimators += strided
        if args.smooth:  # the offline smoothing beside a model that does not smooth (6-D)
            smooth = [es for e in base if hasattr(e, "smoothed") and not e.uses_mag and not getattr(e.fusion, "smoother", True)
                      and (es := e.smoothed()) is not None]  # fmt: skip
            if not smooth:
                notes.append("--smooth: no model here runs the anchored estimator without the smoothing; nothing added")
            estimators += smooth
        if args.no_smooth:  # the unsmoothed tilt beside the model as it ships (6-D)
            plain = [es for e in base if hasattr(e, "unsmoothed") and not e.uses_mag and (es := e.unsmoothed()) is not None]
            if not plain:
                notes.append("--no-smooth: no model here smooths offline; nothing added")
            estimators += plain
        if args.live:  # the bridge's causal estimate beside the model as it ships (6-D)
            for e in base:
                es = e.live() if hasattr(e, "live") else None
                if es is not None:
                    estimators.append(es)
                elif hasattr(getattr(e, "fusion", None), "smoother"):  # (an older fusion, the LSTM's: offline is live)
                    why = ("it is 9-D; the live column is 6-D" if e.uses_mag else
                           "it has no offline step: its own column is already the bridge's")  # fmt: skip
                    notes.append(f"--live: nothing added for {display_name(e.name)}: {why}")
    else:
        notes.append("TE-PINN not evaluated (--no-model)")
    estimators += baseline_estimators(cfg, with_mag=args.with_mag)
    if not args.no_peers:
        estimators += peer_estimators(cfg, with_mag=args.with_mag, notes=notes)
    names = {e.name for e in estimators}
    if len(names) < len(estimators):
        raise TepinnError("two estimators share a name; give the checkpoints different file names")
    from ..jit_warmup import warm_up

    warm_up(filters=True)  # a cold numba cache: the estimators' loops compiled in two processes at once
    import warnings

    read_notes = list(notes)  # what reading the inputs and choosing the estimators said (files left out...)
    with warnings.catch_warnings():  # (numpy's "All-NaN" where nothing is scored: said below in one line)
        warnings.simplefilter("ignore", RuntimeWarning)
        result = evaluate(records, estimators, hcfg, progress=not args.quiet, notes=notes)
    if not any(r.get("n_scored_common", 0) for r in result.records):
        raise TepinnError(f"no sample left to score: the {len(records)} record(s) are shorter than the warm-up "
                          f"(--warmup-s {args.warmup_s:g}) or have no reference after it")  # fmt: skip
    if args.noise_sweep:
        result.noise_sweep = noise_sweep(records, estimators, hcfg, progress=not args.quiet, notes=result.notes)
    files = write_report(result, args.output)
    from ..evaluation.harness import ALL_LEFT_OUT_NOTE

    said = result.notes if not args.quiet else [*read_notes, *(n for n in result.notes if n == ALL_LEFT_OUT_NOTE)]
    for n in said:  # (-q: a file left out is still said, and a summary over records that all fail the checks)
        sys.stderr.write(f"note: {n}\n")
    best = sorted((d["inclination_rmse_deg"], k) for k, d in result.dataset.items() if d["inclination_rmse_deg"] is not None)
    why = [w for r in result.records if (w := kept_out(r))]
    if ALL_LEFT_OUT_NOTE in result.notes:  # (every record failed the rate or reference check: averaged all the same)
        over = "records, every one failing the rate or reference check: no meaningful comparison"
    else:
        over = ("records" if not why else f"the {len(records) - len(why)} records in the summary; {len(why)} listed "
                "apart: " + ", ".join(f"{w} ({why.count(w)})" for w in dict.fromkeys(why)))
    figures = (", ".join(f"{display_name(k)} {v:.2f}°" for v, k in best) if best else
               "none: no record in the summary (each record's figures are in the report)")  # (review60: the line ended at ':')
    print(f"{len(records)} record(s), {len(estimators)} estimator(s); inclination RMSE (mean over {over}): {figures}")
    print(f"report: {files[-1]} (interactive: {files[-1].with_name('report.html')})")
    return 0



def _same_content(a, b) -> bool:
    """Whether two files hold the same bytes (their sizes first, then their hashes)."""
    import os

    from ..model.runtime import file_sha256

    try:
        return os.path.getsize(a) == os.path.getsize(b) and file_sha256(a) == file_sha256(b)
    except OSError:
        return False
