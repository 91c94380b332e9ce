//! Joint-coupled error: the angle error of joint `joint` driven by the angle of joint
//! `driver` (wrist cross-talk, cable/hose torque, encoder coupling):
//! `δθ_joint = a sin q_driver + b cos q_driver` (kind `joint_coupling`).
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::file::{self, EffectFileError};
use super::{amplitude_deg, deg_param, q_at, spread, Coefs, EffectModel, Family, SinCosFile};
use crate::dataset::CalEffect;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// Joint `joint`'s error driven by joint `driver`'s angle (both 1-based): two coefficients
/// (rad).
#[derive(Debug, Clone, PartialEq)]
pub struct Coupling {
    pub joint: usize,
    pub driver: usize,
}

/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct File {
    #[serde(deserialize_with = "file::count")]
    driver_joint: u64,
    #[serde(flatten)]
    pair: SinCosFile,
}

impl EffectModel for Coupling {
    fn kind(&self) -> &'static str {
        Self::KIND
    }
    fn joint(&self) -> Option<usize> {
        Some(self.joint)
    }
    fn n_params(&self) -> usize {
        2
    }
    fn param_names(&self) -> Vec<String> {
        let d = self.driver;
        vec![format!("sin q{d} [rad]"), format!("cos q{d} [rad]")]
    }
    fn label(&self) -> String {
        format!("{}(j{} ← q{})", Self::KIND, self.joint, self.driver)
    }
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        let (joint, driver) = (self.joint, self.driver);
        if joint >= 1 && joint <= model.dof() && driver >= 1 && driver <= ctx.q.len() {
            let q = ctx.q[driver - 1];
            vec![(joint - 1, 0, q.sin()), (joint - 1, 1, q.cos())]
        } else {
            vec![]
        }
    }
    fn check_identifiable(&self, _model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        let (joint, driver) = (self.joint, self.driver);
        let sd = spread(train.iter().filter_map(|o| o.q.get(driver - 1).copied()));
        if joint == driver || sd < 0.1 {
            return Err(format!(
                "joint {driver} hardly moves (sd {:.2}°): it cannot drive joint {joint}",
                sd.to_degrees()
            ));
        }
        Ok(())
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        let d = self.driver;
        vec![
            deg_param(&format!("sin_q{d}"), c, 0),
            deg_param(&format!("cos_q{d}"), c, 1),
        ]
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&File {
            driver_joint: self.driver as u64,
            pair: SinCosFile::of(c),
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        format!(
            "joint {}'s angle error follows the angle of joint {} (cross-talk, cable or hose \
             torque) with an amplitude of {}°",
            self.joint,
            self.driver,
            super::plain_number(amplitude_deg(c), 4)
        )
    }
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        let q = q_at(o, self.driver);
        (q.to_degrees(), format!("q{} (deg)", self.driver))
    }
}

impl Family for Coupling {
    const KIND: &'static str = "joint_coupling";
    type File = File;
    fn from_file(e: &CalEffect, f: File) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        if !(1..=64).contains(&f.driver_joint) {
            return Err(EffectFileError::invalid(
                e,
                "\"driver_joint\" must be a joint number ≥ 1".into(),
            ));
        }
        let (c, std) = f.pair.coefs();
        Ok((
            Coupling {
                joint: file::joint(e)?,
                driver: f.driver_joint as usize,
            },
            c,
            std,
        ))
    }
    fn joint_candidates(
        model: &KinematicModel,
        _opt: &crate::diagnose::Options,
        j: usize,
    ) -> Vec<Vec<Self>> {
        // One group per affected joint; every driver counts as a test.
        vec![(1..=model.dof())
            .filter(|&d| d != j)
            .map(|driver| Coupling { joint: j, driver })
            .collect()]
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (
            Coupling {
                joint: 5,
                driver: 4,
            },
            vec![2e-4, -1e-4],
        )
    }
}
