//! Tracker scale about its origin: `y = (1 + s) p` (kind `tracker_scale`). Collinear with a
//! growth of every link length: identifiable only against a length the robot side trusts.
use nalgebra::{Matrix3xX, Point3, Vector3};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::file::{self, lenient, EffectFileError};
use super::{joint_columns, pm, Coefs, EffectModel, Family};
use crate::dataset::CalEffect;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// The tracker's scale error: one coefficient (1).
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerScale;

/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct File {
    scale_ppm: f64,
    #[serde(default = "file::nan", deserialize_with = "lenient")]
    std: f64,
}

impl EffectModel for TrackerScale {
    fn kind(&self) -> &'static str {
        Self::KIND
    }
    fn n_params(&self) -> usize {
        1
    }
    fn param_names(&self) -> Vec<String> {
        vec!["scale [1]".into()]
    }
    fn columns(
        &self,
        model: &KinematicModel,
        jm: &Matrix3xX<f64>,
        p: &Point3<f64>,
        ctx: &PoseCtx,
    ) -> Vec<Vector3<f64>> {
        let mut cols = joint_columns(self, model, jm, ctx);
        cols[0] = p.coords;
        cols
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        vec![EffectParameter::new(
            "scale",
            "ppm",
            c.v(0) * 1e6,
            c.s(0) * 1e6,
        )]
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&File {
            scale_ppm: c.v(0) * 1e6,
            std: c.s(0) * 1e6,
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        format!(
            "the tracker's distances are scaled by {} ppm{} ({} mm over 1 m)",
            super::plain_number(c.v(0) * 1e6, 1),
            pm(c.s(0) * 1e6, " ppm"),
            super::plain_number(c.v(0) * 1e3, 4)
        )
    }
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        (o.p.coords.norm(), "distance from the tracker (mm)".into())
    }
}

impl Family for TrackerScale {
    const KIND: &'static str = "tracker_scale";
    type File = File;
    fn from_file(_e: &CalEffect, f: File) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        Ok((TrackerScale, vec![f.scale_ppm * 1e-6], vec![f.std * 1e-6]))
    }
    fn global_candidates(
        _model: &KinematicModel,
        _train: &[PoseObs],
        _opt: &crate::diagnose::Options,
    ) -> Vec<Vec<super::Block>> {
        vec![vec![TrackerScale.into()]]
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (TrackerScale, vec![3e-4])
    }
}
