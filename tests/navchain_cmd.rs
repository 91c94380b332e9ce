//! `robocal calibrate navchain` (issue 29 §3): seed 003's 6–n–6 correction network trained
//! on what a kinematic calibration leaves, stored in the calibration file, applied by
//! `robocal predict`, and compared on the same held-out poses with the physical diagnosis.
//! The files are synthesised by the independent world (`robocal_mocks`); the held-out
//! figures are against the measurements (noise included), as a user would score them.
use std::collections::HashMap;
use std::path::Path;

use robocal::dataset::{CalibrationFile, PoseRecord};
use robocal::model::KinematicModel;
use robocal::solve::obs::session_observations;

use crate::common::{cli, s};
use crate::diagnose::table;

/// Held-out RMS (mm) of `robocal predict --calibration cal --data held --session train`
/// against the held-out measurements, and the number of poses scored.
pub(crate) fn predicted_rms(cal: &Path, train: &Path, held: &Path, out: &Path) -> (f64, usize) {
    let code = cli(&[
        "predict",
        "--calibration",
        s(cal),
        "--data",
        s(held),
        "--session",
        s(train),
        "--out",
        s(out),
    ]);
    assert_eq!(code, 0, "predict with {}", cal.display());
    let got: HashMap<u64, [f64; 3]> = crate::diagnose_predict::points(out).into_iter().collect();
    let ds = |p: &Path| robocal::dataset::read_dataset(p).unwrap().dataset;
    let (tr, he) = (ds(train), ds(held));
    let dof = KinematicModel::from_robot_block(&tr.header.robot)
        .unwrap()
        .dof();
    let her: Vec<&PoseRecord> = he.poses().collect();
    let session: Vec<&PoseRecord> = her.iter().copied().chain(tr.poses()).collect();
    let obs = session_observations(&her, &session, dof).0;
    let (mut ss, mut n) = (0.0, 0usize);
    for o in &obs {
        let p = got[&o.ctx.id];
        ss += (p[0] - o.p.x).powi(2) + (p[1] - o.p.y).powi(2) + (p[2] - o.p.z).powi(2);
        n += 1;
    }
    ((ss / n.max(1) as f64).sqrt(), n)
}

#[test]
fn navchain_network_trains_stores_predicts_and_is_compared_with_the_diagnosis() {
    let w = table::worlds()
        .into_iter()
        .find(|w| w.name.starts_with("compliance j2"))
        .expect("a compliance j2 world");
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let (train, held) = crate::diagnose_predict::synth_files(&w, 3, dir);
    // 1. The geometric calibration the network corrects.
    let geo = dir.join("geo");
    assert_eq!(
        cli(&[
            "calibrate",
            "kinematics",
            "--data",
            s(&train),
            "--out",
            s(&geo)
        ]),
        0
    );
    // 2. The network on top of it (trained on the training file only).
    let nn = dir.join("nn");
    assert_eq!(
        cli(&[
            "calibrate",
            "navchain",
            "--calibration",
            s(&geo.join("calibration.json")),
            "--data",
            s(&train),
            "--heldout",
            s(&held),
            "--epochs",
            "1500",
            "--out",
            s(&nn),
        ]),
        0
    );
    // 3. It loads back, typed, and `predict` applies it: the held-out RMS of `predict`
    // is the one the command stored.
    let cal = CalibrationFile::load(nn.join("calibration.json")).unwrap();
    let block = robocal::navchain::correction::from_calibration(&cal)
        .unwrap()
        .expect("a navchain_net block");
    let (geo_rms, n) = predicted_rms(
        &geo.join("calibration.json"),
        &train,
        &held,
        &dir.join("geo.csv"),
    );
    let (nn_rms, n2) = predicted_rms(
        &nn.join("calibration.json"),
        &train,
        &held,
        &dir.join("nn.csv"),
    );
    assert_eq!((n, n2), (n, block.heldout_poses.unwrap()));
    assert!(
        (block.heldout_rms_mm_before.unwrap() - geo_rms).abs() < 1e-5
            && (block.heldout_rms_mm_after.unwrap() - nn_rms).abs() < 1e-5,
        "stored {:?} → {:?}, predict {geo_rms} → {nn_rms}",
        block.heldout_rms_mm_before,
        block.heldout_rms_mm_after
    );
    // 4. The physical diagnosis on the same training file, scored on the same poses.
    let diag = dir.join("diag");
    let req = robocal::diagnose::stage::DiagnoseRequest {
        data: train.clone(),
        out: diag.clone(),
        calibration: None,
        heldout: Some(held.clone()),
        no_nonparametric: false,
        physics_first: false,
        kernel_benchmark: false,
        no_transmission_map: false,
        geometric_prior: None,
        no_geometric_prior: false,
    };
    robocal::diagnose::stage::run(&req).unwrap();
    let (phys_rms, _) = predicted_rms(
        &diag.join("calibration.json"),
        &train,
        &held,
        &dir.join("diag.csv"),
    );
    let d: robocal::schema::DiagnosisFile =
        robocal::schema::read(&diag.join("diagnosis.json")).unwrap();
    let kinds: Vec<&str> = d.effects.iter().map(|e| e.kind.as_str()).collect();
    println!(
        "navchain on `{}` ({n} held-out poses, vs measurements): geometric {geo_rms:.4} mm, seed \
         003 network {nn_rms:.4} mm (training {:.4} → {:.4} mm), physical diagnosis {kinds:?} \
         {phys_rms:.4} mm",
        w.name, block.train_rms_mm_before, block.train_rms_mm_after
    );
    // The network helps on held-out poses (the compliance residual is smooth in the pose).
    assert!(nn_rms < geo_rms, "network {nn_rms} vs geometric {geo_rms}");
    // 5. A damaged block is refused with the field named, not applied.
    let text = std::fs::read_to_string(nn.join("calibration.json")).unwrap();
    let bad = dir.join("bad.json");
    std::fs::write(
        &bad,
        text.replace("\"robocal-navchain-net/1\"", "\"robocal-navchain-net/9\""),
    )
    .unwrap();
    let err = robocal::solve::predict::predict_files(&bad, &held).unwrap_err();
    assert!(format!("{err:#}").contains("navchain_net"), "{err:#}");
}
