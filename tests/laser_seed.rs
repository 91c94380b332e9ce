//! Seed 000's figures on the simulated laser cell (issue 29 §1): the kinematic session of the
//! visit, then the laser session through its identified arm. The calibrate stage refines the
//! arm's joint parameters jointly with the beam from the planes and the selection targets
//! (`solve::laser::arm_refine`), the operator centres the spot on the plate's dots (the
//! scenario's `scene.plate.centring`), and the held-out five-direction spread is scored beside
//! the seed's. The plate's dot positions (world truth) are read only here, as the seed's
//! Optotrak reference for FRE / TRE.
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use nalgebra::Point3;
use robocal::dataset::{CalibrationFile, Dataset};
use robocal::session::{SessionFile, VerdictKind};
use robocal::solve::laser;

use crate::common::{cli, root, s};

const SCENARIO: &str = "mocks/scenarios/lab-vs060-il600-planes.toml";

/// The kinematic session, then the laser session with its arm calibration: (laser dir, exit).
fn sessions() -> &'static (PathBuf, i32) {
    static S: OnceLock<(PathBuf, i32)> = OnceLock::new();
    S.get_or_init(|| {
        let base = std::env::temp_dir().join(format!("robocal-laser-seed-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        let sc = root().join(SCENARIO);
        let kin = base.join("kin");
        let t0 = std::time::Instant::now();
        let code = cli(&[
            "session",
            "--sim",
            s(&sc),
            "--out",
            s(&kin),
            "--in-process",
            "--no-history",
        ]);
        assert!(code == 0 || code == 2, "kinematic session: exit {code}");
        let las = base.join("laser");
        let code = cli(&[
            "session",
            "--sim",
            s(&sc),
            "--kind",
            "laser",
            "--arm-calibration",
            s(&kin.join("deploy/calibration.json")),
            "--out",
            s(&las),
            "--in-process",
            "--no-history",
        ]);
        println!(
            "kinematic + laser sessions: exit {code} in {:.1} s",
            t0.elapsed().as_secs_f64()
        );
        (las, code)
    })
}

/// The plate's dots in the base frame (the world's truth: the reference instrument).
fn dots() -> Vec<Point3<f64>> {
    let sc = robocal_mocks::Scenario::load(&root().join(SCENARIO)).unwrap();
    let pl = sc.scene.plate.expect("plate");
    let t = pl.placement.isometry();
    pl.targets
        .iter()
        .map(|d| t * Point3::new(d.xy_mm[0], d.xy_mm[1], 0.0))
        .collect()
}

fn obs(dir: &Path, set: &str, arm: &laser::IdentifiedArm) -> Vec<laser::LaserObs> {
    let p = dir.join(format!("run-{set}/dataset.jsonl"));
    let ds = Dataset::load(&p).unwrap();
    laser::observations_through(&ds, Some(arm)).unwrap()
}

fn arm_of(dir: &Path, file: &str) -> laser::IdentifiedArm {
    let p = dir.join("run-train/dataset.jsonl");
    let ds = Dataset::load(&p).unwrap();
    laser::identified_arm(&dir.join(file), &ds, &p).unwrap()
}

/// Every method on the held-out targets through `arm`, with the dots as the reference of
/// FRE / TRE (each record's dot = the one nearest its spot through the deployed beam).
fn comparison(dir: &Path, arm: &laser::IdentifiedArm) -> laser::Comparison {
    let train: Vec<_> = obs(dir, "train", arm)
        .into_iter()
        .filter(|o| o.plane.is_some())
        .collect();
    let sel: Vec<_> = obs(dir, "selection", arm)
        .into_iter()
        .filter(|o| o.target.is_some())
        .collect();
    let val: Vec<_> = obs(dir, "validation", arm)
        .into_iter()
        .filter(|o| o.target.is_some())
        .collect();
    let beam = laser::beam_from_calibration(
        &CalibrationFile::load(dir.join("deploy/calibration.json")).unwrap(),
    )
    .unwrap();
    let dots = dots();
    let truth: HashMap<u64, Point3<f64>> = val
        .iter()
        .map(|o| {
            let p = beam.spot(&o.flange, o.d);
            let d = *dots
                .iter()
                .min_by(|a, b| (*a - p).norm().total_cmp(&(*b - p).norm()))
                .unwrap();
            assert!((d - p).norm() < 5.0, "spot {p} is not on a dot");
            (o.id, d)
        })
        .collect();
    laser::compare_split(&train, &sel, &val, Some(&truth), None).unwrap()
}

fn row<'a>(c: &'a laser::Comparison, name: &str) -> &'a laser::MethodRow {
    c.rows.iter().find(|r| r.method == name).unwrap()
}

#[test]
fn laser_session_meets_the_seed_through_the_refined_arm() {
    let (dir, code) = sessions();
    let f = SessionFile::load(&dir.join("session.json")).unwrap();
    println!("{}", f.verdict_line);
    assert_eq!(f.verdict, VerdictKind::Pass, "{}", f.verdict_line);
    assert_eq!(*code, 0);
    assert!(dir.join("deploy/arm-calibration.json").is_file());
    let l = f.laser.as_ref().unwrap();
    let before = f.measured.laser_spread_mm_before.unwrap();
    let after = f.measured.laser_spread_mm_after.unwrap();
    // Seed 000: orthogonal planes 0.37 ± 0.05 mm (with ~0.4 mm of aiming by eye; ours 0.1 mm).
    assert!(after < 0.37, "held-out spread {before} -> {after} mm");
    let ortho = l
        .methods
        .iter()
        .find(|m| m.method == "orthogonal-planes LM")
        .unwrap();
    assert!(ortho.spread_mean_mm < 0.37, "{ortho:?}");
    // The single planes (seed: 1.37 ± 0.24 mm) do worse than the three orthogonal planes.
    for m in l
        .methods
        .iter()
        .filter(|m| m.method.starts_with("closed-form"))
    {
        assert!(m.spread_mean_mm > 2.0 * ortho.spread_mean_mm, "{m:?}");
    }
    // Ablation: the same data through the arm as calibrated (no refinement) vs refined, on
    // the held-out targets, FRE / TRE against the dots (seed: 0.24 / 0.26 mm).
    let plain = comparison(dir, &arm_of(dir, laser_session_arm()));
    let refined = comparison(dir, &arm_of(dir, "deploy/arm-calibration.json"));
    for (what, c) in [("as calibrated", &plain), ("refined", &refined)] {
        for m in [
            "closed-form P1",
            "closed-form P2",
            "closed-form P3",
            "orthogonal-planes LM",
            "direct ML",
        ] {
            if let Some(r) = c.rows.iter().find(|r| r.method == m) {
                println!(
                    "arm {what:<14} {m:<22} held-out spread {:.3} ± {:.3} mm, FRE {:?} TRE {:?} mm",
                    r.spread_mean_mm, r.spread_std_mm, r.fre_mm, r.tre_mm
                );
            }
        }
    }
    let (p, r) = (
        row(&plain, "orthogonal-planes LM"),
        row(&refined, "orthogonal-planes LM"),
    );
    // Both arms meet the seed once the spots of a target are one physical point: the arm as
    // calibrated already held the orientation; the refinement may not make it worse.
    assert!(p.spread_mean_mm < 0.37, "as calibrated: {p:?}");
    assert!(
        r.spread_mean_mm < p.spread_mean_mm + 0.05,
        "refinement: {} -> {} mm",
        p.spread_mean_mm,
        r.spread_mean_mm
    );
    for c in [p, r] {
        let (fre, tre) = (c.fre_mm.unwrap(), c.tre_mm.unwrap());
        assert!(fre < 0.24 && tre < 0.26, "FRE {fre} TRE {tre} mm");
    }
    // The single planes are far worse than the orthogonal planes (seed: 1.37 vs 0.37 mm).
    for m in ["closed-form P1", "closed-form P2"] {
        assert!(row(&refined, m).spread_mean_mm > 3.0 * r.spread_mean_mm);
    }
}

/// The session's copy of the kinematic calibration.
fn laser_session_arm() -> &'static str {
    robocal::session::laser::ARM_CALIBRATION
}

#[test]
fn the_planes_pin_the_arm_orientation_the_marker_left_loose() {
    // Evidence of why the orientation was not identified: the arm refinement's σ-scaled
    // singular values (> 1 = the laser data pin that direction better than the prior).
    let (dir, _) = sessions();
    let cal_path = dir.join(laser_session_arm());
    let cal = CalibrationFile::load(&cal_path).unwrap();
    let p = dir.join("run-train/dataset.jsonl");
    let ds = Dataset::load(&p).unwrap();
    let arm = laser::identified_arm(&cal_path, &ds, &p).unwrap();
    let train: Vec<_> = laser::arm_refine::arm_observations(&ds, &arm)
        .unwrap()
        .into_iter()
        .filter(|o| o.obs.plane.is_some())
        .collect();
    let sp = dir.join("run-selection/dataset.jsonl");
    let sds = Dataset::load(&sp).unwrap();
    let sel: Vec<_> = laser::arm_refine::arm_observations(&sds, &arm)
        .unwrap()
        .into_iter()
        .filter(|o| o.obs.target.is_some())
        .collect();
    let plain: Vec<_> = train.iter().map(|o| o.obs.clone()).collect();
    let sel_plain: Vec<_> = sel.iter().map(|o| o.obs.clone()).collect();
    let fit = laser::compare_split(&plain, &sel_plain, &sel_plain, None, None).unwrap();
    let r = laser::arm_refine::refine(
        &arm,
        &cal,
        &train,
        &sel,
        &fit.outliers,
        (&fit.final_beam.unwrap(), &fit.final_planes),
        &Default::default(),
    )
    .unwrap();
    let id = &r.identifiability;
    println!(
        "{} arm parameters; σ-scaled singular values, planes: {:?}",
        id.arm_params.len(),
        id.planes_sv
            .iter()
            .map(|x| format!("{x:.2}"))
            .collect::<Vec<_>>()
    );
    println!(
        "with the selection targets: {:?}",
        id.with_targets_sv
            .iter()
            .map(|x| format!("{x:.2}"))
            .collect::<Vec<_>>()
    );
    for (n, u, d) in &r.changes {
        let (v, unit) = match u {
            robocal::model::Unit::Rad => (d.to_degrees(), "deg"),
            robocal::model::Unit::Mm => (*d, "mm"),
        };
        println!("  {n:<8} {v:+.4} {unit}");
    }
    println!(
        "plane RMS {:.4} -> {:.4} mm, selection spread {:.4} -> {:.4} mm",
        r.plane_rms_before_mm,
        r.plane_rms_after_mm,
        r.selection_spread_before_mm,
        r.selection_spread_after_mm
    );
    assert!(id.planes_pinned >= id.arm_params.len() / 2, "{id:?}");
    assert!(r.selection_spread_after_mm < r.selection_spread_before_mm);
    assert!(r.plane_rms_after_mm < 1.5 * r.plane_rms_before_mm + 0.01);
}
