#!/usr/bin/env bash
# Issue 35 item 4: the street detector pre-trained longer, on clean and noisy dusk scenes,
# resumable across sessions (run it again to continue):
#   bash scripts/issue35_detector.sh [RUN_DIR] [STEPS]   (default benches/results/issue35/detector, 6000)
# 4,000 street scenes of 192 x 288 (the design run's crop; regenerated from their seed each
# time, data/ is not kept), each training image darkened by a log-uniform factor in [0.1, 1] in
# linear light and half of them given the design run's sensor noise (--noise 0.5), batch 8,
# AdamW with warm-up and a cosine decay over STEPS, THREADS torch threads (default 2). A session's background
# work does not outlive it: the run's checkpoint (detector.pt, with the optimizer's state) resumes a
# run in the same folder; git keeps only eval_clean.json (the detector ships as street-pretrained,
# tasks/bundled/detectors.json). Then the clean held-out mAP (150 scenes, seed 1).
set -euo pipefail
RUN="${1:-benches/results/issue35/detector}"
STEPS="${2:-6000}"
DATA=data/street192x288-4000
[ -f "$DATA/annotations.json" ] || optix scenes street --out "$DATA" -n 4000 --size 192x288 --seed 0 --quiet
[ -f "${DATA}_test/annotations.json" ] || optix scenes street --out "${DATA}_test" -n 150 --size 192x288 --seed 1 --quiet
optix detect train "$DATA" --out "$RUN" --steps "$STEPS" --threads "${THREADS:-2}" --dim 0.1 --noise 0.5 --quiet
optix detect eval "$RUN" "${DATA}_test" > "$RUN/eval_clean.json"
cat "$RUN/eval_clean.json"
