"""After rule 40 (deciding nothing): σ on the 17 seen BROAD trials with the accelerometer shaken as robustness.py's
--acc-vibration A does it (white noise and a 60–180 Hz tone, each A m/s² RMS per axis, seed 2000+i), before and
after rule 40, from probes. The README's limitation (4 m/s²: NEES 4.3, 86 % within 3σ) is re-measured here."""
import sys
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).parent))

if __name__ == "__main__":
    import rule40_fit as R
    from tepinn_flight.ingest import load_record
    from tepinn_flight.record import FlightRecord
    import tepinn_flight.ingest
    a = float(sys.argv[1])
    files = sorted(Path("../shared/broad").glob("*.hdf5"))
    recs = {}
    for i, p in enumerate(files):
        rec = load_record(p)
        rng = np.random.default_rng(2000 + i)
        f_hz, ph = rng.uniform(60.0, 180.0), rng.uniform(0.0, 2 * np.pi, 3)
        t = rec.t_s - rec.t_s[0]
        tone = np.sqrt(2.0) * a * np.sin(2 * np.pi * f_hz * t[:, None] + ph)
        acc = rec.acc_m_s2 + a * rng.standard_normal((len(rec), 3)) + tone
        df = rec.data.copy()
        df[["acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2"]] = acc
        recs[p.name] = FlightRecord(df, dict(rec.meta))
    tepinn_flight.ingest.load_record = lambda p: recs[Path(p).name]
    out = f"/work/review66/probe_broad_vib{a:g}.npz"
    R.probe(out, [str(p) for p in files])
    d = R.load(out)
    fs = [d[n] for n in sorted(d)]
    o, n = R.score(fs, 0.75, 0.0, 1.0), R.score(fs, 0.5, 0.0005, 3.0)
    print(f"vibration {a:g} m/s²: before NEES {o[0]:.2f}, {100*o[1]:.2f} % (worst {100*min(o[2]):.1f}); after NEES {n[0]:.2f}, {100*n[1]:.2f} % (worst {100*min(n[2]):.1f})")
