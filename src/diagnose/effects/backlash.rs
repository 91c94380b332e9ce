//! Backlash / lost motion: `δθ_j = b · s_j`, `s_j` the approach direction (±1) of joint `j`.
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::file::{self, lenient, EffectFileError};
use super::{deg_param, pm, Coefs, EffectModel, Family};
use crate::dataset::CalEffect;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// Backlash of `joint` (1-based): one coefficient, half the lost motion (rad).
#[derive(Debug, Clone, PartialEq)]
pub struct Backlash {
    pub joint: usize,
}

/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct File {
    half_lost_motion_deg: f64,
    #[serde(default = "file::nan", deserialize_with = "lenient")]
    half_lost_motion_std: f64,
}

impl EffectModel for Backlash {
    fn kind(&self) -> &'static str {
        Self::KIND
    }
    fn joint(&self) -> Option<usize> {
        Some(self.joint)
    }
    fn n_params(&self) -> usize {
        1
    }
    fn param_names(&self) -> Vec<String> {
        vec!["half lost motion [rad]".into()]
    }
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        let joint = self.joint;
        match ctx.approach.get(joint.wrapping_sub(1)) {
            Some(s) if joint >= 1 && joint <= model.dof() => vec![(joint - 1, 0, *s)],
            _ => vec![],
        }
    }
    fn check_identifiable(&self, _model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        let joint = self.joint;
        let side = |s: f64| {
            train
                .iter()
                .filter(|o| o.approach.get(joint - 1) == Some(&s))
                .count()
        };
        let (plus, minus) = (side(1.0), side(-1.0));
        if plus >= 5 && minus >= 5 {
            Ok(())
        } else {
            Err(format!(
                "joint {joint} is approached {plus}× from below and {minus}× from above (need ≥ 5 each)"
            ))
        }
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        vec![deg_param("half_lost_motion", c, 0)]
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&File {
            half_lost_motion_deg: c.v(0).to_degrees(),
            half_lost_motion_std: c.s(0).to_degrees(),
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        format!(
            "joint {} loses {}° of motion when it reverses (backlash: {}° each way{})",
            self.joint,
            super::plain_number(2.0 * c.v(0).abs().to_degrees(), 4),
            super::plain_number(c.v(0).to_degrees(), 4),
            pm(c.s(0).to_degrees(), "°")
        )
    }
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        (
            o.ctx
                .approach
                .get(self.joint - 1)
                .copied()
                .unwrap_or(f64::NAN),
            format!("approach direction of joint {}", self.joint),
        )
    }
}

impl Family for Backlash {
    const KIND: &'static str = "backlash";
    type File = File;
    fn from_file(e: &CalEffect, f: File) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        Ok((
            Backlash {
                joint: file::joint(e)?,
            },
            vec![f.half_lost_motion_deg.to_radians()],
            vec![f.half_lost_motion_std.to_radians()],
        ))
    }
    fn joint_candidates(
        _model: &KinematicModel,
        _opt: &crate::diagnose::Options,
        j: usize,
    ) -> Vec<Vec<Self>> {
        vec![vec![Backlash { joint: j }]]
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (Backlash { joint: 2 }, vec![3e-4])
    }
}
