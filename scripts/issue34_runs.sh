#!/usr/bin/env bash
# Issue 34's long runs, resumable (run it again to continue; finished runs are not re-run):
#   bash scripts/issue34_runs.sh [OUT [--no-table]]   (default runs/issue34; logs in OUT/*.log)
# 1. Fig. 12 in the paper-width space on exact optics: Alg. 1 and vanilla from 3 uniform random
#    starts (seeds 0 1 2), the quick budget (docs/e2e.md, "The paper-width space").
# 2. The optics model in the loop with the new processing and crops: surrogate against exact, 3 seeds
#    (step 4; benches/optics_tradeoff.py, docs/optics-in-the-loop.md).
# 3. The main job (iq-software, quick budget, the defaults) on 3 seeds.
# 4. Fig. 12 as in 1, from the nominal lens (seeds 0 1 2).
# 5. The three image-quality tasks at the full budget, 3 seeds each, on the defaults (step 7);
#    --no-table stops before it.
# Run it from the project's environment (source .venv/bin/activate, as ./run.sh makes it).
set -euo pipefail
OUT="${1:-runs/issue34}"
mkdir -p "$OUT"
printf 'optics = "exact"\nspace = "paper-triplet-wide"\nthreads = 2\n' > "$OUT/wide.toml"
fig12() {
  python benches/alg1_vs_vanilla.py --task iq-software --seeds 0 1 2 --budget quick --init "$1" \
    --config "$OUT/wide.toml" --out "$OUT/fig12_wide_$1" >> "$OUT/fig12_wide_$1.log" 2>&1
}
fig12 uniform
python benches/optics_tradeoff.py --points surrogate,exact --seeds 0,1,2 --threads 2 --quiet \
  --out "$OUT/tradeoff" >> "$OUT/tradeoff.log" 2>&1
python benches/e2e_tasks.py --tasks iq-software --budget quick --seeds 0 1 2 --out "$OUT/mainjob_quick" \
  >> "$OUT/mainjob_quick.log" 2>&1
fig12 nominal
[ "${2:-}" = "--no-table" ] && exit 0
python benches/e2e_tasks.py --budget full --seeds 0 1 2 --out "$OUT/table_full" >> "$OUT/table_full.log" 2>&1
