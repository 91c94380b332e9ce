//! The robot of an imported dataset (`--robot`): a built-in preset name, `ur10` (the UR10 CB3
//! nominal chain of the IPA dataset, `robots/ur10.json`), `ur5` (the UR5 CB3 chain,
//! `robots/ur5.json`), a chain JSON file (a header `robot`
//! block) or a URDF file. The header always gets a full `robot` block that loads back.
use std::path::Path;

use super::error::ImportError;
use crate::dataset::{ChainJoint, FixedOrigin, RobotBlock};
use crate::model::chain::SerialChain;
use crate::model::KinematicModel;

/// The UR10 (CB3) nominal chain: Universal Robots' published DH written URDF-style (mm, deg),
/// exactly `shared/data/real-ur10-ipa-grid/robot_chain.json`.
pub const UR10_CHAIN_JSON: &str = include_str!("../../robots/ur10.json");

/// The UR10 robot block.
pub fn ur10() -> RobotBlock {
    // The embedded file is checked by a unit test.
    serde_json::from_str(UR10_CHAIN_JSON).unwrap_or_else(|_| RobotBlock::named("ur10"))
}

/// The UR5 (CB3) nominal chain: Universal Robots' published DH (d1 89.159, a2 −425,
/// a3 −392.25, d4 109.15, d5 94.65, d6 82.3 mm) written URDF-style like the UR10's; the
/// robot of `pauljac7700/serial_robots_datasets` (its targets are this chain's forward
/// kinematics to 0.012 mm RMS).
pub const UR5_CHAIN_JSON: &str = include_str!("../../robots/ur5.json");

/// The UR5 (CB3) robot block.
pub fn ur5() -> RobotBlock {
    // The embedded file is checked by a unit test.
    serde_json::from_str(UR5_CHAIN_JSON).unwrap_or_else(|_| RobotBlock::named("ur5"))
}

fn iso_to_origin(iso: &nalgebra::Isometry3<f64>) -> ([f64; 3], [f64; 3]) {
    let t = iso.translation.vector;
    let (r, p, y) = iso.rotation.euler_angles();
    let clean = |v: f64| if v.abs() < 1e-12 { 0.0 } else { v };
    (
        [clean(t.x), clean(t.y), clean(t.z)],
        [
            clean(r.to_degrees()),
            clean(p.to_degrees()),
            clean(y.to_degrees()),
        ],
    )
}

/// A URDF-parsed chain as a header `robot` block (mm, deg).
pub fn robot_block_from_chain(sc: &SerialChain, model: &str) -> RobotBlock {
    let chain = sc
        .joints
        .iter()
        .map(|j| {
            let (xyz, rpy) = iso_to_origin(&j.origin);
            ChainJoint {
                name: j.name.clone(),
                origin_xyz: xyz,
                origin_rpy: rpy,
                axis: [j.axis.x, j.axis.y, j.axis.z],
                limits: j.limits.map(|(lo, hi)| [lo.to_degrees(), hi.to_degrees()]),
                extra: Default::default(),
            }
        })
        .collect();
    let (xyz, rpy) = iso_to_origin(&sc.flange);
    RobotBlock {
        model: model.into(),
        serial: None,
        chain: Some(chain),
        flange: Some(FixedOrigin {
            origin_xyz: xyz,
            origin_rpy: rpy,
            extra: Default::default(),
        }),
        extra: Default::default(),
    }
}

/// Resolve `--robot`: `ur10`, a preset name, `*.json` (a `robot` block) or `*.urdf`.
pub fn resolve(spec: &str) -> Result<RobotBlock, ImportError> {
    let lower = spec.trim().to_ascii_lowercase();
    let block = if lower == "ur10" {
        ur10()
    } else if lower == "ur5" {
        ur5()
    } else if lower.ends_with(".json") || lower.ends_with(".urdf") {
        let path = Path::new(spec);
        let text = crate::fsio::read_to_string(path).map_err(|e| ImportError::Io {
            file: spec.into(),
            source: e,
        })?;
        if lower.ends_with(".urdf") {
            let sc = SerialChain::from_urdf_str(&text, None, None)
                .map_err(|e| ImportError::bad(spec, None, None, format!("URDF: {e}")))?;
            let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("urdf");
            robot_block_from_chain(&sc, stem)
        } else {
            serde_json::from_str::<RobotBlock>(&text).map_err(|e| {
                ImportError::bad(
                    spec,
                    Some(e.line()),
                    None,
                    crate::schema::kind::with_other_kind(
                        format_args!(
                            "not a robot block (`{{\"model\": ..., \"chain\": [{{\"name\", \"origin_xyz\" mm, \"origin_rpy\" deg, \"axis\"}}, ...], \"flange\": ...}}`): {e}"
                        ),
                        &text,
                        "a robot block",
                    ),
                )
            })?
        }
    } else {
        match crate::model::presets::preset(spec) {
            Ok(m) => RobotBlock {
                model: m.name().to_string(),
                serial: None,
                chain: None,
                flange: None,
                extra: Default::default(),
            },
            Err(_) => {
                return Err(ImportError::Usage(format!(
                "--robot \"{spec}\": not a known robot (ur10, ur5, {}) nor a .json chain / .urdf file",
                crate::model::presets::PRESET_NAMES.join(", ")
            )))
            }
        }
    };
    KinematicModel::from_robot_block(&block)
        .map_err(|e| ImportError::bad(spec, None, None, format!("robot: {e}")))?;
    Ok(block)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ur10_and_presets_resolve() {
        let b = resolve("ur10").unwrap();
        assert_eq!(b.model, "ur10");
        assert_eq!(b.dof(), Some(6));
        let c = b.chain.as_ref().unwrap();
        assert_eq!(c[2].origin_xyz, [-612.0, 0.0, 0.0]);
        assert_eq!(b.flange.as_ref().unwrap().origin_xyz, [0.0, 0.0, 92.2]);
        assert_eq!(resolve("ur10e").unwrap().model, "ur10e");
        let u5 = resolve("ur5").unwrap();
        assert_eq!((u5.model.as_str(), u5.dof()), ("ur5", Some(6)));
        let c5 = u5.chain.as_ref().unwrap();
        assert_eq!(c5[1].origin_xyz, [0.0, 0.0, 89.159]);
        assert_eq!(c5[3].origin_xyz, [-392.25, 0.0, 0.0]);
        assert_eq!(u5.flange.as_ref().unwrap().origin_xyz, [0.0, 0.0, 82.3]);
        let e = resolve("ur11").unwrap_err().to_string();
        assert!(e.contains("ur11") && e.contains("ur10e"), "{e}");
    }

    /// `robots/ur5.json` and `robots/wam.json` are the published DH tables: their flange
    /// positions equal a standard-DH forward kinematics (computed independently with numpy).
    #[test]
    fn ur5_and_wam_chains_are_the_published_dh_tables() {
        let q = [0.3, -1.1, 0.7, -0.4, 1.2, 0.5, 0.2];
        let ur5 = KinematicModel::from_robot_block(&ur5()).unwrap();
        let p = ur5.flange_pose(&q[..6]).translation.vector;
        let want = [-604.16945418, -332.36072187, 609.75428498];
        assert!((p - nalgebra::Vector3::from(want)).norm() < 1e-6, "{p:?}");
        let wam_file = concat!(env!("CARGO_MANIFEST_DIR"), "/robots/wam.json");
        let wam = KinematicModel::from_robot_block(&resolve(wam_file).unwrap()).unwrap();
        assert_eq!(wam.dof(), 7);
        let p = wam.flange_pose(&q).translation.vector;
        let want = [-764.41786041, -298.73490676, 290.66965143];
        assert!((p - nalgebra::Vector3::from(want)).norm() < 1e-6, "{p:?}");
    }

    #[test]
    fn urdf_chain_round_trips_through_the_block() {
        let m = KinematicModel::from_robot_block(&ur10()).unwrap();
        let sc =
            SerialChain::from_chain_joints(ur10().chain.as_ref().unwrap(), ur10().flange.as_ref())
                .unwrap();
        let back = KinematicModel::from_robot_block(&robot_block_from_chain(&sc, "x")).unwrap();
        let q = [0.3, -1.1, 0.7, -0.4, 1.2, 0.5];
        let d =
            (m.flange_pose(&q).translation.vector - back.flange_pose(&q).translation.vector).norm();
        assert!(d < 1e-9, "{d}");
    }
}
