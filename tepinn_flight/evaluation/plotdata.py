"""What the report's figures (PNG and interactive HTML) share: one fixed colour per method, the
records the time series show, wrap breaks for ±180° angles and min/max decimation for big logs."""

from __future__ import annotations

import math
import re

import numpy as np

from .left_out import kept_out

#: TE-PINN paper colours (truth black, complementary red, LSTM blue, TE-PINN green) and one fixed,
#: well separated colour for every other method, so a method has the same colour in every report
#: whatever else was evaluated. 9-D variants keep their method's colour and are drawn dashed.
PAPER_COLOURS = {"truth": "black", "complementary": "red", "lstm": "blue", "tepinn": "green"}
METHOD_COLOURS = {
    **PAPER_COLOURS,
    "madgwick": "#ff7f0e",  # orange
    "madgwick-original": "#b8860b",  # dark goldenrod
    "ekf": "#9467bd",  # purple
    "vqf": "#8c564b",  # brown
    "offline-vqf": "#17becf",  # cyan
    "riann": "#e377c2",  # pink
    "fusion": "#808000",  # olive
    "mlp": "#7f7f7f",  # grey
}
#: for ids without a fixed colour, or a second estimator of the same method (two checkpoints)
OTHER_COLOURS = ["#ff1493", "#000080", "#008080", "#d2691e", "#6a3d9a", "#2f4f4f", "#b22222", "#4682b4",
                 "#9acd32", "#c71585", "#daa520", "#5f9ea0"]  # fmt: skip


def method_id(name: str) -> str:
    """The method behind an estimator id: ``vqf-9d`` -> ``vqf``, ``tepinn-run2`` -> ``tepinn``,
    ``madgwick-original-9d-beta0.1`` -> ``madgwick-original``; unknown ids come back unchanged."""
    base = re.sub(r"-9d(-beta[0-9.eE+-]+)?$", "", str(name))
    if base in METHOD_COLOURS:
        return base
    for key in sorted(METHOD_COLOURS, key=len, reverse=True):
        if base.startswith(key + "-"):
            return key
    if base.lower().startswith("te-pinn"):
        return "tepinn"
    return base


def is_9d(name: str) -> bool:
    return bool(re.search(r"-9d(-beta[0-9.eE+-]+)?$", str(name)))


def colour_map(names: list[str]) -> dict[str, str]:
    """Estimator id -> colour (a CSS name or ``#rrggbb``, which matplotlib and plotly both read)."""
    out: dict[str, str] = {}
    taken: set[tuple[str, bool]] = set()
    k = 0
    for n in names:
        c = METHOD_COLOURS.get(method_id(n))
        if c is None or (c, is_9d(n)) in taken or c == "black":
            c = OTHER_COLOURS[k % len(OTHER_COLOURS)]
            k += 1
        out[n] = c
        taken.add((c, is_9d(n)))
    return out


# ----------------------------------------------------------------------------- which records to show


def showcase_records(result, max_all: int = 3) -> list[tuple[dict, str]]:
    """The records the time-series figures show, as (series, caption): every record when there are
    at most ``max_all``, else the best and the worst record for TE-PINN by its inclination RMSE
    relative to VQF's on the same record (the first learned estimator and the best non-learned one
    where TE-PINN or VQF was not evaluated)."""
    from .names import display_name

    series = list(result.series)
    if not series:
        return []
    info = {e["name"]: e for e in result.estimators}
    names = list(result.dataset)
    primary = "tepinn" if "tepinn" in names else next((n for n in names if info.get(n, {}).get("kind") == "learned"), None)
    ranked = sorted((n for n in names if n != primary and result.dataset[n]["inclination_rmse_deg"] is not None
                     and info.get(n, {}).get("kind") != "learned"), key=lambda n: result.dataset[n]["inclination_rmse_deg"])  # fmt: skip
    ref = "vqf" if "vqf" in names and primary != "vqf" else (ranked[0] if ranked else None)
    if primary is None:
        primary, ref = ref, None
    by_name = {r["name"]: r for r in result.records}

    def score(s):
        r = by_name.get(s["name"], {}).get("results", {})
        a = (r.get(primary) or {}).get("inclination_rmse_deg") if primary else None
        b = (r.get(ref) or {}).get("inclination_rmse_deg") if ref else None
        why = kept_out(by_name.get(s["name"], {}))
        slow = f" ({why}, not in the summary)" if why else ""
        if a is None or not math.isfinite(a):
            return None, slow.strip(" ()")
        if b is not None and math.isfinite(b) and b > 0:
            return a / b, f"{display_name(primary)} {a:.2f}° = {a / b:.2f}× {display_name(ref)}{slow}"
        return a, f"{display_name(primary)} {a:.2f}°{slow}"

    scored = [(score(s), s) for s in series]
    if len(series) <= max_all:
        return [(s, txt) for (_, txt), s in scored]
    fast = [x for x in scored if not kept_out(by_name.get(x[1]["name"], {}))]
    if fast:  # best and worst among the records in the summary (not those left out of it)
        scored, series = fast, [s for _, s in fast]
    if len(series) <= max_all:
        return [(s, txt) for (_, txt), s in scored]
    ok = [(v, txt, s) for (v, txt), s in scored if v is not None]
    if not ok:
        s = max(series, key=lambda s: int(np.sum(s["mask"])))
        return [(s, "most scored samples")]
    best = min(ok, key=lambda x: x[0])
    worst = max(ok, key=lambda x: x[0])
    out = [(best[2], f"best for {display_name(primary)}: {best[1]}")]
    if worst[2] is not best[2]:
        out.append((worst[2], f"worst for {display_name(primary)}: {worst[1]}"))
    return out


# ----------------------------------------------------------------------------- curves


def break_wraps(t: np.ndarray, y: np.ndarray, jump: float = 180.0) -> tuple[np.ndarray, np.ndarray]:
    """Insert a NaN point (a line break) wherever ``y`` (an angle in degrees within ±180°) jumps by
    more than ``jump`` between samples, so a wrap from +179° to −179° is not drawn as a vertical line."""
    t = np.asarray(t, np.float64)
    y = np.asarray(y, np.float64)
    with np.errstate(invalid="ignore"):
        idx = np.flatnonzero(np.abs(np.diff(y)) > jump) + 1
    if not idx.size:
        return t, y
    return np.insert(t, idx, 0.5 * (t[idx - 1] + t[idx])), np.insert(y, idx, np.nan)


def minmax_indices(y: np.ndarray, max_points: int = 4000) -> np.ndarray:
    """Indices (ascending) of at most ``max_points`` samples of ``y`` that keep its peaks and gaps.

    ``y`` is cut into ``max_points // 3`` buckets of (almost) equal length, bucket ``b`` being
    ``y[n*b//nb : n*(b+1)//nb]``; from each the first smallest and the first largest finite value
    are kept, and the first NaN where the bucket has one (so line breaks survive). Series of at
    most ``max_points`` samples come back whole."""
    y = np.asarray(y, np.float64)
    n = len(y)
    if max_points < 3:
        raise ValueError(f"max_points must be >= 3, got {max_points}")
    if n <= max_points:
        return np.arange(n)
    nb = max_points // 3
    edges = (np.arange(nb + 1) * n) // nb
    bucket = np.repeat(np.arange(nb), np.diff(edges))
    nan = np.isnan(y)
    lo = np.where(nan, np.inf, y)
    hi = np.where(nan, -np.inf, y)
    # sorted by bucket, then value, stable: the first element of each bucket's run is its argmin
    amin = np.lexsort((lo, bucket))[edges[:-1]]
    amax = np.lexsort((-hi, bucket))[edges[:-1]]
    first_nan = np.minimum.reduceat(np.where(nan, np.arange(n), n), edges[:-1])
    first_nan = first_nan[first_nan < edges[1:]]
    return np.unique(np.concatenate([amin, amax, first_nan]))


__all__ = ["PAPER_COLOURS", "METHOD_COLOURS", "colour_map", "method_id", "is_9d", "showcase_records",
           "break_wraps", "minmax_indices"]  # fmt: skip
