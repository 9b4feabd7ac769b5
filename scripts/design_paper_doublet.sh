#!/usr/bin/env bash
# The paper-doublet nominal (issue 57, docs/form-factor.md), from the repository root:
#   bash scripts/design_paper_doublet.sh [OUT_DIR] [MINUTES_EACH]
# The triplet's recipe (scripts/design_paper_triplet.sh) for two singlets at the triplet's
# specification (EFL 25 mm, f/4.4, +-14.9 deg, 470/550/650 nm, the paper's constraints and the
# sensor's half-diagonal): from bundled/spaces/paper-doublet.start.json (a PMMA biconvex, the
# stop, an N-SF11 biconcave; surfaces 1 and 5 even-aspheric),
# 1. global searches of all 19 variables (radii, conics, a4..a10, glass and air thicknesses),
#    one on the RMS spot merit and one on the RMS wavefront merit (tilt per field), MINUTES_EACH
#    minutes each on every core;
# 2. each search's best polished on the RMS spot merit with the triplet's field weights
#    1,1,3,4,5; the better polish (lower merit) is OUT_DIR/paper-doublet.json, the bundled nominal.
# The searches stop at their time budget, so a rerun visits other basins.
set -euo pipefail
OUT=${1:-runs/paper-doublet-design}
MIN=${2:-12}
mkdir -p "$OUT"
START=python/optix_e2e/bundled/spaces/paper-doublet.start.json
SPH=s_1_radius,s_2_radius,s_4_radius,s_5_radius,s_1_thickness,s_2_thickness,s_3_thickness,s_4_thickness,s_5_thickness
ASP=s_1_conic,s_1_4th,s_1_6th,s_1_8th,s_1_10th,s_5_conic,s_5_4th,s_5_6th,s_5_8th,s_5_10th
CON="--efl 25 --min-center 2 --min-edge 2 --min-air-gap 1 --min-bfd 10 --min-image-height 6.634 --rings 4 --arms 8"
GLOBAL="--vars $SPH,$ASP $CON --field-weights 1,1,1,2,5 --max-iter 300 --global --seed 1 --minutes $MIN --set-semi-diameters"
for m in spot "wavefront --tilt field"; do
  f=${m%% *}
  [ -f "$OUT/$f.json" ] || optix lens optimize "$START" $GLOBAL --merit $m --out "$OUT/$f.json" \
    --summary "$OUT/$f.summary.json" --basins "$OUT/$f.basins.csv" > /dev/null 2> "$OUT/$f.log"
done
for f in spot wavefront; do
  optix lens optimize "$OUT/$f.json" --vars $SPH,$ASP $CON --field-weights 1,1,3,4,5 --max-iter 600 \
    --set-semi-diameters --name paper-doublet --out "$OUT/polish-$f.json" \
    --summary "$OUT/polish-$f.summary.json" > /dev/null
done
python - "$OUT" <<'PY'
import json, shutil, sys
out = sys.argv[1]
merit = {f: json.load(open(f"{out}/polish-{f}.summary.json"))["after"]["merit"] for f in ("spot", "wavefront")}
best = min(merit, key=merit.get)
shutil.copy(f"{out}/polish-{best}.json", f"{out}/paper-doublet.json")
print(f"polished merits {merit}: {best} -> {out}/paper-doublet.json")
PY
for m in spot wavefront paper-doublet; do optix lens info "$OUT/$m.json"; done
