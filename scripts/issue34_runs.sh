#!/usr/bin/env bash
# Issue 34's long runs, resumable (run it again to continue; finished runs are not re-run):
#   bash scripts/issue34_runs.sh [OUT]   (default runs/issue34; logs in OUT/*.log)
# 1. Fig. 12 in the paper-width space on exact optics: Alg. 1 and vanilla from 3 uniform random
#    starts (seeds 0 1 2) and from the nominal, the quick budget (docs/e2e.md, "The paper-width space").
# 2. The three image-quality tasks at the full budget, 3 seeds each, on the defaults (step 7).
set -euo pipefail
OUT="${1:-runs/issue34}"
mkdir -p "$OUT"
printf 'optics = "exact"\nspace = "paper-triplet-wide"\nthreads = 2\n' > "$OUT/wide.toml"
for init in uniform nominal; do
  python benches/alg1_vs_vanilla.py --task iq-software --seeds 0 1 2 --budget quick --init "$init" \
    --config "$OUT/wide.toml" --out "$OUT/fig12_wide_$init" >> "$OUT/fig12_wide_$init.log" 2>&1
done
python benches/e2e_tasks.py --budget full --seeds 0 1 2 --out "$OUT/table_full" >> "$OUT/table_full.log" 2>&1
