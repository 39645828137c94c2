"""Raw streams → flight record: one time base, segments, reference and magnetometer on IMU times."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .. import __version__, conventions
from ..errors import NoImuData
from ..quat import quat_canonical, slerp
from ..record import (FORMAT_VERSION, MAX_ABS_TIME_S, MAX_ACC_M_S2, MAX_GNSS_SPEED_M_S, MAX_GYRO_RAD_S,  # noqa: F401
                      MAX_MAG_UT, MAX_QUAT_NORM_ERR, MIN_ESTIMATION_RATE_HZ, FlightRecord, make_frame)  # (the limits: tests read them here)
from ..record_gaps import GAP_PERIODS  # a new segment starts where the IMU step exceeds this many periods
from .streams import GnssVelStream, ImuStream, MagStream, RawLog, RefStream, nominal_period_s


#: What to do about an IMU too slow for estimation, per log format (the note ``ingest`` and ``info`` show).
SLOW_IMU_ADVICE = {
    "tlog": "typical of a telemetry link: use the vehicle's onboard log (DataFlash .bin / ULog) instead, or raise "
            "the IMU stream rate (ArduPilot SRn_RAW_SENS, PX4 `mavlink stream`)",
    "dataflash": "this is the onboard log, logging the IMU slowly: raise ArduPilot's IMU logging rate "
                 "(LOG_BITMASK: the IMU / IMU_FAST bits) and log again",
    "ulog": "this is the onboard log with sensor_combined decimated: log it at full rate (SDLOG_PROFILE: high rate "
            "or system identification) and log again",
}


# --------------------------------------------------------------------------- plausibility
# Physical limits, beyond the range of any sensor a drone or aircraft carries: a sample outside
# them is a corrupt row (DataFlash has no checksums; a flipped byte makes 1e27 rad/s), dropped and
# counted with the reader's corrupt frames. They live with the record format (``record.py``, whose
# ``validate`` refuses a record holding such a value); every reader's streams pass through
# :func:`drop_implausible` on their way into a record.

#: a sample whose time lies this far from both its neighbours' and from the median of the
#: samples around it (in file order) is a corrupt time stamp, not a gap or a reboot:
#: max(SPIKE_MIN_S, SPIKE_PERIODS nominal periods)
SPIKE_MIN_S = 1.0
SPIKE_PERIODS = 50.0


def out_of_order(t: np.ndarray) -> np.ndarray:
    """Samples, in file order, whose time stamp lies outside the interval of their two neighbours' while those are
    in order, and that no swap with a neighbour puts in order: one row stamped early or late by less than a spike (a
    flipped low byte of ``TimeMS``, ±255 ms), which made time go back and forth — a restart of the estimators and an
    output whose time is not increasing (review60). A reboot is not one (time goes back and stays back: the
    neighbours are out of order there), nor two rows logged in each other's place — a boot's first two samples
    swapped, or a row off by under two periods, which reads the same: the segment rule takes those as before."""
    n = len(t)
    out = np.zeros(n, bool)
    if n < 3:
        return out
    a, b, c = t[:-2], t[1:-1], t[2:]
    before = np.r_[-np.inf, t[:-3]]  # the row two before (none for the second row)
    after = np.r_[t[3:], np.inf]  # the row two after
    early = (b < a) & ~((before < b) | (before > a))  # (before > a: a begins after a reversal, a boot's start)
    late = (b > c) & ~((b < after) | (after < c))
    out[1:-1] = (a < c) & (early | late)
    return out


def time_spikes(t: np.ndarray) -> np.ndarray:
    """Samples whose time stamp is corrupt, in file order: a spike (see ``SPIKE_*``) or out of order with both its
    neighbours (:func:`out_of_order`)."""
    n = len(t)
    if n < 3:
        return np.zeros(n, bool)
    p = nominal_period_s(t)
    jump = max(SPIKE_MIN_S, SPIKE_PERIODS * p) if np.isfinite(p) else SPIKE_MIN_S
    prev = np.abs(np.diff(t, prepend=t[1]))  # the first/last sample's missing neighbour: the other one
    nxt = np.abs(np.diff(t, append=t[-2]))
    lonely = (prev > jump) & (nxt > jump)
    if not lonely.any():
        return out_of_order(t)
    half = 4  # the median of 9 samples is undisturbed by up to 4 corrupt ones among them
    idx = np.flatnonzero(lonely)
    lo = np.clip(idx - half, 0, n)
    hi = np.clip(idx + half + 1, 0, n)
    med = np.array([np.median(t[a:b]) for a, b in zip(lo, hi)])
    out = np.zeros(n, bool)
    out[idx] = np.abs(t[idx] - med) > jump
    return out | out_of_order(t)


def _renumber_epochs(t: np.ndarray, ep: np.ndarray, keep: np.ndarray, period: float):
    """Epoch boundaries made by dropped corrupt time stamps (time goes on forward across them once
    the spikes are gone) are joined; returns the IMU's new epochs and a map for other streams."""
    t_k, ep_k = t[keep], ep[keep]
    u = np.unique(ep_k)
    if len(u) < 2:
        return ep_k, (lambda e: np.zeros_like(np.asarray(e)) if len(u) else np.asarray(e))
    jump = max(SPIKE_MIN_S, SPIKE_PERIODS * period) if np.isfinite(period) else SPIKE_MIN_S
    first = np.searchsorted(ep_k, u, side="left") if np.all(np.diff(ep_k) >= 0) else None
    if first is None:  # epochs not in file order: leave them as they are
        return ep_k, (lambda e: np.asarray(e))
    step = t_k[first[1:]] - t_k[first[1:] - 1]
    joined = (step > 0) & (step <= jump)
    new_id = np.concatenate([[0], np.cumsum(~joined)]).astype(np.int64)

    def remap(e):
        e = np.asarray(e, np.int64)
        i = np.clip(np.searchsorted(u, e, side="right") - 1, 0, len(u) - 1)
        return new_id[i]

    return remap(ep_k), remap


def drop_implausible(raw: RawLog, source_path: str | os.PathLike) -> tuple[RawLog, int, list[str]]:
    """``raw`` without its physically impossible rows (the limits above): non-finite or
    out-of-range IMU, magnetometer and reference samples and corrupt time stamps (spikes far from
    their neighbours, which readers take for reboots). Returns the cleaned log, the number of
    IMU rows dropped and notes. No plausible IMU sample left: :class:`NoImuData`."""
    imu = raw.imu
    t = np.asarray(imu.t_s, np.float64)
    gyr = np.asarray(imu.gyr_rad_s, np.float64)
    acc = np.asarray(imu.acc_m_s2, np.float64)
    n = len(t)
    ep = _epoch(n, imu.epoch)
    with np.errstate(invalid="ignore"):
        ok_val = (np.isfinite(t) & (np.abs(t) <= MAX_ABS_TIME_S)
                  & np.all(np.abs(gyr) <= MAX_GYRO_RAD_S, axis=1) & np.all(np.abs(acc) <= MAX_ACC_M_S2, axis=1))  # fmt: skip
    spikes = np.zeros(n, bool)
    idx = np.flatnonzero(ok_val)
    spikes[idx] = time_spikes(t[idx])
    keep = ok_val & ~spikes
    notes: list[str] = []
    n_val, n_spk = int((~ok_val).sum()), int(spikes.sum())
    if n and not keep.any():
        raise NoImuData(
            f"no plausible IMU samples: all {n} rows are corrupt (non-finite, |gyro| > {MAX_GYRO_RAD_S:g} rad/s, "
            f"|acc| > {MAX_ACC_M_S2:g} m/s² or impossible times)", source_path)  # fmt: skip
    if n_val:
        notes.append(f"{n_val} IMU row(s) with impossible values (non-finite, |gyro| > {MAX_GYRO_RAD_S:g} rad/s, "
                     f"|acc| > {MAX_ACC_M_S2:g} m/s² or |t| > {MAX_ABS_TIME_S:g} s) dropped as corrupt")  # fmt: skip
    if n_spk:
        notes.append(f"{n_spk} IMU row(s) with corrupt time stamps (far from or out of order with their neighbours') "
                     "dropped")
    if keep.all():
        new_ep, remap = ep, None
    else:
        new_ep, remap = _renumber_epochs(t, ep, keep, nominal_period_s(t[keep], ep[keep]))
    if remap is not None and imu.epoch is not None and len(np.unique(new_ep)) < len(np.unique(ep[keep])):
        joined = len(np.unique(ep[keep])) - len(np.unique(new_ep))
        notes.append(f"{joined} boot epoch boundary(ies) made by corrupt time stamps joined")
    new_imu = ImuStream(
        t[keep], gyr[keep], acc[keep], None if imu.clipped is None else np.asarray(imu.clipped, bool)[keep],
        None if imu.epoch is None else new_ep, None if imu.gyr_clipped is None else np.asarray(imu.gyr_clipped, bool)[keep],
    )  # fmt: skip

    mag = raw.mag
    if mag is not None and len(mag.t_s):
        mt = np.asarray(mag.t_s, np.float64)
        mv = np.asarray(mag.mag_ut, np.float64)
        with np.errstate(invalid="ignore"):
            bad = np.isfinite(mt) & (np.abs(mt) <= MAX_ABS_TIME_S)
            bad = ~bad | np.any(np.abs(mv) > MAX_MAG_UT, axis=1)  # NaN values stay: holes, not corruption
        m_ep = mag.epoch if mag.epoch is None or remap is None else remap(mag.epoch)
        if bad.any():
            notes.append(f"{int(bad.sum())} magnetometer sample(s) beyond {MAX_MAG_UT:g} µT or at impossible times dropped")
            mag = MagStream(mt[~bad], mv[~bad], None if m_ep is None else np.asarray(m_ep)[~bad])
        elif m_ep is not mag.epoch:
            mag = MagStream(mt, mv, m_ep)
    ref = raw.ref
    if ref is not None and len(ref.t_s):
        rt = np.asarray(ref.t_s, np.float64)
        rq = np.asarray(ref.q_nb_wxyz, np.float64)
        with np.errstate(invalid="ignore"):
            norm_err = np.abs(np.linalg.norm(rq, axis=1) - 1.0)
            bad = ~(np.isfinite(rt) & (np.abs(rt) <= MAX_ABS_TIME_S)) | (norm_err > MAX_QUAT_NORM_ERR)
        r_ep = ref.epoch if ref.epoch is None or remap is None else remap(ref.epoch)
        if bad.any():
            notes.append(f"{int(bad.sum())} reference sample(s) with impossible values (quaternion norm off by "
                         f"> {MAX_QUAT_NORM_ERR:g}, non-finite) or times dropped")  # fmt: skip
            ref = RefStream(rt[~bad], rq[~bad], ref.source, None if r_ep is None else np.asarray(r_ep)[~bad])
        elif r_ep is not ref.epoch:
            ref = RefStream(rt, rq, ref.source, r_ep)
    gnss = raw.gnss
    if gnss is not None and len(gnss.t_s):
        gt = np.asarray(gnss.t_s, np.float64)
        gv = np.asarray(gnss.vel_ne_m_s, np.float64)
        with np.errstate(invalid="ignore"):
            bad = ~(np.isfinite(gt) & (np.abs(gt) <= MAX_ABS_TIME_S) & np.all(np.isfinite(gv), axis=1)
                    & np.all(np.abs(gv) <= MAX_GNSS_SPEED_M_S, axis=1))  # fmt: skip
        g_ep = gnss.epoch if gnss.epoch is None or remap is None else remap(gnss.epoch)
        if bad.any():
            notes.append(f"{int(bad.sum())} GNSS velocity sample(s) non-finite, beyond {MAX_GNSS_SPEED_M_S:g} m/s "
                         "or at impossible times dropped")  # fmt: skip
            gnss = GnssVelStream(gt[~bad], gv[~bad], gnss.source, None if g_ep is None else np.asarray(g_ep)[~bad])
        elif g_ep is not gnss.epoch:
            gnss = GnssVelStream(gt, gv, gnss.source, g_ep)
    if keep.all() and mag is raw.mag and ref is raw.ref and gnss is raw.gnss:
        return raw, 0, notes
    valid = None if raw.valid is None else np.asarray(raw.valid, bool)[keep]
    extra = {k: np.asarray(v)[keep] for k, v in raw.extra.items()}
    return (RawLog(new_imu, mag, ref, gnss=gnss, meta=raw.meta, valid=valid, extra=extra),
            int((~keep).sum()), notes)  # fmt: skip


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
    if len(raw.imu.t_s) == 0:
        raise NoImuData("no IMU samples in the log", source_path)
    raw, n_implausible, plaus_notes = drop_implausible(raw, source_path)
    imu = raw.imu
    n = len(imu.t_s)
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
    gyr_clipped = None if imu.gyr_clipped is None else np.asarray(imu.gyr_clipped, bool)[keep]
    valid = None if raw.valid is None else np.asarray(raw.valid, bool)[keep]
    extra = {k: np.asarray(v)[keep] for k, v in raw.extra.items()}

    period = nominal_period_s(t_src, ep)
    seg = segments_from_time(t_src, ep, period)

    # record time: seconds from the first sample; each later boot epoch continues after the last
    t_rec = np.empty_like(t_src)
    offsets, starts = {}, {}
    end = None
    for e in np.unique(ep):
        m = ep == e
        start = t_src[m].min()  # (a boot's first sample in file order may be a late one)
        off = -start if end is None else end + (period if np.isfinite(period) else 0.0) - start
        offsets[int(e)] = float(off)
        starts[int(e)] = float(start + off)
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

    gnss_vel, gnss_rate = None, None
    if raw.gnss is not None and len(raw.gnss.t_s) > 1:
        g_ep = _epoch(len(raw.gnss.t_s), raw.gnss.epoch)
        g_t = np.asarray(raw.gnss.t_s, np.float64)
        g_period = nominal_period_s(g_t, g_ep)
        gnss_vel = _on_imu_times(t_src, ep, g_t, g_ep, np.asarray(raw.gnss.vel_ne_m_s, float), g_period, False)
        gnss_rate = 1.0 / g_period if np.isfinite(g_period) and g_period > 0 else None
        if not np.isfinite(gnss_vel).any():
            gnss_vel = None

    df = make_frame(
        t_rec, seg, gyr, acc, mag, q_ref, clipped, valid=valid, gyr_clipped=gyr_clipped,
        gyr_bias_rad_s=extra.pop("gyr_bias_rad_s", None), acc_bias_m_s2=extra.pop("acc_bias_m_s2", None),
        gnss_vel_ne_m_s=gnss_vel,
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
        "gnss_source": raw.gnss.source if gnss_vel is not None else "none",
        "gnss_rate_hz": gnss_rate,
        "corrupt_frames": int(raw.meta.get("corrupt_frames", 0)) + n_implausible,
        "implausible_samples_dropped": n_implausible,
        "skipped_frames": int(raw.meta.get("skipped_frames", 0)),
        "duplicate_samples_dropped": n_dup,
        "segments": int(seg[-1]) + 1 if len(seg) else 0,
        "boot_epochs": len(offsets),
        "epoch_time_offsets_s": offsets,
        "epoch_start_t_s": starts,
        "conventions": conventions.describe(),
        "created_by": f"tepinn-flight {__version__}",
    }
    for k, v in raw.meta.items():
        meta.setdefault(k, v)
    notes = list(raw.meta.get("notes", [])) + plaus_notes
    usable = rate is not None and rate >= MIN_ESTIMATION_RATE_HZ
    meta["estimation_ok"] = bool(usable)
    if not usable and rate is None:  # (review60: one sample had been "0.0 Hz ... typical of a telemetry link")
        notes.append(f"{len(df)} IMU sample(s): no rate to read, nothing to estimate (a log cut short?)")
    elif not usable:
        notes.append(f"IMU rate {rate:.1f} Hz is below {MIN_ESTIMATION_RATE_HZ:.0f} Hz: "
                     f"too slow for windowed attitude estimation; {SLOW_IMU_ADVICE.get(meta['source_kind'], 'log the IMU faster')}")
    if raw.ref is None:
        notes.append("no reference attitude in the log: q_ref_* columns are NaN")
    meta["notes"] = notes
    rec = FlightRecord(df, meta)
    rec.validate()
    return rec
