"""Evaluation report: ``report.md`` (tables), PNG figures, ``metrics.json`` and ``report.html`` (the
interactive version, :mod:`.report_html`), written atomically.

Colours follow the TE-PINN paper: ground truth black, the analytical (complementary) filter red,
the LSTM blue, TE-PINN green; every other method has its own fixed colour (:mod:`.plotdata`). 6-D estimates are shown
after their one constant heading alignment per run (the same one the metrics use) and on the
reference's quaternion hemisphere (q ≡ −q), so curves are comparable.

Every file is written to a temporary name and renamed into place; ``report.md`` is written last, so
a report whose Markdown exists is complete.
"""

from __future__ import annotations

import io
import json
import math
import os
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from .. import __version__
from ..record import atomic_write
from .harness import WIN_MARGIN_DEG, EvalResult
from .names import display_name
from .plotdata import PAPER_COLOURS, break_wraps, colour_map, is_9d, minmax_indices, showcase_records
from .left_out import LEFT_OUT_NOTE, kept_out, summary_heading
from .report_html import RECORD_COLUMNS, kept_out_records, rate_counts, rate_labels, record_rows, write_html

FIGURES = {
    "quaternion": "fig_quaternion.png",
    "euler": "fig_euler.png",
    "inclination_error": "fig_inclination_error.png",
    "error_vs_rate": "fig_error_vs_rate.png",
    "per_record": "fig_per_record.png",
    "uncertainty": "fig_uncertainty.png",
    "error_vs_noise": "fig_error_vs_noise.png",
}
HTML_REPORT = "report.html"
#: how report.md names the runtime a learned model ran in (``evaluate --runtime``)
RUNTIME_NAMES = {"onnx": "onnxruntime", "torch": "PyTorch"}


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    _plt().close(fig)
    data = buf.getvalue()
    atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))


def _stride(n: int, max_points: int = 6000) -> int:
    return max(1, int(math.ceil(n / max_points)))


def _finish(fig, path):
    """Save and close the figure, or (``path`` None, for tests) hand it back."""
    if path is None:
        return fig
    _save(fig, path)
    return None


def _ls(name: str) -> str:
    return "--" if is_9d(name) else "-"


def _grid(plt, rows: int, shown: list, height: float):
    """One column per showcased record; laid out so that the title, the panels' two-line captions and the legend
    below (:func:`_legend_below`) do not overlap."""
    nc = max(1, len(shown))
    return plt.subplots(rows, nc, figsize=(10 if nc == 1 else 6.5 * nc, height), sharex="col", squeeze=False,
                        layout="constrained")  # fmt: skip


def _legend_below(fig, axes) -> None:
    """The estimators' legend under the panels, not on a panel's data (the first panel's lines name them all)."""
    handles, labels = axes[0][0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 10), fontsize=8, frameon=False)


def _drawn(est: dict) -> list:
    """The estimates in drawing order: TE-PINN last, so that its line is on top of the peers' (it was hidden under
    eight of them where they agree)."""
    return sorted(est.items(), key=lambda kv: kv[0].startswith("tepinn"))


def _style(name: str) -> dict:
    return {"zorder": 3, "lw": 1.1} if name.startswith("tepinn") else {"zorder": 2, "lw": 0.8}


def _hemisphere_ref(ref: np.ndarray) -> np.ndarray:
    """The reference where it is finite, elsewhere its nearest finite sample before (else after): what an estimate's
    sign is matched to, so that the plotted quaternion does not jump where the reference is missing."""
    import pandas as pd

    return pd.DataFrame(ref).ffill().bfill().to_numpy()


def _caption(s: dict, cap: str) -> str:
    return f"{s['name']}\n{cap}" if cap else s["name"]


# ----------------------------------------------------------------------------- figures


def fig_quaternion(result, colours, path=None):
    plt = _plt()
    shown = showcase_records(result)
    fig, axes = _grid(plt, 4, shown, 8)
    for c, (s, cap) in enumerate(shown):
        k = _stride(len(s["t_s"]))
        t = s["t_s"][::k]
        ref = s["q_ref"][::k]
        side = _hemisphere_ref(ref)
        for name, e in _drawn(s["est"]):
            if not e.get("tracks_heading", True):  # (RIANN: every component mixes in a heading it does not track)
                continue
            q = e["q"][::k]
            q = np.where(np.sum(q * side, axis=1, keepdims=True) < 0, -q, q)
            for i in range(4):
                axes[i][c].plot(t, q[:, i], color=colours[name], ls=_ls(name), label=display_name(name), **_style(name))
        for i, comp in enumerate("wxyz"):
            axes[i][c].plot(t, ref[:, i], color=PAPER_COLOURS["truth"], lw=1.2, label="reference")
            axes[i][0].set_ylabel(f"q_{comp}")
        axes[0][c].set_title(_caption(s, cap), fontsize=9)
        axes[-1][c].set_xlabel("t [s]")
    _legend_below(fig, axes)
    fig.suptitle("Quaternion components (6-D estimates heading-aligned; not those that track no heading: RIANN)")
    return _finish(fig, path)


def fig_euler(result, colours, path=None):
    """Roll, pitch, yaw; roll and yaw broken at their ±180° wraps (no vertical jump lines)."""
    from ..quat import quat_to_euler_zyx

    plt = _plt()
    shown = showcase_records(result)
    fig, axes = _grid(plt, 3, shown, 7)
    for c, (s, cap) in enumerate(shown):
        t = s["t_s"]
        for name, e in _drawn(s["est"]) + [("reference", {"q": s["q_ref"]})]:
            ref = name == "reference"
            eul = quat_to_euler_zyx(e["q"])
            for i in range(3 if e.get("tracks_heading", True) else 2):  # (RIANN: no yaw to draw)
                y = np.degrees(eul[i])
                idx = minmax_indices(y, 6000)
                tt, yy = t[idx], y[idx]
                if i != 1:
                    tt, yy = break_wraps(tt, yy)
                axes[i][c].plot(tt, yy, color=PAPER_COLOURS["truth"] if ref else colours[name], ls="-" if ref else _ls(name),
                                label=name if ref else display_name(name),
                                **({"lw": 1.2, "zorder": 2.5} if ref else _style(name)))  # fmt: skip
        for i in (0, 2):
            axes[i][c].set_ylim(-185, 185)
            axes[i][c].set_yticks([-180, -90, 0, 90, 180])
        axes[0][c].set_title(_caption(s, cap), fontsize=9)
        axes[-1][c].set_xlabel("t [s]")
    for i, lab in enumerate(("roll", "pitch", "yaw")):
        axes[i][0].set_ylabel(f"{lab} [°]")
    _legend_below(fig, axes)
    fig.suptitle("Roll, pitch, yaw (6-D yaw after one constant alignment; lines break at ±180°)")
    return _finish(fig, path)


def fig_inclination_error(result, colours, path=None):
    plt = _plt()
    shown = showcase_records(result)
    fig, axes = _grid(plt, 1, shown, 4)
    for c, (s, cap) in enumerate(shown):
        ax = axes[0][c]
        t, m = s["t_s"], s["mask"]
        for name, e in _drawn(s["est"]):
            y = np.degrees(e["incl"]).copy()
            y[~m] = np.nan
            idx = minmax_indices(y, 6000)
            ax.plot(t[idx], y[idx], color=colours[name], ls=_ls(name), label=display_name(name), **_style(name))
        ax.set_title(_caption(s, cap), fontsize=9)
        ax.set_xlabel("t [s]")
    axes[0][0].set_ylabel("inclination error [°]")
    _legend_below(fig, axes)
    fig.suptitle("Inclination error over scored samples")
    return _finish(fig, path)


def fig_error_vs_rate(result, colours, path=None):
    plt = _plt()
    labels = rate_labels(result.config.rate_bins_deg_s)
    counts = rate_counts(result) if result.dataset else [0] * len(labels)
    fig, ax = plt.subplots(figsize=(8, 4.8))
    x = np.arange(len(labels))
    for name, d in result.dataset.items():
        y = np.array([np.nan if v is None else v for v in d["dynamic_error_deg"]], np.float64)
        ax.plot(x, y, "o", ls=_ls(name), color=colours[name], label=display_name(name))
    ax.set_xticks(x, [f"{lab}\nn = {n}" for lab, n in zip(labels, counts)])
    ax.set_xlabel("angular rate |ω| [°/s] (n: scored samples in the bin)")
    ax.set_ylabel("inclination RMSE [°]")
    ax.set_title("Dynamic error: inclination RMSE by angular rate (pooled over records)")
    ax.legend(fontsize=7, ncol=3)
    return _finish(fig, path)


#: label every per-record dot up to this many records; above, only each estimator's best and worst
LABEL_ALL_RECORDS = 12


def _label_sides(vals: np.ndarray, label, log_scale: bool, span: float, near: float = 0.03) -> list[tuple[int, int]]:
    """(record index, +1 right / −1 left) of the dots to label: going up the values, a label closer than ``near`` of
    the axis' span to the one before goes to the other side, and one close to both sides' last is left out (the
    labels of records with nearly the same RMSE were printed over each other)."""
    def pos(v):
        return math.log10(v) if log_scale else v

    out, last = [], {1: -np.inf, -1: -np.inf}
    gap = near * span if span > 0 else np.inf  # (every value the same: one label each side)
    for j in sorted((int(j) for j in label), key=lambda j: vals[j]):
        if not (np.isfinite(vals[j]) and (vals[j] > 0 or not log_scale)):
            continue
        y = pos(vals[j])
        for side in (1, -1):
            if y - last[side] >= gap:
                out.append((j, side))
                last[side] = y
                break
    return out


def fig_per_record(result, colours, path=None):
    plt = _plt()
    names = list(result.dataset)
    rec_names = [r["name"] for r in result.records]
    ok = np.array([not kept_out(r) for r in result.records], bool)  # the summary's records (its mean is theirs)
    if not ok.any():
        ok[:] = True  # (results without the harness's record of it, every record left out: over them all)
    fig, ax = plt.subplots(figsize=(max(6, 1.3 * len(names) + 2), 5))
    allv = np.array([r["results"][n].get("inclination_rmse_deg") or np.nan for r in result.records for n in names], np.float64)
    allv = allv[np.isfinite(allv) & (allv > 0)]
    log_scale = bool(allv.size and allv.max() > 20 * allv.min())  # records an order of magnitude apart: all readable
    span = (np.log10(allv.max() / allv.min()) if log_scale else allv.max() - allv.min()) if allv.size else 0.0
    for i, name in enumerate(names):
        vals = [r["results"][name].get("inclination_rmse_deg") for r in result.records]
        vals = np.array([np.nan if v is None else v for v in vals], np.float64)
        jitter = np.linspace(-0.15, 0.15, len(vals)) if len(vals) > 1 else np.zeros(1)
        ax.scatter((i + jitter)[ok], vals[ok], color=colours[name], s=14)
        if (~ok).any():  # kept out of the summary (IMU too slow, reference not trusted...): hollow, not in the mean
            ax.scatter((i + jitter)[~ok], vals[~ok], facecolors="none", edgecolors=colours[name], s=14,
                       label="not in the summary (IMU too slow, reference not trusted...): not in the mean" if i == 0 else None)  # fmt: skip
        fin = np.flatnonzero(np.isfinite(vals))
        if len(vals) > LABEL_ALL_RECORDS and (np.isfinite(vals) & ok).any():  # best and worst of the summary's records
            fin = np.flatnonzero(np.isfinite(vals) & ok)
        if np.isfinite(vals[ok]).any():
            ax.hlines(np.nanmean(vals[ok]), i - 0.3, i + 0.3, color=colours[name], lw=2)
        if fin.size:
            label = fin if len(vals) <= LABEL_ALL_RECORDS else np.unique([fin[np.argmin(vals[fin])], fin[np.argmax(vals[fin])]])
            for j, side in _label_sides(vals, label, log_scale, span):
                ax.annotate(rec_names[j], (i + jitter[j], vals[j]), xytext=(4 * side, 0), textcoords="offset points",
                            fontsize=6, va="center", ha="left" if side > 0 else "right", color="#333333")  # fmt: skip
    ax.set_xticks(range(len(names)), [display_name(n) for n in names], rotation=30, ha="right")
    ax.set_ylabel("inclination RMSE per record [°]")
    if log_scale:
        ax.set_yscale("log")
    shown = "dots labelled with the record" if len(rec_names) <= LABEL_ALL_RECORDS else "best and worst record labelled"
    if (~ok).any():
        ax.legend(fontsize=7)
    ax.set_title(f"Per-record inclination RMSE (bar: mean over records; {shown})")
    return _finish(fig, path)


def pooled_sigma_samples(result, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(σ, squared 2-D tilt error) of estimator ``name`` over the scored samples of the summary's records (those
    left out of the summary — IMU too slow, reference untrusted, an estimator without an estimate — left out here
    too, as from the table beside the figure; session 53)."""
    sig, err = [np.empty(0)], [np.empty(0)]
    for s, r in zip(result.series, result.records):
        e = s["est"][name]
        if not r.get("in_summary", True) or e.get("sigma") is None or e.get("tilt_err") is None:
            continue
        m = s["mask"] & np.isfinite(e["sigma"]) & np.all(np.isfinite(e["tilt_err"]), axis=1)
        sig.append(e["sigma"][m])
        err.append(np.sum(e["tilt_err"][m] ** 2, axis=1))
    return np.concatenate(sig), np.concatenate(err)


def fig_uncertainty(result, colours, path=None):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 5.5))
    any_sigma = False
    top = 0.0
    for name in result.dataset:
        sig, err = pooled_sigma_samples(result, name)
        if not sig.size:
            continue
        any_sigma = True
        qs = np.unique(np.quantile(sig, np.linspace(0, 1, 11)))
        idx = np.clip(np.digitize(sig, qs[1:-1]), 0, len(qs) - 2)
        xs, ys = [], []
        for b in range(len(qs) - 1):
            sel = idx == b
            if sel.sum() >= 5:
                xs.append(np.degrees(np.sqrt(np.mean(sig[sel] ** 2))))
                ys.append(np.degrees(np.sqrt(np.mean(err[sel]) / 2.0)))  # RMS per-axis tilt error
        ax.plot(xs, ys, "o-", color=colours[name], label=display_name(name))
        top = max(top, max(xs + ys) if xs else 0.0)
    if any_sigma:
        ax.plot([0, top * 1.05], [0, top * 1.05], "k--", lw=1, label="calibrated")
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no estimator reports σ", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("predicted σ per tilt axis [°] (decile bins)")
    ax.set_ylabel("actual RMS tilt error per axis [°]")
    ax.set_title("Uncertainty calibration")
    return _finish(fig, path)


def fig_error_vs_noise(result, colours, path=None):
    plt = _plt()
    sw = result.noise_sweep
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name, ys in sw["inclination_rmse_deg"].items():
        y = np.array([np.nan if v is None else v for v in ys], np.float64)
        ax.plot(sw["levels"], y, "o-", color=colours.get(name, "gray"), label=display_name(name))
    ax.set_xlabel(f"added white noise, multiples of σ_gyr = {sw['base_gyr_sigma_rad_s']:.3g} rad/s, "
                  f"σ_acc = {sw['base_acc_sigma_m_s2']:.3g} m/s² per sample")  # fmt: skip
    ax.set_ylabel("inclination RMSE [°]")
    ax.set_title(f"Error vs added sensor noise ({sw['n_records']} simulated records)")
    ax.legend(fontsize=7, ncol=3)
    return _finish(fig, path)


# ----------------------------------------------------------------------------- markdown


def _f(v, nd=2):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def md_cell(text: str) -> str:
    """``text`` as a Markdown table cell shows it: ``|`` escaped (a record named ``a|b`` had split its row, every value
    under the wrong estimator), ``&``, ``<`` and ``>`` as entities (``tag<i>`` had been read as markup)."""
    return str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace("|", "\\|")


def _pct(v):
    return "–" if v is None or not math.isfinite(v) else f"{100 * v:.1f} %"


def render_markdown(result: EvalResult, figures: dict[str, str], title: str = "Attitude estimation report") -> str:
    L = [f"# {title}", "", f"Interactive version, every record zoomable: [{HTML_REPORT}]({HTML_REPORT}).", ""]
    L.append(f"tepinn-flight {__version__}, {datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}. "
             f"{len(result.records)} record(s), {len(result.estimators)} estimator(s).")  # fmt: skip
    L.append("")
    L.append("## Protocol")
    L.append("")
    c = result.config
    L.append(f"- Scored samples: the record's `valid` mask ∧ finite reference ∧ after the first {c.warmup_s:g} s of every "
             "segment ∧ a finite estimate from every estimator that covers ≥ "
             f"{100 * c.min_coverage:.0f} % of those samples — the same samples for all estimators.")  # fmt: skip
    L.append("- 6-D estimators (no magnetometer): ONE constant heading offset per run (segment), the circular mean of the "
             "heading error, removed before heading / total / yaw errors and plots; 9-D estimators: none.")  # fmt: skip
    L.append("- Errors (BROAD's definitions): earth-frame error q_e = q_est ⊗ q_ref⁻¹; inclination 2·acos(√(w²+z²)), "
             "heading 2·atan(|z/w|), total 2·acos(|w|). Per record RMSE, then the mean over records.")  # fmt: skip
    L.append("- Mean quaternion error: mean of the sign-invariant distance min(‖q − q_ref‖, ‖q + q_ref‖) (dimensionless); "
             "mean angle: mean of 2·acos(|⟨q, q_ref⟩|). Shown beside the RMSEs, not as the headline.")  # fmt: skip
    L.append("- Heading drift: slope of the aligned, unwrapped heading error over time (least squares), °/min; the table "
             "gives the mean of |slope| over records.")  # fmt: skip
    L.append("")
    if result.notes:
        L.append("## Notes")
        L.append("")
        L += [f"- {n}" for n in result.notes]
        L.append("")
    L.append("## Records")
    L.append("")
    L.append("The figures' time axes are each record's t (0 at its first sample); the log's own clock (TimeUS, "
             "time_boot_ms, timestamp) is t plus the \"log clock at t = 0\" column, up to a reboot.")
    L.append("")
    L.append("| " + " | ".join(RECORD_COLUMNS) + " |")
    L.append("|---|---|---:|---|---|---:|---:|---:|---:|")
    for row in record_rows(result):
        L.append("| " + " | ".join(map(md_cell, row)) + " |")
    L.append("")
    slow = kept_out_records(result)
    if slow:
        L.append("## Records not in the summary")
        L.append("")
        L.append(LEFT_OUT_NOTE)
        L.append("")
        L.append("| record | why | IMU rate [Hz] | " + " | ".join(display_name(n) for n in result.dataset) + " |")
        L.append("|---|---|---:|" + "---:|" * len(result.dataset))
        for r in slow:
            L.append(f"| {md_cell(r['name'])} | {kept_out(r)} | {_f(r.get('imu_rate_hz'), 1)} | "
                     + " | ".join(_f(r["results"][n].get("inclination_rmse_deg")) for n in result.dataset) + " |")
        L.append("")
    L.append(f"## {summary_heading(result.records)}")
    L.append("")
    L.append("Median and p95: of the records' inclination RMSEs (with one record, the RMSE itself); the gyro bias RMS: "
             "the mean over the records that hold the true bias (simulations); every other column is a mean over records "
             "(a 9-D estimator's heading, total and drift over those with a magnetometer). Heading: after one constant "
             "offset per segment in 6-D; '–' for an estimator that tracks none (RIANN).")
    L.append("")
    L.append("| estimator | kind | causal | mode | incl. RMSE [°] | median of records | p95 of records | roll [°] | pitch [°] | heading [°] | "
             "total [°] | \\|drift\\| [°/min] | mean q dist | mean angle [°] | gyro bias RMS [°/s] | µs/sample |")  # fmt: skip
    L.append("|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    info = {e["name"]: e for e in result.estimators}
    for name, d in sorted(result.dataset.items(), key=lambda kv: (kv[1]["inclination_rmse_deg"] is None, kv[1]["inclination_rmse_deg"] or 0)):
        e = info[name]
        L.append(f"| {display_name(name)} | {e['kind']} | {'yes' if e['causal'] else 'no'} | {'9-D' if e['uses_mag'] else '6-D'} | "
                 f"**{_f(d['inclination_rmse_deg'])}** | {_f(d['inclination_rmse_median_deg'])} | {_f(d['inclination_rmse_p95_deg'])} | "
                 f"{_f(d['roll_rmse_deg'])} | {_f(d['pitch_rmse_deg'])} | {_f(d['heading_rmse_deg'])} | {_f(d['total_rmse_deg'])} | "
                 f"{_f(d['heading_drift_abs_deg_per_min'])} | {_f(d['mean_quat_distance'], 4)} | {_f(d['mean_quat_angle_deg'])} | "
                 f"{_f(d['gyr_bias_rms_deg_s'], 3)} | {_f(d['us_per_sample'], 2)} |")  # fmt: skip
    L.append("")
    L.append("Estimator ids in metrics.json: " + ", ".join(f"{display_name(n)} = `{n}`" for n in result.dataset) + ".")
    L.append("")
    models = [f"{display_name(e['name'])}: `{md_cell(e['model'])}` in {RUNTIME_NAMES.get(e['runtime'], e['runtime'])}"
              for e in result.estimators if e.get("model")]  # fmt: skip
    if models:
        L.append("Learned models: " + "; ".join(models) + ".")
        L.append("")
    low = [f"{display_name(k)} ({_pct(v['coverage_min'])})" for k, v in result.dataset.items()
           if v.get("coverage_min") is not None and v["coverage_min"] < c.min_coverage]  # fmt: skip
    if low:
        L.append(f"Scored on their own finite samples (coverage below {100 * c.min_coverage:.0f} %): {', '.join(low)}.")
        L.append("")
    L.append(f"![quaternion components]({figures['quaternion']})")
    L.append("")
    L.append(f"![roll pitch yaw]({figures['euler']})")
    L.append("")
    L.append(f"![inclination error over time]({figures['inclination_error']})")
    L.append("")
    L.append("## Per record: inclination RMSE [°]")
    L.append("")
    names = list(result.dataset)
    L.append("| record | " + " | ".join(display_name(n) for n in names) + " |")
    L.append("|---|" + "---:|" * len(names))
    for r in result.records:
        why = kept_out(r)
        tag = f" ({why}, not in the summary)" if why else ""
        L.append(f"| {md_cell(r['name'])}{tag} | " + " | ".join(_f(r["results"][n].get("inclination_rmse_deg")) for n in names) + " |")
    L.append("")
    L.append(f"![per-record inclination RMSE]({figures['per_record']})")
    L.append("")
    L.append("## Dynamic error: inclination RMSE [°] by angular rate [°/s]")
    L.append("")
    edges = list(c.rate_bins_deg_s)
    labels = [f"{edges[i]:g}–{edges[i + 1]:g}" if math.isfinite(edges[i + 1]) else f">{edges[i]:g}" for i in range(len(edges) - 1)]
    L.append("| estimator | " + " | ".join(labels) + " |")
    L.append("|---|" + "---:|" * len(labels))
    for name, d in result.dataset.items():
        L.append(f"| {display_name(name)} | " + " | ".join(_f(v) for v in d["dynamic_error_deg"]) + " |")
    L.append("| samples | " + " | ".join(str(n) for n in rate_counts(result)) + " |")
    L.append("")
    L.append(f"![error vs angular rate]({figures['error_vs_rate']})")
    L.append("")
    L.append("## Uncertainty quality (estimators that report σ)")
    L.append("")
    L.append("Tilt error vector (2-D, earth frame) against the per-axis σ: coverage within 1/2/3 σ (expected for a calibrated "
             "2-D Gaussian: 39.3 / 86.5 / 98.9 %), mean NEES ‖e‖²/σ² (expected 2), Spearman correlation of σ and ‖e‖. "
             "Pooled over every scored sample of the records in the summary; in brackets, the mean over records "
             "(each record weighs the same: how the README and `benchmarks/real_vs_peers.py` quote σ).")  # fmt: skip
    L.append("")
    L.append("| estimator | 1σ | 2σ | 3σ [per record] | NEES [per record] | Spearman (per record) |")
    L.append("|---|---:|---:|---:|---:|---:|")
    rows = 0
    for name, d in result.dataset.items():
        u = d.get("uncertainty")
        if u:
            rows += 1
            L.append(f"| {display_name(name)} | {_pct(u['coverage_1sigma'])} | {_pct(u['coverage_2sigma'])} | {_pct(u['coverage_3sigma'])} "
                     f"[{_pct(u.get('coverage_3sigma_per_record_mean'))}] | {_f(u['nees'])} [{_f(u.get('nees_per_record_mean'))}] | "
                     f"{_f(u['spearman_mean'])} |")  # fmt: skip
    if not rows:
        L.append("| (none) | | | | | |")
    L.append("")
    L.append(f"![uncertainty calibration]({figures['uncertainty']})")
    L.append("")
    L.append("## Paired comparison over records (Wilcoxon signed-rank, inclination RMSE)")
    L.append("")
    if result.comparisons:
        L.append(f"A record counts as better only by more than {WIN_MARGIN_DEG:g}° (closer is a tie: the same estimate "
                 "differs by rounding noise).")
        if max(cmp_["n"] for cmp_ in result.comparisons) < 6:
            L.append("With fewer than 6 records no two-sided Wilcoxon signed-rank test can reach p < 0.05: read these "
                     "p-values as too few records, not as no difference.")
        L.append("")
        L.append("| A | B (best other) | n | mean A [°] | mean B [°] | change | A better in (ties) | p (two-sided) | p (A < B) |")
        L.append("|---|---|---:|---:|---:|---:|---:|---:|---:|")
        for cmp_ in result.comparisons:
            ch = cmp_["relative_change"]
            L.append(f"| {display_name(cmp_['a'])} | {display_name(cmp_['b'])} | {cmp_['n']} | {_f(cmp_['mean_a'])} | {_f(cmp_['mean_b'])} | "
                     f"{'–' if ch is None else f'{100 * ch:+.1f} %'} | {cmp_['wins_a']}/{cmp_.get('n_records', len(result.records))} ({cmp_.get('ties', 0)}) | "
                     f"{_f(cmp_['pvalue_two_sided'], 4)} | {_f(cmp_['pvalue_a_less'], 4)} |")  # fmt: skip
        if not any(e["kind"] == "learned" for e in result.estimators):
            L.append("")
            L.append("No learned estimator (TE-PINN / LSTM) was evaluated; the row compares the runner-up with the best.")
    else:
        L.append("Not enough estimators for a comparison.")
    L.append("")
    L.append("## Error vs sensor noise")
    L.append("")
    sw = result.noise_sweep
    if sw:
        L.append(f"White Gaussian noise added to the gyro and accelerometer of the {sw['n_records']} simulated record(s), "
                 f"σ = level × ({sw['base_gyr_sigma_rad_s']:.3g} rad/s, {sw['base_acc_sigma_m_s2']:.3g} m/s²) per sample, on top of "
                 "the simulated sensor noise; then the same evaluation (mean inclination RMSE over records, °).")  # fmt: skip
        L.append("")
        L.append("| estimator | " + " | ".join(f"×{lv:g}" for lv in sw["levels"]) + " |")
        L.append("|---|" + "---:|" * len(sw["levels"]))
        for name, ys in sw["inclination_rmse_deg"].items():
            L.append(f"| {display_name(name)} | " + " | ".join(_f(v) for v in ys) + " |")
        L.append("")
        L.append(f"![error vs noise]({figures['error_vs_noise']})")
    else:
        L.append("Not run (use `--noise-sweep` with simulated records).")
    L.append("")
    L.append("Machine-readable results: [metrics.json](metrics.json). Interactive version (zoom into every record; "
             f"opens offline in a browser): [{HTML_REPORT}]({HTML_REPORT}).")
    L.append("")
    return "\n".join(L)


def report_files() -> tuple[str, ...]:
    """The names of the files a report writes in its folder (those of an earlier report there are replaced)."""
    return ("report.md", HTML_REPORT, "metrics.json", *FIGURES.values())


def write_report(result: EvalResult, out_dir: str | os.PathLike, title: str = "Attitude estimation report") -> list[Path]:
    """Write figures, ``metrics.json`` and (last) ``report.md`` into ``out_dir``; returns the paths.

    An earlier report in ``out_dir`` is taken apart first — its ``report.md`` before anything else, then its other
    files — so that a run stopped half way leaves no ``report.md`` beside the new figures (it left the old one,
    describing other records), and no figure of an earlier run stays (a ``--noise-sweep`` one)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for name in report_files():
        try:
            (out / name).unlink()
        except FileNotFoundError:
            pass
    colours = colour_map(list(result.dataset))
    makers = {
        "quaternion": fig_quaternion, "euler": fig_euler, "inclination_error": fig_inclination_error,
        "error_vs_rate": fig_error_vs_rate, "per_record": fig_per_record, "uncertainty": fig_uncertainty,
    }  # fmt: skip
    if result.noise_sweep:
        makers["error_vs_noise"] = fig_error_vs_noise
    written = []
    for key, fn in makers.items():
        p = out / FIGURES[key]
        fn(result, colours, p)
        written.append(p)
    js = json.dumps(result.to_json(), indent=1, allow_nan=False)
    atomic_write(out / "metrics.json", lambda tmp: Path(tmp).write_text(js, encoding="utf-8"))
    written.append(out / "metrics.json")
    written.append(write_html(result, out / HTML_REPORT, title))
    md = render_markdown(result, FIGURES, title)
    atomic_write(out / "report.md", lambda tmp: Path(tmp).write_text(md, encoding="utf-8"))
    written.append(out / "report.md")
    return written


__all__ = ["write_report", "render_markdown", "colour_map", "FIGURES", "HTML_REPORT", "PAPER_COLOURS"]
