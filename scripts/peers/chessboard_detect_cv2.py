#!/usr/bin/env python3
"""Peer check: OpenCV's chessboard detectors on rendered images (detector accuracy).

Reads one JSON object on stdin: {"pattern": [cols, rows] (inner corners), "images": [paths]}
and prints one JSON object:
  {"opencv": version,
   "results": [{"classic": {"found": bool, "corners": [[u, v], ...]},
                "sb": {"found": bool, "corners": [[u, v], ...]}}, ...]}
classic = cv2.findChessboardCorners (default flags) + cv2.cornerSubPix (11x11 window, as a user
would run it); sb = cv2.findChessboardCornersSB (default flags, its own sub-pixel fit).
"""
import json
import sys

import cv2


def main():
    job = json.load(sys.stdin)
    pattern = tuple(job["pattern"])
    out = []
    for path in job["images"]:
        grey = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        r = {"classic": {"found": False, "corners": []}, "sb": {"found": False, "corners": []}}
        if grey is not None:
            found, c = cv2.findChessboardCorners(grey, pattern)
            if found:
                c = cv2.cornerSubPix(grey, c.copy(), (11, 11), (-1, -1),
                                     (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-3))
                r["classic"] = {"found": True, "corners": c.reshape(-1, 2).tolist()}
            found, c = cv2.findChessboardCornersSB(grey, pattern)
            if found:
                r["sb"] = {"found": True, "corners": c.reshape(-1, 2).tolist()}
        out.append(r)
    print(json.dumps({"opencv": cv2.__version__, "results": out}))


if __name__ == "__main__":
    main()
