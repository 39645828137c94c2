"""Statistics of a flight record, what ``info`` reports: pure computation on the record, no printing
(:mod:`tepinn_flight.cli.summary` renders them)."""

from __future__ import annotations

import numpy as np

from .record import SIMULATED_KINDS, FlightRecord
from .record_gaps import LOST_STEP_PERIODS, MAX_BRIDGED_GAP_S, inner_steps, is_bridgeable, lost_steps, record_period_s


def summarize(rec: FlightRecord) -> dict:
    """Duration, rates, segments and gaps, lost samples and the stamps' jitter inside segments, max angular
    rate, clipping, reference coverage and whether the
    reference turns as the gyro does and agrees with the accelerometer's gravity (:mod:`.model.reference_trust`)."""
    t = rec.t_s
    seg = rec.segment
    m = rec.meta
    gyr = rec.gyr_rad_s
    out: dict = {
        "source_file": m.get("source_file"),
        "source_kind": m.get("source_kind"),
        "format": m.get("format", m.get("source_kind")),
        "vehicle_type": m.get("vehicle_type"),
        "autopilot": m.get("autopilot"),
        "firmware": m.get("firmware"),
        "samples": int(len(rec)),
        "imu_instance": m.get("imu_instance"),
        "imu_instances": m.get("imu_instances"),
        "imu_rate_hz": m.get("imu_rate_hz"),
        "estimation_ok": m.get("estimation_ok"),
        "reference_source": m.get("reference_source"),
        "reference_rate_hz": m.get("reference_rate_hz"),
        "level_trim_rad": m.get("level_trim_rad"),
        "imu_time_field": m.get("imu_time_field"),
        "boot_epochs": m.get("boot_epochs"),
        "reference_coverage": float(np.mean(np.all(np.isfinite(rec.q_ref_wxyz), axis=1))) if len(rec) else 0.0,
        "corrupt_frames": m.get("corrupt_frames", 0),
        "skipped_frames": m.get("skipped_frames", 0),
        "duplicate_samples_dropped": m.get("duplicate_samples_dropped", 0),
        "notes": m.get("notes", []),
    }
    if m.get("source_kind") in SIMULATED_KINDS:  # what was flown (review60: only in the Parquet metadata)
        flown = [str(x[2]) for x in (m.get("maneuvers") or []) if isinstance(x, (list, tuple)) and len(x) == 3]
        out["simulated"] = {k: m.get(k) for k in ("aircraft", "seed", "sensor_preset", "turbulence", "termination")}
        out["simulated"]["maneuvers"] = flown
    if len(rec) == 0:
        out.update(duration_s=0.0, segments=0, gaps=[], max_rate_deg_s=0.0, clipped_samples=0)
        return out
    seg_ids = np.unique(seg)
    durations = [float(t[seg == s][-1] - t[seg == s][0]) for s in seg_ids]
    breaks = np.flatnonzero(np.diff(seg) != 0)
    period = record_period_s(rec)
    gaps = [{"at_s": float(t[i]), "gap_s": float(t[i + 1] - t[i]),
             "bridged": is_bridgeable(float(t[i + 1] - t[i]), period)} for i in breaks]  # fmt: skip
    norm = np.linalg.norm(gyr, axis=1)
    slow = slower_stretches(t, breaks, [g["bridged"] for g in gaps], period)
    steps = inner_steps(rec)
    usual = steps[(steps > 0.5) & (steps <= LOST_STEP_PERIODS)]
    out.update(
        steps=int(steps.size),  # inside segments: samples lost one at a time, and the stamps' jitter
        lost_steps=lost_steps(steps),
        step_jitter=float(np.std(usual)) if usual.size > 1 else 0.0,
    )
    out.update(
        duration_s=float(sum(durations)),
        span_s=float(t[-1] - t[0]),
        log_clock_s=_log_clock_span(t, m),
        segments=int(len(seg_ids)),
        gaps=gaps,
        bridged_gaps=int(sum(g["bridged"] for g in gaps)),
        slower_stretches=slow,
        acc_noise_m_s2=sample_noise(rec.acc_m_s2, seg, period),
        gyr_noise_deg_s=None if (g_n := sample_noise(gyr, seg, period)) is None else float(np.degrees(g_n)),
        max_bridged_gap_s=MAX_BRIDGED_GAP_S,
        max_rate_deg_s=float(np.degrees(np.nanmax(norm))) if np.any(np.isfinite(norm)) else float("nan"),
        max_axis_rate_deg_s=[round(float(np.degrees(np.nanmax(a))), 1) if np.any(np.isfinite(a)) else float("nan")
                             for a in np.abs(gyr).T],  # (an all-NaN axis: NaN, without numpy's warning)
        clipped_samples=int(rec.clipped.sum()),
        has_mag=bool(np.any(np.isfinite(rec.mag_ut))),
    )
    if "gyr_clipped" in rec.data:
        out["gyr_clipped_samples"] = int(rec.gyr_clipped.sum())
    vel = rec.gnss_vel_ne_m_s
    if vel is not None:  # what the GNSS-aided tilt reads
        ok = np.all(np.isfinite(vel), axis=1)
        out["gnss"] = {"source": m.get("gnss_source"), "rate_hz": m.get("gnss_rate_hz"), "coverage": float(ok.mean()),
                       "max_speed_m_s": float(np.hypot(vel[ok, 0], vel[ok, 1]).max()) if ok.any() else 0.0}  # fmt: skip
    if "valid" in rec.data:
        out["valid_fraction"] = float(rec.valid.mean())
    if out["reference_coverage"] > 0:  # is the reference the IMU's attitude (an autopilot estimator that diverged?)
        from .model.reference_trust import check_reference

        chk = check_reference(rec)
        out["reference_check"] = {"trusted": chk.trusted, "turn_share": chk.turn_share, "intervals": chk.intervals,
                                  "gravity_deg": chk.gravity_deg, "quiet_s": chk.quiet_s, "lag_s": chk.lag_s,
                                  "lag_bracketed": chk.lag_bracketed, "frame_deg": chk.frame_deg,
                                  "rate_note": chk.rate_note, "line": chk.describe()}  # fmt: skip
    return out


#: A run of at least this many consecutive breaks, each one step long, is a stretch logged at a lower rate.
MIN_SLOWER_RUN = 20


def slower_stretches(t: np.ndarray, breaks: np.ndarray, bridged: list, period: float) -> list[dict]:
    """Stretches where the IMU was logged at a lower rate than the record's nominal one (a GCS lowering a
    tlog's stream rate): runs of ≥ :data:`MIN_SLOWER_RUN` consecutive breaks (every step a break by the
    nominal period), all bridged → ``[{"from_s", "to_s", "steps", "first_break", "rate_hz"}]`` (``first_break``: the
    index of its first break among the record's breaks). The estimators fill such a
    stretch at the nominal rate, as any short dropout; ``info`` says it in one line instead of one per break."""
    out: list[dict] = []
    if len(breaks) < MIN_SLOWER_RUN or not (np.isfinite(period) and period > 0):
        return out
    b = np.asarray(breaks)
    ok = np.asarray(bridged, bool)
    cut = np.flatnonzero((np.diff(b) != 1) | ~ok[1:] | ~ok[:-1]) + 1  # runs of consecutive, bridged breaks
    for run in np.split(np.arange(len(b)), cut):
        if len(run) < MIN_SLOWER_RUN or not ok[run].all():
            continue
        i0, i1 = int(b[run[0]]), int(b[run[-1]]) + 1
        out.append({"from_s": float(t[i0]), "to_s": float(t[i1]), "steps": int(len(run)), "first_break": int(run[0]),
                    "rate_hz": float(1.0 / np.median(np.diff(t[i0 : i1 + 1])))})  # fmt: skip
    return out


def second_differences(values: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """(n, k) x[i−1] − 2x[i] + x[i+1] where the three samples share a segment, NaN elsewhere (a segment's ends):
    white noise of σ gives σ√6 per axis, smooth motion next to nothing."""
    x = np.asarray(values, np.float64)
    out = np.full(x.shape, np.nan)
    if len(x) >= 3:
        seg = np.asarray(seg)
        same = (seg[:-2] == seg[1:-1]) & (seg[1:-1] == seg[2:])
        out[1:-1] = np.where(same[:, None], x[:-2] - 2.0 * x[1:-1] + x[2:], np.nan)
    return out


def sample_noise(values: np.ndarray, seg: np.ndarray, period: float, window_s: float = 1.0) -> float | None:
    """A sensor's noise per sample and axis, as its second differences show it (:func:`second_differences`): in
    windows of ``window_s``, √(mean over axes of their variance / 6), the median over the windows (None: less than
    one window). A vibrating frame shows here in m/s² on the accelerometer."""
    if not (np.isfinite(period) and period > 0) or len(values) < 3:
        return None
    d = second_differences(values, seg)
    d = d[np.all(np.isfinite(d), axis=1)]
    k = max(8, int(round(window_s / period)))
    m = len(d) // k
    if m < 1:
        return None
    v = d[: m * k].reshape(m, k, -1).var(axis=1).mean(axis=1) / 6.0
    return float(np.sqrt(np.median(v)))


def centred_mean(t_s: np.ndarray, values: np.ndarray, seg: np.ndarray, window_s: float) -> np.ndarray:
    """(n,) the mean of the finite ``values`` over a centred ``window_s`` around each sample, within its segment
    (NaN where the window holds none)."""
    from .record import segment_slices

    t = np.asarray(t_s, np.float64)
    v = np.asarray(values, np.float64)
    good = np.isfinite(v)
    out = np.full(len(t), np.nan)
    for s in segment_slices(np.asarray(seg)):
        tt = t[s]
        c = np.r_[0.0, np.cumsum(np.where(good[s], v[s], 0.0))]
        k = np.r_[0, np.cumsum(good[s])]
        lo = np.searchsorted(tt, tt - 0.5 * window_s, "left")
        hi = np.searchsorted(tt, tt + 0.5 * window_s, "right")
        cnt = k[hi] - k[lo]
        with np.errstate(invalid="ignore", divide="ignore"):
            out[s] = (c[hi] - c[lo]) / cnt
    return out


def running_sample_noise(t_s: np.ndarray, values: np.ndarray, seg: np.ndarray, window_s: float = 1.0) -> np.ndarray:
    """(n,) a sensor's noise per sample and axis around each sample: √(mean over the axes and over a centred
    ``window_s`` within the segment of the squared :func:`second_differences` / 6) — :func:`sample_noise`'s reading,
    sample by sample (σ's vibration term, rule 41). 0 where the window holds no finite second difference."""
    d = second_differences(values, seg)
    m = centred_mean(t_s, np.mean(d * d, axis=1) / 6.0, seg, window_s)
    return np.where(np.isfinite(m), np.sqrt(m), 0.0)


def _log_clock_span(t: np.ndarray, meta: dict) -> list[float] | None:
    """[first, last] sample on the log's own clock (:mod:`.log_clock`), or None where the record has none."""
    from .log_clock import log_clock_s

    c = log_clock_s(t[[0, -1]], meta)
    return None if c is None else [float(c[0]), float(c[1])]
