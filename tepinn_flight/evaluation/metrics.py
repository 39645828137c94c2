"""Attitude-error metrics: pure numpy functions of arrays (no records, no files).

Quaternions are ``(N, 4)`` w, x, y, z, body → earth (NED), Hamilton. Angles are radians unless a
name says ``_deg``. NaN inputs give NaN per-sample errors, which every aggregate skips (``nanmean``),
as BROAD's ``rmse()`` does.

Definitions (BROAD, Laidig et al. 2021, ``example_code/broad_utils.py``):

- earth-frame error ``q_e = q_est ⊗ q_ref⁻¹`` (inputs and output normalised);
- total error ``2·acos(|w|)``; heading error ``2·atan(|z/w|)``; inclination error
  ``2·acos(√(w² + z²))`` — the split of ``q_e`` into a rotation about the earth vertical and a
  rotation about a horizontal axis. It is the same in NED and ENU (both share the vertical axis).
- 6-D heading alignment: ONE constant offset per run, the circular mean δ of the signed heading
  error ``2·atan2(z, w)`` over the scored samples; the estimate becomes ``qz(−δ) ⊗ q_est``. Never per
  window (that would hide drift).
- Mean quaternion error (TE-PINN's "mean quaternion error", reported beside the RMSEs, never as the
  headline): the mean over samples of the sign-invariant Euclidean distance
  ``min(‖q − q_ref‖, ‖q + q_ref‖)`` of unit quaternions (the square root of the network's
  sign-invariant MSE term; dimensionless, ≈ angle/2 for small errors). The mean angle
  ``2·acos(|⟨q, q_ref⟩|)`` is given too.
"""

from __future__ import annotations

import math

import numpy as np

from ..quat import quat_about_z, quat_conj, quat_log, quat_mul, quat_normalize, quat_to_euler_zyx

# ----------------------------------------------------------------------------- per-sample errors


def error_quat_earth(q_est: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """``q_e = q_est ⊗ q_ref⁻¹`` (normalised), the error expressed in the earth frame."""
    q_est = quat_normalize(np.asarray(q_est, np.float64))
    q_ref = quat_normalize(np.asarray(q_ref, np.float64))
    return quat_normalize(quat_mul(q_est, quat_conj(q_ref)))


def total_error_rad(q_e: np.ndarray) -> np.ndarray:
    return 2.0 * np.arccos(np.clip(np.abs(q_e[..., 0]), 0.0, 1.0))


def heading_error_rad(q_e: np.ndarray) -> np.ndarray:
    """Unsigned heading error ``2·atan(|z/w|)`` in [0, π]."""
    return 2.0 * np.arctan2(np.abs(q_e[..., 3]), np.abs(q_e[..., 0]))


def signed_heading_error_rad(q_e: np.ndarray) -> np.ndarray:
    """Signed rotation about the earth vertical, ``2·atan2(z, w)`` wrapped to (−π, π]."""
    return wrap_angle(2.0 * np.arctan2(q_e[..., 3], q_e[..., 0]))


def inclination_error_rad(q_e: np.ndarray) -> np.ndarray:
    return 2.0 * np.arccos(np.clip(np.sqrt(q_e[..., 0] ** 2 + q_e[..., 3] ** 2), 0.0, 1.0))


def tilt_error_vector_rad(q_e: np.ndarray) -> np.ndarray:
    """2-D tilt error (earth x, y components, rad): the inclination part of ``q_e``.

    ``q_e = q_incl ⊗ q_z`` with ``q_z`` the rotation about the vertical; ``q_incl`` has a horizontal
    axis and its angle is the inclination error. Returns ``log(q_incl)[:2]`` (its norm equals
    :func:`inclination_error_rad`).
    """
    w, z = q_e[..., 0], q_e[..., 3]
    n = np.sqrt(w * w + z * z)
    safe = np.where(n > 1e-12, n, 1.0)
    c, s = np.where(n > 1e-12, w / safe, 1.0), np.where(n > 1e-12, z / safe, 0.0)
    q_z_conj = np.stack([c, 0 * c, 0 * c, -s], axis=-1)
    q_incl = quat_mul(q_e, q_z_conj)
    q_incl = np.where(q_incl[..., :1] < 0, -q_incl, q_incl)
    return quat_log(q_incl)[..., :2]


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap to (−π, π]."""
    return -(((-np.asarray(a, np.float64) + np.pi) % (2 * np.pi)) - np.pi)


def euler_errors_rad(q_est: np.ndarray, q_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Wrapped differences of aerospace Z-Y-X roll, pitch and yaw (estimate − reference)."""
    r1, p1, y1 = quat_to_euler_zyx(quat_normalize(np.asarray(q_est, np.float64)))
    r0, p0, y0 = quat_to_euler_zyx(quat_normalize(np.asarray(q_ref, np.float64)))
    return wrap_angle(r1 - r0), wrap_angle(p1 - p0), wrap_angle(y1 - y0)


def quat_distance(q_est: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """Sign-invariant Euclidean distance ``min(‖q − q_ref‖, ‖q + q_ref‖)`` of unit quaternions."""
    a = quat_normalize(np.asarray(q_est, np.float64))
    b = quat_normalize(np.asarray(q_ref, np.float64))
    return np.minimum(np.linalg.norm(a - b, axis=-1), np.linalg.norm(a + b, axis=-1))


def quat_angle_error_rad(q_est: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """``2·acos(|⟨q, q_ref⟩|)`` — equal to the total error of ``q_est ⊗ q_ref⁻¹``."""
    a = quat_normalize(np.asarray(q_est, np.float64))
    b = quat_normalize(np.asarray(q_ref, np.float64))
    return 2.0 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0))


# ----------------------------------------------------------------------------- aggregates


def rmse(err: np.ndarray, mask: np.ndarray | None = None) -> float:
    """``sqrt(nanmean(err²))`` over ``mask`` (NaN when nothing is left)."""
    e = np.asarray(err, np.float64)
    if mask is not None:
        e = e[np.asarray(mask, bool)]
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e * e))) if e.size else float("nan")


def nanmean(x: np.ndarray, mask: np.ndarray | None = None) -> float:
    x = np.asarray(x, np.float64)
    if mask is not None:
        x = x[np.asarray(mask, bool)]
    x = x[np.isfinite(x)]
    return float(np.mean(x)) if x.size else float("nan")


def circular_mean(angles: np.ndarray) -> float:
    a = np.asarray(angles, np.float64)
    a = a[np.isfinite(a)]
    if not a.size:
        return float("nan")
    return float(np.arctan2(np.mean(np.sin(a)), np.mean(np.cos(a))))


def heading_offset_rad(q_est: np.ndarray, q_ref: np.ndarray, mask: np.ndarray | None = None) -> float:
    """The ONE constant heading offset δ of a run: circular mean of the signed heading error."""
    d = signed_heading_error_rad(error_quat_earth(q_est, q_ref))
    return circular_mean(d if mask is None else d[np.asarray(mask, bool)])


def align_heading(q_est: np.ndarray, delta_rad: float) -> np.ndarray:
    """``qz(−δ) ⊗ q_est``: remove a constant heading offset (rotation about the earth vertical)."""
    if not np.isfinite(delta_rad):
        return np.asarray(q_est, np.float64)
    return quat_mul(quat_about_z(np.float64(-delta_rad)), np.asarray(q_est, np.float64))


def drift_rate_deg_per_min(t_s: np.ndarray, signed_err_rad: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Slope (°/min) of the least-squares line through the (unwrapped) signed heading error."""
    t = np.asarray(t_s, np.float64)
    e = np.asarray(signed_err_rad, np.float64)
    m = np.isfinite(t) & np.isfinite(e)
    if mask is not None:
        m &= np.asarray(mask, bool)
    if m.sum() < 3:
        return float("nan")
    t, e = t[m], np.unwrap(e[m])
    tc = t - t.mean()
    den = float(np.sum(tc * tc))
    if den <= 0:
        return float("nan")
    return float(np.degrees(np.sum(tc * (e - e.mean())) / den) * 60.0)


#: Angular-rate bin edges (°/s) of the dynamic error.
RATE_BINS_DEG_S = (0.0, 30.0, 60.0, 120.0, 240.0, 480.0, math.inf)


def binned_sq_error(err_rad: np.ndarray, rate_rad_s: np.ndarray, mask: np.ndarray | None = None,
                    edges_deg_s=RATE_BINS_DEG_S) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Per angular-rate bin: (sum of squared errors, count). Pooling these over records gives
    the dataset's dynamic error per bin, ``sqrt(Σ sq / Σ n)``."""
    e = np.asarray(err_rad, np.float64)
    r = np.degrees(np.asarray(rate_rad_s, np.float64))
    m = np.isfinite(e) & np.isfinite(r)
    if mask is not None:
        m &= np.asarray(mask, bool)
    idx = np.digitize(r[m], np.asarray(edges_deg_s)[1:-1], right=False)
    nb = len(edges_deg_s) - 1
    sq = np.bincount(idx, weights=e[m] ** 2, minlength=nb)[:nb]
    cnt = np.bincount(idx, minlength=nb)[:nb].astype(np.int64)
    return sq, cnt


def binned_rmse(sq: np.ndarray, cnt: np.ndarray) -> np.ndarray:
    cnt = np.asarray(cnt, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, np.sqrt(np.asarray(sq) / np.where(cnt > 0, cnt, 1)), np.nan)


def bias_error_rms(b_est: np.ndarray, b_true: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """RMS gyro-bias error: total ``sqrt(mean ‖b̂ − b‖²)`` and per axis, rad/s."""
    d = np.asarray(b_est, np.float64) - np.asarray(b_true, np.float64)
    m = np.all(np.isfinite(d), axis=1)
    if mask is not None:
        m &= np.asarray(mask, bool)
    if not m.any():
        return {"total": float("nan"), "axes": [float("nan")] * 3}
    d = d[m]
    return {"total": float(np.sqrt(np.mean(np.sum(d * d, axis=1)))), "axes": np.sqrt(np.mean(d * d, axis=0)).tolist()}


# ----------------------------------------------------------------------------- uncertainty

#: Probability that a 2-D isotropic Gaussian error lies within k σ: 1 − exp(−k²/2).
COVERAGE_EXPECTED_2D = {k: 1.0 - math.exp(-k * k / 2.0) for k in (1, 2, 3)}


def uncertainty_metrics(err_vec_rad: np.ndarray, sigma_rad: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """Calibration of a per-axis σ for a 2-D tilt error vector ``e`` (N, 2).

    coverage_k: fraction with ‖e‖ ≤ k·σ (expected 39.3 / 86.5 / 98.9 % for k = 1 / 2 / 3);
    nees: mean ‖e‖²/σ² (expected 2); spearman / pearson: correlation of σ with ‖e‖.
    """
    e = np.asarray(err_vec_rad, np.float64)
    s = np.asarray(sigma_rad, np.float64)
    m = np.all(np.isfinite(e), axis=1) & np.isfinite(s) & (s > 0)
    if mask is not None:
        m &= np.asarray(mask, bool)
    out = {"n": int(m.sum())}
    if out["n"] < 2:
        return out | {f"coverage_{k}sigma": float("nan") for k in (1, 2, 3)} | {"nees": float("nan"),
                                                                               "spearman": float("nan"),
                                                                               "pearson": float("nan")}  # fmt: skip
    r = np.linalg.norm(e[m], axis=1)
    s = s[m]
    for k in (1, 2, 3):
        out[f"coverage_{k}sigma"] = float(np.mean(r <= k * s))
    out["nees"] = float(np.mean((r / s) ** 2))
    out["spearman"] = spearman(s, r)
    out["pearson"] = pearson(s, r)
    return out


def rankdata(x: np.ndarray) -> np.ndarray:
    """Ranks 1..n with ties given their average rank."""
    x = np.asarray(x, np.float64)
    order = np.argsort(x, kind="mergesort")
    xs = x[order]
    ranks = np.empty(len(x), np.float64)
    n = len(x)
    if n == 0:
        return ranks
    starts = np.r_[0, np.flatnonzero(np.diff(xs)) + 1]
    ends = np.r_[starts[1:], n]
    avg = (starts + ends - 1) / 2.0 + 1.0
    ranks[order] = np.repeat(avg, ends - starts)
    return ranks


def pearson(x: np.ndarray, y: np.ndarray) -> float:
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    xc, yc = x - x.mean(), y - y.mean()
    den = math.sqrt(float(np.sum(xc * xc)) * float(np.sum(yc * yc)))
    return float(np.sum(xc * yc) / den) if den > 0 else float("nan")


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    return pearson(rankdata(x), rankdata(y))


# ----------------------------------------------------------------------------- statistics


def wilcoxon_signed_rank(x, y=None, alternative: str = "two-sided") -> dict:
    """Paired Wilcoxon signed-rank test of ``x − y`` (pure numpy; scipy is not needed).

    Zero differences are dropped (scipy's default ``zero_method='wilcox'``); tied |d| get average
    ranks. ``statistic`` is W⁺ (sum of ranks of positive differences; for ``two-sided`` scipy
    reports min(W⁺, W⁻), given here as ``statistic_min``). The p-value is exact (enumerated null
    distribution) for n ≤ 50 without ties, else the normal approximation with tie correction and no
    continuity correction — scipy's ``method='auto'`` choices. ``alternative='less'`` tests whether
    x tends to be smaller than y (e.g. the errors of the better estimator).
    """
    if alternative not in ("two-sided", "less", "greater"):
        raise ValueError(f"alternative must be two-sided, less or greater, not {alternative!r}")
    x = np.asarray(x, np.float64)
    d = x if y is None else x - np.asarray(y, np.float64)
    d = d[np.isfinite(d)]
    d = d[d != 0]
    n = len(d)
    out = {"n": int(n), "alternative": alternative}
    if n == 0:
        return out | {"statistic": float("nan"), "statistic_min": float("nan"), "pvalue": float("nan"), "method": "none"}
    r = rankdata(np.abs(d))
    w_plus = float(np.sum(r[d > 0]))
    w_minus = float(np.sum(r[d < 0]))
    ties = len(np.unique(np.abs(d))) < n
    out["statistic"] = w_plus
    out["statistic_min"] = min(w_plus, w_minus)
    if n <= 50 and not ties:
        # exact null distribution of W⁺: number of subsets of {1..n} with each rank sum
        counts = np.zeros(n * (n + 1) // 2 + 1, np.float64)
        counts[0] = 1.0
        for k in range(1, n + 1):
            counts[k:] = counts[k:] + counts[: len(counts) - k].copy()
        pmf = counts / counts.sum()
        cdf = np.cumsum(pmf)
        w = int(round(w_plus))
        p_le = cdf[w]
        p_ge = 1.0 - (cdf[w - 1] if w > 0 else 0.0)
        if alternative == "less":
            p = p_le
        elif alternative == "greater":
            p = p_ge
        else:
            p = min(1.0, 2.0 * min(p_le, p_ge))
        out["method"] = "exact"
    else:
        mean = n * (n + 1) / 4.0
        _, tcnt = np.unique(np.abs(d), return_counts=True)
        var = n * (n + 1) * (2 * n + 1) / 24.0 - float(np.sum(tcnt**3 - tcnt)) / 48.0
        zval = (w_plus - mean) / math.sqrt(var) if var > 0 else 0.0
        cdf = 0.5 * math.erfc(-zval / math.sqrt(2.0))
        sf = 0.5 * math.erfc(zval / math.sqrt(2.0))
        p = cdf if alternative == "less" else sf if alternative == "greater" else min(1.0, 2.0 * min(cdf, sf))
        out["method"] = "normal"
        out["z"] = float(zval)
    out["pvalue"] = float(p)
    return out


# ----------------------------------------------------------------------------- one run, all metrics


def score_run(t_s, q_est, q_ref, mask, rate_rad_s=None, sigma_rad=None, bias_est=None, bias_true=None,
              runs=None, align: bool = True) -> dict:  # fmt: skip
    """All metrics of one estimate against one reference over the scored samples ``mask``.

    ``runs`` (int per sample, e.g. the record's segment) marks independent filter runs: each gets
    its own constant heading offset (``align=True``, 6-D) and drift slope. Returns plain floats
    (radians) plus the per-bin sums of the dynamic error, and the aligned estimate for plotting.
    """
    t_s = np.asarray(t_s, np.float64)
    q_est = np.asarray(q_est, np.float64)
    q_ref = np.asarray(q_ref, np.float64)
    mask = np.asarray(mask, bool) & np.all(np.isfinite(q_est), axis=1) & np.all(np.isfinite(q_ref), axis=1)
    runs = np.zeros(len(t_s), np.int64) if runs is None else np.asarray(runs)
    q_al = q_est.copy()
    offsets, drifts, drift_w = [], [], []
    for r in np.unique(runs):
        sel = runs == r
        m = mask & sel
        if align:
            delta = heading_offset_rad(q_est[sel], q_ref[sel], m[sel]) if m.any() else float("nan")
            if np.isfinite(delta):
                q_al[sel] = align_heading(q_est[sel], delta)
            offsets.append(delta)
        if m.sum() >= 3:
            e_h = signed_heading_error_rad(error_quat_earth(q_al[sel], q_ref[sel]))
            drifts.append(drift_rate_deg_per_min(t_s[sel], e_h, m[sel]))
            drift_w.append(float(m.sum()))
    q_e = error_quat_earth(q_al, q_ref)
    incl = inclination_error_rad(q_e)
    head = heading_error_rad(q_e)
    tot = total_error_rad(q_e)
    er, ep, ey = euler_errors_rad(q_al, q_ref)
    out = {
        "n_scored": int(mask.sum()),
        "inclination_rmse_rad": rmse(incl, mask),
        "heading_rmse_rad": rmse(head, mask),
        "total_rmse_rad": rmse(tot, mask),
        "roll_rmse_rad": rmse(er, mask),
        "pitch_rmse_rad": rmse(ep, mask),
        "yaw_rmse_rad": rmse(ey, mask),
        "inclination_mean_rad": nanmean(incl, mask),
        "inclination_p95_rad": float(np.nanpercentile(incl[mask], 95)) if mask.any() else float("nan"),
        "mean_quat_distance": nanmean(quat_distance(q_al, q_ref), mask),
        "mean_quat_angle_rad": nanmean(quat_angle_error_rad(q_al, q_ref), mask),
        "heading_offsets_rad": offsets,
        "heading_drift_deg_per_min": (float(np.average(drifts, weights=drift_w))
                                      if drifts and np.all(np.isfinite(drifts)) else float("nan")),  # fmt: skip
    }
    if rate_rad_s is not None:
        sq, cnt = binned_sq_error(incl, rate_rad_s, mask)
        out["rate_bins_sq"] = sq.tolist()
        out["rate_bins_n"] = cnt.tolist()
    if sigma_rad is not None and np.any(np.isfinite(sigma_rad)):
        out["uncertainty"] = uncertainty_metrics(tilt_error_vector_rad(q_e), sigma_rad, mask)
    if bias_est is not None and bias_true is not None:
        out["gyr_bias"] = bias_error_rms(bias_est, bias_true, mask)
    out["_q_aligned"] = q_al
    out["_inclination_rad"] = incl
    return out
