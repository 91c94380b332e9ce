#!/usr/bin/env python3
"""Peer check: OpenCV's own calibration test on samples/data/left01..14.jpg, step by step.

Reproduces modules/calib3d/misc/python/test/test_calibration.py (OpenCV, Apache-2.0):
findChessboardCorners (default flags), cornerSubPix (5x5 window, EPS+COUNT 30 / 0.1), then
calibrateCamera (flags 0, square 1). Reads one JSON object on stdin: {"images": [paths]} and
prints {"opencv": version, "corners": [[[u, v], ...] or null per image], "rms": float,
"K": 3x3, "dist": [k1, k2, p1, p2, k3]} so that robocal's solver can be fed OpenCV's own
corners (detector and solver separated).
"""
import json
import sys

import cv2
import numpy as np


def main():
    job = json.load(sys.stdin)
    pattern = (9, 6)
    pts = np.zeros((54, 3), np.float32)
    pts[:, :2] = np.indices(pattern).T.reshape(-1, 2)
    obj, img, out = [], [], []
    h = w = 0
    for path in job["images"]:
        grey = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if grey is None:
            out.append(None)
            continue
        h, w = grey.shape[:2]
        found, c = cv2.findChessboardCorners(grey, pattern)
        if not found:
            out.append(None)
            continue
        term = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.1)
        cv2.cornerSubPix(grey, c, (5, 5), (-1, -1), term)
        out.append(c.reshape(-1, 2).tolist())
        img.append(c.reshape(-1, 2))
        obj.append(pts)
    rms, k, dist, _, _ = cv2.calibrateCamera(obj, img, (w, h), None, None, flags=0)
    print(json.dumps({"opencv": cv2.__version__, "corners": out, "rms": rms,
                      "K": k.tolist(), "dist": dist.ravel().tolist()}))


if __name__ == "__main__":
    main()
