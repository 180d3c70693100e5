#!/usr/bin/env bash
# Every test: set-up (idempotent), then the Rust workspace tests, the Python lint and the Python tests.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo test --workspace --quiet
export PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl}
python3 -m ruff check python tests benches
python3 -m pytest -q tests
