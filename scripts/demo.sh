#!/usr/bin/env bash
# The demo: set-up, then make data, train, predict, evaluate and write out/demo/report.md.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl}
python3 -m isa demo --out out/demo "$@"
