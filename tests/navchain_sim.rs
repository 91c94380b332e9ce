//! Trials of the simulated navigation chain (shared by `tests/navchain.rs` and
//! `examples/nav_chain.rs`): the world (`robocal_mocks::navchain`) measures, robocal
//! estimates, the world says where the tool tip really went.
#![allow(dead_code)]
use nalgebra::{Matrix3, Point3};
use robocal::navchain::{link_covariances, ChainInputs, CHI2_3_95};
use robocal::register::icp::{register_surface_indexed, IcpOptions, SurfaceIndex};
use robocal::register::mesh::Mesh;
use robocal::register::paired::{register_paired, PairedOptions};
use robocal::register::robot_world::{self as rw, RefineOptions, RwObs};
use robocal::register::{NamedPoint, StereoTrackerModel};
use robocal_mocks::navchain::{phantom_mesh, NavNoise, NavWorld};

/// The tracker model robocal is given (the tracker's data sheet: same physics as the world).
pub fn model_of(n: &NavNoise) -> StereoTrackerModel {
    StereoTrackerModel {
        baseline_mm: n.baseline_mm,
        focal_px: n.focal_px,
        disparity_sigma_px: n.disparity_sigma_px,
        pixel_sigma_px: n.pixel_sigma_px,
        floor_mm: 0.0,
    }
}

pub fn named(v: Vec<(String, Point3<f64>)>) -> Vec<NamedPoint> {
    v.into_iter()
        .map(|(name, p)| NamedPoint { name, p, line: 0 })
        .collect()
}

/// One chain trial's outcome.
pub struct ChainTrial {
    /// Actual tip error (base frame, mm).
    pub err: nalgebra::Vector3<f64>,
    /// Predicted covariance (first order).
    pub cov: Matrix3<f64>,
    /// Per-link variance (trace) at the target.
    pub link_var: [f64; 5],
    pub covered: bool,
}

/// One random room, one random target: register, robot-world, chain, reach.
pub fn chain_trial(seed: u64, noise: NavNoise) -> ChainTrial {
    let mut w = NavWorld::new(seed, noise);
    let model = model_of(&noise);
    let ct = named(w.ct_fiducials());
    let trk = named(w.tracker_fiducials());
    let reg = register_paired(
        &ct,
        &trk,
        &PairedOptions {
            tracker_model: Some(model),
            ct_sigma_mm: Some(noise.ct_sigma_mm),
        },
    )
    .expect("paired registration");
    let obs: Vec<RwObs> = w
        .robot_world_poses(20)
        .into_iter()
        .enumerate()
        .map(|(i, (a, b))| RwObs { id: i as u64, a, b })
        .collect();
    let start = rw::shah(&obs).expect("shah");
    let r = rw::refine(
        &obs,
        start,
        &RefineOptions {
            tracker_model: Some(model),
            sigma_pos_mm: noise.robot_sigma_mm,
            sigma_rot_deg: noise.marker_rot_sigma_deg,
        },
    )
    .expect("refine");
    let inp = ChainInputs {
        t_tracker_ct: reg.t_tracker_ct,
        cov_reg_ct: reg.cov_ct.unwrap(),
        cov_reg_tracker: reg.cov_tracker.unwrap(),
        t_base_tracker: r.y,
        cov_y: r.cov_y,
        cov_robot: Matrix3::identity() * noise.robot_sigma_mm.powi(2),
        cov_tool: Matrix3::identity() * noise.tool_sigma_mm.powi(2),
    };
    let x = w.random_target();
    let parts = link_covariances(&inp, &x);
    let cov: Matrix3<f64> = parts.iter().sum();
    let planned = r.y * (reg.t_tracker_ct * x);
    let reached = w.reach(&planned);
    let err = reached - w.true_in_base(&x);
    let d2 = (err.transpose() * cov.try_inverse().unwrap() * err)[(0, 0)];
    ChainTrial {
        err,
        cov,
        link_var: [0, 1, 2, 3, 4].map(|k| parts[k].trace()),
        covered: d2 <= CHI2_3_95,
    }
}

/// The phantom mesh as robocal reads it.
pub fn phantom() -> Mesh {
    let (v, t) = phantom_mesh(90, 180);
    Mesh {
        vertices: v
            .into_iter()
            .map(|p| Point3::new(p[0], p[1], p[2]))
            .collect(),
        triangles: t,
    }
}

/// ICP from a start `angle_deg` / `shift_mm` off the truth; returns (rotation error deg,
/// largest error at the fiducials mm).
pub fn icp_trial(idx: &SurfaceIndex, seed: u64, angle_deg: f64, shift_mm: f64) -> (f64, f64) {
    let mut w = NavWorld::new(seed, NavNoise::default());
    let pts = w.surface_points(150);
    let start = w.perturbed_start(angle_deg, shift_mm);
    let r = register_surface_indexed(idx, &pts, Some(&start), &IcpOptions::default()).expect("icp");
    let rot = r
        .t_tracker_ct
        .rotation
        .angle_to(&w.t_tracker_ct.rotation)
        .to_degrees();
    let pos = w
        .fiducials
        .iter()
        .map(|(_, p)| (r.t_tracker_ct * p - w.t_tracker_ct * p).norm())
        .fold(0.0, f64::max);
    (rot, pos)
}
