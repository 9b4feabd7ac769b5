#!/usr/bin/env bash
# The pre-trained street detector that `optix design detection` starts from (issue 19; shipped as
# python/optix_e2e/tasks/bundled/street_detector.pt, docs/detection.md):
#   bash scripts/train_street_detector.sh [DATA] [RUN_DIR] [MINUTES]
# 2000 street scenes of 192 x 288 (the design run's crop), noise-free renderings darkened by a
# log-uniform factor in [0.1, 1] in linear light (dusk exposures), trained on one CPU thread.
set -euo pipefail
DATA="${1:-data/street192}"
RUN="${2:-runs/det192d}"
MINUTES="${3:-32}"
optix scenes street --out "$DATA" -n 2000 --size 192x288 --seed 0 --quiet
optix detect train "$DATA" --out "$RUN" --minutes "$MINUTES" --steps 20000 --threads 1 --dim 0.1 --quiet
optix scenes street --out "${DATA}_test" -n 150 --size 192x288 --seed 1 --quiet
optix detect eval "$RUN" "${DATA}_test"
