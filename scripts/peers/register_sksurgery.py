"""Peer of `robocal register` (paired fiducials): scikit-surgerycore's orthogonal
Procrustes (Arun 1987) and its Fitzpatrick-West TRE, on the same points.

Usage: register_sksurgery.py IN.json   (fixed = tracker, moving = CT, targets, fle2)
Prints one JSON line per case: R (row-major), t, fre, tre2 (sksurgerycore) and tre2_cols
(the same formula with numpy, the principal axes as the lines through the centroid along
the eigenvectors = columns of eig's output; scikit-surgerycore 0.8.3 passes an eigenvector
row as a second *point* of the line, which is right only when the centroid is the origin).
"""
import json
import sys

import numpy as np
from sksurgerycore.algorithms import procrustes, errors
from sksurgerycore.algorithms import vector_math as vm


def tre2_columns(fid, fle2, target):
    n = fid.shape[0]
    c = np.mean(fid, axis=0)
    _, ev = np.linalg.eig(np.cov(fid.T))
    s = 0.0
    for k in range(3):
        u = ev[:, k]
        fk2 = np.mean([vm.distance_from_line(c, c + u, p) ** 2 for p in fid])
        dk = vm.distance_from_line(c, c + u, target[0])
        s += dk * dk / fk2
    return fle2 / n * (1.0 + s / 3.0)


def main():
    cases = json.load(open(sys.argv[1]))
    for case in cases:
        fixed = np.array(case["fixed"], dtype=float)
        moving = np.array(case["moving"], dtype=float)
        r, t, fre = procrustes.orthogonal_procrustes(fixed, moving)
        tre2 = []
        tre2c = []
        for x in case["targets"]:
            tp = np.array([x], dtype=float)
            tre2.append(float(errors.compute_tre_from_fle(moving, case["fle2"], tp)))
            tre2c.append(float(tre2_columns(moving, case["fle2"], tp)))
        print(json.dumps({
            "R": [float(v) for v in np.asarray(r).reshape(-1)],
            "t": [float(v) for v in np.asarray(t).reshape(-1)],
            "fre": float(fre),
            "tre2": tre2,
            "tre2_cols": tre2c,
        }))


if __name__ == "__main__":
    main()
