"""Cold start of the compiled loops: numba's compile on first use (empty cache) and the cache load
after it, per component, each in a fresh process, for this checkout and (``--compare PATH``) another
checkout measured in the same run (e.g. the main branch before a change).

For every component and checkout: a fresh ``NUMBA_CACHE_DIR`` (an empty temp folder); process 1
times the first call (compile + run) and a second identical call (run); process 2, on the cache
process 1 left, times its first call (cache load + run). Reported: compile = first − second call of
process 1, load = process 2's first call − process 1's second call. Imports are not counted (they
are the same for both checkouts and paid whether or not anything compiles).

The calls are what a user's first run makes: ``fusion`` the offline estimator's loop
(``FusionRun`` with the shipped ``FusionConfig``, as ``estimate`` runs it), ``fusion-live`` the
live bridge's per-sample call (``AttitudeFusion.step``), ``filters`` the baseline filters
``evaluate`` runs (complementary and Madgwick 6-D and 9-D, the EKF) through ``FilterEstimator`` on a
flight record, ``tlog-sync`` the frame sync of a real tlog (``scan_tlog``; skipped when
``../shared/real-logs`` is missing), ``anchored`` the shipped estimator's kernels between network
windows (``AnchoredVQF.update`` on a block, ``correct`` with every gate open, ``update_one``: what
``estimate`` and the live worker run; ``model/anchor_kernels.py``), ``features`` the token features the
onnxruntime path computes for the network (``model/window_features.py``, session 11), ``gnss-aid``
the GNSS-aided tilt's window sums and rotations (``model/gnss_aid_kernels.py``, session 21; a record
with GNSS velocity), ``estimate-cli`` the whole ``estimate`` command on a 20-s GNSS-aided F450 record, in the process
(every loop it compiles; since session 37 a cold cache starts ``jit_warmup``'s helper process beside it).

Usage: python benchmarks/jit_compile.py [--compare /path/to/other/checkout] [--only fusion,filters]
Wall-clock seconds; the machine may be shared, so compare the two checkouts within one run.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TLOG = ROOT.parent / "shared" / "real-logs" / "uavlv_vtol.tlog"

_PRELUDE = """
import json, time
import numpy as np
"""

_TIMING = """
t0 = time.perf_counter(); call(); t1 = time.perf_counter(); call(); t2 = time.perf_counter()
print("JIT_RESULT " + json.dumps({"first_s": t1 - t0, "second_s": t2 - t1}))
"""

SETUP = {
    "fusion": """
from tepinn_flight.model.fusion import FusionConfig, FusionRun
n = 2000
t = np.arange(n) / 200.0
gyr = np.tile([0.05, -0.02, 0.1], (n, 1))
idx = np.arange(15, n, 16)
q_est = np.tile([0.99, 0.1, 0.0, 0.0], (len(idx), 1)) / np.linalg.norm([0.99, 0.1, 0.0, 0.0])
def call():
    run = FusionRun(t, gyr, FusionConfig())
    run.add(idx, q_est, np.full(len(idx), 0.02), np.zeros((len(idx), 3)))
    run.advance(n)
""",
    "fusion-live": """
from tepinn_flight.model.fusion import AttitudeFusion, FusionConfig
def call():
    f = AttitudeFusion(FusionConfig())
    for i in range(50):
        est = ((0.99, 0.1, 0.0, 0.0), 0.02, (0.0, 0.0, 0.0)) if i % 16 == 15 else None
        f.step(i / 200.0, (0.05, -0.02, 0.1), est)
""",
    "filters": """
from tepinn_flight.evaluation.estimators import FilterEstimator
from tepinn_flight.evaluation.filters import Complementary, Ekf, Madgwick
from tepinn_flight.record import FlightRecord, make_frame
n = 2000
t = np.arange(n) / 200.0
rng = np.random.default_rng(0)
gyr = rng.normal(0, 0.1, (n, 3))
acc = np.array([0.0, 0.0, -9.81]) + rng.normal(0, 0.1, (n, 3))
mag = np.array([20.0, 0.0, 45.0]) + rng.normal(0, 0.5, (n, 3))
rec = FlightRecord(make_frame(t, np.zeros(n, int), gyr, acc, mag, np.tile([1.0, 0, 0, 0], (n, 1))),
                   {"source_kind": "synthetic"})
ests = [FilterEstimator(Complementary()), FilterEstimator(Madgwick()), FilterEstimator(Ekf()),
        FilterEstimator(Complementary(), use_mag=True), FilterEstimator(Madgwick(), use_mag=True)]
def call():
    for e in ests:
        e.estimate(rec)
""",
    "anchored": """
import dataclasses
from tepinn_flight.model.anchor import AnchorConfig, AnchoredVQF, WindowOutput
cfg = dataclasses.replace(AnchorConfig(), speed_lo_m_s=0.0, speed_hi_m_s=1e-3)  # every gate open
t = np.arange(50) / 200.0
gyr, acc = np.tile([0.05, -0.02, 0.1], (50, 1)), np.tile([0.0, 0.0, -9.81], (50, 1))
q = np.array([0.99, 0.1, 0.0, 0.0]) / np.linalg.norm([0.99, 0.1, 0.0, 0.0])
def call():
    f = AnchoredVQF(cfg, 1 / 200.0)
    f.update(t, gyr, acc)
    f.correct(WindowOutput(q, 0.02, np.zeros(3), np.array([30.0, 0.0, 0.0]), np.zeros(3), np.array([0.1, 0.0, 0.0])))
    f.update(t + 0.25, gyr, acc)
    f.update_one(0.5, (0.05, -0.02, 0.1), (0.0, 0.0, -9.81))
""",
    "features": """
from tepinn_flight.model.config import ModelConfig
from tepinn_flight.model.window_features import SensorValues, window_features
cfg = ModelConfig()
k = cfg.window_tokens
w = (np.full((1, k, 3), 0.1), np.tile([0.0, 0.0, -9.81], (1, k, 1)), np.full((1, k), 8.0),
     (np.arange(k) - k + 1) / 25.0 * np.ones((1, k)), np.full((1, k), 0.04), None, np.zeros((1, k)))
def call():
    window_features(cfg, SensorValues.identity(), *w)
""",
    "gnss-aid": """
from tepinn_flight.model.gnss_aid import GnssAidConfig, motion_acc_body
n = 4000
t = np.arange(n) / 200.0
q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
acc = np.column_stack([np.sin(t), np.cos(t), np.full(n, -9.81)])
vel = np.column_stack([-np.cos(t), np.sin(t)])
def call():
    motion_acc_body(t, q, acc, vel, GnssAidConfig())
""",
    "estimate-cli": """
import os, tempfile
from tepinn_flight.cli.main import main
from tepinn_flight.record import write_record
from tepinn_flight.sim.simulate import simulate_record
d = tempfile.mkdtemp()
write_record(simulate_record("F450", 20.0, rate_hz=200.0, seed=2), os.path.join(d, "r.parquet"))  # GNSS-aided
def call():
    assert main(["estimate", os.path.join(d, "r.parquet"), "-o", os.path.join(d, "e.parquet"), "-q"]) == 0
""",
    "tlog-sync": f"""
from tepinn_flight.ingest.mavlink_scan import scan_tlog
def call():
    scan_tlog({str(TLOG)!r}, ["ATTITUDE"])
""",
}


def _run(tree: Path, component: str, cache: str) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree), "NUMBA_CACHE_DIR": cache}
    env.pop("NUMBA_DISABLE_JIT", None)
    code = _PRELUDE + SETUP[component] + _TIMING
    p = subprocess.run([sys.executable, "-c", code], cwd=tree, env=env, capture_output=True, text=True)
    for line in p.stdout.splitlines():
        if line.startswith("JIT_RESULT "):
            return json.loads(line[len("JIT_RESULT "):])
    raise SystemExit(f"{component} in {tree} failed:\n{p.stderr[-2000:]}")


def measure(tree: Path, component: str) -> tuple[float, float]:
    """(compile s, cache-load s) of one component in one checkout."""
    cache = tempfile.mkdtemp(prefix="numba-cold-")
    try:
        cold = _run(tree, component, cache)
        warm = _run(tree, component, cache)
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    return cold["first_s"] - cold["second_s"], warm["first_s"] - cold["second_s"]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--compare", type=Path, help="another checkout measured in the same run (e.g. /work/main)")
    ap.add_argument("--only", default=",".join(SETUP), help="comma-separated components: " + ", ".join(SETUP))
    args = ap.parse_args(argv)
    comps = [c.strip() for c in args.only.split(",") if c.strip()]
    for c in comps:
        if c not in SETUP:
            raise SystemExit(f"unknown component {c!r} (choose from {', '.join(SETUP)})")
    if "tlog-sync" in comps and not TLOG.exists():
        print(f"tlog-sync skipped: {TLOG} not found")
        comps.remove("tlog-sync")
    trees = [("this", ROOT)] + ([("compare", args.compare.resolve())] if args.compare else [])
    print(f"this: {ROOT}" + (f"   compare: {args.compare.resolve()}" if args.compare else ""))
    head = f"{'component':<12} {'compile s':>10} {'load s':>8}"
    if args.compare:
        head += f" {'cmp compile s':>14} {'cmp load s':>11} {'compile ratio':>14}"
    print(head)
    for c in comps:
        res = {name: measure(tree, c) for name, tree in trees}
        row = f"{c:<12} {res['this'][0]:>10.2f} {res['this'][1]:>8.2f}"
        if args.compare:
            cc, cl = res["compare"]
            row += f" {cc:>14.2f} {cl:>11.2f} {cc / max(res['this'][0], 1e-9):>13.1f}×"
        print(row, flush=True)


if __name__ == "__main__":
    main()
