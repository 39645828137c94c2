"""What the GNSS aid costs offline: the shipped estimator with the aid in fast flight
(``AnchorConfig.gnss_aid_in_flight``, session 15: two more anchored passes where it holds), session 14's (the aid
stopped at 20 m/s: on a fixed wing, no extra pass), the shipped one without the receiver's latency read from the
record (rule 37c, session 64: read on multirotors only) and VQF on the same samples, in the same run, in alternating
rounds (this machine is shared; absolute times drift).

    python benchmarks/gnss_aid_speed.py [RECORD_OR_LOG] [--aircraft c172x] [--duration 60] [--rounds 2] [--threads 2]

Default record: a 60-s c172x flight at 400 Hz (seed 52, the simulated receiver), flown here; ``--aircraft F450
--duration 600`` a long multirotor flight, where the latency is read.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("record", nargs="?", default=None, help="a record or log (default: a simulated c172x flight)")
    ap.add_argument("--aircraft", default="c172x", help="the aircraft flown when no record is given (default c172x)")
    ap.add_argument("--duration", type=float, default=60.0, help="its flight's length in s (default 60)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()

    import torch

    from tepinn_flight.evaluation.peers import VqfEstimator
    from tepinn_flight.ingest import load_record
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    import tepinn_flight.model.estimate as estimate_module
    from tepinn_flight.model.estimate import estimate_anchored
    from tepinn_flight.model.gnss_aid import GnssAidConfig
    from tepinn_flight.sim.simulate import simulate_record

    torch.set_num_threads(args.threads)
    rec = load_record(Path(args.record)) if args.record else simulate_record(args.aircraft, args.duration, 400.0, seed=52)
    model, anchor, _ = load_model(default_model_path())

    def latency_not_read(fn):
        shipped = estimate_module.GnssAidConfig
        estimate_module.GnssAidConfig = lambda: GnssAidConfig(latency_grid_s=())  # the aid's settings, read nowhere
        try:
            return fn()
        finally:
            estimate_module.GnssAidConfig = shipped

    runs = {
        "TE-PINN, aid in fast flight (shipped)": lambda: estimate_anchored(model, rec, anchor),
        "TE-PINN, aid below 20 m/s (session 14)": lambda: estimate_anchored(
            model, rec, dataclasses.replace(anchor, gnss_aid_in_flight=False)),
        "TE-PINN, latency not read (session 63)": lambda: latency_not_read(lambda: estimate_anchored(model, rec, anchor)),
        "VQF": lambda: VqfEstimator().estimate(rec),
    }  # fmt: skip
    aid = estimate_anchored(model, rec, anchor).attrs.get("gnss_aid", "")  # (also the first run's warm-up)
    print(f"{len(rec)} samples; {aid}")
    best = {k: float("inf") for k in runs}
    for _ in range(args.rounds):
        for name, fn in runs.items():
            t0 = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - t0)
    vqf = len(rec) / best["VQF"]
    for name, dt in best.items():
        rate = len(rec) / dt
        print(f"{name:42s} {rate / 1e3:9.1f} k samples/s   {rate / vqf:6.3f}× VQF")
    return 0


if __name__ == "__main__":
    sys.exit(main())
