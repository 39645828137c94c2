"""Multiplicative EKF (error-state, 6 states) with gyro-bias estimation and a tilt σ output.

State: attitude ``q_nb`` (body FRD → NED) and gyro bias ``b`` (rad/s); error state
``x = (δθ, δb)`` with ``q_true = q ⊗ exp(δθ)`` (body-frame attitude error) and ``b_true = b + δb``.

- Propagation (every sample): ``q ← q ⊗ exp((ω − b)·dt)``;
  ``P ← F P Fᵀ + Q``, ``F = [[R(ω̂dt)ᵀ, −I·dt], [0, I]]``,
  ``Q = diag(σ_g²·dt·I, σ_bw²·dt·I)``.
- Accelerometer update (6-D): measurement = the unit specific force, model ``h = −R_nbᵀ e_z`` ("up"
  in body), ``H = [−[v]×, 0]`` with ``v = R_nbᵀ e_z``, σ = ``(σ_a + k·| |a| − g |)/g`` per axis,
  skipped beyond ``acc_gate_m_s2``. With ``acc_lowpass_tau_s > 0`` the specific force is first
  low-passed in an inertial frame that follows the bias-corrected gyro alone (VQF's idea, Laidig &
  Seel 2023), so zero-mean linear accelerations cancel before they tilt the estimate.
- The accelerometer cannot observe heading, so the attitude correction's component about the earth
  vertical is dropped (heading then comes from the bias-corrected gyro alone and is not pulled
  around by tilt/heading cross-covariances during large accelerations).
- Rest: when the gyro and accelerometer stay within ``rest_*_dev`` of their 0.5 s low-pass for
  ``rest_min_s``, a zero-angular-rate update (measurement: the low-passed gyro, ``H = [0, I]``)
  makes the bias — including its vertical component, unobservable from the accelerometer when
  level — observable.
- Output σ: per-axis σ of the 2-D tilt error in the earth frame,
  ``sqrt((tr P_θθ − vᵀ P_θθ v)/2)``, the same meaning as TE-PINN's ``sigma_rad`` (calibrated:
  NEES of the tilt error ≈ 2).

Heading starts at yaw 0 (6-D). The defaults are physical guesses (MEMS gyro noise with a vibration
margin; VQF's ``biasClip`` = 2 °/s), not fitted to any test set. The low-pass is 1 s rather than
VQF's 3 s: the inertial frame drifts with the bias error, and a longer low-pass turns that drift
into a tilt lag the filter then mistakes for attitude error (bias error 0.2 °/s at 3 s vs 0.04 °/s
at 1 s on a constant-rate coning motion). :func:`tune` fits the noise parameters on training
records only.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ...conventions import GRAVITY_M_S2
from ...errors import ConfigError
from ...quat_scalar import down_in_body, qmul
from ...small_linalg import mul, mul_bt, solve_in_place, sub_at_bt, symmetrize
from .common import as_tuple4, check_inputs, initial_attitude


@dataclass(frozen=True)
class EkfParams:
    gyro_noise_rad_s_sqrt_hz: float = 1e-3  # angle random walk density incl. unmodelled errors
    bias_walk_rad_s_sqrt_s: float = 1e-5  # gyro bias random walk (rad/s per √s)
    acc_noise_m_s2: float = 1.0  # σ of the (low-passed) accelerometer incl. vibration, per sample
    acc_dynamic_gain: float = 0.0  # extra σ per m/s² of | |a| − g | (unmodelled linear acceleration)
    acc_gate_m_s2: float = math.inf  # skip the accelerometer update beyond this | |a| − g |
    init_attitude_sigma_rad: float = 0.1  # initial σ of each attitude error component
    init_bias_sigma_rad_s: float = 0.02  # initial σ of each bias component (≈ 1.1 °/s)
    bias_limit_rad_s: float = 0.035  # the bias estimate is clipped to ± this (2 °/s, VQF's biasClip)
    acc_lowpass_tau_s: float = 1.0  # > 0: low-pass the specific force in an inertial frame first (s)
    rest_gyr_sigma_rad_s: float = 0.005  # σ of the zero-rate update at detected rest (0: no rest updates)
    rest_gyr_dev_rad_s: float = 0.035  # rest: |ω − lowpass(ω)| below this (2 °/s) ...
    rest_acc_dev_m_s2: float = 0.5  # ... and |a − lowpass(a)| below this ...
    rest_min_s: float = 1.5  # ... for at least this long

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            # (inf only where it means "no limit"; a noise of inf made a filter that trusts nothing, scored as 0 %)
            no_limit = f.name == "acc_gate_m_s2" and v == math.inf
            if not (isinstance(v, (int, float)) and (math.isfinite(v) or no_limit) and v >= 0):
                raise ConfigError(f"ekf.{f.name} must be a finite number >= 0, got {v!r}")
        if self.acc_noise_m_s2 <= 0 or self.init_attitude_sigma_rad <= 0:
            raise ConfigError("ekf.acc_noise_m_s2 and ekf.init_attitude_sigma_rad must be > 0")


class Ekf:
    name = "ekf"

    def __init__(self, params: EkfParams | None = None):
        self.params = params or EkfParams()

    def estimate(self, gyr, acc, t_s, mag=None, q0=None, bias0=None) -> dict:
        """6-D (``mag`` is ignored). Returns ``q_nb_wxyz``, ``bias_rad_s`` and ``sigma_rad``."""
        gyr, acc, dt, _ = check_inputs(gyr, acc, t_s, None)
        if q0 is None:
            q0 = initial_attitude(acc[0]) if len(acc) else [1, 0, 0, 0]
        b0 = (0.0, 0.0, 0.0) if bias0 is None else tuple(float(v) for v in bias0)
        q, b, s = _run(gyr, acc, dt, self.params, as_tuple4(q0), b0)
        return {"q_nb_wxyz": q, "bias_rad_s": b, "sigma_rad": s}


@njit(cache=True)
def _rotate_body(w, x, y, z, rx, ry, rz):
    """``q ⊗ exp(r)`` for a body-frame rotation vector ``r`` (rad), scalars for the per-sample loop.
    Returns (the new q, the increment exp(r)) as (w, x, y, z) tuples."""
    th = math.sqrt(rx * rx + ry * ry + rz * rz)
    if th > 1e-12:
        s = math.sin(0.5 * th) / th
        dw, dx, dy, dz = math.cos(0.5 * th), rx * s, ry * s, rz * s
    else:
        dw, dx, dy, dz = 1.0, 0.5 * rx, 0.5 * ry, 0.5 * rz
    return qmul(w, x, y, z, dw, dx, dy, dz), (dw, dx, dy, dz)


def _run(gyr, acc, dt, p: EkfParams, q, b):
    return _loop(gyr, acc, dt, q, b, p.init_attitude_sigma_rad, p.init_bias_sigma_rad_s, p.gyro_noise_rad_s_sqrt_hz,
                 p.bias_walk_rad_s_sqrt_s, p.bias_limit_rad_s, p.acc_lowpass_tau_s, p.rest_gyr_sigma_rad_s,
                 p.rest_gyr_dev_rad_s, p.rest_acc_dev_m_s2, p.rest_min_s, p.acc_noise_m_s2, p.acc_dynamic_gain,
                 p.acc_gate_m_s2, GRAVITY_M_S2)  # fmt: skip


@njit(cache=True)
def _loop(gyr, acc, dt, q, b, init_att, init_bias, gyro_noise, bias_walk, lim, lp_tau, rest_sigma, rest_gyr_dev,
          rest_acc_dev, rest_min_s, acc_noise, acc_dyn, acc_gate, g):  # fmt: skip
    """The per-sample loop (compiled; float64 arrays in): (q (n, 4), bias (n, 3), σ (n,))."""
    n = len(gyr)
    q_out = np.empty((n, 4))
    b_out = np.empty((n, 3))
    s_out = np.empty(n)
    w, x, y, z = q
    bx, by, bz = b
    P = np.zeros((6, 6))
    for k in range(3):
        P[k, k] = init_att**2
        P[3 + k, 3 + k] = init_bias**2
    F = np.zeros((6, 6))  # (np.eye would compile one more numpy function)
    for k in range(6):
        F[k, k] = 1.0
    T = np.empty((6, 6))  # work buffers, reused for every sample: no allocation in the loop
    pb = np.empty((6, 3))
    S = np.empty((3, 3))
    X = np.empty((3, 6))
    sg2, sb2 = gyro_noise**2, bias_walk**2
    have_lp = False
    lp0 = lp1 = lp2 = 0.0
    qi = (1.0, 0.0, 0.0, 0.0)
    rest_var = rest_sigma**2
    rest_g2, rest_a2 = rest_gyr_dev**2, rest_acc_dev**2
    rest_t = 0.0
    have_l = False
    lg0 = lg1 = lg2 = la0 = la1 = la2 = 0.0
    sqrt = math.sqrt
    vxm = np.zeros((3, 3))
    for i in range(n):
        h = dt[i]
        gx, gy, gz = gyr[i, 0], gyr[i, 1], gyr[i, 2]
        (w, x, y, z), (dw, dx, dy, dz) = _rotate_body(w, x, y, z, (gx - bx) * h, (gy - by) * h, (gz - bz) * h)
        dw0, dx0, dy0, dz0 = dw, dx, dy, dz
        # F: attitude block = R(dq)ᵀ, bias coupling −I·h
        F[0, 0], F[0, 1], F[0, 2] = 1 - 2 * (dy * dy + dz * dz), 2 * (dx * dy + dw * dz), 2 * (dx * dz - dw * dy)
        F[1, 0], F[1, 1], F[1, 2] = 2 * (dx * dy - dw * dz), 1 - 2 * (dx * dx + dz * dz), 2 * (dy * dz + dw * dx)
        F[2, 0], F[2, 1], F[2, 2] = 2 * (dx * dz + dw * dy), 2 * (dy * dz - dw * dx), 1 - 2 * (dx * dx + dy * dy)
        F[0, 3] = F[1, 4] = F[2, 5] = -h
        mul(F, P, T)
        mul_bt(T, F, P)  # F P Fᵀ
        for k in range(3):
            P[k, k] += sg2 * h
            P[3 + k, 3 + k] += sb2 * h
        ax, ay, az = acc[i, 0], acc[i, 1], acc[i, 2]
        if rest_sigma > 0.0:
            al = 1.0 - math.exp(-h / 0.5)
            if not have_l:
                lg0, lg1, lg2, la0, la1, la2 = gx, gy, gz, ax, ay, az
                have_l = True
            else:
                lg0 += al * (gx - lg0)
                lg1 += al * (gy - lg1)
                lg2 += al * (gz - lg2)
                la0 += al * (ax - la0)
                la1 += al * (ay - la1)
                la2 += al * (az - la2)
            dg = (gx - lg0) ** 2 + (gy - lg1) ** 2 + (gz - lg2) ** 2
            da = (ax - la0) ** 2 + (ay - la1) ** 2 + (az - la2) ** 2
            rest_t = rest_t + h if (dg < rest_g2 and da < rest_a2) else 0.0
            if rest_t >= rest_min_s:
                # zero-angular-rate update: the low-passed gyro measures the bias, H = [0, I]
                for k in range(6):
                    for l in range(3):
                        pb[k, l] = P[k, 3 + l]  # P Hᵀ
                        X[l, k] = P[k, 3 + l]
                for k in range(3):
                    for l in range(3):
                        S[k, l] = pb[3 + l, k]  # (H P Hᵀ)ᵀ: the solve takes Sᵀ
                    S[k, k] += rest_var
                solve_in_place(S, X)  # X = S⁻ᵀ pbᵀ = Kᵀ, K = pb S⁻¹
                res0, res1, res2 = lg0 - bx, lg1 - by, lg2 - bz
                sub_at_bt(P, X, pb)  # P − K pbᵀ, K = Xᵀ
                symmetrize(P)
                b0 = X[0, 3] * res0 + X[1, 3] * res1 + X[2, 3] * res2
                b1 = X[0, 4] * res0 + X[1, 4] * res1 + X[2, 4] * res2
                b2 = X[0, 5] * res0 + X[1, 5] * res1 + X[2, 5] * res2
                bx = min(lim, max(-lim, bx + b0))
                by = min(lim, max(-lim, by + b1))
                bz = min(lim, max(-lim, bz + b2))
        # predicted down direction in body
        vx, vy, vz = down_in_body(w, x, y, z)
        if lp_tau > 0.0 and (ax != 0.0 or ay != 0.0 or az != 0.0):
            # VQF's idea: low-pass the specific force in an inertial frame I that follows the
            # bias-corrected gyro only (no corrections), so zero-mean linear accelerations cancel
            qi = qmul(qi[0], qi[1], qi[2], qi[3], dw0, dx0, dy0, dz0)
            gw, gx_, gy_, gz_ = qi
            r00, r01, r02 = 1 - 2 * (gy_ * gy_ + gz_ * gz_), 2 * (gx_ * gy_ - gw * gz_), 2 * (gx_ * gz_ + gw * gy_)
            r10, r11, r12 = 2 * (gx_ * gy_ + gw * gz_), 1 - 2 * (gx_ * gx_ + gz_ * gz_), 2 * (gy_ * gz_ - gw * gx_)
            r20, r21, r22 = 2 * (gx_ * gz_ - gw * gy_), 2 * (gy_ * gz_ + gw * gx_), 1 - 2 * (gx_ * gx_ + gy_ * gy_)
            nx, ny, nz = r00 * ax + r01 * ay + r02 * az, r10 * ax + r11 * ay + r12 * az, r20 * ax + r21 * ay + r22 * az
            if not have_lp:
                lp0, lp1, lp2 = nx, ny, nz
                have_lp = True
            else:
                al = 1.0 - math.exp(-h / lp_tau)
                lp0 += al * (nx - lp0)
                lp1 += al * (ny - lp1)
                lp2 += al * (nz - lp2)
            ax = r00 * lp0 + r10 * lp1 + r20 * lp2
            ay = r01 * lp0 + r11 * lp1 + r21 * lp2
            az = r02 * lp0 + r12 * lp1 + r22 * lp2
            if i % 1000 == 999:  # keep q_I normalised
                nq = 1.0 / sqrt(gw * gw + gx_ * gx_ + gy_ * gy_ + gz_ * gz_)
                qi = (gw * nq, gx_ * nq, gy_ * nq, gz_ * nq)
        na = sqrt(ax * ax + ay * ay + az * az)
        dev = abs(na - g)
        if na > 0.0 and dev <= acc_gate:
            sa = (acc_noise + acc_dyn * dev) / g
            vxm[0, 1], vxm[0, 2], vxm[1, 0], vxm[1, 2], vxm[2, 0], vxm[2, 1] = -vz, vy, vz, -vx, -vy, vx  # [v]×
            for k in range(6):  # pb = P Hᵀ, Hᵀ = [[v]×; 0]
                for l in range(3):
                    sm = 0.0
                    for m in range(3):
                        sm += P[k, m] * vxm[m, l]
                    pb[k, l] = sm
                    X[l, k] = sm
            for k in range(3):  # S = H P Hᵀ = −[v]× pb[:3], stored transposed (the solve takes Sᵀ)
                for l in range(3):
                    sm = 0.0
                    for m in range(3):
                        sm += vxm[l, m] * pb[m, k]
                    S[k, l] = -sm
            S[0, 0] += sa * sa
            S[1, 1] += sa * sa
            S[2, 2] += sa * sa
            solve_in_place(S, X)  # X = S⁻ᵀ pbᵀ = Kᵀ, K = pb S⁻¹
            r = 1.0 / na
            res0, res1, res2 = ax * r + vx, ay * r + vy, az * r + vz  # z − h, h = −v
            ex = X[0, 0] * res0 + X[1, 0] * res1 + X[2, 0] * res2
            ey = X[0, 1] * res0 + X[1, 1] * res1 + X[2, 1] * res2
            ez = X[0, 2] * res0 + X[1, 2] * res1 + X[2, 2] * res2
            b0 = X[0, 3] * res0 + X[1, 3] * res1 + X[2, 3] * res2
            b1 = X[0, 4] * res0 + X[1, 4] * res1 + X[2, 4] * res2
            b2 = X[0, 5] * res0 + X[1, 5] * res1 + X[2, 5] * res2
            sub_at_bt(P, X, pb)  # P − K pbᵀ, K = Xᵀ
            symmetrize(P)
            # the accelerometer cannot observe heading: drop the correction's earth-vertical part
            # (its component along the body-frame down vector v), so heading comes from the gyro only
            pv = ex * vx + ey * vy + ez * vz
            ex, ey, ez = ex - pv * vx, ey - pv * vy, ez - pv * vz
            w, x, y, z = _rotate_body(w, x, y, z, ex, ey, ez)[0]
            bx = min(lim, max(-lim, bx + b0))
            by = min(lim, max(-lim, by + b1))
            bz = min(lim, max(-lim, bz + b2))
            vx, vy, vz = down_in_body(w, x, y, z)
        r = 1.0 / sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w * r, x * r, y * r, z * r
        q_out[i, 0], q_out[i, 1], q_out[i, 2], q_out[i, 3] = w, x, y, z
        b_out[i, 0], b_out[i, 1], b_out[i, 2] = bx, by, bz
        # tilt σ per axis: (tr Pθθ − vᵀ Pθθ v) / 2
        t00, t01, t02, t11, t12, t22 = P[0, 0], P[0, 1], P[0, 2], P[1, 1], P[1, 2], P[2, 2]
        vpv = (vx * vx * t00 + vy * vy * t11 + vz * vz * t22
               + 2.0 * (vx * vy * t01 + vx * vz * t02 + vy * vz * t12))  # fmt: skip
        s_out[i] = sqrt(max(0.0, 0.5 * (t00 + t11 + t22 - vpv)))
    return q_out, b_out, s_out


#: Default tuning grid (the three noise parameters that matter most; 3 × 3 × 3 = 27 runs).
DEFAULT_GRID = {
    "gyro_noise_rad_s_sqrt_hz": (5e-4, 2e-3, 8e-3),
    "acc_noise_m_s2": (0.2, 0.5, 1.5),
    "bias_walk_rad_s_sqrt_s": (2e-5, 1e-4, 5e-4),
}


def tune(records, grid: dict | None = None, base: EkfParams | None = None, warmup_s: float = 5.0,
         progress: bool = False) -> tuple[EkfParams, list[dict]]:  # fmt: skip
    """Grid-search EKF noise parameters on **training** records (never on test records).

    The objective is the mean over records of the 6-D inclination RMSE on the usual scoring mask
    (``valid``, finite reference, after ``warmup_s`` of every segment) — one common parameter set
    for all records, BROAD's TAGP idea. Returns the best parameters and one row per grid point.
    """
    from ...record import EST_Q_COLS
    from ..estimators import FilterEstimator
    from ..harness import scoring_mask
    from ..metrics import error_quat_earth, inclination_error_rad, rmse

    base = base or EkfParams()
    grid = dict(DEFAULT_GRID if grid is None else grid)
    names = list(grid)
    for k in names:
        if k not in {f.name for f in dataclasses.fields(EkfParams)}:
            raise ConfigError(f"unknown EKF parameter '{k}' in the tuning grid")
    records = list(records)
    if not records:
        raise ConfigError("EKF tuning needs at least one training record")
    scored = [(r, m) for r in records for m in [scoring_mask(r, warmup_s)] if m.any()]  # (records with no score: out)
    if not scored:  # (every grid point scored NaN, and the first was reported as "tuned")
        raise ConfigError(f"EKF tuning: no sample left to score on the {len(records)} training record(s): each is "
                          f"shorter than the warm-up ({warmup_s:g} s) or has no reference after it")  # fmt: skip
    records, masks = [r for r, _ in scored], [m for _, m in scored]
    rows = []
    combos = list(itertools.product(*(grid[k] for k in names)))
    it = combos
    if progress:
        import sys

        from tqdm import tqdm

        it = tqdm(combos, desc="tune ekf", unit="params", file=sys.stderr, leave=False)
    for combo in it:
        params = dataclasses.replace(base, **dict(zip(names, combo)))
        est = FilterEstimator(Ekf(params))
        errs = []
        for rec, m in zip(records, masks):
            q = est.estimate(rec)[EST_Q_COLS].to_numpy()
            errs.append(rmse(inclination_error_rad(error_quat_earth(q, rec.q_ref_wxyz)), m))
        rows.append({**dict(zip(names, combo)), "mean_inclination_rmse_deg": float(np.degrees(np.nanmean(errs)))})
    best = min(range(len(rows)), key=lambda i: (np.nan_to_num(rows[i]["mean_inclination_rmse_deg"], nan=np.inf)))
    return dataclasses.replace(base, **{k: rows[best][k] for k in names}), rows
