#!/usr/bin/env bash
# A full dry run of a calibration session against the simulated cell: a thin wrapper over
# `robocal session` (plan -> training + held-out runs -> calibrate -> diagnose -> validate ->
# verdict -> report.html), plus a camera session on the UR5e eye-in-hand cell (out/dry-run/camera/).
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

# A camera session on the UR5e eye-in-hand cell, through the same `robocal session`: seed 004
# viewpoints on a shell about the chessboard (24 training + 12 held-out views, one image each)
# -> pure-Rust board detection -> intrinsics + every closed-form hand-eye + the maximum-
# likelihood refinement with uncertainties -> camera diagnosis (the world's arm carries joint
# offsets the nominal UR5e model lacks: `arm_kinematics`) -> held-out reprojection before /
# after -> verdict against accept/camera.toml -> report.html with the camera calibration.
step "camera session: seed 004 shell on the UR5e camera cell ($CAMERA_SCENARIO)"
set +e
"$BIN" session --sim "$CAMERA_SCENARIO" --out "$OUT/camera" --note "scripts/dry-run.sh (camera)" \
    | tee "$OUT/camera-headline.txt"
CAMERA_CODE=${PIPESTATUS[0]}
set -e
if [ "$CAMERA_CODE" -eq 1 ]; then
    fail $LINENO "robocal session, camera cell (exit 1)"
    exit 1
fi
test -s "$OUT/camera/report.html"
grep -q 'id="camera-hand-eye"' "$OUT/camera/report.html"
# The camera diagnosis through the typed report (robocal-diagnosis/2, pixels).
"$BIN" report --dir "$OUT/camera/diagnose" --out "$OUT/camera/diagnose/report.md" | tail -n 1

printf '\ndry run done in %d s: %s\n' "$((SECONDS - START))" "$OUT"
# The verdict line (the run's progress lines come before it on stdout).
verdict() { grep -m 1 -E '^(PASS|FAIL|INCOMPLETE)' "$1" || echo "(no verdict line in $1)"; }
printf 'VERDICT: %s\n' "$(verdict "$OUT/headline.txt")"
printf 'CAMERA VERDICT: %s\n' "$(verdict "$OUT/camera-headline.txt")"
printf 'report: %s\n' "$OUT/session/report.html"
printf 'camera report: %s\n' "$OUT/camera/report.html"
# The sessions' verdicts are the script's: 0 both PASS, 2 a FAIL / INCOMPLETE.
if [ "$CODE" -ne 0 ]; then exit "$CODE"; fi
exit "$CAMERA_CODE"
