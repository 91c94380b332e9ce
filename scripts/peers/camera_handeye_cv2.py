#!/usr/bin/env python3
"""Peer check: OpenCV's camera + hand-eye calibration on the same data robocal calibrates.

Reads one JSON object on stdin:
  {"pattern": [cols, rows],            # inner corners
   "square_mm": s,
   "size": [w, h],
   "corners": [[[u, v], ...], ...],    # per training view, board order (row by row), or null
   "flange": [[r00..r22, tx, ty, tz], ...],  # base <- flange per training view (R row-major)
   "detect_images": ["a.pgm", ...],    # images for OpenCV's own detector (accuracy only)
   "flags": "k1k2" | "default"}
and prints one JSON object:
  {"opencv": version, "rms": calibrateCamera RMS,
   "K": 3x3, "dist": [...], "rvecs": [...], "tvecs": [...],
   "hand_eye": {"tsai": {"R": 3x3, "t": [..]}, "park": ..., "horaud": ..., "andreff": ...,
                "daniilidis": ...},
   "detect": [{"found": bool, "corners": [[u, v], ...]}, ...]}
cv2.calibrateCamera gets the corners robocal detected (same corners, so the estimators are
compared, not the detectors); the detector is measured separately on detect_images with
cv2.findChessboardCorners + cv2.cornerSubPix (11x11), as a user would run it.
"""
import json
import sys

import cv2
import numpy as np


def main():
    job = json.load(sys.stdin)
    cols, rows = job["pattern"]
    s = float(job["square_mm"])
    w, h = job["size"]
    objp = np.array([[(i + 1) * s, (j + 1) * s, 0.0] for j in range(rows) for i in range(cols)],
                    dtype=np.float32)
    obj, img, used = [], [], []
    for k, c in enumerate(job["corners"]):
        if c is None:
            continue
        obj.append(objp)
        img.append(np.array(c, dtype=np.float32).reshape(-1, 1, 2))
        used.append(k)
    flags = 0
    if job.get("flags") == "k1k2":
        flags = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, (w, h), None, None, flags=flags,
                                                     criteria=crit)
    Rg, tg, Rt, tt = [], [], [], []
    for k, rv, tv in zip(used, rvecs, tvecs):
        f = job["flange"][k]
        Rg.append(np.array(f[:9], dtype=np.float64).reshape(3, 3))
        tg.append(np.array(f[9:12], dtype=np.float64).reshape(3, 1))
        Rt.append(cv2.Rodrigues(rv)[0])
        tt.append(np.array(tv, dtype=np.float64).reshape(3, 1))
    methods = {
        "tsai": cv2.CALIB_HAND_EYE_TSAI,
        "park": cv2.CALIB_HAND_EYE_PARK,
        "horaud": cv2.CALIB_HAND_EYE_HORAUD,
        "andreff": cv2.CALIB_HAND_EYE_ANDREFF,
        "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
    }
    he = {}
    for name, m in methods.items():
        R, t = cv2.calibrateHandEye(Rg, tg, Rt, tt, method=m)
        he[name] = {"R": R.tolist(), "t": t.reshape(-1).tolist()}
    det = []
    for path in job.get("detect_images", []):
        grey = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if grey is None:
            det.append({"found": False, "corners": [], "error": "unreadable"})
            continue
        found, corners = cv2.findChessboardCorners(grey, (cols, rows))
        out = {"found": bool(found), "corners": []}
        if found:
            c2 = cv2.cornerSubPix(grey, corners.copy(), (11, 11), (-1, -1),
                                  (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-3))
            out["corners"] = c2.reshape(-1, 2).tolist()
        det.append(out)
    print(json.dumps({
        "opencv": cv2.__version__,
        "rms": rms,
        "K": K.tolist(),
        "dist": dist.reshape(-1).tolist(),
        "used": used,
        "rvecs": [r.reshape(-1).tolist() for r in rvecs],
        "tvecs": [t.reshape(-1).tolist() for t in tvecs],
        "hand_eye": he,
        "detect": det,
    }))


if __name__ == "__main__":
    main()
