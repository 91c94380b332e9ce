//! Issue 20: RCM hand-eye calibration on the simulated RCM cell (truth in `robocal_mocks::rcm`).
use std::process::Command;

use nalgebra::{Isometry3, Translation3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use robocal::dataset::endoscope::EndoscopeCamera;
use robocal::dataset::{CalibrationFile, Dataset};
use robocal::model::KinematicModel;
use robocal::plan::rcm::{generate, RcmPlanSpec};
use robocal::solve::rcm::{self, RcmData, RcmError, RcmObs};
use robocal_mocks::rcm::{RcmCell, RcmScenario};

pub(crate) fn cell() -> RcmCell {
    RcmCell::new(RcmScenario::builtin())
}

fn spec(cell: &RcmCell, pivot: f64, n: usize, seed: u64) -> RcmPlanSpec {
    RcmPlanSpec {
        trocar_mm: cell.scenario.trocar_mm,
        insertion_dir: cell.scenario.insertion_dir,
        x_hint: [0.0, 1.0, 0.0],
        pivot_deg: pivot,
        insertion_mm: [50.0, 150.0],
        roll_deg: 10.0,
        count: n,
        seed,
        shaft_length_mm: 350.0,
    }
}

fn camera(cell: &RcmCell) -> EndoscopeCamera {
    let c = &cell.scenario.camera;
    EndoscopeCamera {
        kind: "endoscope".into(),
        width: c.width,
        height: c.height,
        fx: c.fx,
        fy: c.fy,
        cx: c.cx,
        cy: c.cy,
        dist: c.dist,
    }
}

/// Observations of the instrument poses `poses` (true = reported), noise `sigma` px.
fn observe(cell: &RcmCell, poses: &[Isometry3<f64>], sigma: f64, seed: u64) -> RcmData {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let obs = poses
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let v = cell.view_noisy(p, Some(sigma), &mut rng)?;
            Some(RcmObs {
                id: i as u64 + 1,
                line: i + 2,
                flange: *p,
                segs: v.shaft_lines,
            })
        })
        .collect();
    RcmData::new(camera(cell), cell.scenario.instrument.shaft_radius_mm, obs)
}

pub(crate) fn planned(cell: &RcmCell, pivot: f64, n: usize) -> Vec<Isometry3<f64>> {
    let m = KinematicModel::preset("ur5e").unwrap();
    generate(&spec(cell, pivot, n, 3), Some(&m))
        .unwrap()
        .into_iter()
        .map(|p| p.instrument)
        .collect()
}

#[test]
fn clean_world_recovers_the_true_camera_pose() {
    let cell = cell();
    let poses = planned(&cell, 25.0, 15);
    let data = observe(&cell, &poses, 0.0, 1);
    assert!(
        data.obs.len() >= 12,
        "only {} poses visible",
        data.obs.len()
    );
    let r = rcm::calibrate(
        &data,
        &rcm::RcmOptions {
            bootstrap: 0,
            seed: 0,
        },
    )
    .unwrap();
    let (st, sr) = rcm::pose_error(&r.seed.hand_eye, &cell.camera);
    let (mt, mr) = rcm::pose_error(&r.ml.pose, &cell.camera);
    println!(
        "clean: seed {st:.2e} mm {sr:.2e} deg; ML {mt:.2e} mm {mr:.2e} deg; rms {:.2e} px",
        r.ml.rms_px
    );
    assert!(st < 1e-3 && sr < 1e-4, "seed two-step: {st} mm {sr} deg");
    assert!(mt < 1e-6 && mr < 1e-7, "ML: {mt} mm {mr} deg");
    let trocar = Vector3::from(cell.scenario.trocar_mm);
    assert!((r.rcm_base.0 - trocar).norm() < 1e-6);
}

#[test]
fn noisy_world_error_is_within_the_reported_uncertainty() {
    let cell = cell();
    let poses = planned(&cell, 25.0, 20);
    let data = observe(&cell, &poses, 0.5, 2);
    let r = rcm::calibrate(
        &data,
        &rcm::RcmOptions {
            bootstrap: 30,
            seed: 1,
        },
    )
    .unwrap();
    let d = r.ml.pose.translation.vector - cell.camera.translation.vector;
    let b = r.bootstrap.unwrap();
    println!(
        "0.5 px: ML error ({:.3}, {:.3}, {:.3}) mm, cov σ {:?} mm, bootstrap σ {:?} mm, rms {:.3} px",
        d.x, d.y, d.z, r.std.xyz_mm, b.xyz_mm, r.ml.rms_px
    );
    for k in 0..3 {
        assert!(
            d[k].abs() < 5.0 * r.std.xyz_mm[k] + 1e-3,
            "axis {k}: {} vs σ {}",
            d[k],
            r.std.xyz_mm[k]
        );
        // Bootstrap and covariance agree within a factor 3.
        assert!(b.xyz_mm[k] < 3.0 * r.std.xyz_mm[k] && r.std.xyz_mm[k] < 3.0 * b.xyz_mm[k]);
    }
    assert!((r.ml.rms_px - 0.5).abs() < 0.2, "rms {}", r.ml.rms_px);
}

#[test]
fn degenerate_inputs_are_clear_errors() {
    let cell = cell();
    let poses = planned(&cell, 25.0, 10);
    // Fewer than 3 poses.
    let d = observe(&cell, &poses[..2], 0.0, 3);
    let e = rcm::calibrate(&d, &Default::default()).unwrap_err();
    assert!(matches!(e, RcmError::TooFew { got: 2 }), "{e}");
    // All axes in one plane: pivot about a single axis.
    let s = spec(&cell, 25.0, 8, 1);
    let flat: Vec<Isometry3<f64>> = (0..8)
        .map(|i| {
            robocal::plan::rcm::rcm_pose(&s, (-20.0 + 5.0 * i as f64).to_radians(), 0.0, 100.0, 0.0)
        })
        .collect();
    let e = rcm::calibrate(&observe(&cell, &flat, 0.0, 4), &Default::default()).unwrap_err();
    assert!(e.to_string().contains("one plane"), "{e}");
    // Axes not meeting: the robot's instrument poses do not pivot about one point.
    let shifted: Vec<Isometry3<f64>> = poses
        .iter()
        .enumerate()
        .map(|(i, p)| Translation3::new(3.0 * i as f64, -2.0 * i as f64, 0.0) * p)
        .collect();
    let mut d = observe(&cell, &poses, 0.0, 5);
    for (o, s) in d.obs.iter_mut().zip(&shifted) {
        o.flange = *s;
    }
    let e = rcm::calibrate(&d, &Default::default()).unwrap_err();
    assert!(e.to_string().contains("do not meet"), "{e}");
    // Parallel axes (no pivot at all).
    let same = vec![poses[0]; 5];
    let e = rcm::calibrate(&observe(&cell, &same, 0.0, 6), &Default::default()).unwrap_err();
    assert!(e.to_string().contains("parallel"), "{e}");
    // Coincident boundary lines in one pose.
    let mut d = observe(&cell, &poses, 0.0, 7);
    d.obs[1].segs[1] = d.obs[1].segs[0];
    let e = rcm::calibrate(&d, &Default::default()).unwrap_err();
    assert!(
        e.to_string().contains("coincide") && e.to_string().contains("pose 2"),
        "{e}"
    );
}

#[test]
fn cli_writes_a_calibration_that_loads_and_matches_the_truth() {
    let cell = cell();
    let poses = planned(&cell, 25.0, 15);
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let views: Vec<_> = poses
        .iter()
        .filter_map(|p| Some((*p, cell.view_noisy(p, Some(0.2), &mut rng)?)))
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("rcm.jsonl");
    std::fs::write(&data, cell.dataset_jsonl(&views)).unwrap();
    let out = dir.path().join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_robocal"))
        .args(["calibrate", "rcm", "--bootstrap", "10", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    println!("{}", String::from_utf8_lossy(&o.stdout));
    let cal = CalibrationFile::load(out.join("calibration.json")).unwrap();
    let cam: robocal::dataset::endoscope::CameraCal =
        serde_json::from_value(cal.extra["camera"].clone()).unwrap();
    assert_eq!(cam.hand_eye.mount, "base");
    let t = Vector3::from(cam.hand_eye.xyz_mm);
    let err = (t - cell.camera.translation.vector).norm();
    assert!(err < 1.0, "hand-eye translation error {err} mm");
    assert!(out.join("rcm_report.json").exists());
    // A malformed record names file, line and field.
    let text = std::fs::read_to_string(&data).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    lines[3] = lines[3].replace("\"shaft_lines\":[[", "\"shaft_lines\":[[\"x\",");
    let bad = dir.path().join("bad.jsonl");
    std::fs::write(&bad, lines.join("\n") + "\n").unwrap();
    let ds = Dataset::load(&bad).unwrap();
    let e = RcmData::from_dataset(&ds, &bad).unwrap_err().to_string();
    assert!(
        e.contains("bad.jsonl:4") && e.contains("shaft_lines"),
        "{e}"
    );
}
