#!/usr/bin/env bash
# Coverage-guided fuzzing of every wire decoder, a short fixed time each (total < ~3 min).
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
