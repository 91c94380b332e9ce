#!/usr/bin/env python3
"""Peer timing: OpenCV's whole camera + hand-eye pipeline on a robocal camera dataset.

Usage: camera_pipeline_cv2.py DATASET.jsonl

Reads the `robocal-dataset/1` file a user would give `robocal calibrate camera` (header
`target` = chessboard cols/rows of inner corners and square_mm; one `pose` record per view with
`image` relative to the file and `flange` {p (mm), quat [w, x, y, z]} = base <- flange), then,
as a user of OpenCV would:
  cv2.imread (grey) -> cv2.findChessboardCorners -> cv2.cornerSubPix (11x11)
  -> cv2.calibrateCamera -> cv2.calibrateHandEye (Park)
and prints one JSON object:
  {"opencv": version, "views": n, "found": n_found, "rms_px": calibrateCamera RMS,
   "detect_s": s, "calibrate_s": s, "handeye_s": s, "total_s": s}
(`total_s` excludes the Python start-up and the `import cv2`; the caller times the process.)
Exits non-zero when fewer than 3 views have a detected board.
"""
import json
import os
import sys
import time

import cv2
import numpy as np


def quat_to_r(w, x, y, z):
    n = (w * w + x * x + y * y + z * z) ** 0.5
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def main():
    path = sys.argv[1]
    base = os.path.dirname(os.path.abspath(path))
    with open(path) as f:
        lines = [json.loads(l) for l in f if l.strip()]
    head, recs = lines[0], [r for r in lines[1:] if r.get("kind") == "pose" and r.get("image")]
    cols, rows = int(head["target"]["cols"]), int(head["target"]["rows"])
    sq = float(head["target"]["square_mm"])
    obj = np.zeros((cols * rows, 3), np.float32)
    obj[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * sq
    t0 = time.perf_counter()
    img_pts, obj_pts, flange, size = [], [], [], None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
    for r in recs:
        g = cv2.imread(os.path.join(base, r["image"]), cv2.IMREAD_GRAYSCALE)
        if g is None:
            continue
        size = (g.shape[1], g.shape[0])
        ok, c = cv2.findChessboardCorners(g, (cols, rows))
        if not ok:
            continue
        c = cv2.cornerSubPix(g, c, (11, 11), (-1, -1), crit)
        img_pts.append(c)
        obj_pts.append(obj)
        flange.append(r["flange"])
    t1 = time.perf_counter()
    if len(img_pts) < 3:
        print(json.dumps({"error": f"only {len(img_pts)} views with a detected board"}))
        sys.exit(2)
    rms, k, dist, rvecs, tvecs = cv2.calibrateCamera(obj_pts, img_pts, size, None, None)
    t2 = time.perf_counter()
    r_g2b = [quat_to_r(*fl["quat"]) for fl in flange]
    t_g2b = [np.array(fl["p"], float).reshape(3, 1) for fl in flange]
    r_t2c = [cv2.Rodrigues(rv)[0] for rv in rvecs]
    cv2.calibrateHandEye(r_g2b, t_g2b, r_t2c, list(tvecs), method=cv2.CALIB_HAND_EYE_PARK)
    t3 = time.perf_counter()
    print(json.dumps({
        "opencv": cv2.__version__, "views": len(recs), "found": len(img_pts), "rms_px": rms,
        "detect_s": t1 - t0, "calibrate_s": t2 - t1, "handeye_s": t3 - t2, "total_s": t3 - t0,
    }))


if __name__ == "__main__":
    main()
