"""Peer of `robocal calibrate robot-world`: OpenCV's calibrateRobotWorldHandEye (SHAH, LI)
and calibrateHandEye (TSAI, seed 003's route) on the same poses. OpenCV >= 4.10 Tsai drops
pose pairs whose gripper motion has |2 sin(theta/2)| < 0.3 (PR opencv#24897); robocal's
`tsai_route_min_motion(obs, OPENCV_TSAI_MIN_MOTION)` reproduces that to 1e-12.

Usage: robot_world_cv2.py IN.json   ({"A": [16 row-major T_base_flange...],
                                      "B": [16 row-major T_tracker_marker...]})
Prints one JSON line per method: Y = T_base_tracker and X = T_flange_marker (row-major 4x4).
"""
import json
import sys

import cv2
import numpy as np


def inv(t):
    o = np.eye(4)
    o[:3, :3] = t[:3, :3].T
    o[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return o


def h(r, t):
    o = np.eye(4)
    o[:3, :3] = r
    o[:3, 3] = np.asarray(t).reshape(3)
    return o


def main():
    d = json.load(open(sys.argv[1]))
    a = [np.array(m, dtype=float).reshape(4, 4) for m in d["A"]]
    b = [np.array(m, dtype=float).reshape(4, 4) for m in d["B"]]
    bi = [inv(m) for m in b]
    ai = [inv(m) for m in a]
    for name, method in [("shah", cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH),
                         ("li", cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI)]:
        r_b2w, t_b2w, r_g2c, t_g2c = cv2.calibrateRobotWorldHandEye(
            [m[:3, :3] for m in bi], [m[:3, 3] for m in bi],
            [m[:3, :3] for m in ai], [m[:3, 3] for m in ai], method=method)
        y = inv(h(r_b2w, t_b2w))
        x = inv(h(r_g2c, t_g2c))
        print(json.dumps({"method": name, "Y": y.reshape(-1).tolist(), "X": x.reshape(-1).tolist()}))
    r, t = cv2.calibrateHandEye([m[:3, :3] for m in ai], [m[:3, 3] for m in ai],
                                [m[:3, :3] for m in b], [m[:3, 3] for m in b],
                                method=cv2.CALIB_HAND_EYE_TSAI)
    print(json.dumps({"method": "tsai", "Y": h(r, t).reshape(-1).tolist()}))


if __name__ == "__main__":
    main()
