//! Temperature-driven drift of the whole arm as one block: every link length grows by
//! `g·ΔT` and every joint offset drifts by `κ_j·ΔT`, `ΔT = temp_c − t0_c` (params
//! `[g, κ_1..κ_n]`; kind `temperature_drift`).
use nalgebra::{Matrix3xX, Point3, Vector3};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::file::{self, lenient_vec, rad, EffectFileError};
use super::{growth_column, joint_columns, Coefs, EffectModel, Family};
use crate::dataset::CalEffect;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// Joints a [`TempDrift`] carries an offset rate for (the library's arms: 6).
pub const TEMP_DRIFT_JOINTS: usize = 6;

/// Temperature drift above `t0_c` (°C): one growth rate (1/K) and an offset rate per joint
/// (rad/K).
#[derive(Debug, Clone, PartialEq)]
pub struct TempDrift {
    pub t0_c: f64,
}

/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct File {
    t0_c: f64,
    growth_ppm_per_k: f64,
    offset_deg_per_k: Vec<f64>,
    /// Growth (ppm/K), then the offsets (deg/K).
    #[serde(default, deserialize_with = "lenient_vec")]
    std: Vec<f64>,
}

impl TempDrift {
    fn delta_t(&self, ctx: &PoseCtx) -> f64 {
        ctx.temp_c.map(|t| t - self.t0_c).unwrap_or(0.0)
    }
}

impl EffectModel for TempDrift {
    fn kind(&self) -> &'static str {
        Self::KIND
    }
    // One growth rate and an offset rate per joint (the dof is not known here: the
    // library's arms have 6 joints).
    fn n_params(&self) -> usize {
        1 + TEMP_DRIFT_JOINTS
    }
    fn param_names(&self) -> Vec<String> {
        std::iter::once("growth [1/K]".to_string())
            .chain((1..=TEMP_DRIFT_JOINTS).map(|j| format!("offset j{j} [rad/K]")))
            .collect()
    }
    fn label(&self) -> String {
        format!("{}(lengths + offsets, temperature)", Self::KIND)
    }
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        let x = self.delta_t(ctx);
        (0..model.dof().min(TEMP_DRIFT_JOINTS))
            .map(|j| (j, 1 + j, x))
            .collect()
    }
    fn growth_driver(&self, ctx: &PoseCtx) -> Option<f64> {
        Some(self.delta_t(ctx))
    }
    fn columns(
        &self,
        model: &KinematicModel,
        jm: &Matrix3xX<f64>,
        _p: &Point3<f64>,
        ctx: &PoseCtx,
    ) -> Vec<Vector3<f64>> {
        let mut cols = joint_columns(self, model, jm, ctx);
        growth_column(model, jm, self.delta_t(ctx), &mut cols[0]);
        cols
    }
    fn check_identifiable(&self, _model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        let t: Vec<f64> = train.iter().filter_map(|o| o.temp_c).collect();
        if t.len() < train.len() || t.is_empty() {
            return Err("not every record carries temp_c".into());
        }
        let (lo, hi) = (
            t.iter().copied().fold(f64::INFINITY, f64::min),
            t.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        );
        if hi - lo < 0.5 {
            return Err(format!(
                "temp_c spans only {:.2} °C (need ≥ 0.5 °C)",
                hi - lo
            ));
        }
        Ok(())
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        let mut v = vec![
            EffectParameter::new("t0", "degC", self.t0_c, f64::NAN),
            EffectParameter::new("growth", "ppm/K", c.v(0) * 1e6, c.s(0) * 1e6),
        ];
        for (k, ck) in c.value.iter().enumerate().skip(1) {
            v.push(EffectParameter::new(
                &format!("offset_j{k}"),
                "deg/K",
                ck.to_degrees(),
                c.s(k).to_degrees(),
            ));
        }
        v
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&File {
            t0_c: self.t0_c,
            growth_ppm_per_k: c.v(0) * 1e6,
            offset_deg_per_k: c.value.iter().skip(1).map(|v| v.to_degrees()).collect(),
            std: c
                .std
                .iter()
                .enumerate()
                .map(|(k, v)| if k == 0 { v * 1e6 } else { v.to_degrees() })
                .collect(),
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        let (jmax, kmax) =
            c.value
                .iter()
                .enumerate()
                .skip(1)
                .fold((0, 0.0f64), |(j, m), (k, v)| {
                    if v.abs() > m.abs() {
                        (k, *v)
                    } else {
                        (j, m)
                    }
                });
        format!(
            "as the temperature rises above {:.1} °C, every link grows {} ppm per K and the joint \
             zeros drift, most at joint {jmax}: {}° per K",
            self.t0_c,
            super::plain_number(c.v(0) * 1e6, 2),
            super::plain_number(kmax.to_degrees(), 4)
        )
    }
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        (
            o.ctx.temp_c.unwrap_or(f64::NAN),
            "temperature temp_c (°C)".into(),
        )
    }
}

impl Family for TempDrift {
    const KIND: &'static str = "temperature_drift";
    type File = File;
    fn from_file(e: &CalEffect, f: File) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        if f.offset_deg_per_k.len() != TEMP_DRIFT_JOINTS {
            return Err(EffectFileError::invalid(
                e,
                format!(
                    "{} offset rates in \"offset_deg_per_k\" (need {TEMP_DRIFT_JOINTS})",
                    f.offset_deg_per_k.len()
                ),
            ));
        }
        let mut c = vec![f.growth_ppm_per_k * 1e-6];
        c.extend(rad(&f.offset_deg_per_k));
        let std = f
            .std
            .iter()
            .enumerate()
            .map(|(k, v)| if k == 0 { v * 1e-6 } else { v.to_radians() })
            .collect();
        Ok((TempDrift { t0_c: f.t0_c }, c, std))
    }
    fn global_candidates(
        _model: &KinematicModel,
        train: &[PoseObs],
        _opt: &crate::diagnose::Options,
    ) -> Vec<Vec<super::Block>> {
        if !train.iter().any(|o| o.temp_c.is_some()) {
            return vec![];
        }
        let lo = train
            .iter()
            .filter_map(|o| o.temp_c)
            .fold(f64::INFINITY, f64::min);
        vec![vec![TempDrift { t0_c: lo }.into()]]
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (
            TempDrift { t0_c: 21.5 },
            vec![1.2e-5, 1e-5, -2e-5, 3e-5, 0.0, 1e-5, -1e-5],
        )
    }
}
