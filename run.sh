#!/usr/bin/env bash
# Fresh machine -> results: create .venv, build and install the project (the Rust engine
# is compiled in release mode by maturin through a PEP 517 build; the installer is uv, pinned,
# itself installed by pip: it installs torch's 6 GB in seconds from its cache), then run the main
# job: an end-to-end design of the paper's Cooke triplet with a software ISP for image
# quality (optix design iq-software, budget quick), against the nominal lens with its
# processing fine-tuned for the same steps, evaluated under the engine's exact PSFs.
#   ./run.sh [OUT_DIR]        (default: results; running it again resumes / reuses the run)
set -euo pipefail
cd "$(dirname "$0")"
OUT="${1:-results}"
if [ ! -x .venv/bin/python ]; then
  "${PYTHON:-python3}" -m venv .venv
fi
# shellcheck disable=SC1091
. .venv/bin/activate
python -m pip install --disable-pip-version-check -q "uv==0.13.9"
uv pip install -q --compile-bytecode --refresh-package optix-e2e --reinstall-package optix-e2e .  # .pyc once (test.sh says why)
optix design iq-software --out "$OUT/design-iq-software"
echo "results: $OUT/design-iq-software/results.json (panels.png, psf_*.png, lens/end_to_end.zmx, report/);"
echo "TensorBoard: tensorboard --logdir $OUT/design-iq-software/tb; the PSF demo: optix demo --out $OUT/psf-demo"
