//! The simulated operator in the world: the probe is seen through the whole pivot and touch
//! steps of the operator scenario, its tip stays in the divot, and a DENSO follows the hand
//! while a UR follows it only in freedrive.
use nalgebra::Point3;
use robocal_drivers::ToolStatus;
use robocal_mocks::scenario::{ClockMode, Scenario};
use robocal_mocks::world::operator::Step;
use robocal_mocks::world::WorldHandle;
use std::path::PathBuf;

fn scenario() -> Scenario {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenarios/operator-vs060-vega.toml");
    let mut s = Scenario::load(&p).unwrap();
    s.clock = ClockMode::Virtual;
    s
}

#[test]
fn probe_is_visible_while_pivoting_and_touching() {
    let s = scenario();
    let op = s.operator.clone().unwrap();
    let total: f64 = op.steps.iter().map(Step::duration).sum();
    let w = WorldHandle::from_scenario(&s).unwrap();
    let (mut seen, mut hidden, mut in_hand) = (0, 0, 0);
    let mut divot_err: f64 = 0.0;
    let n = (total * 60.0) as usize;
    for _ in 0..n {
        let f = w.tracker_frame();
        let truth = w.operator_probe_truth();
        let probe = f.tools.iter().find(|t| t.tool == "probe");
        if let Some(m) = truth {
            in_hand += 1;
            match probe.map(|p| p.status) {
                Some(ToolStatus::Visible { .. }) => seen += 1,
                _ => hidden += 1,
            }
            let tip = m * Point3::from(op.probe_tip_mm);
            if w.now() < 15.0 {
                divot_err = divot_err.max((tip - Point3::new(350.0, 40.0, 560.0)).norm());
            }
        }
    }
    println!("probe in hand {in_hand} frames: visible {seen}, not {hidden}; divot error {divot_err:.2e} mm");
    assert!(in_hand > 60 * 25, "{in_hand}");
    assert_eq!(hidden, 0, "probe not visible in {hidden} frames");
    assert!(divot_err < 1e-6);
}

#[test]
fn denso_follows_the_hand_ur_only_in_freedrive() {
    let s = scenario();
    let w = WorldHandle::from_scenario(&s).unwrap();
    w.arm_joint_state(0);
    // Pivot 0.5 + 14, wait 1, touch 4 × 6 = 39.5 s, then the drag; its first hold 39.5 + 2.5.
    w.advance(43.0);
    let q = w.arm_joint_state(0).q;
    let want = [10.0f64, 10.0, 80.0, 0.0, 50.0, 0.0];
    for (a, b) in q.iter().zip(want) {
        assert!((a.to_degrees() - b).abs() < 0.01, "{q:?}");
    }
    // The same script on a UR: the hand pushes a braked arm in vain until freedrive.
    let mut u = s.clone();
    u.arms[0].model = "ur5e".into();
    u.arms[0].protocol = robocal_mocks::scenario::Protocol::Ur;
    u.arms[0].home_deg = Some(vec![0.0, -90.0, 90.0, -90.0, -90.0, 0.0]);
    let w = WorldHandle::from_scenario(&u).unwrap();
    let q0 = w.arm_joint_state(0).q;
    w.advance(43.0);
    assert_eq!(w.arm_joint_state(0).q, q0, "a UR moved without freedrive");
    w.arm_set_freedrive(0, true);
    let q = w.arm_joint_state(0).q;
    assert!((q[0].to_degrees() - 10.0).abs() < 0.01, "{q:?}");
}
