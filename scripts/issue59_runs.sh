#!/usr/bin/env bash
# Issue 59: detection out of the box. The plain command on its defaults (no config file), quick
# budget, seeds 0 1 2, then their table over seeds; resumable (a finished run is not re-run):
#   bash scripts/issue59_runs.sh [OUT]   (default runs/issue59; 12-17 min a run on this 2-core CPU)
# The defaults: the shipped street-tuned detector and its hardware ISP (isp_init = detector), the
# wide space on exact optics, lens steps even over the ranges, lr_optics 5e-2
# (tasks/detection.py PLUGIN.budgets). benches/results/issue59 keeps each run's results.json,
# config.json and lens files, and the table.
set -euo pipefail
OUT="${1:-runs/issue59}"
mkdir -p "$OUT"
for s in 0 1 2; do
  [ -f "$OUT/quick_seed$s/results.json" ] && { echo "$OUT/quick_seed$s: finished already"; continue; }
  optix design detection --budget quick --seed "$s" --out "$OUT/quick_seed$s" --quiet | tail -4
done
python benches/detection_seeds.py "$OUT"/quick_seed{0,1,2} --out "$OUT/quick_table"
