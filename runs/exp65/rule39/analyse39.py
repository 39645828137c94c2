"""Rule 39's table: per batch group, mean inclination RMSE of shipped (aid) / candidate / no aid, flights where the
candidate is worse than shipped by > 0.3°, flights worse than no aid by > 0.3° (shipped → candidate).
usage: python analyse39.py ARM CANDIDATE.jsonl BASE.jsonl [BASE.jsonl...] -- GROUP=batch,batch ..."""
import json, sys
from pathlib import Path

ARM = sys.argv.pop(1)
files, groups = sys.argv[1:sys.argv.index("--")], sys.argv[sys.argv.index("--") + 1:]
rows = [json.loads(l) for f in files for l in Path(f).read_text().splitlines()]
val = {(r["batch"], r["flight"], r["arm"]): r["incl"] for r in rows}
print("| flights | n | shipped | candidate | Δ | no aid | worse than shipped > 0.3° | worse than no aid > 0.3° (shipped → candidate) |")
print("|---|---|---|---|---|---|---|---|")
for g in groups:
    name, batches = g.split("=")
    keys = sorted({(b, f) for (b, f, a) in val if b in batches.split(",") and a == "candidate"})
    keys = [k for k in keys if (*k, "aid") in val and (*k, "noaid") in val]
    s = [val[(*k, "aid")] for k in keys]
    c = [val[(*k, ARM)] for k in keys]
    n = [val[(*k, "noaid")] for k in keys]
    worse = [(k[1][:36], round(b - a, 2)) for k, a, b in zip(keys, s, c) if b > a + 0.3]
    m = lambda x: sum(x) / len(x)
    print(f"| {name} | {len(keys)} | {m(s):.2f} | {m(c):.2f} | {m(c) - m(s):+.2f} | {m(n):.2f} | {len(worse)} {worse} | "
          f"{sum(a > x + 0.3 for a, x in zip(s, n))} → {sum(b > x + 0.3 for b, x in zip(c, n))} |")
