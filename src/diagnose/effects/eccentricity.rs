//! Encoder/gear eccentricity of one joint: `δθ_j = a1 sin q + b1 cos q + a2 sin 2q + b2 cos 2q`
//! (harmonics 1 and 2 of the joint's rotation; higher ones are [`super::Ripple`]).
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::file::{self, deg, lenient_vec, rad, EffectFileError};
use super::{deg_param, joint_angle, q_at, Coefs, EffectModel, Family};
use crate::dataset::CalEffect;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// Eccentricity of `joint` (1-based): four coefficients (rad).
#[derive(Debug, Clone, PartialEq)]
pub struct Eccentricity {
    pub joint: usize,
}

/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct File {
    sin1_deg: f64,
    cos1_deg: f64,
    sin2_deg: f64,
    cos2_deg: f64,
    #[serde(default, deserialize_with = "lenient_vec")]
    std_deg: Vec<f64>,
}

const NAMES: [&str; 4] = ["sin1", "cos1", "sin2", "cos2"];

impl EffectModel for Eccentricity {
    fn kind(&self) -> &'static str {
        Self::KIND
    }
    fn joint(&self) -> Option<usize> {
        Some(self.joint)
    }
    fn n_params(&self) -> usize {
        4
    }
    fn param_names(&self) -> Vec<String> {
        vec![
            "sin q [rad]".into(),
            "cos q [rad]".into(),
            "sin 2q [rad]".into(),
            "cos 2q [rad]".into(),
        ]
    }
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        let j = self.joint;
        match joint_angle(model, ctx, j) {
            Some(q) => vec![
                (j - 1, 0, q.sin()),
                (j - 1, 1, q.cos()),
                (j - 1, 2, (2.0 * q).sin()),
                (j - 1, 3, (2.0 * q).cos()),
            ],
            None => vec![],
        }
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        NAMES
            .iter()
            .enumerate()
            .map(|(k, n)| deg_param(n, c, k))
            .collect()
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&File {
            sin1_deg: c.v(0).to_degrees(),
            cos1_deg: c.v(1).to_degrees(),
            sin2_deg: c.v(2).to_degrees(),
            cos2_deg: c.v(3).to_degrees(),
            std_deg: deg(c.std),
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        let amp = |k: usize| c.v(k).hypot(c.v(k + 1)).to_degrees();
        format!(
            "joint {}'s angle error varies with its angle as an eccentric encoder or gear makes \
             it: {}° once per turn and {}° twice per turn (amplitudes)",
            self.joint,
            super::plain_number(amp(0), 4),
            super::plain_number(amp(2), 4)
        )
    }
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        let q = q_at(o, self.joint);
        (q.to_degrees(), format!("q{} (deg)", self.joint))
    }
}

impl Family for Eccentricity {
    const KIND: &'static str = "joint_eccentricity";
    type File = File;
    fn from_file(e: &CalEffect, f: File) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        Ok((
            Eccentricity {
                joint: file::joint(e)?,
            },
            rad(&[f.sin1_deg, f.cos1_deg, f.sin2_deg, f.cos2_deg]),
            rad(&f.std_deg),
        ))
    }
    fn joint_candidates(
        _model: &KinematicModel,
        _opt: &crate::diagnose::Options,
        j: usize,
    ) -> Vec<Vec<Self>> {
        vec![vec![Eccentricity { joint: j }]]
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (Eccentricity { joint: 3 }, vec![1e-4, -2e-4, 5e-5, 1e-4])
    }
}
