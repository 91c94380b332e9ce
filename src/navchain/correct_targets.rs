//! `robocal correct` with seed 003's correction network: the calibrated robot
//! puts its tool at `FK(q) + c(q)`, `c` the network's position correction (trained in the
//! tracker frame, rotated into the robot base here). The corrected joints solve
//! `FK(q) + c(q) = target` by a fixed point on the identified model's inverse kinematics
//! (target shifted by `−c(q)`, same IK branch), which converges because `c` changes little
//! with `q` (tenths of a mm over the corrections involved). The orientation is the identified
//! model's: the network corrects positions only.
use anyhow::{bail, Context as _};
use nalgebra::{Isometry3, Translation3, Vector3};

use crate::model::KinematicModel;
use crate::schema::navnet::NavNetBlock;
use crate::solve::correct::{correct_targets, Corrected, Target};

/// Fixed-point iterations at most, and the position (mm) the result must reach.
const MAX_ITER: usize = 30;
const TOL_MM: f64 = 1e-4;

/// The network's correction of the tool position in the robot base (mm) at joints `q` (rad).
pub fn correction_in_base(block: &NavNetBlock, model: &KinematicModel, q: &[f64]) -> Vector3<f64> {
    let c = crate::navchain::correction::correction(block, model, q);
    model.base().rotation.inverse() * c
}

/// Where the calibrated robot with the network puts the tool position at `q` (base, mm).
pub fn tool_position(block: &NavNetBlock, model: &KinematicModel, q: &[f64]) -> Vector3<f64> {
    model.tool_pose_in_base(q).translation.vector + correction_in_base(block, model, q)
}

/// [`correct_targets`] with the network: each target and branch of the identified model,
/// its joints moved so that the network-corrected tool position lands on the target, the
/// nominal command's error measured on the network-corrected robot. Returns the rows and
/// the largest correction applied (mm).
pub fn correct_targets_with_net(
    calibrated: &KinematicModel,
    nominal: &KinematicModel,
    targets: &[Target],
    block: &NavNetBlock,
) -> anyhow::Result<(Vec<Corrected>, f64)> {
    let mut out = Vec::new();
    let mut largest: f64 = 0.0;
    let rows = targets
        .iter()
        .map(|t| correct_targets(calibrated, nominal, std::slice::from_ref(t)).map(|r| (t, r)));
    for (t, r0) in rows
        .collect::<anyhow::Result<Vec<_>>>()?
        .into_iter()
        .flat_map(|(t, rs)| rs.into_iter().map(move |r| (t, r)))
    {
        let goal = t.pose.translation.vector;
        let mut row = r0.clone();
        let mut miss = f64::INFINITY;
        for _ in 0..MAX_ITER {
            miss = (tool_position(block, calibrated, &row.q_corrected) - goal).norm();
            if miss < TOL_MM {
                break;
            }
            let c = correction_in_base(block, calibrated, &row.q_corrected);
            let shifted = Target {
                name: t.name.clone(),
                pose: Isometry3::from_parts(Translation3::from(goal - c), t.pose.rotation),
                branch: Some(row.branch),
            };
            row = correct_targets(calibrated, nominal, &[shifted])
                .with_context(|| format!("target `{}` shifted by the network", t.name))?
                .into_iter()
                .next()
                .context("no IK solution on the same branch")?;
        }
        if miss >= TOL_MM {
            bail!(
                "target `{}` branch {}: the network-corrected position did not converge ({miss:.4} mm \
                 off after {MAX_ITER} iterations): the network's correction changes too fast here",
                t.name,
                r0.branch
            );
        }
        largest = largest.max(correction_in_base(block, calibrated, &row.q_corrected).norm());
        // The nominal command (for the original target) on the robot with the network.
        let err = r0.q_nominal.as_ref().map(|q| {
            let got = calibrated.tool_pose_in_base(q);
            (
                (tool_position(block, calibrated, q) - goal).norm(),
                got.rotation.angle_to(&t.pose.rotation).to_degrees(),
            )
        });
        out.push(Corrected {
            nominal_pos_err_mm: err.map(|e| e.0),
            nominal_rot_err_deg: err.map(|e| e.1),
            q_nominal: r0.q_nominal,
            ..row
        });
    }
    Ok((out, largest))
}
