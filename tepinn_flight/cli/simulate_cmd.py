"""``tepinn-flight simulate``: JSBSim flights with a realistic IMU, as flight records (and tlogs)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from .helptext import add_examples

HELP = "simulate flights in JSBSim with a realistic IMU error model (one flight or a campaign)"
DESCRIPTION = (
    "Fly an aircraft in JSBSim (noise-free truth), apply a sensor error model (noise, biases, bias "
    "random walk, scale/cross-axis errors, quantization, saturation, magnetometer hard/soft iron) and "
    "write a flight record whose q_ref_* is the true attitude and gyr_bias_*/acc_bias_* the true "
    "biases. With --campaign, run many flights in parallel processes (resumable). Sensor presets live "
    "in flight_sims/sensors/ (default: consumer = MPU-6000 class as seen in an autopilot log)."
)


def add_arguments(p) -> None:
    add_examples(p,
                 'tepinn-flight simulate --list',
                 'tepinn-flight simulate --aircraft c172x --duration 120 --seed 3 -o c172x.parquet',
                 'tepinn-flight simulate --campaign flight_sims/campaigns/smoke.toml -o sims/')
    what = p.add_mutually_exclusive_group()
    what.add_argument("--aircraft", metavar="NAME", help="aircraft to fly (see --list), e.g. c172x, F450")
    what.add_argument("--campaign", metavar="TOML", help="campaign file (flight_sims/campaigns/*.toml)")
    what.add_argument("--list", action="store_true", help="list aircraft, maneuvers, turbulence levels and sensor presets")
    p.add_argument("-o", "--output", metavar="OUT",
                   help="record file (one flight; default <aircraft>_seed<N>.parquet) or folder (--campaign)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="flight duration in s (default 60)")
    p.add_argument("--rate", type=float, default=None, metavar="HZ",
                   help="simulation and IMU rate in Hz (default 400; the sensor's rate_hz may decimate it)")
    p.add_argument("--seed", type=int, default=None, metavar="N",
                   help="seed of the flight and the sensor noise (default 0); with --campaign the campaign's seed "
                        "replaced: the same flights drawn anew (the held-out campaign with --seed 2026 is the README's "
                        "other-seed check)")
    p.add_argument("--sensor", default=None, metavar="PRESET",
                   help="sensor preset name or TOML path (default consumer; see --list)")
    p.add_argument("--sensor-set", action="append", default=None, metavar="KEY=VALUE",
                   help="override a sensor parameter, e.g. gyro.arw_deg_sqrt_h=0.5 or rate_hz=200 (repeatable)")
    p.add_argument("--maneuvers", default=None, metavar="A,B,C",
                   help="maneuvers flown in order and repeated (default: a random chain from the seed)")
    p.add_argument("--turbulence", default=None, metavar="LEVEL",
                   help="none, light, moderate or severe (default: drawn from the seed among none, light and "
                        "moderate; severe only when asked)")
    p.add_argument("--tlog", default=None, metavar="FILE",
                   help="also write the flight as a MAVLink 2 tlog (ArduPilot-style, attitude = truth)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="parallel worker processes for --campaign (default: CPU count)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors (no progress bar)")


_SINGLE_ONLY = ("aircraft", "duration", "rate", "sensor", "sensor_set", "maneuvers", "turbulence", "tlog")


def run(args) -> int:
    from .notes import run_noting_compiles

    return run_noting_compiles("simulate", args, _run)  # the first run after installing compiles the loops: say so


def _run(args) -> int:
    from ..errors import ConfigError

    if args.list:
        return _list()
    if args.campaign:
        given = [n for n in _SINGLE_ONLY if getattr(args, n) is not None]
        if given:
            opts = ", ".join("--" + n.replace("_", "-") for n in given)
            raise ConfigError(f"{opts} cannot be combined with --campaign (the campaign file sets them)")
        if args.output is None:
            raise ConfigError("--campaign needs -o DIR (the output folder)")
        return _campaign(args)
    if args.workers is not None:
        raise ConfigError("--workers applies to --campaign only")
    if not args.aircraft:
        raise ConfigError("give --aircraft NAME (or --campaign FILE, or --list)")
    return _single(args)


def _single(args) -> int:
    from ..errors import ConfigError
    from ..record import check_output, write_record
    from ..sim.sensors import DEFAULT_PRESET, decimation_factor, load_sensor_config
    from ..sim.simulate import check_flight_args, simulate_record
    from .paths import check_suffix, output_format

    duration = 60.0 if args.duration is None else args.duration
    rate = 400.0 if args.rate is None else args.rate
    seed = 0 if args.seed is None else args.seed
    check_flight_args(duration, rate, seed)
    maneuvers = None
    if args.maneuvers is not None:
        maneuvers = [m.strip() for m in args.maneuvers.split(",") if m.strip()]
        if not maneuvers:
            raise ConfigError("--maneuvers is empty")
    sensor = load_sensor_config(args.sensor or DEFAULT_PRESET, args.sensor_set or [])
    if sensor.rate_hz is not None:  # before the flight (review60: refused after it had flown, minutes on a long one)
        decimation_factor(rate, float(sensor.rate_hz))
    out = Path(args.output) if args.output else Path(f"{args.aircraft}_seed{seed}.parquet")
    if out.is_dir():
        raise ConfigError("is a folder; give a record file name for one flight", out)
    output_format(out, "simulate")  # a record is Parquet, whatever the name says
    check_output(out)  # before the flight: a place that cannot be written is a one-line error
    if args.tlog:
        check_suffix("--tlog", args.tlog, ("", ".tlog"), "a MAVLink telemetry log")
        if Path(args.tlog).resolve() == out.resolve():
            raise ConfigError(f"--tlog {args.tlog} and -o name the same file: the tlog would replace the record")
        check_output(args.tlog)
    t0 = time.perf_counter()
    rec = simulate_record(args.aircraft, duration, rate, seed, sensor=sensor, sensor_overrides=(),
                          maneuvers=maneuvers, turbulence=args.turbulence)  # fmt: skip
    rec.meta["sensor_overrides"] = list(args.sensor_set or [])
    t_sim = time.perf_counter() - t0
    write_record(rec, out)
    line = (f"{rec.meta['aircraft']} {rec.meta['duration_s']:.1f} s ({rec.meta['termination']}), {len(rec)} samples "
            f"at {rec.meta['imu_rate_hz']:g} Hz, sensor {rec.meta['sensor_preset']}, seed {seed}, "
            f"{int(rec.clipped.sum())} clipped -> {out} ({t_sim:.1f} s)")  # fmt: skip
    if args.tlog:
        from ..tlog_writer import write_tlog

        counts = write_tlog(args.tlog, rec)
        line += f"; tlog {args.tlog} ({sum(counts.values())} messages)"
    if not args.quiet:
        print(line)
    return 0


def _campaign(args) -> int:
    from ..record import check_output
    from ..sim.campaign import run_campaign

    check_output(args.output, folder=True)
    from ..jit_notice import announce
    from ..jit_warmup import cold
    from ..sim import quad_flight_kernel, vibration

    if cold([quad_flight_kernel.fly_quad, vibration._accumulate]):
        announce()  # the workers' forkserver compiles them, out of this process's sight
    res = run_campaign(args.campaign, args.output, workers=args.workers, progress=not args.quiet, seed=args.seed)
    if not args.quiet or res.failed:
        seeded = "" if args.seed is None else f" (seed {args.seed})"
        print(f"campaign {args.campaign}{seeded}: {res.total} flights, {res.computed} computed, {res.skipped} already done, "
              f"{len(res.failed)} failed in {res.wall_s:.1f} s (the workers' time {res.flight_s:.1f} s) -> {args.output}")
    if res.failed:
        sys.stderr.write(f"tepinn-flight simulate: error: {len(res.failed)} flight(s) failed: {res.failure_causes()}; "
                         "re-run the same command to retry them\n")
        return 1
    return 0


def _list() -> int:
    from ..sim import flight as fl
    from ..sim.sensors import list_presets, load_sensor_config

    print("aircraft (maneuvers):")
    for name, spec in fl.AIRCRAFT.items():
        print(f"  {name:<12} {spec.vehicle_type:<11} {spec.description}")
        try:
            names = ", ".join(fl.maneuver_names(name))
        except Exception as exc:  # an aircraft whose maneuver library cannot be loaded
            names = f"(unavailable: {type(exc).__name__}: {exc})"
        print(f"  {'':<12} maneuvers: {names}")
    print(f"turbulence: {', '.join(getattr(fl, 'TURBULENCE', {}))} (default: drawn from the seed among none, light and moderate)")
    print("sensor presets:")
    for p in list_presets():
        print(f"  {p:<14} {load_sensor_config(p).description}")
    return 0
