#!/usr/bin/env bash
# Every test: create/reuse .venv, install the project with its test extra (builds the Rust
# extension in release mode), run the Rust core's tests, then the Python suite.
set -euo pipefail
cd "$(dirname "$0")"
if [ ! -x .venv/bin/python ]; then
  "${PYTHON:-python3}" -m venv .venv
fi
# shellcheck disable=SC1091
. .venv/bin/activate
python -m pip install --disable-pip-version-check -q ".[test]"
echo "== lint: ruff, rustfmt, clippy (the stub check is tests/engine/test_engine_stub.py)"
ruff check python tests benches scripts
ruff format --check python tests benches scripts
if cargo fmt --version >/dev/null 2>&1 && cargo clippy --version >/dev/null 2>&1; then
  cargo fmt --all --check
  cargo clippy --release --all-targets -- -D warnings
else
  echo "!! rustfmt/clippy are not installed here: the Rust lint did NOT run (rustup component add rustfmt clippy)"
fi
echo "== cargo test --release (crates/psf-engine)"
cargo test --release
echo "== pytest"
python -m pytest -q tests
