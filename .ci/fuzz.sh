#!/usr/bin/env bash
# Coverage-guided fuzzing of every wire decoder and file reader (dataset, calibration, plan,
# plan spec, scenario, device file, RCM / robot-world / camera datasets, registration, mesh,
# accept spec, point tables, laser datasets, session record, `correct` targets), a short fixed time each.
# Installs cargo-fuzz when missing. `--sanitizer none` works on the stable toolchain.
# Usage: bash .ci/fuzz.sh [seconds-per-target]   (default 25)
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p target
secs=${1:-25}
if ! cargo fuzz --version >/dev/null 2>&1; then
  cargo install cargo-fuzz --locked
fi
cd fuzz
targets=$(cargo fuzz list)
# Seed the file-reader targets with the project's own files (first 4 KB: -max_len) and the
# small hand-picked seeds in fuzz/seeds/<target>/, so the short runs start from valid input.
seed() {
  local t=$1; shift
  mkdir -p "corpus/$t"
  for f in "$@"; do
    [ -f "$f" ] && head -c 4000 "$f" > "corpus/$t/seed-$(echo "$f" | tr '/.' '__')"
  done
  return 0
}
seed dataset ../tests/data/*/heldout.jsonl ../tests/data/*/train.jsonl seeds/dataset/*
seed calibration seeds/calibration/*
seed plan seeds/plan/*
seed spec ../plans/*.toml
seed scenario ../mocks/scenarios/*.toml
seed devices seeds/devices/*
seed import seeds/import/*
seed accept ../accept/*.toml
seed robot_world ../tests/data/*/train.jsonl
seed camera_dataset ../tests/data/*/train.jsonl
seed rcm ../tests/data/*/train.jsonl
seed registration ../tests/data/*/*.csv
seed points_csv ../tests/data/*/*.csv
seed laser ../tests/data/laser-planes/*.jsonl
seed session seeds/session/*
seed correct_targets seeds/correct_targets/*
# Build every target in one cargo invocation (links run in parallel), then run each.
echo "== fuzz build (all targets)"
cargo fuzz build --sanitizer none > ../target/fuzz-build.log 2>&1 || { tail -40 ../target/fuzz-build.log; echo "fuzz build FAILED"; exit 1; }
for t in $targets; do
  echo "== fuzz $t (${secs}s)"
  mkdir -p "corpus/$t"
  set +e
  cargo fuzz run "$t" --sanitizer none -- -max_total_time="$secs" -max_len=4096 > "../target/fuzz-$t.log" 2>&1
  rc=$?
  set -e
  grep -E '^(#[0-9]+ +DONE|Done|==[0-9]+==|SUMMARY|thread|panicked|stat::)' "../target/fuzz-$t.log" || true
  # libFuzzer exits non-zero on a crash (or a build failure): fail CI and show the tail.
  if [ "$rc" != "0" ]; then tail -40 "../target/fuzz-$t.log"; echo "fuzz target $t FAILED (rc=$rc)"; exit "$rc"; fi
done
echo "fuzz: all targets clean"
