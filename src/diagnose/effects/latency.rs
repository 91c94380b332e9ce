//! Timing latency between the robot's and the tracker's streams: `y(t) = p(t − Δt)`, i.e.
//! `δθ = −q̇ Δt` (needs recorded joint velocities `qd`; kind `latency`).
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::file::{self, lenient, EffectFileError};
use super::{pm, Coefs, EffectModel, Family};
use crate::dataset::CalEffect;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// The latency: one coefficient (s).
#[derive(Debug, Clone, PartialEq)]
pub struct Latency;

/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct File {
    latency_s: f64,
    #[serde(default = "file::nan", deserialize_with = "lenient")]
    std: f64,
}

impl EffectModel for Latency {
    fn kind(&self) -> &'static str {
        Self::KIND
    }
    fn n_params(&self) -> usize {
        1
    }
    fn param_names(&self) -> Vec<String> {
        vec!["latency [s]".into()]
    }
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        match &ctx.qd {
            Some(qd) => qd
                .iter()
                .take(model.dof())
                .enumerate()
                .map(|(j, v)| (j, 0, -v))
                .collect(),
            None => vec![],
        }
    }
    fn check_identifiable(&self, _model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        let with_qd = train.iter().filter(|o| o.qd.is_some()).count();
        if with_qd * 2 >= train.len() && with_qd > 0 {
            Ok(())
        } else {
            Err("records carry no joint velocity (stop-and-measure data): latency is unobservable and irrelevant".into())
        }
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        vec![EffectParameter::new("latency", "s", c.v(0), c.s(0))]
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&File {
            latency_s: c.v(0),
            std: c.s(0),
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        format!(
            "the tracker's and the robot's clocks are offset by {} ms{}",
            super::plain_number(c.v(0) * 1e3, 2),
            pm(c.s(0) * 1e3, " ms")
        )
    }
}

impl Family for Latency {
    const KIND: &'static str = "latency";
    type File = File;
    fn from_file(_e: &CalEffect, f: File) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        Ok((Latency, vec![f.latency_s], vec![f.std]))
    }
    fn global_candidates(
        _model: &KinematicModel,
        _train: &[PoseObs],
        _opt: &crate::diagnose::Options,
    ) -> Vec<Vec<super::Block>> {
        vec![vec![Latency.into()]]
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (Latency, vec![0.004])
    }
}
