"""TE-PINN vs VQF vs the LSTM vs our EKF on real files by kind and on held-out simulations, in one run.

Real files: the shared real drone logs that `ingest` can estimate (reference: the autopilot's own
estimate), by vehicle and IMU rate, and the shared BROAD trials (optical truth) by motion class.
The split is `train/splits/real.toml`: which files are held out (never trained, selected or
calibrated on) and which the shipped network saw — the table says which is which. Simulated: the
held-out campaign `flight_sims/campaigns/heldout.toml` (seed 77; every `--sim-every`-th flight), or
another campaign (`--campaign`), or the same flights with another seed (`--campaign-seed`, as an independent check
would fly them: the README's seeds 2026 and 5252; `--no-real` leaves the real files out).

Inclination RMSE per file (5 s warm-up, the same samples for every estimator), the files where
TE-PINN's gyro self-calibration applied (with what it read), the mean per kind,
ratios to VQF side by side, the per-file check of the issue (TE-PINN ≤ max(1.5× VQF, VQF + 0.5°)),
and TE-PINN's σ calibration by kind (mean NEES, share within 3σ, Spearman's rank correlation of σ with the
error — does σ rise where the error does —, each per file averaged; the NEES and 3σ target is
set for the real files — the simulated line shows σ in sustained manoeuvres).
TE-PINN is the model as it ships: offline, its tilt smoothed where no gate acts (session 25), and where a record has
a GNSS receiver (the simulations' records, some drone logs) the motion acceleration it measures taken out of the
accelerometer, which no peer is given. So two more columns (session 45): offline VQF (`vqf.offlineVQF`, the acausal
peer the smoothing should be judged against) and TE-PINN on the IMU alone ("TP IMU only": `--no-gnss-aid`, as the
peers run), with their ratios in the summary lines.
`--no-smooth` adds it without the smoothing (`estimate --no-smooth`, the live bridge's tilt) as its own
column; `--smooth` adds the smoothing to a `--model` written before session 25 (which does not smooth).

Your own files (session 46): name logs, BROAD trials, records or folders of them and they are scored instead of the
shared split (no simulations unless `--sim-every` asks for them). A file the split names keeps its label; any other is
"given": the shipped model never trained on a file of that name. Files that cannot be scored fairly are listed apart
with the reason, as `evaluate` does: an IMU below 20 Hz, no reference attitude, a reference that fails the trust check
(`model/reference_trust.py`), or a file `ingest` cannot read. Without files, the shared files the split names in neither
list are named at the end (not scored: some decided design choices, others cannot be estimated).

    python benchmarks/real_vs_peers.py [--shared ../shared] [--sim-every 4] [--model CKPT] [--lstm CKPT] [--no-smooth] [--smooth]
    python benchmarks/real_vs_peers.py --campaign-seed 2026 --sim runs/seed2026 --sim-every 1 --no-real
    python benchmarks/real_vs_peers.py my_logs/ other_broad/*.hdf5
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("files", nargs="*", help="logs, BROAD trials, records or folders of them, scored instead of the shared split")
    ap.add_argument("--shared", default=str(REPO.parent / "shared"))
    ap.add_argument("--sim", default=str(REPO / "runs/heldout"), help="folder of the held-out campaign")
    ap.add_argument("--campaign", default=str(REPO / "flight_sims/campaigns/heldout.toml"),
                    help="the campaign flown into --sim (default: the held-out one, seed 77)")
    ap.add_argument("--campaign-seed", type=int, default=None, metavar="N",
                    help="fly --campaign with N as its seed (`simulate --campaign --seed`: the same flights drawn anew)")
    ap.add_argument("--no-real", action="store_true", help="simulated flights only (none of the shared real files; files named are scored)")
    ap.add_argument("--sim-every", type=int, default=None,
                    help="every N-th held-out flight (0: none; default 4, or 0 where files are named)")
    ap.add_argument("--model", default=None, help="TE-PINN checkpoint (default: shipped)")
    ap.add_argument("--lstm", default=None, help="LSTM baseline checkpoint (default: shipped)")
    ap.add_argument("--smooth", action="store_true",
                    help="add TE-PINN with the offline tilt smoothing, for a --model that does not smooth (written before session 25)")
    ap.add_argument("--no-smooth", action="store_true",
                    help="add TE-PINN without the offline tilt smoothing (estimate --no-smooth: the live bridge's tilt)")
    args = ap.parse_args()
    from tepinn_flight.errors import TepinnError

    try:
        return run(args)
    except TepinnError as exc:  # a campaign or a folder that does not fit: one line
        print(f"real_vs_peers.py: error: {exc}", file=sys.stderr)
        return 2


def run(args) -> int:
    import torch

    from tepinn_flight.evaluation.estimators import FilterEstimator, TepinnEstimator
    from tepinn_flight.evaluation.filters import Ekf
    from tepinn_flight.evaluation.names import display_name
    from tepinn_flight.evaluation.peers import VqfEstimator
    from tepinn_flight.model.checkpoint import default_lstm_path, default_model_path
    from tepinn_flight.record import read_record
    from tepinn_flight.sim.campaign import run_campaign

    torch.set_num_threads(1)
    split = tomllib.loads((REPO / "train/splits/real.toml").read_text())
    shared = Path(args.shared)
    held_names = set(split["heldout"]["real_logs"]) | set(split["heldout"].get("broad", []))
    seen_names = set(split["seen"].get("real_logs", [])) | set(split["seen"]["broad"])
    files = []  # (kind, group, name, record, split label: "held-out", "seen" or "given")
    apart = []  # (name, why it is not scored)
    sim_every = (0 if args.files else 4) if args.sim_every is None else args.sim_every
    if args.files:
        named = [(p, "held-out" if p.name in held_names else "seen" if p.name in seen_names else "given")
                 for p in expand_files(args.files)]  # fmt: skip
    elif args.no_real:
        named = []
    else:  # the shared split: held-out first, then seen; drone logs, then BROAD trials
        named = [(shared / sub / n, label) for sub, key in (("real-logs", "real_logs"), ("broad", "broad"))
                 for label, part in (("held-out", "heldout"), ("seen", "seen")) for n in split[part].get(key, [])
                 if (shared / sub / n).exists()]  # fmt: skip
    for p, label in named:  # each by the rules evaluate's summary keeps records by
        item, why = load_scorable(p, label)
        if item is None:
            apart.append((p.name, why))
        else:
            files.append(item)
    if sim_every:
        run_campaign(Path(args.campaign), Path(args.sim), progress=True, seed=args.campaign_seed)
        for p in sorted(Path(args.sim).glob("*.parquet"))[::sim_every]:
            grp = p.stem.split("-")[1]
            files.append(("simulated", grp, p.stem, read_record(p), "held-out"))
    if not files:
        print(f"no files found (shared folder {shared}, simulations {args.sim})"
              + "".join(f"\n  not scored: {n}: {why}" for n, why in apart))
        return 2

    ests = [TepinnEstimator.from_checkpoint(args.model or default_model_path(), "tepinn"), VqfEstimator(),
            TepinnEstimator.from_checkpoint(args.lstm or default_lstm_path(), "lstm"), FilterEstimator(Ekf(), name="ekf"),
            VqfEstimator(offline=True)]  # fmt: skip
    if hasattr(ests[0].fusion, "gnss_aid"):  # TE-PINN on the IMU alone, as its peers run (session 45: the disclosure)
        import dataclasses

        ests.append(TepinnEstimator(ests[0].model, dataclasses.replace(ests[0].fusion, gnss_aid=False), "tepinn-imu",
                                    ests[0].checkpoint))  # fmt: skip
    if args.smooth and not getattr(ests[0].fusion, "smoother", True):
        ests.insert(1, ests[0].smoothed())
    if args.no_smooth and ests[0].unsmoothed() is not None:
        ests.insert(1, ests[0].unsmoothed())
    names = [e.name for e in ests]
    rows = []
    t0 = time.perf_counter()
    for kind, grp, name, rec, label in files:
        rows.append({"kind": kind, "group": grp, "name": name, "split": label, **score_file(ests, rec)})
    print(f"\n{len(files)} files, {time.perf_counter() - t0:.0f} s; inclination RMSE (deg), 5 s warm-up\n")
    label = {n: {"tepinn-nosmooth": "TP no-smooth", "tepinn-smooth": "TP smoothed", "tepinn-imu": "TP IMU only",
                 "offline-vqf": "offl. VQF"}.get(n, display_name(n)) for n in names}  # fmt: skip
    width = {n: max(9, len(label[n]) + 1) for n in names}
    head = f"{'kind':<10} {'group':<26} {'file':<44} {'split':<9}" + "".join(f"{label[n]:>{width[n]}}" for n in names)
    print(head + f"{'TP/VQF':>8}  per-file check")
    for r in rows:
        ok = r["tepinn"] <= max(1.5 * r["vqf"], r["vqf"] + 0.5)
        print(f"{r['kind']:<10} {r['group'][:26]:<26} {r['name'][:44]:<44} {r['split']:<9}"
              + "".join(f"{r[n]:>{width[n]}.2f}" for n in names) + f"{r['tepinn'] / r['vqf']:>8.2f}  {'ok' if ok else 'FAIL'}")
    applied = [r for r in rows if "selfcal" in r]
    print(f"\nTE-PINN's gyro self-calibration applied on {len(applied)} of {len(rows)} files"
          + "".join(f"\n  {r['name'][:44]}: {r['selfcal']}" for r in applied))
    aided = [r for r in rows if "gnss" in r]
    print(f"TE-PINN's GNSS-aided tilt applied on {len(aided)} of {len(rows)} files"
          + "".join(f"\n  {r['name'][:44]}: {r['gnss']}" for r in aided))
    sm = [r for r in rows if "smooth" in r]
    print(f"TE-PINN's offline tilt smoothing applied on {len(sm)} of {len(rows)} files")
    print()
    for kind in ("drone log", "BROAD", "simulated"):
        for label in ("held-out", "seen", "given"):
            sel = [r for r in rows if r["kind"] == kind and r["split"] == label]
            if not sel:
                continue
            means = {n: float(np.nanmean([r[n] for r in sel])) for n in names}
            fails = sum(r["tepinn"] > max(1.5 * r["vqf"], r["vqf"] + 0.5) for r in sel)
            line = f"{kind:<10} {SPLIT_LABELS[label]:<20} n={len(sel):<3}" + "".join(
                f" {display_name(n)} {means[n]:.2f}" for n in names)
            print(line + f" | TE-PINN/VQF {means['tepinn'] / means['vqf']:.3f}, /LSTM {means['tepinn'] / means['lstm']:.3f}"
                         f", /EKF {means['tepinn'] / means['ekf']:.3f}, /offline VQF {means['tepinn'] / means['offline-vqf']:.3f}"
                         + (f"; on the IMU alone (no GNSS aid, as every peer) /VQF {means['tepinn-imu'] / means['vqf']:.3f}, "
                            f"/LSTM {means['tepinn-imu'] / means['lstm']:.3f}, /offline VQF "
                            f"{means['tepinn-imu'] / means['offline-vqf']:.3f}" if "tepinn-imu" in means else "")
                         + f"; files failing the per-file check: {fails}")  # fmt: skip
            for other in (n for n in names if n in ("tepinn-smooth", "tepinn-nosmooth")):
                print(f"{'':<10} {display_name(other)}/VQF {means[other] / means['vqf']:.3f}, /LSTM "
                      f"{means[other] / means['lstm']:.3f}; files failing the per-file check: "
                      f"{sum(r[other] > max(1.5 * r['vqf'], r['vqf'] + 0.5) for r in sel)}")
            for n in [n for n in names if n.startswith("tepinn")]:
                nees = [r[f"nees:{n}"] for r in sel if np.isfinite(r.get(f"nees:{n}", np.nan))]
                if nees:
                    print(f"{'':<10} σ of {display_name(n)}: mean NEES {np.mean(nees):.2f} (target 1.5–2.5), within 3σ "
                          f"{100 * np.mean([r[f'in3:{n}'] for r in sel if f'in3:{n}' in r]):.1f} % (target ≥ 97 %), "
                          f"Spearman(σ, |e|) {np.nanmean([r.get(f'rho:{n}', np.nan) for r in sel]):.2f}, per file averaged")
    if not args.files and not args.no_real:
        apart += [(n, "named in neither list of train/splits/real.toml (a design log, or no usable IMU or reference: "
                      "name it as an argument to see which)") for n in unlisted_shared(shared, held_names | seen_names)]
    if apart:
        print(f"\nnot scored ({len(apart)}):" + "".join(f"\n  {n}: {why}" for n, why in apart))
    return 0


#: the warm-up left out of every score (as `evaluate`'s default)
WARMUP_S = 5.0
#: what each split label means in the summary lines
SPLIT_LABELS = {"held-out": "held-out", "seen": "seen in training", "given": "given (not in split)"}
#: what a folder named on the command line is searched for (not recursive)
SCORABLE_SUFFIXES = (".bin", ".log", ".tlog", ".ulg", ".hdf5", ".h5", ".parquet")


def expand_files(args: list[str]) -> list[Path]:
    """The files named, each folder replaced by its files with a log, trial or record suffix (sorted)."""
    out = []
    for a in args:
        p = Path(a)
        if p.is_dir():
            out += sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() in SCORABLE_SUFFIXES)
        else:
            out.append(p)
    return list({p.resolve(): p for p in out}.values())  # a file named twice (or as a folder's) once


def file_group(rec, name: str) -> str:
    """The summary's group of a real record: a BROAD trial's motion class, else autopilot, vehicle and IMU rate."""
    if rec.meta.get("source_kind") == "broad":
        return motion_class(str(rec.meta.get("broad_trial") or Path(name).stem))
    rate = float(rec.meta.get("imu_rate_hz") or 0)
    return f"{rec.meta.get('autopilot', '?')} {rec.meta.get('vehicle_type', '?')} {rate:.0f} Hz"


def motion_class(trial: str) -> str:
    """A BROAD trial's motion class from its name: '01_undisturbed_slow_rotation_with_breaks_B' -> 'slow rotation with
    breaks', '32_disturbed_attached_magnet_1cm' -> 'attached magnet' (number, (un)disturbed and variant left out)."""
    parts = [x for x in trial.split("_") if x]
    if parts and parts[0].lower() == "broad":
        parts = parts[1:]
    if parts and parts[0].isdigit():
        parts = parts[1:]
    if parts and parts[0].lower() in ("undisturbed", "disturbed"):
        parts = parts[1:]
    if len(parts) > 1 and (len(parts[-1]) == 1 or parts[-1].lower().endswith("cm")):
        parts = parts[:-1]
    return " ".join(parts) or trial


def load_scorable(path: Path, label: str):
    """``((kind, group, name, record, label), "")`` for a file that can be scored fairly, else ``(None, why)``: a file
    ``ingest`` cannot read, an IMU below 20 Hz, no reference attitude, or a reference that fails the trust check
    (the rules ``evaluate`` keeps such records out of its summary by)."""
    from tepinn_flight.errors import TepinnError
    from tepinn_flight.ingest import load_record
    from tepinn_flight.model.reference_trust import check_reference
    from tepinn_flight.record import SIMULATED_KINDS, estimation_ok

    try:
        rec = load_record(path)
    except (TepinnError, OSError) as exc:
        return None, f"not read: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
    if not estimation_ok(rec.meta):
        return None, f"IMU too slow for windowed estimation ({float(rec.meta.get('imu_rate_hz') or 0):.1f} Hz, under 20 Hz)"
    if not np.any(np.all(np.isfinite(rec.q_ref_wxyz), axis=1)):
        return None, "no reference attitude"
    from tepinn_flight.evaluation.harness import scoring_mask

    if not np.any(scoring_mask(rec, WARMUP_S) & np.all(np.isfinite(rec.q_ref_wxyz), axis=1)):
        return None, f"nothing to score after the {WARMUP_S:g}-s warm-up ({len(rec)} samples)"
    chk = check_reference(rec)
    if not chk.trusted:
        return None, f"reference not trusted: {chk.describe()}"
    kind = rec.meta.get("source_kind")
    if kind in SIMULATED_KINDS:
        return ("simulated", str(rec.meta.get("aircraft", "?")), path.name, rec, label), ""
    return ("BROAD" if kind == "broad" else "drone log", file_group(rec, path.name), path.name, rec, label), ""


def unlisted_shared(shared: Path, listed: set[str]) -> list[str]:
    """The files of the shared real logs and BROAD folders that the split names in neither list."""
    out = []
    for sub in ("real-logs", "broad"):
        folder = shared / sub
        if folder.is_dir():
            out += [q.name for q in sorted(folder.iterdir())
                    if q.is_file() and q.suffix.lower() in SCORABLE_SUFFIXES and q.name not in listed]
    return out


def score_file(ests, rec) -> dict:
    """Each estimator of ``ests`` on ``rec`` → {name: inclination RMSE (deg), 5 s warm-up, the same samples
    for all}, and for TE-PINN estimators ``nees:NAME`` / ``in3:NAME`` (σ of the 2-D tilt error: mean NEES,
    share within 3σ; ``rho:NAME``: Spearman's rank correlation of σ with |e|, NaN where σ is constant) and what
    its whole-record steps did (``selfcal``, ``gnss``, ``smooth``). Short logging dropouts are bridged for every
    estimator, as ``evaluate`` does."""
    from tepinn_flight.evaluation.harness import scoring_mask
    from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad, tilt_error_vector_rad, uncertainty_metrics
    from tepinn_flight.record_gaps import bridge_gaps

    r = {}
    br = bridge_gaps(rec)
    dfs = {e.name: br.original(e.estimate(br.record)) for e in ests}
    quats = {k: df[["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy() for k, df in dfs.items()}
    # the same samples for every estimator: where each has an estimate (review61: each had been scored on its own)
    mm = scoring_mask(rec, WARMUP_S) & np.logical_and.reduce([np.all(np.isfinite(q), 1) for q in quats.values()])
    for e in ests:
        df, q = dfs[e.name], quats[e.name]
        qe = error_quat_earth(q[mm], rec.q_ref_wxyz[mm])
        r[e.name] = float(np.degrees(np.sqrt(np.mean(inclination_error_rad(qe) ** 2)))) if mm.any() else np.nan
        if e.name == "tepinn" and str(df.attrs.get("gyro_selfcal", "")).endswith("; applied"):
            r["selfcal"] = df.attrs["gyro_selfcal"]
        if e.name == "tepinn" and str(df.attrs.get("gnss_aid", "")).endswith("; applied"):
            r["gnss"] = df.attrs["gnss_aid"]
        if e.name.startswith("tepinn") and "sigma_rad" in df:  # σ on every kind (the issue's target: real)
            u = uncertainty_metrics(tilt_error_vector_rad(qe), df["sigma_rad"].to_numpy()[mm])
            r[f"nees:{e.name}"], r[f"in3:{e.name}"], r[f"rho:{e.name}"] = u["nees"], u["coverage_3sigma"], u["spearman"]
        if e.name in ("tepinn", "tepinn-smooth") and str(df.attrs.get("smoother", "")).endswith("; applied"):
            r["smooth"] = df.attrs["smoother"]
    return r


if __name__ == "__main__":
    sys.exit(main())
