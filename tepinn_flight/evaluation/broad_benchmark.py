"""The BROAD benchmark protocol (Laidig et al., Data 6(7):72, 2021) and its harness check.

Errors exactly as BROAD's ``example_code/broad_utils.py``: per trial, the RMSE over the ``movement``
samples (our records' ``valid`` column) of the total / heading / inclination error of
``q_e = q_est ⊗ q_ref⁻¹``, NaN reference samples skipped (``nanmean``); aggregate = mean over
trials. No warm-up is removed (BROAD's protocol): estimators start at sample 0.

Frames. Our records hold body FRD → NED (``q_NB = q_NE ⊗ q_ES ⊗ q_SB``, fixed rotations stored in
the record's metadata). The error split is the same in both frames: q_SB cancels in
``q_est ⊗ q_ref⁻¹`` and q_NE maps the ENU vertical onto the NED vertical, which leaves |w| and |z|
of the error quaternion unchanged — so we compute in NED. :func:`to_broad_frame` converts back to
BROAD's sensor → ENU for anyone who wants to check (``tests/test_broad_benchmark.py`` does).

- 9-D: raw errors, no alignment.
- 6-D: ONE constant heading offset per trial (circular mean of the heading error over the scored
  samples) removed before the total/heading errors; the inclination error is unaffected.

Harness check: BROAD's published Madgwick numbers (β = 0.12, the ORIGINAL C code with its bx/bz
quirk, 9-D, initialised with ``quatFromAccMag`` from the first sample) are recomputed for the same
trials; the benchmark's other numbers are trusted only when the mean over trials agrees to within
:data:`REPRO_TOLERANCE_DEG`.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from ..errors import TepinnError
from ..quat import quat_conj, quat_mul, quat_rotate
from ..record import FlightRecord
from . import metrics as M
from .estimators import EST_Q_COLS, FilterEstimator
from .filters.madgwick import Madgwick, MadgwickParams
from .names import display_name

REPRO_TOLERANCE_DEG = 0.05
PUBLISHED_MADGWICK = "published_madgwick_average_rmse.json"
METRICS = ("total_rmse_deg", "heading_rmse_deg", "inclination_rmse_deg")
Q_NED_NWU = np.array([0.0, 1.0, 0.0, 0.0])  # Madgwick's own earth frame (z up, x magnetic north) → NED


def broad_trial_files(folder: str | os.PathLike, pattern: str = "*.hdf5") -> list[Path]:
    d = Path(folder)
    if not d.is_dir():
        raise TepinnError("not a folder of BROAD trials", d)
    files = sorted(p for p in d.glob(pattern) if p.is_file())
    if not files:
        raise TepinnError(f"no BROAD trial files ({pattern}) in this folder", d)
    return files


def _meta_quat(rec: FlightRecord, key: str) -> np.ndarray:
    v = rec.meta.get(key)
    if v is None:
        raise TepinnError(f"record {rec.meta.get('source_file')} is not a BROAD trial (no '{key}' in its metadata)")
    return np.asarray(v, np.float64)


def to_broad_frame(q_nb: np.ndarray, rec: FlightRecord) -> np.ndarray:
    """Body → NED estimates back to BROAD's sensor → ENU: ``q_ES = q_NE⁻¹ ⊗ q_NB ⊗ q_SB⁻¹``."""
    q_sb = _meta_quat(rec, "broad_q_sensor_body_wxyz")
    q_ne = _meta_quat(rec, "broad_q_ned_enu_wxyz")
    q_nb = np.asarray(q_nb, np.float64)
    return quat_mul(quat_conj(np.broadcast_to(q_ne, q_nb.shape)), quat_mul(q_nb, quat_conj(np.broadcast_to(q_sb, q_nb.shape))))


def broad_errors(q_est: np.ndarray, q_ref: np.ndarray, movement: np.ndarray, align_heading: bool = False) -> dict:
    """BROAD's total / heading / inclination RMSE (degrees) over ``movement``; 6-D: one constant
    heading offset removed first (``align_heading``)."""
    movement = np.asarray(movement, bool)
    q_est = np.asarray(q_est, np.float64)
    delta = None
    if align_heading:
        finite = np.all(np.isfinite(q_est), axis=1) & np.all(np.isfinite(q_ref), axis=1)
        delta = M.heading_offset_rad(q_est, q_ref, movement & finite)
        q_est = M.align_heading(q_est, delta)
    q_e = M.error_quat_earth(q_est, q_ref)
    out = {
        "total_rmse_deg": math.degrees(M.rmse(M.total_error_rad(q_e), movement)),
        "heading_rmse_deg": math.degrees(M.rmse(M.heading_error_rad(q_e), movement)),
        "inclination_rmse_deg": math.degrees(M.rmse(M.inclination_error_rad(q_e), movement)),
    }
    if delta is not None:
        out["heading_offset_deg"] = math.degrees(delta) if np.isfinite(delta) else None
    return out


def broad_initial_quat(rec: FlightRecord, index: int = 0) -> np.ndarray:
    """BROAD's ``quatFromAccMag(acc[0], mag[0])`` initial state, re-expressed for our frames.

    BROAD computes it in the sensor frame for Madgwick's own earth frame (z up); as a state of our
    NED formulation it is ``q_{NED←NWU} ⊗ q_init ⊗ q_SB``. (It is BROAD's exact formula, including
    its conventions, so the published numbers reproduce; it is not a "correct" initial attitude.)
    """
    q_sb = _meta_quat(rec, "broad_q_sensor_body_wxyz")
    acc_b = rec.acc_m_s2[index]
    mag_b = rec.mag_ut[index]
    sb = np.broadcast_to(q_sb, (1, 4))
    acc = quat_rotate(sb, acc_b[None])[0]  # body → sensor axes
    mag = quat_rotate(sb, mag_b[None])[0]
    z = acc
    x = np.cross(np.cross(z, -mag), z)
    y = np.cross(z, x)
    r = np.column_stack([x / np.linalg.norm(x), y / np.linalg.norm(y), z / np.linalg.norm(z)])
    w_sq = (1 + r[0, 0] + r[1, 1] + r[2, 2]) / 4
    x_sq = (1 + r[0, 0] - r[1, 1] - r[2, 2]) / 4
    y_sq = (1 - r[0, 0] + r[1, 1] - r[2, 2]) / 4
    z_sq = (1 - r[0, 0] - r[1, 1] + r[2, 2]) / 4
    q_init = np.array([
        math.sqrt(max(w_sq, 0.0)),
        math.copysign(math.sqrt(max(x_sq, 0.0)), r[2, 1] - r[1, 2]),
        math.copysign(math.sqrt(max(y_sq, 0.0)), r[0, 2] - r[2, 0]),
        math.copysign(math.sqrt(max(z_sq, 0.0)), r[1, 0] - r[0, 1]),
    ])  # fmt: skip
    return quat_mul(Q_NED_NWU, quat_mul(q_init, q_sb))


def broad_madgwick_estimator(beta: float = 0.12) -> FilterEstimator:
    """The estimator behind BROAD's published Madgwick numbers (original quirk, 9-D, BROAD's init)."""
    return FilterEstimator(Madgwick(MadgwickParams(beta=beta, original_quirk=True)),
                           name=f"madgwick-original-9d-beta{beta:g}", use_mag=True,
                           q0_fn=lambda rec, sl: broad_initial_quat(rec, sl.start))  # fmt: skip


def load_published(path: str | os.PathLike) -> dict:
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
        trials = data["trials"]
        beta = float(data["tagp_parameters"]["beta"])
    except FileNotFoundError:
        raise TepinnError("published BROAD Madgwick results not found", p) from None
    except (ValueError, KeyError, TypeError) as exc:
        raise TepinnError(f"not BROAD's results_madgwick_average_rmse.json ({type(exc).__name__}: {exc})", p) from None
    return {"beta": beta, "trials": {k: v["tagp_parameters"] for k, v in trials.items()}}


def reproduction_check(trial_results: dict[str, dict], published: dict) -> dict:
    """Compare our Madgwick numbers per trial with the published ones (same trials only)."""
    common = [t for t in trial_results if t in published["trials"]]
    per_trial = {}
    for t in common:
        per_trial[t] = {m: {"ours": trial_results[t][m], "published": published["trials"][t][m],
                            "diff": trial_results[t][m] - published["trials"][t][m]} for m in METRICS}  # fmt: skip
    if not common:
        return {"n_trials": 0, "ok": False, "error_deg": None, "max_trial_error_deg": None, "per_trial": {},
                "reason": "none of the trials is in the published results"}  # fmt: skip
    mean_ours = {m: float(np.mean([trial_results[t][m] for t in common])) for m in METRICS}
    mean_pub = {m: float(np.mean([published["trials"][t][m] for t in common])) for m in METRICS}
    err = max(abs(mean_ours[m] - mean_pub[m]) for m in METRICS)
    worst = max(abs(per_trial[t][m]["diff"]) for t in common for m in METRICS)
    return {"n_trials": len(common), "mean_ours": mean_ours, "mean_published": mean_pub, "error_deg": err,
            "max_trial_error_deg": worst, "tolerance_deg": REPRO_TOLERANCE_DEG, "ok": bool(err <= REPRO_TOLERANCE_DEG),
            "per_trial": per_trial}  # fmt: skip


def trial_groups(folder: Path) -> dict[str, list[str]]:
    """Trial → BROAD groups from ``trials.json`` in the folder (empty when absent)."""
    p = Path(folder) / "trials.json"
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
        return {k: list(v.get("groups", [])) for k, v in data["trials"].items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}


def run_broad_benchmark(folder, estimators: list, published_path=None, pattern: str = "*.hdf5",
                        progress: bool = True, notes: list | None = None) -> dict:  # fmt: skip
    """Ingest every trial, reproduce the published Madgwick numbers, then score all estimators."""
    from ..ingest import ingest_log

    folder = Path(folder)
    files = broad_trial_files(folder, pattern)
    notes = list(notes or [])
    pub_path = Path(published_path) if published_path else folder / PUBLISHED_MADGWICK
    published = None
    if pub_path.exists() or published_path:
        published = load_published(pub_path)
    else:
        notes.append(f"no {PUBLISHED_MADGWICK} in {folder} (give --published): the harness cannot be checked, "
                     "so no number below is trusted")  # fmt: skip
    check_est = broad_madgwick_estimator(published["beta"] if published else 0.12)
    all_est = [check_est] + list(estimators)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(files) * len(all_est), desc="BROAD", unit="run", file=sys.stderr, leave=False)
    trials, per_est, timing = [], {e.name: {} for e in all_est}, {e.name: [0.0, 0] for e in all_est}
    try:
        for f in files:
            rec = ingest_log(f)
            name = str(rec.meta.get("broad_trial") or f.stem)
            trials.append(name)
            q_ref = rec.q_ref_wxyz
            mv = rec.valid
            for est in all_est:
                if bar is not None:
                    bar.set_postfix_str(f"{name[:12]} {display_name(est.name)}", refresh=False)
                t0 = time.perf_counter()
                df = est.estimate(rec)
                el = time.perf_counter() - t0
                q = df[EST_Q_COLS].to_numpy(np.float64)
                res = broad_errors(q, q_ref, mv, align_heading=not est.uses_mag)
                res["coverage"] = float(np.mean(np.all(np.isfinite(q[mv]), axis=1))) if mv.any() else float("nan")
                per_est[est.name][name] = res
                timing[est.name][0] += el
                timing[est.name][1] += len(rec)
                if bar is not None:
                    bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    groups = trial_groups(folder)
    summary = {}
    for est in all_est:
        rs = per_est[est.name]
        d = {m: float(np.nanmean([rs[t][m] for t in trials])) for m in METRICS}
        if not getattr(est, "tracks_heading", True):  # RIANN: no heading to score (its 72.8° was printed as one)
            d["total_rmse_deg"] = d["heading_rmse_deg"] = None
        d["us_per_sample"] = 1e6 * timing[est.name][0] / max(1, timing[est.name][1])
        d["mode"] = "9-D" if est.uses_mag else "6-D (one heading offset per trial)"
        d["causal"] = bool(est.causal)
        d["kind"] = est.kind
        by_group = {}
        for g in ("undisturbed", "disturbed"):
            ts = [t for t in trials if g in groups.get(t, [])]
            if ts:
                by_group[g] = {m: float(np.nanmean([rs[t][m] for t in ts])) for m in METRICS} | {"n": len(ts)}
        d["groups"] = by_group
        summary[est.name] = d
    check = reproduction_check(per_est[check_est.name], published) if published else {
        "n_trials": 0, "ok": False, "error_deg": None, "reason": "no published results"}  # fmt: skip
    return {"folder": str(folder), "trials": trials, "check_estimator": check_est.name, "check": check,
            "trusted": bool(check.get("ok")), "summary": summary, "per_trial": per_est, "notes": notes}  # fmt: skip


def _cell(v: float, width: int) -> str:
    return f"{v:{width}.2f}" if v is not None and np.isfinite(v) else f"{'-':>{width}s}"


def format_broad(result: dict) -> str:
    """Human-readable BROAD tables; learned estimators are marked UNTRUSTED when the check failed."""
    L = []
    c = result["check"]
    n = len(result["trials"])
    L.append(f"BROAD benchmark: {n} trial(s) from {result['folder']}")
    if c.get("error_deg") is not None:
        mo, mp = c["mean_ours"], c["mean_published"]
        L.append(f"Harness check — {display_name(result['check_estimator'])} vs BROAD's published values on the same {c['n_trials']} trial(s):")
        L.append("  total / heading / inclination RMSE, mean over trials [deg]: "
                 f"ours {mo['total_rmse_deg']:.3f} / {mo['heading_rmse_deg']:.3f} / {mo['inclination_rmse_deg']:.3f}, "
                 f"published {mp['total_rmse_deg']:.3f} / {mp['heading_rmse_deg']:.3f} / {mp['inclination_rmse_deg']:.3f}")  # fmt: skip
        L.append(f"  reproduction error {c['error_deg']:.4f} deg (largest per-trial difference {c['max_trial_error_deg']:.4f} deg), "
                 f"tolerance {c['tolerance_deg']} deg: {'OK' if c['ok'] else 'FAILED'}")  # fmt: skip
    else:
        L.append(f"Harness check not possible: {c.get('reason', 'no published results')}.")
    if not result["trusted"]:
        L.append("  -> the harness is NOT validated: learned-estimator numbers below are marked UNTRUSTED.")
    L.append("")
    rows = sorted(result["summary"].items(), key=lambda kv: (kv[1]["mode"].startswith("6"), kv[1]["inclination_rmse_deg"]))
    w = max([30, *(len(display_name(n)) for n, _ in rows)])  # (review60: a 33-character name shifted its row)
    L.append(f"{'estimator':{w}s} {'mode':8s} {'causal':6s} {'total':>7s} {'heading':>8s} {'incl.':>7s} {'us/sample':>10s}")
    for name, d in rows:
        untrusted = d["kind"] == "learned" and not result["trusted"]
        mode = "9-D" if d["mode"].startswith("9") else "6-D"
        L.append(f"{display_name(name):{w}s} {mode:8s} {'yes' if d['causal'] else 'no':6s} "
                 f"{_cell(d['total_rmse_deg'], 7)} {_cell(d['heading_rmse_deg'], 8)} {d['inclination_rmse_deg']:7.2f} "
                 f"{d['us_per_sample']:10.2f}" + ("   UNTRUSTED" if untrusted else ""))  # fmt: skip
    L.append("")
    L.append("RMSE in degrees over BROAD's movement samples, mean over trials; 6-D rows: total and heading after one constant "
             "heading offset per trial; 9-D rows: raw; '-': an estimator that tracks no heading (RIANN).")  # fmt: skip
    for nt in result["notes"]:
        L.append(f"note: {nt}")
    return "\n".join(L)
