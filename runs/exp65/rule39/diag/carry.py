"""Rule 39b's loss flights: is the loss in the dive carried by the aid's correction (the aided accelerometer the last
pass reads differs between the arms there) or by the filter's state (the same aided accelerometer)?"""
import functools, glob
import numpy as np
import tepinn_flight.model.estimate as E
from tepinn_flight.evaluation.estimators import default_tepinn
from tepinn_flight.model.gnss_aid import GnssAidConfig
from tepinn_flight.record import read_record

CASES = [("sims/0001", 42.58, 54.32), ("sims/0032", 48.9, 60.0), ("sims50/0003", 45.1, 50.7), ("sims_judge/0006", 45.3, 55.7)]
CAP = []
_orig = E._anchored_pass


def cap(anchor, seg, cols, idx, out, use_mag, vehicle=None):
    res = _orig(anchor, seg, cols, idx, out, use_mag, vehicle)
    CAP.append((np.array(cols[2]), np.asarray(out.get("gnss_fast", [])), np.asarray(out.get("gnss_aided", [])), res[0].copy()))
    return res


E._anchored_pass = cap
tep = default_tepinn(runtime="auto")
for key, t0, t1 in CASES:
    b, k = key.split("/")
    rec = read_record(glob.glob(f"/work/review64/fw/{b}/{k}-*.parquet")[0])
    s = (rec.t_s >= t0) & (rec.t_s < t1)
    got = {}
    for arm in ("ship", "39b"):
        CAP.clear()
        E.GnssAidConfig = (functools.partial(GnssAidConfig, gate_after_hard_for=("fixed-wing",), gate_after_hard_speed=True)
                           if arm == "39b" else GnssAidConfig)
        tep.estimate(rec)
        E.GnssAidConfig = GnssAidConfig
        got[arm] = list(CAP)
    n = min(len(got["ship"]), len(got["39b"]))
    for p in range(n):
        a0, a1 = got["ship"][p][0][s], got["39b"][p][0][s]
        d = np.linalg.norm(a1 - a0, axis=1)
        print(f"{key} pass {p}: aided acc in the dive differs by median {np.median(d):.3f}, max {d.max():.2f} m/s2; "
              f"passes ship {len(got['ship'])} 39b {len(got['39b'])}")
