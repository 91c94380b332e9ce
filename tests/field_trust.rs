//! Issue 26 / 28: a robocal file of another kind is named by the reader that got it (not
//! "invalid JSON"), a robocal TOML file given for a JSON one and the reverse too; a simulated
//! session plans inside its scenario's `[arm.safety]`; `devices --probe` checks the arm's
//! current joints against the device file's `[safety]`.
use std::path::Path;

use crate::common::{bin as run, root, s as p};
use crate::e2e::SimServe;

/// A one-row targets file and a pretty-printed calibration file (the writer's layout: its
/// first line is `{`) in `dir`.
fn targets_and_calibration(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let targets = dir.join("targets.csv");
    std::fs::write(
        &targets,
        "name,x_mm,y_mm,z_mm,qw,qx,qy,qz\nA,400,0,300,0,1,0,0\n",
    )
    .unwrap();
    let cal = dir.join("calibration.json");
    std::fs::write(
        &cal,
        "{\n  \"format\": \"robocal-calibration/1\",\n  \"robot\": {\"model\": \"denso-vs060\"},\n  \
         \"params\": []\n}\n",
    )
    .unwrap();
    (targets, cal)
}

#[test]
fn a_file_of_another_robocal_kind_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let dataset = root().join("tests/data/kin-geometric/train.jsonl");
    let (targets, cal) = targets_and_calibration(tmp.path());
    let cases: [(&str, Vec<&str>, &str); 4] = [
        (
            "correct --calibration DATASET",
            vec!["correct", "--calibration", p(&dataset), "--targets", p(&targets)],
            "this is a dataset (JSON Lines, `--data`), format `robocal-dataset/1`, not a calibration file",
        ),
        (
            "predict --calibration DATASET",
            vec!["predict", "--calibration", p(&dataset), "--data", p(&dataset)],
            "this is a dataset (JSON Lines, `--data`), format `robocal-dataset/1`, not a calibration file",
        ),
        (
            "inspect CALIBRATION",
            vec!["inspect", p(&cal)],
            "this is a calibration file (`calibration.json`), format `robocal-calibration/1`, not a dataset",
        ),
        (
            "plan --check DATASET",
            vec!["plan", "--check", p(&dataset)],
            "this is a dataset (JSON Lines, `--data`), format `robocal-dataset/1`, not a pose plan",
        ),
    ];
    for (name, args, want) in cases {
        let (code, stdout, stderr) = run(&args);
        println!("{name}: {}", stderr.trim());
        assert_eq!(code, Some(1), "{name}: {stdout}\n{stderr}");
        assert!(stderr.contains(want), "{name}: {stderr}");
        assert!(!stderr.contains("panicked"), "{name}: {stderr}");
    }
}

#[test]
fn a_toml_file_given_for_json_and_a_json_file_given_for_toml_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let dataset = root().join("tests/data/kin-geometric/train.jsonl");
    let scenario = root().join("mocks/scenarios/hospital-vs060-vega.toml");
    let spec = root().join("plans/seed004-shell.toml");
    let accept = root().join("accept/camera.toml");
    let devices = root().join("examples/CELL.toml");
    let (targets, cal) = targets_and_calibration(tmp.path());
    let out = tmp.path().join("session");
    let toml_for_json = "this is a TOML file (";
    let cases: Vec<(&str, Vec<&str>, [&str; 2])> = vec![
        (
            "correct --calibration SCENARIO",
            vec![
                "correct",
                "--calibration",
                p(&scenario),
                "--targets",
                p(&targets),
            ],
            [toml_for_json, "a scenario, judging by its tables [arm]"],
        ),
        (
            "inspect PLAN-SPEC",
            vec!["inspect", p(&spec)],
            [toml_for_json, "a plan spec, judging by its tables ["],
        ),
        (
            "predict --data ACCEPT",
            vec!["predict", "--calibration", p(&cal), "--data", p(&accept)],
            [toml_for_json, "an accept spec, judging by its keys `"],
        ),
        (
            "predict --calibration DEVICES",
            vec![
                "predict",
                "--calibration",
                p(&devices),
                "--data",
                p(&dataset),
            ],
            [
                toml_for_json,
                "a device file, judging by its tables [device]",
            ],
        ),
        (
            "session --sim CALIBRATION",
            vec![
                "session",
                "--sim",
                p(&cal),
                "--out",
                p(&out),
                "--plan-only",
                "--no-history",
            ],
            [
                "this is a calibration file",
                "not a scenario (TOML, `--sim`)",
            ],
        ),
        (
            "session --accept DATASET",
            vec![
                "session",
                "--sim",
                p(&scenario),
                "--accept",
                p(&dataset),
                "--out",
                p(&out),
                "--plan-only",
                "--poses",
                "20",
                "--heldout-points",
                "10",
                "--no-history",
            ],
            ["this is a dataset", "not an accept spec (TOML, `--accept`)"],
        ),
        (
            "devices --devices CALIBRATION",
            vec!["devices", "--devices", p(&cal)],
            [
                "this is a calibration file",
                "not a device file (TOML, `--devices`)",
            ],
        ),
        (
            "devices --devices PLAN-SPEC",
            vec!["devices", "--devices", p(&spec)],
            ["this is a TOML file (a plan spec", "not a device file"],
        ),
        (
            "plan --spec DATASET",
            vec!["plan", "--spec", p(&dataset), "--robot", "denso-vs060"],
            ["this is a dataset", "not a plan spec (TOML"],
        ),
    ];
    for (name, args, want) in cases {
        let (code, stdout, stderr) = run(&args);
        println!("{name}: {}", stderr.trim());
        assert_ne!(code, Some(0), "{name}: {stdout}\n{stderr}");
        assert!(!stderr.contains("panicked"), "{name}: {stderr}");
        for w in want {
            assert!(stderr.contains(w), "{name}: wanted {w:?} in {stderr}");
        }
        assert!(
            stderr.contains("check which file went to which option"),
            "{name}: {stderr}"
        );
    }
}

/// The hospital scenario with its `[arm.safety]` replaced by `block` (TOML lines).
fn hospital_with_safety(dir: &Path, name: &str, block: &str) -> std::path::PathBuf {
    let text =
        std::fs::read_to_string(root().join("mocks/scenarios/hospital-vs060-vega.toml")).unwrap();
    let start = text
        .find("[arm.safety]\n")
        .expect("the hospital scenario's [arm.safety]");
    let end = text[start + 1..]
        .find("\n[")
        .map_or(text.len(), |i| start + 1 + i + 1);
    let f = dir.join(format!("{name}.toml"));
    std::fs::write(
        &f,
        format!("{}[arm.safety]\n{block}\n{}", &text[..start], &text[end..]),
    )
    .unwrap();
    f
}

/// The least flange height (mm) and the largest flange radius from the base axis (mm) over
/// the poses of a plan file.
fn flange_extent(plan: &Path) -> (f64, f64, usize) {
    let f = robocal::plan::PlanFile::read(plan).unwrap();
    let m = robocal::model::KinematicModel::preset("denso-vs060").unwrap();
    let (mut zmin, mut rmax) = (f64::INFINITY, 0.0f64);
    for pose in &f.poses {
        let q: Vec<f64> = pose.q_deg.iter().map(|x| x.to_radians()).collect();
        let t = m.flange_pose(&q).translation.vector;
        zmin = zmin.min(t.z);
        rmax = rmax.max(t.x.hypot(t.y));
    }
    (zmin, rmax, f.poses.len())
}

#[test]
fn sim_session_plans_inside_the_scenarios_arm_safety() {
    let tmp = tempfile::tempdir().unwrap();
    let plan_only = |scen: &Path, name: &str| {
        let out = tmp.path().join(name);
        let stderr = crate::cell_safety::plan_only_session(&["--sim", p(scen)], &out);
        (out, stderr)
    };
    // The table raised to z = 200 mm (+50 mm clearance), a cylinder of radius 450 mm: the
    // shipped block (table 0 + 50 mm, radius 900 mm) lets the plan reach beyond it.
    let (floor, radius) = (250.0, 450.0);
    let (free, _) = plan_only(
        &root().join("mocks/scenarios/hospital-vs060-vega.toml"),
        "free",
    );
    let (zmin, rmax, n) = flange_extent(&free.join("plan/train.json"));
    println!("hospital as shipped: flange z ≥ {zmin:.1} mm, r ≤ {rmax:.1} mm ({n} poses)");
    assert!(
        zmin < floor || rmax > radius,
        "the control plan is already inside the stricter block"
    );
    let strict = hospital_with_safety(
        tmp.path(),
        "strict",
        "table_z_mm = 200.0\ntable_clearance_mm = 50.0\nenvelope = { shape = \"cylinder\", \
         center_xy = [0.0, 0.0], radius = 450.0, z_min = 0.0, z_max = 1100.0 }",
    );
    let (dir, stderr) = plan_only(&strict, "strict");
    for set in ["train", "validation"] {
        let (zmin, rmax, n) = flange_extent(&dir.join(format!("plan/{set}.json")));
        println!("strict {set}: flange z ≥ {zmin:.1} mm, r ≤ {rmax:.1} mm ({n} poses)");
        assert!(n > 0, "{set}: no pose planned");
        assert!(
            zmin >= floor - 1e-6,
            "{set}: flange at z = {zmin} mm, below {floor}"
        );
        assert!(
            rmax <= radius + 1e-6,
            "{set}: flange at r = {rmax} mm, beyond {radius}"
        );
    }
    assert!(
        stderr.contains("table from the cell's [safety]: z = 200 mm")
            && stderr.contains("envelope from the cell's [safety]"),
        "{stderr}"
    );
}

#[test]
fn probe_checks_the_arms_current_joints_against_safety() {
    let tmp = tempfile::tempdir().unwrap();
    // The hospital arm rests at its home, joints (0, 0, 90, 0, 45, 0) deg.
    let serve = SimServe::start(&root().join("mocks/scenarios/hospital-vs060-vega.toml"));
    let bcap = serve.endpoint("bcap", "addr").unwrap();
    let ndi = serve.endpoint("ndi-tcp", "addr").unwrap();
    let probe = |name: &str, block: &str| {
        let file = crate::live_session::cell(
            &tmp.path().join(name),
            &bcap,
            &ndi,
            &format!("tools = [\"tools/flange-marker.rom\"]\n\n{block}"),
        );
        let (code, stdout, stderr) = run(&["devices", "--devices", p(&file), "--probe"]);
        println!("{name}:\n{stdout}{stderr}");
        let arm = stdout
            .lines()
            .skip_while(|l| !l.starts_with("vs060"))
            .nth(1)
            .unwrap_or_default()
            .to_string();
        (code, arm, stderr)
    };
    let joints = |j1: &str| {
        format!(
            "[safety]\njoint_limits_deg = [{j1}, [-120, 120], [-125, 155], [-270, 270], \
             [-120, 120], [-360, 360]]\n"
        )
    };
    let (_, arm, _) = probe("inside", &joints("[-45, 45]"));
    assert!(arm.contains("ok: mode"), "{arm}");
    let (code, arm, stderr) = probe("joint-1", &joints("[10, 45]"));
    assert_eq!(code, Some(1), "{arm}\n{stderr}");
    assert!(
        arm.contains("error (safety-violation)")
            && arm.contains("joint 1 at 0.00° is outside joint_limits_deg [10, 45]")
            && arm.contains("bring it inside"),
        "{arm}"
    );
    let (code, arm, _) = probe("table", "[safety]\ntable_z_mm = 1500.0\n");
    assert_eq!(code, Some(1), "{arm}");
    assert!(
        arm.contains("is below the table + clearance (z = 1500 mm)"),
        "{arm}"
    );
    let (code, arm, _) = probe(
        "envelope",
        "[safety]\nenvelope = { shape = \"box\", min = [-900.0, -900.0, 0.0], max = [100.0, 900.0, \
         1200.0] }\n",
    );
    assert_eq!(code, Some(1), "{arm}");
    assert!(arm.contains("is outside the envelope"), "{arm}");
}
