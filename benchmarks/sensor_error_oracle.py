"""How much of TE-PINN's tilt error on simulated flights is the IMU's own error: an oracle diagnostic.

Our simulated IMUs read ``y = M x + b + n`` (``sim/sensors.py``: a scale and misalignment matrix M, a bias b that
starts at a turn-on value and walks, noise n; rotor vibration is part of x). A flight record keeps the truth of M
(``meta["sensor_truth"]``) and of b (``gyr_bias_*``, ``acc_bias_*`` columns). This script estimates each flight
four times with the shipped model — as simulated; the accelerometer's M and b removed (``M⁻¹(y − b)``); the gyro's
removed; both — and prints the inclination RMSE and σ's mean NEES (5 s warm-up) for each, per flight and per
aircraft and sensor grade. What disappears with the oracle is error no filter can read from the data of a flight
without rests (a gyro's scale in flips, an accelerometer's bias in hover); what stays is the estimator's.

Session 33 (three consumer multirotor training flights): 0.90–1.91° (NEES ~4) as simulated, 0.09–0.31° (NEES
0.07–0.39) with both sensors' errors removed; the gyro's part dominates agile flight (1.91° → 0.66°), the
accelerometer's the hover (NEES 4.04 → 1.17). An industrial flight: 0.44° → 0.30°.

    python benchmarks/sensor_error_oracle.py runs/default/data --every 6 [--model CKPT]
    python benchmarks/sensor_error_oracle.py FLIGHT.parquet [FLIGHT.parquet ...]
"""

from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

CASES = ("as simulated", "acc oracle", "gyro oracle", "both")


def corrected(rec, acc: bool, gyr: bool):
    """A copy of ``rec`` with the accelerometer's and/or the gyro's simulated errors removed: ``M⁻¹(y − b)``."""
    from tepinn_flight.record import ACC_BIAS_COLS, ACC_COLS, GYR_BIAS_COLS, GYR_COLS

    truth = rec.meta["sensor_truth"]
    r = copy.copy(rec)
    r.data = rec.data.copy()
    for on, key, cols, bias_cols in ((acc, "accel", ACC_COLS, ACC_BIAS_COLS), (gyr, "gyro", GYR_COLS, GYR_BIAS_COLS)):
        if on:
            m = np.asarray(truth[key]["matrix"], np.float64)
            y = rec.data[cols].to_numpy() - rec.data[bias_cols].to_numpy()
            r.data[cols] = np.linalg.solve(m, y.T).T
    return r


def score(est, rec) -> tuple[float, float]:
    """(inclination RMSE in degrees, σ's mean NEES of the 2-D tilt error), 5 s warm-up."""
    from tepinn_flight.evaluation.harness import scoring_mask
    from tepinn_flight.evaluation.metrics import error_quat_earth, tilt_error_vector_rad
    from tepinn_flight.model.estimate import EST_Q_COLS

    df = est.estimate(rec)
    q = df[EST_Q_COLS].to_numpy()
    s = df["sigma_rad"].to_numpy()
    m = scoring_mask(rec, 5.0) & np.all(np.isfinite(q), 1) & np.isfinite(s)
    e2 = np.sum(tilt_error_vector_rad(error_quat_earth(q[m], rec.q_ref_wxyz[m])) ** 2, axis=1)
    return float(np.degrees(np.sqrt(e2.mean()))), float(np.mean(e2 / s[m] ** 2))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("paths", nargs="+", help="simulated flight records (.parquet) or folders of them")
    ap.add_argument("--every", type=int, default=1, help="every N-th record of a folder")
    ap.add_argument("--model", default=None, help="TE-PINN checkpoint (default: shipped)")
    args = ap.parse_args()

    import torch

    from tepinn_flight.evaluation.estimators import TepinnEstimator
    from tepinn_flight.model.checkpoint import default_model_path
    from tepinn_flight.record import read_record

    torch.set_num_threads(1)
    files = []
    for p in map(Path, args.paths):
        files += sorted(p.glob("*.parquet"))[:: max(1, args.every)] if p.is_dir() else [p]
    est = TepinnEstimator.from_checkpoint(args.model or default_model_path(), "tepinn")
    rows = []
    print(f"{'flight':<44}" + "".join(f"{c:>22}" for c in CASES) + "   (RMSE °, NEES)")
    for f in files:
        try:
            rec = read_record(f)
        except Exception as exc:  # noqa: BLE001 (a file that is not a record: one line, go on)
            print(f"{f.name}: skipped ({exc})")
            continue
        if "sensor_truth" not in rec.meta:
            print(f"{f.name}: skipped (no simulated sensor truth: a real log?)")
            continue
        res = [score(est, corrected(rec, acc, gyr)) for acc, gyr in ((False, False), (True, False), (False, True), (True, True))]
        sim = rec.meta.get("simulation", {})
        rows.append((sim.get("aircraft", "?"), rec.meta.get("sensor_preset", "?"), res))
        print(f"{f.stem[:44]:<44}" + "".join(f"{r:>14.2f} {n:>7.2f}" for r, n in res), flush=True)
    if not rows:
        print("no simulated flight with sensor truth found")
        return 2
    print("\nmean per aircraft and sensor grade (n flights)")
    for key in sorted({(a, s) for a, s, _ in rows}):
        sel = np.array([r for a, s, r in rows if (a, s) == key])  # (n, 4 cases, 2)
        print(f"{key[0] + ' ' + key[1] + f' ({len(sel)})':<44}" + "".join(f"{x:>14.2f} {y:>7.2f}" for x, y in sel.mean(axis=0)))
    allr = np.array([r for _, _, r in rows])
    print(f"{'all (' + str(len(allr)) + ')':<44}" + "".join(f"{x:>14.2f} {y:>7.2f}" for x, y in allr.mean(axis=0)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
