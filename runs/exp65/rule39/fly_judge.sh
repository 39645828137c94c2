#!/bin/bash
# rule 39's judging flights: the helper's two TOMLs with NEW seeds (6470: 36 at 400 Hz; 6471: 12 at a 50 Hz IMU)
set -e
cd /work/main/runs/exp65/rule39
. /work/main/.venv/bin/activate
export PYTHONPATH=/work/main
tepinn-flight simulate --campaign /work/review64/fw/design64fw.toml --seed 6470 -o judge400 --workers 1 -q
tepinn-flight simulate --campaign /work/review64/fw/design64fw_50hz.toml --seed 6471 -o judge50 --workers 1 -q
