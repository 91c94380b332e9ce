//! `robocal correct` (desired tool poses → corrected joints, CSV / URScript / PacScript) and
//! `robocal calibrate tool` (tool + base with the identified arm fixed, bootstrap std), run
//! through the binary on a UR5e whose arm differs from nominal.
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use robocal::dataset::{CalibrationFile, RobotBlock};
use robocal::model::KinematicModel;

use super::pivot::robocal_status as robocal;

/// The "true" arm: nominal UR5e with a few tenths of a mm / degree changed, a marker tool.
fn arm() -> KinematicModel {
    let mut m = KinematicModel::preset("ur5e").unwrap();
    for (n, dv) in [("phi2", 0.004), ("a3", 0.6), ("d4", -0.4), ("phi5", -0.003)] {
        let v = m.params().iter().find(|p| p.name == n).unwrap().value;
        m.set_param(n, v + dv).unwrap();
    }
    m.set_tool(&Isometry3::from_parts(
        Translation3::new(5.0, -3.0, 120.0),
        UnitQuaternion::from_euler_angles(0.1, -0.05, 0.3),
    ));
    m.set_base(&Isometry3::from_parts(
        Translation3::new(300.0, -200.0, -1500.0),
        UnitQuaternion::from_euler_angles(3.0, 0.1, -0.4),
    ));
    m
}

fn robot() -> RobotBlock {
    RobotBlock::named("ur5e")
}

fn save_cal(dir: &Path, m: &KinematicModel) -> PathBuf {
    let p = dir.join("cal.json");
    robocal::solve::calfile::kinematic_file(&robot(), m)
        .save(&p)
        .unwrap();
    p
}

fn joints(rng: &mut ChaCha8Rng) -> Vec<f64> {
    vec![
        rng.random_range(-1.0..1.0),
        rng.random_range(-2.0..-1.0),
        rng.random_range(0.8..1.8),
        rng.random_range(-2.0..-1.0),
        rng.random_range(-2.0..-1.0),
        rng.random_range(-1.0..1.0),
    ]
}

/// `robocal correct --calibration CAL --targets T` and `extra` options.
fn correct(cal: &Path, targets: &Path, extra: &[&str]) -> (bool, String) {
    let mut a = vec![
        "correct",
        "--calibration",
        cal.to_str().unwrap(),
        "--targets",
        targets.to_str().unwrap(),
    ];
    a.extend_from_slice(extra);
    robocal(&a)
}

#[test]
fn corrected_joints_reach_the_desired_poses_and_scripts_carry_them() {
    let d = tempfile::tempdir().unwrap();
    let m = arm();
    let cal = save_cal(d.path(), &m);
    let mut rng = ChaCha8Rng::seed_from_u64(30);
    let mut csv = String::from("name,x_mm,y_mm,z_mm,qw,qx,qy,qz\n");
    let mut want = Vec::new();
    for i in 0..5 {
        let t = m.tool_pose_in_base(&joints(&mut rng));
        let (p, q) = (t.translation.vector, t.rotation.quaternion());
        csv.push_str(&format!(
            "T{i},{},{},{},{},{},{},{}\n",
            p.x, p.y, p.z, q.w, q.i, q.j, q.k
        ));
        want.push(t);
    }
    let targets = d.path().join("targets.csv");
    std::fs::write(&targets, csv).unwrap();
    let out = d.path().join("corrected.csv");
    let (ok, text) = correct(&cal, &targets, &["--out", out.to_str().unwrap()]);
    assert!(ok, "{text}");
    assert!(text.contains("nominal command would miss"), "{text}");
    let mut rd = csv::Reader::from_path(&out).unwrap();
    let head = rd.headers().unwrap().clone();
    let col = |n: &str| head.iter().position(|h| h == n).unwrap();
    let mut rows = 0;
    for r in rd.records() {
        let r = r.unwrap();
        let i: usize = r[col("name")][1..].parse().unwrap();
        let q: Vec<f64> = (1..=6)
            .map(|k| {
                r[col(&format!("q{k}_deg"))]
                    .parse::<f64>()
                    .unwrap()
                    .to_radians()
            })
            .collect();
        let got = m.tool_pose_in_base(&q);
        let e = (got.translation.vector - want[i].translation.vector).norm();
        assert!(e < 1e-3, "target {i}: {e} mm");
        let miss: f64 = r[col("nominal_pos_err_mm")].parse().unwrap();
        assert!(miss > 0.1 && miss < 10.0, "{miss}");
        rows += 1;
    }
    assert!(rows >= 5, "{rows}");
    for (fmt, needle) in [("urscript", "movej(["), ("pacscript", "Move P, J(")] {
        let p = d.path().join(fmt);
        let (ok, text) = correct(
            &cal,
            &targets,
            &["--format", fmt, "--out", p.to_str().unwrap()],
        );
        assert!(ok, "{text}");
        let s = std::fs::read_to_string(&p).unwrap();
        assert_eq!(s.matches(needle).count(), rows, "{s}");
    }
    // A target in metres is refused with its line and field.
    std::fs::write(
        &targets,
        "name,x_mm,y_mm,z_mm,qw,qx,qy,qz\nA,0.4,0.1,0.3,1,0,0,2\n",
    )
    .unwrap();
    let (ok, text) = correct(&cal, &targets, &[]);
    assert!(
        !ok && text.contains("targets.csv:2") && text.contains("qw"),
        "{text}"
    );
}

#[test]
fn tool_with_the_identified_arm_recovers_tool_and_base_within_their_std() {
    let d = tempfile::tempdir().unwrap();
    let truth = arm();
    // The identified arm as the first step gave it: right arm, tool and base unknown.
    let mut first = truth.clone();
    first.set_tool(&Isometry3::translation(0.0, 0.0, 100.0));
    first.set_base(&Isometry3::identity());
    let cal = save_cal(d.path(), &first);
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    let nz = Normal::new(0.0, 0.05).unwrap();
    let mut s =
        String::from("{\"format\": \"robocal-dataset/1\", \"robot\": {\"model\": \"ur5e\"}}\n");
    for i in 0..40 {
        let q = joints(&mut rng);
        let m = truth.measured_pose(&q);
        let p = m.translation.vector + Vector3::from_fn(|_, _| nz.sample(&mut rng));
        let r = m.rotation
            * UnitQuaternion::from_scaled_axis(Vector3::from_fn(|_, _| {
                1e-4 * nz.sample(&mut rng) / 0.05
            }));
        let qd: Vec<f64> = q.iter().map(|x| x.to_degrees()).collect();
        let rq = r.quaternion();
        s.push_str(&format!(
            "{{\"kind\": \"pose\", \"id\": {i}, \"t\": {}, \"q\": {:?}, \"marker\": {{\"p\": [{}, {}, {}], \"quat\": [{}, {}, {}, {}], \"visible\": true}}}}\n",
            i as f64 * 5.0, qd, p.x, p.y, p.z, rq.w, rq.i, rq.j, rq.k
        ));
    }
    let data = d.path().join("tool.jsonl");
    std::fs::write(&data, s).unwrap();
    let out = d.path().join("out");
    let tool = |extra: &[&str]| {
        let mut a = vec!["calibrate", "tool", "--arm", cal.to_str().unwrap()];
        a.extend_from_slice(&["--data", data.to_str().unwrap()]);
        a.extend_from_slice(extra);
        robocal(&a)
    };
    let (ok, text) = tool(&["--out", out.to_str().unwrap(), "--bootstrap", "40"]);
    assert!(ok, "{text}");
    let f = CalibrationFile::load(out.join("calibration.json")).unwrap();
    let tt = truth.tool().translation.vector;
    for (n, v) in [("tool_x", tt.x), ("tool_y", tt.y), ("tool_z", tt.z)] {
        let p = f.param(n).unwrap_or_else(|| panic!("no {n}"));
        let sd = p.std.unwrap();
        assert!(sd > 0.0 && sd < 0.2, "{n}: std {sd}");
        assert!(
            (p.value - v).abs() < 5.0 * sd + 0.01,
            "{n}: {} vs {v} (std {sd})",
            p.value
        );
    }
    // Position only (no orientation): refused with the reason.
    let s = std::fs::read_to_string(&data).unwrap();
    let stripped: String = s
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            let mut v = v;
            if let Some(m) = v.get_mut("marker").and_then(|m| m.as_object_mut()) {
                m.remove("quat");
            }
            v.to_string() + "\n"
        })
        .collect();
    std::fs::write(&data, stripped).unwrap();
    let (ok, text) = tool(&[]);
    assert!(!ok && text.contains("orientation"), "{text}");
}
