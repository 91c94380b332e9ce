//! Pose planner (issue 6): generators reproduce their seeds' geometry, each constraint
//! rejects what it should, the time model / ordering, observability, plan file and exports.
use std::path::PathBuf;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use robocal::dataset::RobotBlock;
use robocal::model::KinematicModel;
use robocal::plan::constraints::{self, Frustum, RejectReason};
use robocal::plan::gen::{self, BranchPolicy, Candidate, HitPlane};
use robocal::plan::spec::{LaserSpec, TrackerKind, TrackerSpec};
use robocal::plan::timing::{self, TimeModel};
use robocal::plan::{self, export, observe, PlanFile, PlanOptions, PlanSpec};

fn plans_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("plans")
}

fn spec(name: &str) -> PlanSpec {
    PlanSpec::from_file(&plans_dir().join(name)).unwrap()
}

fn vs060() -> KinematicModel {
    KinematicModel::preset("denso-vs060").unwrap()
}

fn preset_block(name: &str) -> RobotBlock {
    RobotBlock {
        model: name.into(),
        serial: None,
        chain: None,
        flange: None,
        extra: Default::default(),
    }
}

#[test]
fn every_plan_file_parses_strictly() {
    let mut n = 0;
    for e in std::fs::read_dir(plans_dir()).unwrap() {
        let p = e.unwrap().path();
        if p.extension().and_then(|s| s.to_str()) == Some("toml") {
            let name = p.file_name().unwrap().to_string_lossy().to_string();
            if name.ends_with("-session.toml") {
                // A session's spec holds the plans of several stages (calibration planes and
                // validation targets): the session's own reader splits and checks it.
                let text = std::fs::read_to_string(&p).unwrap();
                robocal::session::laser::parse_spec(&text)
                    .unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
            } else {
                PlanSpec::from_file(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            }
            n += 1;
        }
    }
    assert!(n >= 4, "expected at least the four seed plans, found {n}");
}

#[test]
fn unknown_keys_and_bad_ranges_are_rejected() {
    let good = std::fs::read_to_string(plans_dir().join("seed001-annulus.toml")).unwrap();
    let typo = good.replace(
        "radius_mm = [250.0, 550.0]",
        "radius_mm = [250.0, 550.0]\nradiuss = 3",
    );
    assert!(PlanSpec::from_toml_str(&typo).is_err());
    let rev = good.replace("radius_mm = [250.0, 550.0]", "radius_mm = [550.0, 250.0]");
    assert!(PlanSpec::from_toml_str(&rev).is_err());
    let none = "name = \"x\"\n";
    assert!(
        PlanSpec::from_toml_str(none).is_err(),
        "a spec needs a generator"
    );
}

// ------------------------------------------------------------------ generators

#[test]
fn annulus_matches_seed001_ranges() {
    let s = spec("seed001-annulus.toml");
    let c = gen::generate(&s);
    assert_eq!(c.len(), 200);
    let (mut rmin, mut rmax, mut amin, mut amax) = (f64::MAX, 0.0f64, f64::MAX, f64::MIN);
    for cand in &c {
        let p = cand.tool_in_base.translation.vector;
        let r = p.x.hypot(p.y);
        let az = p.y.atan2(p.x).to_degrees();
        assert!((250.0 - 1e-9..=550.0 + 1e-9).contains(&r), "r {r}");
        assert!((-60.0 - 1e-9..=60.0 + 1e-9).contains(&az), "azimuth {az}");
        assert!((200.0..=550.0).contains(&p.z), "z {}", p.z);
        // R = Rz(z)·Ry(y)·Rx(x): first column (cos z cos y, sin z cos y, −sin y).
        let m = cand.tool_in_base.rotation.to_rotation_matrix();
        let m = m.matrix();
        let sy = -m[(2, 0)];
        assert!(
            sy >= 60f64.to_radians().sin() - 1e-9,
            "attitude Y outside 60..120: sin {sy}"
        );
        let z0 = m[(1, 0)].atan2(m[(0, 0)]).to_degrees();
        let zdist = [z0, z0 - 180.0, z0 + 180.0]
            .iter()
            .map(|z| if z.abs() <= 30.0 { 0.0 } else { z.abs() - 30.0 })
            .fold(f64::MAX, f64::min);
        assert!(zdist < 1e-6, "attitude Z outside ±30: {z0}");
        rmin = rmin.min(r);
        rmax = rmax.max(r);
        amin = amin.min(az);
        amax = amax.max(az);
    }
    assert!(rmin < 290.0 && rmax > 520.0, "radius spread {rmin}..{rmax}");
    assert!(amin < -45.0 && amax > 45.0, "azimuth spread {amin}..{amax}");
    // Deterministic in the seed.
    assert_eq!(c, gen::generate(&s));
}

#[test]
fn annulus_plan_on_vs060_keeps_every_feasible_branch() {
    let s = spec("seed001-annulus.toml");
    let model = vs060();
    let out = plan::build_plan(
        &s,
        preset_block("denso-vs060"),
        &model,
        &PlanOptions::default(),
    )
    .unwrap();
    let sum = &out.file.summary;
    assert_eq!(sum.targets, 200);
    assert_eq!(sum.feasible, out.file.poses.len());
    assert_eq!(sum.per_branch.values().sum::<usize>(), sum.feasible);
    assert!(
        sum.per_branch.len() >= 2,
        "several IK branches: {:?}",
        sum.per_branch
    );
    // Seed 001: 200 points gave 551 poses, i.e. well over one branch per point.
    assert!(sum.feasible > 250, "feasible {}", sum.feasible);
    let mut points = std::collections::BTreeSet::new();
    let tool = plan::frame_iso(&s.tool);
    for p in &out.file.poses {
        points.insert(p.point);
        let q: Vec<f64> = p.q_deg.iter().map(|x| x.to_radians()).collect();
        for (x, (lo, hi)) in q.iter().zip(model.joint_limits()) {
            assert!(*x >= lo && *x <= hi);
        }
        // Tool point is the generated target, above the table.
        let t = model.flange_pose(&q) * tool;
        assert!(t.translation.z >= 200.0 - 1e-6 && t.translation.z <= 550.0 + 1e-6);
    }
    assert!(sum.feasible > points.len(), "branches per point > 1");
    assert!(sum.observability.o1 > 0.0);
    PlanFile::from_json_str(&serde_json::to_string(&out.file).unwrap()).unwrap();
    // The embedded spec reads back as the same strict spec (the CLI takes script speeds from it).
    let back: PlanSpec = serde_json::from_value(out.file.spec.clone()).unwrap();
    assert_eq!(back, s);
}

#[test]
fn shell_matches_seed004_geometry() {
    let s = spec("seed004-shell.toml");
    let sh = s.shell.clone().unwrap();
    let c = gen::generate(&s);
    assert_eq!(c.len(), sh.strata.iter().product::<usize>());
    let center = Point3::from(sh.center_mm);
    let pole = Vector3::from(sh.pole).normalize();
    let mut thetas = Vec::new();
    let mut alphas = Vec::new();
    for cand in &c {
        let cam = Point3::from(cand.tool_in_base.translation.vector);
        let rot = cand.tool_in_base.rotation;
        let (x, z) = (rot * Vector3::x(), rot * Vector3::z());
        let d = cam - center;
        let r = d.norm();
        assert!((200.0 - 1e-9..=380.0 + 1e-9).contains(&r), "r {r}");
        let theta = d
            .normalize()
            .dot(&pole)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        assert!(theta <= 30.0 + 1e-9, "polar {theta}");
        // Optical axis points at the centre.
        assert!((z - (-d / r)).norm() < 1e-9);
        // x is normal to the plane through camera, centre and pole.
        assert!(x.dot(&pole).abs() < 1e-9 && x.dot(&d).abs() < 1e-6);
        thetas.push(theta);
        alphas.push(d.y.atan2(d.x).to_degrees().rem_euclid(360.0));
    }
    // Stratified: every azimuth sector of 45° holds a viewpoint, polar strata spread.
    for k in 0..8 {
        assert!(alphas
            .iter()
            .any(|a| *a >= 45.0 * k as f64 && *a < 45.0 * (k + 1) as f64));
    }
    assert!(thetas.iter().cloned().fold(0.0, f64::max) > 20.0);
    assert!(thetas.iter().cloned().fold(90.0, f64::min) < 10.0);
    // The camera-to-flange transform maps viewpoints to flange poses the VS060 reaches.
    let out = plan::build_plan(
        &s,
        preset_block("denso-vs060"),
        &vs060(),
        &PlanOptions::default(),
    )
    .unwrap();
    assert!(
        out.file.summary.feasible >= c.len() / 2,
        "{:?}",
        out.file.summary.rejects
    );
}

#[test]
fn planes_match_seed000_blocks_and_moves() {
    let s = spec("seed000-planes.toml");
    let ps = s.planes.clone().unwrap();
    let c = gen::generate(&s);
    assert_eq!(c.len(), 180);
    let laser = s.laser.clone().unwrap();
    for pl in &ps.planes {
        let mine: Vec<&Candidate> = c
            .iter()
            .filter(|x| x.plane.as_deref() == Some(pl.name.as_str()))
            .collect();
        assert_eq!(mine.len(), 60, "{}", pl.name);
        let n = Vector3::from(pl.normal).normalize();
        for b in 1..=15 {
            let blk: Vec<_> = mine.iter().filter(|x| x.block == Some(b)).collect();
            assert_eq!(
                blk.iter()
                    .filter(|x| x.move_kind.as_deref() == Some("translate"))
                    .count(),
                3
            );
            assert_eq!(
                blk.iter()
                    .filter(|x| x.move_kind.as_deref() == Some("rotate"))
                    .count(),
                1
            );
        }
        // Each translation group keeps one orientation over all blocks (translation only).
        for g in ["T1", "T2", "T3"] {
            let rots: Vec<UnitQuaternion<f64>> = mine
                .iter()
                .filter(|x| x.label.ends_with(g))
                .map(|x| x.tool_in_base.rotation)
                .collect();
            assert_eq!(rots.len(), 15);
            assert!(
                rots.iter().all(|r| r.angle_to(&rots[0]) < 1e-9),
                "{} {g}",
                pl.name
            );
        }
        let center = Point3::from(pl.center_mm);
        for x in &mine {
            let o = Point3::from(x.tool_in_base.translation.vector);
            let beam = x.tool_in_base.rotation * Vector3::z();
            let standoff = (o - center).dot(&n);
            assert!(
                (450.0 - 1e-6..=750.0 + 1e-6).contains(&standoff),
                "standoff {standoff}"
            );
            let inc = (-beam.dot(&n)).acos().to_degrees();
            assert!(inc <= 20.0 + 1e-9, "incidence {inc}");
            // The beam hits the plane inside the rectangle.
            let t = (center - o).dot(&n) / beam.dot(&n);
            let hit = o + beam * t;
            let u = Vector3::from(pl.u_axis).normalize();
            let v = n.cross(&u);
            assert!((hit - center).dot(&u).abs() <= pl.size_mm[0] / 2.0 + 1e-6);
            assert!((hit - center).dot(&v).abs() <= pl.size_mm[1] / 2.0 + 1e-6);
            assert!(constraints::laser_check(
                &laser,
                &x.tool_in_base,
                x.hit_plane.as_ref().unwrap()
            )
            .is_none());
        }
    }
}

#[test]
fn five_direction_validation_matches_seed000() {
    let s = spec("seed000-validation.toml");
    let f = s.validation.clone().unwrap().five_direction.unwrap();
    let c = gen::generate(&s);
    let five: Vec<&Candidate> = c.iter().filter(|x| x.target.is_some()).collect();
    assert_eq!(five.len(), 50, "10 targets × 5 directions");
    let n = Vector3::from(f.plane.normal).normalize();
    let mut targets: Vec<String> = five.iter().map(|x| x.target.clone().unwrap()).collect();
    targets.dedup();
    assert_eq!(targets.len(), 10);
    for t in targets {
        let dirs: Vec<&&Candidate> = five
            .iter()
            .filter(|x| x.target.as_ref() == Some(&t))
            .collect();
        assert_eq!(dirs.len(), 5);
        let beams: Vec<Vector3<f64>> = dirs
            .iter()
            .map(|x| x.tool_in_base.rotation * Vector3::z())
            .collect();
        assert!(
            (beams[0] + n).norm() < 1e-9,
            "first direction along the normal"
        );
        let mut azis = Vec::new();
        for b in &beams[1..] {
            let tilt = (-b.dot(&n)).acos().to_degrees();
            assert!((tilt - 45.0).abs() < 1e-9, "tilt {tilt}");
            let perp = b - n * b.dot(&n);
            azis.push(perp.normalize());
        }
        for k in 0..4 {
            let ang = azis[k]
                .dot(&azis[(k + 1) % 4])
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees();
            assert!((ang - 90.0).abs() < 1e-9, "spacing {ang}");
        }
        // All five beams hit the same target point at the stand-off.
        let hits: Vec<Point3<f64>> = dirs
            .iter()
            .zip(&beams)
            .map(|(x, b)| Point3::from(x.tool_in_base.translation.vector) + b * f.standoff_mm)
            .collect();
        assert!(hits.iter().all(|h| (h - hits[0]).norm() < 1e-9));
    }
    // Coincidence poses: every kept point has ≥ 2 feasible branches.
    let out = plan::build_plan(
        &s,
        preset_block("denso-vs060"),
        &vs060(),
        &PlanOptions::default(),
    )
    .unwrap();
    let mut per_point = std::collections::BTreeMap::new();
    for p in out.file.poses.iter().filter(|p| p.label.starts_with('C')) {
        *per_point.entry(p.point).or_insert(0) += 1;
    }
    assert!(!per_point.is_empty());
    // The five-direction poses all fit the VS060 (the laser roll is free where needed).
    assert_eq!(
        out.file.poses.iter().filter(|p| p.target.is_some()).count(),
        50
    );
    assert!(per_point.values().all(|&k| k >= 2), "{per_point:?}");
}

// ------------------------------------------------------------------ constraints one by one

fn pose(p: [f64; 3], rot: UnitQuaternion<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(p[0], p[1], p[2]), rot)
}

#[test]
fn joint_limit_table_envelope_and_self_collision_checks() {
    let model = vs060();
    let s = spec("seed001-annulus.toml");
    let tool = plan::frame_iso(&s.tool);
    let mut c = s.constraints.clone();
    // A good pose passes.
    let q_ok = [0.0, 0.3, 1.6, 0.0, 0.8, 0.0];
    assert_eq!(constraints::arm_check(&c, &model, &q_ok, &tool), None);
    // Joint limit.
    let (_, hi) = model.joint_limits()[0];
    let q_lim = [hi + 0.01, 0.3, 1.6, 0.0, 0.8, 0.0];
    assert_eq!(
        constraints::arm_check(&c, &model, &q_lim, &tool),
        Some(RejectReason::JointLimit { joint: 1 })
    );
    // Table: raise the table above the arm.
    let mut ct = c.clone();
    ct.table_z_mm = Some(400.0);
    assert!(matches!(
        constraints::arm_check(&ct, &model, &q_ok, &tool),
        Some(RejectReason::Table { .. })
    ));
    // Envelope: a box that excludes the tool.
    c.envelope = Some(robocal_drivers::safety::Envelope::Box {
        min: [-100.0, -100.0, 0.0],
        max: [100.0, 100.0, 100.0],
    });
    assert_eq!(
        constraints::arm_check(&c, &model, &q_ok, &tool),
        Some(RejectReason::Envelope)
    );
    // Self-collision on synthetic capsules: a folded chain collides, a straight one does not.
    let straight: Vec<Point3<f64>> = (0..5)
        .map(|k| Point3::new(0.0, 0.0, 200.0 * k as f64))
        .collect();
    assert_eq!(constraints::self_collision(&straight, 40.0, 20.0), None);
    let folded = vec![
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(0.0, 0.0, 300.0),
        Point3::new(300.0, 0.0, 300.0),
        Point3::new(30.0, 0.0, 270.0),
        Point3::new(30.0, 0.0, 100.0),
    ];
    assert!(constraints::self_collision(&folded, 40.0, 20.0).is_some());
    assert!(
        (constraints::segment_distance(
            &Point3::new(0.0, 0.0, 0.0),
            &Point3::new(10.0, 0.0, 0.0),
            &Point3::new(5.0, 3.0, -1.0),
            &Point3::new(5.0, 3.0, 1.0)
        ) - 3.0)
            .abs()
            < 1e-12
    );
}

#[test]
fn tracker_volume_and_angle_checks() {
    // Tracker at 2 m on base +x looking back (−z towards base −x).
    let t = TrackerSpec {
        kind: TrackerKind::PolarisVega,
        pose: robocal::plan::spec::FrameSpec {
            xyz: [2000.0, 0.0, 400.0],
            rpy: [0.0, 90.0, 0.0],
        },
        marker_normal: [0.0, 0.0, 1.0],
        max_angle_deg: 60.0,
    };
    let tp = plan::frame_iso(&t.pose);
    let facing = UnitQuaternion::from_euler_angles(0.0, std::f64::consts::FRAC_PI_2, 0.0); // tool z → base +x
    assert_eq!(
        constraints::tracker_check(&t, &tp, &pose([500.0, 0.0, 400.0], facing)),
        None
    );
    // Too close (inside the 950 mm dead zone) and too far aside.
    assert_eq!(
        constraints::tracker_check(&t, &tp, &pose([1500.0, 0.0, 400.0], facing)),
        Some(RejectReason::TrackerVolume)
    );
    assert_eq!(
        constraints::tracker_check(&t, &tp, &pose([500.0, 900.0, 400.0], facing)),
        Some(RejectReason::TrackerVolume)
    );
    // Facing away.
    let away = UnitQuaternion::from_euler_angles(0.0, -std::f64::consts::FRAC_PI_2, 0.0);
    assert!(matches!(
        constraints::tracker_check(&t, &tp, &pose([500.0, 0.0, 400.0], away)),
        Some(RejectReason::TrackerAngle { angle_deg }) if angle_deg > 170.0
    ));
    // The approximate frusta are ordered as published: Certus reaches further than Vega.
    let vega = Frustum::of(TrackerKind::PolarisVega);
    let ext = Frustum::of(TrackerKind::PolarisVegaExtended);
    let certus = Frustum::of(TrackerKind::OptotrakCertus);
    assert!(vega.far_mm < ext.far_mm && ext.far_mm < certus.far_mm);
    assert!(
        !vega.contains(&Point3::new(0.0, 0.0, -2600.0))
            && ext.contains(&Point3::new(0.0, 0.0, -2600.0))
    );
}

#[test]
fn laser_range_and_incidence_checks() {
    let l = LaserSpec {
        range_mm: [200.0, 1000.0],
        max_incidence_deg: 20.0,
    };
    let plane = HitPlane {
        point: Point3::origin(),
        normal: Vector3::z(),
    };
    let down = UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.0); // tool z → −z
    assert_eq!(
        constraints::laser_check(&l, &pose([0.0, 0.0, 600.0], down), &plane),
        None
    );
    assert!(matches!(
        constraints::laser_check(&l, &pose([0.0, 0.0, 1200.0], down), &plane),
        Some(RejectReason::LaserRange { range_mm }) if (range_mm - 1200.0).abs() < 1e-9
    ));
    assert!(matches!(
        constraints::laser_check(&l, &pose([0.0, 0.0, 150.0], down), &plane),
        Some(RejectReason::LaserRange { .. })
    ));
    let tilted =
        UnitQuaternion::from_euler_angles(std::f64::consts::PI - 30f64.to_radians(), 0.0, 0.0);
    assert!(matches!(
        constraints::laser_check(&l, &pose([0.0, 0.0, 600.0], tilted), &plane),
        Some(RejectReason::LaserIncidence { angle_deg }) if (angle_deg - 30.0).abs() < 1e-9
    ));
    // Pointing away from the plane: never hits.
    assert!(matches!(
        constraints::laser_check(
            &l,
            &pose([0.0, 0.0, 600.0], UnitQuaternion::identity()),
            &plane
        ),
        Some(RejectReason::LaserRange { .. })
    ));
}

#[test]
fn unreachable_and_too_few_branches_are_counted() {
    let model = vs060();
    let mut s = spec("seed001-annulus.toml");
    s.tracker = None;
    let far = Candidate {
        point: 0,
        tool_in_base: pose([3000.0, 0.0, 400.0], UnitQuaternion::identity()),
        group: "train".into(),
        label: "far".into(),
        plane: None,
        move_kind: None,
        block: None,
        target: None,
        hit_plane: None,
        branches: BranchPolicy::All,
        free_roll: true,
    };
    let mut greedy = far.clone();
    greedy.point = 1;
    greedy.tool_in_base = pose(
        [450.0, 0.0, 400.0],
        UnitQuaternion::from_euler_angles(0.0, 1.5, 0.0),
    );
    greedy.branches = BranchPolicy::AllAtLeast(9);
    let f = plan::feasibility(&model, &s, vec![far, greedy]);
    let counts = f.reject_counts();
    assert_eq!(counts.get("unreachable"), Some(&1));
    assert_eq!(counts.get("too-few-branches"), Some(&1));
    assert!(f.poses.is_empty());
}

// ------------------------------------------------------------------ time model, order

#[test]
fn trapezoid_time_model_and_ordering() {
    // Triangular below v²/a, trapezoidal above.
    assert!((timing::trapezoid_time(0.5, 1.0, 1.0) - 2.0 * 0.5f64.sqrt()).abs() < 1e-12);
    assert!((timing::trapezoid_time(3.0, 1.0, 2.0) - (3.0 + 0.5)).abs() < 1e-12);
    let s = spec("seed001-annulus.toml");
    let tm = TimeModel::from_spec(&s.timing, 6);
    assert!(
        (tm.move_time(&[0.0; 6], &[0.0, 1.0, 0.0, 0.0, 0.0, 0.0])
            - timing::trapezoid_time(1.0, 60f64.to_radians(), 120f64.to_radians()))
        .abs()
            < 1e-12
    );
    let out = plan::build_plan(
        &s,
        preset_block("denso-vs060"),
        &vs060(),
        &PlanOptions::default(),
    )
    .unwrap();
    let t = &out.file.summary.timing;
    assert!(t.optimised_s < 0.9 * t.generated_s, "{t:?}");
    assert!(t.optimised_poses_per_hour > t.generated_poses_per_hour);
    // Optimised order is a permutation and the file's q follow it.
    let mut o = out.order.clone();
    o.sort_unstable();
    assert_eq!(o, (0..out.feasibility.poses.len()).collect::<Vec<_>>());
    let qs: Vec<Vec<f64>> = out
        .file
        .poses
        .iter()
        .map(|p| p.q_deg.iter().map(|x| x.to_radians()).collect())
        .collect();
    let ident: Vec<usize> = (0..qs.len()).collect();
    assert!((tm.session_time(&qs, &ident) - t.optimised_s).abs() < 1e-6);
}

// ------------------------------------------------------------------ observability

#[test]
fn observability_flags_unidentifiable_and_select_reaches_full_o1() {
    let model = vs060();
    let s = spec("seed001-annulus.toml");
    let idm = plan::identification_model(&model, &s).unwrap();
    // One repeated pose cannot identify ~30 parameters.
    let q = [0.1, 0.3, 1.6, 0.2, 0.8, 0.1];
    let qs: Vec<&[f64]> = vec![&q; 20];
    let mut j = observe::stacked_jacobian(&idm, &qs);
    let sc = observe::column_scales(&j);
    observe::scale_columns(&mut j, &sc);
    let ob = observe::analyse(&j, 20, &observe::free_names(&idm), 1e-6);
    assert_eq!(ob.o1, 0.0);
    assert!(!ob.unidentifiable.is_empty());
    // The full plan identifies everything; a parameter with no effect is flagged.
    let out = plan::build_plan(
        &s,
        preset_block("denso-vs060"),
        &model,
        &PlanOptions { select: Some(60) },
    )
    .unwrap();
    let sel = out.file.summary.select.clone().unwrap();
    assert!(
        sel.all.unidentifiable.is_empty(),
        "{:?}",
        sel.all.unidentifiable
    );
    assert!(sel.all.o1 > 0.0 && sel.all.condition.is_finite());
    assert_eq!(out.file.poses.len(), 60);
    assert!(
        sel.selected.o1 >= sel.all.o1,
        "selected {} vs all {}",
        sel.selected.o1,
        sel.all.o1
    );
    assert!(sel.poses_to_reach_full_o1.is_some_and(|n| n <= 60));
    // A marker on the joint-6 axis leaves phi5/d5/a6/alpha6 unidentifiable: warn loudly.
    let mut s2 = s.clone();
    s2.tool.xyz = [0.0, 0.0, 100.0];
    let out2 = plan::build_plan(
        &s2,
        preset_block("denso-vs060"),
        &model,
        &PlanOptions::default(),
    )
    .unwrap();
    assert!(
        out2.file
            .summary
            .warnings
            .iter()
            .any(|w| w.contains("UNIDENTIFIABLE")),
        "{:?}",
        out2.file.summary.warnings
    );
}

// ------------------------------------------------------------------ plan file and exports

#[test]
fn plan_file_round_trip_validation_and_exports() {
    let s = spec("seed000-planes.toml");
    let out = plan::build_plan(
        &s,
        preset_block("denso-vs060"),
        &vs060(),
        &PlanOptions::default(),
    )
    .unwrap();
    let f = &out.file;
    assert!(!f.poses.is_empty(), "{:?}", f.summary.rejects);
    assert!(f
        .poses
        .iter()
        .all(|p| p.plane.is_some() && p.move_kind.is_some() && p.block.is_some()));
    let text = serde_json::to_string_pretty(f).unwrap();
    let back = PlanFile::from_json_str(&text).unwrap();
    assert_eq!(back.poses.len(), f.poses.len());
    for (a, b) in back.poses.iter().zip(&f.poses) {
        assert_eq!(
            (a.id, a.point, a.branch, &a.label, &a.plane),
            (b.id, b.point, b.branch, &b.label, &b.plane)
        );
        assert!(a
            .q_deg
            .iter()
            .zip(&b.q_deg)
            .all(|(x, y)| (x - y).abs() < 1e-9));
    }
    assert_eq!(back.summary.feasible, f.summary.feasible);
    // Tampering is caught.
    let mut bad = f.clone();
    bad.poses[0].q_deg[1] += 1.0;
    assert!(PlanFile::from_json_str(&serde_json::to_string(&bad).unwrap()).is_err());
    let mut bad = f.clone();
    bad.format = "robocal-plan/9".into();
    assert!(bad.validate().is_err());
    let mut bad = f.clone();
    bad.poses[0].q_deg.pop();
    assert!(bad.validate().is_err());
    let unknown = text.replacen("\"format\"", "\"formatt\": 1, \"format\"", 1);
    assert!(PlanFile::from_json_str(&unknown).is_err());
    // Exports.
    let csv = export::to_csv(f).unwrap();
    assert_eq!(csv.lines().count(), f.poses.len() + 1);
    assert!(csv.lines().next().unwrap().contains("q6_deg"));
    let ur = export::to_urscript(f, 1.0, 1.4, 1.5);
    assert_eq!(ur.matches("movej(").count(), f.poses.len());
    assert!(ur.starts_with("def "));
    let pac = export::to_pacscript(f, 20.0, 1.5);
    assert_eq!(pac.matches("Move P, J(").count(), f.poses.len());
    assert!(pac.contains("TakeArm") && pac.contains("GiveArm"));
}

#[test]
fn cli_plan_writes_a_valid_plan_without_devices() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("PLAN.json");
    let csv = dir.path().join("poses.csv");
    let pcs = dir.path().join("plan.pcs");
    let spec = plans_dir().join("seed004-shell.toml");
    let code = robocal::main_with_args([
        "robocal".into(),
        "plan".into(),
        "--spec".into(),
        spec.into_os_string(),
        "--robot".into(),
        "denso-vs060".into(),
        "--out".into(),
        out.clone().into_os_string(),
        "--csv".into(),
        csv.clone().into_os_string(),
        "--pacscript".into(),
        pcs.clone().into_os_string(),
        "--json".into(),
    ]);
    assert_eq!(code, 0);
    let f = PlanFile::read(&out).unwrap();
    assert!(!f.poses.is_empty());
    assert!(csv.exists() && pcs.exists());
    let check = robocal::main_with_args([
        "robocal".into(),
        "plan".into(),
        "--check".into(),
        out.into_os_string(),
    ]);
    assert_eq!(check, 0);
    let missing_robot =
        robocal::main_with_args(["robocal", "plan", "--spec", "plans/seed004-shell.toml"]);
    assert_eq!(missing_robot, 1);
}

#[test]
fn numeric_ik_fallback_for_geometries_without_closed_form() {
    let ds = robocal::dataset::Dataset::load(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/kin-geometric/train.jsonl"),
    )
    .unwrap();
    let mut chain = ds.header.robot.chain.clone().unwrap();
    // Tilt joint 4 by 7°: no longer a spherical-wrist VS060, so no closed form.
    chain[3].origin_rpy = [7.0, 0.0, 0.0];
    let model = KinematicModel::from_chain(&chain, ds.header.robot.flange.as_ref()).unwrap();
    assert!(model.ik_family().is_none());
    let q = [0.2, 0.4, 1.3, 0.1, 0.7, -0.3];
    let target = model.flange_pose(&q);
    let sols = plan::solve_ik(&model, &target).expect("numeric IK finds the pose");
    assert!(!sols.is_empty());
    for s in &sols {
        let (dp, dr) = robocal::model::pose_distance(&model.flange_pose(&s.q), &target);
        assert!(dp < 1e-5 && dr < 1e-7, "{dp} {dr}");
        assert!(s.label.starts_with("numeric-"));
    }
    assert!(plan::solve_ik(&model, &Isometry3::translation(5000.0, 0.0, 0.0)).is_none());
}

#[test]
fn cli_plan_takes_the_robot_from_a_dataset_chain() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("PLAN.json");
    let code = robocal::main_with_args([
        "robocal".into(),
        "plan".into(),
        "--spec".into(),
        plans_dir().join("seed000-planes.toml").into_os_string(),
        "--chain".into(),
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/kin-geometric/train.jsonl")
            .into_os_string(),
        "--out".into(),
        out.clone().into_os_string(),
        "--urscript".into(),
        dir.path().join("plan.script").into_os_string(),
    ]);
    assert_eq!(code, 0);
    let f = PlanFile::read(&out).unwrap();
    assert!(f.robot.chain.is_some());
    assert!(!f.poses.is_empty());
    assert!(dir.path().join("plan.script").exists());
}

#[test]
fn safety_path_check_counts_moves_past_the_table() {
    let model = vs060();
    let mut s = spec("seed001-annulus.toml");
    let tool = plan::frame_iso(&s.tool);
    let hi = vec![0.0, 0.0, 1.2, 0.0, 0.5, 0.0];
    let lo = vec![0.0, 1.2, 1.5, 0.0, 0.9, 0.0];
    let z = |q: &[f64]| {
        (model.flange_pose(q) * tool)
            .translation
            .z
            .min(model.flange_pose(q).translation.z)
    };
    assert!(z(&lo) + 100.0 < z(&hi), "{} {}", z(&lo), z(&hi));
    s.constraints.envelope = None;
    s.constraints.table_z_mm = Some((z(&lo) + z(&hi)) / 2.0);
    s.constraints.table_clearance_mm = 0.0;
    let tm = TimeModel::from_spec(&s.timing, 6);
    assert_eq!(
        plan::path_check(&model, &s, &tm, &[hi.clone(), hi.clone()]),
        0
    );
    assert_eq!(
        plan::path_check(&model, &s, &tm, &[hi.clone(), lo.clone()]),
        1
    );
    assert_eq!(plan::path_check(&model, &s, &tm, &[hi.clone(), lo, hi]), 2);
}
