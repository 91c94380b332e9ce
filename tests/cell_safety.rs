//! Issue 28 / 26 §2: a device file's `[safety]` block (table, envelope, joint limits, speed
//! cap) is what the cell is. Each bad block is refused when the file is read (`devices`,
//! `session --live` before consent) naming the field; `run --live` refuses a plan wider than
//! the block before consent, naming the limit; `session --live` plans inside the block.
use std::path::{Path, PathBuf};

use crate::common::{bin as run, root, s as p};

/// A cell folder `dir/name/cell` whose device file (DENSO VS060 on b-CAP, Polaris Vega with
/// the shipped tool file, both at closed local ports) ends with `safety`.
fn cell(dir: &Path, name: &str, safety: &str) -> PathBuf {
    crate::live_session::cell(
        &dir.join(name),
        "127.0.0.1:1",
        "127.0.0.1:2",
        &format!("tools = [\"tools/flange-marker.rom\"]\n\n{safety}"),
    )
}

/// A `[safety]` block with joint 1's limits `j1` and the preset's for the others.
fn joints(j1: &str) -> String {
    format!(
        "[safety]\njoint_limits_deg = [{j1}, [-120, 120], [-125, 155], [-270, 270], [-120, 120], \
         [-360, 360]]\n"
    )
}

/// The seed 001 spec's own limits: table z = 0 mm + 50 mm, cylinder r 900 mm, z 0…1100 mm.
const SAME_AS_SPEC: &str = "[safety]\ntable_z_mm = 0.0\ntable_clearance_mm = 50.0\n\
    envelope = { shape = \"cylinder\", center_xy = [0.0, 0.0], radius = 900.0, z_min = 0.0, \
    z_max = 1100.0 }\n";

#[test]
fn device_safety_block_each_refusal_names_the_field() {
    let tmp = tempfile::tempdir().unwrap();
    let (wide, unordered) = (joints("[-180, 180]"), joints("[170, -170]"));
    let cases = [
        (
            "metres",
            "[safety]\nenvelope = { shape = \"box\", min = [-0.9, -0.9, 0.0], max = [0.9, 0.9, \
             1.2] }\n",
            "metres typed?",
        ),
        (
            "swapped",
            "[safety]\nenvelope = { shape = \"box\", min = [-900.0, -900.0, 1200.0], max = \
             [900.0, 900.0, 0.0] }\n",
            "min z = 1200 is not below max z = 0",
        ),
        (
            "wider-joints",
            wide.as_str(),
            "joint_limits_deg[0] = [-180, 180] is wider than the denso-vs060's own limit",
        ),
        (
            "unordered-joints",
            unordered.as_str(),
            "lower must be below upper",
        ),
        (
            "nan-table",
            "[safety]\ntable_z_mm = nan\n",
            "table_z_mm = NaN",
        ),
        (
            "speed",
            "[safety]\nmax_speed_deg_s = 0.0\n",
            "max_speed_deg_s = 0",
        ),
        (
            "below-table",
            "[safety]\ntable_z_mm = 0.0\ntable_clearance_mm = 50.0\nenvelope = { shape = \
             \"box\", min = [-900.0, -900.0, -100.0], max = [900.0, 900.0, 30.0] }\n",
            "not above the table",
        ),
        (
            "typo",
            "[safety]\ntable_height_mm = 0.0\n",
            "table_height_mm",
        ),
    ];
    for (name, block, want) in cases {
        let file = cell(tmp.path(), name, block);
        let (code, stdout, stderr) = run(&["devices", "--devices", p(&file), "--probe"]);
        assert_eq!(code, Some(1), "{name}: {stdout}\n{stderr}");
        assert!(
            stderr.contains(want) && stderr.contains(p(&file)),
            "{name}: want {want:?} in:\n{stderr}"
        );
        // The session refuses it before anything is created or asked.
        let out = tmp.path().join(format!("{name}-session"));
        let (code, stdout, stderr) = run(&[
            "session",
            "--devices",
            p(&file),
            "--live",
            "--yes",
            "--out",
            p(&out),
            "--no-history",
        ]);
        assert_eq!(code, Some(1), "{name}: {stdout}\n{stderr}");
        assert!(stderr.contains(want), "{name}: {stderr}");
        assert!(!out.exists(), "{name}: the session was created");
    }
    // The shipped example reads, and `devices` lists its block.
    let (code, stdout, stderr) = run(&["devices", "--devices", "examples/CELL.toml"]);
    assert_eq!(code, Some(0), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("[safety]     table z = 0 mm (+50 mm clearance)")
            && stdout.contains("speed cap 120 deg/s"),
        "{stdout}"
    );
}

#[test]
fn run_live_refuses_a_plan_wider_than_the_cells_block() {
    let tmp = tempfile::tempdir().unwrap();
    let plan = tmp.path().join("plan.json");
    let spec = root().join("plans/seed001-annulus.toml");
    let (code, _, stderr) = run(&[
        "plan",
        "--spec",
        p(&spec),
        "--robot",
        "denso-vs060",
        "--out",
        p(&plan),
    ]);
    assert_eq!(code, Some(0), "{stderr}");
    let narrow = joints("[-20, 20]");
    let cases = [
        (
            "table",
            "[safety]\ntable_z_mm = 100.0\ntable_clearance_mm = 50.0\n",
            "the cell's table is at z = 100 mm with 50 mm clearance",
        ),
        (
            "envelope",
            "[safety]\nenvelope = { shape = \"box\", min = [-600.0, -600.0, 0.0], max = [600.0, \
             600.0, 1100.0] }\n",
            "is not inside the cell's envelope",
        ),
        (
            "joints",
            narrow.as_str(),
            "is outside the cell's joint limit [-20, 20]°",
        ),
        (
            "speed",
            "[safety]\nmax_speed_deg_s = 30.0\n",
            "above the cell's limit of 30 deg/s",
        ),
    ];
    let run_live = |file: &Path, out: &Path| {
        run(&[
            "run",
            "--plan",
            p(&plan),
            "--devices",
            p(file),
            "--live",
            "--yes",
            "--out",
            p(out),
        ])
    };
    for (name, block, want) in cases {
        let file = cell(tmp.path(), name, block);
        let out = tmp.path().join(format!("{name}-run"));
        let (code, stdout, stderr) = run_live(&file, &out);
        assert_eq!(code, Some(1), "{name}: {stdout}\n{stderr}");
        assert!(stderr.contains(want), "{name}: want {want:?} in:\n{stderr}");
        assert!(
            name == "speed" || stderr.contains("never wider"),
            "{name}: {stderr}"
        );
        assert!(!stderr.contains("will move the arm"), "{name}: asked");
        assert!(!out.exists(), "{name}: the run was created");
    }
    // A block the plan fits passes the checks: the run asks, then fails only to connect.
    let file = cell(tmp.path(), "same", SAME_AS_SPEC);
    let out = tmp.path().join("same-run");
    let (code, _, stderr) = run_live(&file, &out);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("will move the arm"), "{stderr}");
    assert!(!stderr.contains("never wider"), "{stderr}");
}

/// Whether every pose of `plan` keeps joint 1 within ±`j1` deg and the flange above `floor`.
fn plan_inside(plan: &Path, j1: f64, floor: f64) -> (bool, usize) {
    let f = robocal::plan::PlanFile::read(plan).unwrap();
    let m = robocal::model::KinematicModel::preset("denso-vs060").unwrap();
    let ok = f.poses.iter().all(|p| {
        let q: Vec<f64> = p.q_deg.iter().map(|x| x.to_radians()).collect();
        p.q_deg[0].abs() <= j1 + 1e-9 && m.flange_pose(&q).translation.z >= floor - 1e-6
    });
    (ok, f.poses.len())
}

/// `robocal session CELL_ARGS --plan-only` of 20 training and 10 validation poses into `out`;
/// asserts exit 0 and returns stderr (the plan's notes).
pub(crate) fn plan_only_session(cell_args: &[&str], out: &Path) -> String {
    let mut args = vec!["session"];
    args.extend(cell_args);
    args.extend([
        "--plan-only",
        "--poses",
        "20",
        "--heldout-points",
        "10",
        "--out",
        p(out),
        "--no-history",
    ]);
    let (code, stdout, stderr) = run(&args);
    assert_eq!(code, Some(0), "{cell_args:?}: {stdout}\n{stderr}");
    stderr
}

#[test]
fn live_session_plans_inside_the_cells_block() {
    let tmp = tempfile::tempdir().unwrap();
    let plan_only = |name: &str, block: &str| {
        let file = cell(tmp.path(), name, block);
        let out = tmp.path().join(format!("{name}-session"));
        let stderr = plan_only_session(&["--devices", p(&file), "--live"], &out);
        (out, stderr)
    };
    // Without a block the seed 001 plan swings joint 1 beyond ±45° and goes below z = 250 mm.
    let (free, _) = plan_only("free", "");
    let (inside, n) = plan_inside(&free.join("plan/train.json"), 45.0, 250.0);
    assert!(
        !inside && n == 20,
        "the control plan is already inside the block"
    );
    let block = "[safety]\ntable_z_mm = 200.0\ntable_clearance_mm = 50.0\njoint_limits_deg = \
                 [[-45, 45], [-120, 120], [-125, 155], [-270, 270], [-120, 120], [-360, 360]]\n";
    let (dir, stderr) = plan_only("strict", block);
    println!("{stderr}");
    for set in ["train", "validation"] {
        let (inside, n) = plan_inside(&dir.join(format!("plan/{set}.json")), 45.0, 250.0);
        assert!(inside && n > 0, "{set}: a pose outside the cell's [safety]");
    }
    assert!(
        stderr.contains("table from the cell's [safety]: z = 200 mm"),
        "{stderr}"
    );
    assert!(
        stderr.contains("joint limits from the cell's [safety]"),
        "{stderr}"
    );
}
