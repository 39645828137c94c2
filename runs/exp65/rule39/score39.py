"""Rules 39/39b/39c's measurement (runs/exp65/rule39.md): the candidates (fixed wing: aided windows keep the flight-speed
gate 3 s after the receiver shows a hard manoeuvre) on the c172x flights of the given folders; shipped / no-aid / VQF too where not scored before
(review64/fw/results.jsonl holds them for its four folders). One process, resumable.
usage: python score39.py OUT.jsonl FOLDER [FOLDER...] [--arms=candidate,candidate_b,candidate_b29,candidate_b31,candidate_c,aid,noaid,vqf]
(candidate: rule 39; candidate_b: 39b, its span 2.9/3.1 s in _b29/_b31; candidate_c: 39c; PYTHONPATH: a worktree with rule39c.patch)"""
import dataclasses, functools, json, sys, time
from pathlib import Path

import tepinn_flight.model.estimate as est_mod
from tepinn_flight.evaluation.estimators import TepinnEstimator, default_tepinn
from tepinn_flight.evaluation.harness import HarnessConfig, evaluate
from tepinn_flight.evaluation.peers import VqfEstimator
from tepinn_flight.model.gnss_aid import GnssAidConfig
from tepinn_flight.record import read_record


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--arms")]
    arms = ["candidate"]
    for a in sys.argv[1:]:
        if a.startswith("--arms="):
            arms = a.split("=", 1)[1].split(",")
    out, folders = Path(args[0]), args[1:]
    tep = default_tepinn(runtime="auto")
    noaid = TepinnEstimator(tep.model, dataclasses.replace(tep.fusion, gnss_aid=False), "noaid", tep.checkpoint)
    have = set()
    if out.exists():
        have = {(d["batch"], d["flight"], d["arm"]) for d in map(json.loads, out.read_text().splitlines())}
    for folder in folders:
        for p in sorted(Path(folder).glob("*.parquet")):
            rec = None
            for arm in arms:
                if (Path(folder).name, p.stem, arm) in have:
                    continue
                rec = rec or read_record(p)
                t0 = time.time()
                est_mod.GnssAidConfig = (functools.partial(GnssAidConfig, gate_after_hard_for=("fixed-wing",), gate_after_hard_speed=arm.startswith("candidate_b") or arm == "candidate_c", gate_after_hard_last_pass_only=(arm == "candidate_c"), gate_after_hard_s={"candidate_b29": 2.9, "candidate_b31": 3.1}.get(arm, 3.0))
                                         if arm.startswith("candidate") else GnssAidConfig)
                e = {"candidate": tep, "candidate_b": tep, "candidate_b29": tep, "candidate_b31": tep, "candidate_c": tep, "aid": tep, "noaid": noaid, "vqf": VqfEstimator()}[arm]
                r = evaluate([rec], [e], HarnessConfig(), progress=False, keep_series=False).records[0]
                est_mod.GnssAidConfig = GnssAidConfig
                row = {"batch": Path(folder).name, "flight": p.stem, "arm": arm,
                       "incl": r["results"][e.name]["inclination_rmse_deg"], "sec": round(time.time() - t0, 2)}
                with out.open("a") as fh:
                    fh.write(json.dumps(row) + "\n")
                print(row, flush=True)


if __name__ == "__main__":
    main()
