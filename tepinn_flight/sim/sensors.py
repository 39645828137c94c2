"""IMU and magnetometer error model applied to a noise-free :class:`TruthTrajectory` (numpy).

Per axis triad, at the sensor's output rate ``f`` (period ``dt = 1/f``)::

    y_k = Q( sat( M · x_k + b_k + n_k ) )        gyro (x = true rate), accelerometer (x = true
                                                  specific force), both body FRD
    M   = I + diag(s) + C                         s: scale-factor errors, C: cross-axis terms
                                                  (zero diagonal), drawn once per flight
    b_k = b_turn_on + g_k                         turn-on bias (drawn once) + in-run bias
    g_k = φ g_{k-1} + σ_g √(1-φ²) w_k, g_0 = 0    φ = exp(-dt/τ); with τ = inf (default) this is
                                                  the random walk g_k = g_{k-1} + K √dt w_k
    n_k = N √f · v_k                              white noise of density N (ARW / VRW)

``sat`` clips each axis to ``±range`` (such samples set ``clipped``), ``Q`` rounds to the LSB.
The magnetometer reads ``m = S · (R_nbᵀ (B_n + d_n(t))) + h + k·T(t)·u + n`` with soft-iron
``S = I + E`` (``E`` symmetric), hard-iron ``h``, white noise, local disturbance episodes ``d_n``
(earth frame, 1–10 s each) and motor-current interference along a body-fixed unit vector ``u``
proportional to the thrust ``T`` (true specific force along −z, in g), is sampled at its own rate
and held (zero-order hold) onto the IMU samples. The GNSS receiver reports the true horizontal velocity
``latency_s`` late with white noise, ``rate_hz`` fixes a second, linear between fixes on the IMU samples
(:class:`GnssConfig`; what ``ingest`` makes of a log's fixes). Datasheet units in the configuration, converted here:

- ``gyro.arw_deg_sqrt_h`` (°/√h = 60 × °/s/√Hz): N = arw / 60 · π/180 rad/s/√Hz;
- ``accel.vrw_m_s_sqrt_h`` (m/s/√h; 400 µg/√Hz = 0.2354 m/s/√h): N = vrw / 60 m/s²/√Hz;
- ``gyro.bias_rw_deg_h_sqrt_h`` (°/h/√h, rate random walk): K = v · π/180 / 3600 / 60 rad/s/√s;
- ``accel.bias_rw_mg_sqrt_h`` (mg/√h): K = v · 1e-3 g / 60 m/s²/√s;
- turn-on biases in °/s and mg, scale factor and cross-axis in %, ranges in °/s, g, µT.

If the sensor rate is below the truth (dynamics) rate, the truth is decimated by an integer factor:
``anti_alias = "none"`` takes every k-th truth sample, ``"boxcar"`` averages the last k truth
samples (integrate-and-dump, as delta-angle IMUs do; it delays the signal by (k-1)/2 truth samples).
Every random draw comes from a seeded generator in a fixed order, with one independent stream per
sensor, so switching one error term on or off does not change the others' realisations.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ..config import apply_overrides, check, finite_nonneg, from_dict, load_toml, to_dict
from ..conventions import GRAVITY_M_S2
from ..errors import ConfigError
from ..quat import quat_conj, quat_rotate
from . import FLIGHT_SIMS_DIR
from .truth import TruthTrajectory

DEG = math.pi / 180.0

#: Default preset of ``tepinn-flight simulate`` (MPU-6000 class, as seen in an autopilot log).
DEFAULT_PRESET = "consumer"


# --------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class GyroConfig:
    """Gyroscope errors (datasheet units; every σ is 1-sigma per axis)."""

    range_deg_s: float = 2000.0  # full scale ±; beyond it the axis saturates (clipped)
    lsb_deg_s: float = 0.0  # quantization step (0: none); 16-bit at ±2000 °/s is 1/16.4
    arw_deg_sqrt_h: float = 0.0  # angle random walk (white rate noise)
    turn_on_bias_deg_s: float = 0.0  # σ of the constant bias drawn at power-on
    bias_rw_deg_h_sqrt_h: float = 0.0  # rate random walk K of the in-run bias
    bias_corr_time_s: float = math.inf  # inf: pure random walk; finite: Gauss-Markov
    scale_factor_pct: float = 0.0  # σ of each diagonal scale error
    cross_axis_pct: float = 0.0  # σ of each off-diagonal cross-axis coefficient

    def __post_init__(self):
        _check_triad(self, "range_deg_s", "lsb_deg_s")


@dataclass(frozen=True)
class AccelConfig:
    """Accelerometer errors (datasheet units; every σ is 1-sigma per axis)."""

    range_g: float = 16.0
    lsb_mg: float = 0.0  # 16-bit at ±16 g is 0.488 mg
    vrw_m_s_sqrt_h: float = 0.0  # velocity random walk (white noise)
    turn_on_bias_mg: float = 0.0
    bias_rw_mg_sqrt_h: float = 0.0
    bias_corr_time_s: float = math.inf
    scale_factor_pct: float = 0.0
    cross_axis_pct: float = 0.0

    def __post_init__(self):
        _check_triad(self, "range_g", "lsb_mg", 1e-3)  # (a step in mg, the range in g)


@dataclass(frozen=True)
class MagConfig:
    """Magnetometer: rate, range, resolution, white noise, hard and soft iron."""

    enabled: bool = True
    rate_hz: float = 100.0  # held (zero-order hold) onto the IMU samples; capped at the IMU rate
    range_ut: float = 800.0  # ±; the axis is clipped (not flagged in ``clipped``)
    lsb_ut: float = 0.0
    noise_ut: float = 0.0  # white noise σ per sample
    hard_iron_ut: float = 0.0  # σ of each hard-iron offset component
    soft_iron_pct: float = 0.0  # σ of each entry of the symmetric soft-iron deviation E
    # motor-current interference: a body-fixed field proportional to the thrust, read from the true
    # specific force along body z (a multirotor's thrust per mass), µT per g; the direction is drawn
    # once per flight (the power wiring's geometry), the size is this
    motor_ut_per_g: float = 0.0
    # local disturbances (steel structures, cars, power lines passed by): episodes at this rate, each
    # 1–10 s long with a constant earth-frame offset of σ disturbance_ut per component
    disturbances_per_min: float = 0.0
    disturbance_ut: float = 0.0

    def __post_init__(self):
        check(self.rate_hz > 0 and math.isfinite(self.rate_hz), f"'rate_hz' must be > 0, got {self.rate_hz!r}")
        check(self.range_ut > 0, f"'range_ut' must be > 0, got {self.range_ut!r}")
        for name in ("lsb_ut", "noise_ut", "hard_iron_ut", "soft_iron_pct", "motor_ut_per_g", "disturbances_per_min",
                     "disturbance_ut"):  # fmt: skip
            finite_nonneg(name, getattr(self, name))


@dataclass(frozen=True)
class GnssConfig:
    """GNSS receiver velocity over ground (what a u-blox M8/M9 class receiver reports), horizontal:
    a fix every ``1 / rate_hz`` s, the true velocity ``latency_s`` earlier plus white noise of
    σ ``vel_noise_m_s`` per axis, linear between fixes on the IMU samples (as ``ingest`` puts a log's
    fixes there). Its draws come from a stream of their own: the IMU's realisations do not change."""

    enabled: bool = True
    rate_hz: float = 5.0  # 5–10 Hz typical (ArduPilot's default GPS rate 5 Hz)
    vel_noise_m_s: float = 0.05  # u-blox M8: 0.05 m/s speed accuracy (datasheet, 50 %)
    latency_s: float = 0.1  # measurement to log: 0.05–0.2 s

    def __post_init__(self):
        check(self.rate_hz > 0 and math.isfinite(self.rate_hz), f"'rate_hz' must be > 0, got {self.rate_hz!r}")
        for name in ("vel_noise_m_s", "latency_s"):
            finite_nonneg(name, getattr(self, name))


@dataclass(frozen=True)
class SensorConfig:
    """One sensor suite (a TOML preset in ``flight_sims/sensors/``)."""

    name: str = "custom"
    description: str = ""
    rate_hz: float | None = None  # IMU output rate; omitted: the simulation rate
    anti_alias: Literal["none", "boxcar"] = "none"
    # the log, not the sensor: this share of the IMU samples lost one at a time (a logger or a telemetry radio
    # dropping rows: steps of two periods), and the stamps' error (σ, s; clipped at ±0.45 period; each row's truth
    # stays that of its sample). Off in every preset and campaign; `robustness`-style probes of real-log timing
    lost_fraction: float = 0.0
    stamp_jitter_s: float = 0.0
    gyro: GyroConfig = field(default_factory=GyroConfig)
    accel: AccelConfig = field(default_factory=AccelConfig)
    mag: MagConfig = field(default_factory=MagConfig)
    gnss: GnssConfig = field(default_factory=GnssConfig)

    def __post_init__(self):
        if self.rate_hz is not None:
            check(self.rate_hz > 0 and math.isfinite(self.rate_hz), f"'rate_hz' must be > 0, got {self.rate_hz!r}")
        check(0.0 <= self.lost_fraction < 0.5, f"'lost_fraction' must be in [0, 0.5), got {self.lost_fraction!r}")
        finite_nonneg("stamp_jitter_s", self.stamp_jitter_s)

    def to_dict(self) -> dict:
        """Fully resolved parameters (for record metadata); ``bias_corr_time_s`` inf → "inf"."""
        return _json_safe(to_dict(self))


def _check_triad(cfg, range_name: str, lsb_name: str, lsb_in_range_units: float = 1.0) -> None:
    check(getattr(cfg, range_name) > 0, f"'{range_name}' must be > 0, got {getattr(cfg, range_name)!r}")
    for f in cfg.__dataclass_fields__:
        if f == range_name:
            continue
        finite_nonneg(f, getattr(cfg, f), allow_inf=f == "bias_corr_time_s")
    check(cfg.bias_corr_time_s > 0, f"'bias_corr_time_s' must be > 0 (inf for a random walk), got {cfg.bias_corr_time_s!r}")
    lsb = getattr(cfg, lsb_name) * lsb_in_range_units
    # a step past the range read every sample 0 and clipped (session 53)
    check(lsb < getattr(cfg, range_name), f"'{lsb_name}' must be below '{range_name}' (the quantization step is a "
          f"fraction of the range), got {getattr(cfg, lsb_name)!r} against {getattr(cfg, range_name)!r}")  # fmt: skip


def _json_safe(v):
    if isinstance(v, dict):
        return {k: _json_safe(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_json_safe(x) for x in v]
    if isinstance(v, float) and not math.isfinite(v):
        return "inf" if v > 0 else ("-inf" if v < 0 else "nan")
    return v


# --------------------------------------------------------------------------- presets


def presets_dir() -> Path:
    """``flight_sims/sensors`` of the checkout (or ``$TEPINN_FLIGHT_SIMS/sensors``)."""
    root = os.environ.get("TEPINN_FLIGHT_SIMS")
    base = Path(root) if root else FLIGHT_SIMS_DIR
    return base / "sensors"


def list_presets() -> list[str]:
    d = presets_dir()
    return sorted(p.stem for p in d.glob("*.toml")) if d.is_dir() else []


def load_sensor_config(preset: str = DEFAULT_PRESET, overrides: list[str] | tuple[str, ...] = ()) -> SensorConfig:
    """A preset name (``consumer``, ...) or a TOML path, plus ``key=value`` overrides."""
    if preset.endswith(".toml") or os.sep in preset or "/" in preset:
        path = Path(preset)
    else:
        path = presets_dir() / f"{preset}.toml"
        if not presets_dir().parent.is_dir():  # (review60: "known: none found in .../site-packages/flight_sims")
            raise ConfigError(f"no flight_sims folder at {presets_dir().parent}: the simulation's aircraft, sensor "
                              "presets and campaigns come with the project's checkout — install it editable (pip "
                              "install -e ., the README's setup) or set TEPINN_FLIGHT_SIMS to a flight_sims folder")  # fmt: skip
        if not path.exists():
            known = ", ".join(list_presets()) or f"none found in {presets_dir()}"
            raise ConfigError(f"unknown sensor preset '{preset}' (known: {known}; or give a TOML path)")
    data = load_toml(path)
    try:
        cfg = from_dict(SensorConfig, data)
    except ConfigError as exc:
        raise ConfigError(exc.reason, path) from None
    return apply_overrides(cfg, list(overrides)) if overrides else cfg


# --------------------------------------------------------------------------- model


@dataclass
class SensorOutput:
    """Simulated measurements on the sensor's sample times (a subset of the truth's)."""

    t_s: np.ndarray  # (M,)
    index: np.ndarray  # (M,) truth sample index of each output sample
    gyr_rad_s: np.ndarray  # (M, 3)
    acc_m_s2: np.ndarray  # (M, 3)
    mag_ut: np.ndarray | None  # (M, 3) or None when the magnetometer is disabled
    clipped: np.ndarray  # (M,) bool: a gyro or accelerometer axis at its range limit
    gyr_clipped: np.ndarray  # (M,) bool: a gyro axis at its range limit
    gyr_bias_rad_s: np.ndarray  # (M, 3) true total bias (turn-on + in-run)
    acc_bias_m_s2: np.ndarray  # (M, 3)
    q_nb_wxyz: np.ndarray  # (M, 4) true attitude at the output samples
    gnss_vel_ne_m_s: np.ndarray | None = None  # (M, 2) GNSS velocity north, east on the IMU samples (None: off)
    truth: dict = field(default_factory=dict)  # drawn constants: matrices, turn-on biases, iron


def white_noise_sigma(density: float, rate_hz: float) -> float:
    """Per-sample σ of white noise with (one-sided) density ``density`` per √Hz sampled at ``rate_hz``."""
    return density * math.sqrt(rate_hz)


def ar1_process(e: np.ndarray, phi: float, c: float) -> np.ndarray:
    """``b[0] = 0``, ``b[k] = phi·b[k-1] + c·e[k]`` along axis 0, vectorised in stable blocks."""
    e = np.asarray(e, np.float64)
    n = len(e)
    b = np.zeros_like(e)
    if n < 2 or c == 0.0:
        return b
    if phi == 1.0:
        b[1:] = c * np.cumsum(e[1:], axis=0)
        return b
    lam = -math.log(phi)  # > 0
    block = int(max(1, min(n, 20.0 / lam)))  # phi**-block <= e**20: no loss of precision
    prev = np.zeros(e.shape[1:])
    for s in range(1, n, block):
        blk = e[s : s + block]
        j = np.arange(1, len(blk) + 1, dtype=np.float64)
        shape = (-1,) + (1,) * (e.ndim - 1)
        acc = np.cumsum(blk * np.exp(lam * j).reshape(shape), axis=0)
        b[s : s + len(blk)] = np.exp(-lam * j).reshape(shape) * (prev + c * acc)
        prev = b[s + len(blk) - 1]
    return b


def _bias_process(rng, n: int, dt: float, k_si: float, tau_s: float) -> np.ndarray:
    e = rng.standard_normal((n, 3))
    if math.isinf(tau_s):
        return ar1_process(e, 1.0, k_si * math.sqrt(dt))
    phi = math.exp(-dt / tau_s)
    sigma_ss = k_si * math.sqrt(tau_s / 2.0)
    return ar1_process(e, phi, sigma_ss * math.sqrt(1.0 - phi * phi))


def _draw_matrix(rng, scale_sigma: float, cross_sigma: float) -> np.ndarray:
    s = rng.standard_normal(3) * scale_sigma
    c = rng.standard_normal(6) * cross_sigma
    m = np.eye(3)
    m[~np.eye(3, dtype=bool)] = c  # row-major off-diagonals: xy, xz, yx, yz, zx, zy
    m[np.diag_indices(3)] = 1.0 + s
    return m


def _saturate_quantize(y: np.ndarray, rng_limit: float, lsb: float) -> tuple[np.ndarray, np.ndarray]:
    """Clip to the range (flagging samples at the rail) then round to the LSB."""
    rail = math.floor(rng_limit / lsb) * lsb if lsb > 0 else rng_limit
    hit = np.abs(y) >= rail
    y = np.clip(y, -rail, rail)
    if lsb > 0:
        y = np.round(y / lsb) * lsb
    return y, hit


@dataclass(frozen=True)
class _Triad:
    """A gyro or accelerometer in SI units."""

    range_si: float
    lsb_si: float
    white_density_si: float  # per √Hz
    turn_on_sigma_si: float
    bias_rw_si: float  # per √s
    bias_tau_s: float
    scale_sigma: float
    cross_sigma: float


def _gyro_si(g: GyroConfig) -> _Triad:
    return _Triad(
        g.range_deg_s * DEG, g.lsb_deg_s * DEG, g.arw_deg_sqrt_h / 60.0 * DEG, g.turn_on_bias_deg_s * DEG,
        g.bias_rw_deg_h_sqrt_h * DEG / 3600.0 / 60.0, g.bias_corr_time_s, g.scale_factor_pct / 100.0,
        g.cross_axis_pct / 100.0,
    )  # fmt: skip


def _accel_si(a: AccelConfig) -> _Triad:
    mg = 1e-3 * GRAVITY_M_S2
    return _Triad(
        a.range_g * GRAVITY_M_S2, a.lsb_mg * mg, a.vrw_m_s_sqrt_h / 60.0, a.turn_on_bias_mg * mg,
        a.bias_rw_mg_sqrt_h * mg / 60.0, a.bias_corr_time_s, a.scale_factor_pct / 100.0, a.cross_axis_pct / 100.0,
    )  # fmt: skip


def _triad(rng, x_true: np.ndarray, p: _Triad, rate_hz: float):
    """Apply one triad's error model; draws in a fixed order whatever the parameters."""
    n = len(x_true)
    m = _draw_matrix(rng, p.scale_sigma, p.cross_sigma)
    b0 = rng.standard_normal(3) * p.turn_on_sigma_si
    bias = b0 + _bias_process(rng, n, 1.0 / rate_hz, p.bias_rw_si, p.bias_tau_s)
    noise = rng.standard_normal((n, 3)) * white_noise_sigma(p.white_density_si, rate_hz)
    y = x_true @ m.T + bias + noise
    y, hit = _saturate_quantize(y, p.range_si, p.lsb_si)
    return y, hit.any(axis=1), bias, {"matrix": m.tolist(), "turn_on_bias": b0.tolist()}


def _decimation(truth: TruthTrajectory, cfg: SensorConfig) -> tuple[int, float]:
    t = np.asarray(truth.t_s, np.float64)
    f_truth = float(truth.meta.get("rate_hz") or 0.0)
    if f_truth <= 0:
        if len(t) < 2:
            raise ConfigError("truth trajectory needs a rate (meta['rate_hz']) or at least 2 samples")
        f_truth = 1.0 / float(np.median(np.diff(t)))
    f_out = f_truth if cfg.rate_hz is None else float(cfg.rate_hz)
    return decimation_factor(f_truth, f_out), f_out


def decimation_factor(f_truth: float, f_out: float) -> int:
    """The integer factor from the simulation rate to the sensor's; a :class:`ConfigError` where there is none
    (a campaign checks it before its first flight)."""
    k = f_truth / f_out
    if f_out > f_truth * (1 + 1e-9) or abs(k - round(k)) > 1e-6:
        raise ConfigError(
            f"sensor rate_hz {f_out:g} must divide the simulation rate {f_truth:g} Hz by an integer"
        )
    return int(round(k))


def _boxcar(x: np.ndarray, idx: np.ndarray, k: int) -> np.ndarray:
    """Mean of the last k rows up to and including each index (fewer at the start)."""
    cs = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    lo = np.maximum(idx + 1 - k, 0)
    return (cs[idx + 1] - cs[lo]) / (idx + 1 - lo)[:, None]


def apply_sensors(truth: TruthTrajectory, cfg: SensorConfig, rng: np.random.Generator) -> SensorOutput:
    """Simulate the configured IMU (and magnetometer) on top of the noise-free truth."""
    k, rate = _decimation(truth, cfg)
    n_truth = len(truth.t_s)
    idx = np.arange(0, n_truth, k)
    gyr_true = np.asarray(truth.gyr_true_rad_s, np.float64)
    acc_true = np.asarray(truth.acc_true_m_s2, np.float64)
    if k > 1 and cfg.anti_alias == "boxcar":
        gyr_x, acc_x = _boxcar(gyr_true, idx, k), _boxcar(acc_true, idx, k)
    else:
        gyr_x, acc_x = gyr_true[idx], acc_true[idx]
    q = np.asarray(truth.q_nb_wxyz, np.float64)[idx]
    t = np.asarray(truth.t_s, np.float64)[idx]

    seeds = np.random.SeedSequence(rng.integers(0, 2**63, size=4).tolist()).spawn(5)  # spawn(n)'s first
    r_gyr, r_acc, r_mag, r_gnss, r_log = (np.random.default_rng(s) for s in seeds)  # children do not depend on n
    gyr, gclip, gbias, gtruth = _triad(r_gyr, gyr_x, _gyro_si(cfg.gyro), rate)
    acc, aclip, abias, atruth = _triad(r_acc, acc_x, _accel_si(cfg.accel), rate)
    mag, mtruth = _magnetometer(r_mag, t, q, np.asarray(truth.mag_earth_ut, np.float64), cfg.mag, rate, acc_x)
    gnss = _gnss(r_gnss, np.asarray(truth.t_s, np.float64), truth.vel_ned_m_s, t, cfg.gnss)
    out = SensorOutput(
        t_s=t, index=idx, gyr_rad_s=gyr, acc_m_s2=acc, mag_ut=mag, clipped=gclip | aclip, gyr_clipped=gclip,
        gyr_bias_rad_s=gbias, acc_bias_m_s2=abias, q_nb_wxyz=q, gnss_vel_ne_m_s=gnss,
        truth={"gyro": gtruth, "accel": atruth, "mag": mtruth, "rate_hz": rate, "decimation": k},
    )  # fmt: skip
    return _logged(out, r_log, cfg, rate) if cfg.lost_fraction > 0 or cfg.stamp_jitter_s > 0 else out


def _logged(out: SensorOutput, rng, cfg: SensorConfig, rate_hz: float) -> SensorOutput:
    """``out`` as a log holds it (:func:`..record_gaps.logged_timing`): samples lost one at a time, stamps jittered."""
    from ..record_gaps import logged_timing

    keep, stamps = logged_timing(rng, out.t_s, 1.0 / rate_hz, cfg.lost_fraction, cfg.stamp_jitter_s)
    rows = {f: getattr(out, f) for f in ("index", "gyr_rad_s", "acc_m_s2", "mag_ut", "clipped", "gyr_clipped",
                                          "gyr_bias_rad_s", "acc_bias_m_s2", "q_nb_wxyz", "gnss_vel_ne_m_s")}  # fmt: skip
    kept = {f: (None if v is None else v[keep]) for f, v in rows.items()}
    truth = dict(out.truth, lost_samples=int((~keep).sum()), stamp_jitter_s=float(cfg.stamp_jitter_s))
    return SensorOutput(t_s=stamps, truth=truth, **kept)


def _gnss(rng, t_truth, vel_ned_m_s, t_imu, cfg: GnssConfig) -> np.ndarray | None:
    """GNSS horizontal velocity on the IMU samples (NaN before the first fix and after the last; None:
    disabled or no velocity in the truth)."""
    if not cfg.enabled or vel_ned_m_s is None or len(t_truth) < 2:
        return None
    v = np.asarray(vel_ned_m_s, np.float64)[:, :2]
    t_fix = np.arange(t_truth[0] + cfg.latency_s, t_truth[-1] + 1e-9, 1.0 / cfg.rate_hz)
    if len(t_fix) < 2:
        return None
    v_fix = np.stack([np.interp(t_fix - cfg.latency_s, t_truth, v[:, k]) for k in range(2)], 1)
    v_fix += rng.standard_normal(v_fix.shape) * cfg.vel_noise_m_s
    return np.stack([np.interp(t_imu, t_fix, v_fix[:, k], left=np.nan, right=np.nan) for k in range(2)], 1)


def _magnetometer(rng, t, q, b_earth, cfg: MagConfig, imu_rate: float, acc_true=None):
    e = rng.standard_normal(6) * cfg.soft_iron_pct / 100.0
    soft = np.eye(3)
    iu = np.triu_indices(3)
    soft[iu] += e
    soft[(iu[1], iu[0])] = soft[iu]
    hard = rng.standard_normal(3) * cfg.hard_iron_ut
    consts = {"soft_iron": soft.tolist(), "hard_iron_ut": hard.tolist(), "earth_field_ned_ut": b_earth.tolist()}
    if not cfg.enabled or len(t) == 0:
        return None, consts
    rate = min(cfg.rate_hz, imu_rate)
    tick = np.floor((t - t[0]) * rate + 1e-6).astype(np.int64)
    new = np.concatenate([[True], np.diff(tick) != 0])
    at = np.flatnonzero(new)
    b_body = quat_rotate(quat_conj(q[at]), np.broadcast_to(b_earth, (len(at), 3)))
    noise = rng.standard_normal((len(at), 3)) * cfg.noise_ut
    y = b_body @ soft.T + hard + noise
    # (drawn after everything above, and only when switched on: other realisations do not move)
    if cfg.motor_ut_per_g > 0 and acc_true is not None:
        u = rng.standard_normal(3)
        u /= np.linalg.norm(u)
        thrust_g = np.maximum(-np.asarray(acc_true)[at, 2], 0.0) / 9.80665  # specific force along −z, in g
        y = y + cfg.motor_ut_per_g * thrust_g[:, None] * u
        consts["motor_direction"] = u.tolist()
    if cfg.disturbances_per_min > 0 and cfg.disturbance_ut > 0 and len(at):
        dur = t[-1] - t[0]
        n_ep = rng.poisson(cfg.disturbances_per_min * dur / 60.0)
        starts = t[0] + rng.uniform(0.0, dur, n_ep)
        lengths = rng.uniform(1.0, 10.0, n_ep)
        offs = rng.standard_normal((n_ep, 3)) * cfg.disturbance_ut
        d_earth = np.zeros((len(at), 3))
        for s0, ln, off in zip(starts, lengths, offs):
            d_earth[(t[at] >= s0) & (t[at] < s0 + ln)] += off
        y = y + quat_rotate(quat_conj(q[at]), d_earth) @ soft.T
        consts["disturbances"] = [[float(a), float(a + b)] for a, b in zip(starts, lengths)]
    y, _ = _saturate_quantize(y, cfg.range_ut, cfg.lsb_ut)
    hold = np.cumsum(new) - 1  # output sample -> index of the latest magnetometer sample
    consts["rate_hz"] = rate
    return y[hold], consts
