"""What the gyro self-calibration costs: ``gyro_selfcal.self_calibrate`` beside VQF (offline batch, C++)
on the same samples, in the same run.

Each record is repeated end to end up to ``--tile-s`` seconds (the issue's one-hour log); the
self-calibration's phases (rests with a turn between them) repeat with it, so the cost is that of a
long log with many phases. CPU time (``time.process_time``) is reported because the machine may be
shared. The compiled loop is run once before timing (numba's compile or cache load is not a
per-sample cost).

    python benchmarks/selfcal_speed.py [RECORD_OR_LOG...] [--tile-s 3600] [--repeat 3]

Default records: BROAD trial 08 from ``../shared`` (8 phases, the scale applied) and a simulated
F450 and c172x flight of the held-out campaign when ``--sim`` (default ``runs/heldout``, the folder
``real_vs_peers.py`` flies it into) holds them.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from estimate_speed import tiled  # noqa: E402  (the record played forth and back, as estimate_speed.py times it)
from tepinn_flight.evaluation.peers import VqfEstimator  # noqa: E402
from tepinn_flight.model.gyro_selfcal import self_calibrate  # noqa: E402


def cpu(fn, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("records", nargs="*")
    ap.add_argument("--shared", default=str(REPO.parent / "shared"))
    ap.add_argument("--sim", default=str(REPO / "runs" / "heldout"), help="folder of the held-out campaign's records")
    ap.add_argument("--tile-s", type=float, default=3600.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    from tepinn_flight.ingest import load_record

    paths = [Path(p) for p in args.records]
    if not paths:
        paths = sorted((Path(args.shared) / "broad").glob("broad_08_*.hdf5"))
        sims = Path(args.sim)
        found = [*sorted(sims.glob("*F450-agile-consumer-none*.parquet"))[:1],
                 *sorted(sims.glob("*c172x-aerobatic*.parquet"))[:1]]
        if not found:
            print(f"note: no held-out simulated flights in {sims} (fly them: python benchmarks/real_vs_peers.py, or "
                  "pass --sim): the BROAD trial only", file=sys.stderr)  # fmt: skip
        paths += found
    if not paths:
        print("no records: pass RECORD_OR_LOG, or put the BROAD trials in ../shared/broad")
        return 2
    vqf = VqfEstimator(offline=True)
    print(f"{'record':<44}{'samples':>10}{'phases':>8}{'applied':>9}{'self-cal s':>12}{'VQF s':>8}{'ratio':>7}{'Msamples/s':>12}")
    for p in paths:
        rec = tiled(load_record(p), args.tile_s)
        cal = self_calibrate(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2)  # (also numba's compile / cache load)
        t_sc = cpu(lambda: self_calibrate(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2), args.repeat)
        t_v = cpu(lambda: vqf.estimate(rec), args.repeat)
        print(f"{p.name[:44]:<44}{len(rec):>10}{cal.phases:>8}{str(cal.applied):>9}{t_sc:>12.3f}{t_v:>8.3f}"
              f"{t_sc / t_v:>7.2f}{len(rec) / t_sc / 1e6:>12.1f}", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
