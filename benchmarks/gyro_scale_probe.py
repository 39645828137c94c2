"""Can the gyro's scale be read from the data alone? A probe on the BROAD trials, beside VQF.

Where VQF's error on BROAD comes from (session 10): a common gyro scale of 1.005 takes trial 08 from
1.76° to 1.01°, while 0.995 or 1.01 make most trials worse. This probe estimates the scale without
the truth: at the ends of each motion phase between two rests (|ω| < 0.35 rad/s and ||a| − g| <
0.3 m/s² over 0.2 s), the gravity the accelerometer shows against the gyro's rotation over the phase
(bias: the gyro's mean at rest), for a grid of scales; the median disagreement per scale says which
fits. A trial's scale is taken only where it is clear (``--min-phases`` phases, the disagreement down
by ``--min-gain`` against scale 1) — a threshold chosen on these same (seen) trials.

Printed per trial: the phases, the disagreement at scale 1 and at the best, the scale taken, and
VQF's inclination RMSE (5 s warm-up, as ``real_vs_peers.py``) on the gyro as logged and scaled by it,
both in this run. Whole-trial and not causal: an upper bound for an online estimate. What ships since
session 13 is its per-axis successor with a leave-one-phase-out evidence gate,
``tepinn_flight/model/gyro_selfcal.py`` (``AnchorConfig.gyro_selfcal``); this probe stays as session 10 ran it.

    python benchmarks/gyro_scale_probe.py [--shared ../shared] [--min-phases 2] [--min-gain 0.3]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numba
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tepinn_flight.quat_scalar import exp_rotvec, qmul, qnorm  # noqa: E402

SCALES = np.array([0.985, 0.99, 0.995, 1.0, 1.005, 1.01, 1.015])


@numba.njit(cache=True)
def _attitudes(gyr, dt, scale, bias):
    """Body → start-frame quaternions of the gyro integrated with ``scale`` (exact per-sample turns)."""
    n = len(gyr)
    q = np.empty((n, 4))
    w, x, y, z = 1.0, 0.0, 0.0, 0.0
    for i in range(n):
        q[i, 0], q[i, 1], q[i, 2], q[i, 3] = w, x, y, z
        dw, dx, dy, dz = exp_rotvec((scale * gyr[i, 0] - bias[0]) * dt[i], (scale * gyr[i, 1] - bias[1]) * dt[i],
                                    (scale * gyr[i, 2] - bias[2]) * dt[i])  # fmt: skip
        w, x, y, z = qnorm(*qmul(w, x, y, z, dw, dx, dy, dz))
    return q


def phase_disagreement(rec) -> tuple[int, np.ndarray]:
    """(phases, median end-to-end gravity disagreement in degrees per scale of ``SCALES``)."""
    from tepinn_flight.quat import quat_conj, quat_mul, quat_rotate

    t, g, a = rec.t_s, np.nan_to_num(rec.gyr_rad_s), np.nan_to_num(rec.acc_m_s2)
    dt = np.diff(t, append=t[-1] + np.median(np.diff(t)))
    k = max(1, int(0.2 / np.median(dt)))
    box = np.ones(k) / k
    a_lp = np.stack([np.convolve(a[:, i], box, "same") for i in range(3)], 1)
    rest = (np.convolve(np.linalg.norm(g, axis=1), box, "same") < 0.35) & (np.abs(np.linalg.norm(a_lp, axis=1) - 9.81) < 0.3)
    idx = np.flatnonzero(rest)
    runs = [r for r in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1) if len(r) >= k]
    bias = g[rest].mean(0) if rest.sum() > 100 else np.zeros(3)
    path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(g, axis=1) * dt)])
    phases = [(r0[-1], r1[0]) for r0, r1 in zip(runs[:-1], runs[1:])
              if t[r1[0]] - t[r0[-1]] <= 120.0 and np.degrees(path[r1[0]] - path[r0[-1]]) >= 90.0]  # fmt: skip
    if not phases:
        return 0, np.full(len(SCALES), np.nan)
    cost = np.empty((len(SCALES), len(phases)))
    for si, s in enumerate(SCALES):
        q = _attitudes(np.ascontiguousarray(g), dt, float(s), bias)
        for pi, (i0, i1) in enumerate(phases):
            d = quat_mul(quat_conj(q[i0]), q[i1])
            g0, g1 = a_lp[i0] / np.linalg.norm(a_lp[i0]), a_lp[i1] / np.linalg.norm(a_lp[i1])
            cost[si, pi] = np.degrees(np.arccos(np.clip(np.dot(quat_rotate(quat_conj(d), g0), g1), -1.0, 1.0)))
    return len(phases), np.median(cost, axis=1)


def vqf_rmse_deg(rec) -> float:
    """VQF's inclination RMSE, logging dropouts bridged and scored as everywhere (5 s warm-up)."""
    from tepinn_flight.evaluation.peers import VqfEstimator
    from tepinn_flight.model.finetune import inclination_rmse_deg
    from tepinn_flight.record_gaps import bridge_gaps

    br = bridge_gaps(rec)
    return inclination_rmse_deg(rec, br.original(VqfEstimator().estimate(br.record)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument("--shared", default=str(REPO.parent / "shared"))
    ap.add_argument("--min-phases", type=int, default=2)
    ap.add_argument("--min-gain", type=float, default=0.3, help="disagreement down by at least this fraction")
    args = ap.parse_args()

    from tepinn_flight.ingest import ingest_log
    from tepinn_flight.record import GYR_COLS, FlightRecord

    trials = sorted((Path(args.shared) / "broad").glob("*.hdf5"))
    if not trials:
        print(f"no BROAD trials in {Path(args.shared) / 'broad'}")
        return 2
    print(f"{'trial':<46}{'phases':>7}{'at 1':>7}{'best':>7}{'scale':>7}{'VQF':>8}{'VQF scaled':>11}")
    base, scaled = [], []
    for p in trials:
        rec = ingest_log(p)
        n, cost = phase_disagreement(rec)
        best = int(np.nanargmin(cost)) if n else SCALES.tolist().index(1.0)
        c1 = cost[SCALES.tolist().index(1.0)]
        s = SCALES[best] if n >= args.min_phases and cost[best] <= (1.0 - args.min_gain) * c1 else 1.0
        v = vqf_rmse_deg(rec)
        if s != 1.0:
            d = rec.data.copy()
            d[GYR_COLS] = d[GYR_COLS] * s
            vs = vqf_rmse_deg(FlightRecord(d, dict(rec.meta)))
        else:
            vs = v
        base.append(v)
        scaled.append(vs)
        print(f"{p.name[:46]:<46}{n:>7}{c1:>7.2f}{cost[best]:>7.2f}{s:>7.3f}{v:>8.3f}{vs:>11.3f}", flush=True)
    print(f"\nmean VQF {np.mean(base):.3f}° as logged, {np.mean(scaled):.3f}° with the probed scale "
          f"(ratio {np.mean(scaled) / np.mean(base):.3f}); {len(trials)} trials, all seen by the shipped network")
    return 0


if __name__ == "__main__":
    sys.exit(main())
