#!/usr/bin/env bash
# A full dry run of a calibration session against the simulated cell: a thin wrapper over
# `robocal session` (plan -> training + held-out runs -> calibrate -> diagnose -> validate ->
# verdict -> report.html), plus a camera session on the UR5e eye-in-hand cell.
#
# Everything lands in out/dry-run/ (replaced on each run). Needs only cargo; no hardware.
# Environment: POSES (training poses, default 120), HELDOUT_POINTS (validation points,
# default 40), SCENARIO (default the lab scenario), ACCEPT (acceptance spec, default the
# shipped accept/surgical.toml), FEATURES (e.g. "--features opencv").
set -euo pipefail

cd "$(dirname "$0")/.."
ROOT=$(pwd)
OUT="$ROOT/out/dry-run"
POSES=${POSES:-120}
HELDOUT_POINTS=${HELDOUT_POINTS:-40}
SCENARIO=${SCENARIO:-mocks/scenarios/lab-vs060-optotrak-il600.toml}
ACCEPT=${ACCEPT:-accept/surgical.toml}
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

step "session: $SCENARIO ($POSES training poses, $HELDOUT_POINTS held-out points, $ACCEPT)"
set +e
"$BIN" session --sim "$SCENARIO" --out "$OUT/session" --accept "$ACCEPT" \
    --poses "$POSES" --heldout-points "$HELDOUT_POINTS" --note "scripts/dry-run.sh" \
    | tee "$OUT/headline.txt"
CODE=${PIPESTATUS[0]}
set -e
if [ "$CODE" -eq 1 ]; then
    fail $LINENO "robocal session (exit 1)"
    exit 1
fi
test -s "$OUT/session/report.html"
test -s "$OUT/session/session.json"

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
# Close the loop on the camera data: what the camera model lacks (the world's arm carries joint
# offsets the nominal UR5e model does not know: `arm_kinematics`).
"$BIN" diagnose --data "$OUT/camera/run/dataset.jsonl" --out "$OUT/camera/diagnose" | head -n 6

printf '\ndry run done in %d s: %s\n' "$((SECONDS - START))" "$OUT"
printf 'VERDICT: %s\n' "$(head -n 1 "$OUT/headline.txt")"
printf 'report: %s\n' "$OUT/session/report.html"
# The session's verdict is the script's: 0 PASS, 2 FAIL / INCOMPLETE.
exit "$CODE"
