#!/usr/bin/env python3
"""Writes the small inputs the README's quick tour uses
(examples/quick-tour/): CT fiducials and the same fiducials as a tracker saw them
(ct.csv, trk.csv), three CT targets (targets.csv), and 20 flange / marker pose pairs for
`robocal calibrate robot-world` (rw.jsonl, robocal-dataset/1), 400 marker poses of a probe
pivoted in a divot (pivot-frames.txt, for `calibrate pivot --matrices`) and 40 poses of
tests/data/kin-geometric as a table in radians / metres (poses.csv, for `import csv`). Synthetic: a known CT→tracker
transform, tracker noise 0.1 mm, a known tracker-in-base and marker-on-flange (the hospital
cell's), pose noise 0.1 mm / 0.05 deg. Units mm / degrees. Deterministic (seed 28).

    python3 scripts/make-tour-inputs.py [OUT_DIR]
"""
import json, math, os, random, sys

random.seed(28)
out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..", "examples", "quick-tour")
os.makedirs(out, exist_ok=True)

def qmul(a, b):
    w1, x1, y1, z1 = a; w2, x2, y2, z2 = b
    return (w1*w2 - x1*x2 - y1*y2 - z1*z2, w1*x2 + x1*w2 + y1*z2 - z1*y2,
            w1*y2 - x1*z2 + y1*w2 + z1*x2, w1*z2 + x1*y2 - y1*x2 + z1*w2)

def qaxis(ax, deg):
    h = math.radians(deg) / 2
    n = math.sqrt(sum(c * c for c in ax)) or 1.0
    return (math.cos(h),) + tuple(math.sin(h) * c / n for c in ax)

def rpy(r, p, y):  # URDF rpy: R = Rz(y) Ry(p) Rx(r)
    return qmul(qaxis((0, 0, 1), y), qmul(qaxis((0, 1, 0), p), qaxis((1, 0, 0), r)))

def rot(q, v):
    w, x, y, z = q
    p = (0.0,) + tuple(v)
    r = qmul(qmul(q, p), (w, -x, -y, -z))
    return r[1:]

def compose(a, b):  # (q, t) poses: a * b
    return (qmul(a[0], b[0]), tuple(ai + bi for ai, bi in zip(rot(a[0], b[1]), a[1])))

def inverse(a):
    qi = (a[0][0], -a[0][1], -a[0][2], -a[0][3])
    return (qi, tuple(-c for c in rot(qi, a[1])))

def csv(name, rows):
    with open(os.path.join(out, name), "w") as f:
        f.write("name,x_mm,y_mm,z_mm\n")
        for n, p in rows:
            f.write("%s,%.4f,%.4f,%.4f\n" % ((n,) + tuple(p)))

# CT fiducials about a head phantom, and the tracker's view of them.
ct = [("F%d" % (i + 1), (random.uniform(-80, 80), random.uniform(-80, 80), random.uniform(-40, 60))) for i in range(6)]
t_trk_ct = (rpy(10, -20, 170), (50.0, -30.0, -1500.0))
trk = [(n, tuple(c + random.gauss(0, 0.1) for c in compose(t_trk_ct, ((1, 0, 0, 0), p))[1])) for n, p in ct]
csv("ct.csv", ct)
csv("trk.csv", trk)
csv("targets.csv", [("T%d" % i, (random.uniform(-40, 40), random.uniform(-40, 40), random.uniform(-20, 30))) for i in range(3)])

# Robot-world: A_i (flange in base), B_i = Y^-1 A_i X (marker in tracker) with noise.
y = (rpy(180, -80, 0), (1700.0, 80.0, 650.0))
x = (rpy(0, 0, 30), (25.0, -10.0, 110.0))
lines = [json.dumps({"format": "robocal-dataset/1", "robot": {"model": "denso-vs060"}, "units": {"length": "mm", "angle": "deg"}})]
for i in range(20):
    # The flange's z axis towards the tracker (+x of the base), tilted up to 30 degrees.
    q = qmul(qaxis((0, 1, 0), 90), qmul(qaxis((1, 0, 0), random.uniform(-30, 30)), qaxis((0, 1, 0), random.uniform(-30, 30))))
    q = qmul(q, qaxis((0, 0, 1), random.uniform(-60, 60)))
    a = (q, (random.uniform(300, 550), random.uniform(-200, 200), random.uniform(250, 500)))
    b = compose(compose(inverse(y), a), x)
    noise_q = qaxis((random.gauss(0, 1), random.gauss(0, 1), random.gauss(0, 1)), random.gauss(0, 0.05))
    b = (qmul(noise_q, b[0]), tuple(c + random.gauss(0, 0.1) for c in b[1]))
    lines.append(json.dumps({"kind": "pose", "id": i, "t": float(i),
                             "flange": {"p": [round(c, 5) for c in a[1]], "quat": [round(c, 9) for c in a[0]]},
                             "marker": {"p": [round(c, 5) for c in b[1]], "quat": [round(c, 9) for c in b[0]]}}))
with open(os.path.join(out, "rw.jsonl"), "w") as f:
    f.write("\n".join(lines) + "\n")

# Pivot: a probe (tip 160 mm along its -z from the marker, 8 mm off axis) pivoted in a
# divot at (120, -40, -1400) mm (tracker frame), 400 frames, 0.15 mm marker noise.
tip = (8.0, 0.0, -160.0)
divot = (120.0, -40.0, -1400.0)
with open(os.path.join(out, "pivot-frames.txt"), "w") as f:
    f.write("# id, then the first three rows of the 4x4 marker pose (row-major, mm); synthetic\n")
    for i in range(400):
        q = qmul(qaxis((0, 0, 1), random.uniform(0, 360)), qaxis((1, 0, 0), random.uniform(-30, 30)))
        q = qmul(q, qaxis((0, 1, 0), random.uniform(-30, 30)))
        # marker origin = divot - R tip
        rt = rot(q, tip)
        t_ = [d - r + random.gauss(0, 0.15) for d, r in zip(divot, rt)]
        cols = [rot(q, e) for e in ((1, 0, 0), (0, 1, 0), (0, 0, 1))]
        rows = [[cols[0][k], cols[1][k], cols[2][k], t_[k]] for k in range(3)]
        f.write("%d %s\n" % (i, " ".join("%.6f" % v for r in rows for v in r)))

# Import: 40 poses of tests/data/kin-geometric/train.jsonl as a table in radians and metres
# (`robocal import csv` converts them).
src = os.path.join(os.path.dirname(__file__), "..", "tests", "data", "kin-geometric", "train.jsonl")
with open(src) as fin, open(os.path.join(out, "poses.csv"), "w") as f:
    f.write("t_s,j1_rad,j2_rad,j3_rad,j4_rad,j5_rad,j6_rad,x_m,y_m,z_m\n")
    n = 0
    for line in fin:
        r = json.loads(line)
        if r.get("kind") != "pose" or not r.get("marker", {}).get("visible"):
            continue
        f.write(",".join(["%.2f" % r["t"]] + ["%.8f" % math.radians(a) for a in r["q"]] + ["%.7f" % (c / 1000.0) for c in r["marker"]["p"]]) + "\n")
        n += 1
        if n == 40:
            break
print("wrote", ", ".join(sorted(os.listdir(out))), "in", out)
