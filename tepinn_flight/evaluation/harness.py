"""Run every estimator on the same records with the same scoring mask, then score them.

Protocol (``estimators-and-metrics.md`` §9):

- **Scoring mask** (identical for all estimators): the record's ``valid`` column (BROAD's movement
  mask; all True elsewhere) ∧ finite reference ∧ not in the first ``warmup_s`` seconds of any
  segment (filters restart per segment) ∧ every *covering* estimator has a finite estimate. An
  estimator that leaves more than ``1 − min_coverage`` of the base mask empty is scored on its own
  finite samples instead and flagged (``coverage`` in the results), so one broken estimator cannot
  shrink everyone's mask.
- **Gaps**: short logging dropouts (≤ ``record_gaps.MAX_BRIDGED_GAP_S``) are bridged before any
  estimator runs (:func:`~tepinn_flight.record_gaps.bridge_gaps`), so every estimator propagates
  through the same filled samples (never scored: no reference there) instead of restarting.
- **Heading**: 6-D estimators (``uses_mag`` False) get ONE constant heading alignment per run
  (segment) before heading/total/yaw metrics and plots; 9-D estimators none.
- **Headline**: records whose IMU is too slow for windowed estimation (``ingest`` flags them "IMU
  rate too low for estimation", :func:`~tepinn_flight.record.estimation_ok`), and records whose reference
  attitude fails the trust check (:mod:`~tepinn_flight.model.reference_trust`: an autopilot estimator that
  diverged — every estimator's error there measures the reference's failure), are run and scored like
  the others but kept out of the dataset means and the paired comparison; the report lists them apart
  with the reason (:func:`.left_out.left_out`).
- **Aggregation**: per record, then per dataset = mean over the headline records of the per-record value (with
  median and 95th percentile of the per-record inclination RMSE); the dynamic error pools its
  per-bin sums over records; compute cost = total time / total samples.
- **Statistics**: paired Wilcoxon signed-rank test over records (per-record inclination RMSE) of
  each learned estimator (TE-PINN, LSTM) against the best non-learned one.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError, TepinnError
from ..log_clock import log_clock_s
from ..model.estimate import REPORTED_STEPS, gates_acted
from ..model.reference_trust import check_reference
from ..record import GYR_BIAS_COLS, SIMULATED_KINDS, FlightRecord, estimation_ok, segment_slices
from ..record_gaps import bridge_gaps, inner_steps, lost_steps
from . import metrics as M
from .estimators import EST_BIAS_COLS, EST_Q_COLS
from .left_out import left_out
from .names import display_name


@dataclass(frozen=True)
class HarnessConfig:
    warmup_s: float = 5.0  # skipped at the start of every segment, for every estimator
    min_coverage: float = 0.9  # share of the base mask an estimator must cover to join the common mask
    rate_bins_deg_s: tuple[float, ...] = M.RATE_BINS_DEG_S  # edges of the dynamic-error bins
    noise_levels: tuple[float, ...] = (0.0, 1.0, 2.0, 4.0, 8.0)  # multiples of the base noise (sweep)
    noise_gyr_rad_s: float = 0.01  # base white-noise σ added to the gyro per sample (sweep)
    noise_acc_m_s2: float = 0.2  # base white-noise σ added to the accelerometer per sample (sweep; ×8 ≈ multirotor vibration)
    noise_seed: int = 0

    def __post_init__(self):
        if not (self.warmup_s >= 0 and math.isfinite(self.warmup_s)):
            raise ConfigError(f"warmup_s must be a finite number >= 0, got {self.warmup_s!r}")
        if not (0 < self.min_coverage <= 1):
            raise ConfigError(f"min_coverage must be in (0, 1], got {self.min_coverage!r}")


#: the note where every record fails the checks that keep one out of the summary (said by `evaluate` even with -q)
ALL_LEFT_OUT_NOTE = ("every record has an IMU too slow for windowed estimation or a reference that fails the trust "
                     "check: the summary is over them all and is not a meaningful comparison")  # fmt: skip


def record_name(rec: FlightRecord, i: int = 0) -> str:
    from pathlib import Path

    m = rec.meta
    return str(m.get("broad_trial") or m.get("name") or Path(str(m.get("source_file", f"record{i}"))).stem or f"record{i}")


def scoring_mask(rec: FlightRecord, warmup_s: float) -> np.ndarray:
    """valid ∧ finite reference ∧ after the first ``warmup_s`` of every segment."""
    t = rec.t_s
    seg = rec.segment
    n = len(t)
    start = np.empty(n)
    for sl in segment_slices(seg):
        start[sl] = t[sl.start]
    return rec.valid & np.all(np.isfinite(rec.q_ref_wxyz), axis=1) & (t - start >= warmup_s)


def angular_rate(rec: FlightRecord) -> np.ndarray:
    """|ω| (rad/s) for the dynamic-error bins: the gyro minus the true bias where known."""
    gyr = rec.gyr_rad_s
    if all(c in rec.data for c in GYR_BIAS_COLS):
        gyr = gyr - rec.data[GYR_BIAS_COLS].to_numpy(np.float64)
    return np.linalg.norm(gyr, axis=1)


@dataclass
class EvalResult:
    """Everything the report needs; ``to_json()`` is the machine-readable part."""

    config: HarnessConfig
    estimators: list[dict]
    records: list[dict]
    dataset: dict
    comparisons: list[dict]
    notes: list[str]
    series: list[dict] = field(default_factory=list)  # per record: arrays for the figures
    noise_sweep: dict | None = None

    def to_json(self) -> dict:
        import dataclasses

        return _jsonable({
            "config": dataclasses.asdict(self.config),
            "estimators": self.estimators,
            "dataset": self.dataset,
            "records": self.records,
            "comparisons": self.comparisons,
            "noise_sweep": self.noise_sweep,
            "notes": self.notes,
            "units": "angles in degrees (keys ending _deg), drift in deg/min, bias in deg/s, cost in us/sample",
        })  # fmt: skip


def run_estimators(records, estimators, progress: bool = True, desc: str = "evaluate"):
    """Run every estimator on every record: list (per record) of {name: (DataFrame, seconds)}."""
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(records) * len(estimators), desc=desc, unit="run", file=sys.stderr, leave=False)
    out = []
    try:
        _warm(records[0] if records else None, estimators)
        for rec in records:
            runs = {}
            for est in estimators:
                if bar is not None:
                    bar.set_postfix_str(display_name(est.name), refresh=False)
                t0 = time.perf_counter()
                df = est.estimate(rec)
                el = time.perf_counter() - t0
                if len(df) != len(rec) or not all(c in df for c in EST_Q_COLS):
                    raise TepinnError(f"estimator {est.name} returned {len(df)} rows / columns {list(df.columns)}; "
                                      f"expected {len(rec)} rows with {EST_Q_COLS}")  # fmt: skip
                runs[est.name] = (df, el)
                if bar is not None:
                    bar.update(1)
            out.append(runs)
    finally:
        if bar is not None:
            bar.close()
    return out


#: rows of the first record each estimator runs on, untimed, before the timed runs
WARM_ROWS = 4000


def _warm(rec: FlightRecord | None, estimators) -> None:
    """Each estimator run once on the first ``WARM_ROWS`` rows of ``rec``, untimed: its one-time start-up (a runtime's
    session, torch's first call, a lazily built filter) is not any record's cost (review59: the same network had read
    65.9 µs a sample as TE-PINN, its start-up on the first record, and 18.2 as TE-PINN 9-D)."""
    if rec is None or not len(rec):
        return
    head = FlightRecord(rec.data.iloc[:WARM_ROWS].reset_index(drop=True), dict(rec.meta))
    for est in estimators:
        try:
            est.estimate(head)
        except Exception:  # noqa: BLE001 - a warm-up only: what fails here fails in the timed run, and is said there
            pass


def evaluate(records: list[FlightRecord], estimators: list, config: HarnessConfig | None = None,
             progress: bool = True, keep_series: bool = True, notes: list[str] | None = None,
             names: list[str] | None = None) -> EvalResult:  # fmt: skip
    config = config or HarnessConfig()
    notes = list(notes or [])
    if not records:
        raise TepinnError("no records to evaluate")
    if not estimators:
        raise TepinnError("no estimators to evaluate")
    seen = set()
    for e in estimators:
        if e.name in seen:
            raise TepinnError(f"two estimators are named {e.name!r}")
        seen.add(e.name)
    names = names or _unique_names(records)
    from .estimators import record_mag

    if any(e.uses_mag for e in estimators):
        nomag = [names[i] for i, r in enumerate(records) if record_mag(r) is None]
        if nomag:  # (their heading is left out of the 9-D estimators' summary: aggregate)
            notes.append(f"{len(nomag)} record(s) have no magnetometer ({', '.join(nomag[:5])}{', ...' if len(nomag) > 5 else ''}); "
                         "the 9-D estimators ran without one there and their heading is not meaningful (left out of "
                         "their summary heading)")  # fmt: skip
    bridged = [bridge_gaps(r) for r in records]
    runs = run_estimators([b.record for b in bridged], estimators, progress)
    rec_results, series = [], []
    for i, (br, rr) in enumerate(zip(bridged, runs)):
        res, ser = score_record(br.record, rr, estimators, config, names[i])
        res["n_samples"] = len(records[i])
        res["has_mag"] = record_mag(records[i]) is not None
        res["bridged_gaps"], res["bridged_samples"] = br.gaps, br.filled
        res["lost_samples"] = lost = lost_steps(inner_steps(br.record))
        if lost:  # what sets the estimators apart there (session 29)
            notes.append(f"{names[i]}: {lost} sample(s) lost one at a time (steps of about two periods): the anchored "
                         "TE-PINN integrates the gyro over each step's time, VQF and the other peers over one period")  # fmt: skip
        m = records[i].meta
        res["estimation_ok"] = estimation_ok(m)
        res["imu_rate_hz"] = m.get("imu_rate_hz")
        res["reference_source"] = m.get("reference_source", "none")
        chk = check_reference(records[i])  # a reference that is not the IMU's attitude scores its own failure
        res["reference_check"] = chk.describe()
        res["reference_trusted"] = bool(chk.trusted)
        if not chk.trusted:
            notes.append(f"{names[i]}: {chk.describe()} — every estimator's error there measures the reference's failure")
        for step in REPORTED_STEPS:  # each anchored TE-PINN's REPORTED_STEPS lines
            found = {name: df.attrs[step] for name, (df, _) in rr.items() if df.attrs.get(step)}
            if found:
                res[step] = found
                if step != "network_gates":  # one line per record would crowd the notes: summed up below
                    notes.extend(f"{names[i]}: {display_name(name)}: {line}" for name, line in found.items()
                                 if line.endswith("; applied"))  # fmt: skip
        rec_results.append(res)
        if keep_series:
            series.append(ser)
    for name in dict.fromkeys(n for r in rec_results for n in r.get("network_gates", {})):  # each anchored TE-PINN
        lines = {r["name"]: r.get("network_gates", {}).get(name, "") for r in rec_results}
        if any(v.endswith("; applied") for v in lines.values()):
            notes.append(f"{display_name(name)}: {gates_acted(lines)}")
    kept_out = {id(r): left_out(r) for r in rec_results}  # why each record is not in the summary ("": it is)
    headline = [r for r in rec_results if not left_out(r)]
    slow = [r["name"] for r in rec_results if not r["estimation_ok"]]
    untrusted = [r["name"] for r in rec_results if r["estimation_ok"] and not r["reference_trusted"]]
    if headline:
        for which, why in ((slow, "with an IMU too slow for windowed estimation"),
                           (untrusted, "whose reference attitude fails the trust check")):
            if which:
                notes.append(f"{len(which)} record(s) {why} ({', '.join(which[:5])}{', ...' if len(which) > 5 else ''}) "
                             "are scored but kept out of the summary means and the paired comparison (listed apart)")
    else:
        headline = rec_results
        kept_out = {}
        notes.append(ALL_LEFT_OUT_NOTE)
    # no estimator has a figure there: nothing is scored (not a missing estimate) — kept out even where no record of
    # the summary has a figure (review60: two such records had been the whole summary, a line of dashes)
    unscored = [r for r in headline if not any(_scored(r["results"][e.name]) for e in estimators)]
    if unscored:
        none = [r["name"] for r in unscored]
        notes.append(f"{len(none)} record(s) with no scored sample (shorter than the warm-up, or no reference after "
                     f"it) are kept out of the summary means: {', '.join(none[:5])}{', ...' if len(none) > 5 else ''}")  # fmt: skip
        kept_out |= {id(r): "no scored sample" for r in unscored}
        gone = {id(u) for u in unscored}
        headline = [r for r in headline if id(r) not in gone]
    common, missing = common_records(headline, estimators)
    if missing and common:  # the same records for every estimator's mean (as the same samples within a record)
        shown = "; ".join(f"{k} ({', '.join(display_name(n) for n in v)})" for k, v in list(missing.items())[:5])
        notes.append(f"{len(missing)} record(s) where not every estimator has an estimate are kept out of the summary "
                     f"means and the paired comparison, so that each mean is over the same records: {shown}"
                     f"{'; ...' if len(missing) > 5 else ''}")  # fmt: skip
        by_name = {r["name"]: r for r in headline}
        kept_out |= {id(by_name[k]): "not every estimator has an estimate" for k in missing}
        headline = common
    elif missing:
        notes.append("no record has an estimate of every estimator: each summary mean is over that estimator's own "
                     "records (n_records_scored), and they are not comparable")  # fmt: skip
    summary = {id(r) for r in headline}
    for r in rec_results:
        r["in_summary"] = id(r) in summary  # (the figures that pool samples take these records only)
        r["kept_out"] = "" if r["in_summary"] else kept_out.get(id(r), "")
    dataset = aggregate(headline, estimators, len(config.rate_bins_deg_s) - 1)
    comparisons = compare_learned(headline, estimators, dataset)
    info = [{"name": e.name, "kind": e.kind, "causal": bool(e.causal), "uses_mag": bool(e.uses_mag),
             "heading": ("none (not tracked)" if not getattr(e, "tracks_heading", True) else
                         "raw (9-D)" if e.uses_mag else "one constant offset per run (6-D)"),
             **({"model": e.checkpoint, "runtime": e.runtime} if getattr(e, "checkpoint", None) else {})}
            for e in estimators]  # fmt: skip
    return EvalResult(config, info, rec_results, dataset, comparisons, notes, series)


def _unique_names(records) -> list[str]:
    names, seen = [], {}
    for i, r in enumerate(records):
        n = record_name(r, i)
        if n in seen:
            seen[n] += 1
            n = f"{n}#{seen[n]}"
        else:
            seen[n] = 1
        names.append(n)
    return names


def score_record(rec: FlightRecord, runs: dict, estimators, config: HarnessConfig, name: str):
    base = scoring_mask(rec, config.warmup_s)
    finite = {k: np.all(np.isfinite(df[EST_Q_COLS].to_numpy()), axis=1) for k, (df, _) in runs.items()}
    coverage = {k: (float(np.mean(f[base])) if base.any() else float("nan")) for k, f in finite.items()}
    common = base.copy()
    for k, f in finite.items():
        if coverage[k] >= config.min_coverage:
            common &= f
    rate = angular_rate(rec)
    q_ref = rec.q_ref_wxyz
    has_bias = all(c in rec.data for c in GYR_BIAS_COLS)
    b_true = rec.data[GYR_BIAS_COLS].to_numpy(np.float64) if has_bias else None
    t_log = log_clock_s(rec.t_s[:1], rec.meta) if len(rec) else None  # the log's clock where the figures' t = 0
    out = {"name": name, "source_kind": rec.meta.get("source_kind"), "n_samples": len(rec),
           "log_clock_at_t0_s": float(t_log[0]) if t_log is not None else None,
           "duration_s": float(rec.t_s[-1] - rec.t_s[0]) if len(rec) > 1 else 0.0,
           "n_scored_common": int(common.sum()), "results": {}}  # fmt: skip
    ser = {"name": name, "t_s": rec.t_s, "q_ref": q_ref, "mask": common, "rate": rate, "est": {}}
    for est in estimators:
        df, el = runs[est.name]
        q = df[EST_Q_COLS].to_numpy(np.float64)
        own = coverage[est.name] < config.min_coverage
        mask = (base & finite[est.name]) if own else common
        sigma = df["sigma_rad"].to_numpy(np.float64) if "sigma_rad" in df else None
        b_est = df[EST_BIAS_COLS].to_numpy(np.float64) if all(c in df for c in EST_BIAS_COLS) else None
        s = M.score_run(rec.t_s, q, q_ref, mask, rate_rad_s=rate, sigma_rad=sigma, bias_est=b_est,
                        bias_true=b_true, runs=rec.segment, align=not est.uses_mag)  # fmt: skip
        q_al, incl = s.pop("_q_aligned"), s.pop("_inclination_rad")
        s["coverage"] = coverage[est.name]
        s["own_mask"] = own
        s["seconds"] = el
        s["us_per_sample"] = 1e6 * el / max(1, len(rec))
        out["results"][est.name] = _to_report_units(s)
        ser["est"][est.name] = {"q": q_al, "incl": incl, "sigma": sigma, "tracks_heading": getattr(est, "tracks_heading", True),
                                "tilt_err": M.tilt_error_vector_rad(M.error_quat_earth(q_al, q_ref)) if sigma is not None else None}  # fmt: skip
    return out, ser


def _to_report_units(s: dict) -> dict:
    """Radians → degrees for the report (keys renamed *_deg), bias rad/s → °/s."""
    out = {}
    for k, v in s.items():
        if k.endswith("_rad") and isinstance(v, float):
            out[k[:-4] + "_deg"] = math.degrees(v)
        elif k == "heading_offsets_rad":
            out["heading_offsets_deg"] = [math.degrees(x) for x in v]
        elif k == "gyr_bias":
            out["gyr_bias_rms_deg_s"] = math.degrees(v["total"])
            out["gyr_bias_rms_axes_deg_s"] = [math.degrees(x) for x in v["axes"]]
        else:
            out[k] = v
    return out


#: the summary's figures that need a tracked heading
_HEADING_KEYS = ("heading_rmse_deg", "total_rmse_deg", "yaw_rmse_deg", "mean_quat_distance", "mean_quat_angle_deg",
                 "heading_drift_deg_per_min", "heading_drift_abs_deg_per_min")


def _scored(result: dict) -> bool:
    """Whether one estimator's result on a record has an inclination figure."""
    v = result.get("inclination_rmse_deg")
    return v is not None and math.isfinite(v)


def common_records(rec_results: list[dict], estimators) -> tuple[list[dict], dict[str, list[str]]]:
    """(the records on which every estimator has an inclination figure, {record: the estimators without one} for
    the others). An estimator with a figure on no record at all does not count (it leaves every record out)."""
    have = {e.name: [_scored(r["results"][e.name]) for r in rec_results] for e in estimators}
    counted = [n for n, h in have.items() if any(h)]
    keep, missing = [], {}
    for i, r in enumerate(rec_results):
        miss = [n for n in counted if not have[n][i]]
        if miss:
            missing[r["name"]] = miss
        else:
            keep.append(r)
    return keep, missing


def aggregate(rec_results: list[dict], estimators, n_bins: int) -> dict:
    keys = ["inclination_rmse_deg", "roll_rmse_deg", "pitch_rmse_deg", "heading_rmse_deg", "total_rmse_deg",
            "yaw_rmse_deg", "inclination_mean_deg", "inclination_p95_deg", "mean_quat_distance",
            "mean_quat_angle_deg", "heading_drift_deg_per_min", "gyr_bias_rms_deg_s"]  # fmt: skip
    out = {}
    for est in estimators:
        rs = [r["results"][est.name] for r in rec_results]
        d = {"n_records": len(rs),
             "n_records_scored": sum(_scored(r) for r in rs)}
        for k in keys:
            vals = np.array([r.get(k, np.nan) for r in rs], np.float64)
            vals = vals[np.isfinite(vals)]
            d[k] = float(vals.mean()) if vals.size else None
        incl = np.array([r.get("inclination_rmse_deg", np.nan) for r in rs], np.float64)
        incl = incl[np.isfinite(incl)]
        d["inclination_rmse_median_deg"] = float(np.median(incl)) if incl.size else None
        d["inclination_rmse_p95_deg"] = float(np.percentile(incl, 95)) if incl.size else None
        d["heading_drift_abs_deg_per_min"] = _mean_finite([abs(r.get("heading_drift_deg_per_min", np.nan)) for r in rs])
        if not getattr(est, "tracks_heading", True):  # (RIANN: a heading it does not track is no figure to compare)
            for k in _HEADING_KEYS:
                d[k] = None
        elif getattr(est, "uses_mag", False) and not all(rr.get("has_mag", True) for rr in rec_results):
            # a 9-D heading where the record has no magnetometer measures nothing (the notes say so): its heading
            # figures are the means over the records with one
            with_mag = [r["results"][est.name] for r in rec_results if r.get("has_mag", True)]
            for k in _HEADING_KEYS:
                key = "heading_drift_deg_per_min" if k == "heading_drift_abs_deg_per_min" else k
                vals = np.array([np.nan if r.get(key) is None else r[key] for r in with_mag], np.float64)
                d[k] = _mean_finite(np.abs(vals) if k != key else vals)
            d["n_records_heading"] = len(with_mag)
        sq = np.zeros(n_bins)
        cnt = np.zeros(n_bins)
        for r in rs:
            if "rate_bins_sq" in r:
                sq += np.asarray(r["rate_bins_sq"])
                cnt += np.asarray(r["rate_bins_n"])
        d["dynamic_error_deg"] = [None if not np.isfinite(v) else math.degrees(v) for v in M.binned_rmse(sq, cnt)]
        d["dynamic_error_n"] = cnt.astype(int).tolist()
        unc = [r["uncertainty"] for r in rs if "uncertainty" in r and r["uncertainty"].get("n", 0) >= 2]
        if unc:
            w = np.array([u["n"] for u in unc], np.float64)
            d["uncertainty"] = {k: float(np.average([u[k] for u in unc], weights=w))
                                for k in ("coverage_1sigma", "coverage_2sigma", "coverage_3sigma", "nees")}  # fmt: skip
            d["uncertainty"]["spearman_mean"] = _mean_finite([u["spearman"] for u in unc])
            # (the figures above are pooled over samples; the and real_vs_peers.py's are per record averaged)
            d["uncertainty"]["nees_per_record_mean"] = _mean_finite([u["nees"] for u in unc])
            d["uncertainty"]["coverage_3sigma_per_record_mean"] = _mean_finite([u["coverage_3sigma"] for u in unc])
            d["uncertainty"]["expected"] = {f"coverage_{k}sigma": v for k, v in M.COVERAGE_EXPECTED_2D.items()} | {"nees": 2.0}
        tot_s = sum(r["seconds"] for r in rs)
        tot_n = sum(rr["n_samples"] for rr in rec_results)
        d["us_per_sample"] = 1e6 * tot_s / max(1, tot_n)
        d["coverage_min"] = float(np.nanmin([r["coverage"] for r in rs])) if rs else None
        out[est.name] = d
    return out


def _mean_finite(vals):
    a = np.asarray(vals, np.float64)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else None


#: a record counts for A in the paired comparison only where A's inclination RMSE is below B's by more than this
#: (the report's resolution): identical estimates differ by ~1e-12° and counted as wins before session 45
WIN_MARGIN_DEG = 0.005


def compare_learned(rec_results, estimators, dataset) -> list[dict]:
    """Paired Wilcoxon over records: each learned estimator vs the best non-learned one."""
    learned = [e.name for e in estimators if e.kind == "learned"]
    others = [e.name for e in estimators if e.kind != "learned" and dataset[e.name]["inclination_rmse_deg"] is not None]
    if not others:
        return []
    best = min(others, key=lambda k: dataset[k]["inclination_rmse_deg"])
    pairs = [(name, best) for name in learned]
    if not learned:
        ranked = sorted(others, key=lambda k: dataset[k]["inclination_rmse_deg"])
        pairs = [(ranked[1], ranked[0])] if len(ranked) > 1 else []
    out = []
    for a, b in pairs:
        xa = [r["results"][a].get("inclination_rmse_deg", np.nan) for r in rec_results]
        xb = [r["results"][b].get("inclination_rmse_deg", np.nan) for r in rec_results]
        two = M.wilcoxon_signed_rank(xa, xb)
        less = M.wilcoxon_signed_rank(xa, xb, alternative="less")
        ma, mb = dataset[a]["inclination_rmse_deg"], dataset[b]["inclination_rmse_deg"]
        out.append({
            "a": a, "b": b, "metric": "inclination_rmse_deg (per record)", "n": two["n"],
            "mean_a": ma, "mean_b": mb,
            "relative_change": (ma - mb) / mb if ma is not None and mb else None,
            "wins_a": int(np.sum(np.asarray(xa) < np.asarray(xb) - WIN_MARGIN_DEG)),
            "ties": int(np.sum(np.abs(np.asarray(xa) - np.asarray(xb)) <= WIN_MARGIN_DEG)), "n_records": len(rec_results),
            "pvalue_two_sided": two["pvalue"], "pvalue_a_less": less["pvalue"],
            "statistic_w_plus": two["statistic"], "method": two["method"],
        })  # fmt: skip
    return out


# ----------------------------------------------------------------------------- noise sweep


def add_noise(rec: FlightRecord, gyr_sigma: float, acc_sigma: float, seed: int) -> FlightRecord:
    """A copy of ``rec`` with white Gaussian noise added to the gyro (rad/s) and accelerometer (m/s²)."""
    from ..record import ACC_COLS, GYR_COLS

    rng = np.random.default_rng(seed)
    df = rec.data.copy()
    n = len(df)
    if gyr_sigma > 0:
        df[GYR_COLS] = df[GYR_COLS].to_numpy() + rng.normal(0.0, gyr_sigma, (n, 3))
    if acc_sigma > 0:
        df[ACC_COLS] = df[ACC_COLS].to_numpy() + rng.normal(0.0, acc_sigma, (n, 3))
    return FlightRecord(df, dict(rec.meta))


def noise_sweep(records, estimators, config: HarnessConfig | None = None, progress: bool = True,
                notes: list | None = None) -> dict | None:  # fmt: skip
    """Re-evaluate on simulated records with extra white sensor noise at ``config.noise_levels``
    multiples of (``noise_gyr_rad_s``, ``noise_acc_m_s2``). Real records are left out (their own
    noise is unknown); returns None with a note when there is no simulated record."""
    config = config or HarnessConfig()
    sims = [r for r in records if r.meta.get("source_kind") in SIMULATED_KINDS]
    if not sims:
        if notes is not None:
            notes.append("noise sweep skipped: no simulated (jsbsim/synthetic) record among the inputs")
        return None
    table = {e.name: [] for e in estimators}
    for li, level in enumerate(config.noise_levels):
        noisy = [add_noise(r, level * config.noise_gyr_rad_s, level * config.noise_acc_m_s2,
                           config.noise_seed + 1000 * li + i) for i, r in enumerate(sims)]  # fmt: skip
        res = evaluate(noisy, estimators, config, progress=progress, keep_series=False)
        for e in estimators:
            table[e.name].append(res.dataset[e.name]["inclination_rmse_deg"])
    return {
        "levels": list(config.noise_levels),
        "base_gyr_sigma_rad_s": config.noise_gyr_rad_s,
        "base_acc_sigma_m_s2": config.noise_acc_m_s2,
        "gyr_sigma_rad_s": [lv * config.noise_gyr_rad_s for lv in config.noise_levels],
        "acc_sigma_m_s2": [lv * config.noise_acc_m_s2 for lv in config.noise_levels],
        "n_records": len(sims),
        "inclination_rmse_deg": table,
    }


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    return x
