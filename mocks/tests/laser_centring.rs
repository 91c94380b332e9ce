//! The seed 000 operator on the validation plate (`scene.plate.centring`): after a move, a
//! laser spot within the capture radius of a dot is jogged onto it (the encoders read the
//! jogged joints), once per move; a spot beyond the capture radius is left alone.
use nalgebra::{Point3, UnitQuaternion, Vector3};
use robocal_mocks::scenario::{Centring, Placement, PlateConfig, TargetConfig};
use robocal_mocks::world::WorldHandle;
use robocal_mocks::Scenario;

/// The laser cell with only a plate, square to the beam 400 mm out at the home pose, and one
/// dot at plate (`dx`, `dy`) mm from the home spot.
fn world(dx: f64, dy: f64) -> WorldHandle {
    let p = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenarios/lab-vs060-il600-planes.toml"
    );
    let mut s = Scenario::load(std::path::Path::new(p)).unwrap();
    let w = WorldHandle::from_scenario(&s).unwrap();
    let f = w.arm_true_flange(0);
    let l = &s.lasers[0];
    let o = f * Point3::from(l.beam_origin_mm);
    let u = (f.rotation * Vector3::from(l.beam_dir)).normalize();
    let at = o + u * 400.0;
    let rot = UnitQuaternion::rotation_between(&Vector3::z(), &(-u)).unwrap();
    let (r, pi, y) = rot.euler_angles();
    s.scene.planes.clear();
    s.scene.block = None;
    s.scene.plate = Some(PlateConfig {
        placement: Placement {
            xyz_mm: [at.x, at.y, at.z],
            rpy_deg: [r.to_degrees(), pi.to_degrees(), y.to_degrees()],
        },
        size_mm: [200.0, 200.0],
        targets: vec![TargetConfig {
            label: "dot".into(),
            xy_mm: [dx, dy],
        }],
        centring: Some(Centring {
            capture_mm: 10.0,
            sd_mm: 0.0,
        }),
    });
    s.validate().unwrap();
    WorldHandle::from_scenario(&s).unwrap()
}

fn dot(s: &PlateConfig) -> Point3<f64> {
    s.placement.isometry() * Point3::new(s.targets[0].xy_mm[0], s.targets[0].xy_mm[1], 0.0)
}

#[test]
fn a_spot_near_a_dot_is_jogged_onto_it_once_per_move() {
    let w = world(3.0, -2.0);
    let plate = w.truth().scene.plate.clone().unwrap();
    let q0 = w.arm_joint_state(0).q;
    let (_, before, surface) = w.laser_truth(0).unwrap();
    assert_eq!(surface, "plate");
    let target = dot(&plate);
    assert!(((before - target).norm() - 13f64.sqrt()).abs() < 0.01);
    let _ = w.laser_reading_of(0);
    let q1 = w.arm_joint_state(0).q;
    let (_, after, _) = w.laser_truth(0).unwrap();
    assert!(
        (after - target).norm() < 0.01,
        "spot {:.4} mm off the dot",
        (after - target).norm()
    );
    let moved = q0
        .iter()
        .zip(&q1)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(moved > 1e-5 && moved < 0.02, "jog {moved} rad");
    // Once per move: a second reading does not move the arm again.
    let _ = w.laser_reading_of(0);
    assert_eq!(w.arm_joint_state(0).q, q1);
}

#[test]
fn a_spot_beyond_the_capture_radius_is_left_alone() {
    let w = world(30.0, 0.0);
    let q0 = w.arm_joint_state(0).q;
    let _ = w.laser_reading_of(0);
    assert_eq!(w.arm_joint_state(0).q, q0);
}
