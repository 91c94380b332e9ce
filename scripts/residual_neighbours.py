#!/usr/bin/env python3
"""Is what a model leaves on the held-out poses noise, or structure? For each held-out pose,
its nearest held-out neighbour (marker position); prints the per-axis correlation of their
residuals and the median neighbour distance, for the SciPy peer's geometric fit
(`scripts/peers/geometric_scipy.py`, trained on the `train` group) and for a robocal output's
`heldout_predictions.csv`. Used in docs/findings.md ("An unseen real robot", round 8).

Usage: residual_neighbours.py DATASET.jsonl DIAGNOSE_OUT_DIR   (peer venv: numpy + scipy)
"""
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "peers"))
import geometric_scipy as g  # noqa: E402


def neighbour_corr(r, x):
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    np.fill_diagonal(d, np.inf)
    nn = d.argmin(1)
    return [np.corrcoef(r[:, k], r[nn, k])[0, 1] for k in range(3)], np.median(d.min(1))


def main():
    data, out = sys.argv[1], sys.argv[2]
    head, _ = g.load(data)
    org, fl = g.chain_of(head)
    recs = []
    with open(data) as f:
        for i, line in enumerate(f):
            r = json.loads(line) if line.strip() and i > 0 else {}
            if r.get("kind") == "pose" and "q" in r and r.get("marker", {}).get("p"):
                recs.append(r)
    recs.sort(key=lambda r: r["t"])
    q = np.radians(np.array([r["q"] for r in recs], float))
    m = np.array([r["marker"]["p"] for r in recs], float)
    tr = np.array([r.get("group") != "validation" for r in recs])
    ids = [r["id"] for r in recs]
    geo = g.fit(org, fl, q[tr], m[tr], True)
    held = ~tr
    rg = geo(q[held]) - m[held]
    pred = {}
    with open(os.path.join(out, "heldout_predictions.csv")) as f:
        next(f)
        for line in f:
            i, x, y, z = line.strip().split(",")
            pred[int(i)] = np.array([float(x), float(y), float(z)])
    rf = np.array([pred[i] for i, h in zip(ids, held) if h]) - m[held]
    for name, r in (("geometric (SciPy peer)", rg), ("robocal output", rf)):
        c, dist = neighbour_corr(r, m[held])
        rms = np.sqrt((r ** 2).sum(1).mean())
        print(f"{name}: held-out RMS {rms:.4f} mm; nearest held-out neighbour (median {dist:.1f} mm away) residual correlation x/y/z {c[0]:.2f} / {c[1]:.2f} / {c[2]:.2f}")


if __name__ == "__main__":
    main()
