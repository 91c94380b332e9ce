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
            let rq = UnitQuaternion::from_quaternion(Quaternion::new(v[9], v[10], v[11], v[12]));
            (q, Isometry3::from_parts(t, rq))
        })
        .collect()
}

/// The raw quaternion (x, y, z, w order as nalgebra stores it) of the golden row with joints `q`.
fn raw_quat(q: &[f64], preset: &str) -> nalgebra::Vector4<f64> {
    let mut r = csv::Reader::from_path(data(&format!("golden/fk-{preset}.csv"))).unwrap();
    for rec in r.records() {
        let v: Vec<f64> = rec.unwrap().iter().map(|s| s.parse().unwrap()).collect();
        if v[0..6]
            .iter()
            .zip(q)
            .all(|(a, b)| (a.to_radians() - b).abs() < 1e-15)
        {
            return nalgebra::Vector4::new(v[10], v[11], v[12], v[9]);
        }
    }
    panic!("row not found");
}

/// Max (mm, rad) deviation of a preset from its golden file.
fn golden_dev(preset: &str) -> (f64, f64, usize) {
    let m = KinematicModel::preset(preset).unwrap();
    let rows = golden(preset);
    let mut worst = (0.0f64, 0.0f64);
    let mut worst_comp = 0.0f64;
    for (q, pose) in &rows {
        let fk = m.flange_pose(q);
        let (dp, dr) = pose_distance(&fk, pose);
        worst.0 = worst.0.max(dp);
        worst.1 = worst.1.max(dr);
        // quaternion components (sign-aligned) and coordinates as the file rounds them
        // compare with the file's raw (rounded, unnormalised) numbers
        let b = raw_quat(q, preset);
        let a = fk.rotation.coords;
        let c = (a - b).amax().min((a + b).amax());
        let t = (fk.translation.vector - pose.translation.vector).amax();
        worst_comp = worst_comp.max(c).max(t);
    }
    // the file carries 6 decimals: the model reproduces every number to within half a unit
    // of the last digit (+ float slack), i.e. it rounds to the file's values
    assert!(
        worst_comp <= 5.0e-7 + 1e-9,
        "{preset}: component deviation {worst_comp}"
    );
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

// ---------------------------------------------------------------- random chains

/// A random chain joint (mm, deg). `near` = nearly parallel to the previous axis.
fn rand_joint(
    name: String,
    xyz: [f64; 3],
    rpy: [f64; 3],
    axis: [f64; 3],
    near: Option<(f64, f64)>,
    prev_axis: [f64; 3],
) -> ChainJoint {
    let (rpy, axis) = match near {
        // tiny rpy and the previous axis slightly tilted: nearly parallel axes
        Some((tilt, sign)) => (
            [rpy[0] * 1e-3, rpy[1] * 1e-3, rpy[2]],
            [
                sign * prev_axis[0] + tilt * axis[0],
                sign * prev_axis[1] + tilt * axis[1],
                sign * prev_axis[2] + tilt * axis[2],
            ],
        ),
        None => (rpy, axis),
    };
    ChainJoint {
        name,
        origin_xyz: xyz,
        origin_rpy: rpy,
        axis,
        limits: None,
        extra: Map::new(),
    }
}

/// Rotation of `axis` by rpy (deg) (to keep a nearly-parallel axis truly nearly parallel when
/// the yaw is not small: express the previous axis in the new frame).
fn rot_rpy(rpy_deg: [f64; 3]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(
        rpy_deg[0].to_radians(),
        rpy_deg[1].to_radians(),
        rpy_deg[2].to_radians(),
    )
}

prop_compose! {
    fn arb_chain()(
        n in 1usize..8,
        xyz in prop::collection::vec(prop::array::uniform3(-400.0f64..400.0), 8),
        rpy in prop::collection::vec(prop::array::uniform3(-180.0f64..180.0), 8),
        axes in prop::collection::vec(prop::array::uniform3(-1.0f64..1.0), 8),
        near in prop::collection::vec(prop::option::weighted(0.45, (
            prop_oneof![Just(0.0), 1e-9f64..1e-6, 1e-6f64..1e-2, 1e-2f64..0.08],
            prop_oneof![Just(1.0), Just(-1.0)],
        )), 8),
        zero_xy in prop::collection::vec(any::<bool>(), 8),
        fl_xyz in prop::array::uniform3(-200.0f64..200.0),
        fl_rpy in prop::array::uniform3(-180.0f64..180.0),
    ) -> (Vec<ChainJoint>, FixedOrigin) {
        let mut chain = Vec::new();
        let mut prev = [0.0, 0.0, 1.0];
        for i in 0..n {
            let mut a = axes[i];
            if a.iter().map(|x| x * x).sum::<f64>() < 1e-4 { a = [0.0, 0.0, 1.0]; }
            let mut p = xyz[i];
            if zero_xy[i] { p[0] = 0.0; p[1] = 0.0; } // axes that intersect / coincide
            let nr = if i == 0 { None } else { near[i] };
            let mut j = rand_joint(format!("j{i}"), p, rpy[i], a, nr, prev);
            if nr.is_some() {
                // previous axis expressed in this joint's frame, then tilted
                let pa = rot_rpy(j.origin_rpy).inverse() * Vector3::from(prev);
                let (tilt, sign) = nr.unwrap();
                j.axis = [
                    sign * pa.x + tilt * a[0],
                    sign * pa.y + tilt * a[1],
                    sign * pa.z + tilt * a[2],
                ];
            }
            prev = j.axis;
            chain.push(j);
        }
        (chain, FixedOrigin { origin_xyz: fl_xyz, origin_rpy: fl_rpy, extra: Map::new() })
    }
}

/// Max conversion error (mm, rad) of a chain over `qs`.
fn conversion_error(chain: &[ChainJoint], fl: &FixedOrigin, qs: &[Vec<f64>]) -> (f64, f64) {
    let sc = SerialChain::from_chain_joints(chain, Some(fl)).unwrap();
    let m = KinematicModel::from_chain(chain, Some(fl)).unwrap();
    let mut w = (0.0f64, 0.0f64);
    for q in qs {
        let (dp, dr) = pose_distance(&sc.fk(q), &m.flange_pose(q));
        w.0 = w.0.max(dp);
        w.1 = w.1.max(dr);
    }
    w
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 100, ..ProptestConfig::default() })]
    /// 100 random chains × 100 random joint vectors = 10,000 vectors, ≤ 1e-9 mm.
    #[test]
    fn conversion_is_exact(
        (chain, fl) in arb_chain(),
        qs in prop::collection::vec(prop::collection::vec(-7.0f64..7.0, 8), 100),
    ) {
        let n = chain.len();
        let qs: Vec<Vec<f64>> = qs.into_iter().map(|q| q[..n].to_vec()).collect();
        let (dp, dr) = conversion_error(&chain, &fl, &qs);
        prop_assert!(dp <= 1e-9, "position error {} mm", dp);
        prop_assert!(dr <= 1e-12, "rotation error {} rad", dr);
    }
}

#[test]
fn nearly_parallel_axes_use_beta_and_stay_small() {
    // VS060: axes 2 and 3 parallel → β3 used, d2 fixed at 0.
    let m = KinematicModel::preset("denso-vs060").unwrap();
    assert!(m.uses_beta(3));
    assert!(!m.uses_beta(2) && !m.uses_beta(4));
    let i = m.param_index("d2").unwrap();
    assert!(!m.params()[i].free);
    assert!(m.params()[m.param_index("beta3").unwrap()].free);
    assert!(!m.params()[m.param_index("beta4").unwrap()].free);
    // A chain with axes 2/3 tilted by 0.01°: all lengths stay of the arm's size (no blow-up)
    let mut chain: Vec<ChainJoint> = serde_json::from_str(&header_chain_json()).unwrap();
    chain[2].axis = [0.0, 1.0, 1e-4f64.to_radians().tan() * 100.0];
    let m = KinematicModel::from_chain(&chain, None).unwrap();
    assert!(m.uses_beta(3));
    for p in m.params() {
        if p.unit == Unit::Mm {
            assert!(p.value.abs() < 1100.0, "{} = {}", p.name, p.value);
        }
    }
    let b = m.param("beta3").unwrap();
    assert!(b.abs() > 0.0 && b.abs() < 1e-3, "beta3 = {b}");
}

fn header_chain_json() -> String {
    let line = std::fs::read_to_string(data("kin-geometric/train.jsonl")).unwrap();
    let header: serde_json::Value = serde_json::from_str(line.lines().next().unwrap()).unwrap();
    header["robot"]["chain"].to_string()
}

#[test]
fn vs060_preset_is_the_dataset_header_chain() {
    let line = std::fs::read_to_string(data("kin-geometric/train.jsonl")).unwrap();
    let header: serde_json::Value = serde_json::from_str(line.lines().next().unwrap()).unwrap();
    let robot: RobotBlock = serde_json::from_value(header["robot"].clone()).unwrap();
    let from_header = KinematicModel::from_robot_block(&robot).unwrap();
    let preset = KinematicModel::preset("denso-vs060").unwrap();
    assert_eq!(from_header.joint_limits(), preset.joint_limits());
    let mut rng = 0x1234_5678u64;
    for _ in 0..200 {
        let q: Vec<f64> = (0..6)
            .map(|_| {
                rng = rng
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((rng >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 6.0
            })
            .collect();
        let (dp, dr) = pose_distance(&from_header.flange_pose(&q), &preset.flange_pose(&q));
        assert!(dp < 1e-9 && dr < 1e-12);
    }
    // a header without chain falls back to the preset by name
    let bare = RobotBlock {
        model: "ur5e".into(),
        serial: None,
        chain: None,
        flange: None,
        extra: Map::new(),
    };
    assert_eq!(KinematicModel::from_robot_block(&bare).unwrap().dof(), 6);
    assert!(matches!(
        KinematicModel::preset("kuka-kr6"),
        Err(ModelError::UnknownPreset { .. })
    ));
}

#[test]
fn presets_have_limits_and_mdh_values() {
    let m = KinematicModel::preset("ur5e").unwrap();
    let l = m.joint_limits();
    assert_eq!(l.len(), 6);
    assert!((l[2].1 - std::f64::consts::PI).abs() < 1e-12);
    assert!((m.param("d1").unwrap() - 162.5).abs() < 1e-9);
    assert!(m.base_offset().translation.vector.norm() < 1e-12);
    let v = KinematicModel::preset("denso-vs060").unwrap();
    let l = v.joint_limits();
    assert!((l[2].0 - (-125f64).to_radians()).abs() < 1e-12);
    assert!((l[2].1 - 155f64.to_radians()).abs() < 1e-12);
}

// ---------------------------------------------------------------- Jacobians

/// A preset with every parameter perturbed (a "calibrated" robot) and a non-trivial base/tool.
fn perturbed(preset: &str, seed: u64) -> KinematicModel {
    let mut m = KinematicModel::preset(preset).unwrap();
    let mut v = m.param_values();
    let mut s = seed;
    for (i, p) in m.params().iter().enumerate() {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let u = (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
        v[i] += match (p.group, p.unit) {
            (ParamGroup::Base, Unit::Mm) => 800.0 * u,
            (ParamGroup::Base, Unit::Rad) => 2.0 * u,
            (ParamGroup::Tool, Unit::Mm) => 200.0 * u,
            (ParamGroup::Tool, Unit::Rad) => 1.0 * u,
            (_, Unit::Mm) => 1.0 * u,
            (_, Unit::Rad) => 0.01 * u,
        };
    }
    m.set_param_values(&v);
    m
}

fn fd_point(m: &KinematicModel, q: &[f64], k: usize, h: f64) -> Vector3<f64> {
    let v0 = m.param_values();
    let mut mp = m.clone();
    let mut v = v0.clone();
    v[k] += h;
    mp.set_param_values(&v);
    let a = mp.measured_point(q).coords;
    v[k] -= 2.0 * h;
    mp.set_param_values(&v);
    let b = mp.measured_point(q).coords;
    (a - b) / (2.0 * h)
}

fn fd_rot(m: &KinematicModel, q: &[f64], k: usize, h: f64) -> Vector3<f64> {
    let mut mp = m.clone();
    let mut v = m.param_values();
    v[k] += h;
    mp.set_param_values(&v);
    let a = mp.measured_pose(q).rotation;
    v[k] -= 2.0 * h;
    mp.set_param_values(&v);
    let b = mp.measured_pose(q).rotation;
    (a * b.inverse()).scaled_axis() / (2.0 * h)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 40, ..ProptestConfig::default() })]
    #[test]
    fn param_jacobians_match_finite_differences(
        which in 0usize..3,
        seed in any::<u64>(),
        q in prop::collection::vec(-3.0f64..3.0, 6),
    ) {
        let name = ["denso-vs060", "ur5e", "ur10e"][which];
        let m = perturbed(name, seed);
        let (p, jp) = m.point_param_jacobian(&q);
        prop_assert!((p - m.measured_point(&q)).norm() < 1e-12);
        let (pose, j6) = m.pose_param_jacobian(&q);
        prop_assert!(pose_distance(&pose, &m.measured_pose(&q)).0 < 1e-12);
        prop_assert_eq!(jp.ncols(), m.params().len());
        for k in 0..m.params().len() {
            let h = if m.params()[k].unit == Unit::Mm { 1e-4 } else { 1e-7 };
            let fd = fd_point(&m, &q, k, h);
            let an = jp.column(k).into_owned();
            prop_assert!((fd - an).norm() <= 1e-5 * (1.0 + an.norm()),
                "point column {} ({}): fd {:?} analytic {:?}", k, m.params()[k].name, fd, an);
            let an6 = j6.fixed_view::<3, 1>(0, k).into_owned();
            prop_assert!((an6 - an).norm() < 1e-9, "pose/point position rows differ at {}", k);
            let fr = fd_rot(&m, &q, k, h);
            let ar = j6.fixed_view::<3, 1>(3, k).into_owned();
            prop_assert!((fr - ar).norm() <= 1e-6 * (1.0 + ar.norm()),
                "rotation column {} ({}): fd {:?} analytic {:?}", k, m.params()[k].name, fr, ar);
        }
    }

    #[test]
    fn joint_jacobian_matches_finite_differences(
        which in 0usize..3,
        seed in any::<u64>(),
        q in prop::collection::vec(-3.0f64..3.0, 6),
    ) {
        let name = ["denso-vs060", "ur5e", "ur10e"][which];
        let m = perturbed(name, seed);
        let j = m.joint_jacobian(&q);
        let h = 1e-7;
        for i in 0..6 {
            let mut qa = q.clone();
            qa[i] += h;
            let mut qb = q.clone();
            qb[i] -= h;
            let (fa, fb) = (m.flange_pose(&qa), m.flange_pose(&qb));
            let v = (fa.translation.vector - fb.translation.vector) / (2.0 * h);
            let w = (fa.rotation * fb.rotation.inverse()).scaled_axis() / (2.0 * h);
            let jv = j.fixed_view::<3, 1>(0, i).into_owned();
            let jw = j.fixed_view::<3, 1>(3, i).into_owned();
            prop_assert!((v - jv).norm() <= 1e-5 * (1.0 + jv.norm()), "v col {}: {:?} vs {:?}", i, v, jv);
            prop_assert!((w - jw).norm() <= 1e-6, "w col {}: {:?} vs {:?}", i, w, jw);
        }
    }
}

#[test]
fn point_jacobian_into_reuses_buffer() {
    let m = perturbed("denso-vs060", 7);
    let q = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6];
    let mut buf = nalgebra::Matrix3xX::zeros(m.params().len());
    let p = m.point_param_jacobian_into(&q, &mut buf).unwrap();
    let (p2, j2) = m.point_param_jacobian(&q);
    assert_eq!(p, p2);
    assert_eq!(buf, j2);
    let mut wrong = nalgebra::Matrix3xX::zeros(3);
    assert!(m.point_param_jacobian_into(&q, &mut wrong).is_none());
}

// ---------------------------------------------------------------- calibration params

#[test]
fn cal_params_round_trip_in_file_units() {
    let mut m = perturbed("ur10e", 99);
    let cal = m.to_cal_params();
    let a2 = cal.iter().find(|c| c.name == "a2").unwrap();
    assert_eq!(a2.unit, "mm");
    let al = cal.iter().find(|c| c.name == "alpha1").unwrap();
    assert_eq!(al.unit, "deg");
    assert!((al.value - m.param("alpha1").unwrap().to_degrees()).abs() < 1e-12);
    let mut fresh = KinematicModel::preset("ur10e").unwrap();
    fresh.apply_cal_params(&cal).unwrap();
    let d = &fresh.param_values() - &m.param_values();
    assert!(d.amax() < 1e-12);
    // bad name / unit / value: typed errors, nothing applied
    let mut bad = cal.clone();
    bad[0].name = "nope".into();
    assert!(matches!(
        m.apply_cal_params(&bad),
        Err(ModelError::UnknownParam { .. })
    ));
    let mut bad = cal.clone();
    bad[1].unit = "furlong".into();
    assert!(matches!(
        m.apply_cal_params(&bad),
        Err(ModelError::BadUnit { .. })
    ));
    let mut bad = cal.clone();
    bad[2].value = f64::NAN;
    assert!(matches!(
        m.apply_cal_params(&bad),
        Err(ModelError::NonFinite { .. })
    ));
    // free flags
    m.set_free("tool_rx", true).unwrap();
    assert!(m.params()[m.param_index("tool_rx").unwrap()].free);
    assert!(m.set_free("bogus", true).is_err());
    let n_free = m.free_count();
    let fv = m.free_values();
    assert_eq!(fv.len(), n_free);
    let mut m2 = m.clone();
    m2.set_free_values(&DVector::from_element(n_free, 0.5));
    assert_eq!(m2.free_values(), DVector::from_element(n_free, 0.5));
}

// ---------------------------------------------------------------- IK

fn lcg(s: &mut u64) -> f64 {
    *s = s
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*s >> 11) as f64 / (1u64 << 53) as f64
}

/// Random q inside the limits (kept away from the wrist singularity).
fn random_q(m: &KinematicModel, s: &mut u64) -> Vec<f64> {
    m.joint_limits()
        .iter()
        .map(|&(lo, hi)| {
            let (lo, hi) = (lo.max(-3.0), hi.min(3.0));
            lo + (hi - lo) * lcg(s)
        })
        .collect()
}

/// Smallest singular value of the joint Jacobian with rotation rows weighted by 300 mm.
fn manipulability(m: &KinematicModel, q: &[f64]) -> f64 {
    let mut j = m.joint_jacobian(q);
    for r in 3..6 {
        for c in 0..j.ncols() {
            j[(r, c)] *= 300.0;
        }
    }
    j.svd(false, false).singular_values.min()
}

/// Returns (draws used, draws whose original q was among the solutions, draws where every
/// closed-form seed refined, max mm, max rad).
fn ik_round_trip(m: &KinematicModel, seed: u64, n: usize) -> (usize, usize, usize, f64, f64) {
    let mut s = seed;
    let mut worst = (0.0f64, 0.0f64);
    let mut found_original = 0;
    let mut used = 0;
    let mut eight = 0;
    let mut complete = 0;
    for _ in 0..n {
        let q = random_q(m, &mut s);
        if manipulability(m, &q) < 20.0 {
            continue; // skip near-singular draws
        }
        used += 1;
        let t = m.flange_pose(&q);
        let sols = m.ik(&t).unwrap();
        let seeds = m.ik_family().unwrap().closed_form(&t);
        if m.name() == "denso-vs060"
            && m.param_values()
                == KinematicModel::preset("denso-vs060")
                    .unwrap()
                    .param_values()
        {
            // the mirrored shoulder reaches the same planar distance: always 8 branches
            assert_eq!(
                seeds.len(),
                8,
                "vs060: 8 closed-form branches for a generic pose"
            );
        }
        // every closed-form branch refines (the UR family can have 4 when the other
        // shoulder is out of reach)
        // seeds that are exact on the nominal geometry (clamped boundary seeds excluded)
        let fam = m.ik_family().unwrap();
        let exact = seeds
            .iter()
            .filter(|(_, s)| pose_distance(&fam.nominal_fk(s), &t).0 < 1e-6)
            .count();
        if sols.len() >= exact {
            complete += 1;
        }
        let mut branches: Vec<u8> = sols.iter().map(|s| s.branch).collect();
        branches.dedup();
        assert_eq!(branches.len(), sols.len());
        eight += usize::from(sols.len() == 8);
        for sol in &sols {
            let (dp, dr) = pose_distance(&m.flange_pose(&sol.q), &t);
            worst.0 = worst.0.max(dp);
            worst.1 = worst.1.max(dr);
            assert_eq!(sol.label.index(), sol.branch);
        }
        let lim = m.joint_limits();
        // the original q is one of the solutions (mod 2π)
        if sols.iter().any(|s| {
            s.q.iter().zip(&q).all(|(a, b)| {
                let d = (a - b).rem_euclid(std::f64::consts::TAU);
                d.min(std::f64::consts::TAU - d) < 1e-6
            })
        }) {
            found_original += 1;
        }
        for sol in sols.iter().filter(|s| s.within_limits) {
            for (x, (lo, hi)) in sol.q.iter().zip(&lim) {
                assert!(x >= lo && x <= hi);
            }
        }
    }
    assert!(eight * 2 >= used, "8 branches in only {eight}/{used} draws");
    (used, found_original, complete, worst.0, worst.1)
}

#[test]
fn ik_round_trip_nominal_presets() {
    for name in ["denso-vs060", "ur5e", "ur10e"] {
        let m = KinematicModel::preset(name).unwrap();
        let (used, found, complete, dp, dr) = ik_round_trip(&m, 42, 60);
        assert!(used >= 30, "{name}: only {used} non-singular draws");
        assert_eq!(complete, used, "{name}: every closed-form branch refines");
        assert_eq!(
            found, used,
            "{name}: original q recovered only {found}/{used} times"
        );
        assert!(dp <= 1e-6, "{name}: IK position error {dp} mm");
        assert!(
            dr <= 1e-6f64.to_radians(),
            "{name}: IK rotation error {dr} rad"
        );
    }
}

#[test]
fn ik_round_trip_calibrated_models() {
    for name in ["denso-vs060", "ur5e", "ur10e"] {
        let mut m = perturbed(name, 5);
        // keep base/tool as set; ik works on the flange in the robot base
        m.set_base(&Isometry3::identity());
        let (used, found, complete, dp, dr) = ik_round_trip(&m, 43, 40);
        assert!(used >= 20, "{name}: only {used} non-singular draws");
        // all branches refine, except near workspace boundaries of the calibrated arm
        assert!(
            complete * 10 >= used * 9,
            "{name}: all seeds refined in {complete}/{used} draws"
        );
        assert_eq!(
            found, used,
            "{name}: original q recovered only {found}/{used} times"
        );
        assert!(dp <= 1e-6, "{name}: IK position error {dp} mm");
        assert!(
            dr <= 1e-6f64.to_radians(),
            "{name}: IK rotation error {dr} rad"
        );
    }
}

#[test]
fn ik_unreachable_is_a_typed_error() {
    for name in ["denso-vs060", "ur5e", "ur10e"] {
        let m = KinematicModel::preset(name).unwrap();
        let far = Isometry3::translation(5000.0, 0.0, 0.0);
        assert!(
            matches!(m.ik(&far), Err(IkError::Unreachable { .. })),
            "{name}"
        );
        let nan = Isometry3::translation(f64::NAN, 0.0, 0.0);
        assert!(matches!(m.ik(&nan), Err(IkError::NonFiniteTarget)));
    }
}

#[test]
fn ik_reports_limits_and_wraps() {
    let m = KinematicModel::preset("denso-vs060").unwrap();
    let q = [0.3, 0.4, 1.2, 0.5, 0.7, 0.2];
    let sols = m.ik(&m.flange_pose(&q)).unwrap();
    assert!(sols.iter().any(|s| s.within_limits));
    // shoulder-left branches need q1 ± π; with |q1| ≤ 170° some are outside or wrapped inside
    let lim = m.joint_limits();
    for s in &sols {
        let inside = s.q.iter().zip(&lim).all(|(x, (lo, hi))| x >= lo && x <= hi);
        assert_eq!(inside, s.within_limits, "branch {}", s.label);
    }
}

// ---------------------------------------------------------------- URDF

fn urdf_joint(
    name: &str,
    kind: &str,
    parent: &str,
    child: &str,
    xyz_m: [f64; 3],
    rpy: [f64; 3],
    axis: [f64; 3],
) -> String {
    format!(
        r#"<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>
<origin xyz="{} {} {}" rpy="{} {} {}"/><axis xyz="{} {} {}"/>
<limit lower="-2.9" upper="2.9" effort="1" velocity="1"/></joint>
"#,
        xyz_m[0], xyz_m[1], xyz_m[2], rpy[0], rpy[1], rpy[2], axis[0], axis[1], axis[2]
    )
}

/// The VS060 written as a URDF (metres) with a fixed world joint and a fixed flange joint,
/// plus a branch (a camera link) that must be ignored.
fn vs060_urdf() -> String {
    let mut s = String::from(r#"<?xml version="1.0"?><robot name="vs060">"#);
    for l in [
        "world",
        "base_link",
        "l1",
        "l2",
        "l3",
        "l4",
        "l5",
        "l6",
        "flange",
        "camera",
    ] {
        s += &format!(r#"<link name="{l}"/>"#);
    }
    s += &urdf_joint(
        "world_joint",
        "fixed",
        "world",
        "base_link",
        [0.0; 3],
        [0.0; 3],
        [1.0, 0.0, 0.0],
    );
    s += &urdf_joint(
        "joint_1",
        "revolute",
        "base_link",
        "l1",
        [0.0, 0.0, 0.1815],
        [0.0; 3],
        [0.0, 0.0, 1.0],
    );
    s += &urdf_joint(
        "joint_2",
        "revolute",
        "l1",
        "l2",
        [0.0, 0.0, 0.1635],
        [0.0; 3],
        [0.0, 1.0, 0.0],
    );
    s += &urdf_joint(
        "cam",
        "fixed",
        "l2",
        "camera",
        [0.1, 0.0, 0.0],
        [0.0; 3],
        [1.0, 0.0, 0.0],
    );
    s += &urdf_joint(
        "joint_3",
        "revolute",
        "l2",
        "l3",
        [0.0, 0.0, 0.305],
        [0.0; 3],
        [0.0, 1.0, 0.0],
    );
    s += &urdf_joint(
        "joint_4",
        "revolute",
        "l3",
        "l4",
        [-0.010, 0.0, 0.1645],
        [0.0; 3],
        [0.0, 0.0, 1.0],
    );
    s += &urdf_joint(
        "joint_5",
        "revolute",
        "l4",
        "l5",
        [0.0, 0.0, 0.1355],
        [0.0; 3],
        [0.0, 1.0, 0.0],
    );
    s += &urdf_joint(
        "joint_6",
        "continuous",
        "l5",
        "l6",
        [0.0, 0.0, 0.070],
        [0.0; 3],
        [0.0, 0.0, 1.0],
    );
    s += &urdf_joint(
        "flange_joint",
        "fixed",
        "l6",
        "flange",
        [0.0; 3],
        [0.0; 3],
        [1.0, 0.0, 0.0],
    );
    s += "</robot>";
    s
}

#[test]
fn urdf_vs060_matches_preset() {
    let xml = vs060_urdf();
    let preset = KinematicModel::preset("denso-vs060").unwrap();
    for (base, tip) in [
        (None, Some("flange")),
        (Some("world"), Some("l6")),
        (Some("base_link"), None),
    ] {
        let m = KinematicModel::from_urdf_str(&xml, base, tip).unwrap();
        assert_eq!(m.dof(), 6);
        let mut s = 11u64;
        for _ in 0..100 {
            let q: Vec<f64> = (0..6).map(|_| (lcg(&mut s) - 0.5) * 6.0).collect();
            let (dp, dr) = pose_distance(&m.flange_pose(&q), &preset.flange_pose(&q));
            assert!(dp < 1e-9 && dr < 1e-12, "{base:?}->{tip:?}: {dp} mm");
        }
        // the family is detected, so closed-form IK works on URDF models too
        assert!(m.ik_family().is_some());
    }
    // limits come from the URDF (revolute) or default (continuous)
    let m = KinematicModel::from_urdf_str(&xml, None, Some("flange")).unwrap();
    assert!((m.joint_limits()[0].1 - 2.9).abs() < 1e-12);
}

#[test]
fn urdf_errors_are_typed() {
    let xml = vs060_urdf();
    assert!(matches!(
        KinematicModel::from_urdf_str(&xml, None, Some("nope")),
        Err(ModelError::UrdfLinkNotFound { .. })
    ));
    assert!(matches!(
        KinematicModel::from_urdf_str(&xml, Some("l6"), Some("l1")),
        Err(ModelError::UrdfNoPath { .. })
    ));
    assert!(matches!(
        KinematicModel::from_urdf_str("<robot", None, None),
        Err(ModelError::Urdf { .. })
    ));
    let pris = xml.replace(
        r#"name="joint_3" type="revolute""#,
        r#"name="joint_3" type="prismatic""#,
    );
    assert!(matches!(
        KinematicModel::from_urdf_str(&pris, None, Some("flange")),
        Err(ModelError::UnsupportedJoint { .. })
    ));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 40, ..ProptestConfig::default() })]
    /// Random chains written as URDF (metres, radians) convert exactly.
    #[test]
    fn urdf_random_chains_are_exact(
        (chain, fl) in arb_chain(),
        qs in prop::collection::vec(prop::collection::vec(-7.0f64..7.0, 8), 20),
    ) {
        let mut xml = String::from(r#"<robot name="r"><link name="l0"/>"#);
        for (i, j) in chain.iter().enumerate() {
            xml += &format!(r#"<link name="l{}"/>"#, i + 1);
            let xyz = j.origin_xyz.map(|v| v / 1000.0);
            let rpy = j.origin_rpy.map(f64::to_radians);
            xml += &urdf_joint(&j.name, "continuous", &format!("l{i}"), &format!("l{}", i + 1), xyz, rpy, j.axis);
        }
        xml += r#"<link name="tip"/>"#;
        xml += &urdf_joint("fl", "fixed", &format!("l{}", chain.len()), "tip",
            fl.origin_xyz.map(|v| v / 1000.0), fl.origin_rpy.map(f64::to_radians), [1.0, 0.0, 0.0]);
        xml += "</robot>";
        let m = KinematicModel::from_urdf_str(&xml, None, None).unwrap();
        let sc = SerialChain::from_chain_joints(&chain, Some(&fl)).unwrap();
        for q in &qs {
            let q = &q[..chain.len()];
            let (dp, dr) = pose_distance(&sc.fk(q), &m.flange_pose(q));
            // the decimal text of the XML round-trips f64 exactly (Rust prints shortest repr)
            prop_assert!(dp <= 1e-9, "{} mm", dp);
            prop_assert!(dr <= 1e-12, "{} rad", dr);
        }
    }
}

// ---------------------------------------------------------------- performance

/// The CPU time this thread has used (`CLOCK_THREAD_CPUTIME_ID`).
fn thread_cpu_time() -> std::time::Duration {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant the kernel knows.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID)");
    std::time::Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32)
}

#[test]
fn point_param_jacobian_is_fast() {
    // identification evaluates 500 poses × many iterations; one pass over 500 poses must be
    // far below the 50 ms fit budget even in the test profile
    let m = perturbed("denso-vs060", 3);
    let mut s = 5u64;
    let qs: Vec<Vec<f64>> = (0..500).map(|_| random_q(&m, &mut s)).collect();
    let mut buf = nalgebra::Matrix3xX::zeros(m.params().len());
    // This thread's CPU time, not the wall clock: the budget is the work's, and a test binary
    // running other tests beside this one (or a loaded machine) must not make it fail.
    let t0 = thread_cpu_time();
    let mut acc = 0.0;
    for q in &qs {
        acc += m.point_param_jacobian_into(q, &mut buf).unwrap().x;
    }
    let dt = thread_cpu_time() - t0;
    println!("500 point_param_jacobian evaluations: {dt:?} of CPU");
    assert!(acc.is_finite());
    assert!(dt.as_millis() < 20, "500 point Jacobians took {dt:?}");
}

// ---------------------------------------------------------------- identifiability

#[test]
fn point_redundancies_leave_27_identifiable_params() {
    // seed 001: 27 parameters (18 arm + 6 base + 3 tool) for a 6R arm seen by a tracker
    for name in ["denso-vs060", "ur5e", "ur10e"] {
        let mut m = perturbed(name, 17);
        m.fix_point_redundancies();
        let free = m.free_indices();
        assert_eq!(free.len(), 27, "{name}: free parameters {free:?}");
        let mut s = 3u64;
        let rows = 60;
        let mut a = nalgebra::DMatrix::<f64>::zeros(3 * rows, free.len());
        for r in 0..rows {
            let q = random_q(&m, &mut s);
            let (_, j) = m.point_param_jacobian(&q);
            for (c, &k) in free.iter().enumerate() {
                for i in 0..3 {
                    a[(3 * r + i, c)] = j[(i, k)];
                }
            }
        }
        // scale columns (mm vs rad) before judging the rank
        for (c, &k) in free.iter().enumerate() {
            let n = a.column(c).norm();
            assert!(n > 0.0, "{name}: column {} is zero", m.params()[k].name);
            a.column_mut(c).scale_mut(1.0 / n);
        }
        let sv = a.svd(false, false).singular_values;
        let cond = sv.max() / sv.min();
        assert!(cond < 1e6, "{name}: condition number {cond:e}");
        // without fixing, the full set is rank deficient (base absorbs joint 1)
        let all = KinematicModel::preset(name).unwrap();
        assert!(all.free_count() > 27);
    }
}

// ---------------------------------------------------------------- independent simulator

/// The kin-geometric case's hidden truth (true chain, joint zero offsets, marker on the
/// flange, tracker placement) in this model reproduces `truth.csv`, written by an independent
/// simulator: checks the chain conversion with small rpy (nearly parallel true axes), `phi`
/// as the joint zero offset, and the base/tool conventions of `measured_point`.
#[test]
fn kin_geometric_truth_is_reproduced() {
    use nalgebra::{Matrix4, Rotation3};
    let iso = |m: &serde_json::Value| {
        let mut a = Matrix4::zeros();
        for r in 0..4 {
            for c in 0..4 {
                a[(r, c)] = m[r][c].as_f64().unwrap();
            }
        }
        let rot = Rotation3::from_matrix_unchecked(a.fixed_view::<3, 3>(0, 0).into_owned());
        Isometry3::from_parts(
            Translation3::new(a[(0, 3)], a[(1, 3)], a[(2, 3)]),
            UnitQuaternion::from_rotation_matrix(&rot),
        )
    };
    let case: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data("kin-geometric/case.json")).unwrap())
            .unwrap();
    let held = std::fs::read_to_string(data("kin-geometric/heldout.jsonl")).unwrap();
    let mut lines = held.lines();
    let header: serde_json::Value = serde_json::from_str(lines.next().unwrap()).unwrap();
    let mut chain: Vec<ChainJoint> =
        serde_json::from_value(header["robot"]["chain"].clone()).unwrap();
    for (j, t) in chain.iter_mut().zip(case["true_chain"].as_array().unwrap()) {
        for k in 0..3 {
            j.origin_xyz[k] = t["origin_xyz"][k].as_f64().unwrap();
            j.origin_rpy[k] = t["origin_rpy_deg"][k].as_f64().unwrap();
        }
    }
    let mut m = KinematicModel::from_chain(&chain, None).unwrap();
    assert!(m.uses_beta(3), "true axes 2/3 are nearly parallel");
    m.set_base(&iso(&case["tracker_in_base"]).inverse());
    m.set_tool(&iso(&case["marker_on_flange"]));
    // joint zero offsets: true angle = encoder + offset → phi_i += offset
    for (i, o) in case["joint_offsets_deg"]
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
    {
        let name = format!("phi{}", i + 1);
        let v = m.param(&name).unwrap() + o.as_f64().unwrap().to_radians();
        m.set_param(&name, v).unwrap();
    }
    let truth = std::fs::read_to_string(data("kin-geometric/truth.csv")).unwrap();
    let mut worst = 0.0f64;
    let mut n = 0;
    for (line, t) in lines.zip(truth.lines().skip(1)) {
        let r: serde_json::Value = serde_json::from_str(line).unwrap();
        let t: Vec<f64> = t.split(',').map(|s| s.parse().unwrap()).collect();
        assert_eq!(r["id"].as_f64().unwrap(), t[0]);
        let q: Vec<f64> = r["q"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap().to_radians())
            .collect();
        let p = m.measured_point(&q);
        worst = worst.max((p.coords - Vector3::new(t[1], t[2], t[3])).norm());
        n += 1;
    }
    assert_eq!(n, 150);
    // truth.csv has 5 decimals
    assert!(worst < 2e-5, "max deviation from truth.csv {worst} mm");
}

#[test]
fn ik_for_tool_and_from_seed() {
    let mut m = perturbed("ur5e", 21);
    m.set_base(&Isometry3::identity());
    let q = [0.4, -1.1, 1.3, -0.6, 1.2, 0.3];
    let tool_pose = m.tool_pose_in_base(&q);
    let sols = m.ik_for_tool(&tool_pose).unwrap();
    assert!(!sols.is_empty());
    for s in &sols {
        let (dp, dr) = pose_distance(&m.tool_pose_in_base(&s.q), &tool_pose);
        assert!(dp < 1e-6 && dr < 1e-8, "{dp} mm {dr} rad");
    }
    // from a seed near q (no closed form used), e.g. for a model without a family
    let mut nofam = m.clone();
    nofam.set_ik_family(None);
    assert!(matches!(
        nofam.ik(&m.flange_pose(&q)),
        Err(IkError::NoClosedForm { .. })
    ));
    let seed: Vec<f64> = q.iter().map(|x| x + 0.05).collect();
    let qs = nofam.ik_from_seed(&m.flange_pose(&q), &seed).unwrap();
    for (a, b) in qs.iter().zip(&q) {
        assert!((a - b).abs() < 1e-8);
    }
    assert!(matches!(
        nofam.ik_from_seed(&Isometry3::translation(4000.0, 0.0, 0.0), &seed),
        Err(IkError::Unreachable { .. })
    ));
}
