//! `robocal predict` with the `calibration.json` a kinematic diagnosis wrote reproduces every
//! figure the diagnosis reports (issue 26 §9), one simulated world per kinematic effect kind
//! (the worlds of `examples/diagnose_table.rs`): the files are synthesised by the
//! independent world (`robocal_mocks`), `robocal diagnose` names the kind, and `robocal
//! predict` on the held-out file alone gives the diagnosis' own held-out predictions
//! (`heldout_predictions.csv`) and its held-out RMS (`heldout_rms.final_mm`).
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use robocal::dataset::PoseRecord;
use robocal::model::KinematicModel;
use robocal::schema::DiagnosisFile;
use robocal::solve::obs::session_observations;
use robocal_mocks::synth::{synthesize, SynthConfig};
use robocal_mocks::WorldHandle;

use crate::common::{cli, s};
use crate::diagnose::table;

/// `id → point` of a CSV `id,x_mm,y_mm,z_mm`.
pub(crate) fn points(path: &Path) -> Vec<(u64, [f64; 3])> {
    let mut rd = csv::Reader::from_path(path).unwrap();
    rd.records()
        .map(|r| {
            let r = r.unwrap();
            let f = |i: usize| r[i].parse::<f64>().unwrap();
            (r[0].parse().unwrap(), [f(1), f(2), f(3)])
        })
        .collect()
}

/// Synthesises `w` (the table's small size, one frame per pose) into `dir/train.jsonl` and
/// `dir/heldout.jsonl` (the world's stripped fields left out).
pub(crate) fn synth_files(w: &table::World, seed: u64, dir: &Path) -> (PathBuf, PathBuf) {
    let wh = WorldHandle::from_scenario(&table::scenario(w, seed)).unwrap();
    let cfg = SynthConfig {
        n_train: table::SMALL.n_train,
        n_heldout: table::SMALL.n_heldout,
        seed,
        frames_per_pose: 1,
        ..SynthConfig::default()
    };
    let syn = synthesize(&wh, &cfg).unwrap();
    let (train, held) = (dir.join("train.jsonl"), dir.join("heldout.jsonl"));
    std::fs::write(&train, table::strip(&syn.train_jsonl, w.strip)).unwrap();
    std::fs::write(&held, table::strip(&syn.heldout_jsonl, w.strip)).unwrap();
    (train, held)
}

/// Synthesise the world named `world` (a prefix of a `table::worlds()` name), diagnose it
/// through the command line, predict its held-out file with the written calibration and
/// compare with what the diagnosis reported. `kind` must be among the effects found.
/// `session`: give `robocal predict` the training file as the session's other records
/// (`--session`), as the diagnosis had them (records without `q_prev`).
fn check(world: &str, kind: &str, session: bool) {
    let w = table::worlds()
        .into_iter()
        .find(|w| w.name.starts_with(world))
        .unwrap_or_else(|| panic!("no world {world}"));
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let (train, held) = synth_files(&w, 1, dir);
    let out = dir.join("diag");
    let args = robocal::diagnose::stage::DiagnoseRequest {
        data: train.clone(),
        out: out.clone(),
        calibration: None,
        heldout: Some(held.clone()),
        no_nonparametric: false,
        physics_first: false,
        kernel_benchmark: false,
    };
    let summary = robocal::diagnose::stage::run(&args).unwrap();
    let d: DiagnosisFile = robocal::schema::read(&out.join("diagnosis.json")).unwrap();
    let kinds: Vec<&str> = d.effects.iter().map(|e| e.kind.as_str()).collect();
    assert!(
        kinds.contains(&kind),
        "{world}: {kind} not found in {kinds:?}\n{summary}"
    );
    let pred = dir.join("pred.csv");
    let cal = out.join("calibration.json");
    let mut argv = vec![
        "predict",
        "--calibration",
        s(&cal),
        "--data",
        s(&held),
        "--out",
        s(&pred),
    ];
    if session {
        argv.extend(["--session", s(&train)]);
    }
    assert_eq!(cli(&argv), 0, "{world}: predict");
    let got = points(&pred);
    let written: HashMap<u64, [f64; 3]> = points(&out.join("heldout_predictions.csv"))
        .into_iter()
        .collect();
    // 1. The same prediction of every held-out pose as the diagnosis' own.
    let mut worst = 0.0f64;
    for (id, p) in &got {
        let w = written
            .get(id)
            .unwrap_or_else(|| panic!("{world}: pose {id} not in heldout_predictions.csv"));
        let e = ((p[0] - w[0]).powi(2) + (p[1] - w[1]).powi(2) + (p[2] - w[2]).powi(2)).sqrt();
        worst = worst.max(e);
    }
    assert_eq!(
        got.len(),
        written.len(),
        "{world}: one row per held-out pose"
    );
    // 2. The same held-out RMS against the measurements (the ambiguous poses of a change
    // point left out, as the diagnosis does).
    let ds = |p: &Path| robocal::dataset::read_dataset(p).unwrap().dataset;
    let (tr, he) = (ds(&train), ds(&held));
    let dof = KinematicModel::from_robot_block(&tr.header.robot)
        .unwrap()
        .dof();
    let session: Vec<&PoseRecord> = tr.poses().chain(he.poses()).collect();
    let her: Vec<&PoseRecord> = he.poses().collect();
    let obs = session_observations(&her, &session, dof).0;
    let amb: HashSet<u64> = d.ambiguous_heldout.iter().map(|a| a.id).collect();
    let by_id: HashMap<u64, [f64; 3]> = got.iter().copied().collect();
    let (mut ss, mut n) = (0.0, 0usize);
    for o in obs.iter().filter(|o| !amb.contains(&o.ctx.id)) {
        let p = by_id[&o.ctx.id];
        ss += (p[0] - o.p.x).powi(2) + (p[1] - o.p.y).powi(2) + (p[2] - o.p.z).powi(2);
        n += 1;
    }
    let rms = (ss / n as f64).sqrt();
    let reported = d.heldout_rms.final_mm.unwrap();
    eprintln!(
        "{world}: found {kinds:?} (nonparametric {}); predict vs the diagnosis' held-out \
         predictions: max {worst:.2e} mm; held-out RMS predict {rms:.5} mm, diagnosis \
         {reported:.5} mm ({n} poses)",
        d.nonparametric_used
    );
    assert!(
        worst < 1e-5,
        "{world}: predict differs from the diagnosis by {worst} mm"
    );
    assert_eq!(n, d.n_heldout, "{world}: the poses the diagnosis scored");
    assert!(
        (rms - reported).abs() < 1e-5,
        "{world}: predict {rms} mm vs the diagnosis' {reported} mm"
    );
}

#[test]
fn predict_reproduces_joint_compliance() {
    check("compliance j2", "joint_compliance", false);
}

#[test]
fn predict_reproduces_backlash() {
    check("backlash j4", "backlash", false);
}

#[test]
fn predict_reproduces_backlash_without_q_prev() {
    check("backlash j4 (no q_prev)", "backlash", true);
}

#[test]
fn predict_reproduces_joint_eccentricity() {
    check("eccentricity j1", "joint_eccentricity", false);
}

#[test]
fn predict_reproduces_temperature_drift() {
    check("thermal warm-up (temp_c)", "temperature_drift", false);
}

#[test]
fn predict_reproduces_thermal_drift() {
    check("thermal warm-up (time only)", "thermal_drift", false);
}

#[test]
fn predict_reproduces_transmission_ratio() {
    check("transmission j2", "transmission_ratio", false);
}

#[test]
fn predict_reproduces_base_shift() {
    check("base shift", "base_shift", false);
}

#[test]
fn predict_reproduces_link_deflection() {
    check("link deflection j3", "link_deflection", false);
}
