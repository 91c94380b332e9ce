#!/usr/bin/env python3
"""Peer check: OpenCV's own MJPEG-over-HTTP reader against the simulated camera.

Usage: camera_cv2.py URL FRAMES COLS ROWS

Opens URL exactly as a user would, `cv2.VideoCapture(url)` (FFmpeg backend, `mpjpeg`
demuxer), reads FRAMES frames with `read()`, and prints one JSON object per frame on stdout:
  {"frame": i, "shape": [h, w, c], "mean_grey": m}
then, on the last frame converted to grey, runs
`cv2.findChessboardCorners(grey, (COLS-1, ROWS-1))` and, when found, `cv2.cornerSubPix`
(11x11 window) and prints
  {"found": bool, "pattern": [COLS-1, ROWS-1], "corners": [[u, v], ...],
   "corners_subpix": [[u, v], ...], "backend": "...", "opencv": "..."}
Exits non-zero when the stream cannot be opened or fewer than FRAMES frames are read.
"""
import json
import sys

import cv2


def main():
    url, frames, cols, rows = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    cap = cv2.VideoCapture(url, cv2.CAP_FFMPEG)
    if not cap.isOpened():
        print(json.dumps({"error": f"cannot open {url}"}), flush=True)
        sys.exit(2)
    backend = cap.getBackendName()
    last = None
    for i in range(frames):
        ok, img = cap.read()
        if not ok or img is None:
            print(json.dumps({"error": f"read failed at frame {i}"}), flush=True)
            sys.exit(3)
        print(json.dumps({
            "frame": i,
            "shape": list(img.shape),
            "mean_grey": float(img.mean()),
        }), flush=True)
        last = img
    cap.release()
    grey = cv2.cvtColor(last, cv2.COLOR_BGR2GRAY) if last.ndim == 3 else last
    pattern = (cols - 1, rows - 1)
    found, corners = cv2.findChessboardCorners(grey, pattern)
    out = {
        "found": bool(found),
        "pattern": list(pattern),
        "corners": [],
        "corners_subpix": [],
        "backend": backend,
        "opencv": cv2.__version__,
    }
    if found:
        out["corners"] = [[float(u), float(v)] for u, v in corners.reshape(-1, 2)]
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-3)
        refined = cv2.cornerSubPix(grey, corners.copy(), (11, 11), (-1, -1), criteria)
        out["corners_subpix"] = [[float(u), float(v)] for u, v in refined.reshape(-1, 2)]
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
