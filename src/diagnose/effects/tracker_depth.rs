//! Tracker depth scale: an optical tracker triangulates depth (along its viewing axis, the
//! tracker's z axis) several times worse than across it, and a camera-bar baseline or
//! intrinsics error scales depth alone (`docs/effects.md` E10, its part
//! along the viewing axis). Model: `y = p + s_z (e_z·p) e_z`, `p` the predicted point in the
//! tracker frame (kind `tracker_depth_scale`). Unlike a uniform scale it is not collinear
//! with a growth of the link lengths, so robot poses alone identify it once the points
//! spread in depth.
use nalgebra::{Matrix3xX, Point3, Vector3};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::file::{self, lenient, EffectFileError};
use super::{pm, spread, Coefs, EffectModel, Family};
use crate::dataset::CalEffect;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// Depth spread (mm) of the measured points below which the depth scale is not tested.
const MIN_DEPTH_SPREAD_MM: f64 = 50.0;

/// The tracker's depth scale error: one coefficient (1).
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerDepthScale;

/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct File {
    depth_scale_ppm: f64,
    #[serde(default = "file::nan", deserialize_with = "lenient")]
    std: f64,
}

/// The depth regressor `(e_z·p) e_z` at one pose (the point at the measured angles).
fn depth_column(model: &KinematicModel, ctx: &PoseCtx) -> Vector3<f64> {
    Vector3::new(0.0, 0.0, model.measured_point(&ctx.q).z)
}

impl EffectModel for TrackerDepthScale {
    fn kind(&self) -> &'static str {
        Self::KIND
    }
    fn n_params(&self) -> usize {
        1
    }
    fn param_names(&self) -> Vec<String> {
        vec!["depth scale [1]".into()]
    }
    fn point_displacement(
        &self,
        model: &KinematicModel,
        coefs: &[f64],
        ctx: &PoseCtx,
    ) -> Option<Vector3<f64>> {
        Some(depth_column(model, ctx) * coefs.first().copied().unwrap_or(0.0))
    }
    fn columns(
        &self,
        model: &KinematicModel,
        _jm: &Matrix3xX<f64>,
        _p: &Point3<f64>,
        ctx: &PoseCtx,
    ) -> Vec<Vector3<f64>> {
        vec![depth_column(model, ctx)]
    }
    fn check_identifiable(&self, _model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        let sd = spread(train.iter().map(|o| o.p.z));
        if sd < MIN_DEPTH_SPREAD_MM {
            return Err(format!(
                "the measured points spread only {sd:.1} mm along the tracker's viewing axis (need ≥ {MIN_DEPTH_SPREAD_MM} mm)"
            ));
        }
        Ok(())
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        vec![EffectParameter::new(
            "depth_scale",
            "ppm",
            c.v(0) * 1e6,
            c.s(0) * 1e6,
        )]
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&File {
            depth_scale_ppm: c.v(0) * 1e6,
            std: c.s(0) * 1e6,
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        format!(
            "the tracker scales depth along its viewing axis by {} ppm{} more than across it \
             ({} mm at 1 m from the tracker)",
            super::plain_number(c.v(0) * 1e6, 1),
            pm(c.s(0) * 1e6, " ppm"),
            super::plain_number(c.v(0) * 1e3, 4)
        )
    }
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        (
            o.p.z,
            "depth along the tracker's viewing axis z (mm)".into(),
        )
    }
}

impl Family for TrackerDepthScale {
    const KIND: &'static str = "tracker_depth_scale";
    type File = File;
    fn from_file(_e: &CalEffect, f: File) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        Ok((
            TrackerDepthScale,
            vec![f.depth_scale_ppm * 1e-6],
            vec![f.std * 1e-6],
        ))
    }
    fn global_candidates(
        _model: &KinematicModel,
        _train: &[PoseObs],
        _opt: &crate::diagnose::Options,
    ) -> Vec<Vec<super::Block>> {
        vec![vec![TrackerDepthScale.into()]]
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (TrackerDepthScale, vec![5e-4])
    }
}
