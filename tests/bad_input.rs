//! Bad input (issue 14 §5): a silent wrong answer is worse than an error. One test per class
//! of mistaken input; each runs the real binary under a deadline and asserts a clear error
//! (exit 1, the message names the file / field and the likely cause), no panic, no hang.
//! The wider probe (`scripts/bad-input-probe.py`) counts every class across every subcommand.
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use robocal::schema::same_json;
use serde_json::{json, Value};

/// Deadline of one invocation: every refusal here happens before any fit or motion.
const DEADLINE: Duration = Duration::from_secs(60);

struct Out {
    code: Option<i32>,
    text: String,
}

/// Runs the binary with a deadline; a run past it is killed and reported as a hang.
fn run(args: &[&str]) -> Out {
    run_in(None, &[], args)
}

/// [`run`] in directory `cwd` (else the test's) with extra environment variables.
fn run_in(cwd: Option<&Path>, env: &[(&str, &str)], args: &[&str]) -> Out {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_robocal"));
    if let Some(d) = cwd {
        cmd.current_dir(d);
    }
    let mut child = cmd
        .args(args)
        .envs(env.iter().copied())
        .env("ROBOCAL_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start robocal");
    let t0 = Instant::now();
    loop {
        if child.try_wait().expect("wait").is_some() {
            break;
        }
        if t0.elapsed() > DEADLINE {
            let _ = child.kill();
            let _ = child.wait();
            panic!("HANG: robocal {args:?} still running after {DEADLINE:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let o = child.wait_with_output().expect("output");
    Out {
        code: o.status.code(),
        text: format!(
            "{}{}",
            String::from_utf8_lossy(&o.stderr),
            String::from_utf8_lossy(&o.stdout)
        ),
    }
}

/// Asserts a clear refusal: exit 1, no panic, and every `needle` in the message.
#[track_caller]
fn refused(args: &[&str], needles: &[&str]) -> String {
    refused_out(run(args), args, needles)
}

#[track_caller]
fn refused_out(o: Out, args: &[&str], needles: &[&str]) -> String {
    assert!(
        !o.text.contains("panicked at"),
        "PANIC: robocal {args:?}\n{}",
        o.text
    );
    assert_eq!(
        o.code,
        Some(1),
        "robocal {args:?} should be refused (exit 1)\n{}",
        o.text
    );
    let low = o.text.to_lowercase();
    for n in needles {
        assert!(
            low.contains(&n.to_lowercase()),
            "robocal {args:?}: the message should name {n:?}\n{}",
            o.text
        );
    }
    println!(
        "refused {:?}: {}",
        &args[..args.len().min(2)],
        first_error(&o.text)
    );
    o.text
}

fn first_error(text: &str) -> &str {
    text.lines()
        .find(|l| l.starts_with("error"))
        .unwrap_or_else(|| text.lines().next().unwrap_or(""))
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn lines(rel: &str) -> Vec<Value> {
    std::fs::read_to_string(root().join(rel))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

fn write(dir: &Path, name: &str, rows: &[Value]) -> PathBuf {
    let mut s = String::new();
    for r in rows {
        s.push_str(&r.to_string());
        s.push('\n');
    }
    let p = dir.join(name);
    std::fs::write(&p, s).unwrap();
    p
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The first `n` poses of the geometric test dataset (header + records).
fn geo(n: usize) -> Vec<Value> {
    lines("tests/data/kin-geometric/train.jsonl")
        .into_iter()
        .take(n + 1)
        .collect()
}

fn geo_held(n: usize) -> Vec<Value> {
    lines("tests/data/kin-geometric/heldout.jsonl")
        .into_iter()
        .take(n + 1)
        .collect()
}

/// Pivot records of a marker rotating about a fixed tip (tip 150 mm from the marker).
fn pivot_rows(scale: f64, n: usize) -> Vec<Value> {
    use nalgebra::{UnitQuaternion, Vector3};
    let mut rows = vec![json!({"format": "robocal-dataset/1", "robot": {"model": "denso-vs060"}})];
    let pivot = Vector3::new(100.0, -50.0, -1500.0);
    for i in 0..n {
        let a = i as f64 * 0.7;
        let r = UnitQuaternion::from_euler_angles(0.3 * a.sin(), 0.3 * a.cos(), 0.5 * a);
        let p = (pivot - r * Vector3::new(0.0, 0.0, -150.0)) * scale;
        let q = r.quaternion();
        rows.push(
            json!({"kind": "pivot", "t": i as f64 * 0.1, "tool": "probe",
            "marker": {"p": [p.x, p.y, p.z], "quat": [q.w, q.i, q.j, q.k], "rms": 0.05}}),
        );
    }
    rows
}

/// A small annulus spec (20 points) so plans build in a second.
fn small_plan(dir: &Path) -> PathBuf {
    let spec = std::fs::read_to_string(root().join("plans/seed001-annulus.toml"))
        .unwrap()
        .replace("points = 200", "points = 20");
    let sp = dir.join("small.toml");
    std::fs::write(&sp, spec).unwrap();
    let plan = dir.join("plan.json");
    let o = run(&[
        "plan",
        "--spec",
        s(&sp),
        "--robot",
        "denso-vs060",
        "--out",
        s(&plan),
    ]);
    assert_eq!(o.code, Some(0), "{}", o.text);
    plan
}

fn lab() -> PathBuf {
    root().join("mocks/scenarios/lab-vs060-optotrak-il600.toml")
}

#[test]
fn bad_input_controls_still_work() {
    // The checks must not refuse good data: the same files, unmodified.
    let d = tempfile::tempdir().unwrap();
    let good = write(d.path(), "good.jsonl", &geo(40));
    let held = write(d.path(), "held.jsonl", &geo_held(20));
    let out = d.path().join("nom");
    let o = run(&[
        "calibrate",
        "nominal",
        "--data",
        s(&good),
        "--heldout",
        s(&held),
        "--out",
        s(&out),
    ]);
    assert_eq!(o.code, Some(0), "{}", o.text);
    let o = run(&[
        "predict",
        "--calibration",
        s(&out.join("calibration.json")),
        "--data",
        s(&held),
    ]);
    assert_eq!(o.code, Some(0), "{}", o.text);
    let piv = write(d.path(), "pivot.jsonl", &pivot_rows(1.0, 40));
    let o = run(&["calibrate", "pivot", "--data", s(&piv)]);
    assert_eq!(o.code, Some(0), "{}", o.text);
    let plan = small_plan(d.path());
    let o = run(&["plan", "--check", s(&plan)]);
    assert_eq!(o.code, Some(0), "{}", o.text);
    assert!(o.text.contains("re-checked"), "{}", o.text);
}

#[test]
fn bad_input_units_and_plausibility() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    // Marker positions in metres: used to shrink the robot 1000× with exit 0.
    let mut rows = geo(40);
    for r in rows.iter_mut().skip(1) {
        let p: Vec<f64> = r["marker"]["p"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap() / 1000.0)
            .collect();
        r["marker"]["p"] = json!(p);
    }
    let f = write(dp, "metres.jsonl", &rows);
    let out = dp.join("o");
    for cal in ["kinematics", "nominal"] {
        refused(
            &["calibrate", cal, "--data", s(&f), "--out", s(&out)],
            &["metres.jsonl:2", "marker.p", "look like metres"],
        );
    }
    refused(
        &["diagnose", "--data", s(&f), "--out", s(&out)],
        &["look like metres"],
    );
    // Joint angles in radians.
    let mut rows = geo(40);
    for r in rows.iter_mut().skip(1) {
        for k in ["q", "q_cmd"] {
            let q: Vec<f64> = r[k]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap().to_radians())
                .collect();
            r[k] = json!(q);
        }
    }
    let f = write(dp, "radians.jsonl", &rows);
    refused(
        &["calibrate", "kinematics", "--data", s(&f), "--out", s(&out)],
        &["radians.jsonl:2", "field \"q\"", "look like radians"],
    );
    // One q of 400° (joint 1 limits ±170°) and one of 1e308, on line 7.
    for (v, name) in [(400.0, "q400"), (1e308, "q1e308")] {
        let mut rows = geo(40);
        rows[5]["q"][0] = json!(v);
        let f = write(dp, &format!("{name}.jsonl"), &rows);
        refused(
            &["calibrate", "nominal", "--data", s(&f), "--out", s(&out)],
            &[&format!("{name}.jsonl:6"), "q[0]", "outside its limits"],
        );
    }
    // Laser range −50 mm, and ranges in metres.
    let mut rows = lines("tests/data/laser-planes/train.jsonl");
    rows[3]["range"] = json!(-50.0);
    let f = write(dp, "lneg.jsonl", &rows);
    refused(
        &["calibrate", "laser", "--data", s(&f), "--out", s(&out)],
        &["lneg.jsonl:4", "range", "a distance from 0"],
    );
    let mut rows = lines("tests/data/laser-planes/train.jsonl");
    for r in rows.iter_mut().skip(1) {
        if let Some(x) = r["range"].as_f64() {
            r["range"] = json!(x / 1000.0);
        }
    }
    let f = write(dp, "lmetres.jsonl", &rows);
    refused(
        &["calibrate", "laser", "--data", s(&f), "--out", s(&out)],
        &["range", "look like metres"],
    );
    // A pivot file in metres.
    let f = write(dp, "pmetres.jsonl", &pivot_rows(0.001, 40));
    refused(
        &["calibrate", "pivot", "--data", s(&f)],
        &["pmetres.jsonl:2", "marker.p", "look like metres"],
    );
}

#[test]
fn bad_input_under_determined_fits() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("o");
    // 6 poses for the full kinematic model: refused with the number of poses still needed.
    let f = write(d.path(), "six.jsonl", &geo(6));
    let msg = refused(
        &["calibrate", "kinematics", "--data", s(&f), "--out", s(&out)],
        &["under-determined", "6 usable training poses", "more poses"],
    );
    assert!(!out.join("calibration.json").exists(), "{msg}");
    let f = write(d.path(), "three.jsonl", &geo(3));
    refused(
        &["calibrate", "nominal", "--data", s(&f), "--out", s(&out)],
        &["3 usable training poses", "measure 3 more poses"],
    );
    let f = write(d.path(), "p3.jsonl", &pivot_rows(1.0, 3));
    refused(
        &["calibrate", "pivot", "--data", s(&f)],
        &["under-determined", "record 1 more"],
    );
}

#[test]
fn bad_input_huge_and_non_finite_values_do_not_hang() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let out = dp.join("o");
    // One marker coordinate of 1e308 (used to hang `diagnose` and `calibrate pivot`).
    let mut rows = geo(40);
    rows[5]["marker"]["p"][2] = json!(1e308);
    let f = write(dp, "p308.jsonl", &rows);
    refused(
        &["diagnose", "--data", s(&f), "--out", s(&out)],
        &[
            "p308.jsonl:6",
            "marker.p[2]",
            "not a plausible tracker coordinate",
        ],
    );
    let mut rows = pivot_rows(1.0, 40);
    rows[3]["marker"]["p"][0] = json!(1e308);
    let f = write(dp, "piv308.jsonl", &rows);
    refused(
        &["calibrate", "pivot", "--data", s(&f)],
        &["piv308.jsonl:4", "marker.p[0]"],
    );
    // A calibration with a3 = 1e308 given to diagnose and predict.
    let good = write(dp, "good.jsonl", &geo(40));
    let header = &geo(0)[0];
    let cal = json!({"format": "robocal-calibration/1", "robot": header["robot"],
        "params": [{"name": "a3", "value": 1e308, "unit": "mm", "free": true}]});
    let cp = dp.join("cal308.json");
    std::fs::write(&cp, cal.to_string()).unwrap();
    refused(
        &[
            "diagnose",
            "--data",
            s(&good),
            "--calibration",
            s(&cp),
            "--out",
            s(&out),
        ],
        &["cal308.json", "params[0].value", "a3"],
    );
    refused(
        &["predict", "--calibration", s(&cp), "--data", s(&good)],
        &["a3", "not a plausible calibration value"],
    );
    // A scenario with settle_s = nan.
    let plan = small_plan(dp);
    let sc = std::fs::read_to_string(lab())
        .unwrap()
        .replace("settle_s = 0.3", "settle_s = nan");
    let scp = dp.join("nan.toml");
    std::fs::write(&scp, sc).unwrap();
    refused(
        &[
            "run",
            "--plan",
            s(&plan),
            "--sim",
            s(&scp),
            "--out",
            s(&dp.join("run")),
            "--virtual-clock",
            "--in-process",
        ],
        &["settle_s", "not a finite number"],
    );
    refused(
        &["sim", "serve", "--scenario", s(&scp), "--virtual-clock"],
        &["settle_s"],
    );
    // A plan of 100 000 000 points (used to grow to 7 GB).
    let spec = std::fs::read_to_string(root().join("plans/seed001-annulus.toml"))
        .unwrap()
        .replace("points = 200", "points = 100000000");
    let sp = dp.join("huge.toml");
    std::fs::write(&sp, spec).unwrap();
    refused(
        &[
            "plan",
            "--spec",
            s(&sp),
            "--robot",
            "denso-vs060",
            "--out",
            s(&dp.join("x.json")),
        ],
        &["100000000 targets", "more than 100000"],
    );
}

#[test]
fn bad_input_safety_parameters() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let plan = small_plan(dp);
    let lab = lab();
    let base = |out: &Path| -> Vec<String> {
        [
            "run",
            "--plan",
            s(&plan),
            "--sim",
            s(&lab),
            "--out",
            s(out),
            "--virtual-clock",
            "--in-process",
        ]
        .iter()
        .map(|x| x.to_string())
        .collect()
    };
    for (i, (flag, val, needle)) in [
        ("--speed-deg-s", "0", "finite number > 0"),
        ("--speed-deg-s=-5", "", "finite number > 0"),
        ("--speed-deg-s", "NaN", "finite number > 0"),
        ("--speed-deg-s", "1000", "above the cell's limit of 180"),
        ("--accel-deg-s2", "0", "finite number > 0"),
    ]
    .into_iter()
    .enumerate()
    {
        let out = dp.join(format!("run{i}"));
        let mut a = base(&out);
        a.push(flag.into());
        if !val.is_empty() {
            a.push(val.into());
        }
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        refused(&a, &[flag.split('=').next().unwrap(), needle]);
        assert!(!out.exists(), "nothing may be created for a refused run");
    }
    // A live cell's limit comes from its device file: refused before any device is opened.
    let dev = dp.join("cell.toml");
    std::fs::write(
        &dev,
        "[[device]]\nname = \"vs060\"\nrole = \"arm\"\nvendor = \"denso\"\nprotocol = \"bcap\"\n\
         model = \"denso-vs060\"\naddress = \"127.0.0.1:9\"\nmax_speed_deg_s = 90.0\n",
    )
    .unwrap();
    let out = dp.join("live");
    refused(
        &[
            "run",
            "--plan",
            s(&plan),
            "--devices",
            s(&dev),
            "--live",
            "--yes",
            "--out",
            s(&out),
            "--speed-deg-s",
            "120",
        ],
        &["above the cell's limit of 90", "max_speed_deg_s"],
    );
    assert!(!out.exists());
    // A plan whose table was edited after planning: `plan --check` and `run` re-check it.
    let mut pj: Value = serde_json::from_str(&std::fs::read_to_string(&plan).unwrap()).unwrap();
    pj["spec"]["constraints"]["table_z_mm"] = json!(450.0);
    let edited = dp.join("edited.json");
    std::fs::write(&edited, pj.to_string()).unwrap();
    refused(&["plan", "--check", s(&edited)], &["table", "re-plan"]);
    let out = dp.join("run-edited");
    let mut a = base(&out);
    a[2] = s(&edited).to_string();
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    refused(&a, &["table"]);
    // Widened joint limits in the plan's robot block.
    let mut pj: Value = serde_json::from_str(&std::fs::read_to_string(&plan).unwrap()).unwrap();
    let header = &geo(0)[0];
    let mut robot = header["robot"].clone();
    for j in robot["chain"].as_array_mut().unwrap() {
        j["limits"] = json!([-1000.0, 1000.0]);
    }
    pj["robot"] = robot;
    let widened = dp.join("widened.json");
    std::fs::write(&widened, pj.to_string()).unwrap();
    refused(
        &["plan", "--check", s(&widened)],
        &["wider than the denso-vs060 preset"],
    );
}

#[test]
fn bad_input_devices_probe_timeout_nan_is_an_error_not_a_panic() {
    let d = tempfile::tempdir().unwrap();
    let dev = d.path().join("dev.toml");
    std::fs::write(
        &dev,
        "[[device]]\nname = \"arm\"\nrole = \"arm\"\nvendor = \"denso\"\nprotocol = \"bcap\"\naddress = \"127.0.0.1:9\"\n",
    )
    .unwrap();
    for v in ["NaN", "-1", "inf", "0"] {
        let t = format!("--timeout-s={v}");
        refused(
            &["devices", "--devices", s(&dev), "--probe", &t],
            &["--timeout-s", "finite number of seconds"],
        );
    }
}

#[test]
fn bad_input_mismatched_files() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let out = dp.join("o");
    let good = write(dp, "good.jsonl", &geo(40));
    // A held-out file for another robot model.
    let mut held = geo_held(20);
    held[0]["robot"] = json!({"model": "ur5e"});
    let ur = write(dp, "ur.jsonl", &held);
    for cmd in [
        &["calibrate", "nominal"][..],
        &["calibrate", "kinematics"],
        &["diagnose"],
    ] {
        let mut a: Vec<&str> = cmd.to_vec();
        a.extend(["--data", s(&good), "--heldout", s(&ur), "--out", s(&out)]);
        refused(&a, &["ur.jsonl", "robot.model", "\"ur5e\"", "denso-vs060"]);
    }
    // A calibration for another robot model.
    let cal = json!({"format": "robocal-calibration/1", "robot": {"model": "ur5e"},
        "params": [{"name": "tool_z", "value": 150.0, "unit": "mm", "free": true}]});
    let cp = dp.join("ur-cal.json");
    std::fs::write(&cp, cal.to_string()).unwrap();
    refused(
        &["predict", "--calibration", s(&cp), "--data", s(&good)],
        &["ur-cal.json", "\"ur5e\"", "denso-vs060"],
    );
    // A --heldout file with no usable poses: an error, not silent cross-validation.
    let mut held = geo_held(20);
    for r in held.iter_mut().skip(1) {
        r["marker"] = json!({"visible": false});
    }
    let empty = write(dp, "empty.jsonl", &held);
    for cmd in [
        &["calibrate", "nominal"][..],
        &["calibrate", "kinematics"],
        &["diagnose"],
    ] {
        let mut a: Vec<&str> = cmd.to_vec();
        a.extend(["--data", s(&good), "--heldout", s(&empty), "--out", s(&out)]);
        refused(&a, &["no usable held-out poses"]);
    }
}

/// Deterministic mutation of a seed: byte flips, insertions, deletions, truncation and
/// numbers replaced with extreme values (what a corrupted or mistyped file holds).
fn mutate(seed: &[u8], rng: &mut u64) -> Vec<u8> {
    let mut next = || {
        *rng = rng
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (*rng >> 33) as usize
    };
    let mut v = seed.to_vec();
    let extremes: [&[u8]; 8] = [
        b"1e308",
        b"-1e308",
        b"nan",
        b"inf",
        b"-0",
        b"1e-320",
        b"18446744073709551616",
        b"null",
    ];
    for _ in 0..1 + next() % 4 {
        if v.is_empty() {
            v.push(b'{');
        }
        let at = next() % v.len();
        match next() % 6 {
            0 => v[at] = (next() % 256) as u8,
            1 => v.insert(at, b"{}[],:\"0-.e\n"[next() % 12]),
            2 => {
                v.remove(at);
            }
            3 => v.truncate(at),
            _ => {
                // Replace the number starting at/after `at` with an extreme value.
                if let Some(s) = v[at..].iter().position(|b| b.is_ascii_digit()) {
                    let s = at + s;
                    let e = v[s..]
                        .iter()
                        .position(|b| !(b.is_ascii_digit() || *b == b'.'))
                        .map_or(v.len(), |e| s + e);
                    let x = extremes[next() % extremes.len()];
                    v.splice(s..e, x.iter().copied()).for_each(drop);
                }
            }
        }
    }
    v
}

#[test]
fn bad_input_file_readers_survive_mutated_files() {
    // A fast in-suite complement of the cargo-fuzz targets (fuzz/fuzz_targets/): every
    // reader, fed mutated copies of the project's own files, returns Ok or a clear Err: no
    // panic, no hang; what it accepts it writes back in a form it reads back the same.
    use robocal::dataset::{parse_dataset, CalibrationFile};
    let dir = tempfile::tempdir().unwrap();
    let t0 = Instant::now();
    let n = 400;
    let mut rng = 7u64;
    let mut counts = std::collections::BTreeMap::new();
    let mut note = |k: &str, ok: bool| {
        let e = counts.entry(k.to_string()).or_insert((0usize, 0usize));
        if ok {
            e.0 += 1
        } else {
            e.1 += 1
        }
    };
    let dataset: Vec<u8> =
        std::fs::read_to_string(root().join("tests/data/kin-geometric/heldout.jsonl"))
            .unwrap()
            .lines()
            .take(12)
            .flat_map(|l| format!("{l}\n").into_bytes())
            .collect();
    let fp = Path::new("m.jsonl");
    for _ in 0..n {
        let m = mutate(&dataset, &mut rng);
        let r = parse_dataset(&m, fp);
        if let Ok(l) = &r {
            let _ = robocal::plausible::check_dataset(&l.dataset, fp);
            let again = parse_dataset(l.dataset.to_jsonl().as_bytes(), fp).expect("re-read");
            assert_eq!(again.dataset.records.len(), l.dataset.records.len());
            // Bit-exact: serde_json is built with `float_roundtrip`.
            for (a, b) in again.dataset.records.iter().zip(&l.dataset.records) {
                let (va, vb) = (
                    serde_json::to_value(a).unwrap(),
                    serde_json::to_value(b).unwrap(),
                );
                assert!(same_json(&va, &vb), "re-read record differs:\n{va}\n{vb}");
            }
        }
        note("dataset", r.is_ok());
    }
    let header = &geo(0)[0];
    let cal = json!({"format": "robocal-calibration/1", "robot": header["robot"],
        "params": [{"name": "a3", "value": 305.1, "std": 0.01, "unit": "mm", "free": true},
                   {"name": "base_x", "value": 1000.0, "unit": "mm", "free": true}],
        "effects": [{"kind": "joint_compliance", "joint": 2, "params": {"k_deg_per_nm": 1e-4}}],
        "metrics": {"train_rms_mm": 0.1}})
    .to_string()
    .into_bytes();
    for _ in 0..n {
        let m = mutate(&cal, &mut rng);
        let Ok(text) = std::str::from_utf8(&m) else {
            continue;
        };
        let r = CalibrationFile::parse(text, Path::new("m.json"));
        if let Ok(c) = &r {
            let _ = robocal::plausible::calibration::check_values(c, Path::new("m.json"));
            let again = CalibrationFile::parse(&c.to_json_pretty(), Path::new("m.json"))
                .expect("a calibration robocal accepted reads back");
            let (va, vb) = (
                serde_json::to_value(&again).unwrap(),
                serde_json::to_value(c).unwrap(),
            );
            assert!(
                same_json(&va, &vb),
                "re-read calibration differs:\n{va}\n{vb}"
            );
        }
        note("calibration", r.is_ok());
    }
    let plan = std::fs::read(small_plan(dir.path())).unwrap();
    for _ in 0..n / 4 {
        let m = mutate(&plan, &mut rng);
        let Ok(text) = std::str::from_utf8(&m) else {
            continue;
        };
        let r = robocal::plan::PlanFile::from_json_str(text);
        if let Ok(p) = &r {
            let _ = robocal::plan::recheck::recheck(p, None);
        }
        note("plan", r.is_ok());
    }
    let spec = std::fs::read(root().join("plans/seed001-annulus.toml")).unwrap();
    for _ in 0..n {
        let m = mutate(&spec, &mut rng);
        let Ok(text) = std::str::from_utf8(&m) else {
            continue;
        };
        let r = robocal::plan::PlanSpec::from_toml_str(text);
        if let Ok(s) = &r {
            assert!(s.target_count() <= robocal::plan::spec::MAX_TARGETS);
        }
        note("spec", r.is_ok());
    }
    let scen = std::fs::read(lab()).unwrap();
    for _ in 0..n {
        let m = mutate(&scen, &mut rng);
        let Ok(text) = std::str::from_utf8(&m) else {
            continue;
        };
        let r = robocal_mocks::scenario::Scenario::from_toml(text);
        if let Ok(s) = &r {
            for a in &s.arms {
                assert!(a.motion.settle_s.is_finite(), "{text}");
            }
        }
        note("scenario", r.is_ok());
    }
    let dev = std::fs::read(root().join("fuzz/seeds/devices/cell.toml")).unwrap();
    for _ in 0..n {
        let m = mutate(&dev, &mut rng);
        let Ok(text) = std::str::from_utf8(&m) else {
            continue;
        };
        let r = robocal::acquire::devices::DevicesFile::parse(text, "m.toml");
        note("devices", r.is_ok());
    }
    for (k, (ok, err)) in &counts {
        println!("mutated {k}: {ok} accepted, {err} refused");
    }
    println!("file readers: {:.1} s", t0.elapsed().as_secs_f64());
}

// ---- issue 26: trust at every boundary. One test per class; each fails on the binary
// before the fix (confident wrong answer, clobbered file, silent accept or hang).

fn strs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

fn mkfifo(p: &Path) {
    assert!(Command::new("mkfifo").arg(p).status().unwrap().success());
}

/// A calibration of the geometric test robot (nominal fit on 40 poses) and its held-out file.
fn nominal_cal(dir: &Path) -> (PathBuf, PathBuf) {
    let good = write(dir, "good.jsonl", &geo(40));
    let held = write(dir, "held.jsonl", &geo_held(20));
    let out = dir.join("nom");
    let o = run(&["calibrate", "nominal", "--data", s(&good), "--out", s(&out)]);
    assert_eq!(o.code, Some(0), "{}", o.text);
    (out.join("calibration.json"), held)
}

#[test]
fn bad_input_outputs_never_replace_what_is_not_a_regular_file() {
    use std::os::unix::fs::FileTypeExt as _;
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let (cal, held) = nominal_cal(dp);
    let predict = |out: &Path| {
        vec![
            "predict".to_string(),
            "--calibration".into(),
            s(&cal).into(),
            "--data".into(),
            s(&held).into(),
            "--out".into(),
            s(out).into(),
        ]
    };
    // A FIFO (as a device node would be) is refused and stays a FIFO.
    let fifo = dp.join("out.fifo");
    mkfifo(&fifo);
    refused(&strs(&predict(&fifo)), &["FIFO", "not a regular file"]);
    assert!(std::fs::symlink_metadata(&fifo)
        .unwrap()
        .file_type()
        .is_fifo());
    // A directory given as the output file.
    let dir_out = dp.join("a-dir");
    std::fs::create_dir(&dir_out).unwrap();
    refused(&strs(&predict(&dir_out)), &["directory"]);
    assert!(dir_out.is_dir());
    // A symbolic link: written through, the link stays a link.
    let real = dp.join("real.csv");
    std::fs::write(&real, "old").unwrap();
    let link = dp.join("link.csv");
    std::os::unix::fs::symlink(&real, &link).unwrap();
    // A temporary file a killed writer left (a PID above Linux's limit: not running).
    let stale = dp.join(".real.csv.tmp4194305");
    std::fs::write(&stale, "torn").unwrap();
    let o = run(&strs(&predict(&link)));
    assert_eq!(o.code, Some(0), "{}", o.text);
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());
    assert!(std::fs::read_to_string(&real).unwrap().len() > 100);
    assert!(!stale.exists(), "the stale temporary file was left");
    // `report --out X.html` never overwrites a report.md it did not write.
    let rep = dp.join("rep");
    std::fs::create_dir(&rep).unwrap();
    std::fs::copy(&cal, rep.join("calibration.json")).unwrap();
    let mine = rep.join("report.md");
    std::fs::write(&mine, "my notes").unwrap();
    let o = run(&[
        "report",
        "--dir",
        s(&rep),
        "--out",
        s(&rep.join("summary.html")),
    ]);
    assert_eq!(o.code, Some(0), "{}", o.text);
    assert_eq!(std::fs::read_to_string(&mine).unwrap(), "my notes");
    assert!(rep.join("summary.md").is_file());
}

#[test]
fn bad_input_non_regular_and_unbounded_inputs_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let fifo = dp.join("in.fifo");
    mkfifo(&fifo);
    refused(&["inspect", s(&fifo)], &["FIFO", "not a regular file"]);
    refused(&["inspect", "/dev/zero"], &["character device"]);
    refused(&["inspect", s(dp)], &["directory"]);
    refused(
        &["calibrate", "pivot", "--data", s(&fifo)],
        &["FIFO", "not a regular file"],
    );
    refused(&["plan", "--check", s(&fifo)], &["FIFO"]);
    // One 5 MiB line: refused by its length, not parsed.
    let mut rows = geo(3);
    rows[2]["note"] = json!("x".repeat(5 << 20));
    let long = write(dp, "long.jsonl", &rows);
    refused(&["inspect", s(&long)], &["long.jsonl:3", "longer than"]);
    // An unbounded count: refused before the first fit.
    let good = write(dp, "good.jsonl", &geo(40));
    refused(
        &[
            "calibrate",
            "kinematics",
            "--data",
            s(&good),
            "--out",
            s(&dp.join("k")),
            "--bootstrap",
            "100000000",
        ],
        &["--bootstrap 100000000", "at most 100000"],
    );
}

#[test]
fn bad_input_history_queries_never_create_or_alter_a_database() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let o = run_in(
        Some(dp),
        &[("ROBOCAL_DB", "mysql://user@host/db")],
        &["history", "--robot", "X"],
    );
    refused_out(o, &["history"], &["mysql://", "postgres://"]);
    assert!(
        std::fs::read_dir(dp).unwrap().next().is_none(),
        "history created something in its working directory"
    );
    // A mistyped path creates no database.
    let typo = dp.join("histroy.sqlite");
    refused(
        &["history", "--robot", "X", "--db", s(&typo)],
        &["no history database"],
    );
    assert!(!typo.exists());
    // A foreign SQLite file gets no table added.
    let foreign = dp.join("foreign.sqlite");
    let c = rusqlite::Connection::open(&foreign).unwrap();
    c.execute_batch("CREATE TABLE patients (id INTEGER);")
        .unwrap();
    drop(c);
    let before = std::fs::read(&foreign).unwrap();
    refused(
        &["history", "--robot", "X", "--db", s(&foreign)],
        &["not a robocal history", "patients"],
    );
    assert_eq!(std::fs::read(&foreign).unwrap(), before);
}

#[test]
fn bad_input_accept_spec_must_judge_the_sessions_kind() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let session = |out: &Path, accept: &Path| {
        run(&[
            "session",
            "--sim",
            s(&lab()),
            "--out",
            s(out),
            "--plan-only",
            "--no-history",
            "--accept",
            s(accept),
        ])
    };
    // A camera spec on a kinematic (tracker) cell: it would check nothing.
    let out = dp.join("s1");
    let o = session(&out, &root().join("accept/camera.toml"));
    refused_out(o, &["session"], &["judges camera sessions", "kinematic"]);
    assert!(!out.exists(), "a refused session created its directory");
    // A spec holding only a name.
    let only_name = dp.join("name.toml");
    std::fs::write(&only_name, "name = \"x\"\n").unwrap();
    let out = dp.join("s2");
    let o = session(&out, &only_name);
    refused_out(o, &["session"], &["name.toml", "session"]);
    // A kinematic spec without an accuracy criterion.
    let no_acc = dp.join("noacc.toml");
    std::fs::write(
        &no_acc,
        "name = \"x\"\nsession = \"kinematic\"\nskipped_fraction_max = 0.1\n",
    )
    .unwrap();
    let o = session(&out, &no_acc);
    refused_out(o, &["session"], &["no accuracy criterion"]);
    assert!(!out.exists());
}

#[test]
fn bad_input_session_options_are_checked_before_anything_is_created() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let garbage = dp.join("garbage.json");
    std::fs::write(&garbage, "not json").unwrap();
    let lab = lab();
    let targets = dp.join("t.csv");
    std::fs::write(&targets, "name,x_mm,y_mm,z_mm\nt1,0,0,0\n").unwrap();
    for (i, (extra, needles)) in [
        (vec!["--speed-deg-s=NaN"], vec!["--speed-deg-s", "finite"]),
        (vec!["--speed-deg-s", "1000"], vec!["cell's limit of 180"]),
        (vec!["--accel-deg-s2=inf"], vec!["--accel-deg-s2"]),
        (vec!["--frames", "0"], vec!["--frames 0"]),
        (
            vec!["--history", "mysql://h/db"],
            vec!["mysql://", "postgres://"],
        ),
        (
            vec![
                "--chain-targets",
                s(&targets),
                "--chain-registration",
                s(&garbage),
                "--chain-robot-world",
                s(&garbage),
            ],
            vec!["garbage.json"],
        ),
    ]
    .into_iter()
    .enumerate()
    {
        let out = dp.join(format!("s{i}"));
        let mut a = vec!["session", "--sim", s(&lab), "--out", s(&out), "--plan-only"];
        a.extend(extra);
        refused(&a, &needles);
        assert!(
            !out.exists(),
            "{a:?}: a refused session created its directory"
        );
    }
}

#[test]
fn bad_input_calibration_claims_are_checked_before_use() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let (cal, held) = nominal_cal(dp);
    let base: Value = serde_json::from_str(&std::fs::read_to_string(&cal).unwrap()).unwrap();
    let variant = |name: &str, f: &dyn Fn(&mut Value)| {
        let mut v = base.clone();
        f(&mut v);
        let p = dp.join(name);
        std::fs::write(&p, v.to_string()).unwrap();
        p
    };
    let empty = variant("empty.json", &|v| v["params"] = json!([]));
    refused(
        &["predict", "--calibration", s(&empty), "--data", s(&held)],
        &["params", "empty"],
    );
    let huge = variant("huge.json", &|v| {
        v["effects"] = json!([{"kind": "joint_compliance", "joint": 2,
            "params": {"points": ["j3"], "c_times_mass_deg_kg_per_nm": [1e308]}}])
    });
    refused(
        &["predict", "--calibration", s(&huge), "--data", s(&held)],
        &["effects[0].params", "not a plausible coefficient"],
    );
    let good = write(dp, "g.jsonl", &geo(40));
    let banana = variant("banana.json", &|v| v["kind"] = json!("banana"));
    refused(
        &[
            "diagnose",
            "--data",
            s(&good),
            "--calibration",
            s(&banana),
            "--out",
            s(&dp.join("x")),
        ],
        &["banana", "kind"],
    );
    let warp = variant("warp.json", &|v| {
        v["effects"] = json!([{"kind": "warp_drive", "params": {"factor": 9.0}}])
    });
    refused(
        &[
            "diagnose",
            "--data",
            s(&good),
            "--calibration",
            s(&warp),
            "--out",
            s(&dp.join("x")),
        ],
        &["warp_drive", "effects[0]"],
    );
}

/// A named edit of a plan file and the refusal it must cause.
type PlanEdit<'a> = (&'a str, &'a dyn Fn(&mut Value), &'a str);

#[test]
fn bad_input_plan_wider_than_the_cell_is_refused() {
    // The lab cell states its table and envelope: an edited plan may not relax them.
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let plan = small_plan(dp);
    let lab = lab();
    let base: Value = serde_json::from_str(&std::fs::read_to_string(&plan).unwrap()).unwrap();
    let edits: [PlanEdit; 3] = [
        (
            "low",
            &|v| v["spec"]["constraints"]["table_z_mm"] = json!(-1000.0),
            "cell's table is at z = 0 mm",
        ),
        (
            "noenv",
            &|v| {
                v["spec"]["constraints"]
                    .as_object_mut()
                    .unwrap()
                    .remove("envelope");
            },
            "not inside the cell's envelope",
        ),
        ("nospec", &|v| v["spec"] = json!({}), "cell's table"),
    ];
    for (name, edit, needle) in edits {
        let mut v = base.clone();
        edit(&mut v);
        let p = dp.join(format!("{name}.json"));
        std::fs::write(&p, v.to_string()).unwrap();
        let out = dp.join(format!("run-{name}"));
        refused(
            &[
                "run",
                "--plan",
                s(&p),
                "--sim",
                s(&lab),
                "--out",
                s(&out),
                "--virtual-clock",
                "--in-process",
            ],
            &[needle, "never wider"],
        );
        assert!(!out.exists());
    }
}

#[test]
fn bad_input_pivot_records_of_two_tools_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let mut rows = pivot_rows(1.0, 40);
    let other = pivot_rows(1.0, 40);
    for (i, r) in other.into_iter().skip(1).enumerate() {
        let mut r = r;
        r["tool"] = json!("pointer");
        r["t"] = json!(10.0 + i as f64 * 0.1);
        // Another tool: its marker 80 mm further from the same pivot.
        let p = r["marker"]["p"].as_array().unwrap().clone();
        r["marker"]["p"] = json!([
            p[0].as_f64().unwrap() + 80.0,
            p[1].as_f64().unwrap(),
            p[2].as_f64().unwrap()
        ]);
        rows.push(r);
    }
    let mixed = write(d.path(), "mixed.jsonl", &rows);
    refused(
        &["calibrate", "pivot", "--data", s(&mixed)],
        &["2 tools", "pointer", "--tool"],
    );
    let o = run(&["calibrate", "pivot", "--data", s(&mixed), "--tool", "probe"]);
    assert_eq!(o.code, Some(0), "{}", o.text);
}

/// Robot-world records: flange poses `A` and marker poses `B = Y⁻¹ A X` (marker rigid on the
/// flange), quaternions written `[w, x, y, z]` or, when `xyzw`, in the wrong order.
fn robot_world_rows(xyzw: bool) -> Vec<Value> {
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
    let x = Isometry3::from_parts(
        Translation3::new(25.0, -10.0, 110.0),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 0.5),
    );
    let y = Isometry3::from_parts(
        Translation3::new(1700.0, 80.0, 650.0),
        UnitQuaternion::from_euler_angles(3.0, -1.3, 0.2),
    );
    let pose = |m: &Isometry3<f64>| {
        let q = m.rotation.quaternion();
        let quat = if xyzw {
            [q.i, q.j, q.k, q.w]
        } else {
            [q.w, q.i, q.j, q.k]
        };
        let t = m.translation.vector;
        (json!([t.x, t.y, t.z]), json!(quat))
    };
    let mut rows = vec![geo(0)[0].clone()];
    for i in 0..24 {
        let a = i as f64;
        let fl = Isometry3::from_parts(
            Translation3::new(
                400.0 + 60.0 * (0.7 * a).sin(),
                100.0 * (0.3 * a).cos(),
                500.0,
            ),
            UnitQuaternion::from_scaled_axis(Vector3::new(
                0.5 * (1.1 * a).sin(),
                0.4 * (0.9 * a).cos(),
                0.6 * (0.5 * a).sin(),
            )),
        );
        let b = y.inverse() * fl * x;
        let (fp, fq) = pose(&fl);
        let (mp, mq) = pose(&b);
        // The flange quaternion is always written right; only the marker's is wrong.
        let fq = if xyzw {
            let q = fl.rotation.quaternion();
            json!([q.w, q.i, q.j, q.k])
        } else {
            fq
        };
        rows.push(json!({"kind": "pose", "id": i, "t": a,
            "flange": {"p": fp, "quat": fq},
            "marker": {"p": mp, "quat": mq, "rms": 0.05}}));
    }
    rows
}

#[test]
fn bad_input_robot_world_wrong_quaternion_order_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let good = write(d.path(), "rw.jsonl", &robot_world_rows(false));
    let out = d.path().join("rw.json");
    let o = run(&[
        "calibrate",
        "robot-world",
        "--data",
        s(&good),
        "--out",
        s(&out),
    ]);
    assert_eq!(o.code, Some(0), "{}", o.text);
    let bad = write(d.path(), "xyzw.jsonl", &robot_world_rows(true));
    let out2 = d.path().join("rw2.json");
    refused(
        &[
            "calibrate",
            "robot-world",
            "--data",
            s(&bad),
            "--out",
            s(&out2),
        ],
        &["[x, y, z, w]", "nothing written"],
    );
    assert!(!out2.exists());
}

#[test]
fn bad_input_laser_truth_in_metres_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let data = root().join("tests/data/laser-planes/train.jsonl");
    let held = root().join("tests/data/laser-planes/heldout.jsonl");
    let truth = std::fs::read_to_string(root().join("tests/data/laser-planes/truth.csv")).unwrap();
    let mut m = String::new();
    for (i, l) in truth.lines().enumerate() {
        if i == 0 {
            m += l;
        } else {
            let c: Vec<&str> = l.split(',').collect();
            m += c[0];
            for x in &c[1..] {
                m += &format!(",{}", x.parse::<f64>().unwrap() / 1000.0);
            }
        }
        m.push('\n');
    }
    let tm = d.path().join("truth-m.csv");
    std::fs::write(&tm, m).unwrap();
    let out = d.path().join("o");
    let args = [
        "calibrate",
        "laser",
        "--data",
        s(&data),
        "--heldout",
        s(&held),
        "--truth",
        s(&tm),
        "--out",
        s(&out),
    ];
    refused(&args, &["truth", "metres"]);
}

#[test]
fn bad_input_camera_calibration_values_predict_applies_are_checked() {
    let d = tempfile::tempdir().unwrap();
    let data = write(d.path(), "geo.jsonl", &geo(20));
    let cam = |f: &dyn Fn(&mut Value)| {
        let mut c = json!({"format": "robocal-calibration/1", "robot": geo(0)[0]["robot"], "params": [],
            "kind": "camera", "camera": {
            "intrinsics": {"fx": 900.0, "fy": 900.0, "cx": 320.0, "cy": 240.0, "dist": [0, 0, 0, 0, 0], "width": 640, "height": 480},
            "hand_eye": {"mount": "flange", "xyz_mm": [0, 50, 40], "quat": [1, 0, 0, 0]},
            "target_in_base": {"xyz_mm": [-576.9, -223.3, 0.0], "quat": [0, 1, 0, 0]},
            "target": {"kind": "chessboard", "cols": 9, "rows": 6, "square_mm": 30.0},
            "target_bend_mm": [0.3, 0.0]}});
        f(&mut c["camera"]);
        let p = d.path().join("cam.json");
        std::fs::write(&p, c.to_string()).unwrap();
        p
    };
    let ok = cam(&|_| {});
    let o = run(&["predict", "--calibration", s(&ok), "--data", s(&data)]);
    assert_eq!(o.code, Some(0), "{}", o.text);
    assert!(o.text.starts_with("id,corner,u_px,v_px"), "{}", o.text);
    // A plausible flange map is read and applied: the predictions move.
    let mapped = cam(&|c: &mut Value| {
        c["flange_map"] = json!({"centre_mm": [0, 0, 500],
            "matrix": [[0.004, 0.002, 0], [0, -0.001, 0.003], [0.001, 0, -0.003]]})
    });
    let m = run(&["predict", "--calibration", s(&mapped), "--data", s(&data)]);
    assert_eq!(m.code, Some(0), "{}", m.text);
    assert_ne!(m.text, o.text, "the flange map moves the predicted corners");
    for (f, needle) in [
        (
            &(|c: &mut Value| c["target_bend_mm"] = json!([400.0, 0.0])) as &dyn Fn(&mut Value),
            "target_bend_mm",
        ),
        (
            &|c: &mut Value| c["target_scale"] = json!(1000.0),
            "target_scale",
        ),
        (
            &|c: &mut Value| c["intrinsics"]["fx"] = json!(0.0),
            "intrinsics",
        ),
        // A flange map that is not trace-free (a hand-edited scale), or 20 % per metre.
        (
            &|c: &mut Value| {
                c["flange_map"] = json!({"centre_mm": [0, 0, 500],
                    "matrix": [[0.01, 0, 0], [0, 0, 0], [0, 0, 0]]})
            },
            "flange_map",
        ),
        (
            &|c: &mut Value| {
                c["flange_map"] = json!({"centre_mm": [0, 0, 500],
                    "matrix": [[0, 0.2, 0], [0, 0, 0], [0, 0, 0]]})
            },
            "flange_map",
        ),
    ] {
        let p = cam(f);
        refused(
            &["predict", "--calibration", s(&p), "--data", s(&data)],
            &[needle],
        );
    }
}

#[test]
fn bad_input_robot_world_without_usable_poses_names_the_likely_cause() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("rw.json");
    let mut rows = robot_world_rows(false);
    for r in rows.iter_mut().skip(1) {
        r["marker"] = json!({"visible": false});
    }
    let f = write(d.path(), "unseen.jsonl", &rows);
    let args = [
        "calibrate",
        "robot-world",
        "--data",
        s(&f),
        "--out",
        s(&out),
    ];
    refused(
        &args,
        &["0 usable poses", "likely cause", "did not see the marker"],
    );
    let mut rows = robot_world_rows(false);
    for r in rows.iter_mut().skip(1) {
        r["marker"].as_object_mut().unwrap().remove("quat");
    }
    let f = write(d.path(), "noquat.jsonl", &rows);
    let args = [
        "calibrate",
        "robot-world",
        "--data",
        s(&f),
        "--out",
        s(&out),
    ];
    refused(&args, &["likely cause", "orientation"]);
    assert!(!out.exists());
}
/// The kinematic dataset with every marker quaternion written scalar-last (`[x, y, z, w]`).
#[test]
fn bad_input_marker_quaternions_scalar_last_are_refused_everywhere() {
    let d = tempfile::tempdir().unwrap();
    let (cal, held) = nominal_cal(d.path());
    let mut rows = geo(80);
    for r in rows.iter_mut().skip(1) {
        if let Some(q) = r["marker"]["quat"].as_array().cloned() {
            r["marker"]["quat"] = json!([q[1], q[2], q[3], q[0]]);
        }
    }
    let bad = write(d.path(), "xyzw.jsonl", &rows);
    let o = d.path().join("o");
    for args in [
        vec!["inspect", s(&bad)],
        vec!["calibrate", "nominal", "--data", s(&bad), "--out", s(&o)],
        vec!["predict", "--calibration", s(&cal), "--data", s(&bad)],
    ] {
        refused(&args, &["marker.quat", "[x, y, z, w]"]);
    }
    // The same file written right passes `inspect`.
    let o = run(&["inspect", s(&held)]);
    assert_eq!(o.code, Some(0), "{}", o.text);
}

/// Every shipped scenario states its cell's safety limits (table plane; the tracker cells
/// their envelope too): a plan run on it is checked against the cell, never only against
/// its own editable constraints (issue 26 §2).
#[test]
fn bad_input_every_scenario_states_its_cells_safety_limits() {
    let mut n = 0;
    for e in std::fs::read_dir(root().join("mocks/scenarios")).unwrap() {
        let p = e.unwrap().path();
        if p.extension().and_then(|x| x.to_str()) != Some("toml") {
            continue;
        }
        let sc = robocal_mocks::Scenario::load(&p).unwrap();
        for a in &sc.arms {
            let s = a.safety.as_ref();
            assert!(
                s.is_some_and(|s| s.table_z_mm.is_some()),
                "{}: arm {:?} states no [arm.safety] table_z_mm",
                p.display(),
                a.name
            );
            if !sc.trackers.is_empty() {
                assert!(
                    s.is_some_and(|s| s.envelope.is_some()),
                    "{}: arm {:?} states no [arm.safety] envelope",
                    p.display(),
                    a.name
                );
            }
            n += 1;
        }
    }
    assert!(n >= 10, "{n} arms");
}

/// A camera cell's plan with its table lowered below the cell's is refused naming the limit.
#[test]
fn bad_input_camera_plan_below_the_cells_table_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let spec = std::fs::read_to_string(root().join("plans/seed004-ur5e-camera.toml"))
        .unwrap()
        .replace("table_z_mm = -20.0", "table_z_mm = -400.0");
    assert!(spec.contains("table_z_mm = -400.0"));
    let sp = dp.join("low.toml");
    std::fs::write(&sp, spec).unwrap();
    let plan = dp.join("low.json");
    let o = run(&[
        "plan",
        "--spec",
        s(&sp),
        "--robot",
        "ur5e",
        "--out",
        s(&plan),
    ]);
    assert_eq!(o.code, Some(0), "{}", o.text);
    let sc = root().join("mocks/scenarios/ur5e-camera.toml");
    let out = dp.join("run");
    refused(
        &[
            "run",
            "--plan",
            s(&plan),
            "--sim",
            s(&sc),
            "--out",
            s(&out),
            "--virtual-clock",
            "--in-process",
        ],
        &["table", "never wider"],
    );
    assert!(!out.exists());
}
