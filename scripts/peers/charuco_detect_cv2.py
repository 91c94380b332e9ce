#!/usr/bin/env python3
"""Peer check: OpenCV's ChArUco detector on rendered images (detector accuracy).

Reads one JSON object on stdin:
  {"squares": [cols, rows] (squares, not inner corners), "square_mm": S, "marker_mm": M,
   "dictionary": "DICT_4X4_50", "images": [paths]}
and prints one JSON object:
  {"opencv": version,
   "results": [{"found": bool, "ids": [corner id, ...], "corners": [[u, v], ...],
                "markers": n}, ...]}
cv2.aruco.CharucoBoard (OpenCV >= 4.6 layout, not legacy) + cv2.aruco.CharucoDetector with
default parameters (markers found by the ArUco detector, ChArUco corners interpolated from
them and refined by OpenCV's cornerSubPix), as a user would run it. Corner ids are OpenCV's
(row by row over the inner corners).
"""
import json
import sys

import cv2


def main():
    job = json.load(sys.stdin)
    cols, rows = job["squares"]
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, job["dictionary"]))
    board = cv2.aruco.CharucoBoard((cols, rows), float(job["square_mm"]), float(job["marker_mm"]),
                                   dictionary)
    detector = cv2.aruco.CharucoDetector(board)
    out = []
    for path in job["images"]:
        grey = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        r = {"found": False, "ids": [], "corners": [], "markers": 0}
        if grey is not None:
            corners, ids, marker_corners, marker_ids = detector.detectBoard(grey)
            r["markers"] = 0 if marker_ids is None else len(marker_ids)
            if ids is not None and len(ids) > 0:
                r = {"found": True, "ids": [int(i) for i in ids.reshape(-1)],
                     "corners": corners.reshape(-1, 2).tolist(), "markers": r["markers"]}
        out.append(r)
    print(json.dumps({"opencv": cv2.__version__, "results": out}))


if __name__ == "__main__":
    main()
