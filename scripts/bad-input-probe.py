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


class Probe:
    def __init__(self, exe, timeout, verbose):
        self.exe = exe
        self.timeout = timeout
        self.verbose = verbose
        self.results = []

    def run(self, name, args, expect=(), good=False, timeout=None, server=False):
        t = timeout or self.timeout
        try:
            p = subprocess.run([self.exe] + args, capture_output=True, text=True, timeout=t,
                               stdin=subprocess.DEVNULL)
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
