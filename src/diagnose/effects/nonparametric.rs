//! The data-driven correction of the joint-space residual (a kernel ridge regression,
//! [`crate::diagnose::nonparam::Rbf`]; kind `nonparametric`): no coefficients of its own in
//! the joint fit, a correction added to the prediction.
use serde_json::{Map, Value};

use super::file::EffectFileError;
use super::{Coefs, EffectModel, Family};
use crate::dataset::CalEffect;
use crate::diagnose::nonparam::Rbf;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;

impl EffectModel for Box<Rbf> {
    fn kind(&self) -> &'static str {
        <Self as Family>::KIND
    }
    fn n_params(&self) -> usize {
        0
    }
    fn param_names(&self) -> Vec<String> {
        vec![]
    }
    fn parameters(&self, _c: &Coefs) -> Vec<EffectParameter> {
        vec![]
    }
    fn file_params(&self, _c: &Coefs) -> Map<String, Value> {
        self.to_json()
    }
    fn sentence(&self, _c: &Coefs) -> String {
        format!(
            "a residual no physical effect explains was learnt from the data (a smooth \
             correction over the joint angles from {} poses)",
            self.centers.len()
        )
    }
}

impl Family for Box<Rbf> {
    const KIND: &'static str = "nonparametric";
    type File = Map<String, Value>;
    fn from_file(
        e: &CalEffect,
        f: Map<String, Value>,
    ) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        let r = Rbf::from_json(&f).map_err(|err| EffectFileError::Invalid {
            kind: e.kind.clone(),
            why: err.to_string(),
        })?;
        Ok((Box::new(r), vec![], vec![]))
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (
            Box::new(Rbf {
                arm_frame: false,
                length_scale: 0.8,
                centers: vec![vec![0.3, -0.8, 1.2, 0.4, -0.6, 0.9]],
                weights: vec![[0.05, -0.02, 0.01]],
            }),
            vec![],
        )
    }
}
