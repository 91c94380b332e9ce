#!/usr/bin/env python3
"""Peer check: scikit-surgerynditracker (with ndicapi) configured for a Polaris Vega.

Usage: ndi_sksurgery.py vega HOST PORT FRAMES ROMFILE [ROMFILE ...]
       ndi_sksurgery.py polaris SERIAL_PATH FRAMES ROMFILE [ROMFILE ...]

Connects exactly as a user would (`NDITracker({"tracker type": "vega", ...})`), starts
tracking, reads FRAMES frames with `get_frame()`, stops, closes, and prints one JSON object
per frame on stdout:
  {"handles": [...], "frame_numbers": [...], "tracking": [[qw,qx,qy,qz,x,y,z] | null ...],
   "quality": [...], "firmware_capture": "BX:0801" | "TX:0801"}

The only thing adapted is the client's ICMP pre-check: nditracker runs `ping -c 1 HOST`
before connecting. When this machine has no `ping` binary, the pre-check is answered
"reachable" for loopback addresses only (the simulator listens on loopback); everything on
the wire is the unmodified library.
"""
import ipaddress
import json
import math
import shutil
import sys

from sksurgerynditracker import nditracker


def _loopback_ping(args, *rest, **kw):
    if args and args[0] == "ping":
        return 0 if ipaddress.ip_address(args[-1]).is_loopback else 1
    return _real_call(args, *rest, **kw)


_real_call = nditracker.call
if shutil.which("ping") is None:
    nditracker.call = _loopback_ping


def main():
    if sys.argv[1] == "vega":
        host, port, frames = sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
        roms = sys.argv[5:]
        config = {"tracker type": "vega", "ip address": host, "port": port}
    else:
        # Serial Polaris: ndiProbe (INIT at 9600, GETINFO), ndiOpen, INIT, COMM:50000.
        path, frames = sys.argv[2], int(sys.argv[3])
        roms = sys.argv[4:]
        config = {"tracker type": "polaris", "serial port": path}
    config.update({"romfiles": roms, "use quaternions": True})
    tracker = nditracker.NDITracker(config)
    tracker.start_tracking()
    for _ in range(frames):
        handles, _times, frame_numbers, tracking, quality = tracker.get_frame()
        rows = []
        for t in tracking:
            row = [float(v) for v in t.reshape(-1)]
            rows.append(None if any(math.isnan(v) for v in row) else row)
        print(json.dumps({
            "handles": [int(h) for h in handles],
            "frame_numbers": [None if math.isnan(f) else int(f) for f in map(float, frame_numbers)],
            "tracking": rows,
            "quality": [None if math.isnan(q) else float(q) for q in map(float, quality)],
            "capture": tracker._capture_string,  # pylint: disable=protected-access
        }), flush=True)
    tracker.stop_tracking()
    tracker.close()


if __name__ == "__main__":
    main()
