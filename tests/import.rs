//! `robocal import` end to end, and the reference body (tracker drift) on a simulated session.
use std::path::Path;
use std::process::Command;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use robocal::dataset::{parse_dataset, read_dataset, Dataset, MarkerObs, Record};
use robocal::solve::kinematics::{identify, IdentOptions};
use robocal_mocks::scenario::Scenario;
use robocal_mocks::synth::{synthesize, SynthConfig};
use robocal_mocks::WorldHandle;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_robocal"))
}

/// Synthetic rows in the exact IPA Series B layout (no real data).
fn ipa_b(n: usize) -> String {
    let mut s = String::from("Timestamp;Goal x;Goal y;Goal z;Goal roll;Goal pitch;Goal yaw;shoulder_pan_joint;shoulder_lift_joint;elbow_joint;wrist_1_joint;wrist_2_joint;wrist_3_joint;measurement_temperature;measurement_x;measurement_std_x;measurement_y;measurement_std_y;measurement_z;measurement_std_z;measurement_rx;measurement_std_rx;measurement_ry;measurement_std_ry;measurement_rz;measurement_std_rz\n");
    for i in 0..n {
        let q = format!("{:.3}", -2.0 + 0.01 * i as f64).replace('.', ",");
        s.push_str(&format!("2,02011E+13;0,4;-0,4;0,8;2,9;1,5;1,5;-0,9;-0,05;-1,9;-1,2;{q};-0,001;21,5;-0,5;0,01;-3343;0,008;-427;0,009;-90,1;0,0015;-30;0,0012;-90,4;0,002\n"));
    }
    s
}

#[test]
fn cli_import_ipa_and_csv_load_back() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("measurements_joint_configurations.csv");
    std::fs::write(&input, ipa_b(10)).unwrap();
    let out = dir.path().join("b.jsonl");
    let o = bin()
        .args(["import", "ipa", "--input"])
        .arg(&input)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{err}");
    assert!(
        stdout.contains("10 poses (8 train, 2 validation)"),
        "{stdout}"
    );
    assert!(err.contains("time-based effects cannot be tested"), "{err}");
    let ds = read_dataset(&out).unwrap().dataset;
    assert_eq!(ds.poses().count(), 10);
    assert_eq!(ds.header.extra["source"]["series"], "B");
    // `robocal inspect` reads it
    assert!(bin().arg("inspect").arg(&out).status().unwrap().success());

    // generic CSV, with an error first (an unknown column lists the existing ones)
    let csv = dir.path().join("g.csv");
    let mut text = String::from("t_ms;a1;a2;a3;a4;a5;a6;X;Y;Z;rx;ry;rz\n");
    for i in 0..8 {
        text.push_str(&format!(
            "{};{},5;-20;95;0;30;0;412,1;35,7;505,2;10;-35;120\n",
            100 * i,
            i
        ));
    }
    std::fs::write(&csv, text).unwrap();
    let gout = dir.path().join("g.jsonl");
    let args = |joints: &str| {
        let mut c = bin();
        c.args(["import", "csv", "--input"])
            .arg(&csv)
            .arg("--out")
            .arg(&gout)
            .args([
                "--robot",
                "denso-vs060",
                "--joints",
                joints,
                "--joint-unit",
                "deg",
            ])
            .args([
                "--pos",
                "X,Y,Z",
                "--length-unit",
                "mm",
                "--euler",
                "rx,ry,rz",
                "--euler-seq",
                "XYZ",
            ])
            .args([
                "--time",
                "t_ms",
                "--time-unit",
                "ms",
                "--delimiter",
                ";",
                "--decimal-comma",
            ]);
        c
    };
    let o = args("a1,a2,a3,a4,a5,a7").output().unwrap();
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("g.csv:1: column \"a7\"") && err.contains("\"a6\""),
        "{err}"
    );
    assert!(!gout.exists(), "nothing written on error");
    let o = args("a1,a2,a3,a4,a5,a6").output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ds = read_dataset(&gout).unwrap().dataset;
    let p = ds.poses().nth(3).unwrap();
    assert_eq!(p.t, 0.3);
    assert_eq!(p.q.as_ref().unwrap()[0], 3.5);
}

/// A tracker that drifts during the session, and a reference body measured through it.
fn drift_at(s: f64) -> Isometry3<f64> {
    // a few tenths of a mm and ~0.01° over the session, not linear in time
    let tr = Vector3::new(0.35 * s, -0.25 * s + 0.1 * (6.0 * s).sin(), 0.2 * s * s);
    let axis = Vector3::new(0.3, 0.5, 0.8).normalize();
    Isometry3::new(tr, axis * (0.012f64.to_radians() * s))
}

fn iso_of(m: &MarkerObs) -> Isometry3<f64> {
    let p = m.p.unwrap();
    let q = m.quat.unwrap();
    Isometry3::from_parts(
        Vector3::new(p[0], p[1], p[2]).into(),
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3])),
    )
}

fn obs_of(iso: &Isometry3<f64>) -> MarkerObs {
    let q = iso.rotation.quaternion();
    let t = iso.translation.vector;
    MarkerObs {
        p: Some([t.x, t.y, t.z]),
        quat: Some([q.w, q.i, q.j, q.k]),
        rms: None,
        visible: true,
        frames: Some(1),
        extra: Default::default(),
    }
}

/// Applies the drift to every visible marker; with `reference`, also records a reference body
/// fixed in the cell at `ref_cell`, measured through the same drifting tracker with noise.
fn apply_drift(
    ds: &mut Dataset,
    t_end: f64,
    ref_cell: Option<&Isometry3<f64>>,
    rng: &mut ChaCha8Rng,
) {
    let np = Normal::new(0.0, 0.02).unwrap();
    let nr = Normal::new(0.0, 0.0005f64.to_radians()).unwrap();
    for r in &mut ds.records {
        let Record::Pose(p) = r else { continue };
        let d_inv = drift_at(p.t / t_end).inverse();
        if let Some(m) = p.marker.as_mut().filter(|m| m.visible) {
            let rms = m.rms;
            *m = obs_of(&(d_inv * iso_of(m)));
            m.rms = rms;
        }
        if let Some(rc) = ref_cell {
            let noise = Isometry3::new(
                Vector3::new(np.sample(rng), np.sample(rng), np.sample(rng)),
                Vector3::new(nr.sample(rng), nr.sample(rng), nr.sample(rng)),
            );
            p.reference = Some(obs_of(&(d_inv * rc * noise)));
        }
    }
}

#[test]
fn reference_body_removes_tracker_drift() {
    let mut s = Scenario::single_arm("denso-vs060", 2026);
    s.trackers[0].effects.noise_lateral_mm = 0.03;
    s.trackers[0].effects.noise_depth_mm = 0.03;
    let wh = WorldHandle::from_scenario(&s).unwrap();
    let cfg = SynthConfig {
        n_train: 160,
        n_heldout: 50,
        seed: 7,
        frames_per_pose: 1,
        ..SynthConfig::default()
    };
    let out = synthesize(&wh, &cfg).unwrap();
    let train0 = parse_dataset(out.train_jsonl.as_bytes(), Path::new("train"))
        .unwrap()
        .dataset;
    let held0 = parse_dataset(out.heldout_jsonl.as_bytes(), Path::new("heldout"))
        .unwrap()
        .dataset;
    let t_end = train0
        .poses()
        .chain(held0.poses())
        .map(|p| p.t)
        .fold(0.0, f64::max);
    // the reference body: fixed in the cell near the working volume, turned arbitrarily
    let centre: Vector3<f64> = train0
        .poses()
        .filter_map(|p| p.marker.as_ref()?.p)
        .map(Vector3::from)
        .sum::<Vector3<f64>>()
        / train0.poses().count() as f64;
    let ref_cell = Isometry3::new(
        centre + Vector3::new(150.0, -300.0, 100.0),
        Vector3::new(0.4, -0.2, 1.1),
    );
    let score = |with_ref: bool, drift: bool| -> f64 {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let (mut tr, mut he) = (train0.clone(), held0.clone());
        if drift || with_ref {
            let t = if drift { t_end } else { f64::INFINITY };
            apply_drift(&mut tr, t, with_ref.then_some(&ref_cell), &mut rng);
            apply_drift(&mut he, t, with_ref.then_some(&ref_cell), &mut rng);
        }
        // the written files load back with the reference field
        let tr = parse_dataset(tr.to_jsonl().as_bytes(), Path::new("t"))
            .unwrap()
            .dataset;
        let opts = IdentOptions {
            heldout: Some(he),
            ..IdentOptions::default()
        };
        let res = identify(&tr, &opts).unwrap();
        assert!(res.skipped.is_empty(), "{:?}", res.skipped.first());
        res.heldout.unwrap().rms_after
    };
    let no_drift = score(false, false);
    let drift_raw = score(false, true);
    let drift_ref = score(true, true);
    println!(
        "held-out RMS (mm): no drift {no_drift:.4}; drifting tracker {drift_raw:.4}; drifting tracker + reference body {drift_ref:.4}"
    );
    // the noise floor: marker noise plus the reference body's own measurement noise
    assert!(
        drift_ref < 1.3 * no_drift + 0.02,
        "with reference {drift_ref} vs no drift {no_drift}"
    );
    assert!(
        drift_raw > 2.0 * drift_ref,
        "without reference {drift_raw} vs with {drift_ref}"
    );

    // frames are never mixed: a training file with references and a held-out file without
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut tr = train0.clone();
    apply_drift(&mut tr, t_end, Some(&ref_cell), &mut rng);
    let mixed = identify(
        &tr,
        &IdentOptions {
            heldout: Some(held0.clone()),
            ..IdentOptions::default()
        },
    );
    let Err(e) = mixed else {
        panic!("a training file with references and a held-out file without must be refused")
    };
    let e = e.to_string();
    assert!(e.contains("reference body"), "{e}");
    // poses without a reference in a file with references are skipped with the reason
    if let Some(Record::Pose(p)) = tr.records.iter_mut().find(|r| matches!(r, Record::Pose(_))) {
        p.reference = None;
    }
    let mut he = held0.clone();
    apply_drift(&mut he, t_end, Some(&ref_cell), &mut rng);
    let res = identify(
        &tr,
        &IdentOptions {
            heldout: Some(he),
            ..IdentOptions::default()
        },
    )
    .unwrap();
    assert_eq!(res.skipped.len(), 1);
    assert!(
        res.skipped[0].reason.contains("no `reference`"),
        "{:?}",
        res.skipped
    );
}
