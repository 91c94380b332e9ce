//! Joint compliance under gravity: `δθ_j = Σ_c coef_c τ_c(q)`, `τ_c` the gravity torque
//! (N·m) about joint `j` of 1 kg at mass point `c` (coef: rad·kg/(N·m) = compliance × mass).
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::file::{self, deg, lenient, lenient_vec, rad, EffectFileError};
use super::{
    gravity_torques, gravity_torques_in, mass_points, Coefs, EffectModel, Family, MassPoint,
    GRAVITY_DIR,
};
use crate::dataset::CalEffect;
use crate::model::{KinematicModel, PoseFrames};
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// Joint compliance of `joint` (1-based) with one coefficient per mass point.
#[derive(Debug, Clone, PartialEq)]
pub struct Compliance {
    pub joint: usize,
    pub points: Vec<MassPoint>,
}

impl Compliance {
    /// [`EffectModel::joint_features`] at the pose whose frames are `f` (`dof` joints).
    pub fn features_in(&self, f: &PoseFrames, dof: usize) -> Vec<(usize, usize, f64)> {
        let j = self.joint;
        if j == 0 || j > dof {
            return vec![];
        }
        gravity_torques_in(f, j, &self.points)
            .into_iter()
            .enumerate()
            .map(|(c, tau)| (j - 1, c, tau))
            .collect()
    }
}

/// The calibration-file parameters (`gravity_point_masses`).
/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct File {
    #[serde(default)]
    model: String,
    #[serde(default)]
    gravity_dir: Vec<f64>,
    points: Vec<String>,
    c_times_mass_deg_kg_per_nm: Vec<f64>,
    #[serde(default, deserialize_with = "lenient_vec")]
    c_times_mass_std: Vec<f64>,
    #[serde(default, deserialize_with = "lenient")]
    sum_c_times_mass_deg_kg_per_nm: f64,
}

/// Mass points of a file entry and their per-point coefficients (deg·kg/(N·m) in the file,
/// rad inside); `per_point` coefficients per mass point.
pub(super) fn read_points(
    e: &CalEffect,
    labels: &[String],
    coefs_deg: &[f64],
    per_point: usize,
) -> Result<(Vec<MassPoint>, Vec<f64>), EffectFileError> {
    let pts = labels
        .iter()
        .map(|v| {
            MassPoint::parse(v).ok_or_else(|| {
                EffectFileError::invalid(e, format!("bad point \"{v}\" in \"points\""))
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    if coefs_deg.len() != pts.len() * per_point {
        return Err(EffectFileError::invalid(
            e,
            format!(
                "{} points but {} coefficients (need {} per point)",
                pts.len(),
                coefs_deg.len(),
                per_point
            ),
        ));
    }
    Ok((pts, rad(coefs_deg)))
}

/// "the frame-3 origin, the flange and the marker".
pub(super) fn points_in_words(points: &[MassPoint]) -> String {
    let w: Vec<String> = points.iter().map(|p| p.words()).collect();
    match w.len() {
        0 => "no load point".into(),
        1 => w[0].clone(),
        n => format!("{} and {}", w[..n - 1].join(", "), w[n - 1]),
    }
}

impl EffectModel for Compliance {
    fn kind(&self) -> &'static str {
        Self::KIND
    }
    fn joint(&self) -> Option<usize> {
        Some(self.joint)
    }
    fn n_params(&self) -> usize {
        self.points.len()
    }
    fn param_names(&self) -> Vec<String> {
        self.points
            .iter()
            .map(|p| format!("c·m@{} [rad·kg/Nm]", p.label()))
            .collect()
    }
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        if self.joint == 0 || self.joint > model.dof() {
            return vec![];
        }
        self.features_in(&model.pose_frames(&ctx.q), model.dof())
    }
    fn check_identifiable(&self, model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        // A vertical axis carries a constant gravity torque: absorbed by the offset.
        let joint = self.joint;
        let taus: Vec<f64> = train
            .iter()
            .map(|o| {
                gravity_torques(model, &o.q, joint, &self.points)
                    .iter()
                    .sum()
            })
            .collect();
        let n = taus.len().max(1) as f64;
        let m = taus.iter().sum::<f64>() / n;
        let sd = (taus.iter().map(|t| (t - m).powi(2)).sum::<f64>() / n).sqrt();
        if self.points.is_empty() || sd <= 0.05 {
            return Err(format!(
                "the gravity torque about joint {joint} hardly varies over the poses (sd {sd:.3} N·m per kg)"
            ));
        }
        Ok(())
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        self.points
            .iter()
            .enumerate()
            .map(|(k, pt)| {
                EffectParameter::new(
                    &format!("c_times_mass@{}", pt.label()),
                    "deg*kg/(N*m)",
                    c.v(k).to_degrees(),
                    c.s(k).to_degrees(),
                )
            })
            .collect()
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&File {
            model: "gravity_point_masses".into(),
            gravity_dir: GRAVITY_DIR.to_vec(),
            points: self.points.iter().map(|x| x.label()).collect(),
            c_times_mass_deg_kg_per_nm: deg(c.value),
            c_times_mass_std: deg(c.std),
            sum_c_times_mass_deg_kg_per_nm: c.value.iter().sum::<f64>().to_degrees(),
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        format!(
            "joint {} gives way under the gravity load it carries: {}° per N·m of gravity \
             torque per kg of load (compliance times mass, summed over {})",
            self.joint,
            super::plain_number(c.value.iter().sum::<f64>().to_degrees(), 4),
            points_in_words(&self.points)
        )
    }
    fn plot_driver(&self, model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        (
            gravity_torques(model, &o.ctx.q, self.joint, &self.points)
                .iter()
                .sum(),
            format!(
                "gravity torque about joint {} (N·m per kg, summed over mass points)",
                self.joint
            ),
        )
    }
}

impl Family for Compliance {
    const KIND: &'static str = "joint_compliance";
    type File = File;
    fn from_file(e: &CalEffect, f: File) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        let (points, c) = read_points(e, &f.points, &f.c_times_mass_deg_kg_per_nm, 1)?;
        let joint = file::joint(e)?;
        Ok((Compliance { joint, points }, c, rad(&f.c_times_mass_std)))
    }
    fn joint_candidates(
        model: &KinematicModel,
        _opt: &crate::diagnose::Options,
        j: usize,
    ) -> Vec<Vec<Self>> {
        vec![vec![Compliance {
            joint: j,
            points: mass_points(model, j),
        }]]
    }
    fn example(model: &KinematicModel) -> (Self, Vec<f64>) {
        let points = mass_points(model, 2);
        let n = points.len();
        (Compliance { joint: 2, points }, vec![2e-4; n])
    }
}
