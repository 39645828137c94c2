"""Design experiment (session 66, deciding nothing by itself): how σ of the shipped estimate scores when the
reference is a causal filter (our EKF, VQF) instead of the truth, on seen design flights (design50, seed 5151).
Question: do misses like a real flight's against its autopilot come from the reference being a causal estimate?"""
import sys, json
from pathlib import Path
import numpy as np

if __name__ == "__main__":
    from tepinn_flight.evaluation.estimators import FilterEstimator, TepinnEstimator
    from tepinn_flight.evaluation.filters import Ekf
    from tepinn_flight.evaluation.peers import VqfEstimator
    from tepinn_flight.model.checkpoint import default_model_path
    from tepinn_flight.record import read_record
    from tepinn_flight.evaluation.harness import scoring_mask
    from tepinn_flight.evaluation.metrics import error_quat_earth, inclination_error_rad, tilt_error_vector_rad, uncertainty_metrics
    folder = Path(sys.argv[1])
    ests = [TepinnEstimator.from_checkpoint(default_model_path(), "tepinn"), FilterEstimator(Ekf(), name="ekf"), VqfEstimator()]
    rows = []
    Q = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]
    for p in sorted(folder.glob("*.parquet")):
        rec = read_record(p)
        dfs = {e.name: e.estimate(rec) for e in ests}
        q = {k: d[Q].to_numpy() for k, d in dfs.items()}
        q["truth"] = rec.q_ref_wxyz
        mm = scoring_mask(rec, 5.0) & np.all(np.isfinite(q["tepinn"]), 1)
        sig = dfs["tepinn"]["sigma_rad"].to_numpy()[mm]
        r = {"file": p.name}
        for ref in ("truth", "ekf", "vqf"):
            qe = error_quat_earth(q["tepinn"][mm], q[ref][mm])
            u = uncertainty_metrics(tilt_error_vector_rad(qe), sig)
            r[ref] = (float(np.degrees(np.sqrt(np.mean(inclination_error_rad(qe) ** 2)))), u["nees"], u["coverage_3sigma"])
        for ref in ("ekf", "vqf"):
            qe = error_quat_earth(q[ref][mm], q["truth"][mm])
            r[ref + "_vs_truth"] = float(np.degrees(np.sqrt(np.mean(inclination_error_rad(qe) ** 2))))
        rows.append(r)
        print(r["file"][:40], " ".join(f"{k}: {v[0]:.2f}° {v[1]:.2f} {100*v[2]:.1f}%" for k, v in r.items() if isinstance(v, tuple)),
              f"ekf/truth {r['ekf_vs_truth']:.2f} vqf/truth {r['vqf_vs_truth']:.2f}", flush=True)
    for ref in ("truth", "ekf", "vqf"):
        a = np.array([r[ref] for r in rows])
        print(f"mean vs {ref}: RMSE {a[:,0].mean():.2f}°, NEES {a[:,1].mean():.2f}, within 3σ {100*a[:,2].mean():.1f}%")
    json.dump(rows, open(folder / "refproxy.json", "w"), indent=1)
