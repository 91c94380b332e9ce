//! `robocal capture` end to end against `robocal sim serve` with the simulated operator
//! (scenario `operator-vs060-vega`: a Polaris Vega over TCP with 0.25 mm noise per axis, a
//! scripted hand): the result is compared with the scenario's truth, which never goes over a
//! wire. The operator runs on the wall clock, so each test takes its script's seconds.
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use nalgebra::{Point3, Vector3};
use robocal_mocks::scenario::Scenario;
use robocal_mocks::world::operator::Step;

use crate::common::{root, s};
use crate::e2e::SimServe;

/// The operator scenario with only the steps `keep` picks.
fn scenario(
    dir: &Path,
    keep: impl Fn(&Step) -> bool,
    edit: impl Fn(&mut Step),
) -> (PathBuf, Scenario) {
    let mut sc = Scenario::load(&root().join("mocks/scenarios/operator-vs060-vega.toml")).unwrap();
    let op = sc.operator.as_mut().unwrap();
    op.steps.retain(|st| keep(st));
    op.steps.iter_mut().for_each(edit);
    let f = dir.join("scenario.toml");
    std::fs::write(&f, toml::to_string(&sc).unwrap()).unwrap();
    Scenario::load(&f).unwrap();
    (f, sc)
}

/// A device file for the served cell: the arm on b-CAP, the Vega with the arm's marker and
/// the probe (tools in frame order).
fn cell(dir: &Path, serve: &SimServe) -> PathBuf {
    let tools = dir.join("tools");
    std::fs::create_dir_all(&tools).unwrap();
    let rom = root().join("examples/tools/flange-marker.rom");
    std::fs::copy(&rom, tools.join("flange-marker.rom")).unwrap();
    std::fs::copy(&rom, tools.join("probe.rom")).unwrap();
    let f = dir.join("CELL.toml");
    std::fs::write(
        &f,
        format!(
            "[[device]]\nname = \"vs060\"\nrole = \"arm\"\nvendor = \"denso\"\nprotocol = \
             \"bcap\"\nmodel = \"denso-vs060\"\naddress = \"{}\"\n\n[[device]]\nname = \
             \"vega\"\nrole = \"tracker\"\nvendor = \"ndi\"\nprotocol = \"ndi-tcp\"\naddress = \
             \"{}\"\ntools = [\"tools/flange-marker.rom\", \"tools/probe.rom\"]\n",
            serve.endpoint("bcap", "addr").unwrap(),
            serve.endpoint("ndi-tcp", "addr").unwrap()
        ),
    )
    .unwrap();
    f
}

/// The operator cell of [`scenario`] served by `robocal sim serve`, and its device file.
struct Served {
    sc: Scenario,
    serve: SimServe,
    file: PathBuf,
}

/// Serves the operator scenario (steps as [`scenario`] keeps and edits them) in `dir`.
fn served(dir: &Path, keep: impl Fn(&Step) -> bool, edit: impl Fn(&mut Step)) -> Served {
    let (scen, sc) = scenario(dir, keep, edit);
    let serve = SimServe::start(&scen);
    let file = cell(dir, &serve);
    Served { sc, serve, file }
}

/// `robocal capture pivot` of the probe on the device file `file` into `out`, then `extra`.
fn pivot(file: &Path, out: &Path, extra: &[&str]) -> (Option<i32>, String, String) {
    let mut args = vec![
        "capture",
        "pivot",
        "--devices",
        s(file),
        "--tool",
        "probe",
        "--out",
        s(out),
    ];
    args.extend_from_slice(extra);
    run(&args)
}

fn run(args: &[&str]) -> (Option<i32>, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_robocal"))
        .args(args)
        .env("ROBOCAL_LOG", "warn")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let r = (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    );
    println!("{}\n{}", r.1, r.2);
    r
}

fn is_pivot(st: &Step) -> bool {
    matches!(st, Step::Wait { .. } | Step::Pivot { .. })
}

/// The divot in the tracker frame.
fn divot_in_tracker(sc: &Scenario) -> Point3<f64> {
    let divot = sc
        .operator
        .as_ref()
        .unwrap()
        .steps
        .iter()
        .find_map(|st| match st {
            Step::Pivot { divot_mm, .. } => Some(Point3::from(*divot_mm)),
            _ => None,
        })
        .unwrap();
    sc.trackers[0].tracker_in_base.isometry().inverse() * divot
}

#[test]
fn capture_pivot_recovers_the_probe_tip() {
    let tmp = tempfile::tempdir().unwrap();
    let Served {
        sc,
        serve: _serve,
        file,
    } = served(tmp.path(), is_pivot, |_| {});
    let out = tmp.path().join("pivot");
    // Two tools on the tracker and no --tool: refused, naming both.
    let (code, _, err) = run(&["capture", "pivot", "--devices", s(&file), "--out", s(&out)]);
    assert_eq!(code, Some(1));
    assert!(
        err.contains("2 tools (flange-marker, probe)") && err.contains("--tool"),
        "{err}"
    );
    let (code, stdout, err) = pivot(&file, &out, &[]);
    assert_eq!(code, Some(0), "{err}");
    assert!(
        err.contains("spread") && err.contains("tilt directions"),
        "{err}"
    );
    assert!(stdout.contains("methods"), "{stdout}");
    let pf: robocal::schema::PivotFile = robocal::schema::read(&out.join("pivot.json")).unwrap();
    let rob = pf.robust.as_ref().unwrap();
    let best = pf
        .results
        .iter()
        .find(|r| r.method == format!("robust-{}", rob.trust))
        .unwrap();
    let tip_truth = Vector3::from(sc.operator.as_ref().unwrap().probe_tip_mm);
    let tip_err = (Vector3::from(best.tip_in_marker_mm) - tip_truth).norm();
    let piv_err = (Point3::from(best.pivot_point_mm) - divot_in_tracker(&sc)).norm();
    println!(
        "capture pivot: {} frames, trusted {}: tip error {tip_err:.4} mm, pivot point error \
         {piv_err:.4} mm (0.25 mm tracker noise)",
        best.frames, rob.trust
    );
    assert!(tip_err < 0.1, "tip {tip_err} mm from the truth");
    // The pivot point is not part of the criterion (measured 0.076 – 0.094 mm).
    assert!(piv_err < 0.2, "pivot point {piv_err} mm from the truth");
    // The frames load back as a dataset.
    let ds = robocal::dataset::read_dataset(out.join("pivot.jsonl")).unwrap();
    assert!(ds.dataset.records.len() >= 600);
}

#[test]
fn capture_pivot_refuses_a_small_cone_and_a_moving_divot() {
    let tmp = tempfile::tempdir().unwrap();
    // A divot that slides 0.2 mm/s.
    let Served { serve, file, .. } = served(tmp.path(), is_pivot, |st| {
        if let Step::Pivot { drift_mm_s, .. } = st {
            *drift_mm_s = [0.2, 0.0, 0.0];
        }
    });
    let out = tmp.path().join("pivot");
    let (code, _, err) = pivot(&file, &out, &[]);
    assert_eq!(code, Some(1));
    assert!(err.contains("the divot moved"), "{err}");
    assert!(!out.join("pivot.json").exists());
    drop(serve);
    // A cone of ±6°: too little spread, with a hint.
    let tmp = tempfile::tempdir().unwrap();
    let Served { serve, file, .. } = served(tmp.path(), is_pivot, |st| {
        if let Step::Pivot { cone_deg, .. } = st {
            *cone_deg = 6.0;
        }
    });
    let (code, _, err) = pivot(&file, &out, &["--max-seconds", "6"]);
    drop(serve);
    assert_eq!(code, Some(1));
    assert!(
        err.contains("too little spread") && err.contains("needed 40°"),
        "{err}"
    );
}

#[test]
fn capture_points_averages_still_windows() {
    let tmp = tempfile::tempdir().unwrap();
    let Served {
        sc,
        serve: _serve,
        file,
    } = served(
        tmp.path(),
        |st| matches!(st, Step::Wait { .. } | Step::Touch { .. }),
        |_| {},
    );
    let op = sc.operator.as_ref().unwrap();
    let tip = op.probe_tip_mm;
    let tip_arg = format!("{},{},{}", tip[0], tip[1], tip[2]);
    let out = tmp.path().join("points.csv");
    let (code, stdout, err) = run(&[
        "capture",
        "points",
        "--devices",
        s(&file),
        "--tool",
        "probe",
        "--tip-mm",
        &tip_arg,
        "--names",
        "F1,F2,F3,F4",
        "--out",
        s(&out),
    ]);
    assert_eq!(code, Some(0), "{err}");
    assert!(
        stdout.contains("4 points") && err.contains("spread"),
        "{stdout}\n{err}"
    );
    let got = robocal::register::points::read_points_csv(&out).unwrap();
    let truth: Vec<_> = op
        .steps
        .iter()
        .find_map(|st| match st {
            Step::Touch { points, .. } => Some(points.clone()),
            _ => None,
        })
        .unwrap();
    let tib = sc.trackers[0].tracker_in_base.isometry().inverse();
    let mut worst: f64 = 0.0;
    for (g, t) in got.iter().zip(&truth) {
        assert_eq!(g.name, t.name);
        let e = (g.p - tib * Point3::from(t.xyz_mm)).norm();
        println!("capture points: {} error {e:.4} mm", g.name);
        worst = worst.max(e);
    }
    assert_eq!(got.len(), 4);
    assert!(worst < 0.1, "worst point {worst} mm from the truth");
}

#[test]
fn capture_poses_reads_the_hand_guided_denso_and_ur_freedrive() {
    let tmp = tempfile::tempdir().unwrap();
    let Served { sc, serve, file } =
        served(tmp.path(), |st| matches!(st, Step::Drag { .. }), |_| {});
    let out = tmp.path().join("poses.csv");
    let (code, stdout, err) = run(&[
        "capture",
        "poses",
        "--devices",
        s(&file),
        "--count",
        "4",
        "--out",
        s(&out),
        "--max-seconds",
        "60",
    ]);
    assert_eq!(code, Some(0), "{err}");
    assert!(
        stdout.contains("4 poses") && err.contains("read-only"),
        "{err}"
    );
    let truth: Vec<Vec<f64>> = sc
        .operator
        .as_ref()
        .unwrap()
        .steps
        .iter()
        .find_map(|st| match st {
            Step::Drag { poses_deg, .. } => Some(poses_deg.clone()),
            _ => None,
        })
        .unwrap();
    let check = |out: &Path, truth: &[Vec<f64>], what: &str| {
        let text = std::fs::read_to_string(out).unwrap();
        let got = robocal::capture::poses::read_poses_csv("poses.csv", &text).unwrap();
        assert_eq!(got.len(), truth.len());
        let worst = got
            .iter()
            .zip(truth)
            .flat_map(|(g, t)| g.q_deg.iter().zip(t).map(|(a, b)| (a - b).abs()))
            .fold(0.0, f64::max);
        // Repeatability ±0.02 mm (VS060) / ±0.03 mm (UR5e) at up to 1 m from the joint axis:
        // 0.02 mm / 1000 mm = 0.0011°.
        println!(
            "capture poses ({what}): worst joint error {worst:.6}° ({:.4} mm at 1 m)",
            worst.to_radians() * 1000.0
        );
        assert!(worst < 0.0011, "{what}: {worst}°");
    };
    check(&out, &truth, "DENSO, teach pendant");
    drop(serve);

    // The same hand on a UR5e: freedrive only with --live and consent.
    let tmp = tempfile::tempdir().unwrap();
    let ur_poses: Vec<Vec<f64>> = vec![
        vec![10.0, -80.0, 80.0, -90.0, -90.0, 0.0],
        vec![-20.0, -100.0, 100.0, -80.0, -90.0, 30.0],
        vec![30.0, -70.0, 60.0, -100.0, -80.0, -20.0],
    ];
    let up = ur_poses.clone();
    let (scen, _) = scenario(
        tmp.path(),
        |st| matches!(st, Step::Drag { .. }),
        move |st| {
            if let Step::Drag { poses_deg, .. } = st {
                *poses_deg = up.clone();
            }
        },
    );
    let mut sc: Scenario = Scenario::load(&scen).unwrap();
    sc.arms[0].model = "ur5e".into();
    sc.arms[0].protocol = robocal_mocks::scenario::Protocol::Ur;
    sc.arms[0].home_deg = Some(vec![0.0, -90.0, 90.0, -90.0, -90.0, 0.0]);
    std::fs::write(&scen, toml::to_string(&sc).unwrap()).unwrap();
    let serve = SimServe::start(&scen);
    let ep = |proto: &str| {
        let a = serve.endpoint(proto, "addr").expect(proto);
        a.rsplit_once(':').unwrap().1.to_string()
    };
    let file = tmp.path().join("UR.toml");
    std::fs::write(
        &file,
        format!(
            "[[device]]\nname = \"ur5e\"\nrole = \"arm\"\nvendor = \"universal-robots\"\n\
             protocol = \"rtde\"\nmodel = \"ur5e\"\naddress = \"127.0.0.1\"\nports = {{ rtde = {}, \
             dashboard = {}, script = {} }}\n",
            ep("rtde"),
            ep("dashboard"),
            ep("script")
        ),
    )
    .unwrap();
    let out = tmp.path().join("poses.csv");
    let args = [
        "capture",
        "poses",
        "--devices",
        s(&file),
        "--count",
        "3",
        "--out",
        s(&out),
        "--max-seconds",
        "40",
    ];
    let (code, _, err) = run(&args);
    assert_eq!(code, Some(1));
    assert!(err.contains("add --live"), "{err}");
    let mut live = args.to_vec();
    live.extend(["--live", "--yes"]);
    let (code, _, err) = run(&live);
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("freedrive_mode()"), "{err}");
    check(&out, &ur_poses, "UR5e, freedrive");
}
