//! Built-in robot presets: `denso-vs060` (the public vs060 URDF geometry, exactly the chain in
//! the kin-geometric dataset header), `ur5e` and `ur10e` (Universal Robots' published DH).
use std::f64::consts::FRAC_PI_2;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use super::chain::{origin_iso, ChainSpecJoint, SerialChain};
use super::error::ModelError;
use super::KinematicModel;

/// Names accepted by [`preset`].
pub const PRESET_NAMES: [&str; 3] = ["denso-vs060", "ur5e", "ur10e"];

fn joint(name: &str, xyz: [f64; 3], axis: [f64; 3], lim_deg: f64) -> ChainSpecJoint {
    ChainSpecJoint {
        name: name.into(),
        origin: origin_iso(xyz, [0.0; 3]),
        axis: nalgebra::UnitVector3::new_normalize(Vector3::from(axis)),
        limits: Some((-lim_deg.to_radians(), lim_deg.to_radians())),
    }
}

/// The VS060 chain (mm, rad) of the dataset header.
pub fn vs060_chain() -> SerialChain {
    let mut j = vec![
        joint("joint_1", [0.0, 0.0, 181.5], [0.0, 0.0, 1.0], 170.0),
        joint("joint_2", [0.0, 0.0, 163.5], [0.0, 1.0, 0.0], 120.0),
        joint("joint_3", [0.0, 0.0, 305.0], [0.0, 1.0, 0.0], 0.0),
        joint("joint_4", [-10.0, 0.0, 164.5], [0.0, 0.0, 1.0], 270.0),
        joint("joint_5", [0.0, 0.0, 135.5], [0.0, 1.0, 0.0], 120.0),
        joint("joint_6", [0.0, 0.0, 70.0], [0.0, 0.0, 1.0], 360.0),
    ];
    j[2].limits = Some(((-125f64).to_radians(), 155f64.to_radians()));
    SerialChain {
        joints: j,
        flange: Isometry3::identity(),
    }
}

/// A chain whose FK equals standard DH `Π Rz(θ_i)·Tz(d_i)·Tx(a_i)·Rx(α_i)`.
pub fn dh_chain(dh: &[(f64, f64, f64)], limits_deg: &[f64]) -> SerialChain {
    // dh: (d, a, alpha)
    let mut joints = Vec::with_capacity(dh.len());
    let mut prev = Isometry3::identity();
    for (i, &(d, a, alpha)) in dh.iter().enumerate() {
        let lim = limits_deg.get(i).copied().unwrap_or(360.0).to_radians();
        joints.push(ChainSpecJoint {
            name: format!("joint_{}", i + 1),
            origin: prev,
            axis: Vector3::z_axis(),
            limits: Some((-lim, lim)),
        });
        prev = Isometry3::from_parts(
            Translation3::new(a, 0.0, d),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), alpha),
        );
    }
    SerialChain {
        joints,
        flange: prev,
    }
}

/// UR standard DH `(d, a, α)` for the UR5e.
pub const UR5E_DH: [(f64, f64, f64); 6] = [
    (162.5, 0.0, FRAC_PI_2),
    (0.0, -425.0, 0.0),
    (0.0, -392.2, 0.0),
    (133.3, 0.0, FRAC_PI_2),
    (99.7, 0.0, -FRAC_PI_2),
    (99.6, 0.0, 0.0),
];
/// UR standard DH `(d, a, α)` for the UR10e.
pub const UR10E_DH: [(f64, f64, f64); 6] = [
    (180.7, 0.0, FRAC_PI_2),
    (0.0, -612.7, 0.0),
    (0.0, -571.55, 0.0),
    (174.15, 0.0, FRAC_PI_2),
    (119.85, 0.0, -FRAC_PI_2),
    (116.55, 0.0, 0.0),
];
/// UR e-Series limits (deg): ±360° except the elbow (±180°), as in `ur_description`.
pub const UR_LIMITS_DEG: [f64; 6] = [360.0, 360.0, 180.0, 360.0, 360.0, 360.0];

/// Build a preset model by name (case-insensitive; `vs060` is accepted for `denso-vs060`).
pub fn preset(name: &str) -> Result<KinematicModel, ModelError> {
    let key = name.trim().to_ascii_lowercase();
    let (chain, canonical) = match key.as_str() {
        "denso-vs060" | "vs060" | "denso_vs060" => (vs060_chain(), "denso-vs060"),
        "ur5e" | "ur5-e" => (dh_chain(&UR5E_DH, &UR_LIMITS_DEG), "ur5e"),
        "ur10e" | "ur10-e" => (dh_chain(&UR10E_DH, &UR_LIMITS_DEG), "ur10e"),
        _ => {
            return Err(ModelError::UnknownPreset {
                name: name.to_string(),
            })
        }
    };
    KinematicModel::from_serial_chain(&chain, canonical)
}
