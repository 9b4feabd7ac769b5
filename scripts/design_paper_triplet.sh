#!/usr/bin/env bash
# The paper-triplet nominal (docs/designs.md): global searches of the bundled design's 20
# variables under the paper's constraints, one with the RMS spot merit and one with the
# RMS wavefront merit, from the repository root:
#   bash scripts/design_paper_triplet.sh [OUT_DIR] [MINUTES_EACH]
# Writes OUT_DIR/{spot,wavefront}.json (lenses), *.summary.json (basins, figures) and *.log.
set -euo pipefail
OUT=${1:-runs/paper-triplet-design}
MIN=${2:-18}
mkdir -p "$OUT"
SPH=s_1_radius,s_2_radius,s_6_radius,s_7_radius,s_1_thickness,s_2_thickness,s_4_thickness,s_5_thickness,s_6_thickness,s_7_thickness
ASP=s_1_conic,s_1_4th,s_1_6th,s_1_8th,s_1_10th,s_6_conic,s_6_4th,s_6_6th,s_6_8th,s_6_10th
# the paper's constraints (Sec. 7) and the sensor's half-diagonal (IMX249: 6.634 mm)
CON="--efl 25 --min-center 2 --min-edge 2 --min-air-gap 1 --min-bfd 10 --min-image-height 6.634"
COMMON="--vars $SPH,$ASP $CON --field-weights 1,1,1,2,5 --rings 4 --arms 8 --max-iter 300 --global --seed 1 --minutes $MIN --set-semi-diameters"
optix lens optimize paper-triplet $COMMON --merit spot \
  --out "$OUT/spot.json" --summary "$OUT/spot.summary.json" > /dev/null 2> "$OUT/spot.log"
optix lens optimize paper-triplet $COMMON --merit wavefront --tilt field \
  --out "$OUT/wavefront.json" --summary "$OUT/wavefront.summary.json" > /dev/null 2> "$OUT/wavefront.log"
for m in spot wavefront; do optix lens info "$OUT/$m.json"; done
