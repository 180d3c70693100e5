#!/usr/bin/env bash
# The fuzzing campaign (docs/fuzzing.md): every cargo-fuzz target in fuzz/ for MINUTES minutes
# each, one after the other (one job, nice 15: the machine is shared), from the seed corpus of
# scripts/fuzz_corpus.py. Prints per target the executions, coverage (libFuzzer's cov/ft) and
# crashes; crashing inputs land in fuzz/artifacts/<target>/ (turn each into a regression test).
#   bash scripts/fuzz.sh 6            # 6 minutes per target
#   TARGETS="model_decode" bash scripts/fuzz.sh 1
# Needs `cargo install cargo-fuzz`; RUSTC_BOOTSTRAP=1 lets stable rustc take the nightly
# sanitizer flags cargo-fuzz passes.
set -euo pipefail
cd "$(dirname "$0")/.."
MINUTES=${1:?usage: scripts/fuzz.sh MINUTES}
TARGETS=${TARGETS:-"model_decode trainset_decode depth_png camera_file predict_image"}
export RUSTC_BOOTSTRAP=1
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$PWD/target/fuzz}
[ -d fuzz/corpus ] || PYTHONPATH=python PYOPENGL_PLATFORM=${PYOPENGL_PLATFORM:-egl} python3 scripts/fuzz_corpus.py
(cd fuzz && nice -n 15 cargo fuzz build -O)
mkdir -p fuzz/logs
printf '%-16s %8s %12s %8s %8s %8s\n' target minutes executions cov ft crashes
for t in $TARGETS; do
  log=fuzz/logs/$t.log
  status=0
  (cd fuzz && nice -n 15 cargo fuzz run -O "$t" "corpus/$t" -- \
      -max_total_time=$((MINUTES * 60)) -rss_limit_mb=2048 -timeout=10 -print_final_stats=1) >"$log" 2>&1 || status=$?
  execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | grep -o '[0-9]*')
  ft=$(grep -o 'ft: [0-9]*' "$log" | tail -1 | grep -o '[0-9]*')
  crashes=$(ls "fuzz/artifacts/$t" 2>/dev/null | wc -l)
  printf '%-16s %8s %12s %8s %8s %8s\n' "$t" "$MINUTES" "${execs:-?}" "${cov:-?}" "${ft:-?}" "$crashes"
  [ "$status" = 0 ] || echo "  $t stopped with status $status: see $log"
done
