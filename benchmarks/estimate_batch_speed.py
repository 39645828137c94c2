"""Many records through ``tepinn-flight estimate``: samples per second with ``--workers 1`` and ``--workers 2``,
beside offline VQF on the same samples, measured in the same run.

A log analyst estimates a season of logs: records side by side in worker processes use both cores where one
record's estimate cannot (its anchored filter passes are sequential Python around VQF's C++ update; only the
network's batches use a second thread). The records: each given record (default: every 8th flight of the held-out
campaign, `runs/heldout`, fixed wing and multirotors, GNSS-aided) repeated end to end to ``--tile-s`` seconds
and written to a temporary folder; the command is run as a user runs it (a subprocess: its start-up — imports,
the model, numba's cache — is part of the time), ``--rounds`` alternating rounds, the best of each printed.
Outputs of the two settings are checked equal to 1e-6 (a worker runs the network on one thread, whose float32
batches round differently from two threads' slices: ~1e-8 where the network acts).

    python benchmarks/estimate_batch_speed.py [RECORD ...] [--tile-s 600] [--rounds 2]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("records", nargs="*", help="records or logs (default: every 8th held-out flight)")
    ap.add_argument("--tile-s", type=float, default=600.0, help="each record repeated to this many seconds")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()

    import pandas as pd

    from estimate_speed import tiled
    from tepinn_flight.evaluation.peers import make_peer
    from tepinn_flight.ingest import load_record
    from tepinn_flight.record import write_record

    paths = [Path(p) for p in args.records] or sorted((REPO / "runs/heldout").glob("*.parquet"))[::8]
    if not paths:
        print("no records: give some, or fly the held-out campaign first "
              "(tepinn-flight simulate --campaign flight_sims/campaigns/heldout.toml -o runs/heldout)")
        return 2
    vqf = make_peer("vqf", [])
    with tempfile.TemporaryDirectory() as d:
        src = Path(d) / "in"
        src.mkdir()
        n = 0
        for p in paths:
            rec = tiled(load_record(p), args.tile_s)
            write_record(rec, src / f"{p.stem}.parquet")
            n += len(rec)
        recs = sorted(src.glob("*.parquet"))
        print(f"{len(recs)} records, {n} samples ({args.tile_s:g} s each)")
        best = {}
        for k in range(args.rounds):
            t0 = time.perf_counter()
            for p in recs:
                vqf.estimate(load_record(p))
            best["VQF (in process, reading each record)"] = max(best.get("VQF (in process, reading each record)", 0),
                                                                n / (time.perf_counter() - t0))  # fmt: skip
            for w in (1, 2):
                out = Path(d) / f"out{w}"
                out.mkdir(exist_ok=True)  # (a folder, also for one record: estimate -o FILE had written a file there)
                t0 = time.perf_counter()
                subprocess.run([sys.executable, "-m", "tepinn_flight", "estimate", *map(str, recs), "-o", f"{out}/",
                                "--workers", str(w), "-q"], check=True, cwd=REPO)  # fmt: skip
                key = f"TE-PINN, estimate --workers {w}"
                best[key] = max(best.get(key, 0), n / (time.perf_counter() - t0))
        # one thread per worker: the network's float32 batches are not cut per thread as with two, so where the
        # network acts the two agree to rounding (~1e-8), not bit for bit
        same, diff = True, 0.0
        for p in recs:  # the same rows, columns and NaNs (review61: nanmax alone had passed an output half NaN), then
            a, b = (pd.read_parquet(Path(d) / f"out{w}" / p.name) for w in (1, 2))  # the finite values to 1e-6
            if list(a.columns) != list(b.columns) or a.shape != b.shape:
                same = False
                continue
            a, b = a.to_numpy(np.float64), b.to_numpy(np.float64)
            same &= bool(np.array_equal(np.isnan(a), np.isnan(b)))
            fin = np.isfinite(a) & np.isfinite(b)
            diff = max(diff, float(np.abs(a[fin] - b[fin]).max(initial=0.0)))
        same &= diff <= 1e-6
    v = best.pop("VQF (in process, reading each record)")
    print(f"{'':38s} {'samples/s':>10s} {'VQF / it':>9s}")
    print(f"{'VQF (in process, reading each record)':38s} {v:10.0f} {1.0:9.1f}")
    for key, s in best.items():
        print(f"{key:38s} {s:10.0f} {v / s:9.1f}")
    w1, w2 = best["TE-PINN, estimate --workers 1"], best["TE-PINN, estimate --workers 2"]
    print(f"--workers 2 / --workers 1: {w2 / w1:.2f}x; outputs equal to 1e-6: {same} (largest difference {diff:.1e})")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
