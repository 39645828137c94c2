"""Rule 41's fit and gate (runs/exp66/rule41.md) from rule40_fit.py's probes (which carry N·√Δt as V since rule 41).
Usage: rule41_fit.py BROAD.npz VIB1.npz VIB2.npz VIB4.npz TRAIN4.npz D50.npz"""
import sys
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).parent))
from rule40_fit import load, sigma

S, K, TAU = 0.5, 0.0005, 3.0
GRID = (0.0, 0.01, 0.02, 0.03, 0.05, 0.08, 0.12)


def score(files, kv):
    ne, cv = [], []
    for d in files:
        v = sigma(d, S, K, TAU, kv) ** 2
        ne.append(np.mean(d["e2"] / v)); cv.append(np.mean(d["e2"] <= 9 * v))
    return float(np.mean(ne)), float(np.mean(cv)), cv


if __name__ == "__main__":
    broad, v1, v2, v4, tr, d50 = [[d[n] for n in sorted(d)] for d in map(load, sys.argv[1:7])]
    pooled = v1 + v2 + v4
    for kv in GRID:
        print(f"k_v {kv:.2f}: vibration 1/2/4 pooled NEES {score(pooled, kv)[0]:.2f} {100*score(pooled, kv)[1]:.2f} %; "
              + "; ".join(f"{n} NEES {score(f, kv)[0]:.2f} {100*score(f, kv)[1]:.2f} %"
                          for n, f in (("1", v1), ("2", v2), ("4", v4), ("clean", broad), ("train4", tr), ("d50", d50))))
    ok = [kv for kv in GRID if score(pooled, kv)[1] >= 0.97]
    kv = min(ok) if ok else max(GRID, key=lambda k: score(pooled, k)[1])
    print(f"rule 41's choice: k_v {kv}")
    c0, c1 = score(broad, 0.0), score(broad, kv)
    a = c1[1] >= c0[1] - 0.001 and c1[0] >= 1.5
    band = lambda x: 0.0 if 1.5 <= x <= 2.5 else min(abs(x - 1.5), abs(x - 2.5))
    b = True
    for n, f in (("train4", tr), ("d50", d50)):
        o, w = score(f, 0.0), score(f, kv)
        okb = w[1] >= o[1] - 0.003 and (band(w[0]) == 0 if band(o[0]) == 0 else band(w[0]) <= band(o[0]) + 0.1)
        b &= okb
        print(f"gate (b) {n}: NEES {o[0]:.2f} {100*o[1]:.2f} % -> {w[0]:.2f} {100*w[1]:.2f} %: {'pass' if okb else 'FAIL'}")
    c = score(v4, kv)[0] <= 2.5
    print(f"gate (a) clean BROAD: NEES {c0[0]:.2f} {100*c0[1]:.2f} % -> {c1[0]:.2f} {100*c1[1]:.2f} %: {'pass' if a else 'FAIL'}")
    print(f"gate (c) at 4 m/s²: NEES {score(v4, 0.0)[0]:.2f} -> {score(v4, kv)[0]:.2f}: {'pass' if c else 'FAIL'}")
    print(f"ship: {'yes' if a and b and c else 'no'}")
