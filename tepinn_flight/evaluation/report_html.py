"""``report.html``: the interactive report beside ``report.md``, one self-contained file.

For every record one zoomable plotly figure (roll, pitch, heading of every estimator against the
reference, and the inclination error over the scored samples; the four panels share the time axis,
a click on a legend entry hides that estimator everywhere), then the summary, per-record and
per-rate tables. plotly.js is embedded, so the file opens offline. Long logs are decimated per
trace to at most ``max_points`` points by min/max buckets (:func:`.plotdata.minmax_indices`), which
keeps every peak; roll and heading are broken at their ±180° wraps. 6-D estimates are shown after
their constant heading alignment (as in the metrics and the PNG figures).
"""

from __future__ import annotations

import html
import math
import os
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from .. import __version__
from ..record import atomic_write
from .left_out import LEFT_OUT_NOTE, kept_out, left_out, summary_heading
from .names import display_name
from .plotdata import PAPER_COLOURS, break_wraps, colour_map, is_9d, minmax_indices

MAX_POINTS = 4000  # per trace, after decimation
ROWS = (("roll", "roll [°]"), ("pitch", "pitch [°]"), ("heading", "heading (yaw) [°]"),
        ("inclination error", "inclination error [°]"))  # fmt: skip

_CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em auto; max-width: 1400px; padding: 0 1em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; }
td.n { text-align: right; font-variant-numeric: tabular-nums; }
th { background: #f3f3f3; }
.note { color: #555; font-size: 0.9em; }
.fig { height: 950px; margin-bottom: 2em; }
"""


def _num(values, nd: int) -> list:
    """Plain JSON numbers (rounded), NaN/inf as null: plotly draws a line break there."""
    a = np.asarray(values, np.float64)
    return [None if not math.isfinite(v) else round(v, nd) for v in a.tolist()]


def _trace_xy(t: np.ndarray, y: np.ndarray, wraps: bool, max_points: int) -> tuple[list, list]:
    i = minmax_indices(y, max_points)  # decimated first, then broken at the wraps the kept points show (as the PNG
    t, y = t[i], y[i]  # figures do): a bucket holding two wraps had kept one break and joined its extremes across ±180°
    if wraps:
        t, y = break_wraps(t, y)
    return _num(t, 3), _num(y, 3)


def record_figure(series: dict, colours: dict[str, str], max_points: int = MAX_POINTS):
    """The plotly figure of one record (``EvalResult.series`` entry)."""
    from plotly.subplots import make_subplots

    from ..quat import quat_to_euler_zyx

    fig = make_subplots(rows=4, cols=1, shared_xaxes=True, vertical_spacing=0.03)
    t = np.asarray(series["t_s"], np.float64)
    mask = np.asarray(series["mask"], bool)
    curves = [("reference", np.asarray(series["q_ref"]), None, True)] + [
        (n, e["q"], e["incl"], e.get("tracks_heading", True)) for n, e in series["est"].items()]
    for name, q, incl, heading in curves:
        ref = name == "reference"
        label = "reference" if ref else display_name(name)
        line = {"color": PAPER_COLOURS["truth"] if ref else colours[name], "width": 1.6 if ref else 1.0}
        if not ref and is_9d(name):
            line["dash"] = "dash"
        roll, pitch, yaw = (np.degrees(a) for a in quat_to_euler_zyx(np.asarray(q, np.float64)))
        rows = [(roll, True), (pitch, False), (yaw if heading else np.full_like(yaw, np.nan), True)]  # (RIANN: no yaw)
        if incl is not None:
            err = np.degrees(np.asarray(incl, np.float64)).copy()
            err[~mask] = np.nan
            rows.append((err, False))
        for r, (y, wraps) in enumerate(rows, start=1):
            x, yy = _trace_xy(t, y, wraps, max_points)
            fig.add_scatter(x=x, y=yy, mode="lines", name=label, legendgroup=label, showlegend=r == 1, line=line,
                            row=r, col=1, hovertemplate=f"{html.escape(label)}<br>t %{{x:.2f}} s: %{{y:.2f}}°<extra></extra>")  # fmt: skip
    for r, (_, title) in enumerate(ROWS, start=1):
        fig.update_yaxes(title_text=title, row=r, col=1)
        if r in (1, 3):  # roll, heading: the whole circle, broken at the wraps
            fig.update_yaxes(range=[-185, 185], tickvals=[-180, -90, 0, 90, 180], row=r, col=1)
    fig.update_xaxes(title_text="t [s]", row=4, col=1)
    fig.update_layout(template="plotly_white", hovermode="closest", margin={"l": 60, "r": 20, "t": 30, "b": 40},
                      legend={"orientation": "h", "y": 1.04, "x": 0}, autosize=True)  # fmt: skip
    return fig


def _table(header: list[str], rows: list[list], numeric_from: int = 1) -> str:
    h = "".join(f"<th>{html.escape(str(c))}</th>" for c in header)
    body = []
    for row in rows:
        cells = [f"<td{' class=n' if i >= numeric_from else ''}>{html.escape(str(c))}</td>" for i, c in enumerate(row)]
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table><thead><tr>{h}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _f(v, nd=2) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{v:.{nd}f}" if isinstance(v, float) else str(v)


def rate_labels(edges) -> list[str]:
    edges = list(edges)
    return [f"{edges[i]:g}–{edges[i + 1]:g}" if math.isfinite(edges[i + 1]) else f">{edges[i]:g}" for i in range(len(edges) - 1)]


def rate_counts(result) -> list[int]:
    """Samples per rate bin: those of the common scoring mask (an estimator scored on it)."""
    ds = result.dataset
    common = [d for d in ds.values() if d.get("coverage_min") is None or d["coverage_min"] >= result.config.min_coverage]
    d = (common or list(ds.values()))[0]
    return list(d["dynamic_error_n"])


RECORD_COLUMNS = ["record", "kind", "IMU rate [Hz]", "reference", "estimation OK", "duration [s]",
                  "log clock at t = 0 [s]", "samples", "scored (common)"]  # fmt: skip


def record_rows(result) -> list[list[str]]:
    """One row per record for the Records table (:data:`RECORD_COLUMNS`): records whose IMU is too
    slow for estimation, or whose reference fails the trust check, say so; those not in the summary means say that."""
    rows = []
    for r in result.records:
        rate = r.get("imu_rate_hz")
        ok = r.get("estimation_ok", True)
        out = kept_out(r)
        why = out or left_out(r)
        gaps, lost = r.get("bridged_gaps", 0), r.get("lost_samples", 0)
        extra = ", ".join([f"{gaps} dropout(s) bridged"] * bool(gaps) + [f"{lost} lost one at a time"] * bool(lost))
        rows.append([r["name"], str(r["source_kind"]), "–" if rate is None else f"{rate:.1f}", str(r.get("reference_source", "–")),
                     ("yes" if ok else "no") + (f": {why}" if why else "") + (", not in the summary" if out else ""),
                     f"{r['duration_s']:.1f}", "–" if r.get("log_clock_at_t0_s") is None else f"{r['log_clock_at_t0_s']:.3f}",
                     f"{r['n_samples']}" + (f" ({extra})" if extra else ""),
                     str(r["n_scored_common"])])  # fmt: skip
    return rows


def kept_out_records(result) -> list[dict]:
    """The records kept out of the summary means (:func:`.left_out.kept_out`)."""
    return [r for r in result.records if kept_out(r)]


def render_html(result, title: str = "Attitude estimation report", max_points: int = MAX_POINTS) -> str:
    """The whole page as a string (plotly.js embedded once, in the first figure)."""
    colours = colour_map(list(result.dataset))
    names = list(result.dataset)
    P = [f"<!DOCTYPE html><html lang=en><head><meta charset=utf-8><title>{html.escape(title)}</title>"
         f"<style>{_CSS}</style></head><body>", f"<h1>{html.escape(title)}</h1>",
         f"<p class=note>tepinn-flight {html.escape(__version__)}, {datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}. "
         f"{len(result.records)} record(s), {len(result.estimators)} estimator(s). Drag to zoom, double-click to reset, "
         "click a legend entry to hide that estimator. Long records are drawn with at most "
         f"{max_points} points per curve (smallest and largest value of every time bucket, so peaks stay). "
         "6-D estimators after their one constant heading alignment per run. The tables are at the end; "
         "report.md has the protocol, the statistics and the figures.</p>"]  # fmt: skip
    if result.notes:
        P.append("<ul class=note>" + "".join(f"<li>{html.escape(n)}</li>" for n in result.notes) + "</ul>")
    P.append("<h2>Records</h2><ul>" + "".join(f"<li><a href='#rec{i}'>{html.escape(s['name'])}</a></li>"
                                               for i, s in enumerate(result.series)) + "</ul>")  # fmt: skip
    P.append(_table(RECORD_COLUMNS, record_rows(result), numeric_from=5))
    first = True
    for i, s in enumerate(result.series):
        P.append(f"<h2 id='rec{i}'>{html.escape(s['name'])}</h2>")
        fig = record_figure(s, colours, max_points)
        P.append(f"<div class=fig>{fig.to_html(full_html=False, include_plotlyjs=first, div_id=f'fig{i}', default_height='100%')}</div>")
        first = False
    # tables
    info = {e["name"]: e for e in result.estimators}
    order = sorted(names, key=lambda n: (result.dataset[n]["inclination_rmse_deg"] is None, result.dataset[n]["inclination_rmse_deg"] or 0))
    slow = kept_out_records(result)
    P.append(f"<h2>{html.escape(summary_heading(result.records))}</h2>")
    P.append(_table(["estimator", "mode", "incl. RMSE [°]", "roll [°]", "pitch [°]", "heading [°]", "total [°]", "|drift| [°/min]"],
                    [[display_name(n), "9-D" if info.get(n, {}).get("uses_mag") else "6-D"] +
                     [_f(result.dataset[n][k]) for k in ("inclination_rmse_deg", "roll_rmse_deg", "pitch_rmse_deg",
                                                         "heading_rmse_deg", "total_rmse_deg", "heading_drift_abs_deg_per_min")]
                     for n in order], numeric_from=2))  # fmt: skip
    if slow:
        P.append("<h2>Records not in the summary</h2>")
        P.append(f"<p class=note>{html.escape(LEFT_OUT_NOTE)}</p>")
        P.append(_table(["record", "why", "IMU rate [Hz]"] + [display_name(n) for n in names],
                        [[r["name"], kept_out(r), _f(r.get("imu_rate_hz"), 1)]
                         + [_f(r["results"][n].get("inclination_rmse_deg")) for n in names] for r in slow]))  # fmt: skip
    P.append("<h2>Per record: inclination RMSE [°]</h2>")
    P.append(_table(["record", "scored samples"] + [display_name(n) for n in names],
                    [[r["name"], r["n_scored_common"]] + [_f(r["results"][n].get("inclination_rmse_deg")) for n in names]
                     for r in result.records]))  # fmt: skip
    P.append("<h2>Dynamic error: inclination RMSE [°] by angular rate [°/s]</h2>")
    labels = rate_labels(result.config.rate_bins_deg_s)
    rows = [[display_name(n)] + [_f(v) for v in result.dataset[n]["dynamic_error_deg"]] for n in names]
    if names:
        rows.append(["samples"] + [str(v) for v in rate_counts(result)])
    P.append(_table(["estimator"] + labels, rows))
    P.append("</body></html>")
    return "\n".join(P)


def write_html(result, path: str | os.PathLike, title: str = "Attitude estimation report", max_points: int = MAX_POINTS) -> Path:
    text = render_html(result, title, max_points)
    path = Path(path)
    atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))
    return path


__all__ = ["render_html", "write_html", "record_figure", "MAX_POINTS", "rate_labels", "rate_counts", "record_rows",
           "kept_out_records", "RECORD_COLUMNS"]
