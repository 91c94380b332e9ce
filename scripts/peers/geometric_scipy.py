#!/usr/bin/env python3
"""Peer reference: a redundant geometric calibration with SciPy `least_squares`, on a robocal
dataset (`robocal-dataset/1` JSONL, position-only marker records), independent of robocal's
solver. Used for the unseen real robot of issue 31 §4 (round 8, docs/findings.md).

Model (the same family as the IPA reference in `../shared/data/real-ur10-ipa-grid/README.md`):
the header's URDF-style chain (origin_xyz mm, origin_rpy deg, axis), each joint's fixed origin
perturbed by 3 translations + 3 small rotations and each joint angle by an offset (7 per
joint, redundant), the marker's position in the flange (3) and the tracker <- base pose (6).
Fitted by `least_squares(method="trf", x_scale="jac")` on the training poses only, from the
nominal chain; the start of the setup is a closed-form (Kabsch) fit of the nominal chain.

Splits (the same as `examples/real_policy.rs`):
  interleaved   train = group "train", held out = group "validation";
  time-blocked  train = the first 75 % of the training poses (in t order), held out = the
                validation poses after the last of them;
  --heldout F   train = every pose of the dataset, held out = every pose of F.

Prints one Markdown row per split: held-out RMS / p95 / max of the 3-D error (mm) for the
nominal chain (setup and marker fitted) and the geometric fit, the training RMS and the gap.

Usage: geometric_scipy.py DATASET.jsonl [--heldout OTHER.jsonl]
"""
import json
import sys

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation


def load(path):
    head, poses = None, []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line:
                continue
            r = json.loads(line)
            if head is None:
                head = r
                continue
            if r.get("kind") != "pose" or "q" not in r or "marker" not in r:
                continue
            m = r["marker"]
            if not m.get("visible", True) or m.get("p") is None:
                continue
            poses.append((r["t"], r.get("group", "train"), r["q"], m["p"]))
    poses.sort(key=lambda p: p[0])
    return head, poses


def chain_of(head):
    ch = head["robot"]["chain"]
    org = [(np.array(j["origin_xyz"], float), np.radians(j["origin_rpy"]), np.array(j["axis"], float)) for j in ch]
    fl = head["robot"].get("flange") or {"origin_xyz": [0, 0, 0], "origin_rpy": [0, 0, 0]}
    return org, (np.array(fl["origin_xyz"], float), np.radians(fl.get("origin_rpy", [0, 0, 0])))


def rpy_matrix(rpy):
    # URDF: fixed-axis roll (x), pitch (y), yaw (z) = R = Rz(y) Ry(p) Rx(r).
    return Rotation.from_euler("xyz", rpy).as_matrix()


def fk_points(x, org, flange, q):
    """Marker positions in the tracker frame for parameters x (n joints × 7 + 3 + 6)."""
    n = len(org)
    npose = q.shape[0]
    R = np.tile(np.eye(3), (npose, 1, 1))
    p = np.zeros((npose, 3))
    for i, (xyz, rpy, axis) in enumerate(org):
        d = x[7 * i: 7 * i + 7]
        Ro = rpy_matrix(rpy) @ Rotation.from_rotvec(d[3:6] * 1e-3).as_matrix()
        p = p + np.einsum("nij,j->ni", R, xyz + d[0:3])
        R = R @ Ro
        Rq = Rotation.from_rotvec(np.outer(q[:, i] + d[6] * 1e-3, axis)).as_matrix()
        R = np.einsum("nij,njk->nik", R, Rq)
    p = p + np.einsum("nij,j->ni", R, flange[0])
    R = R @ rpy_matrix(flange[1])
    tool = x[7 * n: 7 * n + 3]
    p = p + np.einsum("nij,j->ni", R, tool)
    base = x[7 * n + 3: 7 * n + 9]
    Rb = Rotation.from_rotvec(base[3:6] * 1e-3).as_matrix()
    return p @ Rb.T + base[0:3]


def kabsch(a, b):
    """R, t minimising |R a + t - b|."""
    ca, cb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    dd = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1, 1, dd]) @ u.T
    return r, cb - r @ ca


def fit(org, flange, q, p, geometric):
    n = len(org)
    x0 = np.zeros(7 * n + 9)
    # Start: nominal chain, marker at the flange, setup by Kabsch; then the setup's rotation is
    # folded into the measured points so the fitted base starts at zero.
    nom = fk_points(x0, org, flange, q)
    r, t = kabsch(nom, p)
    p_in = (p - t) @ r  # measured points brought to the base frame
    free = np.zeros_like(x0, bool)
    free[7 * n:] = True
    if geometric:
        free[: 7 * n] = True

    def res(xf):
        x = x0.copy()
        x[free] = xf
        return (fk_points(x, org, flange, q) - p_in).ravel()

    sol = least_squares(res, x0[free], method="trf", x_scale="jac")
    x = x0.copy()
    x[free] = sol.x

    def predict(qq):
        return fk_points(x, org, flange, qq) @ r.T + t

    return predict


def stats(e):
    d = np.linalg.norm(e, axis=1)
    return np.sqrt((d ** 2).mean()), np.percentile(d, 95), d.max()


def main():
    path = sys.argv[1]
    other = sys.argv[sys.argv.index("--heldout") + 1] if "--heldout" in sys.argv else None
    head, poses = load(path)
    org, flange = chain_of(head)
    q = np.radians(np.array([p[2] for p in poses], float))
    pts = np.array([p[3] for p in poses], float)
    t = np.array([p[0] for p in poses], float)
    grp = np.array([p[1] for p in poses])
    splits = []
    if other:
        _, op = load(other)
        splits.append(("all → " + other, np.ones(len(poses), bool), None,
                       (np.radians(np.array([p[2] for p in op], float)), np.array([p[3] for p in op], float))))
    else:
        tr = grp != "validation"
        splits.append(("interleaved", tr, ~tr, None))
        idx = np.flatnonzero(tr)
        ntb = int(0.75 * len(idx))
        tb = np.zeros(len(poses), bool)
        tb[idx[:ntb]] = True
        cut = t[idx[ntb - 1]]
        splits.append(("time-blocked", tb, (~tr) & (t > cut), None))
    print("| split | train / held out | nominal held-out RMS | geometric held-out RMS / p95 / max | train RMS | gap |")
    print("|---|---|---|---|---|---|")
    for name, tr, ho, ext in splits:
        qh, ph = ext if ext is not None else (q[ho], pts[ho])
        nom = fit(org, flange, q[tr], pts[tr], False)
        geo = fit(org, flange, q[tr], pts[tr], True)
        rn = stats(nom(qh) - ph)[0]
        rg, p95, mx = stats(geo(qh) - ph)
        rt = stats(geo(q[tr]) - pts[tr])[0]
        print(f"| {name} | {tr.sum()} / {len(qh)} | {rn:.4f} | {rg:.4f} / {p95:.4f} / {mx:.4f} | {rt:.4f} | {100 * (rg / rt - 1):.1f} % |")


if __name__ == "__main__":
    main()
