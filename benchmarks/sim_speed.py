"""Simulation speed: real-time factors of the JSBSim flights against JSBSim's bare ``run()`` loop.

For each aircraft, measured in the same process, one core, at 400 Hz:

* ceiling: JSBSim's own ``run()`` loop on the same aircraft (the model as JSBSim ships it) and start
  condition, no Python I/O;
* lean ``run()``: the same loop on the model ``fly()`` loads where it leaves out parts it never reads
  (:mod:`tepinn_flight.sim.lean_model`: the F450's own sensor models and disengaged SCAS, the c172x's
  disengaged autopilot, the ground contacts of all three; the flights are bit-identical) — so ``fly()`` against it is our loop's own overhead;
* dynamics: ``fly()`` (our controller in the loop, truth logging, post-processing);
* full chain: ``simulate_record()`` (dynamics + sensor model + record building), if present.

Then campaign throughput: the same campaign with 1 and with 2 worker processes (the campaign
runner ``run_campaign`` when it exists, else ``multiprocessing`` over ``fly``), and the 2 workers once more in the
same process: the first pool's start (its forkserver imports the simulation once) is a one-off that a 4-flight
campaign feels and a real one does not. A speed-up needs two idle cores.

Each figure is the best of ``--repeats`` interleaved rounds (CPU time; the machine may be shared).

Usage: python benchmarks/sim_speed.py [--duration 60] [--aircraft c172x F450 agile_quad] [--repeats 3]
The target is >= 100x real time at 400 Hz for the full chain on one core.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import tempfile
import time

import numpy as np

RATE_HZ = 400.0


class Clock:
    """Wall time and this process's CPU time (the machine may be shared: CPU time is the fair one)."""

    def __enter__(self):
        self.w0, self.c0 = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.wall = time.perf_counter() - self.w0
        self.cpu = time.process_time() - self.c0


def bare_rtf(aircraft: str, duration_s: float, lean: bool = False) -> tuple[float, float] | None:
    """Real-time factor of JSBSim's run() alone from the same start condition as fly(): the model as
    JSBSim ships it, or (``lean``) the one fly() loads (None where that is the same)."""
    from tepinn_flight.sim.flight import AIRCRAFT, _site
    from tepinn_flight.sim.jsbsim_env import open_fdm

    vehicle = AIRCRAFT[aircraft].build()
    spec = getattr(vehicle, "lean", None)
    if lean and spec is None:
        return None
    rng = np.random.default_rng(0)
    info = {}
    with open_fdm(vehicle.model, 1.0 / RATE_HZ, own_aircraft=vehicle.own_aircraft, lean=spec if lean else None,
                  info=info) as fdm:  # fmt: skip
        if lean and info["jsbsim_model"] == vehicle.model:
            return None  # this jsbsim's files differ: fly() loads the stock model too
        ctl = vehicle.start(fdm, _site(rng), rng, 1.0 / RATE_HZ)
        for _ in range(400):  # motors spun up / trimmed state, as in fly()'s warm-up
            ctl.step()
            fdm.run()
        n = int(duration_s * RATE_HZ)
        run = fdm.run
        with Clock() as c:
            for _ in range(n):
                run()
    return duration_s / c.wall, duration_s / c.cpu


def fly_rtf(aircraft: str, duration_s: float, seed: int) -> tuple[float, float, str]:
    from tepinn_flight.sim.flight import fly

    with Clock() as c:
        tr = fly(aircraft, duration_s, RATE_HZ, seed=seed)
    sim_s = len(tr.t_s) / RATE_HZ
    return sim_s / c.wall, sim_s / c.cpu, tr.meta["termination"]


def chain_rtf(aircraft: str, duration_s: float, seed: int) -> tuple[float, float, float] | None:
    """(wall, CPU) real-time factors of the full chain, the record written, and the CPU one without
    the write (dynamics, controller, sensor model, truth logging: what the issue's 0.8 names)."""
    try:
        from tepinn_flight.record import write_record
        from tepinn_flight.sim.simulate import simulate_record
    except ImportError:
        return None
    with tempfile.TemporaryDirectory() as d:
        with Clock() as c:  # dynamics + sensor model + record written to disk
            with Clock() as c_sim:
                rec = simulate_record(aircraft, duration_s, RATE_HZ, seed)
            write_record(rec, os.path.join(d, "r.parquet"))
    return duration_s / c.wall, duration_s / c.cpu, duration_s / c_sim.cpu


def _fly_job(args):
    aircraft, duration_s, seed = args
    from tepinn_flight.sim.flight import fly

    tr = fly(aircraft, duration_s, RATE_HZ, seed=seed)
    return float(tr.q_nb_wxyz.sum())


def campaign_speedup(aircraft: str, duration_s: float, n_flights: int) -> tuple[str, float, float, float | None, bool]:
    """Serial against 2 workers: the campaign runner when it exists, else a Pool over fly() → (how, serial s, 2 workers
    s, 2 workers s again in this process or None, identical records). The campaign runner's first pool starts its
    forkserver, which imports the simulation once (``sim/preload.py``): a one-off per process, which a short benchmark
    campaign feels and a real one does not; the second campaign shows the steady speed-up."""
    try:
        from tepinn_flight.sim.campaign import run_campaign
    except ImportError:
        run_campaign = None
    if run_campaign is not None:
        import pandas as pd

        with tempfile.TemporaryDirectory() as d:
            toml = os.path.join(d, "bench.toml")
            with open(toml, "w") as fh:
                fh.write(f'name = "bench"\nseed = 3\nduration_s = {duration_s}\nrate_hz = {RATE_HZ}\n'
                         f'[[groups]]\naircraft = ["{aircraft}"]\nprofiles = [{{ name = "random" }}]\n'
                         f'sensors = ["consumer"]\nturbulence = ["random"]\nrepeats = {n_flights}\n')
            times = {}
            for key, workers in (("w1", 1), ("w2", 2), ("w2b", 2)):
                with Clock() as c:
                    res = run_campaign(toml, os.path.join(d, key), workers=workers, progress=False)
                assert not res.failed, res.failed
                times[key] = c.wall
            a = sorted(os.listdir(os.path.join(d, "w1")))
            same = all(pd.read_parquet(os.path.join(d, "w1", f)).equals(pd.read_parquet(os.path.join(d, k, f)))
                       for f in a if f.endswith(".parquet") for k in ("w2", "w2b"))
        return "run_campaign", times["w1"], times["w2"], times["w2b"], same
    jobs = [(aircraft, duration_s, 100 + i) for i in range(n_flights)]
    with Clock() as c1:
        serial = [_fly_job(j) for j in jobs]
    ctx = mp.get_context("forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn")
    with Clock() as c2:
        with ctx.Pool(2) as pool:
            par = pool.map(_fly_job, jobs)
    return "Pool over fly()", c1.wall, c2.wall, None, serial == par


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds per flight")
    ap.add_argument("--aircraft", nargs="+", default=["c172x", "F450", "agile_quad"])
    ap.add_argument("--campaign-flights", type=int, default=4, help="flights of the campaign speed-up (0: not measured)")
    ap.add_argument("--repeats", type=int, default=3, help="interleaved rounds; the best of each is printed")
    args = ap.parse_args(argv)
    print(f"cpu cores: {os.cpu_count()}, load average: {os.getloadavg()[0]:.2f}, rate {RATE_HZ:g} Hz, "
          f"{args.duration:g} s flights")  # fmt: skip
    from tepinn_flight.sim.jsbsim_native import describe

    print(describe())
    print("real-time factors (simulated s per s), wall clock | CPU time of this process")
    print(f"{'aircraft':11s} {'bare run() (ceiling)':>21s} {'fly() dynamics':>17s} {'ratio':>5s} "
          f"{'full chain + record':>20s} {'ratio':>5s}  termination")  # fmt: skip
    best = lambda xs, k=2: tuple(max(x[i] for x in xs) for i in range(k))  # noqa: E731  (fastest round)
    lean_rows, chain_rows = [], []
    for ac in args.aircraft:
        fly_rtf(ac, 2.0, 0)  # import / first-load costs out of the way
        bare, lean, dyn, chains = [], [], [], []
        for _ in range(max(1, args.repeats)):
            bare.append(bare_rtf(ac, args.duration))
            lean.append(bare_rtf(ac, args.duration, lean=True))
            dyn.append(fly_rtf(ac, args.duration, 1))
            chains.append(chain_rtf(ac, args.duration, 1))
        bw, bc = best(bare)
        dw, dc = best(dyn)
        term = dyn[0][2]
        chain = best(chains, 3) if chains[0] else None
        chain_s = f"{chain[0]:8.0f}x |{chain[1]:6.0f}x {chain[1] / bc:6.2f}" if chain else f"{'n/a':>20s} {'':5s}"
        print(f"{ac:11s} {bw:10.0f}x |{bc:6.0f}x {dw:7.0f}x |{dc:6.0f}x {dc / bc:5.2f} {chain_s}  {term}")
        if chain:
            chain_rows.append(f"{ac:11s} {chain[2]:6.0f}x CPU = {chain[2] / bc:.2f} of the bare run()")
        if lean[0] is not None:
            lw, lc = best(lean)
            lean_rows.append(f"{ac:11s} lean model's bare run() {lw:6.0f}x |{lc:6.0f}x ({lc / bc:.2f} of the stock "
                             f"model's): fly() is {dc / lc:.2f} of it (our loop's own overhead)")  # fmt: skip
    if chain_rows:
        print("the full chain without writing the record (dynamics, controller, sensor model, truth logging):")
        for row in chain_rows:
            print("  " + row)
    if lean_rows:
        print("fly() loads a lean copy of these models (their own sensor models, disengaged SCAS or autopilot "
              "and ground contacts left out; flights bit-identical):")  # fmt: skip
        for row in lean_rows:
            print("  " + row)
    ac = args.aircraft[0]
    if args.campaign_flights < 1:
        return 0
    how, t_s, t_p, t_p2, same = campaign_speedup(ac, args.duration, args.campaign_flights)
    again = "" if t_p2 is None else (f"; a second campaign in the same process (the pool's forkserver already started: "
                                     f"its one-off start and imports left out) {t_p2:.2f} s, speed-up {t_s / t_p2:.2f}x")
    print(f"campaign via {how} ({args.campaign_flights} x {args.duration:g} s {ac}, wall clock): "
          f"1 worker {t_s:.2f} s, 2 workers {t_p:.2f} s, speed-up {t_s / t_p:.2f}x{again}; "
          f"identical records: {same}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
