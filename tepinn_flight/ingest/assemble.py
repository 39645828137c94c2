"""Raw streams → flight record: one time base, segments, reference and magnetometer on IMU times."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .. import __version__, conventions
from ..errors import NoImuData
from ..quat import quat_canonical, slerp
from ..record import FORMAT_VERSION, MIN_ESTIMATION_RATE_HZ, FlightRecord, make_frame
from .streams import RawLog, nominal_period_s

#: A new segment starts where the IMU step exceeds this many nominal periods.
GAP_PERIODS = 2.5


def _epoch(arr_len: int, epoch: np.ndarray | None) -> np.ndarray:
    return np.zeros(arr_len, np.int64) if epoch is None else np.asarray(epoch, np.int64)


def segments_from_time(t_s: np.ndarray, epoch: np.ndarray, period_s: float) -> np.ndarray:
    """Segment id per sample: new at a reboot, a time reversal/repeat or a gap > 2.5 periods."""
    if len(t_s) == 0:
        return np.zeros(0, np.int32)
    dt = np.diff(t_s)
    brk = (np.diff(epoch) != 0) | (dt <= 0)
    if np.isfinite(period_s):
        brk |= dt > GAP_PERIODS * period_s
    return np.concatenate([[0], np.cumsum(brk)]).astype(np.int32)


def _clean_knots(t, *vals):
    """Sort by time and drop repeated times (keep the first) for interpolation."""
    order = np.argsort(t, kind="stable")
    t = t[order]
    keep = np.concatenate([[True], np.diff(t) > 0]) if len(t) else np.zeros(0, bool)
    return (t[keep], *[v[order][keep] for v in vals])


def _covered(tq, tk, finite, max_gap):
    """Queries a stream covers: exactly at a finite knot, or between two finite knots that are
    neighbours in the stream (a NaN knot is a hole, not skipped) and at most ``max_gap`` apart."""
    if len(tk) == 0:
        return np.zeros(len(tq), bool)
    j = np.clip(np.searchsorted(tk, tq, side="right") - 1, 0, len(tk) - 1)
    exact = (tq == tk[j]) & finite[j]
    j2 = np.minimum(j, len(tk) - 2) if len(tk) > 1 else j
    nxt = np.minimum(j2 + 1, len(tk) - 1)
    between = (tq > tk[j2]) & (tq < tk[nxt]) & finite[j2] & finite[nxt] & ((tk[nxt] - tk[j2]) <= max_gap)
    return exact | between


def _on_imu_times(t_imu, ep_imu, t_src, ep_src, values, period_src, quaternion):
    """Put a secondary stream (reference or magnetometer) onto the IMU samples, epoch by epoch.

    NaN outside the stream's span, across gaps longer than 2.5 of its periods and next to its own
    NaN samples; values exactly at a stream sample are that sample.
    """
    out = np.full((len(t_imu), values.shape[1]), np.nan)
    max_gap = max(GAP_PERIODS * period_src if np.isfinite(period_src) else 0.0, 1e-9)
    for e in np.unique(ep_imu):
        qi = np.flatnonzero(ep_imu == e)
        si = ep_src == e
        if si.sum() == 0:
            continue
        tk, vk = _clean_knots(t_src[si], values[si])
        finite = np.all(np.isfinite(vk), axis=1)
        if not finite.any():
            continue
        tq = t_imu[qi]
        ok = _covered(tq, tk, finite, max_gap)
        if quaternion:
            res = slerp(tq[ok], tk[finite], vk[finite])
        else:
            res = np.stack([np.interp(tq[ok], tk[finite], vk[finite][:, k]) for k in range(vk.shape[1])], 1)
        out[qi[ok]] = res
    return out


def build_record(raw: RawLog, source_path: str | os.PathLike) -> FlightRecord:
    """Assemble a validated :class:`FlightRecord` from a reader's :class:`RawLog`."""
    imu = raw.imu
    n = len(imu.t_s)
    if n == 0:
        raise NoImuData("no IMU samples in the log", source_path)
    t_src = np.asarray(imu.t_s, np.float64)
    ep = _epoch(n, imu.epoch)

    # drop exact repeats of a sample time inside one epoch (the same message logged twice)
    keep = np.ones(n, bool)
    keep[1:] = ~((np.diff(t_src) == 0) & (np.diff(ep) == 0))
    n_dup = int((~keep).sum())
    t_src, ep = t_src[keep], ep[keep]
    gyr = np.asarray(imu.gyr_rad_s, np.float64)[keep]
    acc = np.asarray(imu.acc_m_s2, np.float64)[keep]
    clipped = None if imu.clipped is None else np.asarray(imu.clipped, bool)[keep]
    valid = None if raw.valid is None else np.asarray(raw.valid, bool)[keep]
    extra = {k: np.asarray(v)[keep] for k, v in raw.extra.items()}

    period = nominal_period_s(t_src, ep)
    seg = segments_from_time(t_src, ep, period)

    # record time: seconds from the first sample; each later boot epoch continues after the last
    t_rec = np.empty_like(t_src)
    offsets = {}
    end = None
    for e in np.unique(ep):
        m = ep == e
        start = t_src[m][0]
        off = -start if end is None else end + (period if np.isfinite(period) else 0.0) - start
        offsets[int(e)] = float(off)
        t_rec[m] = t_src[m] + off
        end = t_rec[m].max()

    q_ref = None
    ref_rate = None
    ref_cover = 0.0
    if raw.ref is not None and len(raw.ref.t_s) > 0:
        r_ep = _epoch(len(raw.ref.t_s), raw.ref.epoch)
        r_t = np.asarray(raw.ref.t_s, np.float64)
        r_period = nominal_period_s(r_t, r_ep)
        q_ref = _on_imu_times(t_src, ep, r_t, r_ep, np.asarray(raw.ref.q_nb_wxyz, float), r_period, True)
        q_ref = quat_canonical(q_ref)
        ref_rate = 1.0 / r_period if np.isfinite(r_period) and r_period > 0 else None
        ref_cover = float(np.mean(np.all(np.isfinite(q_ref), axis=1)))

    mag = None
    if raw.mag is not None and len(raw.mag.t_s) > 0:
        m_ep = _epoch(len(raw.mag.t_s), raw.mag.epoch)
        m_t = np.asarray(raw.mag.t_s, np.float64)
        mag = _on_imu_times(t_src, ep, m_t, m_ep, np.asarray(raw.mag.mag_ut, float), nominal_period_s(m_t, m_ep), False)

    df = make_frame(
        t_rec, seg, gyr, acc, mag, q_ref, clipped, valid=valid,
        gyr_bias_rad_s=extra.pop("gyr_bias_rad_s", None), acc_bias_m_s2=extra.pop("acc_bias_m_s2", None),
    )  # fmt: skip

    rate = 1.0 / period if np.isfinite(period) and period > 0 else None
    meta = {
        "format_version": FORMAT_VERSION,
        "source_file": Path(source_path).name,
        "source_kind": raw.meta.get("source_kind"),
        "vehicle_type": raw.meta.get("vehicle_type", "unknown"),
        "autopilot": raw.meta.get("autopilot", "unknown"),
        "firmware": raw.meta.get("firmware", "unknown"),
        "imu_instance": raw.meta.get("imu_instance", 0),
        "imu_rate_hz": rate,
        "reference_source": raw.ref.source if raw.ref is not None else "none",
        "reference_rate_hz": ref_rate,
        "reference_coverage": ref_cover,
        "corrupt_frames": int(raw.meta.get("corrupt_frames", 0)),
        "skipped_frames": int(raw.meta.get("skipped_frames", 0)),
        "duplicate_samples_dropped": n_dup,
        "segments": int(seg[-1]) + 1 if len(seg) else 0,
        "boot_epochs": len(offsets),
        "epoch_time_offsets_s": offsets,
        "conventions": conventions.describe(),
        "created_by": f"tepinn-flight {__version__}",
    }
    for k, v in raw.meta.items():
        meta.setdefault(k, v)
    notes = list(raw.meta.get("notes", []))
    usable = rate is not None and rate >= MIN_ESTIMATION_RATE_HZ
    meta["estimation_ok"] = bool(usable)
    if not usable:
        notes.append(
            f"IMU rate {0 if rate is None else rate:.1f} Hz is below {MIN_ESTIMATION_RATE_HZ:.0f} Hz: "
            "too slow for windowed attitude estimation (typical of telemetry links); "
            "use the onboard log (DataFlash .bin / ULog) instead"
        )
    if raw.ref is None:
        notes.append("no reference attitude in the log: q_ref_* columns are NaN")
    meta["notes"] = notes
    rec = FlightRecord(df, meta)
    rec.validate()
    return rec
