#!/usr/bin/env bash
# Every test: set-up (idempotent), rustfmt, clippy, the Rust workspace tests, the stub check, the Python
# lint and the Python tests.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo fmt --all --check
cargo clippy --workspace --all-targets --quiet -- -D warnings
cargo test --workspace --quiet
# The stubs (python/isa/_core.pyi) match the compiled module (no allowlist needed: private
# names such as the _testing submodule are not checked).
python3 -m mypy.stubtest isa._core
export PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl}
python3 -m ruff check python tests benches
python3 -m pytest -q tests
