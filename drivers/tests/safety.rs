//! Property test: over random plans, no command that violates the limits ever reaches the
//! wrapped arm (joint limits, speed cap, envelope and table along the interpolated path).

use nalgebra::Point3;
use proptest::prelude::*;
use robocal_drivers::fake::FakeArm;
use robocal_drivers::safety::{guard, ArmGeometry, Envelope, SafetyLimits, TablePlane};
use robocal_drivers::{Arm, ErrorKind, MoveSpeed};
use std::sync::Arc;

/// A 3-joint test arm: yaw, then a two-link planar arm (lengths mm) on a 300 mm column.
fn points(q: &[f64]) -> Vec<Point3<f64>> {
    let (l1, l2, h) = (400.0, 300.0, 300.0);
    let (c0, s0) = (q[0].cos(), q[0].sin());
    let r1 = l1 * q[1].cos();
    let z1 = h + l1 * q[1].sin();
    let r2 = r1 + l2 * (q[1] + q[2]).cos();
    let z2 = z1 + l2 * (q[1] + q[2]).sin();
    vec![
        Point3::new(r1 * c0, r1 * s0, z1),
        Point3::new(r2 * c0, r2 * s0, z2),
    ]
}

const REACH_MM: f64 = 700.0;

fn limits() -> SafetyLimits {
    SafetyLimits {
        joint_lower: vec![-2.5, -0.5, -2.5],
        joint_upper: vec![2.5, 2.0, 2.5],
        max_vel: 0.5,
        max_acc: 1.0,
        envelope: Some(Envelope::Cylinder {
            center_xy: [0.0, 0.0],
            radius: 650.0,
            z_min: -100.0,
            z_max: 1000.0,
        }),
        table: Some(TablePlane {
            point: [0.0, 0.0, 50.0],
            normal: [0.0, 0.0, 1.0],
            clearance_mm: 10.0,
        }),
        path_step: 0.5f64.to_radians(),
    }
}

/// Independent check at 4× finer sampling, with the displacement bound between the guard's samples.
fn path_ok(l: &SafetyLimits, from: &[f64], to: &[f64]) -> bool {
    let tol = REACH_MM * l.path_step * 3.0_f64.sqrt();
    let n = 400;
    (0..=n).all(|k| {
        let s = k as f64 / n as f64;
        let q: Vec<f64> = from.iter().zip(to).map(|(a, b)| a + s * (b - a)).collect();
        points(&q).iter().all(|p| {
            let r = (p.x * p.x + p.y * p.y).sqrt();
            r <= 650.0 + tol && p.z >= -100.0 - tol && p.z <= 1000.0 + tol && p.z - 60.0 >= -tol
        })
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn nothing_unsafe_reaches_the_arm(
        plan in prop::collection::vec(
            (prop::collection::vec(-3.0f64..3.0, 3), 0.01f64..3.0, 0.01f64..5.0), 1..25)
    ) {
        let rt = tokio::runtime::Builder::new_current_thread().build().unwrap();
        let start = vec![0.0, 0.6, -0.8];
        let fake = FakeArm::new(start.clone());
        let geom: Arc<dyn ArmGeometry> = Arc::new(points);
        let l = limits();
        let arm: Arc<dyn Arm> = guard(Arc::new(fake.clone()), l.clone(), Some(geom));
        let mut refused = 0usize;
        rt.block_on(async {
            for (target, v, a) in &plan {
                match arm.move_joints(target, MoveSpeed { max_vel: *v, max_acc: *a }).await {
                    Ok(()) => {}
                    Err(e) => { prop_assert_eq!(e.kind(), ErrorKind::SafetyViolation); refused += 1; }
                }
            }
            Ok(())
        })?;
        let cmds = fake.commands();
        prop_assert_eq!(cmds.len() + refused, plan.len());
        let mut from = start;
        for c in cmds {
            prop_assert!(c.speed.max_vel <= l.max_vel && c.speed.max_acc <= l.max_acc);
            for (i, v) in c.target.iter().enumerate() {
                prop_assert!(*v >= l.joint_lower[i] && *v <= l.joint_upper[i]);
            }
            prop_assert!(path_ok(&l, &from, &c.target), "unsafe path reached the arm: {:?} -> {:?}", from, c.target);
            from = c.target.clone();
        }
    }
}

#[tokio::test]
async fn a_move_through_the_table_is_refused_even_if_both_ends_are_safe() {
    // Forearm swings from 2.5 rad (tip up) to -2.5 rad (tip down): both ends are above the
    // table, but half-way the tip passes z = 0, below the 50 mm table plus 10 mm clearance.
    let mut l = limits();
    l.envelope = None;
    let (start, end) = (vec![0.0, 0.0, 2.5], vec![0.0, 0.0, -2.5]);
    for q in [&start, &end] {
        assert!(points(q).iter().all(|p| p.z > 60.0));
    }
    let fake = FakeArm::new(start);
    let arm = guard(Arc::new(fake.clone()), l, Some(Arc::new(points)));
    let e = arm
        .move_joints(&end, MoveSpeed::default())
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::SafetyViolation);
    assert!(e.to_string().contains("table"), "{e}");
    assert!(fake.commands().is_empty());
}

#[tokio::test]
async fn speed_is_clamped_not_passed_through() {
    let fake = FakeArm::new(vec![0.0, 0.6, -0.8]);
    let arm = guard(Arc::new(fake.clone()), limits(), None);
    arm.move_joints(
        &[0.1, 0.6, -0.8],
        MoveSpeed {
            max_vel: 10.0,
            max_acc: 50.0,
        },
    )
    .await
    .unwrap();
    let c = &fake.commands()[0];
    assert_eq!(c.speed.max_vel, 0.5);
    assert_eq!(c.speed.max_acc, 1.0);
}

#[tokio::test]
async fn joint_limit_and_nan_are_refused() {
    let fake = FakeArm::new(vec![0.0, 0.6, -0.8]);
    let arm = guard(Arc::new(fake.clone()), limits(), None);
    let e = arm
        .move_joints(&[3.0, 0.6, -0.8], MoveSpeed::default())
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::SafetyViolation);
    assert!(e.to_string().contains("joint 1"), "{e}");
    let e = arm
        .move_joints(&[f64::NAN, 0.6, -0.8], MoveSpeed::default())
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::SafetyViolation);
    let e = arm
        .move_joints(&[0.0, 0.6], MoveSpeed::default())
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::SafetyViolation);
    assert!(fake.commands().is_empty());
}
