#!/usr/bin/env bash
# The end-to-end design space's data and surrogate (issue 18 item 5; docs/e2e.md):
#   bash scripts/train_e2e_surrogate.sh [DATA_ROOT] [RUN_DIR] [MINUTES]
# 12288 training designs + 1024 test designs of the bundled `paper-triplet-e2e` space, with a
# 246 um window (41 sensor pixels at 5.86 um, which holds the outer fields' PSFs; the
# super-resolved PSFs at 2 um to keep the data at 2.4 MB per design), then the surrogate
# trained on this machine's CPU, then its accuracy on the test designs.
set -euo pipefail
DATA="${1:-data/e2e}"
RUN="${2:-runs/sur_e2e}"
MINUTES="${3:-100}"
WIN=(--window-um 246 --pixel-um 2)
optix dataset generate paper-triplet-e2e -n 12288 --seed 0 --out "$DATA/train" "${WIN[@]}"
optix dataset generate paper-triplet-e2e -n 1024 --seed 1 --out "$DATA/test" "${WIN[@]}"
optix surrogate train "$DATA/train" --out "$RUN" --minutes "$MINUTES" --steps 200000 --batch 128 \
      --threads 2 --val-every 1000
optix surrogate eval "$RUN" "$DATA/test" --json --out "$RUN/eval"
