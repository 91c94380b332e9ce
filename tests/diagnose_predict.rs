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
use robocal_mocks::scenario::Scenario;
use robocal_mocks::synth::{synthesize, SynthConfig};
use robocal_mocks::world::gear::{Coupling, NonlinearCompliance, Ripple, WaveGenerator};
use robocal_mocks::WorldHandle;

use crate::common::{cli, predict_cli, s};
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
    synth_files_with(w, seed, dir, None)
}

/// [`synth_files`], measuring on the fly at the fraction `in_motion` of each move when given
/// (the records carry `qd`).
fn synth_files_with(
    w: &table::World,
    seed: u64,
    dir: &Path,
    in_motion: Option<f64>,
) -> (PathBuf, PathBuf) {
    let wh = WorldHandle::from_scenario(&table::scenario(w, seed)).unwrap();
    let cfg = SynthConfig {
        n_train: table::SMALL.n_train,
        n_heldout: table::SMALL.n_heldout,
        seed,
        frames_per_pose: 1,
        in_motion,
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
    check_world(&w, Some(kind), session, None);
}

/// [`check`] on the world `w` (`kind`: None = no effect expected to be named; `in_motion`:
/// see [`synth_files_with`]); returns the diagnosis and the directory its files are in
/// (`train.jsonl`, `heldout.jsonl`, `diag/`, `pred.csv`; kept while the `TempDir` lives).
fn check_world(
    w: &table::World,
    kind: Option<&str>,
    session: bool,
    in_motion: Option<f64>,
) -> (DiagnosisFile, tempfile::TempDir) {
    let world = w.name;
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let (train, held) = synth_files_with(w, 1, dir, in_motion);
    let out = dir.join("diag");
    let args = robocal::diagnose::stage::DiagnoseRequest {
        data: train.clone(),
        out: out.clone(),
        calibration: None,
        heldout: Some(held.clone()),
        no_nonparametric: false,
        physics_first: false,
        kernel_benchmark: false,
        no_transmission_map: false,
        geometric_prior: None,
        no_geometric_prior: false,
    };
    let summary = robocal::diagnose::stage::run(&args).unwrap();
    let d: DiagnosisFile = robocal::schema::read(&out.join("diagnosis.json")).unwrap();
    let kinds: Vec<&str> = d.effects.iter().map(|e| e.kind.as_str()).collect();
    if let Some(kind) = kind {
        let why: Vec<String> = d
            .untestable
            .iter()
            .filter(|u| u.effect.contains(kind))
            .map(|u| format!("untestable: {}", u.reason))
            .chain(
                d.not_identifiable
                    .iter()
                    .filter(|e| e.kind == kind)
                    .map(|e| format!("not identifiable: {}", e.candidate)),
            )
            .collect();
        assert!(
            kinds.contains(&kind),
            "{world}: {kind} not found in {kinds:?} ({why:?})\n{summary}"
        );
    }
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
    let written: HashMap<u64, [f64; 3]> = points(&out.join("heldout_predictions.csv"))
        .into_iter()
        .collect();
    // Predict writes a row for every pose record; the diagnosis scores the usable ones (a
    // record measured on the fly may have lost the marker).
    let got: Vec<(u64, [f64; 3])> = points(&pred)
        .into_iter()
        .filter(|(id, _)| written.contains_key(id))
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
    (d, tmp)
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

// ------------------------------------------------------------------ worlds beyond the table
// The effects the diagnosis table does not sweep, each hidden in the independent world
// (`robocal_mocks::world::gear`, the tracker's latency and depth scale): the world computes
// its truth with its own physics (amplitude and phase), never with robocal's effect models.

/// A world of this file: `name` and what it hides (the table's noise and seed handling).
fn world(name: &'static str, effects: fn(&mut Scenario)) -> table::World {
    table::World {
        name,
        expect: vec![],
        outside_library: false,
        absorbed: false,
        effects,
        strip: table::STRIP,
        library_without: &[],
    }
}

/// Joint 4 turns ±180°: a 9-cycle ripple is sampled over many of its periods (joint 3's
/// 100° range spans less than the one period the family needs to test a harmonic > 4).
fn ripple_j4(s: &mut Scenario) {
    s.arms[0].effects.ripple = vec![Ripple {
        joint: 4,
        harmonic: 9,
        amplitude_deg: 0.04,
        phase_deg: 30.0,
    }];
}

/// A gear error of joint 4 (which turns ±180° in these worlds) with twelve harmonics of
/// equal size (3…14 cycles per turn): more than the chain names one by one; the
/// transmission error map takes the rest.
fn gear_error_j4(s: &mut Scenario) {
    s.arms[0].effects.ripple = (3..=14)
        .map(|h| Ripple {
            joint: 4,
            harmonic: h,
            amplitude_deg: 0.012,
            phase_deg: 37.0 * f64::from(h),
        })
        .collect();
}

fn coupling_j3_q4(s: &mut Scenario) {
    s.arms[0].effects.coupling = vec![Coupling {
        joint: 3,
        driver: 4,
        harmonic: 1,
        amplitude_deg: 0.015,
        phase_deg: 40.0,
    }];
}

fn wave_generator_j2(s: &mut Scenario) {
    // The diagnosis' default gear ratio (101), the flexspline's two lobes.
    s.arms[0].effects.wave_generator = vec![WaveGenerator {
        joint: 2,
        gear_ratio: 101.0,
        harmonic: 2,
        amplitude_deg: 0.01,
        phase_deg: 10.0,
    }];
}

fn latency_3ms(s: &mut Scenario) {
    s.trackers[0].effects.latency_s = 0.003;
}

fn depth_scale(s: &mut Scenario) {
    s.trackers[0].effects.depth_scale_ppm = 1500.0;
}

fn tracker_scale(s: &mut Scenario) {
    s.trackers[0].effects.scale_ppm = 300.0;
}

/// Outside the library: joint 2's reducer twists by `c τ|τ|` (load-dependent stiffness)
/// under the gravity torque of the table's masses; the compliance family is linear in τ.
fn nonlinear_compliance_j2(s: &mut Scenario) {
    table::masses(s);
    s.arms[0].effects.nonlinear_compliance = vec![NonlinearCompliance {
        joint: 2,
        rad_per_nm2: 1e-5,
    }];
}

/// Outside the library: joint 2's error follows three cycles per turn of joint 6 (the
/// coupling family has the driver's first harmonic only).
fn coupling_j2_3q6(s: &mut Scenario) {
    s.arms[0].effects.coupling = vec![Coupling {
        joint: 2,
        driver: 6,
        harmonic: 3,
        amplitude_deg: 0.03,
        phase_deg: 20.0,
    }];
}

/// Outside the library: joint 1's error follows twice the angle of joint 4 (a hose wound
/// around the wrist).
fn coupling_j1_2q4(s: &mut Scenario) {
    s.arms[0].effects.coupling = vec![Coupling {
        joint: 1,
        driver: 4,
        harmonic: 2,
        amplitude_deg: 0.02,
        phase_deg: 20.0,
    }];
}

#[test]
fn predict_reproduces_transmission_ripple() {
    check_world(
        &world("ripple j4 ×9", ripple_j4),
        Some("transmission_ripple"),
        false,
        None,
    );
}

#[test]
fn predict_reproduces_transmission_error_map() {
    check_world(
        &world("gear error j4, 12 harmonics", gear_error_j4),
        Some("transmission_error_map"),
        false,
        None,
    );
}

#[test]
fn predict_reproduces_joint_coupling() {
    check_world(
        &world("coupling j3 ← q4", coupling_j3_q4),
        Some("joint_coupling"),
        false,
        None,
    );
}

#[test]
fn predict_reproduces_wave_generator() {
    check_world(
        &world("wave generator j2", wave_generator_j2),
        Some("wave_generator"),
        false,
        None,
    );
}

/// Measured on the fly (one frame half-way through each move, `qd` recorded) with a tracker
/// 3 ms late.
#[test]
fn predict_reproduces_latency() {
    check_world(
        &world("latency 3 ms (on the fly)", latency_3ms),
        Some("latency"),
        false,
        Some(0.5),
    );
}

/// Worlds whose effect is outside the library: predict reproduces the diagnosis on each,
/// and the diagnosis falls back on the `nonparametric` correction on at least one (where no
/// library effect mimics the residual well enough).
#[test]
fn predict_reproduces_nonparametric() {
    let mut with_correction = vec![];
    for w in [
        world(
            "nonlinear compliance j2 (outside the library)",
            nonlinear_compliance_j2,
        ),
        world("coupling j2 ← 3·q6 (outside the library)", coupling_j2_3q6),
        world("coupling j1 ← 2·q4 (outside the library)", coupling_j1_2q4),
    ] {
        let (d, _dir) = check_world(&w, None, false, None);
        if d.nonparametric_used {
            assert!(d.effects.iter().any(|e| e.kind == "nonparametric"));
            with_correction.push(w.name);
        }
    }
    eprintln!("nonparametric correction used on: {with_correction:?}");
    assert!(!with_correction.is_empty(), "no world used the correction");
}

/// A tracker effect the geometry absorbs on this data: diagnose on the world `w` does not
/// name `kind` (the report or the evidence says why), predict reproduces what the diagnosis
/// reports, and the kind is still a calibration-file effect (an independent length standard
/// or another tracker placement identifies it): predict applies the file's `params` as
/// `scaled(p)` of the prediction without it, within `tol` mm.
fn check_absorbed_tracker_effect(
    w: &table::World,
    kind: &str,
    params: serde_json::Value,
    scaled: fn([f64; 3]) -> [f64; 3],
    tol: f64,
) {
    let (d, dir) = check_world(w, None, false, None);
    let dir = dir.path();
    assert!(d.effects.iter().all(|e| e.kind != kind), "{kind} named");
    let report = std::fs::read_to_string(dir.join("diag/report.md")).unwrap();
    assert!(
        report.contains("independent length standard")
            || d.not_identifiable.iter().any(|e| e.kind == kind),
        "{kind}: the diagnosis says it is absorbed"
    );
    let cal = dir.join("diag/calibration.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&cal).unwrap()).unwrap();
    v["effects"]
        .as_array_mut()
        .unwrap()
        .push(serde_json::json!({"kind": kind, "params": params}));
    let with = dir.join("with-effect.json");
    std::fs::write(&with, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    let out = dir.join("pred-with-effect.csv");
    let held = dir.join("heldout.jsonl");
    assert_eq!(predict_cli(&with, &held, &out), 0);
    let before: HashMap<u64, [f64; 3]> = points(&dir.join("pred.csv")).into_iter().collect();
    let after = points(&out);
    assert_eq!(after.len(), before.len());
    for (id, p) in after {
        let b = scaled(before[&id]);
        for k in 0..3 {
            assert!(
                (p[k] - b[k]).abs() < tol,
                "{kind}: pose {id}: {p:?} vs {b:?} expected"
            );
        }
    }
}

/// A uniform tracker scale is collinear with the link lengths: the diagnosis reports it
/// absorbed (no length standard) and writes no `tracker_scale`; a file's `tracker_scale` is
/// applied as `y = (1 + s) p` about the tracker origin.
#[test]
fn predict_reproduces_tracker_scale() {
    check_absorbed_tracker_effect(
        &world("tracker scale 300 ppm", tracker_scale),
        "tracker_scale",
        serde_json::json!({"scale_ppm": 300.0}),
        |p| p.map(|x| x * (1.0 + 300e-6)),
        1e-5,
    );
}

/// A depth scale (the tracker's z axis) on this cell's poses: the geometry absorbs it (the
/// diagnosis lists it as not identifiable, independence < 0.1: the tracker looks along a
/// direction the link lengths and base pose can stretch); a file's `tracker_depth_scale` is
/// applied as `z' = z + s z₀` (`z₀` the geometric point's depth: the other effects' sub-mm
/// displacements are not scaled, so `(1 + s) z` holds to 1500 ppm × 1 mm).
#[test]
fn predict_reproduces_tracker_depth_scale() {
    check_absorbed_tracker_effect(
        &world("tracker depth scale 1500 ppm", depth_scale),
        "tracker_depth_scale",
        serde_json::json!({"depth_scale_ppm": 1500.0}),
        |p| [p[0], p[1], p[2] * (1.0 + 1500e-6)],
        1.5e-3,
    );
}

/// Every kind of the effect registry (`robocal::diagnose::effects::KINDS`) has its test
/// `predict_reproduces_<kind>` in this file, not ignored: a kind added to the registry
/// without one fails.
#[test]
fn every_registry_kind_has_a_predict_test() {
    let src = include_str!("diagnose_predict.rs");
    let missing: Vec<&str> = robocal::diagnose::effects::KINDS
        .iter()
        .copied()
        .filter(|k| !src.contains(&format!("#[test]\nfn predict_reproduces_{k}()")))
        .collect();
    assert!(
        missing.is_empty(),
        "effect kinds without a predict test in tests/diagnose_predict.rs: {missing:?}"
    );
}
