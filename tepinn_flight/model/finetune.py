"""Fine-tuning on a user's own logs: ``tepinn-flight train --init MODEL --data LOG_OR_DIR... -o RUN_DIR``.

The built-in recipe (:func:`finetune_config`) starts from the checkpoint's weights (``--init
default``: the shipped model) and trains on the user's logs — any format ``ingest`` reads, the
autopilot's own estimate as the label — for a few minutes on the CPU, validation held out by whole
file — only logs whose reference is the IMU's attitude (:mod:`.reference_trust`: it turns as the gyro
turns and agrees with the accelerometer's gravity where the vehicle is quiet; session 27). Then the
anchored estimator's VQF accelerometer time constant is chosen on the training files
(mean per-file inclination RMSE against the reference): the autopilot's estimator has its own
trade-off between gyro and accelerometer, and the one that fits the vehicle's logs is a property of
the vehicle (vibration, typical accelerations). So is its gyro's scale per axis, fitted next on the
same files and kept only where it gains 2 % (session 10: on the BROAD trials, one IMU, a z scale of
1.005 took VQF from 0.683° to 0.550°). Last, σ (``sigma_floor_deg`` σ₀, ``sigma_acc_gain`` c, and
whether the sampling term counts, ``sigma_sampling_gain`` g: 0 or 1) is fitted on the same files against their reference (:func:`fit_anchor_sigma`): how far the estimate
strays from the vehicle's own autopilot is the vehicle's too — the shipped σ was fitted on BROAD's
optical truth — kept only where it scores better than the starting model's σ on the validation files by σ's rule
(:func:`choose_sigma`, session 51: a σ fitted on calm logs fails the dynamic ones). Then whether the offline tilt smoothing (:mod:`.smoother`, on in the shipped model since
session 25: nearer a true attitude) stays on: only where it lowers the training files' mean RMSE against
their reference — an autopilot's own estimate is causal, and a vehicle fine-tuned to agree with its
autopilot usually agrees better without it (:func:`tune_smoothing`). ``RUN_DIR/model.pt`` then works with
``estimate --model``; ``RUN_DIR/finetune.json`` holds the before/after figures on the validation
files.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from ..errors import ConfigError, TepinnError
from ..record import EST_Q_COLS, FlightRecord, atomic_write, estimation_ok
from ..vehicle_class import FIXED_WING, MULTIROTOR, vehicle_class
from .losses import LossConfig
from .train_config import DataConfig, OptimConfig, TrainConfig

#: VQF accelerometer time constants (s) the fine-tuning chooses from
TAU_ACC_GRID_S = (1.0, 2.0, 3.0, 5.0, 8.0, 12.0)
#: the gyro's scale factors it tries on each body axis in turn (x, y, z; 1 kept where none is better)
GYRO_SCALE_GRID = (0.99, 0.995, 0.9975, 1.0025, 1.005, 1.01)
#: a gyro calibration is kept only where it lowers the training files' mean RMSE by this fraction
GYRO_SCALE_MIN_GAIN = 0.02
#: passes over the three axes (a second one undoes what the first axis took from the others' errors)
GYRO_SCALE_PASSES = 2
#: σ is fitted for mean NEES nearest 2 among the (σ₀, c) keeping at least this share of the samples
#: within 3σ, per file averaged (a margin over the 97 % that a calibrated σ should reach)
SIGMA_COVERAGE = 0.975


def finetune_config(model_config, records: list[str], minutes: float = 6.0, seed: int = 0) -> TrainConfig:
    """The built-in fine-tuning recipe: small learning rate, no rate or gyro-bias augmentation, no
    baseline loss, constant learning rate after the warm-up, a quarter of the files (at least one,
    when there are two or more) held out for validation."""
    return TrainConfig(
        seed=seed, init="", model=model_config, loss=LossConfig(base_cauchy_rad=0.0),
        data=DataConfig(records=tuple(records), val_fraction=0.25, rate_factors=(1,), max_val_windows=1024,
                        gyro_bias_aug_deg_s=0.0),
        optim=OptimConfig(batch_size=32, epochs=30, steps_per_epoch=40, lr=2e-4, lr_physics=5e-5,
                          early_stop_patience=4, max_minutes=minutes, warmup_steps=40, cosine_decay=False),
    )  # fmt: skip


#: the trained network's checkpoint while its filter's settings and σ are being tuned (then: model.pt)
UNTUNED_NAME = "model.untuned.pt"
#: files that make a folder a fine-tuning's or a training's run folder (its checkpoints, its moved references)
RUN_MARKERS = ("last.pt", "finetune.json", UNTUNED_NAME)


def collect_logs(items, exclude=None, notes: list[str] | None = None) -> list[Path]:
    """Files as given; folders: every file below them that is a record or a log ``ingest`` reads — but none inside
    ``exclude`` (this run's folder) or inside a run folder (:data:`RUN_MARKERS`: review59, a run's moved copies of
    the logs, ``RUN/aligned/``, were taken as more logs by the next run, each flight then trained on under one name and
    validated on under the other). ``notes`` gets a line for each folder so left out and each file named as a log that
    holds none."""
    from ..ingest.inputs import RECORD_OR_LOG_FORMATS, files_in

    skip = Path(exclude).resolve() if exclude is not None else None
    out: list[Path] = []
    runs: set[Path] = set()
    for it in items:
        p = Path(it)
        if p.is_dir():
            for f in files_in(p, RECORD_OR_LOG_FORMATS, recursive=True, notes=notes):
                run = _run_folder(f, p, skip)
                if run is None:
                    out.append(f)
                else:
                    runs.add(run)
        elif p.exists():
            out.append(p)
        else:
            raise ConfigError(f"no such log or folder: {it}")
    if notes is not None:
        notes += [f"{r}: a training's or fine-tuning's run folder (its checkpoints and moved logs): left out" for r in sorted(runs)]
    if not out:
        raise ConfigError("no logs found in --data")
    return sorted(set(out))


def _run_folder(f: Path, root: Path, skip: Path | None) -> Path | None:
    """The run folder ``f`` lies in below ``root`` (this run's ``skip``, or one holding :data:`RUN_MARKERS`), or None."""
    for d in f.parents:
        if skip is not None and d.resolve() == skip:
            return d
        if any((d / m).is_file() for m in RUN_MARKERS):
            return d
        if d == root or len(d.parts) <= len(root.parts):
            return None
    return None


def flight_fingerprint(rec: FlightRecord) -> str:
    """A digest of a record's IMU samples (times, gyro, accelerometer): the same flight read from two files — a log and
    the record ``ingest`` made of it beside it, a copy under another name, a run's moved copy — gives the same one."""
    import hashlib

    h = hashlib.sha256()
    for a in (rec.t_s, rec.gyr_rad_s, rec.acc_m_s2):
        h.update(np.ascontiguousarray(a, np.float64).tobytes())
    return h.hexdigest()


def training_order(paths: list[str], recs: list) -> tuple[list[str], list]:
    """(paths, records) in the training data's own order — :func:`.train_data.resolve_records`: the paths sorted, each
    once — so that the split by file the fine-tuning reports is the one the training made (session 53: a log named
    twice, or the order a link's target sorts in, had the network train on the file reported as validation)."""
    by_path: dict = {}
    for pth, r in zip(paths, recs):
        by_path.setdefault(Path(pth), r)
    order = sorted(by_path)
    return [str(k) for k in order], [by_path[k] for k in order]


#: vehicle classes (:mod:`..vehicle_class`: a DataFlash log says "copter", a tlog "quadrotor") → one name per kind;
#: other names as the log gives them, a DataFlash "sub" as a tlog's "submarine"
_KIND = {MULTIROTOR: "multirotor", FIXED_WING: "fixed wing"}
_OTHER_KIND = {"sub": "submarine"}


def _kind(vehicle_type) -> str:
    low = str(vehicle_type).lower()
    return _KIND.get(vehicle_class(vehicle_type), _OTHER_KIND.get(low, low))


def vehicle_of(rec: FlightRecord) -> str | None:
    """What the log says of the vehicle it came from — autopilot, kind of vehicle, flight-controller board where the
    log names one (ULog's ``ver_hw``) — or None where it says nothing. Logs of one vehicle give one answer."""
    m = rec.meta
    ap, kind, hw = m.get("autopilot"), m.get("vehicle_type"), m.get("hardware")
    if not ap and not kind:
        return None
    kind = _kind(kind) if kind else None
    return " ".join(str(x) for x in (ap, kind, hw) if x)


#: a log scored for less than this (s, after each segment's 5-s warm-up) is too short to tune or validate on: its
#: figures were NaN, and the settings then chosen by NaN comparisons (session 53)
MIN_SCORED_S = 10.0


def usable(rec: FlightRecord) -> bool:
    """A log the fine-tuning can learn from: fast enough IMU, a reference on most samples, and at least
    :data:`MIN_SCORED_S` of samples scored after the warm-up (:func:`unusable_reason` says which fails)."""
    return not unusable_reason(rec)


def unusable_reason(rec: FlightRecord) -> str:
    """Why the fine-tuning cannot learn from ``rec`` ("" where it can): the IMU's rate, the reference's share, the
    seconds scored (review59: one sentence naming all three had been every skipped log's note)."""
    if not estimation_ok(rec.meta):
        rate = rec.meta.get("imu_rate_hz")
        return f"IMU at {rate:.1f} Hz, below 20 Hz" if rate else "IMU below 20 Hz"
    share = float(np.mean(np.all(np.isfinite(rec.q_ref_wxyz), axis=1))) if len(rec) else 0.0
    if not share > 0.5:
        return f"a reference attitude on {100 * share:.0f} % of the samples (it needs most)"
    from ..evaluation.harness import scoring_mask

    rate = rec.meta.get("imu_rate_hz") or (1.0 / float(np.median(np.diff(rec.t_s))) if len(rec) > 1 else 0.0)
    scored = scoring_mask(rec, 5.0).sum() / rate if rate > 0 else 0.0
    if not scored >= MIN_SCORED_S:
        return f"{scored:.1f} s scored after the 5-s warm-up, under {MIN_SCORED_S:.0f} s"
    return ""


def record_windows(model, anchor, records: list[FlightRecord]) -> list:
    """The network's windows of each record as the estimator ``anchor`` makes them (the older fusion
    alongside as the pulls' target): what the tunings below hand every candidate — none of the settings
    they try (time constant, gyro scale, σ, smoothing) changes them."""
    from .estimate import anchored_windows
    from .fusion import FusionConfig

    fusion = anchor.fusion_config or FusionConfig()
    return [anchored_windows(model, r, fusion=fusion, anchor=anchor) for r in records]


def tune_anchor(model, anchor, records: list[FlightRecord], grid=TAU_ACC_GRID_S, warmup_s: float = 5.0,
                scale_grid=GYRO_SCALE_GRID, windows=None):
    """The VQF accelerometer time constant, then the gyro's scale on each body axis in turn, with the
    lowest mean per-file inclination RMSE on ``records``; the scales are kept only where together they
    gain ``GYRO_SCALE_MIN_GAIN``. ``windows``: :func:`record_windows`' result when at hand. Returns
    (anchor, {tau: mean RMSE °}, {"1,1,1.005": mean RMSE °, ...})."""
    from .estimate import estimate_anchored

    wins = windows if windows is not None else record_windows(model, anchor, records)

    def score(cand) -> float:
        return float(np.mean([inclination_rmse_deg(r, estimate_anchored(model, r, cand, windows=w), warmup_s)
                              for r, w in zip(records, wins)]))  # fmt: skip

    table = {tau: score(dataclasses.replace(anchor, tau_acc_s=tau)) for tau in grid}
    best = dataclasses.replace(anchor, tau_acc_s=min(table, key=table.get))
    base = cur_err = table[best.tau_acc_s]
    cur, scales = best, {}
    for _ in range(GYRO_SCALE_PASSES):  # a gyro's scale error is the vehicle's (its calibration): one axis at a time
        for axis in range(3):
            for f in (1.0, *scale_grid):
                gs = list(cur.gyro_scale)
                gs[axis] = f
                if tuple(gs) == cur.gyro_scale:
                    continue
                cand = dataclasses.replace(cur, gyro_scale=tuple(gs))
                scales[",".join(f"{v:g}" for v in gs)] = e = score(cand)
                if e < cur_err:
                    cur, cur_err = cand, e
    if cur_err > (1.0 - GYRO_SCALE_MIN_GAIN) * base:  # not a clear gain: no calibration
        cur = best
    return cur, table, scales


def tune_smoothing(model, anchor, records: list[FlightRecord], warmup_s: float = 5.0, windows=None):
    """``anchor`` with the offline smoothing on if that lowers the mean per-file inclination RMSE of
    ``records`` against their reference (ties: off, the estimate the live bridge gives), and
    {"on": mean RMSE °, "off": mean RMSE °}. ``windows``: :func:`record_windows`' result when at hand."""
    from .estimate import estimate_anchored

    table = {}
    wins = windows if windows is not None else record_windows(model, anchor, records)
    for key, on in (("on", True), ("off", False)):
        cand = dataclasses.replace(anchor, smoother=on)
        table[key] = float(np.mean([inclination_rmse_deg(r, estimate_anchored(model, r, cand, windows=w), warmup_s)
                                    for r, w in zip(records, wins)]))  # fmt: skip
    return dataclasses.replace(anchor, smoother=table["on"] < table["off"]), table


def sigma_samples(model, anchor, records: list[FlightRecord], warmup_s: float = 5.0):
    """Per file, what σ is fitted and scored on: the estimator ``anchor``'s own scored samples
    (:func:`~tepinn_flight.evaluation.sigma_calibration.estimator_error_samples`)."""
    from ..evaluation.sigma_calibration import estimator_error_samples

    return [estimator_error_samples(model, r, anchor, str(i), warmup_s) for i, r in enumerate(records)]


def fit_anchor_sigma(model, anchor, records: list[FlightRecord], warmup_s: float = 5.0, coverage: float = SIGMA_COVERAGE):
    """``anchor`` with σ₀, c and the sampling term's g (0 or 1) fitted on ``records`` against their
    reference (mean NEES nearest 2 at a 3σ-coverage floor:
    :func:`~tepinn_flight.evaluation.sigma_calibration.fit_sigma`), and the fit (σ₀, c, g, NEES and
    share within 3σ on those files). σ's aircraft terms (``sigma_aircraft_deg``, ``sigma_acc_gain_aircraft``) are
    then 0: σ₀ and c are the vehicle's own."""
    from ..evaluation.sigma_calibration import fit_sigma

    fit = fit_sigma(sigma_samples(model, anchor, records, warmup_s), coverage=coverage, sampling_gains=(0.0, 1.0))
    return dataclasses.replace(anchor, sigma_floor_deg=fit.sigma_floor_deg, sigma_acc_gain=fit.sigma_acc_gain,
                               sigma_sampling_gain=fit.sigma_sampling_gain, sigma_aircraft_deg=0.0,
                               sigma_acc_gain_aircraft=0.0), fit  # fmt: skip


#: σ's terms the fine-tuning either fits on the training files or keeps from the model it starts from
SIGMA_TERMS = ("sigma_floor_deg", "sigma_acc_gain", "sigma_sampling_gain", "sigma_aircraft_deg", "sigma_acc_gain_aircraft")


def choose_sigma(model, fitted, init, val: list[FlightRecord], warmup_s: float = 5.0, coverage: float = SIGMA_COVERAGE):
    """σ as fitted on the training files (``fitted``: :func:`fit_anchor_sigma`'s filter) or the starting model's σ terms
    (``init``'s :data:`SIGMA_TERMS`, on the same tuned filter), whichever σ's rule scores better on the validation files
    ``val`` (the fit where they tie): a σ fitted on a vehicle's calm logs can fail its dynamic ones (session 51) →
    (the filter, "fitted" or "init", each candidate's (NEES, share within 3σ) on ``val``)."""
    from ..evaluation.sigma_calibration import rule_key, score

    kept = dataclasses.replace(fitted, **{k: getattr(init, k) for k in SIGMA_TERMS})
    samples = sigma_samples(model, fitted, val, warmup_s)  # (σ is an output only: the same samples for both)
    scores = {name: score(samples, *(getattr(a, k) for k in SIGMA_TERMS)) for name, a in (("fitted", fitted), ("init", kept))}
    if rule_key(*scores["init"], coverage) < rule_key(*scores["fitted"], coverage):
        return kept, "init", scores
    return fitted, "fitted", scores


def sigma_scores(model, anchor, records: list[FlightRecord], warmup_s: float = 5.0) -> tuple[float, float]:
    """(mean NEES, share within 3σ), per file averaged, of ``anchor``'s σ on ``records``."""
    from ..evaluation.sigma_calibration import score

    return score(sigma_samples(model, anchor, records, warmup_s), *(getattr(anchor, k) for k in SIGMA_TERMS))


def inclination_rmse_deg(rec: FlightRecord, est, warmup_s: float = 5.0) -> float:
    """Inclination RMSE (°) of an estimate frame against the record's reference (the harness's mask)."""
    from ..evaluation.harness import scoring_mask
    from ..evaluation.metrics import error_quat_earth, inclination_error_rad

    q = est[EST_Q_COLS].to_numpy()
    m = scoring_mask(rec, warmup_s) & np.all(np.isfinite(q), axis=1)
    if not m.any():
        return float("nan")
    e = inclination_error_rad(error_quat_earth(q[m], rec.q_ref_wxyz[m]))
    return float(np.degrees(np.sqrt(np.mean(e**2))))


def finetune(init: str, items, out_dir, minutes: float = 6.0, progress: bool = True, seed: int = 0,
             align_reference: bool = False) -> dict:
    """Fine-tune ``init`` (a checkpoint path or "default") on the logs in ``items``; see module doc. With
    ``align_reference`` a log refused for its reference's timing or frame is learned from once moved onto the IMU's
    (:func:`.reference_trust.aligned_if_refused`), where it then passes: its moved copy is written to
    ``out_dir/aligned/`` and trained from."""
    from ..ingest import load_record
    from .checkpoint import default_model_path, fusion_config_from, load_model, save_checkpoint
    from .anchor import AnchorConfig
    from .train import train
    from .estimate import gates_acted
    from ..record import write_record
    from .reference_trust import aligned_if_refused, check_reference
    from .train_data import split_by_flight

    out = Path(out_dir)
    if (out / "last.pt").exists():  # (train() said "use --resume", which fine-tuning does not take; session 56)
        raise ConfigError(f"{out} already holds a run (last.pt): fine-tuning starts from the start each time (it has "
                          "no --resume); pick a new folder or remove that one")  # fmt: skip
    init_path = default_model_path() if init == "default" else Path(init)
    model0, est0, ck0 = load_model(init_path)
    if not isinstance(est0, AnchorConfig):
        raise ConfigError(f"--init {init}: fine-tuning starts from a model that runs the filter-anchored estimator (the "
                          "shipped one, 'default', or a fine-tuned RUN/model.pt); this checkpoint runs the older "
                          "network-centred fusion (a training run's best.pt or last.pt, or a recipe without an "
                          "anchor_config)")  # fmt: skip
    paths, recs, ref_checks, seen = [], [], {}, {}
    found_notes: list[str] = []
    found = collect_logs(items, exclude=out, notes=found_notes)
    for n in found_notes:
        print(f"note: {n}", file=sys.stderr)
    for p in found:
        try:
            r = load_record(p)
        except TepinnError as exc:
            print(f"note: {p}: skipped ({exc.reason})", file=sys.stderr)
            continue
        same = seen.setdefault(flight_fingerprint(r), p)
        if same != p:  # one flight under two names would be trained on under one and validated on under the other
            print(f"note: {p}: skipped (the same flight as {same}: the same IMU samples)", file=sys.stderr)
            continue
        why = unusable_reason(r)
        if why:
            print(f"note: {p}: skipped ({why}: nothing to learn from)", file=sys.stderr)
            continue
        src, as_logged = p, ""
        if align_reference:
            moved, what = aligned_if_refused(r)
            if what:
                print(f"note: {p}: {what}", file=sys.stderr)
            if moved is not r:  # learned from the moved copy (training reads its files by path)
                as_logged = f"as logged: {check_reference(r).describe()}; {what}; the moved copy: "
                stem, k = Path(p).stem, 1
                p = out / "aligned" / f"{stem}.parquet"
                while p.exists():  # (two logs of one name in different folders)
                    k += 1
                    p = out / "aligned" / f"{stem}-{k}.parquet"
                write_record(moved, p)
                r = moved
        chk = check_reference(r)  # a reference that is not the IMU's attitude would teach everything wrong
        ref_checks[str(Path(src).resolve())] = as_logged + chk.describe()  # (a moved one: what it was, what was done)
        if not chk.trusted:
            print(f"note: {src}: skipped ({chk.describe()})", file=sys.stderr)
            continue
        paths.append(str(Path(p).resolve()))
        recs.append(r)
    if not recs:
        raise ConfigError("none of the --data logs can be learned from (each needs an IMU of >= 20 Hz and a reference "
                          "attitude that turns as its gyro does, agrees with its accelerometer's gravity and is on the IMU's time "
                          "and in its frame: the notes above say what each lacks)")  # fmt: skip
    paths, recs = training_order(paths, recs)
    vehicles = sorted({v for v in map(vehicle_of, recs) if v})
    if len(vehicles) > 1:  # a vehicle's gyro scale, time constant and σ, fitted on several: right for none of them
        print(f"warning: the logs come from {len(vehicles)} different vehicles or boards ({'; '.join(vehicles)}): the "
              "fine-tuning fits one vehicle's gyro calibration, accelerometer time constant and σ — give it one "
              "vehicle's logs", file=sys.stderr)  # fmt: skip
    cfg = dataclasses.replace(finetune_config(model0.config, paths, minutes, seed), init=str(init_path))
    # the network before its filter's settings and σ are tuned: not RUN_DIR/model.pt until they are (a run stopped
    # while tuning had left an untuned model.pt that `estimate --model` took without a word; session 53)
    untuned = out / UNTUNED_NAME
    result = train(cfg, out, progress=progress, report_gates=False, model_name=UNTUNED_NAME)  # reported below
    tr, va = split_by_flight(len(recs), cfg.data.val_fraction, seed)
    say = _stage_notes(progress, len(tr), len(va))
    val = [recs[i] for i in va] or [recs[i] for i in tr]
    model1, _, ck = load_model(untuned)
    # the filter's settings and σ₀, c, g are tuned on the causal estimate (the live bridge's; the offline
    # smoothing scales σ by its own factor where it applies), as the shipped ones were
    causal0 = dataclasses.replace(est0, smoother=False)
    train_recs = [recs[i] for i in tr]
    say("the filter's accelerometer time constant and the gyro's scale, on the {train}")
    wins = record_windows(model1, causal0, train_recs)  # once: no setting tuned below changes them
    anchor, table, scales = tune_anchor(model1, causal0, train_recs, windows=wins)
    say("σ fitted on the {train}, scored against the starting model's on the {val}")
    fitted, sfit = fit_anchor_sigma(model1, anchor, train_recs)
    anchor, sigma_choice, sigma_val = choose_sigma(model1, fitted, est0, val)
    nees_causal = sigma_scores(model0, causal0, val), sigma_val[sigma_choice]
    say("the offline smoothing on or off, on the {train}")
    anchor, smooth_table = tune_smoothing(model1, anchor, train_recs, windows=wins)
    say("the starting model and the fine-tuned one on the {val}")
    before = [inclination_rmse_deg(r, _est(model0, est0, r)) for r in val]
    ests = [_est(model1, anchor, r) for r in val]
    after = [inclination_rmse_deg(r, e) for r, e in zip(val, ests)]
    # where the fine-tuned network's gates act on the validation files (a network out of its domain can open one)
    # keyed by the file's path (ArduPilot names every SD card's first log 00000001.BIN: a base name loses all but one)
    val_paths = [paths[i] for i in va] if va else [paths[i] for i in tr]
    gates = {val_paths[i]: e.attrs.get("network_gates", "") for i, e in enumerate(ests)}
    (nees0, in3_0), (nees1, in3_1) = nees_causal
    summary = {
        "init": str(init_path), "files": paths, "train_files": [paths[i] for i in tr], "val_files": [paths[i] for i in va],
        "tau_acc_grid_deg": {f"{k:g}": v for k, v in table.items()}, "tau_acc_s": anchor.tau_acc_s,
        "gyro_scale_grid_deg": scales, "gyro_scale": list(anchor.gyro_scale),
        "smoother_grid_deg": smooth_table, "smoother": anchor.smoother,
        "val_inclination_rmse_deg_before": float(np.mean(before)), "val_inclination_rmse_deg_after": float(np.mean(after)),
        "val_worse_than_init": bool(np.mean(after) > np.mean(before)), "reference_checks": ref_checks,
        "vehicles": vehicles,
        "sigma_floor_deg": anchor.sigma_floor_deg, "sigma_acc_gain": anchor.sigma_acc_gain,
        "sigma_sampling_gain": anchor.sigma_sampling_gain,
        "fitted_sigma_train_nees": sfit.nees, "fitted_sigma_train_within_3sigma": sfit.coverage_3sigma,
        "val_sigma_nees_before": nees0, "val_sigma_nees_after": nees1,
        "val_sigma_within_3sigma_before": in3_0, "val_sigma_within_3sigma_after": in3_1,
        "sigma_note": "sigma fitted and scored on the causal estimate (estimate --no-smooth); the fit or the starting "
                      "model's sigma kept by its score on the validation files, so their sigma figures are not blind",
        "sigma_kept": sigma_choice, "val_sigma_by_choice": {k: list(v) for k, v in sigma_val.items()},
        "fitted_sigma": {"sigma_floor_deg": fitted.sigma_floor_deg, "sigma_acc_gain": fitted.sigma_acc_gain,
                         "sigma_sampling_gain": fitted.sigma_sampling_gain},
        "val_network_gates": gates, "val_network_gates_summary": gates_acted(gates),
        "validation_note": "" if va else "one file only: the figures are on the file it was tuned on",
        **{k: v for k, v in result.items() if isinstance(v, (int, float, str))},
    }  # fmt: skip
    from ..evaluation.harness import _jsonable

    text = json.dumps(_jsonable(summary), indent=2, allow_nan=False)  # (NaN: null; JSON has none)
    atomic_write(out / "finetune.json", lambda tmp: Path(tmp).write_text(text))
    # the tuned model last, once its validation is written (review59: a stop while validating had left a model.pt
    # that no figure or warning had judged, and `estimate --model` took it)
    save_checkpoint(out / "model.pt", model1, fusion_config_from(ck.get("fusion_config")), anchor,
                    **{k: v for k, v in ck.items() if k not in ("format", "version", "model_config", "fusion_config",
                                                                 "anchor_config", "state_dict", "conventions")})  # fmt: skip
    untuned.unlink(missing_ok=True)  # model.pt is the tuned one now
    return summary


def _stage_notes(progress: bool, n_train: int, n_val: int):
    """The tuning's progress after the training's bar: one numbered line per stage with the time since the first
    (the stages take from seconds to minutes; session 60: they had shown nothing)."""
    t0, k = time.monotonic(), [0]
    files = {"train": f"{n_train} training file{'s' * (n_train != 1)}",
             "val": f"{n_val} validation file{'s' * (n_val != 1)}" if n_val else "file it was tuned on (none held out)"}

    def say(what: str) -> None:
        k[0] += 1
        if progress:
            print(f"tuning {k[0]}/4 (+{time.monotonic() - t0:.0f} s): {what.format(**files)}", file=sys.stderr, flush=True)

    return say


def _est(model, anchor, rec):
    from .estimate import estimate_anchored

    return estimate_anchored(model, rec, anchor)
