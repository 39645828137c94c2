"""Physical check of units and frames: body rates derived from the reference vs the gyro.

A test helper (the ingest and simulation tests check every reader with it); not part of the package.

With the right units and axes, the gyro and the rates differentiated from the reference attitude
agree: per-axis correlation near 1 and least-squares gain near 1. Wrong units (mrad/s read as
rad/s) show as a gain of 1000 or 0.001; a wrong axis as a low or negative correlation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tepinn_flight.quat import body_rates_from_quats
from tepinn_flight.record import FlightRecord


@dataclass(frozen=True)
class RateConsistency:
    corr: np.ndarray  # (3,) per-axis Pearson correlation (NaN on axes that do not move)
    gain: np.ndarray  # (3,) least-squares gain reference_rate ≈ gain · gyro
    moving: np.ndarray  # (3,) bool: axis std of the reference rate above the threshold
    n: int  # number of rate samples used


def rate_consistency(
    rec: FlightRecord, min_std_rad_s: float = 0.05, max_ref_step_s: float | None = None
) -> RateConsistency:
    """Compare the gyro with rates differentiated from ``q_ref`` at the reference's own samples.

    The reference is slerped onto the IMU times in a record; differentiating it over spans where
    it is interpolated would only smooth, so we pick the IMU samples nearest to the reference
    rate (``reference_rate_hz`` in the metadata) and average the gyro between them.
    """
    t, seg = rec.t_s, rec.segment
    q = rec.q_ref_wxyz
    gyr = rec.gyr_rad_s
    ok = np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(gyr), axis=1) & ~rec.clipped
    ref_rate = rec.meta.get("reference_rate_hz") or rec.meta.get("imu_rate_hz") or 1.0
    imu_rate = rec.meta.get("imu_rate_hz") or ref_rate
    stride = max(1, int(round(imu_rate / min(ref_rate, imu_rate))))
    idx = np.flatnonzero(ok)
    ref_rates, gyr_means = [], []
    for s in np.unique(seg[idx]):
        ii = idx[seg[idx] == s][::stride]
        if len(ii) < 3:
            continue
        dt = np.diff(t[ii])
        good = dt > 0
        if max_ref_step_s is not None:
            good &= dt <= max_ref_step_s
        w_ref = body_rates_from_quats(q[ii], dt)
        csum = np.cumsum(np.vstack([np.zeros((1, 3)), gyr]), axis=0)
        a, b = ii[:-1], ii[1:]
        # trapezoidal mean of the gyro samples a..b: what the attitude change between the two
        # reference samples integrates (with snapshot gyros, both ends count half)
        w_gyr = (csum[b + 1] - csum[a] - 0.5 * (gyr[a] + gyr[b])) / (b - a)[:, None]
        ref_rates.append(w_ref[good])
        gyr_means.append(w_gyr[good])
    if not ref_rates:
        nan = np.full(3, np.nan)
        return RateConsistency(nan, nan, np.zeros(3, bool), 0)
    wr = np.concatenate(ref_rates)
    wg = np.concatenate(gyr_means)
    corr = np.full(3, np.nan)
    gain = np.full(3, np.nan)
    moving = wr.std(axis=0) > min_std_rad_s
    for k in range(3):
        if wr[:, k].std() > 0 and wg[:, k].std() > 0:
            corr[k] = np.corrcoef(wr[:, k], wg[:, k])[0, 1]
        denom = np.dot(wg[:, k], wg[:, k])
        if denom > 0:
            gain[k] = np.dot(wg[:, k], wr[:, k]) / denom
    return RateConsistency(corr, gain, moving, len(wr))
