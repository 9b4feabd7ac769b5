#!/usr/bin/env bash
# The eight-element experiment's data and surrogate (issue 21; docs/eight-element.md):
#   bash scripts/train_apo8_surrogate.sh [DATA_ROOT] [RUN_DIR] [MINUTES]
# 12288 training designs + 1024 test designs of the bundled `apo-gauss-8e-mv` space, traced
# with the lens's clear apertures (its vignetting is part of every design's PSFs and relative
# illumination), in a 64 um window at 1 um (9 x 9 sensor pixels of 5.86 um: the space's
# PSFs are one to three pixels wide), then the surrogate trained on this machine's CPU, then
# its accuracy on the test designs, per field.
set -euo pipefail
DATA="${1:-data/apo8}"
RUN="${2:-runs/sur_apo8}"
MINUTES="${3:-45}"
SET=(--apertures fixed --window-um 64 --pixel-um 1)
optix dataset generate apo-gauss-8e-mv -n 12288 --seed 0 --out "$DATA/train" "${SET[@]}"
optix dataset generate apo-gauss-8e-mv -n 1024 --seed 1 --out "$DATA/test" "${SET[@]}"
optix surrogate train "$DATA/train" --out "$RUN" --minutes "$MINUTES" --steps 200000 --batch 128 \
      --threads 2 --val-every 1000
optix surrogate eval "$RUN" "$DATA/test" --json --out "$RUN/eval"
