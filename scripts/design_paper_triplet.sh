#!/usr/bin/env bash
# The paper-triplet nominal (docs/designs.md), from the repository root:
#   bash scripts/design_paper_triplet.sh [OUT_DIR] [MINUTES_EACH]
# 1. global searches of the previous nominal's (paper-triplet-v1) 20 variables under the
#    paper's constraints and the sensor corner, one on the RMS spot merit and one on the RMS
#    wavefront merit (tilt per field), MINUTES_EACH minutes each on every core;
# 2. the wavefront search's best, polished on the RMS spot merit with field weights that
#    even the fields out: OUT_DIR/paper-triplet.json, the bundled nominal.
# Writes OUT_DIR/{spot,wavefront}.json (lenses), *.summary.json, *.basins.csv and *.log.
# The searches stop at their time budget, so a rerun visits other basins (their summaries
# record the rounds, polishes and seed).
set -euo pipefail
OUT=${1:-runs/paper-triplet-design}
MIN=${2:-18}
mkdir -p "$OUT"
SPH=s_1_radius,s_2_radius,s_6_radius,s_7_radius,s_1_thickness,s_2_thickness,s_4_thickness,s_5_thickness,s_6_thickness,s_7_thickness
ASP=s_1_conic,s_1_4th,s_1_6th,s_1_8th,s_1_10th,s_6_conic,s_6_4th,s_6_6th,s_6_8th,s_6_10th
# the paper's constraints (Sec. 7) and the sensor's half-diagonal (IMX249: 6.634 mm)
CON="--efl 25 --min-center 2 --min-edge 2 --min-air-gap 1 --min-bfd 10 --min-image-height 6.634 --rings 4 --arms 8"
GLOBAL="--vars $SPH,$ASP $CON --field-weights 1,1,1,2,5 --max-iter 300 --global --seed 1 --minutes $MIN --set-semi-diameters"
for m in spot "wavefront --tilt field"; do
  f=${m%% *}
  optix lens optimize paper-triplet-v1 $GLOBAL --merit $m --out "$OUT/$f.json" \
    --summary "$OUT/$f.summary.json" --basins "$OUT/$f.basins.csv" > /dev/null 2> "$OUT/$f.log"
done
optix lens optimize "$OUT/wavefront.json" --vars $SPH,$ASP $CON --field-weights 1,1,3,4,5 --max-iter 600 \
  --set-semi-diameters --name paper-triplet --out "$OUT/paper-triplet.json" \
  --summary "$OUT/paper-triplet.summary.json" > /dev/null
for m in spot wavefront paper-triplet; do optix lens info "$OUT/$m.json"; done
