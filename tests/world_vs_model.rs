//! Two independent implementations agree: the simulator's true robot (robocal-mocks' own
//! URDF-chain FK with hidden geometric errors and zero offsets) versus the root crate's MDH +
//! Hayati model built with `KinematicModel::from_chain` from the same true geometry, with the
//! offsets put into the `phi{i}` parameters and the tracker/marker placement into base/tool.
//! Every effect off and zero noise: the world's noise-free marker positions must equal the
//! model's `measured_point` to ≤ 1e-9 mm on 10,000 random joint vectors per preset.

use nalgebra::DVector;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use robocal::dataset::{ChainJoint, FixedOrigin};
use robocal::model::KinematicModel;
use robocal_mocks::scenario::Scenario;
use robocal_mocks::world::effects::JointContext;
use robocal_mocks::WorldHandle;
use serde_json::Map;

fn check_preset(model: &str, seed: u64) -> f64 {
    let scenario = Scenario::single_arm(model, seed);
    let world = WorldHandle::from_scenario(&scenario).unwrap();
    let truth = world.truth();
    let arm = &truth.arms[0].physics;
    let tr = &truth.trackers[0];
    let chain: Vec<ChainJoint> = arm
        .chain
        .joints
        .iter()
        .map(|j| ChainJoint {
            name: j.name.clone(),
            origin_xyz: [j.origin_xyz_mm.x, j.origin_xyz_mm.y, j.origin_xyz_mm.z],
            origin_rpy: [
                j.origin_rpy_rad.x.to_degrees(),
                j.origin_rpy_rad.y.to_degrees(),
                j.origin_rpy_rad.z.to_degrees(),
            ],
            axis: [j.axis.x, j.axis.y, j.axis.z],
            limits: None,
            extra: Map::new(),
        })
        .collect();
    let flange = FixedOrigin {
        origin_xyz: arm.chain.flange_xyz_mm.into(),
        origin_rpy: arm.chain.flange_rpy_rad.map(f64::to_degrees).into(),
        extra: Map::new(),
    };
    let mut m = KinematicModel::from_chain(&chain, Some(&flange)).unwrap();
    let mut v: DVector<f64> = m.param_values();
    for (i, off) in arm.offsets_rad.iter().enumerate() {
        let k = m.param_index(&format!("phi{}", i + 1)).unwrap();
        v[k] += off;
    }
    m.set_param_values(&v);
    m.set_base(&tr.tracker_in_base.inverse());
    m.set_tool(&tr.marker_on_flange);

    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let ctx = JointContext::at_rest(arm.chain.dof());
    let mut worst: f64 = 0.0;
    for _ in 0..10_000 {
        let q: Vec<f64> = arm
            .nominal
            .joints
            .iter()
            .map(|j| rng.random_range(j.limits_rad.0..=j.limits_rad.1))
            .collect();
        let world_p = tr.tracker_in_base.inverse()
            * arm.true_flange(&q, &ctx)
            * tr.marker_on_flange
            * nalgebra::Point3::origin();
        let model_p = m.measured_point(&q);
        worst = worst.max((world_p - model_p).norm());
    }
    worst
}

#[test]
fn world_equals_model_on_10000_random_poses() {
    for (model, seed) in [("denso-vs060", 1), ("ur5e", 2), ("ur10e", 3)] {
        let worst = check_preset(model, seed);
        println!("world_vs_model {model}: worst |world − model| = {worst:.3e} mm");
        assert!(worst <= 1e-9, "{model}: {worst:e} mm");
    }
}
