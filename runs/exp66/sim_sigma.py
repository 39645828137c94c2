"""The shipped σ's per-file averaged NEES and share within 3σ on a folder of simulated records, two decimals
(disclosure after rule 40: `real_vs_peers.py` prints one)."""
import sys
from pathlib import Path
import numpy as np

if __name__ == "__main__":
    from tepinn_flight.evaluation.estimators import TepinnEstimator
    from tepinn_flight.model.checkpoint import default_model_path
    from tepinn_flight.record import read_record
    from tepinn_flight.evaluation.harness import scoring_mask
    from tepinn_flight.evaluation.metrics import error_quat_earth, tilt_error_vector_rad, uncertainty_metrics
    est = TepinnEstimator.from_checkpoint(default_model_path(), "tepinn")
    Q = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]
    ne, cv = [], []
    for p in sorted(Path(sys.argv[1]).glob("*.parquet")):
        rec = read_record(p)
        df = est.estimate(rec)
        q = df[Q].to_numpy()
        m = scoring_mask(rec, 5.0) & np.all(np.isfinite(q), 1)
        u = uncertainty_metrics(tilt_error_vector_rad(error_quat_earth(q[m], rec.q_ref_wxyz[m])), df["sigma_rad"].to_numpy()[m])
        ne.append(u["nees"]); cv.append(u["coverage_3sigma"])
    print(f"{len(ne)} files: mean NEES {np.mean(ne):.3f}, within 3σ {100*np.mean(cv):.2f} %")
