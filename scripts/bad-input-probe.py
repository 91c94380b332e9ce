#!/usr/bin/env python3
"""Bad-input probe (issue 14 point 5): feeds malformed or mistaken inputs to every
subcommand of the robocal binary and classifies each outcome.

    python3 scripts/bad-input-probe.py [--bin target/debug/robocal] [--timeout 20] [-v]

Outcomes of a *bad* input (what the case should be refused for is in its name):
  error   exit != 0, no panic, and the message names the expected cause (a word of `expect`)
  vague   exit != 0, no panic, but the message does not name the cause
  panic   the process panicked (`panicked at` on stderr / exit 101)
  hang    killed after --timeout seconds
  accept  exit 0: a silent accept or a confident wrong result
Good inputs (controls) must exit 0: `ok` or `broken`.
Needs only the project's own files (tests/data, plans, mocks/scenarios).
"""
import argparse
import json
import math
import os
import random
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GEO = os.path.join(ROOT, "tests/data/kin-geometric")
LASER = os.path.join(ROOT, "tests/data/laser-planes")
LAB = os.path.join(ROOT, "mocks/scenarios/lab-vs060-optotrak-il600.toml")
ANNULUS = os.path.join(ROOT, "plans/seed001-annulus.toml")


def read_jsonl(p):
    with open(p) as f:
        return [json.loads(line) for line in f if line.strip()]


def write_jsonl(p, rows):
    with open(p, "w") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")
    return p


def quat_mul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return [w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2]


def rotate(q, v):
    p = [0.0] + list(v)
    qc = [q[0], -q[1], -q[2], -q[3]]
    return quat_mul(quat_mul(q, p), qc)[1:]


def pivot_dataset(path, scale=1.0, n=60, bad=None):
    """Synthetic pivot records: a marker rotating about a fixed tip (tip 150 mm along z)."""
    rng = random.Random(7)
    hdr = {"format": "robocal-dataset/1", "robot": {"model": "denso-vs060"}}
    rows = [hdr]
    pivot = [100.0, -50.0, -1500.0]
    tip = [0.0, 0.0, -150.0]
    for i in range(n):
        ax = [rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-0.2, 0.2)]
        nrm = math.sqrt(sum(a * a for a in ax))
        ang = rng.uniform(0.1, 0.6)
        q = [math.cos(ang / 2)] + [math.sin(ang / 2) * a / nrm for a in ax]
        rt = rotate(q, tip)
        p = [(pivot[k] - rt[k]) * scale for k in range(3)]
        rows.append({"kind": "pivot", "t": i * 0.1, "tool": "probe",
                     "marker": {"p": p, "quat": q, "rms": 0.05}})
    if bad:
        bad(rows)
    return write_jsonl(path, rows)


def limit_memory():
    """A case that reads /dev/zero or a huge line must not take the machine down with it:
    6 GiB of address space per run (a run that needs more is killed: counted as a panic)."""
    import resource
    resource.setrlimit(resource.RLIMIT_AS, (6 << 30, 6 << 30))


class Probe:
    def __init__(self, exe, timeout, verbose):
        self.cwd = None
        self.exe = exe
        self.timeout = timeout
        self.verbose = verbose
        self.results = []

    def run(self, name, args, expect=(), good=False, timeout=None, server=False):
        t = timeout or self.timeout
        try:
            p = subprocess.run([self.exe] + args, capture_output=True, text=True, timeout=t,
                               stdin=subprocess.DEVNULL, preexec_fn=limit_memory, cwd=self.cwd)
            rc, out, err = p.returncode, p.stdout, p.stderr
        except subprocess.TimeoutExpired as e:
            rc, out, err = None, (e.stdout or b"").decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or ""), ""
        msg = (err or "") + (out or "")
        if rc is None:
            # A server that keeps serving a file it accepted: a silent accept, not a hang.
            outcome = ("accept" if server else "hang") if not good else ("ok" if server else "broken")
        elif "panicked at" in msg or rc == 101:
            outcome = "panic" if not good else "broken"
        elif good:
            outcome = "ok" if rc == 0 else "broken"
        elif rc == 0:
            outcome = "accept"
        else:
            low = msg.lower()
            outcome = "error" if (not expect or any(e.lower() in low for e in expect)) else "vague"
        first = next((line for line in (err or "").splitlines() if line.startswith("error")), "")
        if not first:
            first = (err or out or "").strip().splitlines()[-1:] or [""]
            first = first[0]
        self.results.append((name, outcome, first[:200]))
        if self.verbose:
            print(f"{outcome:7} {name}: {first[:160]}", flush=True)
        return outcome


def issue26(P, d, j, small, hdr, good, goodheld, cal, pgood, lgood):
    """Issue 26 classes: outputs that are not regular files, inputs that are not regular or
    are unbounded, read-only history, accept specs that check nothing, session options
    checked before anything moves, calibration claims, id order, plausibility of the newer
    readers."""
    b = P.run
    import stat
    os.makedirs(j("i26"), exist_ok=True)
    k = lambda *p: j("i26", *p)  # noqa: E731

    # ---- input files that are not regular, or unbounded (§7)
    fifo = k("in.fifo")
    os.mkfifo(fifo)
    adir = k("a-dir")
    os.makedirs(adir)
    garbage = k("garbage.bin")
    open(garbage, "wb").write(bytes(range(256)) * 16)
    longline = k("long.jsonl")
    with open(longline, "w") as f:
        f.write(json.dumps(hdr) + "\n")
        f.write(json.dumps({"kind": "event", "t": 0.0, "what": "note", "text": "x" * (5 << 20)}) + "\n")
    empty = k("empty.jsonl")
    open(empty, "w").close()
    pts = k("pts.csv")
    with open(pts, "w") as f:
        f.write("name,x_mm,y_mm,z_mm\n")
        for i, (x, y, z) in enumerate([(0, 0, 0), (50, 0, 0), (0, 60, 0), (0, 0, 70), (30, 30, 30)]):
            f.write(f"f{i},{x},{y},{z}\n")
    plan = j("plan.json")
    b("ctl register paired", ["register", "--ct", pts, "--tracker", pts, "--out", k("reg-ok.json")], good=True)
    eye = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]
    json.dump({"format": "robocal-robot-world/1", "T_base_tracker": {"matrix": eye}, "T_flange_marker": {"matrix": eye},
               "n_poses": 20, "rms_pos_mm": 0.05, "rms_rot_deg": 0.02, "chi2_reduced": 1.0, "closed_forms": []}, open(k("rw-ok.json"), "w"))
    readers = [
        ("inspect", lambda x: ["inspect", x], True),
        ("calibrate nominal", lambda x: ["calibrate", "nominal", "--data", x, "--out", k("o")], True),
        ("calibrate kinematics", lambda x: ["calibrate", "kinematics", "--data", x, "--out", k("o")], True),
        ("calibrate pivot", lambda x: ["calibrate", "pivot", "--data", x], True),
        ("calibrate laser", lambda x: ["calibrate", "laser", "--data", x, "--out", k("o")], True),
        ("calibrate robot-world", lambda x: ["calibrate", "robot-world", "--data", x, "--out", k("rw.json")], True),
        ("calibrate rcm", lambda x: ["calibrate", "rcm", "--data", x, "--out", k("o")], True),
        ("calibrate camera", lambda x: ["calibrate", "camera", "--data", x, "--out", k("o"), "--quiet"], True),
        ("diagnose", lambda x: ["diagnose", "--data", x, "--out", k("o")], True),
        ("diagnose --heldout", lambda x: ["diagnose", "--data", good, "--heldout", x, "--out", k("o")], True),
        ("predict --data", lambda x: ["predict", "--calibration", cal, "--data", x], True),
        ("predict --calibration", lambda x: ["predict", "--calibration", x, "--data", good], False),
        ("calibrate nominal --heldout", lambda x: ["calibrate", "nominal", "--data", good, "--heldout", x, "--out", k("o")], True),
        ("plan --check", lambda x: ["plan", "--check", x], False),
        ("plan --spec", lambda x: ["plan", "--spec", x, "--robot", "denso-vs060", "--out", k("p.json")], False),
        ("plan --chain", lambda x: ["plan", "--spec", ANNULUS, "--chain", x, "--out", k("p.json")], True),
        ("run --plan", lambda x: ["run", "--plan", x, "--sim", LAB, "--out", k("r"), "--virtual-clock", "--in-process"], False),
        ("run --sim", lambda x: ["run", "--plan", plan, "--sim", x, "--out", k("r"), "--virtual-clock", "--in-process"], False),
        ("session --sim", lambda x: ["session", "--sim", x, "--out", k("s"), "--plan-only", "--no-history"], False),
        ("session --accept", lambda x: ["session", "--sim", LAB, "--accept", x, "--out", k("s"), "--plan-only", "--no-history"], False),
        ("session --spec", lambda x: ["session", "--sim", LAB, "--spec", x, "--out", k("s"), "--plan-only", "--no-history"], False),
        ("register --ct", lambda x: ["register", "--ct", x, "--tracker", pts, "--out", k("reg.json")], False),
        ("register --tracker", lambda x: ["register", "--ct", pts, "--tracker", x, "--out", k("reg.json")], False),
        ("register --ct-mesh", lambda x: ["register", "--ct-mesh", x, "--tracker", pts, "--out", k("reg.json")], False),
        ("register --tracker-data", lambda x: ["register", "--ct", pts, "--tracker-data", x, "--out", k("reg.json")], True),
        ("chain --registration", lambda x: ["chain", "--registration", x, "--robot-world", x, "--targets", pts, "--robot-sigma-mm", "0.1"], False),
        ("chain --targets", lambda x: ["chain", "--registration", k("reg-ok.json"), "--robot-world", k("rw-ok.json"), "--targets", x, "--robot-sigma-mm", "0.1"], False),
        ("import csv", lambda x: ["import", "csv", "--input", x, "--out", k("imp.jsonl"), "--robot", "ur10", "--joints", "a,b,c,d,e,f", "--joint-unit", "deg", "--pos", "x,y,z", "--length-unit", "mm"], False),
        ("report --dir", lambda x: ["report", "--dir", x], False),
    ]
    kinds = [("FIFO", fifo, ["fifo", "regular file"], 8),
             ("/dev/zero", "/dev/zero", ["device", "regular file"], 5),
             ("directory", adir, ["directory"], 10),
             ("garbage", garbage, [], 10),
             ("empty", empty, [], 10),
             ("5 MiB line", longline, ["longer than", "line"], 20)]
    for rname, cmd, dataset in readers:
        for kname, path, exp, t in kinds:
            if rname == "report --dir" and kname not in ("FIFO", "/dev/zero", "garbage"):
                continue
            if kname == "5 MiB line" and not dataset:
                exp = []
            b(f"input {kname}: {rname}", cmd(path), exp, timeout=t)

    # ---- outputs that are not regular files (§1); a private device node, never the host's
    def node(name):
        p = k(name)
        try:
            os.mknod(p, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
            return p
        except OSError:
            return None
    real = k("real.out")
    targets = []
    f2 = k("out.fifo")
    os.mkfifo(f2)
    targets.append(("FIFO", f2, ["fifo"]))
    dn = node("out.null")
    if dn:
        targets.append(("device node", dn, ["device"]))
    od = k("out-dir.csv")
    os.makedirs(od)
    targets.append(("directory", od, ["directory"]))
    lf = k("link-fifo.out")
    os.symlink(f2, lf)
    targets.append(("symlink to FIFO", lf, ["fifo"]))
    dl = k("dangling.out")
    os.symlink(k("missing", "x.out"), dl)
    targets.append(("dangling symlink", dl, ["symbolic link", "missing"]))
    def md_link(x):
        """`report` takes only a .md / .html path: a `.md` symbolic link to the target."""
        if x.endswith(".md"):
            return x
        m = x + ".md"
        if not os.path.lexists(m):
            os.symlink(x, m)
        return m

    writers = [
        ("predict --out", lambda x: ["predict", "--calibration", cal, "--data", goodheld, "--out", x]),
        ("plan --out", lambda x: ["plan", "--spec", k("small.toml"), "--robot", "denso-vs060", "--out", x]),
        ("plan --csv", lambda x: ["plan", "--spec", k("small.toml"), "--robot", "denso-vs060", "--csv", x]),
        ("plan --urscript", lambda x: ["plan", "--spec", k("small.toml"), "--robot", "denso-vs060", "--urscript", x]),
        ("plan --summary", lambda x: ["plan", "--spec", k("small.toml"), "--robot", "denso-vs060", "--summary", x]),
        ("import csv --out", lambda x: ["import", "csv", "--input", k("imp.csv"), "--out", x, "--robot", "ur10", "--joints", "a,b,c,d,e,f", "--joint-unit", "deg", "--pos", "x,y,z", "--length-unit", "mm"]),
        ("register --out", lambda x: ["register", "--ct", pts, "--tracker", pts, "--out", x]),
        ("report --out .md", lambda x: ["report", "--dir", j("o-kin"), "--out", md_link(x)]),
    ]
    open(k("small.toml"), "w").write(open(ANNULUS).read().replace("points = 200", "points = 12"))
    with open(k("imp.csv"), "w") as f:
        f.write("a,b,c,d,e,f,x,y,z\n")
        for i in range(30):
            f.write(",".join(str(v) for v in [i, -10 + i, 20, 5, -i, 3, 400 + i, 10 * i, 300]) + "\n")
    for wname, cmd in writers:
        for tname, path, exp in targets:
            b(f"output {tname}: {wname}", cmd(path), exp, timeout=15)
        # Control: a symbolic link to a regular file is written through and stays a link.
        open(real, "w").write("old")
        link = k("link.md" if "report" in wname else "link.out")
        if os.path.lexists(link):
            os.remove(link)
        os.symlink(real, link)
        out = b(f"ctl output symlink to a file: {wname}", cmd(link), good=True, timeout=60)
        if out == "ok" and not os.path.islink(link):
            P.results[-1] = (P.results[-1][0], "broken", "the symbolic link was replaced by a file")
    # report --out X.html must not overwrite a report.md it did not write.
    rep = k("rep")
    os.makedirs(rep)
    if os.path.exists(cal):
        open(os.path.join(rep, "calibration.json"), "w").write(open(cal).read())
    open(os.path.join(rep, "report.md"), "w").write("my notes")
    out = b("ctl report --out x.html keeps another report.md", ["report", "--dir", rep, "--out", os.path.join(rep, "x.html")], good=True)
    if out == "ok" and open(os.path.join(rep, "report.md")).read() != "my notes":
        P.results[-1] = (P.results[-1][0], "accept", "report.md overwritten")

    # ---- read-only history (§8)
    hd = k("hist")
    os.makedirs(hd)
    P.cwd = hd
    for url in ("mysql://u@h/db", "sqlite3://x.db", "http://example/x", "ftp://a/b", "redis://h"):
        out = b(f"history --db {url}", ["history", "--robot", "X", "--db", url], ["scheme", "postgres"])
    for name in ("typo.sqlite", "sub/dir/typo.sqlite"):
        b(f"history --db missing {name}", ["history", "--robot", "X", "--db", os.path.join(hd, name)], ["no history database"])
    import sqlite3
    foreign = os.path.join(hd, "foreign.sqlite")
    c = sqlite3.connect(foreign)
    c.execute("CREATE TABLE patients (id INTEGER)")
    c.commit()
    c.close()
    before = open(foreign, "rb").read()
    b("history --db foreign SQLite", ["history", "--robot", "X", "--db", foreign], ["not a robocal history"])
    if open(foreign, "rb").read() != before:
        P.results[-1] = (P.results[-1][0], "accept", "the foreign database was altered")
    b("history --db a text file", ["history", "--robot", "X", "--db", garbage], ["not a sqlite", "not a robocal"])
    b("history --db a directory", ["history", "--robot", "X", "--db", adir], ["regular file", "directory"])
    P.cwd = None
    if len(os.listdir(hd)) != 1:
        P.results.append(("history created files in its working directory", "accept", str(os.listdir(hd))))

    # ---- accept specs (§4): kind named, matches the cell, has an accuracy criterion
    acc = lambda name, text: (open(k(name), "w").write(text), k(name))[1]  # noqa: E731
    specs = [
        ("camera spec on a kinematic cell", os.path.join(ROOT, "accept/camera.toml"), ["judges camera"]),
        ("only a name", acc("a1.toml", 'name = "x"\n'), ["session"]),
        ("no session kind", acc("a2.toml", 'name = "x"\nheldout_rms_mm_max = 1.0\n'), ["session"]),
        ("no accuracy criterion", acc("a3.toml", 'name = "x"\nsession = "kinematic"\nskipped_fraction_max = 0.1\n'), ["accuracy criterion"]),
        ("only must_improve", acc("a4.toml", 'name = "x"\nsession = "kinematic"\nmust_improve = true\n'), ["accuracy criterion"]),
        ("camera criterion in a kinematic spec", acc("a5.toml", 'name = "x"\nsession = "kinematic"\nheldout_rms_mm_max = 1.0\nheldout_reprojection_px_max = 0.5\n'), ["never be checked"]),
        ("unknown session kind", acc("a6.toml", 'name = "x"\nsession = "laser"\nheldout_rms_mm_max = 1.0\n'), ["session"]),
        ("camera spec without px criterion", acc("a7.toml", 'name = "x"\nsession = "camera"\nhand_eye_ci95_mm_max = 1.0\n'), ["heldout_reprojection_px_max"]),
        ("param ci only", acc("a8.toml", 'name = "x"\nsession = "kinematic"\nparam_ci95_mm_max = 1.0\n'), ["accuracy criterion"]),
    ]
    for i, (name, path, exp) in enumerate(specs):
        b(f"session --accept: {name}", ["session", "--sim", LAB, "--out", k(f"acc{i}"), "--plan-only", "--no-history", "--accept", path], exp, timeout=60)
    b("ctl session --accept research --plan-only", ["session", "--sim", LAB, "--out", k("acc-ok"), "--plan-only", "--no-history", "--accept", os.path.join(ROOT, "accept/research.toml")], good=True, timeout=300)

    # ---- session options checked before anything is created (§5)
    gj = k("garbage.json")
    open(gj, "w").write("not json")
    for i, (opts, exp) in enumerate([
            (["--speed-deg-s=NaN"], ["speed"]), (["--speed-deg-s=inf"], ["speed"]), (["--speed-deg-s=0"], ["speed"]),
            (["--speed-deg-s=-3"], ["speed"]), (["--speed-deg-s=1000"], ["limit"]), (["--accel-deg-s2=NaN"], ["accel"]),
            (["--accel-deg-s2=0"], ["accel"]), (["--accel-deg-s2=1e9"], ["limit"]), (["--frames=0"], ["frames"]),
            (["--frames=100000000"], ["frames"]), (["--history", "mysql://h/db"], ["scheme"]),
            (["--history", garbage], ["sqlite"]), (["--history", adir], ["regular file", "directory"]),
            (["--chain-targets", pts, "--chain-registration", gj, "--chain-robot-world", gj], ["garbage.json"]),
            (["--chain-targets", fifo, "--chain-registration", gj, "--chain-robot-world", gj], ["fifo", "garbage.json"]),
            (["--chain-targets", pts, "--chain-registration", gj, "--chain-robot-world", gj, "--chain-tool-sigma-mm=NaN"], ["sigma"]),
            (["--arm", "nosuch"], ["nosuch"]), (["--poses", "0"], ["poses"]), (["--heldout-points", "1"], ["heldout"])]):
        b(f"session {' '.join(o if '/' not in o else os.path.basename(o) for o in opts)}", ["session", "--sim", LAB, "--out", k(f"opt{i}"), "--plan-only"] + opts, exp, timeout=60)

    # ---- calibration claims (§3)
    calj = json.load(open(cal)) if os.path.exists(cal) else None
    if calj:
        def cvar(name, f):
            c = json.loads(json.dumps(calj))
            f(c)
            json.dump(c, open(k(name), "w"))
            return k(name)
        cases = [
            ("params []", cvar("c-empty.json", lambda c: c.update(params=[])), ["params", "empty"]),
            ("compliance 1e308", cvar("c-comp.json", lambda c: c.update(effects=[{"kind": "joint_compliance", "joint": 2, "params": {"points": ["j3"], "c_times_mass_deg_kg_per_nm": [1e308]}}])), ["plausible"]),
            ("scale_ppm 1e300", cvar("c-scale.json", lambda c: c.update(effects=[{"kind": "tracker_scale", "params": {"scale_ppm": 1e300}}])), ["plausible"]),
            ("kind banana", cvar("c-banana.json", lambda c: c.update(kind="banana")), ["banana"]),
            ("effect warp_drive", cvar("c-warp.json", lambda c: c.update(effects=[{"kind": "warp_drive", "params": {}}])), ["warp_drive"]),
            ("effect without params", cvar("c-noparam.json", lambda c: c.update(effects=[{"kind": "backlash", "joint": 2, "params": {}}])), ["backlash", "half_lost_motion"]),
            ("kind laser without a beam", cvar("c-laser.json", lambda c: c.update(kind="laser")), ["laser"]),
        ]
        for name, path, exp in cases:
            b(f"predict: calibration {name}", ["predict", "--calibration", path, "--data", goodheld], exp)
            b(f"diagnose --calibration {name}", ["diagnose", "--data", good, "--calibration", path, "--out", k("o")], exp + ["kinematic"] if "kind" in name else exp, timeout=120)

    # ---- dataset ids reversed / swapped / merged (§3: a regression)
    poses = small[1:]
    rev = write_jsonl(k("rev.jsonl"), [small[0]] + list(reversed(poses)))
    sw = [small[0]] + poses[:]
    sw[5], sw[6] = sw[6], sw[5]
    swp = write_jsonl(k("swap.jsonl"), sw)
    merged = write_jsonl(k("merged.jsonl"), [small[0]] + poses[:30] + poses[:10])
    for what, path, exp in [("ids reversed", rev, ["id"]), ("ids swapped", swp, ["id"]), ("ids repeated (two files merged)", merged, ["id"])]:
        b(f"inspect: {what}", ["inspect", path], exp)
        b(f"calibrate nominal: {what}", ["calibrate", "nominal", "--data", path, "--out", k("o")], exp)
        b(f"calibrate kinematics: {what}", ["calibrate", "kinematics", "--data", path, "--out", k("o")], exp)
        b(f"predict: {what}", ["predict", "--calibration", cal, "--data", path], exp)
        b(f"diagnose: {what}", ["diagnose", "--data", path, "--out", k("o")], exp)

    # ---- quaternions (§3): non-unit, 1e308, wrong order, in every reader of marker poses
    def qvar(name, g):
        rows = json.loads(json.dumps(small))
        g(rows)
        return write_jsonl(k(name + ".jsonl"), rows)
    has_q = any("quat" in (r.get("marker") or {}) for r in small[1:])
    if has_q:
        qcases = [("marker quat norm 2", qvar("q2", lambda rs: rs[3]["marker"].update(quat=[2.0, 0, 0, 0]))),
                  ("marker quat 1e308", qvar("q308", lambda rs: rs[3]["marker"].update(quat=[1e308, 0, 0, 0]))),
                  ("marker quat zeros", qvar("q0", lambda rs: rs[3]["marker"].update(quat=[0, 0, 0, 0])))]
        for name, path in qcases:
            for cmd in (["inspect", path], ["calibrate", "nominal", "--data", path, "--out", k("o")],
                        ["calibrate", "robot-world", "--data", path, "--out", k("rw.json")], ["predict", "--calibration", cal, "--data", path]):
                b(f"{cmd[0]} {cmd[1] if cmd[0] == 'calibrate' else ''}: {name}".replace("  ", " "), cmd, ["quat"])
    pq = [("pivot quat norm 3", pivot_dataset(k("pq3.jsonl"), bad=lambda rs: rs[3]["marker"].update(quat=[3.0, 0, 0, 0]))),
          ("pivot quat NaN-like 1e308", pivot_dataset(k("pq308.jsonl"), bad=lambda rs: rs[3]["marker"].update(quat=[1e308, 1e308, 0, 0])))]
    def two_tools(rows):
        extra = []
        for r in rows[1:]:
            r2 = json.loads(json.dumps(r))
            r2["tool"] = "pointer"
            r2["t"] += 100.0
            r2["marker"]["p"][0] += 80.0
            extra.append(r2)
        rows.extend(extra)
    pq.append(("records of two tools", pivot_dataset(k("ptwo.jsonl"), bad=two_tools)))
    for name, path in pq:
        b(f"calibrate pivot: {name}", ["calibrate", "pivot", "--data", path], ["tools"] if "tools" in name else ["quat"])
        if "tools" not in name:
            b(f"inspect: {name}", ["inspect", path], ["quat"])

    # ---- chain --joints-deg outside the limits (§3)
    reg, rw = k("reg-ok.json"), k("rw-ok.json")
    if os.path.exists(reg) and os.path.exists(cal):
        for q in ("800,0,0,0,0,0", "0,0,0,0,0,1e308", "0,0,0,0,0,-400", "0,200,0,0,0,0"):
            b(f"chain --joints-deg {q}", ["chain", "--registration", reg, "--robot-world", rw, "--targets", pts, "--calibration", cal, "--joints-deg", q], ["limit"])
        b("ctl chain --joints-deg 0,10,80,0,40,0", ["chain", "--registration", reg, "--robot-world", rw, "--targets", pts, "--calibration", cal, "--joints-deg", "0,10,80,0,40,0"], good=True)

    # ---- bounded counts (§7)
    for cmd, exp in [(["calibrate", "kinematics", "--data", good, "--out", k("o"), "--bootstrap", "100000000"], ["bootstrap"]),
                     (["calibrate", "camera", "--data", good, "--out", k("o"), "--bootstrap", "100000000"], ["bootstrap", "camera"]),
                     (["calibrate", "rcm", "--data", good, "--out", k("o"), "--bootstrap", "100000000"], ["bootstrap", "camera", "instrument"]),
                     (["chain", "--registration", garbage, "--robot-world", garbage, "--targets", pts, "--robot-sigma-mm", "0.1", "--mc", "100000000000"], ["mc"])]:
        b(f"{cmd[0]} {cmd[1]} {cmd[-2]} {cmd[-1]}", cmd, exp, timeout=30)


def ascii_stl(path, tris):
    with open(path, "w") as f:
        f.write("solid probe\n")
        for a, b, c in tris:
            f.write(" facet normal 0 0 0\n  outer loop\n")
            for v in (a, b, c):
                f.write(f"   vertex {v[0]} {v[1]} {v[2]}\n")
            f.write("  endloop\n endfacet\n")
        f.write("endsolid probe\n")
    return path


def bumpy_surface(scale=1.0, n=24, size=120.0):
    """A distinctive surface z = f(x, y) (two bumps and a ridge; mm) as triangles, scaled."""
    def z(x, y):
        return (25 * math.exp(-((x - 30) ** 2 + (y - 20) ** 2) / 600) + 15 * math.exp(-((x + 35) ** 2 + (y + 25) ** 2) / 300)
                + 0.08 * x + 0.15 * y * y / size)
    h = size / n
    tris = []
    for i in range(n):
        for k in range(n):
            x0, y0 = -size / 2 + i * h, -size / 2 + k * h
            p = [(x0, y0), (x0 + h, y0), (x0 + h, y0 + h), (x0, y0 + h)]
            v = [[c[0] * scale, c[1] * scale, z(*c) * scale] for c in p]
            tris.append((v[0], v[1], v[2]))
            tris.append((v[0], v[2], v[3]))
    return tris, z


def issue26_round3(P, j, small, good, cal, lgood, lheldp):
    """Issue 26, third round: quaternions in the wrong order in every reader of marker poses,
    truth points / CT meshes in metres, camera calibration values predict applies, the
    likely cause of "0 usable poses"."""
    b = P.run
    os.makedirs(j("r3"), exist_ok=True)
    k = lambda *p: j("r3", *p)  # noqa: E731

    # ---- quaternions scalar-last ([x, y, z, w]) in a file declared [w, x, y, z] (§3)
    rows = json.loads(json.dumps(small))
    for r in rows[1:]:
        q = (r.get("marker") or {}).get("quat")
        if q:
            r["marker"]["quat"] = [q[1], q[2], q[3], q[0]]
    xyzw = write_jsonl(k("xyzw.jsonl"), rows)
    for cmd in (["inspect", xyzw], ["calibrate", "nominal", "--data", xyzw, "--out", k("o")],
                ["calibrate", "kinematics", "--data", xyzw, "--out", k("o")],
                ["calibrate", "robot-world", "--data", xyzw, "--out", k("rw.json")],
                ["predict", "--calibration", cal, "--data", xyzw],
                ["diagnose", "--data", xyzw, "--out", k("o")]):
        b(f"{' '.join(cmd[:2]) if cmd[0] == 'calibrate' else cmd[0]}: marker quaternions scalar-last", cmd, ["[x, y, z, w]"], timeout=120)
    b("ctl calibrate robot-world", ["calibrate", "robot-world", "--data", good, "--out", k("rw-ok.json")], good=True)
    # Pivot records only (no robot rotation to compare with): the pivot fit tells the order.
    def pivot_xyzw(rows):
        for r in rows[1:]:
            q = r["marker"]["quat"]
            r["marker"]["quat"] = [q[1], q[2], q[3], q[0]]
    b("calibrate pivot: quaternions scalar-last", ["calibrate", "pivot", "--data", pivot_dataset(k("pxyzw.jsonl"), bad=pivot_xyzw)], ["[x, y, z, w]"])
    b("ctl calibrate pivot", ["calibrate", "pivot", "--data", pivot_dataset(k("pok.jsonl"))], good=True)

    # ---- 0 usable poses: the likely cause (§6)
    for name, g, exp in [("markers not seen", lambda r: r.update(marker={"visible": False}), ["did not see"]),
                         ("markers without orientation", lambda r: r["marker"].pop("quat", None), ["orientation"])]:
        rows = json.loads(json.dumps(small))
        for r in rows[1:]:
            g(r)
        path = write_jsonl(k(name.replace(" ", "-") + ".jsonl"), rows)
        b(f"calibrate robot-world: {name}", ["calibrate", "robot-world", "--data", path, "--out", k("rw.json")], exp)

    # ---- calibrate laser --truth in metres (§3)
    truth = os.path.join(LASER, "truth.csv")
    lines = open(truth).read().splitlines()
    tm = k("truth-m.csv")
    with open(tm, "w") as f:
        f.write(lines[0] + "\n")
        for line in lines[1:]:
            c = line.split(",")
            f.write(",".join([c[0]] + [str(float(x) / 1000) for x in c[1:]]) + "\n")
    b("ctl calibrate laser --truth", ["calibrate", "laser", "--data", lgood, "--heldout", lheldp, "--truth", truth, "--out", k("o-las")], good=True)
    b("calibrate laser --truth in metres", ["calibrate", "laser", "--data", lgood, "--heldout", lheldp, "--truth", tm, "--out", k("o-las2")], ["metres"])

    # ---- register --ct-mesh in metres (§3)
    tris_mm, z = bumpy_surface(1.0)
    tris_m, _ = bumpy_surface(0.001)
    mesh_mm = ascii_stl(k("mesh-mm.stl"), tris_mm)
    mesh_m = ascii_stl(k("mesh-m.stl"), tris_m)
    rng = random.Random(5)
    trk = k("surface.csv")
    with open(trk, "w") as f:
        f.write("name,x_mm,y_mm,z_mm\n")
        for i in range(80):
            x, y = rng.uniform(-55, 55), rng.uniform(-55, 55)
            f.write(f"s{i},{x + 3.0},{y - 2.0},{z(x, y) + 1.5}\n")
    b("ctl register --ct-mesh", ["register", "--ct-mesh", mesh_mm, "--tracker", trk, "--out", k("reg-s.json")], good=True, timeout=120)
    b("register --ct-mesh: mesh in metres", ["register", "--ct-mesh", mesh_m, "--tracker", trk, "--out", k("reg-m.json")], ["metres"], timeout=120)

    # ---- camera calibration values predict applies (§9, §3)
    cam = {"format": "robocal-calibration/1", "robot": small[0]["robot"], "params": [], "kind": "camera",
           "camera": {"intrinsics": {"fx": 900.0, "fy": 900.0, "cx": 320.0, "cy": 240.0, "dist": [0, 0, 0, 0, 0], "width": 640, "height": 480},
                      "hand_eye": {"mount": "flange", "xyz_mm": [0, 50, 40], "quat": [1, 0, 0, 0]},
                      "target_in_base": {"xyz_mm": [-576.9, -223.3, 0.0], "quat": [0, 1, 0, 0]},
                      "target": {"kind": "chessboard", "cols": 9, "rows": 6, "square_mm": 30.0}}}
    def camvar(name, f):
        c = json.loads(json.dumps(cam))
        f(c["camera"])
        path = k(name + ".json")
        json.dump(c, open(path, "w"))
        return path
    b("ctl predict camera calibration", ["predict", "--calibration", camvar("cam-ok", lambda c: c.update(target_bend_mm=[0.3, 0.0])), "--data", good, "--out", k("cam.csv")], good=True)
    for name, f, exp in [("target_bend_mm 400 (m for mm?)", lambda c: c.update(target_bend_mm=[400.0, 0.0]), ["target_bend_mm"]),
                         ("target_scale 1000", lambda c: c.update(target_scale=1000.0), ["target_scale"]),
                         ("target_scale 0", lambda c: c.update(target_scale=0.0), ["target_scale"]),
                         ("fx 0", lambda c: c["intrinsics"].update(fx=0.0), ["intrinsics"]),
                         ("dist 1e308", lambda c: c["intrinsics"].update(dist=[1e308, 0, 0, 0, 0]), ["intrinsics"]),
                         ("hand-eye quat norm 2", lambda c: c["hand_eye"].update(quat=[2, 0, 0, 0]), ["hand_eye", "quat"]),
                         ("board 0 columns", lambda c: c["target"].update(cols=0), ["board", "target"])]:
        b(f"predict: camera calibration {name}", ["predict", "--calibration", camvar("cam-" + name.split()[0], f), "--data", good], exp)


def issue26_round5(P, j, good, cal, lgood):
    """Issue 26, fifth round: `correct` (targets and robot-program options), tracker points
    on one plane for `register --ct-mesh`, `.rom` tool files of a device file, camera images
    that cannot be read."""
    b = P.run
    os.makedirs(j("r5"), exist_ok=True)
    k = lambda *p: j("r5", *p)  # noqa: E731

    # ---- correct: targets and robot-program options (§3, §5)
    def targets(name, rows, head="name,x_mm,y_mm,z_mm,qw,qx,qy,qz"):
        path = k(name + ".csv")
        with open(path, "w") as f:
            f.write(head + "\n")
            for r in rows:
                f.write(",".join(str(x) for x in r) + "\n")
        return path
    tgood = targets("t-good", [["A", 400, 0, 300, 0, 1, 0, 0], ["B", 380, 60, 320, 0, 1, 0, 0]])
    c = ["correct", "--calibration", cal, "--targets"]
    b("ctl correct", c + [tgood], good=True)
    b("ctl correct --format urscript", c + [tgood, "--format", "urscript", "--speed", "0.5", "--accel", "1.0"], good=True)
    b("ctl correct --format pacscript", c + [tgood, "--format", "pacscript", "--speed", "20"], good=True)
    for name, rows, exp in [
            ("targets in metres", [["A", 0.4, 0, 0.3, 0, 1, 0, 0], ["B", 0.38, 0.06, 0.32, 0, 1, 0, 0]], ["metres"]),
            ("targets 1e308", [["A", 1e308, 0, 300, 0, 1, 0, 0]], ["x_mm"]),
            ("target NaN", [["A", "NaN", 0, 300, 0, 1, 0, 0]], ["not finite"]),
            ("quaternion norm 2", [["A", 400, 0, 300, 0, 2, 0, 0]], ["quaternion"]),
            ("quaternion zero", [["A", 400, 0, 300, 0, 0, 0, 0]], ["quaternion"]),
            ("Euler angles in the quaternion", [["A", 400, 0, 300, 180, 0, 90, 0]], ["quaternion"]),
            ("target out of reach", [["A", 5000, 0, 300, 0, 1, 0, 0]], ["unreachable"]),
            ("branch 9", [["A", 400, 0, 300, 0, 1, 0, 0, 9]], ["branch"]),
            ("row with a missing field", [["A", 400, 0, 300, 0, 1, 0]], ["line", "field"]),
            ("no rows", [], ["no target"])]:
        head = "name,x_mm,y_mm,z_mm,qw,qx,qy,qz" + (",branch" if name == "branch 9" else "")
        b(f"correct: {name}", c + [targets("t-" + name.split()[0] + str(len(name)), rows, head)], exp)
    b("correct: header without qw", c + [targets("t-noqw", [["A", 400, 0, 300, 1, 0, 0]], "name,x_mm,y_mm,z_mm,qx,qy,qz")], ["qw"])
    b("correct: header in metres", c + [targets("t-m", [["A", 0.4, 0, 0.3, 0, 1, 0, 0]], "name,x_m,y_m,z_m,qw,qx,qy,qz")], ["x_mm"])
    for name, extra, exp in [
            ("urscript --speed 30 (deg/s as rad/s)", ["--format", "urscript", "--speed", "30"], ["rad/s"]),
            ("urscript --speed 1e9", ["--format", "urscript", "--speed", "1e9"], ["rad/s"]),
            ("urscript --accel 1000", ["--format", "urscript", "--accel", "1000"], ["rad/s²"]),
            ("pacscript --speed 500", ["--format", "pacscript", "--speed", "500"], ["percentage"]),
            ("--speed NaN", ["--format", "urscript", "--speed=NaN"], ["speed"]),
            ("--speed -1", ["--format", "urscript", "--speed=-1"], ["speed"]),
            ("--wait inf", ["--format", "urscript", "--wait=inf"], ["wait"])]:
        b(f"correct: {name}", c + [tgood] + extra, exp)
    b("correct: laser calibration", ["correct", "--calibration", j("o-las", "calibration.json"), "--targets", tgood], ["kinematic"])
    b("correct: calibration is a dataset", ["correct", "--calibration", good, "--targets", tgood], ["this is a dataset"])
    b("correct: targets file is a directory", c + [k()], ["directory"])

    # ---- register --ct-mesh with tracker points on one plane: unconstrained directions (§3)
    tris, z = bumpy_surface(1.0)
    mesh = ascii_stl(k("mesh.stl"), tris)
    rng = random.Random(11)
    flat = k("flat.csv")
    with open(flat, "w") as f:
        f.write("name,x_mm,y_mm,z_mm\n")
        for i in range(60):
            f.write(f"f{i},{rng.uniform(-50, 50)},{rng.uniform(-50, 50)},{40.0 + rng.gauss(0, 0.05)}\n")
    line = k("line.csv")
    with open(line, "w") as f:
        f.write("name,x_mm,y_mm,z_mm\n")
        for i in range(40):
            x = -50 + 2.5 * i
            f.write(f"l{i},{x},{0.0},{z(x, 0.0)}\n")
    b("register --ct-mesh: tracker points on one flat plane", ["register", "--ct-mesh", mesh, "--tracker", flat, "--out", k("reg-flat.json")], ["unconstrained", "plane", "slide"], timeout=120)
    b("register --ct-mesh: tracker points along one line", ["register", "--ct-mesh", mesh, "--tracker", line, "--out", k("reg-line.json")], ["unconstrained", "line", "slide"], timeout=120)

    # ---- device file: the tracker's `.rom` tool files (§5)
    cell = k("cell")
    os.makedirs(os.path.join(cell, "tools"), exist_ok=True)
    text = open(os.path.join(ROOT, "examples/CELL.toml")).read()
    for name, setup, exp in [
            ("missing .rom", lambda: None, ["rom"]),
            (".rom is a directory", lambda: os.makedirs(os.path.join(cell, "tools", "flange-marker.rom"), exist_ok=True), ["rom"]),
    ]:
        setup()
        dev = os.path.join(cell, "CELL.toml")
        open(dev, "w").write(text)
        b(f"devices --probe: {name}", ["devices", "--devices", dev, "--probe", "--timeout-s", "1"], exp, timeout=30)
    os.rmdir(os.path.join(cell, "tools", "flange-marker.rom"))
    open(os.path.join(cell, "tools", "flange-marker.rom"), "wb").write(bytes([0x5a]) * 752)
    b("devices --probe: garbage .rom", ["devices", "--devices", os.path.join(cell, "CELL.toml"), "--probe", "--timeout-s", "1"], ["rom"], timeout=30)

    # ---- camera images that cannot be read: each named with its reason (§6)
    hdr = {"format": "robocal-dataset/1", "robot": {"model": "ur5e"},
           "camera": {"kind": "mono", "width": 640, "height": 480, "mount": "flange"},
           "target": {"kind": "chessboard", "cols": 9, "rows": 6, "square_mm": 30.0}}
    imgs = k("imgs")
    os.makedirs(os.path.join(imgs, "adir.png"), exist_ok=True)
    open(os.path.join(imgs, "garbage.png"), "wb").write(bytes(range(256)) * 8)
    open(os.path.join(imgs, "trunc.pgm"), "wb").write(b"P5\n640 480\n255\n" + bytes(1000))
    open(os.path.join(imgs, "small.pgm"), "wb").write(b"P5\n64 48\n255\n" + bytes(64 * 48))
    open(os.path.join(imgs, "empty.png"), "wb").write(b"")
    names = ["missing.png", "adir.png", "garbage.png", "trunc.pgm", "small.pgm", "empty.png", "/etc/passwd"]
    rows = [hdr]
    for i, n in enumerate(names * 2):
        rows.append({"kind": "pose", "id": i, "t": float(i), "q": [0, -90, 90, 0, 90, 0],
                     "image": n if n.startswith("/") else "imgs/" + n})
    camds = write_jsonl(k("cam.jsonl"), rows)
    b("calibrate camera: no image readable (missing, directory, garbage, truncated, wrong size, empty, /etc/passwd)",
      ["calibrate", "camera", "--data", camds, "--out", k("cam-out")], ["missing", "not an image", "truncated", "directory"], timeout=60)


def issue26_round6(P, d, j, good, cal):
    """Issue 26, sixth round: a robocal file of another kind given where a reader expects its
    own (a dataset as `--calibration`, a calibration as `--data`, ...): the reader names the
    kind it got, not only "invalid JSON"."""
    b = P.run
    reg, rw = j("i26", "reg-ok.json"), j("i26", "rw-ok.json")
    pts = j("i26", "pts.csv")
    tg = j("r6-targets.csv")
    open(tg, "w").write("name,x_mm,y_mm,z_mm,qw,qx,qy,qz\nA,400,0,300,0,1,0,0\n")
    ds = "this is a dataset"
    cl = "this is a calibration file"
    b("wrong kind: correct --calibration DATASET", ["correct", "--calibration", good, "--targets", tg], [ds])
    b("wrong kind: predict --calibration DATASET", ["predict", "--calibration", good, "--data", good], [ds])
    b("wrong kind: diagnose --calibration DATASET", ["diagnose", "--data", good, "--calibration", good, "--out", j("r6-o")], [ds])
    b("wrong kind: predict --data CALIBRATION", ["predict", "--calibration", cal, "--data", cal], [cl])
    b("wrong kind: inspect CALIBRATION", ["inspect", cal], [cl])
    b("wrong kind: calibrate kinematics --data CALIBRATION", ["calibrate", "kinematics", "--data", cal, "--out", j("r6-k")], [cl])
    b("wrong kind: plan --check DATASET", ["plan", "--check", good], [ds])
    b("wrong kind: plan --check CALIBRATION", ["plan", "--check", cal], ["robocal-calibration/1"])
    if os.path.exists(reg) and os.path.exists(rw):
        b("wrong kind: chain --robot-world DATASET", ["chain", "--registration", reg, "--robot-world", good, "--targets", pts, "--robot-sigma-mm", "0.1"], [ds])
        b("wrong kind: chain --registration CALIBRATION", ["chain", "--registration", cal, "--robot-world", rw, "--targets", pts, "--robot-sigma-mm", "0.1"], [cl])
        b("wrong kind: chain --registration DATASET", ["chain", "--registration", good, "--robot-world", rw, "--targets", pts, "--robot-sigma-mm", "0.1"], [ds])


def issue26_round7(P, j, good, cal):
    """Issue 26, seventh round: a robocal TOML file (scenario, plan spec, accept spec, device
    file) given to a JSON reader, and a robocal JSON file given to a TOML reader, are named."""
    b = P.run
    tg = j("r7-targets.csv")
    open(tg, "w").write("name,x_mm,y_mm,z_mm,qw,qx,qy,qz\nA,400,0,300,0,1,0,0\n")
    acc = os.path.join(ROOT, "accept/surgical.toml")
    dev = os.path.join(ROOT, "examples/CELL.toml")
    t = "this is a TOML file"
    b("toml for json: correct --calibration SCENARIO", ["correct", "--calibration", LAB, "--targets", tg], [t + " (a scenario"])
    b("toml for json: predict --calibration PLAN-SPEC", ["predict", "--calibration", ANNULUS, "--data", good], [t + " (a plan spec"])
    b("toml for json: inspect PLAN-SPEC", ["inspect", ANNULUS], [t + " (a plan spec"])
    b("toml for json: predict --data ACCEPT", ["predict", "--calibration", cal, "--data", acc], [t + " (an accept spec"])
    b("toml for json: calibrate kinematics --data DEVICES", ["calibrate", "kinematics", "--data", dev, "--out", j("r7-k")], [t + " (a device file"])
    b("toml for json: plan --check SCENARIO", ["plan", "--check", LAB], [t + " (a scenario"])
    b("json for toml: session --sim CALIBRATION", ["session", "--sim", cal, "--out", j("r7-s1"), "--plan-only", "--no-history"], ["not a scenario"])
    b("json for toml: sim serve --scenario DATASET", ["sim", "serve", "--scenario", good, "--virtual-clock"], ["not a scenario"], timeout=10, server=True)
    b("json for toml: session --accept DATASET", ["session", "--sim", LAB, "--accept", good, "--out", j("r7-s2"), "--plan-only", "--poses", "20", "--heldout-points", "10", "--no-history"], ["not an accept spec"], timeout=60)
    b("json for toml: devices --devices CALIBRATION", ["devices", "--devices", cal], ["not a device file"])
    b("json for toml: plan --spec DATASET", ["plan", "--spec", good, "--robot", "denso-vs060"], ["not a plan spec"])
    b("toml for toml: devices --devices PLAN-SPEC", ["devices", "--devices", ANNULUS], ["a plan spec"])
    b("toml for toml: session --accept SCENARIO", ["session", "--sim", LAB, "--accept", LAB, "--out", j("r7-s3"), "--plan-only", "--poses", "20", "--heldout-points", "10", "--no-history"], ["a scenario"], timeout=60)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default=os.path.join(ROOT, "target/debug/robocal"))
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args()
    P = Probe(a.bin, a.timeout, a.verbose)
    d = tempfile.mkdtemp(prefix="robocal-probe-")
    j = lambda *p: os.path.join(d, *p)  # noqa: E731

    train = read_jsonl(os.path.join(GEO, "train.jsonl"))
    held = read_jsonl(os.path.join(GEO, "heldout.jsonl"))
    hdr, poses = train[0], train[1:]
    small = [hdr] + poses[:80]
    good = write_jsonl(j("good.jsonl"), small)
    goodheld = write_jsonl(j("goodheld.jsonl"), [held[0]] + held[1:40])

    def variant(name, f, base=None):
        rows = json.loads(json.dumps(base or small))
        f(rows)
        return write_jsonl(j(name + ".jsonl"), rows)

    def each_pose(rows, g):
        for r in rows[1:]:
            if r.get("kind") == "pose":
                g(r)

    metres = variant("metres", lambda rs: each_pose(rs, lambda r: r["marker"].update(
        p=[x / 1000 for x in r["marker"]["p"]])))
    radians = variant("radians", lambda rs: each_pose(rs, lambda r: r.update(
        q=[math.radians(x) for x in r["q"]], q_cmd=[math.radians(x) for x in r["q_cmd"]])))

    def set_q(rs, i, k, v):
        rs[i]["q"][k] = v

    q1e308 = variant("q1e308", lambda rs: set_q(rs, 5, 1, 1e308))
    q400 = variant("q400", lambda rs: set_q(rs, 5, 0, 400.0))

    def set_p(rs, i, k, v):
        rs[i]["marker"]["p"][k] = v

    p1e308 = variant("p1e308", lambda rs: set_p(rs, 5, 2, 1e308))
    p1e200 = variant("p1e200", lambda rs: set_p(rs, 5, 0, 1e200))
    six = write_jsonl(j("six.jsonl"), [hdr] + poses[:6])
    twelve = write_jsonl(j("twelve.jsonl"), [hdr] + poses[:12])
    three = write_jsonl(j("three.jsonl"), [hdr] + poses[:3])
    t1e308 = variant("t1e308", lambda rs: rs[4].update(t=1e308))
    negrms = variant("negrms", lambda rs: rs[4]["marker"].update(rms=-1.0))
    hugetemp = variant("hugetemp", lambda rs: rs[4].update(temp_c=1e300))
    ur = json.loads(json.dumps(held[0]))
    ur["robot"] = {"model": "ur5e"}
    urheld = write_jsonl(j("urheld.jsonl"), [ur] + [dict(r, q=r["q"]) for r in held[1:40]])
    invis = []
    for r in held[1:30]:
        r = json.loads(json.dumps(r))
        r["marker"] = {"visible": False}
        invis.append(r)
    emptyheld = write_jsonl(j("emptyheld.jsonl"), [held[0]] + invis)
    eventsonly = write_jsonl(j("eventsonly.jsonl"), [held[0], {"kind": "event", "t": 1.0, "what": "note"}])

    # Laser.
    ltrain = read_jsonl(os.path.join(LASER, "train.jsonl"))
    lheld = read_jsonl(os.path.join(LASER, "heldout.jsonl"))
    lgood = write_jsonl(j("lgood.jsonl"), ltrain)
    lheldp = write_jsonl(j("lheld.jsonl"), lheld)
    lneg = variant("lneg", lambda rs: rs[3].update(range=-50.0), ltrain)
    lmetres = variant("lmetres", lambda rs: [r.update(range=r["range"] / 1000) for r in rs[1:] if r.get("range") is not None], ltrain)
    lflm = variant("lflangem", lambda rs: [r["flange"].update(p=[x / 1000 for x in r["flange"]["p"]]) for r in rs[1:] if "flange" in r], ltrain)
    l1e308 = variant("l1e308", lambda rs: rs[3].update(range=1e308), ltrain)

    # Pivot.
    pgood = pivot_dataset(j("pgood.jsonl"))
    pmetres = pivot_dataset(j("pmetres.jsonl"), scale=0.001)
    p308 = pivot_dataset(j("p308.jsonl"), bad=lambda rs: rs[3]["marker"]["p"].__setitem__(0, 1e308))
    pfew = pivot_dataset(j("pfew.jsonl"), n=3)

    b = P.run
    # ---- controls (good input must still work)
    b("ctl calibrate nominal", ["calibrate", "nominal", "--data", good, "--out", j("o-nom"), "--heldout", goodheld], good=True)
    b("ctl calibrate kinematics", ["calibrate", "kinematics", "--data", good, "--out", j("o-kin"), "--heldout", goodheld], good=True)
    cal = j("o-kin", "calibration.json")
    b("ctl predict", ["predict", "--calibration", cal, "--data", goodheld, "--out", j("pred.csv")], good=True)
    b("ctl calibrate laser", ["calibrate", "laser", "--data", lgood, "--heldout", lheldp, "--out", j("o-las")], good=True)
    b("ctl calibrate pivot", ["calibrate", "pivot", "--data", pgood], good=True)
    b("ctl inspect", ["inspect", good], good=True)
    b("ctl plan", ["plan", "--spec", ANNULUS, "--robot", "denso-vs060", "--out", j("plan.json")], good=True, timeout=120)
    b("ctl plan --check", ["plan", "--check", j("plan.json")], good=True)
    b("ctl diagnose", ["diagnose", "--data", good, "--heldout", goodheld, "--out", j("o-diag")], good=True, timeout=120)

    # ---- units and plausibility
    for what, path, exp in [("marker metres", metres, ["metres"]), ("q radians", radians, ["radians"]),
                            ("q 1e308", q1e308, ["q", "limit"]), ("q 400 deg", q400, ["limit"]),
                            ("marker 1e308", p1e308, ["marker"]), ("marker 1e200", p1e200, ["marker"]),
                            ("t 1e308", t1e308, ["t"]), ("marker rms -1", negrms, ["rms"]),
                            ("temp_c 1e300", hugetemp, ["temp"])]:
        b(f"calibrate nominal: {what}", ["calibrate", "nominal", "--data", path, "--out", j("x")], exp)
        b(f"calibrate kinematics: {what}", ["calibrate", "kinematics", "--data", path, "--out", j("x")], exp)
        b(f"diagnose: {what}", ["diagnose", "--data", path, "--out", j("x")], exp)
        b(f"predict: {what}", ["predict", "--calibration", cal, "--data", path], exp)
        b(f"calibrate nominal --heldout: {what}", ["calibrate", "nominal", "--data", good, "--heldout", path, "--out", j("x")], exp)
    for what, path, exp in [("range -50", lneg, ["range"]), ("range metres", lmetres, ["metres"]),
                            ("flange metres", lflm, ["metres"]), ("range 1e308", l1e308, ["range"])]:
        b(f"calibrate laser: {what}", ["calibrate", "laser", "--data", path, "--out", j("x")], exp)
        b(f"calibrate laser --heldout: {what}", ["calibrate", "laser", "--data", lgood, "--heldout", path, "--out", j("x")], exp)
        b(f"diagnose laser: {what}", ["diagnose", "--data", path, "--out", j("x")], exp)
        b(f"predict laser: {what}", ["predict", "--calibration", j("o-las", "calibration.json"), "--data", path], exp)
    b("calibrate pivot: metres", ["calibrate", "pivot", "--data", pmetres], ["metres"])
    b("calibrate pivot: marker 1e308", ["calibrate", "pivot", "--data", p308], ["marker"])

    # ---- under-determined fits
    b("calibrate kinematics: 6 poses", ["calibrate", "kinematics", "--data", six, "--out", j("x")], ["more poses"])
    b("calibrate kinematics: 12 poses", ["calibrate", "kinematics", "--data", twelve, "--out", j("x")], ["more poses"])
    b("calibrate nominal: 3 poses", ["calibrate", "nominal", "--data", three, "--out", j("x")], ["more poses"])
    b("diagnose: 6 poses", ["diagnose", "--data", six, "--out", j("x")], ["poses"])
    b("calibrate pivot: 3 frames", ["calibrate", "pivot", "--data", pfew], ["frames"])
    b("calibrate kinematics --bootstrap: 12 poses", ["calibrate", "kinematics", "--data", twelve, "--out", j("x"), "--bootstrap", "5"], ["more poses"])

    # ---- calibration files with huge values / for another robot
    calj = json.load(open(cal)) if os.path.exists(cal) else None
    if calj:
        c308 = json.loads(json.dumps(calj))
        for p in c308["params"]:
            if p["name"] == "a3":
                p["value"] = 1e308
        json.dump(c308, open(j("cal308.json"), "w"))
        cur = json.loads(json.dumps(calj))
        cur["robot"] = {"model": "ur5e"}
        cur["params"] = [p for p in cur["params"] if p.get("name", "").startswith(("base", "tool"))]
        json.dump(cur, open(j("calur.json"), "w"))
        cnan = json.loads(json.dumps(calj))
        cnan["params"][0]["std"] = -1
        json.dump(cnan, open(j("calneg.json"), "w"))
        b("diagnose --calibration a3=1e308", ["diagnose", "--data", good, "--calibration", j("cal308.json"), "--out", j("x")], ["a3"])
        b("predict: calibration a3=1e308", ["predict", "--calibration", j("cal308.json"), "--data", good], ["a3"])
        b("predict: calibration for ur5e", ["predict", "--calibration", j("calur.json"), "--data", good], ["ur5e"])
        b("diagnose --calibration for ur5e", ["diagnose", "--data", good, "--calibration", j("calur.json"), "--out", j("x")], ["ur5e"])
        b("predict: calibration std -1", ["predict", "--calibration", j("calneg.json"), "--data", good], ["std"])

    # ---- mismatched / empty held-out files
    for cmd in (["calibrate", "nominal"], ["calibrate", "kinematics"], ["diagnose"]):
        n = " ".join(cmd)
        b(f"{n}: --heldout for ur5e", cmd + ["--data", good, "--heldout", urheld, "--out", j("x")], ["ur5e"])
        b(f"{n}: --heldout no usable poses", cmd + ["--data", good, "--heldout", emptyheld, "--out", j("x")], ["usable"])
        b(f"{n}: --heldout events only", cmd + ["--data", good, "--heldout", eventsonly, "--out", j("x")], ["usable", "pose"])
    b("calibrate laser: --heldout for ur5e", ["calibrate", "laser", "--data", lgood, "--heldout", urheld, "--out", j("x")], ["ur5e", "range", "flange"])

    # ---- plan: huge counts, non-finite timing, edited plan files
    spec = open(ANNULUS).read()

    def spec_variant(name, old, new):
        p = j(name + ".toml")
        assert old in spec, old
        open(p, "w").write(spec.replace(old, new))
        return p

    b("plan: points = 100000000", ["plan", "--spec", spec_variant("huge", "points = 200", "points = 100000000"), "--robot", "denso-vs060", "--out", j("x.json")], ["points"])
    b("plan: settle_s = nan", ["plan", "--spec", spec_variant("snan", "settle_s = 1.5", "settle_s = nan"), "--robot", "denso-vs060", "--out", j("x.json")], ["settle"])
    b("plan: sample_s = inf", ["plan", "--spec", spec_variant("sinf", "sample_s = 2.0", "sample_s = inf"), "--robot", "denso-vs060", "--out", j("x.json")], ["sample"])
    b("plan: speed_deg_s = [inf]", ["plan", "--spec", spec_variant("vinf", "speed_deg_s = [60.0]", "speed_deg_s = [inf]"), "--robot", "denso-vs060", "--out", j("x.json")], ["speed"])
    b("plan: radius 1e308", ["plan", "--spec", spec_variant("r308", "radius_mm = [250.0, 550.0]", "radius_mm = [250.0, 1e308]"), "--robot", "denso-vs060", "--out", j("x.json")], ["radius"])
    b("plan: --select 0", ["plan", "--spec", ANNULUS, "--robot", "denso-vs060", "--select", "0", "--out", j("x.json")], ["select"])
    b("plan: --pac-speed nan", ["plan", "--spec", ANNULUS, "--robot", "denso-vs060", "--pacscript", j("x.pcs"), "--pac-speed", "NaN"], ["speed"])
    planj = json.load(open(j("plan.json"))) if os.path.exists(j("plan.json")) else None
    if planj:
        def plan_variant(name, f):
            pj = json.loads(json.dumps(planj))
            f(pj)
            json.dump(pj, open(j(name + ".json"), "w"))
            return j(name + ".json")
        table = plan_variant("ptable", lambda pj: pj["spec"]["constraints"].update(table_z_mm=450.0))
        env = plan_variant("penv", lambda pj: pj["spec"]["constraints"]["envelope"].update(radius=300.0))
        nolim = plan_variant("plimits", lambda pj: pj.update(robot=dict(hdr["robot"], chain=[
            dict(jt, limits=[-1000, 1000]) for jt in hdr["robot"]["chain"]])))
        urplan = plan_variant("pur", lambda pj: pj["robot"].update(model="ur5e"))
        b("plan --check: poses below the edited table", ["plan", "--check", table], ["table"])
        b("plan --check: poses outside the edited envelope", ["plan", "--check", env], ["envelope"])
        b("run: plan whose table the poses violate", ["run", "--plan", table, "--sim", LAB, "--out", j("r-table"), "--virtual-clock", "--in-process", "--max-poses", "2"], ["table"], timeout=60)
        b("run: plan for ur5e on the vs060 cell", ["run", "--plan", urplan, "--sim", LAB, "--out", j("r-ur"), "--virtual-clock", "--in-process", "--max-poses", "2"], ["ur5e", "robot", "forward kinematics"], timeout=60)
        # Safety limits come from the cell (issue 26 §2): a plan may be stricter, never wider.
        low = plan_variant("plow", lambda pj: pj["spec"]["constraints"].update(table_z_mm=-1000.0))
        noenv = plan_variant("pnoenv", lambda pj: pj["spec"]["constraints"].pop("envelope", None))
        wide = plan_variant("pwide", lambda pj: pj["spec"]["constraints"]["envelope"].update(radius=5000.0, z_min=-2000.0))
        notable = plan_variant("pnotable", lambda pj: pj["spec"]["constraints"].pop("table_z_mm", None))
        noclear = plan_variant("pnoclear", lambda pj: pj["spec"]["constraints"].update(table_clearance_mm=0.0))
        nospec = plan_variant("pnospec", lambda pj: pj.update(spec={}))
        for what, pth, exp in [("table lowered to -1000 mm", low, ["table"]), ("envelope removed", noenv, ["envelope"]),
                               ("envelope widened", wide, ["envelope"]), ("table removed", notable, ["table"]),
                               ("table clearance 0", noclear, ["table"]), ("spec emptied", nospec, ["table", "envelope"])]:
            b(f"run: plan wider than the cell: {what}", ["run", "--plan", pth, "--sim", LAB, "--out", j("r-wide" + what[:5].replace(" ", "")), "--virtual-clock", "--in-process", "--max-poses", "2"], exp, timeout=60)
        b("plan --check: widened joint limits", ["plan", "--check", nolim], ["limit"])
        if True:
            b("run: plan with widened joint limits", ["run", "--plan", nolim, "--sim", LAB, "--out", j("r-lim"), "--virtual-clock", "--in-process", "--max-poses", "2"], ["limit"], timeout=60)

        # ---- safety parameters of `run`
        for flag, val, exp in [("--speed-deg-s", "0", ["speed"]), ("--speed-deg-s", "-5", ["speed"]),
                               ("--speed-deg-s", "NaN", ["speed"]), ("--speed-deg-s", "inf", ["speed"]),
                               ("--speed-deg-s", "1000", ["speed", "limit"]), ("--accel-deg-s2", "0", ["accel"]),
                               ("--accel-deg-s2", "NaN", ["accel"]), ("--accel-deg-s2", "1e9", ["accel", "limit"]),
                               ("--frames", "0", ["frames"])]:
            for proc in (["--in-process"], []):
                tag = "in-process" if proc else "wire"
                b(f"run ({tag}): {flag} {val}", ["run", "--plan", j("plan.json"), "--sim", LAB, "--out", j(f"r{flag}{val}{tag}"), "--virtual-clock", "--max-poses", "2", f"{flag}={val}"] + proc, exp, timeout=60)
        b("ctl run", ["run", "--plan", j("plan.json"), "--sim", LAB, "--out", j("r-good"), "--virtual-clock", "--in-process", "--max-poses", "2"], good=True, timeout=60)

    # ---- scenarios
    lab = open(LAB).read()

    def scen_variant(name, old, new):
        p = j(name + ".toml")
        if old not in lab:
            return None
        open(p, "w").write(lab.replace(old, new, 1))
        return p

    for name, old, new, exp in [
        ("settle_s = nan", "settle_s = 0.3", "settle_s = nan", ["settle"]),
        ("settle_s = 1e300", "settle_s = 0.3", "settle_s = 1e300", ["settle"]),
        ("max_vel = 0", "max_vel_deg_s = 180.0", "max_vel_deg_s = 0.0", ["max_vel"]),
        ("max_acc = inf", "max_acc_deg_s2 = 360.0", "max_acc_deg_s2 = inf", ["max_acc"]),
        ("rate_hz = 0", "rate_hz = 100.0", "rate_hz = 0.0", ["rate_hz"]),
        ("rate_hz = nan", "rate_hz = 100.0", "rate_hz = nan", ["rate_hz"]),
        ("fit_rms = -1", "fit_rms_mm = 0.04", "fit_rms_mm = -1.0", ["fit_rms"]),
    ]:
        tag = "".join(c for c in name if c.isalnum())
        p = scen_variant("sc-" + tag, old, new)
        if p is None:
            continue
        if planj:
            b(f"run --sim scenario {name}", ["run", "--plan", j("plan.json"), "--sim", p, "--out", j("r-" + tag), "--virtual-clock", "--in-process", "--max-poses", "2"], exp, timeout=30)
        b(f"sim serve scenario {name}", ["sim", "serve", "--scenario", p, "--virtual-clock"], exp, timeout=5, server=True)

    # ---- devices
    dev = j("dev.toml")
    open(dev, "w").write('[[device]]\nname = "arm"\nrole = "arm"\nvendor = "denso"\nprotocol = "bcap"\naddress = "127.0.0.1:9"\n')
    for v in ("NaN", "-1", "inf", "0"):
        b(f"devices --probe --timeout-s {v}", ["devices", "--devices", dev, "--probe", f"--timeout-s={v}"], ["timeout"])
    garbage = j("garbage.bin")
    open(garbage, "wb").write(bytes(range(256)) * 4)
    for cmd in (["inspect", garbage], ["devices", "--devices", garbage], ["sim", "serve", "--scenario", garbage],
                ["plan", "--check", garbage], ["predict", "--calibration", garbage, "--data", good],
                ["report", "--dir", d + "/nonexistent"], ["calibrate", "pivot", "--data", garbage]):
        b("garbage: " + " ".join(c if c != garbage else "GARBAGE" for c in cmd[:2]), cmd, [], timeout=10)

    issue26(P, d, j, small, hdr, good, goodheld, cal, pgood, lgood)
    issue26_round3(P, j, small, good, cal, lgood, lheldp)
    issue26_round5(P, j, good, cal, lgood)
    issue26_round6(P, d, j, good, cal)
    issue26_round7(P, j, good, cal)

    # ---- summary
    cats = {}
    for name, outcome, _ in P.results:
        cats[outcome] = cats.get(outcome, 0) + 1
    bad = [r for r in P.results if r[1] in ("panic", "hang", "accept", "broken", "vague")]
    print(f"\n{len(P.results)} cases: " + ", ".join(f"{k} {v}" for k, v in sorted(cats.items())))
    for name, outcome, msg in bad:
        print(f"  {outcome:7} {name}: {msg}")
    print(f"(files in {d})")
    return 1 if any(r[1] in ("panic", "hang", "accept", "broken") for r in P.results) else 0


if __name__ == "__main__":
    sys.exit(main())
