//! Identification: nominal fit and kinematic identification against the independent
//! simulator's reference data, analytic Jacobians vs finite differences, identifiability,
//! bootstrap, tool calibration with the identified arm, metrics with IK branches, CLI.
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use nalgebra::{DVector, Isometry3, Matrix3xX, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use robocal::dataset::{CalibrationFile, Dataset};
use robocal::model::KinematicModel;
use robocal::solve::bootstrap::{bootstrap, BootstrapOptions, SubsetSize};
use robocal::solve::kinematics::{identify, identify_obs, Effect, IdentOptions, KinProblem};
use robocal::solve::lm::{numeric_jacobian, LsqProblem};
use robocal::solve::nominal::{fit_nominal, NominalOptions};
use robocal::solve::obs::{observations, Split};
use robocal::solve::{metrics, tool, PoseObs};

fn data(p: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(p)
}

fn read_csv(path: &Path) -> HashMap<u64, Point3<f64>> {
    let mut r = csv::Reader::from_path(path).unwrap();
    r.records()
        .map(|rec| {
            let rec = rec.unwrap();
            let v: Vec<f64> = rec.iter().map(|s| s.parse().unwrap()).collect();
            (v[0] as u64, Point3::new(v[1], v[2], v[3]))
        })
        .collect()
}

fn rms_against(truth: &HashMap<u64, Point3<f64>>, pred: &[(u64, Point3<f64>)]) -> f64 {
    let s: f64 = pred
        .iter()
        .map(|(id, p)| (p - truth[id]).norm_squared())
        .sum();
    (s / pred.len() as f64).sqrt()
}

struct Case {
    train: Dataset,
    held: Dataset,
    held_obs: Vec<PoseObs>,
    truth: HashMap<u64, Point3<f64>>,
    nominal: HashMap<u64, Point3<f64>>,
}

fn case(name: &str) -> Case {
    let train = Dataset::load(data(&format!("{name}/train.jsonl"))).unwrap();
    let held = Dataset::load(data(&format!("{name}/heldout.jsonl"))).unwrap();
    let (held_obs, skipped) = observations(&held, 6, Split::All);
    assert!(skipped.is_empty());
    Case {
        train,
        held,
        held_obs,
        truth: read_csv(&data(&format!("{name}/truth.csv"))),
        nominal: read_csv(&data(&format!("{name}/nominal.csv"))),
    }
}

fn predict(m: &KinematicModel, obs: &[PoseObs]) -> Vec<(u64, Point3<f64>)> {
    obs.iter().map(|o| (o.id, m.measured_point(&o.q))).collect()
}

#[test]
fn nominal_fit_reproduces_reference_nominal_csv() {
    let c = case("kin-geometric");
    let fit = fit_nominal(
        &c.train,
        &NominalOptions {
            heldout: Some(&c.held),
        },
    )
    .unwrap();
    assert_eq!(fit.n_train, 500);
    assert_eq!(fit.n_heldout, 150);
    assert!(fit.termination.converged(), "{:?}", fit.termination);
    let pred = predict(&fit.model, &c.held_obs);
    let vs_ref = rms_against(&c.nominal, &pred);
    assert!(vs_ref <= 0.01, "nominal vs nominal.csv: {vs_ref} mm");
    let vs_truth = rms_against(&c.truth, &pred);
    assert!(
        (vs_truth - 0.864).abs() < 0.01,
        "nominal vs truth: {vs_truth} mm"
    );
    // The held-out score is measured against the noisy measurements.
    let h = fit.heldout_rms_mm_before.unwrap();
    assert!(h > 0.8 && h < 0.95, "{h}");
    // Tool offset as in case.json (marker 25, -10, 110 mm on the flange) to ~1 mm.
    let t = fit.model.tool().translation.vector;
    assert!((t - Vector3::new(25.0, -10.0, 110.0)).norm() < 2.0, "{t}");
}

#[test]
fn identification_reaches_simulator_truth_on_kin_geometric() {
    let c = case("kin-geometric");
    let opts = IdentOptions {
        heldout: Some(c.held.clone()),
        ..Default::default()
    };
    let res = identify(&c.train, &opts).unwrap();
    assert!(res.termination.converged(), "{:?}", res.termination);
    let after = rms_against(&c.truth, &predict(&res.model, &c.held_obs));
    let before = rms_against(&c.truth, &predict(&res.nominal, &c.held_obs));
    assert!(after <= 0.02, "after {after} mm");
    assert!((before - 0.864).abs() < 0.01, "before {before}");
    // 27 identifiable parameters (seed 001), the redundant ones named with partners.
    assert_eq!(res.x.len(), 27, "{:?}", res.x_names);
    let fixed: Vec<&str> = res.fixed.iter().map(|f| f.name.as_str()).collect();
    for n in ["d1", "phi6", "d6", "phi1"] {
        assert!(fixed.contains(&n), "{n} not fixed: {fixed:?}");
    }
    let d6 = res.fixed.iter().find(|f| f.name == "d6").unwrap();
    assert!(d6.reason.contains("tool_z"), "{}", d6.reason);
    // Residual sigma ≈ the simulator's noise (0.035 mm per axis).
    assert!((res.sigma_mm - 0.035).abs() < 0.01, "{}", res.sigma_mm);
    let h = res.heldout.unwrap();
    assert!(h.rms_after < 0.08 && h.rms_before > 0.8, "{h:?}");
    // Every free parameter has a finite, positive std; fixed ones none.
    for p in &res.params {
        assert_eq!(p.std.is_some(), p.free, "{}", p.name);
        if let Some(s) = p.std {
            assert!(s.is_finite() && s > 0.0, "{} {s}", p.name);
        }
    }
    // Identified parameters stay close to nominal (errors are ~0.5 mm / ~0.1°) and are
    // determined far better than their change.
    for p in res
        .params
        .iter()
        .filter(|p| p.free && p.name.starts_with('a'))
    {
        let d = (p.value - p.nominal).abs();
        let lim = if p.unit == robocal::model::Unit::Mm {
            2.0
        } else {
            0.01
        };
        assert!(d < lim, "{}: {} vs nominal {}", p.name, p.value, p.nominal);
    }
    // The calibration file round-trips through the model used by `robocal predict`.
    let f = robocal::solve::calfile::ident_file(&c.train.header.robot, &res);
    let text = serde_json::to_string(&f).unwrap();
    let back: CalibrationFile = serde_json::from_str(&text).unwrap();
    let mut m = KinematicModel::from_robot_block(&back.robot).unwrap();
    m.apply_cal_params(&back.params).unwrap();
    let a = predict(&m, &c.held_obs);
    let b = predict(&res.model, &c.held_obs);
    for (x, y) in a.iter().zip(&b) {
        assert!((x.1 - y.1).norm() < 1e-6);
    }
    assert!(back.metrics["heldout_rms_mm_after"].as_f64().unwrap() < 0.08);
}

#[test]
fn geometric_model_on_compliance_case_reaches_reference_level() {
    let c = case("kin-compliance-j2");
    let opts = IdentOptions {
        heldout: Some(c.held.clone()),
        ..Default::default()
    };
    let res = identify(&c.train, &opts).unwrap();
    let after = rms_against(&c.truth, &predict(&res.model, &c.held_obs));
    let before = rms_against(&c.truth, &predict(&res.nominal, &c.held_obs));
    // Reference (independent geometric solver): 1.410 → 0.157 mm.
    assert!((before - 1.410).abs() < 0.02, "before {before}");
    assert!(after < 0.2, "after {after}");
}

/// A toy effect: a constant offset of the marker in the tracker frame along x, scaled by
/// sin(q2) (so it is not a base translation).
#[derive(Debug)]
struct Sag;
impl Effect for Sag {
    fn kind(&self) -> String {
        "test_sag".into()
    }
    fn param_names(&self) -> Vec<String> {
        vec!["sag_mm".into()]
    }
    fn initial(&self) -> Vec<f64> {
        vec![0.0]
    }
    fn point_correction(
        &self,
        _m: &KinematicModel,
        o: &PoseObs,
        th: &[f64],
        jac: Option<&mut Matrix3xX<f64>>,
    ) -> Vector3<f64> {
        let s = o.q[1].sin();
        if let Some(j) = jac {
            j[(2, 0)] = s;
        }
        Vector3::new(0.0, 0.0, th[0] * s)
    }
}

#[test]
fn kin_problem_jacobian_matches_finite_differences() {
    let c = case("kin-geometric");
    let (obs, _) = observations(&c.train, 6, Split::Train);
    let obs = &obs[..40];
    let fit = fit_nominal(&c.train, &NominalOptions::default()).unwrap();
    let mut model = fit.model.clone();
    for n in ["tool_rx", "tool_ry", "tool_rz"] {
        model.set_free(n, true).unwrap();
    }
    let effects: Vec<Arc<dyn Effect>> = vec![Arc::new(Sag)];
    // Position rows with an effect column.
    let p = KinProblem::new(model.clone(), obs, &effects);
    let mut x = p.x0();
    let n = x.len();
    x[n - 1] = 0.3;
    let (_, ja) = p.residuals_jacobian(&x);
    let jn = numeric_jacobian(|x| p.residuals(x), &x, 1e-6);
    for k in 0..n {
        let d = (ja.column(k) - jn.column(k)).amax();
        let s = ja.column(k).amax().max(1.0);
        assert!(d / s < 1e-5, "column {} ({}): {d}", k, p.x_names()[k]);
    }
    // Orientation rows: exact at zero residual, so build noise-free quaternions.
    let synth: Vec<PoseObs> = obs
        .iter()
        .map(|o| {
            let pose = model.measured_pose(&o.q);
            PoseObs {
                p: Point3::from(pose.translation.vector),
                quat: Some(pose.rotation),
                ..o.clone()
            }
        })
        .collect();
    let mut p = KinProblem::new(model.clone(), &synth, &[]);
    p.orientation = Some(50.0);
    let x = p.x0();
    let (r, ja) = p.residuals_jacobian(&x);
    assert!(r.amax() < 1e-8);
    let jn = numeric_jacobian(|x| p.residuals(x), &x, 1e-6);
    for k in 0..x.len() {
        let d = (ja.column(k) - jn.column(k)).amax();
        let s = ja.column(k).amax().max(1.0);
        assert!(
            d / s < 1e-5,
            "orientation column {} ({}): {d}",
            k,
            p.x_names()[k]
        );
    }
}

/// Perturb the nominal model's joint parameters randomly (mm / rad scale `s`).
fn perturbed(
    nominal: &KinematicModel,
    rng: &mut ChaCha8Rng,
    s_mm: f64,
    s_rad: f64,
) -> KinematicModel {
    let mut m = nominal.clone();
    let mut v = m.param_values();
    for (i, p) in nominal.params().iter().enumerate() {
        if p.free && matches!(p.group, robocal::model::ParamGroup::Joint(_)) {
            v[i] += match p.unit {
                robocal::model::Unit::Mm => rng.random_range(-s_mm..s_mm),
                robocal::model::Unit::Rad => rng.random_range(-s_rad..s_rad),
            };
        }
    }
    m.set_param_values(&v);
    m
}

fn random_q(rng: &mut ChaCha8Rng) -> Vec<f64> {
    vec![
        rng.random_range(-1.0..1.0),
        rng.random_range(-0.3..0.9),
        rng.random_range(0.6..2.0),
        rng.random_range(-2.0..2.0),
        rng.random_range(-1.8..1.8),
        rng.random_range(-3.0..3.0),
    ]
}

fn setup_truth(seed: u64) -> (KinematicModel, KinematicModel) {
    let c = Dataset::load(data("kin-geometric/train.jsonl")).unwrap();
    let nominal = KinematicModel::from_robot_block(&c.header.robot).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut truth = perturbed(&nominal, &mut rng, 0.3, 0.0008);
    truth.set_base(&Isometry3::new(
        Vector3::new(1700.0, 80.0, 650.0),
        Vector3::new(0.3, -1.2, 0.5),
    ));
    truth.set_tool(&Isometry3::from_parts(
        Translation3::new(25.0, -10.0, 110.0),
        UnitQuaternion::from_euler_angles(0.1, 0.2, 0.5),
    ));
    (nominal, truth)
}

#[test]
fn huber_lists_gross_outliers_and_keeps_accuracy() {
    let (nominal, truth) = setup_truth(11);
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let mut obs: Vec<PoseObs> = (0..200)
        .map(|i| {
            let q = random_q(&mut rng);
            let p = truth.measured_point(&q)
                + Vector3::new(
                    rng.random_range(-0.03..0.03),
                    rng.random_range(-0.03..0.03),
                    rng.random_range(-0.03..0.03),
                );
            let mut o = PoseObs::at(i, i as f64, q, p);
            o.point = Some(i);
            o.branch = Some(0);
            o.group = Some("train".into());
            o
        })
        .collect();
    for i in [5usize, 77, 150] {
        obs[i].p += Vector3::new(4.0, -3.0, 2.0);
    }
    let test: Vec<PoseObs> = (0..50)
        .map(|i| {
            let q = random_q(&mut rng);
            let mut o = obs[0].clone();
            o.ctx.id = 1000 + i;
            o.p = truth.measured_point(&q);
            o.ctx.approach = vec![0.0; q.len()];
            o.ctx.q = q;
            o
        })
        .collect();
    let opts = IdentOptions {
        huber_mm: Some(0.2),
        kfold: 0,
        ..Default::default()
    };
    let res = identify_obs(&nominal, obs.clone(), test.clone(), None, vec![], &opts).unwrap();
    let ids: Vec<u64> = res.outliers.iter().map(|o| o.0).collect();
    assert_eq!(ids, vec![5, 77, 150]);
    let h = res.heldout.unwrap();
    assert!(h.rms_after < 0.05, "huber held-out {h:?}");
    // Plain least squares is pulled by the outliers.
    let plain = identify_obs(
        &nominal,
        obs,
        test,
        None,
        vec![],
        &IdentOptions {
            kfold: 0,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(plain.heldout.unwrap().rms_after > 2.0 * h.rms_after);
}

#[test]
fn tool_with_identified_arm_recovers_marker_orientation_and_base() {
    let (_, truth) = setup_truth(21);
    let mut rng = ChaCha8Rng::seed_from_u64(22);
    let obs: Vec<PoseObs> = (0..40)
        .map(|i| {
            let q = random_q(&mut rng);
            let pose = truth.measured_pose(&q);
            let mut o = PoseObs::at(i, 0.0, q, Point3::from(pose.translation.vector));
            o.quat = Some(pose.rotation);
            o
        })
        .collect();
    // The arm is known (identified); base and tool are not.
    let mut arm = truth.clone();
    arm.set_base(&Isometry3::identity());
    arm.set_tool(&Isometry3::identity());
    let fit = tool::tool_with_arm(&arm, &obs).unwrap();
    assert!((fit.tool.translation.vector - truth.tool().translation.vector).norm() < 1e-6);
    assert!(fit.tool.rotation.angle_to(&truth.tool().rotation) < 1e-8);
    assert!((fit.base.translation.vector - truth.base().translation.vector).norm() < 1e-5);
    assert!(fit.rms_mm < 1e-6 && fit.rms_rot_deg < 1e-6);
}

#[test]
fn coincidence_error_drops_after_identification_with_ik_branches() {
    // Targets reached by every IK branch of the NOMINAL model, landing where the TRUE
    // robot puts them: the spread is the before; the identified model explains it.
    let (nominal, truth) = setup_truth(31);
    let mut rng = ChaCha8Rng::seed_from_u64(32);
    let mut train = Vec::new();
    let mut held = Vec::new();
    let mut id = 0;
    let mut n_multi = 0;
    for point in 0..120u64 {
        let q0 = random_q(&mut rng);
        let target = nominal.flange_pose(&q0);
        let Ok(sols) = nominal.ik(&target) else {
            continue;
        };
        let lim = nominal.joint_limits();
        let sols: Vec<_> = sols
            .into_iter()
            .filter(|s| s.q.iter().zip(&lim).all(|(q, l)| *q >= l.0 && *q <= l.1))
            .collect();
        if sols.len() >= 2 {
            n_multi += 1;
        }
        for s in sols {
            let mut o = PoseObs::at(id, id as f64, s.q.clone(), truth.measured_point(&s.q));
            o.point = Some(point);
            o.branch = Some(s.branch as u64);
            id += 1;
            if point % 4 == 3 {
                held.push(o);
            } else {
                train.push(o);
            }
        }
    }
    assert!(n_multi > 20, "only {n_multi} multi-branch targets");
    let res = identify_obs(
        &nominal,
        train,
        held.clone(),
        None,
        vec![],
        &IdentOptions {
            kfold: 0,
            ..Default::default()
        },
    )
    .unwrap();
    let pb: Vec<_> = held
        .iter()
        .map(|o| res.nominal.measured_point(&o.q))
        .collect();
    let pa: Vec<_> = held
        .iter()
        .map(|o| res.model.measured_point(&o.q))
        .collect();
    let cb = metrics::coincidence(&held, &pb).unwrap();
    let ca = metrics::coincidence(&held, &pa).unwrap();
    assert!(cb.mean_mm > 0.2, "before {cb:?}");
    assert!(
        ca.mean_mm < 0.01 * cb.mean_mm.max(1.0),
        "after {} before {}",
        ca.mean_mm,
        cb.mean_mm
    );
    let rb = metrics::relative_distance(&pb, &held.iter().map(|o| o.p).collect::<Vec<_>>(), 1.0)
        .unwrap();
    let ra = metrics::relative_distance(&pa, &held.iter().map(|o| o.p).collect::<Vec<_>>(), 1.0)
        .unwrap();
    assert!(ra.mean_pct < 0.1 * rb.mean_pct, "{ra:?} vs {rb:?}");
}

#[test]
fn bootstrap_spread_matches_covariance() {
    let c = case("kin-geometric");
    let res = identify(
        &c.train,
        &IdentOptions {
            heldout: Some(c.held.clone()),
            ..Default::default()
        },
    )
    .unwrap();
    let bo = BootstrapOptions {
        k: 40,
        subset: SubsetSize::Fraction(0.5),
        seed: 5,
        ..Default::default()
    };
    let b = bootstrap(&res, &[], &bo).unwrap();
    assert_eq!(b.samples.len() + b.n_failed, 40);
    assert!(b.n_failed == 0);
    assert_eq!(b.subset_size, 250);
    // Subsets of half the data without replacement: the spread of subset estimates around
    // the full fit is ≈ σ_full·sqrt((1 − f)/f) = σ_full for f = 1/2.
    let mut ratios = Vec::new();
    for (i, name) in b.names.iter().enumerate() {
        let p = res.params.iter().find(|p| &p.name == name).unwrap();
        ratios.push(b.summaries[i].std / p.std.unwrap());
    }
    ratios.sort_by(f64::total_cmp);
    let median = ratios[ratios.len() / 2];
    assert!(
        median > 0.6 && median < 1.6,
        "median std ratio {median}, {ratios:?}"
    );
    // Subset means stay near the full-data fit.
    assert!(b.max_mean_shift_sigma < 1.5, "{}", b.max_mean_shift_sigma);
    let e = robocal::solve::kinematics::model_errors(&b.mean_model, &c.held_obs);
    assert!(robocal::solve::stats::rms(&e) < 0.08);
    let _ = DVector::<f64>::zeros(1);
}

#[test]
fn cli_calibrate_nominal_and_kinematics_then_predict() {
    let dir = tempfile::tempdir().unwrap();
    let train = data("kin-geometric/train.jsonl");
    let held = data("kin-geometric/heldout.jsonl");
    let out_n = dir.path().join("nom");
    let code = robocal::main_with_args([
        "robocal",
        "calibrate",
        "nominal",
        "--data",
        train.to_str().unwrap(),
        "--heldout",
        held.to_str().unwrap(),
        "--out",
        out_n.to_str().unwrap(),
    ]);
    assert_eq!(code, 0);
    let f = CalibrationFile::load(out_n.join("calibration.json")).unwrap();
    assert_eq!(f.extra["kind"], "kinematic");
    let h = f.metrics["heldout_rms_mm_before"].as_f64().unwrap();
    assert!(h > 0.8 && h < 0.95, "{h}");
    assert!(f.metrics["train_rms_mm"].as_f64().unwrap() > 0.7);
    let out_k = dir.path().join("kin");
    let code = robocal::main_with_args([
        "robocal",
        "calibrate",
        "kinematics",
        "--data",
        train.to_str().unwrap(),
        "--heldout",
        held.to_str().unwrap(),
        "--out",
        out_k.to_str().unwrap(),
        "--bootstrap",
        "8",
        "--subset",
        "200",
    ]);
    assert_eq!(code, 0);
    let f = CalibrationFile::load(out_k.join("calibration.json")).unwrap();
    assert!(f.metrics["heldout_rms_mm_after"].as_f64().unwrap() < 0.08);
    assert!(f.param("a2").unwrap().std.unwrap() > 0.0);
    assert!(out_k.join("bootstrap.csv").exists());
    // The bootstrap's full covariance is written and is the chain's robot link.
    let bc: robocal::navchain::BootstrapCovariance =
        serde_json::from_value(f.extra["bootstrap"]["covariance"].clone()).unwrap();
    assert_eq!(bc.matrix.len(), bc.names.len() * bc.names.len());
    let (c, source) =
        robocal::navchain::robot_link_from_calibration(&f, &[0.1, -0.3, 1.2, 0.2, 0.6, -0.4])
            .unwrap();
    println!(
        "robot link from the bootstrap covariance: tip RMS {:.4} mm",
        c.trace().sqrt()
    );
    assert_eq!(source, "bootstrap covariance");
    assert!(c.trace() > 0.0 && c.trace().sqrt() < 0.5, "{c}");
    let csv_path = dir.path().join("pred.csv");
    let code = robocal::main_with_args([
        "robocal",
        "predict",
        "--calibration",
        out_k.join("calibration.json").to_str().unwrap(),
        "--data",
        held.to_str().unwrap(),
        "--out",
        csv_path.to_str().unwrap(),
    ]);
    assert_eq!(code, 0);
    let pred = read_csv(&csv_path);
    let truth = read_csv(&data("kin-geometric/truth.csv"));
    let p: Vec<(u64, Point3<f64>)> = pred.into_iter().collect();
    assert!(rms_against(&truth, &p) < 0.02);
    // Bad input: missing file → exit code 1, no panic.
    let code = robocal::main_with_args([
        "robocal",
        "calibrate",
        "kinematics",
        "--data",
        "/nonexistent.jsonl",
        "--out",
        out_k.to_str().unwrap(),
    ]);
    assert_eq!(code, 1);
}

#[test]
fn kfold_scores_without_heldout_and_orientation_fit() {
    // No validation records and no held-out file: 5-fold cross-validation on train.
    let c = case("kin-geometric");
    let mut small = c.train.clone();
    let mut kept = 0;
    small.records.retain(|r| match r {
        robocal::dataset::Record::Pose(_) => {
            kept += 1;
            kept <= 150
        }
        _ => true,
    });
    let res = identify(&small, &IdentOptions::default()).unwrap();
    let h = res.heldout.unwrap();
    assert_eq!(
        h.source,
        robocal::solve::kinematics::HeldoutSource::KFold(5)
    );
    assert_eq!(h.n, 150);
    assert!(h.rms_before > 0.7 && h.rms_after < 0.1, "{h:?}");
    // With marker orientation: tool gets 6 parameters; accuracy is kept.
    let opts = IdentOptions {
        heldout: Some(c.held.clone()),
        orientation: true,
        ..Default::default()
    };
    let res = identify(&c.train, &opts).unwrap();
    assert!(
        res.x_names.iter().any(|n| n == "tool_rz"),
        "{:?}",
        res.x_names
    );
    let after = rms_against(&c.truth, &predict(&res.model, &c.held_obs));
    assert!(after <= 0.02, "orientation fit: {after} mm");
    // The marker sits rotated 30° about the flange z axis (case.json).
    let rz = res.model.tool().rotation.euler_angles().2.to_degrees();
    assert!((rz - 30.0).abs() < 1.0, "tool rz {rz}");
}
