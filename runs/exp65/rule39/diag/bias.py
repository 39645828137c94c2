"""Rule 39b's loss flights: the estimate's gyro bias (and its error against the truth's bias) for both arms at the start
of the maneuver where 39b loses most, and the tilt error there."""
import functools, glob
import numpy as np
import tepinn_flight.model.estimate as E
from tepinn_flight.evaluation.estimators import default_tepinn
from tepinn_flight.model.gnss_aid import GnssAidConfig
from tepinn_flight.record import read_record

CASES = [("sims/0001", 42.58), ("sims/0032", 48.9), ("sims50/0003", 45.1), ("sims_judge/0006", 45.3)]
tep = default_tepinn(runtime="auto")
for key, t0 in CASES:
    b, k = key.split("/")
    rec = read_record(glob.glob(f"/work/review64/fw/{b}/{k}-*.parquet")[0])
    i = np.searchsorted(rec.t_s, t0)
    truth = rec.data[["gyr_bias_x_rad_s", "gyr_bias_y_rad_s", "gyr_bias_z_rad_s"]].to_numpy()[i]
    out = {}
    for arm in ("ship", "39b"):
        E.GnssAidConfig = (functools.partial(GnssAidConfig, gate_after_hard_for=("fixed-wing",), gate_after_hard_speed=True)
                           if arm == "39b" else GnssAidConfig)
        est = tep.estimate(rec)
        E.GnssAidConfig = GnssAidConfig
        cols = [c for c in est.columns if "bias" in c and "gyr" in c]
        out[arm] = est[cols].to_numpy()[i]
    print(key, "at", t0, "s: truth bias (deg/s)", np.round(np.degrees(truth), 3), "| ship", np.round(np.degrees(out["ship"]), 3),
          "| 39b", np.round(np.degrees(out["39b"]), 3))
