//! Kinematic model: golden FK vectors, exact chain → MDH + Hayati conversion, analytic
//! Jacobians vs finite differences, IK round trips, calibration-parameter round trips.
use std::path::PathBuf;

use nalgebra::{DVector, Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;
use robocal::dataset::{ChainJoint, FixedOrigin, RobotBlock};
use robocal::model::{
    pose_distance, IkError, KinematicModel, ModelError, ParamGroup, SerialChain, Unit,
};
use serde_json::Map;

fn data(p: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(p)
}

/// (q rad, flange pose) rows of a golden file.
fn golden(preset: &str) -> Vec<(Vec<f64>, Isometry3<f64>)> {
    let mut r = csv::Reader::from_path(data(&format!("golden/fk-{preset}.csv"))).unwrap();
    r.records()
        .map(|rec| {
            let v: Vec<f64> = rec.unwrap().iter().map(|s| s.parse().unwrap()).collect();
            let q = v[0..6].iter().map(|d| d.to_radians()).collect();
            let t = Translation3::new(v[6], v[7], v[8]);
            let rq =
                UnitQuaternion::from_quaternion(Quaternion::new(v[9], v[10], v[11], v[12]));
            (q, Isometry3::from_parts(t, rq))
        })
        .collect()
}

/// Max (mm, rad) deviation of a preset from its golden file.
fn golden_dev(preset: &str) -> (f64, f64, usize) {
    let m = KinematicModel::preset(preset).unwrap();
    let rows = golden(preset);
    let mut worst = (0.0f64, 0.0f64);
    for (q, pose) in &rows {
        let (dp, dr) = pose_distance(&m.flange_pose(q), pose);
        worst.0 = worst.0.max(dp);
        worst.1 = worst.1.max(dr);
    }
    (worst.0, worst.1, rows.len())
}

#[test]
fn golden_vs060() {
    let (dp, dr, n) = golden_dev("denso-vs060");
    assert_eq!(n, 200);
    // files carry 6 decimals: 1e-6 mm and quaternion rounding (≤ ~2e-6 rad)
    assert!(dp <= 1e-6 + 1e-9, "vs060 golden position deviation {dp} mm");
    assert!(dr <= 3e-6, "vs060 golden rotation deviation {dr} rad");
}

#[test]
fn golden_ur5e() {
    let (dp, dr, n) = golden_dev("ur5e");
    assert_eq!(n, 200);
    assert!(dp <= 1e-6 + 1e-9, "ur5e golden position deviation {dp} mm");
    assert!(dr <= 3e-6, "ur5e golden rotation deviation {dr} rad");
}

#[test]
fn golden_ur10e() {
    let (dp, dr, n) = golden_dev("ur10e");
    assert_eq!(n, 200);
    assert!(dp <= 1e-6 + 1e-9, "ur10e golden position deviation {dp} mm");
    assert!(dr <= 3e-6, "ur10e golden rotation deviation {dr} rad");
}
