"""Fitting the estimator to a trained network: :func:`calibrate_fusion` (the network-centred
fusion's settings on validation flights), :func:`calibrate_with` (with a recipe's
``[calibration]``) and :func:`recalibrate` (redo it on a finished run)."""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import numpy as np

from .. import __version__
from ..record import EST_BIAS_COLS, EST_Q_COLS, GYR_BIAS_COLS, FlightRecord
from .checkpoint import save_checkpoint
from .estimate import estimate_record
from .fusion import FusionConfig
from .network import TEPINN
from .train_config import TrainConfig
from .train_data import load_records, split_by_flight


def calibrate_fusion(model: TEPINN, records: list[FlightRecord], base: FusionConfig, max_records: int = 12,
                     fallback_records: list[FlightRecord] = (), bias_state_sweeps: int = 2,
                     feedback_deadzones_rad_s: tuple[float, ...] = (), feedback_windows: int = 25,
                     ) -> tuple[FusionConfig, dict]:  # fmt: skip
    """Fit the fusion on validation flights, minimising the mean over flights of the per-flight
    tilt RMSE of the fused output (the figure the benchmark and ``evaluate`` report): the process
    noise of the low-pass fusion, then the bias-state Kalman fusion (``bias_states``) by a
    coordinate search over its σ scale, bias σ, process noise (per second and per radian turned)
    and bias random walk — the better of the two is kept; for the low-pass, the bias time constant.
    The settings for saturated gyro samples are compared on the validation flights that clip, or,
    where none does, on up to 6 of ``fallback_records`` (training flights) that do; then bias
    feedback with each of ``feedback_deadzones_rad_s`` (kept where it helps). Last, the σ scale that
    makes the reported σ calibrated on the typical sample (median |e|²/σ² = 2 ln 2, the median of a
    2-D Gaussian tilt error)."""
    from ..quat import inclination_heading_split, quat_conj, quat_mul
    from .estimate import window_estimates

    usable = [r for r in records if (r.meta.get("imu_rate_hz") or 0) >= 20]
    if not usable:
        return base, {}
    pick = np.unique(np.linspace(0, len(usable) - 1, min(max_records, len(usable))).round().astype(int))
    recs = [usable[i] for i in pick]
    wins = [window_estimates(model, r) for r in recs]

    def run(cand, recs=recs, wins=wins):
        errs, sig, berr = [], [], []
        for r, w in zip(recs, wins):
            est = estimate_record(model, r, cand, windows=w)
            q = est[EST_Q_COLS].to_numpy()
            ok = np.all(np.isfinite(q), 1) & np.all(np.isfinite(r.q_ref_wxyz), 1) & (est["sigma_rad"].to_numpy() > 0)
            inc, _ = inclination_heading_split(quat_mul(q[ok], quat_conj(r.q_ref_wxyz[ok])))
            errs.append(inc)
            sig.append(est["sigma_rad"].to_numpy()[ok])
            if GYR_BIAS_COLS[0] in r.data:
                b = est[EST_BIAS_COLS].to_numpy()[ok]
                berr.append(np.sqrt(np.mean(np.sum((b - r.data[GYR_BIAS_COLS].to_numpy()[ok]) ** 2, 1))))
        return errs, sig, berr

    def mean_rmse_deg(errs):
        """Mean over flights of the per-flight tilt RMSE (degrees)."""
        r = [np.degrees(np.sqrt(np.mean(e**2))) for e in errs if len(e)]
        return float(np.mean(r)) if r else float("inf")

    best, best_err, table, best_run = base, float("inf"), {}, None
    for pn in (1e-7, 1e-6, 3e-6, 1e-5, 3e-5, 1e-4, 1e-3):
        cand = dataclasses.replace(base, process_noise_rad2_s=pn, output_sigma_scale=1.0)
        errs, sig, _ = run(cand)
        err = mean_rmse_deg(errs)
        table[f"{pn:g}"] = err
        if err < best_err:
            best, best_err, best_run = cand, err, (errs, sig)
    # innovation-adaptive P (helps uncalibrated gyros; kept only where it helps the typical flight)
    for nis in (9.0, 4.0):
        cand = dataclasses.replace(best, adaptive_nis=nis)
        errs, sig, _ = run(cand)
        err = mean_rmse_deg(errs)
        table[f"{best.process_noise_rad2_s:g},nis={nis:g}"] = err
        if err < best_err:
            best, best_err, best_run = cand, err, (errs, sig)
    # gyro-bias states: the tilt innovations estimate the bias too (an uncalibrated gyro)
    kf_table = {}
    if bias_state_sweeps > 0:
        kf = dataclasses.replace(best, bias_states=True, adaptive_nis=0.0, sigma_scale=2.0, bias_sigma_rad_s=0.1,
                                 bias_init_sigma_rad_s=0.3, bias_rw_rad_s_sqrt_s=1e-3)  # fmt: skip
        errs, sig, _ = run(kf)
        kf_err, kf_run = mean_rmse_deg(errs), (errs, sig)
        kf_table["start"] = kf_err
        grid = (("sigma_scale", (1.0, 1.5, 2.0, 3.0, 4.0)), ("bias_sigma_rad_s", (0.03, 0.1, 0.3, 1.0)),
                ("process_noise_rad2_s", (1e-6, 3e-6, 1e-5, 3e-5, 1e-4, 3e-4)),
                ("bias_rw_rad_s_sqrt_s", (1e-4, 3e-4, 1e-3, 3e-3)),
                ("process_noise_rate_rad", (0.0, 1e-4, 3e-4, 1e-3)))  # fmt: skip
        for _ in range(bias_state_sweeps):  # coordinate search (each setting tried once)
            for name, values in grid:
                for v in values:
                    cand = dataclasses.replace(kf, **{name: v})
                    key = f"{name}={v:g}," + ",".join(f"{k}={getattr(cand, k):g}" for k, _ in grid if k != name)
                    if cand == kf or key in kf_table:
                        continue
                    errs, sig, _ = run(cand)
                    err = kf_table[key] = mean_rmse_deg(errs)
                    if err < kf_err:
                        kf, kf_err, kf_run = cand, err, (errs, sig)
        if kf_err < best_err:
            best, best_err, best_run = kf, kf_err, kf_run
    metrics = {"fusion_val_tilt_rmse_mean_deg": best_err, "fusion_grid": table, "fusion_val_flights": len(recs),
               "fusion_bias_states_grid": kf_table, "fusion_bias_states": best.bias_states}  # fmt: skip
    # saturated gyro samples propagated at (1 + κ)× their reading with the model's learned κ, and
    # then trusted more (a smaller σ added per clipped sample), and for how long after the last
    # saturated sample the attitude stays open to the window estimates (clip_hold_s). These
    # settings act around clipped samples only, so they are compared on the validation flights
    # that clip (all of them), or, where none does, on up to 6 training flights that do
    kappa = model.sensor.clip_gain()
    gain = 0.0 if kappa is None else round(float(kappa.detach()), 4)
    clipping, source = [r for r in usable if bool(np.any(r.clipped))], "validation"
    if not clipping:  # in-sample windows look better than they are: conservative
        clipping = [r for r in fallback_records if (r.meta.get("imu_rate_hz") or 0) >= 20 and bool(np.any(r.clipped))]
        clipping, source = clipping[:: max(1, -(-len(clipping) // 6))], "training"  # at most 6, spread
    if clipping:
        made = {id(r): w for r, w in zip(recs, wins)}  # validation flights' windows are at hand
        cwins = [made[id(r)] if id(r) in made else window_estimates(model, r) for r in clipping]
        base_err = mean_rmse_deg(run(best, clipping, cwins)[0])
        clip_table, pick_clip = {"off": base_err}, None
        for infl in (best.clip_inflation_rad, 0.15, 0.05):
            cand = dataclasses.replace(best, clip_rate_gain=gain, clip_inflation_rad=infl)
            err = mean_rmse_deg(run(cand, clipping, cwins)[0])
            clip_table[f"gain={cand.clip_rate_gain:g},inflation={infl:g}"] = err
            if err < base_err:
                base_err, pick_clip = err, cand
        start = pick_clip or dataclasses.replace(best, clip_rate_gain=gain)
        for hold in (0.3, 1.0, 2.0):
            cand = dataclasses.replace(start, clip_hold_s=hold)
            err = mean_rmse_deg(run(cand, clipping, cwins)[0])
            clip_table[f"gain={cand.clip_rate_gain:g},inflation={cand.clip_inflation_rad:g},hold={hold:g}"] = err
            if err < base_err:
                base_err, pick_clip = err, cand
        metrics["fusion_clip_grid"] = clip_table
        metrics["fusion_clip_flights"] = f"{len(clipping)} {source}"
        if pick_clip is not None:
            best = pick_clip
            if best_run is not None:
                errs, sig, _ = run(best)
                best_err, best_run = mean_rmse_deg(errs), (errs, sig)
                metrics["fusion_val_tilt_rmse_mean_deg"] = best_err
    # bias feedback: the network sees the gyro minus the fusion's bias beyond a dead zone (an
    # uncalibrated gyro); its windows depend on the fusion, so each candidate reruns the network
    fb_table = {"off": best_err} if feedback_deadzones_rad_s else {}
    for dz in feedback_deadzones_rad_s:
        cand = dataclasses.replace(best, bias_feedback_windows=feedback_windows, bias_feedback_deadzone_rad_s=dz)
        errs, sig, _ = run(cand)
        err = fb_table[f"{dz:g}"] = mean_rmse_deg(errs)
        if err < best_err:
            best, best_err, best_run = cand, err, (errs, sig)
            metrics["fusion_val_tilt_rmse_mean_deg"] = best_err
    if fb_table:
        metrics["fusion_feedback_grid"] = fb_table
    # the bias low-pass: the time constant with the lowest gyro-bias error (where truth exists),
    # kept only if the tilt error does not get worse
    btable = {}
    for tau in () if best.bias_states else (5.0, 10.0, 20.0, 40.0):
        cand = dataclasses.replace(best, bias_time_constant_s=tau)
        errs, sig, berr = run(cand)
        if berr:
            btable[f"{tau:g}"] = (float(np.degrees(np.exp(np.mean(np.log(np.maximum(berr, 1e-9)))))), mean_rmse_deg(errs), errs, sig, cand)
    if btable:
        key = min(btable, key=lambda k: btable[k][0] if btable[k][1] <= best_err * 1.02 else float("inf"))
        if btable[key][1] <= best_err * 1.02:
            _, best_err, errs, sig, best = btable[key]
            best_run = (errs, sig)
            metrics["fusion_val_tilt_rmse_mean_deg"] = best_err
        metrics["fusion_bias_grid_deg_s"] = {k: v[0] for k, v in btable.items()}
        metrics["fusion_bias_time_constant_s"] = best.bias_time_constant_s
    if best_run is not None:
        e = np.concatenate(best_run[0])
        s = np.concatenate(best_run[1])
        if len(e):
            scale = float(np.sqrt(np.median(e**2 / s**2) / (2.0 * np.log(2.0))))  # 2-D Gaussian: median |e|²/σ² = 2 ln 2
            best = dataclasses.replace(best, output_sigma_scale=scale)
            metrics["fusion_output_sigma_scale"] = scale
    return best, metrics


def calibrate_with(cfg: TrainConfig, model: TEPINN, val_recs, train_recs) -> tuple[FusionConfig, dict]:
    """:func:`calibrate_fusion` with the recipe's ``[calibration]`` settings."""
    c = cfg.calibration
    return calibrate_fusion(model, val_recs, cfg.fusion, c.max_flights, fallback_records=train_recs,
                            bias_state_sweeps=c.bias_state_sweeps, feedback_windows=c.feedback_windows,
                            feedback_deadzones_rad_s=tuple(math.radians(d) for d in c.feedback_deadzones_deg_s))  # fmt: skip


def recalibrate(run_dir: str | os.PathLike, cfg: TrainConfig, data_dirs=(), config_base: Path = Path(".")) -> dict:
    """Re-run the end of :func:`train` on a finished run: rebuild the validation split, fit the
    fusion to ``best.pt`` and rewrite ``model.pt`` (used when the calibration code improves)."""
    from .checkpoint import load_model

    out = Path(run_dir)
    records = load_records(cfg, data_dirs, config_base, out, progress=False)
    tr_idx, va_idx = split_by_flight(len(records), cfg.data.val_fraction, cfg.seed)
    val_recs = [records[i] for i in va_idx]
    best_model, _, ck = load_model(out / "best.pt")
    fusion, fus_metrics = calibrate_with(cfg, best_model, val_recs, [records[i] for i in tr_idx])
    final_metrics = {**(ck.get("metrics") or {}), **fus_metrics}
    save_checkpoint(out / "model.pt", best_model, fusion, training=ck.get("training"), metrics=final_metrics,
                    loss_config=dataclasses.asdict(cfg.loss), tepinn_flight_version=__version__)  # fmt: skip
    return fus_metrics
