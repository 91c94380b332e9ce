#!/usr/bin/env bash
# Installs the Python peer tools used by the peer tests, one venv per tool
# (their pins conflict in one venv). Idempotent; quiet when already present.
set -euo pipefail
cd "$(dirname "$0")/.."
mk() { # name, packages...
  local name=$1; shift
  local dir=.venv/peers-$name
  if [ ! -x "$dir/bin/python" ] || [ ! -f "$dir/.ok" ]; then
    rm -rf "$dir"
    python3 -m venv "$dir"
    "$dir/bin/pip" install -q --disable-pip-version-check "$@"
    touch "$dir/.ok"
  fi
}
mk urrtde ur-rtde==1.6.5
mk ndi ndicapi==3.7.6 scikit-surgerynditracker==1.0.6
mk pybotics "numpy<2" pybotics==3.1.2 scipy
mk cv2 "opencv-python-headless<5" "numpy<2.3"
mk sksurgery scikit-surgerycore==0.8.3
