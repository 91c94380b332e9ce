#!/usr/bin/env bash
# The main command: a full dry run of a calibration session against the simulated cell.
#
#   plan (seed 001 annulus on denso-vs060, training + held-out validation poses)
#   -> robocal run --sim <lab scenario> --virtual-clock   (training and validation runs)
#   -> robocal calibrate kinematics
#   -> robocal diagnose
#   -> robocal report   (report.md + report.html, headline printed last)
#
# Everything lands in out/dry-run/ (replaced on each run). Needs only cargo; no hardware.
# Environment: POSES (training poses kept by --select, default 120), HELDOUT_POINTS (validation
# annulus points, default 40), SCENARIO (default the lab scenario), BOOTSTRAP (default 100).
set -euo pipefail

cd "$(dirname "$0")/.."
ROOT=$(pwd)
OUT="$ROOT/out/dry-run"
POSES=${POSES:-120}
HELDOUT_POINTS=${HELDOUT_POINTS:-40}
SCENARIO=${SCENARIO:-mocks/scenarios/lab-vs060-optotrak-il600.toml}
BOOTSTRAP=${BOOTSTRAP:-100}
SPEC=plans/seed001-annulus.toml
CAMERA_SCENARIO=${CAMERA_SCENARIO:-mocks/scenarios/ur5e-camera.toml}
FEATURES=${FEATURES:-}

step() { printf '\n==> [%s] %s\n' "$(date -u +%H:%M:%S)" "$*"; }
fail() { printf '\nDRY RUN FAILED at line %s: %s\n' "$1" "$2" >&2; }
trap 'fail $LINENO "$BASH_COMMAND"' ERR

START=$SECONDS

step "cargo build --release"
# shellcheck disable=SC2086
cargo build --release --bin robocal $FEATURES
BIN="$ROOT/target/release/robocal"
test -x "$BIN"

rm -rf "$OUT"
mkdir -p "$OUT"

step "plan: $SPEC on denso-vs060, $POSES training poses (greedy D-optimal selection)"
"$BIN" plan --spec "$SPEC" --robot denso-vs060 --select "$POSES" --out "$OUT/plan-train.json" \
    --summary "$OUT/plan-train.txt" > /dev/null
tail -n 4 "$OUT/plan-train.txt"

step "plan: held-out validation poses (same annulus, seed 2, $HELDOUT_POINTS points, group validation)"
sed -e 's/^name = .*/name = "seed001-annulus-validation"/' \
    -e 's/^seed = .*/seed = 2/' \
    -e 's/^group = .*/group = "validation"/' \
    -e "s/^points = .*/points = $HELDOUT_POINTS/" \
    "$SPEC" > "$OUT/validation-spec.toml"
grep -q '^group = "validation"' "$OUT/validation-spec.toml"
"$BIN" plan --spec "$OUT/validation-spec.toml" --robot denso-vs060 --out "$OUT/plan-validation.json" \
    --summary "$OUT/plan-validation.txt" > /dev/null
tail -n 4 "$OUT/plan-validation.txt"

step "run: training poses on the simulated cell ($SCENARIO, virtual clock)"
"$BIN" run --plan "$OUT/plan-train.json" --sim "$SCENARIO" --virtual-clock --json \
    --out "$OUT/run" > "$OUT/run-progress.log"
tail -n 1 "$OUT/run-progress.log" | cut -c1-200

step "run: validation poses (held out from every fit)"
"$BIN" run --plan "$OUT/plan-validation.json" --sim "$SCENARIO" --virtual-clock --json \
    --out "$OUT/run-validation" > "$OUT/run-validation-progress.log"
tail -n 1 "$OUT/run-validation-progress.log" | cut -c1-200

step "inspect the training dataset"
"$BIN" inspect "$OUT/run/dataset.jsonl"

step "calibrate kinematics (bootstrap $BOOTSTRAP)"
"$BIN" calibrate kinematics --data "$OUT/run/dataset.jsonl" \
    --heldout "$OUT/run-validation/dataset.jsonl" --bootstrap "$BOOTSTRAP" \
    --out "$OUT/calibrate" | tail -n 5

# diagnose scores its chain (nominal -> geometric -> with effects) on the separate validation run.
step "diagnose the residual"
"$BIN" diagnose --data "$OUT/run/dataset.jsonl" \
    --heldout "$OUT/run-validation/dataset.jsonl" --out "$OUT/diagnose" | tail -n 6

# A camera session on the UR5e eye-in-hand cell (seed 004 viewpoints on a shell about the
# chessboard): one image per pose, served by the camera simulator; chessboard corners too when
# robocal is built with `--features opencv` (FEATURES="--features opencv").
step "camera session: seed 004 shell on the UR5e camera cell ($CAMERA_SCENARIO)"
mkdir -p "$OUT/camera"
"$BIN" plan --spec plans/seed004-ur5e-camera.toml --robot ur5e --out "$OUT/camera/plan.json" \
    --summary "$OUT/camera/plan.txt" > /dev/null
"$BIN" run --plan "$OUT/camera/plan.json" --sim "$CAMERA_SCENARIO" --virtual-clock \
    --out "$OUT/camera/run" | tail -n 3
"$BIN" inspect "$OUT/camera/run/dataset.jsonl" | grep -E "^(records|poses|camera)"
# Camera intrinsics + hand-eye from those images (pure-Rust detection, every method side by side).
"$BIN" calibrate camera --data "$OUT/camera/run/dataset.jsonl" --out "$OUT/camera/calibrate" \
    --quiet | tail -n 12

step "report"
"$BIN" report --dir "$OUT" --out "$OUT/report.html" | tee "$OUT/headline.txt"

test -s "$OUT/report.md"
test -s "$OUT/report.html"
printf '\ndry run done in %d s: %s\n' "$((SECONDS - START))" "$OUT"
printf 'HEADLINE: %s\n' "$(tail -n 1 "$OUT/headline.txt")"
