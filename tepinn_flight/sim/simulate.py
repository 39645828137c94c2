"""One simulated flight → a :class:`~tepinn_flight.record.FlightRecord` with its truths.

:func:`simulate_record` flies the aircraft (noise-free truth from JSBSim, :mod:`.flight`) and applies
the sensor model (:mod:`.sensors`); :func:`record_from_truth` is the pure second half, usable with
any :class:`TruthTrajectory`. One ``seed`` fixes both: the dynamics get ``seed`` itself, the sensors
an independent stream ``SeedSequence(seed, spawn_key=(SENSOR_STREAM,))``.

The record carries the truths: ``q_ref_*`` = true attitude, ``gyr_bias_*`` / ``acc_bias_*`` = true
time-varying biases, and metadata naming the aircraft, maneuvers flown, turbulence, sensor preset with
the full resolved sensor parameters and the constants drawn for this flight (``sensor_truth``:
scale/cross-axis matrices, turn-on biases, hard/soft iron), seed and termination.
"""

from __future__ import annotations

import json
import math

import numpy as np

from .. import __version__, conventions
from ..errors import ConfigError
from ..quat import quat_canonical, quat_normalize
from ..record import FORMAT_VERSION, MIN_ESTIMATION_RATE_HZ, FlightRecord, make_frame
from .sensors import DEFAULT_PRESET, SensorConfig, apply_sensors, load_sensor_config
from .truth import TruthTrajectory

#: spawn_key of the sensor-noise stream derived from a flight's seed.
SENSOR_STREAM = 1


def sensor_rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(SENSOR_STREAM,)))


#: the most samples one flight may hold: a flight is made in memory, ~0.7 kB a sample at its peak (truth,
#: sensors, record; measured on the F450 at 400 Hz), so this is ~7 GB: 6.9 h at 400 Hz
MAX_FLIGHT_SAMPLES = 10_000_000


def check_flight_args(duration_s: float, rate_hz: float, seed: int) -> None:
    """The checks that do not need JSBSim (so a bad command line fails before any work)."""
    if not (isinstance(duration_s, (int, float)) and math.isfinite(duration_s) and duration_s > 0):
        raise ConfigError(f"duration must be a positive number of seconds, got {duration_s!r}")
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and rate_hz > 0):
        raise ConfigError(f"rate must be a positive number of Hz, got {rate_hz!r}")
    if duration_s * rate_hz > MAX_FLIGHT_SAMPLES:
        raise ConfigError(
            f"a flight of {duration_s:g} s at {rate_hz:g} Hz would hold {duration_s * rate_hz:,.0f} samples; one flight "
            f"holds at most {MAX_FLIGHT_SAMPLES:,} (it is made in memory, ~0.7 kB a sample): fly several shorter "
            f"ones (a campaign's repeats), at most {MAX_FLIGHT_SAMPLES / rate_hz:,.0f} s each at this rate")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")


def resolve_sensor(sensor: SensorConfig | str = DEFAULT_PRESET, overrides=()) -> SensorConfig:
    if isinstance(sensor, SensorConfig):
        if overrides:
            from ..config import apply_overrides

            return apply_overrides(sensor, list(overrides))
        return sensor
    return load_sensor_config(sensor, list(overrides))


def simulate_record(
    aircraft: str,
    duration_s: float,
    rate_hz: float = 400.0,
    seed: int = 0,
    sensor: SensorConfig | str = DEFAULT_PRESET,
    sensor_overrides: list[str] | tuple[str, ...] = (),
    maneuvers: list[str] | None = None,
    turbulence: str | None = None,
) -> FlightRecord:
    """Fly ``aircraft`` for ``duration_s`` at ``rate_hz`` and return the sensor record (not written)."""
    check_flight_args(duration_s, rate_hz, seed)
    cfg = resolve_sensor(sensor, sensor_overrides)
    from .flight import fly  # JSBSim only when flying

    truth = fly(aircraft, float(duration_s), rate_hz=float(rate_hz), seed=int(seed),
                maneuvers=list(maneuvers) if maneuvers else None, turbulence=turbulence)  # fmt: skip
    extra = {
        "requested_duration_s": float(duration_s),
        "requested_maneuvers": list(maneuvers) if maneuvers else None,
        "requested_turbulence": turbulence,
        "sensor_overrides": list(sensor_overrides),
    }
    return record_from_truth(truth, cfg, int(seed), extra_meta=extra)


def record_from_truth(
    truth: TruthTrajectory, cfg: SensorConfig, seed: int, extra_meta: dict | None = None
) -> FlightRecord:
    """Apply the sensor model (stream derived from ``seed``) and build the validated record."""
    if len(truth.t_s) == 0:
        raise ConfigError("the simulated flight has no samples")
    out = apply_sensors(truth, cfg, sensor_rng(seed))
    q = quat_canonical(quat_normalize(out.q_nb_wxyz))
    df = make_frame(
        out.t_s - out.t_s[0], np.zeros(len(out.t_s), np.int32), out.gyr_rad_s, out.acc_m_s2, out.mag_ut, q,
        out.clipped, gyr_clipped=out.gyr_clipped, gyr_bias_rad_s=out.gyr_bias_rad_s, acc_bias_m_s2=out.acc_bias_m_s2,
        gnss_vel_ne_m_s=out.gnss_vel_ne_m_s,
    )  # fmt: skip
    tm = _jsonable(truth.meta)
    rate = float(out.truth["rate_hz"])
    termination = str(tm.get("termination", "completed"))
    notes = []
    if termination != "completed":
        notes.append(f"flight ended early: {termination}")
    if out.clipped.any():
        notes.append(f"{int(out.clipped.sum())} samples at a gyro/accelerometer range limit (clipped)")
    aircraft = tm.get("aircraft", "unknown")
    meta = {
        "format_version": FORMAT_VERSION,
        "source_file": f"jsbsim:{aircraft}:seed={seed}",
        "source_kind": "jsbsim",
        "format": "jsbsim",
        "vehicle_type": tm.get("vehicle_type", "unknown"),
        "autopilot": "none (simulated)",
        "firmware": f"jsbsim {tm.get('jsbsim_version', tm.get('jsbsim', 'unknown'))}",
        "imu_instance": 0,
        "imu_rate_hz": rate,
        "reference_source": "jsbsim-truth",
        "reference_rate_hz": rate,
        "reference_coverage": 1.0,
        "gnss_source": "simulated" if out.gnss_vel_ne_m_s is not None else "none",
        "gnss_rate_hz": float(cfg.gnss.rate_hz) if out.gnss_vel_ne_m_s is not None else None,
        "corrupt_frames": 0,
        "skipped_frames": 0,
        "segments": 1,
        "estimation_ok": bool(rate >= MIN_ESTIMATION_RATE_HZ),
        "conventions": conventions.describe(),
        "created_by": f"tepinn-flight {__version__}",
        "aircraft": aircraft,
        "seed": int(seed),
        "termination": termination,
        "duration_s": float(out.t_s[-1] - out.t_s[0]) if len(out.t_s) > 1 else 0.0,
        "maneuvers": [[float(a), float(b), str(n)] for a, b, n in truth.maneuvers],
        "turbulence": tm.get("turbulence"),
        "sensor_preset": cfg.name,
        "sensor": cfg.to_dict(),
        "sensor_truth": _jsonable(out.truth),
        "mag_earth_ned_ut": np.asarray(truth.mag_earth_ut, float).tolist(),
        "simulation": tm,
        "notes": notes,
    }
    for k, v in (extra_meta or {}).items():
        meta.setdefault(k, _jsonable(v))
    rec = FlightRecord(df, meta)
    rec.validate()
    return rec


def _jsonable(v):
    """Plain JSON types (numpy scalars/arrays → Python, non-finite floats → strings)."""

    def default(o):
        if isinstance(o, np.integer):
            return int(o)
        if isinstance(o, np.floating):
            return float(o)
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, (tuple, set)):
            return list(o)
        return str(o)

    def fix(o):
        if isinstance(o, float) and not math.isfinite(o):
            return "inf" if o > 0 else ("-inf" if o < 0 else "nan")
        if isinstance(o, dict):
            return {str(k): fix(x) for k, x in o.items()}
        if isinstance(o, list):
            return [fix(x) for x in o]
        return o

    return fix(json.loads(json.dumps(v, default=default)))
