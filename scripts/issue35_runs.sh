#!/usr/bin/env bash
# Issue 35 item 5's design runs, resumable (run it again to continue; a finished run is not re-run):
#   bash scripts/issue35_runs.sh [OUT [STAGE ...]]   (default OUT benches/results/issue35, every stage)
# Every run starts from the item-4 detector (OUT/detector/detector.pt, scripts/issue35_detector.sh)
# on the detection defaults: the wide space paper-triplet-detect-wide on exact optics
# (camera_design/config.py TASK_BUDGETS), one torch thread each (THREADS to change).
# Stages, in the order they run:
#   quick          Alg. 1, quick budget, seed 0
#   quick-vanilla  vanilla Adam, quick budget, seed 0 (the same steps, batches and noise)
#   compare        the two end-to-end cameras on the same held-out scenes (benches/detection_compare.py)
#   quick-seeds    (named only, not in the default list) Alg. 1, quick budget, seeds 1 and 2 (10 min
#                  each), then the table over seeds 0-2 with the quick stage's seed 0, made on the
#                  same code (benches/detection_seeds.py -> OUT/quick_table.{json,md})
#   tune           (named only) the item-4 detector and the hardware ISP (from its default settings)
#                  trained 2,000 steps behind the nominal lens at dusk (`optix detect tune`; THREADS=2:
#                  27 min) -> OUT/tuned_detector/ (detector.pt with the tuned ISP, tune.json)
#   quick-tuned    (named only) Alg. 1, quick budget, seeds 0 1 2, both cameras starting from the tuned
#                  detector and ISP (isp_init = "detector", OUT/detect_tuned.toml) instead of the
#                  item-4 detector and a random ISP draw; then their table (OUT/quick_tuned_table.{json,md}),
#                  vanilla on seed 0 from the same start and Alg. 1 against it (compare_quick_tuned_*.json)
#   full           Alg. 1, full budget, seeds 0 1 2 (35-60 min each on this CPU: checkpointed), then
#                  their table over seeds (benches/detection_seeds.py -> OUT/full_table.{json,md})
#   full-vanilla   vanilla Adam, full budget, seeds 0 1 2 (the same starts, batches and noise), each
#                  seed's end-to-end camera against Alg. 1's (OUT/compare_full_seedS_alg1_vs_vanilla.json)
#                  and their table over seeds (OUT/full_vanilla_table.{json,md})
#   swap           per seed with both full runs finished: lens x processing + detector between the
#                  nominal, Alg. 1's and vanilla's cameras and the nominal lens blurred by 4 um (a control)
#                  (benches/detection_swap.py -> OUT/swap_full_seedS/),
#                  then the effects over seeds (OUT/swap_table/swap_seeds.{json,md})
# SUFFIX (default empty) is appended to every run's and table's name: SUFFIX=_range holds the runs
# made after lens_steps = "range" became the detection default (2026-11-28); the names without it
# are the runs made before, on Adam's steps in the sigmoid's argument (a finished run is kept as made);
# SUFFIX=_lr5 the quick runs after the quick budget's lr_optics became 5e-2 (2026-11-28, stages quick
# and quick-seeds; its comparison with vanilla used detect_quick_vanilla_range, vanilla not using
# lr_optics: docs/detection.md, "The quick budget at lr 5e-2").
# Each finished run's results.json, config.json and lens .zmx are kept in git under the default OUT
# (its .gitignore); its per-step and per-sample records (history.csv, lens_path.csv, metrics.csv),
# detections and logs stay in the local run folder (the benches that read them need the runs).
set -euo pipefail
OUT="${1:-benches/results/issue35}"
shift || true
STAGES="${*:-quick quick-vanilla compare full full-vanilla swap}"
[ -f "$OUT/detector/detector.pt" ] || { echo "no detector at $OUT/detector/detector.pt: run scripts/issue35_detector.sh first" >&2; exit 2; }
printf 'detector = "detector/detector.pt"\nthreads = %s\n' "${THREADS:-1}" > "$OUT/detect.toml"
printf 'detector = "tuned_detector/detector.pt"\nisp_init = "detector"\nthreads = %s\n' "${THREADS:-1}" \
  > "$OUT/detect_tuned.toml"
S="${SUFFIX:-}"
design() {  # NAME BUDGET OPTIMIZER SEED [CONFIG]
  set -- "$1$S" "$2" "$3" "$4" "${5:-$OUT/detect.toml}"
  [ -f "$OUT/$1/results.json" ] && { echo "$OUT/$1: finished already"; return; }
  optix design detection --budget "$2" --optimizer "$3" --seed "$4" --config "$5" --out "$OUT/$1" \
    --quiet >> "$OUT/$1.log" 2>&1
}
for stage in $STAGES; do
  echo "== $stage ($(date -u +%H:%M))"
  case "$stage" in
    quick) design detect_quick quick alg1 0 ;;
    quick-vanilla) design detect_quick_vanilla quick vanilla 0 ;;
    compare)
      python benches/detection_compare.py "$OUT/detect_quick_vanilla$S" "$OUT/detect_quick$S" \
        --out "$OUT/compare_quick_alg1_vs_vanilla$S.json" ;;
    quick-seeds)
      for s in 1 2; do design "detect_quick_seed$s" quick alg1 "$s"; done
      python benches/detection_seeds.py "$OUT/detect_quick$S" "$OUT"/detect_quick_seed{1,2}"$S" --out "$OUT/quick_table$S" ;;
    tune)
      [ -f "$OUT/tuned_detector/tune.json" ] && grep -q '"tuned"' "$OUT/tuned_detector/tune.json" \
        && { echo "$OUT/tuned_detector: finished already"; continue; }
      optix detect tune --config "$OUT/detect.toml" --out "$OUT/tuned_detector" --steps 2000 \
        --quiet >> "$OUT/tuned_detector.log" 2>&1 ;;
    quick-tuned)
      [ -f "$OUT/tuned_detector/detector.pt" ] || { echo "no tuned detector: run the stage tune first" >&2; exit 2; }
      for s in 0 1 2; do design "detect_quick_tuned_seed$s" quick alg1 "$s" "$OUT/detect_tuned.toml"; done
      python benches/detection_seeds.py "$OUT"/detect_quick_tuned_seed{0,1,2}"$S" --out "$OUT/quick_tuned_table$S"
      design detect_quick_tuned_vanilla_seed0 quick vanilla 0 "$OUT/detect_tuned.toml"
      python benches/detection_compare.py "$OUT/detect_quick_tuned_vanilla_seed0$S" "$OUT/detect_quick_tuned_seed0$S" \
        --out "$OUT/compare_quick_tuned_alg1_vs_vanilla$S.json" ;;
    full)
      for s in 0 1 2; do design "detect_full_seed$s" full alg1 "$s"; done
      python benches/detection_seeds.py "$OUT"/detect_full_seed{0,1,2}"$S" --out "$OUT/full_table$S" ;;
    full-vanilla)
      for s in 0 1 2; do
        design "detect_full_vanilla_seed$s" full vanilla "$s"
        [ -f "$OUT/detect_full_seed$s$S/results.json" ] && python benches/detection_compare.py \
          "$OUT/detect_full_vanilla_seed$s$S" "$OUT/detect_full_seed$s$S" \
          --out "$OUT/compare_full_seed${s}_alg1_vs_vanilla$S.json"
      done
      python benches/detection_seeds.py "$OUT"/detect_full_vanilla_seed{0,1,2}"$S" --out "$OUT/full_vanilla_table$S" ;;
    swap)
      for s in 0 1 2; do
        if [ -f "$OUT/detect_full_seed$s$S/results.json" ] && [ -f "$OUT/detect_full_vanilla_seed$s$S/results.json" ] \
          && [ ! -f "$OUT/swap_full_seed$s$S/detection_swap.json" ]; then
          python benches/detection_swap.py "$OUT/detect_full_seed$s$S" "$OUT/detect_full_vanilla_seed$s$S" \
            --out "$OUT/swap_full_seed$s$S" --blur-um 4 --threads "${THREADS:-1}" >> "$OUT/swap_full_seed$s$S.log" 2>&1 \
            || { echo "swap of seed $s failed: see $OUT/swap_full_seed$s$S.log" >&2; exit 1; }
        fi
      done
      python benches/detection_swap.py --seeds "$OUT"/swap_full_seed{0,1,2}"$S" --out "$OUT/swap_table$S" ;;
    *) echo "unknown stage '$stage' (quick quick-vanilla compare quick-seeds tune quick-tuned full full-vanilla swap)" >&2; exit 2 ;;
  esac
done
