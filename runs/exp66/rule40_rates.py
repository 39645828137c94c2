"""After rule 40 (deciding nothing by itself): σ on the 17 seen BROAD trials decimated to ArduCopter log rates
(×6 ≈ 48 Hz, ×11 ≈ 26 Hz, by averaging, the training's `decimate_record`), before and after rule 40, from probes."""
import sys
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).parent))

if __name__ == "__main__":
    import rule40_fit as R
    from tepinn_flight.ingest import load_record
    from tepinn_flight.model.tokens import decimate_record
    import tepinn_flight.ingest as ing
    f = int(sys.argv[1])
    files = sorted(Path("../shared/broad").glob("*.hdf5"))
    orig = ing.load_record
    # probe() loads by path: hand it decimated records through a tiny shim
    recs = {p.name: decimate_record(load_record(p), f) for p in files}
    R_load = lambda p: recs[Path(p).name]
    import tepinn_flight.ingest
    tepinn_flight.ingest.load_record = R_load
    out = f"/work/review66/probe_broad_x{f}.npz"
    R.probe(out, [str(p) for p in files])
    d = R.load(out)
    fs = [d[n] for n in sorted(d)]
    o, n = R.score(fs, 0.75, 0.0, 1.0), R.score(fs, 0.5, 0.0005, 3.0)
    print(f"×{f}: before NEES {o[0]:.2f}, {100*o[1]:.2f} % (worst {100*min(o[2]):.1f}); after NEES {n[0]:.2f}, {100*n[1]:.2f} % (worst {100*min(n[2]):.1f})")
