#!/usr/bin/env bash
# Issue 34's long runs, resumable (run it again to continue; finished runs are not re-run):
#   bash scripts/issue34_runs.sh [OUT [STAGE ...]]   (default OUT benches/results/issue34, every stage)
# Stages, in the order they run:
#   fig12-uniform  Fig. 12 in the paper-width space on exact optics: Alg. 1 and vanilla from 3
#                  uniform random starts (seeds 0 1 2), the quick budget (docs/e2e.md,
#                  "The paper-width space").
#   tradeoff       The optics model in the loop with the new processing and crops: surrogate
#                  against exact, 3 seeds (benches/optics_tradeoff.py, docs/optics-in-the-loop.md).
#   mainjob        The main job (iq-software, quick budget, the defaults) on 3 seeds.
#   fig12-nominal  Fig. 12 as fig12-uniform, from the nominal lens (seeds 0 1 2).
#   table          The three image-quality tasks at the full budget, 3 seeds each, on the defaults.
#   uniform-full   Alg. 1 from the 3 uniform random starts of fig12-uniform at the full budget
#                  (400 steps), exact optics in the paper-width space: do they reach the nominal
#                  camera with 4x the steps? (docs/e2e.md, "The paper-width space").
# Each finished run's results.json, config.json, lens .zmx and summaries are kept in git under the
# default OUT (its .gitignore leaves checkpoints, per-step and per-sample records, TensorBoard and
# images in the local run folder). Logs: OUT/*.log. Run it from the project's environment
# (source .venv/bin/activate, as ./run.sh makes it).
set -euo pipefail
OUT="${1:-benches/results/issue34}"
shift || true
STAGES="${*:-fig12-uniform tradeoff mainjob fig12-nominal table uniform-full}"
mkdir -p "$OUT"
printf 'optics = "exact"\nspace = "paper-triplet-wide"\nthreads = 2\n' > "$OUT/wide.toml"
fig12() {
  python benches/alg1_vs_vanilla.py --task iq-software --seeds 0 1 2 --budget quick --init "$1" \
    --config "$OUT/wide.toml" --out "$OUT/fig12_wide_$1" >> "$OUT/fig12_wide_$1.log" 2>&1
}
for stage in $STAGES; do
  echo "== $stage ($(date -u +%H:%M))"
  case "$stage" in
    fig12-uniform) fig12 uniform ;;
    tradeoff)
      python benches/optics_tradeoff.py --points surrogate,exact --seeds 0,1,2 --threads 2 --quiet \
        --out "$OUT/tradeoff" >> "$OUT/tradeoff.log" 2>&1 ;;
    mainjob)
      python benches/e2e_tasks.py --tasks iq-software --budget quick --seeds 0 1 2 \
        --out "$OUT/mainjob_quick" >> "$OUT/mainjob_quick.log" 2>&1 ;;
    fig12-nominal) fig12 nominal ;;
    table)
      python benches/e2e_tasks.py --budget full --seeds 0 1 2 --out "$OUT/table_full" \
        >> "$OUT/table_full.log" 2>&1 ;;
    uniform-full)
      for seed in 0 1 2; do
        optix design iq-software --budget full --start uniform --seed "$seed" \
          --config "$OUT/wide.toml" --out "$OUT/uniform_full/seed$seed" \
          >> "$OUT/uniform_full_seed$seed.log" 2>&1
      done ;;
    *) echo "unknown stage '$stage' (fig12-uniform tradeoff mainjob fig12-nominal table uniform-full)" >&2; exit 2 ;;
  esac
done
