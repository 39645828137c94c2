"""Per-trial σ of the shipped estimate on the 17 seen BROAD trials (design data): NEES, within 3σ, and the error/σ
tails, to see where σ misses. Saves the per-sample error vector and σ for design work."""
import sys
from pathlib import Path
import numpy as np

if __name__ == "__main__":
    from tepinn_flight.evaluation.estimators import TepinnEstimator
    from tepinn_flight.model.checkpoint import default_model_path
    from tepinn_flight.ingest import load_record
    from tepinn_flight.evaluation.harness import scoring_mask
    from tepinn_flight.evaluation.metrics import error_quat_earth, tilt_error_vector_rad, uncertainty_metrics
    est = TepinnEstimator.from_checkpoint(default_model_path(), "tepinn")
    out = Path(sys.argv[1]); out.mkdir(parents=True, exist_ok=True)
    Q = ["q_est_w", "q_est_x", "q_est_y", "q_est_z"]
    for p in sorted(Path("../shared/broad").glob("*.hdf5")):
        rec = load_record(p)
        df = est.estimate(rec)
        q = df[Q].to_numpy()
        mm = scoring_mask(rec, 5.0) & np.all(np.isfinite(q), 1)
        e = tilt_error_vector_rad(error_quat_earth(q[mm], rec.q_ref_wxyz[mm]))
        s = df["sigma_rad"].to_numpy()[mm]
        u = uncertainty_metrics(e, s)
        r = np.linalg.norm(e, axis=1) / s
        np.savez(out / (p.stem + ".npz"), e=e, s=s, t=rec.data["t_s"].to_numpy()[mm],
                 gyr=rec.data[["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"]].to_numpy()[mm],
                 acc=rec.data[["acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2"]].to_numpy()[mm])
        print(f"{p.stem[:45]:45s} NEES {u['nees']:.2f} in3 {100*u['coverage_3sigma']:.1f}% rho {u['spearman']:.2f} "
              f"σ med {np.degrees(np.median(s)):.2f}° |e| rms {np.degrees(np.sqrt(np.mean(np.sum(e**2,1)))):.2f}° max r {r.max():.1f}", flush=True)
