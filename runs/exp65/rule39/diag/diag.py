"""Where rule 39b loses against shipped on its six design loss flights: per maneuver, the inclination RMSE of both
arms, and the share of the maneuver's samples in 'hard' windows (|a_gnss| > 15 within 3 s). PYTHONPATH = a worktree
with runs/exp65/rule39/rule39b.patch applied."""
import ast, functools, sys
import numpy as np
import tepinn_flight.model.estimate as E
from tepinn_flight.evaluation.estimators import default_tepinn
from tepinn_flight.model.gnss_aid import GnssAidConfig, after_hard, gnss_evidence
from tepinn_flight.quat import gravity_body
from tepinn_flight.record import read_record

FW = "/work/review64/fw/"
LOSSES = ["sims/0001", "sims/0025", "sims/0032", "sims50/0003", "sims50/0010", "sims_judge/0006"]


def incl(qa, qb):
    ga, gb = gravity_body(qa), gravity_body(qb)
    return np.degrees(np.arccos(np.clip(np.sum(ga * gb, 1), -1, 1)))


def main():
    import glob
    tep = default_tepinn(runtime="auto")
    for key in LOSSES:
        b, k = key.split("/")
        path = glob.glob(FW + b + "/" + k + "-*.parquet")[0]
        rec = read_record(path)
        errs = {}
        for arm in ("ship", "39b"):
            E.GnssAidConfig = (functools.partial(GnssAidConfig, gate_after_hard_for=("fixed-wing",), gate_after_hard_speed=True)
                               if arm == "39b" else GnssAidConfig)
            q = tep.estimate(rec)[["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy()
            E.GnssAidConfig = GnssAidConfig
            errs[arm] = incl(q, rec.q_ref_wxyz)
        t = rec.t_s
        ev = gnss_evidence(t, rec.gnss_vel_ne_m_s, GnssAidConfig())
        hard = after_hard(t, ev.za, GnssAidConfig())
        gs = np.hypot(rec.gnss_vel_ne_m_s[:, 0], rec.gnss_vel_ne_m_s[:, 1])
        m = t >= 5.0
        rm = lambda e, s: float(np.sqrt(np.mean(e[s] ** 2))) if s.any() else float("nan")
        print(f"\n{key} {path.split('/')[-1][5:-11]}: RMSE ship {rm(errs['ship'], m):.2f} 39b {rm(errs['39b'], m):.2f}; hard {hard[m].mean():.0%} of samples")
        mv = rec.meta["maneuvers"]
        for a0, a1, name in (ast.literal_eval(mv) if isinstance(mv, str) else mv):
            s = m & (t >= a0) & (t < a1)
            if not s.any():
                continue
            d = errs["39b"][s] - errs["ship"][s]
            print(f"  {name:16s} {a0:5.1f}-{a1:5.1f}  ship {rm(errs['ship'], s):5.2f}  39b {rm(errs['39b'], s):5.2f}  "
                  f"hard {hard[s].mean():4.0%}  gs {np.nanmin(gs[s]):4.1f}-{np.nanmax(gs[s]):4.1f}  max Δ {d.max():+5.1f} at {t[s][d.argmax()]:.1f}s")


if __name__ == "__main__":
    main()
