#!/usr/bin/env bash
# Every test: create/reuse .venv, install the project with its test extra (builds the Rust
# extension in release mode), lint (ruff, rustfmt, clippy), the Rust core's tests, then the
# Python suite (all tiers; the quick tier alone: python -m pytest -m "not slow" tests).
set -euo pipefail
cd "$(dirname "$0")"
start=$SECONDS
stamp() { echo "== $1 (+$((SECONDS - start)) s)"; }
if [ ! -x .venv/bin/python ]; then
  "${PYTHON:-python3}" -m venv .venv
fi
# shellcheck disable=SC1091
. .venv/bin/activate
stamp "install (.venv, uv pip install .[test]: builds the extension, cargo profile ci)"
# uv (pinned, installed by pip) installs what pip would, from its cache in seconds where pip
# took minutes (torch and its CUDA libraries are 6 GB); the project itself is always rebuilt,
# here with cargo's `ci` profile (release optimization without LTO and one codegen unit, the
# same floating-point code): 104 s against 114, and `cargo test --profile ci` below reuses its
# dependencies (compile 76 s against 115). ./run.sh builds the release profile.
# --compile-bytecode: the .pyc files written once here; where PYTHONDONTWRITEBYTECODE is set
# (this machine) Python never writes them, and every process compiled what it imported from
# source (import torch 3.9 s against 1.6; the design run's imports 10.5 s against 4.0).
python -m pip install --disable-pip-version-check -q "uv==0.13.9"
MATURIN_PEP517_ARGS="--profile ci" uv pip install -q --compile-bytecode --refresh-package optix-e2e --reinstall-package optix-e2e ".[test]"
stamp "lint: ruff, rustfmt, clippy (the stub check is tests/engine/test_engine_stub.py)"
ruff check python tests benches scripts
ruff format --check python tests benches scripts
# a hard gate: where rustfmt or clippy is missing, rustup installs them, and without them the
# lint fails (set -e) instead of being skipped; clippy covers the binding crate too
if ! cargo fmt --version >/dev/null 2>&1 || ! cargo clippy --version >/dev/null 2>&1; then
  rustup component add rustfmt clippy
fi
cargo fmt --all --check
cargo clippy --release -p psf-engine -p psf-engine-bench -p psf-engine-py --all-targets -- -D warnings
stamp "cargo test --profile ci (crates/psf-engine; release optimization without LTO)"
cargo test --profile ci
stamp "pytest (two workers, one test file per worker at a time)"
python -m pytest -q -n "${OPTIX_TEST_WORKERS:-2}" --dist loadfile --no-loadscope-reorder --durations=15 tests
stamp "done"
