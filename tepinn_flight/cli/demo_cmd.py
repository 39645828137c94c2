"""``tepinn-flight demo``: the main job on embedded defaults, in a few minutes on a laptop CPU.

Simulates one short high-dynamic flight per default vehicle (F450 flips and rolls, the agile quad,
c172x aerobatics), estimates attitude with the shipped TE-PINN model, the shipped LSTM baseline and
every baseline filter and published peer, and writes the report to ``./tepinn-demo/``.
"""

from __future__ import annotations

from .argtypes import add_runtime
from .helptext import add_examples

HELP = "simulate a few high-dynamic flights, run TE-PINN and every baseline, write a report (the main job)"

#: (aircraft, maneuvers, seed): short, high-dynamic, one per default vehicle
DEMO_FLIGHTS = (
    ("F450", "flip,roll,rate_steps,figure_eight,yaw_spin", 11),
    ("agile_quad", "rate_steps,flip,figure_eight,roll,vibration", 12),
    ("c172x", "aileron_roll,steep_turn,split_s,dive_pullup", 13),
)


def add_arguments(p) -> None:
    add_examples(p,
                 'tepinn-flight demo                              # simulate, estimate, compare: ./tepinn-demo/report.md',
                 'tepinn-flight demo -o demo/ --duration 20       # quicker; on a 20-s fixed-wing flight the network\'s '
                 'flight-speed gate has less to go on (TE-PINN 4.6 deg there against 2.4 deg with it shut; at 45 s it helps: 4.6 against 21.7)')
    p.add_argument("-o", "--output", default="tepinn-demo", metavar="DIR", help="report folder (default ./tepinn-demo)")
    p.add_argument("--duration", type=float, default=45.0, metavar="S", help="seconds per flight (default 45)")
    p.add_argument("--rate", type=float, default=200.0, metavar="HZ", help="IMU rate (default 200)")
    p.add_argument("--sensor", default="consumer", metavar="PRESET", help="sensor preset (default consumer)")
    p.add_argument("--model", default=None, metavar="CKPT", help="TE-PINN checkpoint or .onnx export (default: the shipped model)")
    add_runtime(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no progress lines")


def run(args) -> int:
    from .notes import run_noting_compiles

    return run_noting_compiles("demo", args, _run)  # the first run after installing compiles the loops: say so, once


def _run(args) -> int:
    import sys
    from pathlib import Path

    from ..errors import ConfigError
    from ..evaluation.estimators import TepinnEstimator, default_learned
    from .argtypes import check_runtime
    from ..evaluation.harness import HarnessConfig, evaluate
    from ..evaluation.names import display_name
    from ..evaluation.report import write_report
    from ..evaluation.suite import baseline_estimators, peer_estimators
    from ..record import check_output, write_record
    from ..sim.simulate import simulate_record

    if not args.duration > 10:
        raise ConfigError(f"--duration must be > 10 s, got {args.duration}")
    out = Path(args.output)
    check_output(out, folder=True)  # before the flights: refused now, not after them
    check_runtime([args.model] if args.model else [], args.runtime)
    learned = [TepinnEstimator.from_checkpoint(args.model, "tepinn", args.runtime)] if args.model else None  # (a bad --model too)
    say = (lambda s: None) if args.quiet else (lambda s: sys.stderr.write(s + "\n"))
    from ..jit_warmup import start

    # a cold numba cache: the estimators' loops compile in a helper process beside the fusion's here and the flights
    warm = start(filters=True)
    records = []
    try:
        for aircraft, maneuvers, seed in DEMO_FLIGHTS:
            say(f"simulating {aircraft} ({maneuvers.replace(',', ', ')}), {args.duration:.0f} s at {args.rate:.0f} Hz ...")
            rec = simulate_record(aircraft, args.duration, args.rate, seed, args.sensor, maneuvers=maneuvers.split(","))
            rec.meta["name"] = f"{aircraft}-demo"
            write_record(rec, out / "records" / f"{aircraft}.parquet")
            records.append(rec)
        warm.join()
    finally:
        warm.stop()  # (an error or Ctrl-C while simulating: the helper ends with the demo)
    notes: list[str] = []
    estimators = learned if learned is not None else default_learned(notes, args.runtime)
    estimators += baseline_estimators()
    estimators += peer_estimators(notes=notes)
    result = evaluate(records, estimators, HarnessConfig(), progress=not args.quiet, notes=notes)
    files = write_report(result, out, title="tepinn-flight demo: high-dynamic simulated flights")
    for n in result.notes:
        say(f"note: {n}")
    rows = sorted((d["inclination_rmse_deg"], k) for k, d in result.dataset.items() if d["inclination_rmse_deg"] is not None)
    print("inclination RMSE (mean over the demo flights): " + ", ".join(f"{display_name(k)} {v:.2f}°" for v, k in rows))
    print(f"report: {files[-1]} (interactive: {files[-1].with_name('report.html')})")
    return 0
