//! Tracker–base shift ("tripod bump"): the base pose changes by a small twist after
//! `t_change` (s) (kind `base_shift`).
use nalgebra::{Matrix3xX, Point3, Vector3};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};
use std::borrow::Cow;

use super::file::{self, lenient_vec, EffectFileError};
use super::{Coefs, EffectModel, Family};
use crate::dataset::CalEffect;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// A base shift at `t_change` (s): six coefficients (mm, mm, mm, rad, rad, rad) added to
/// the base parameters from then on.
#[derive(Debug, Clone, PartialEq)]
pub struct BaseShift {
    pub t_change: f64,
}

const SUFFIXES: [&str; 6] = ["x", "y", "z", "rx", "ry", "rz"];

/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct File {
    t_change_s: f64,
    dx_mm: f64,
    dy_mm: f64,
    dz_mm: f64,
    drx_deg: f64,
    dry_deg: f64,
    drz_deg: f64,
    /// mm for the translations, deg for the rotations.
    #[serde(default, deserialize_with = "lenient_vec")]
    std: Vec<f64>,
}

/// File units of coefficient `k` from internal ones (mm stay, rad → deg) and back.
fn to_file(k: usize, v: f64) -> f64 {
    if k < 3 {
        v
    } else {
        v.to_degrees()
    }
}
fn from_file(k: usize, v: f64) -> f64 {
    if k < 3 {
        v
    } else {
        v.to_radians()
    }
}

impl EffectModel for BaseShift {
    fn kind(&self) -> &'static str {
        Self::KIND
    }
    fn n_params(&self) -> usize {
        6
    }
    fn param_names(&self) -> Vec<String> {
        [
            "dx [mm]",
            "dy [mm]",
            "dz [mm]",
            "drx [rad]",
            "dry [rad]",
            "drz [rad]",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect()
    }
    fn label(&self) -> String {
        format!("{}(t≥{:.1}s)", Self::KIND, self.t_change)
    }
    fn apply_frame(&self, coefs: &[f64], out: &mut Cow<KinematicModel>, ctx: &PoseCtx) {
        if ctx.t < self.t_change || coefs.len() != 6 {
            return;
        }
        let m = out.to_mut();
        for (k, sfx) in SUFFIXES.iter().enumerate() {
            let name = format!("base_{sfx}");
            if let Some(v) = m.param(&name) {
                let _ = m.set_param(&name, v + coefs[k]);
            }
        }
    }
    fn columns(
        &self,
        model: &KinematicModel,
        jm: &Matrix3xX<f64>,
        _p: &Point3<f64>,
        ctx: &PoseCtx,
    ) -> Vec<Vector3<f64>> {
        let mut cols = vec![Vector3::zeros(); 6];
        if ctx.t >= self.t_change {
            for (k, sfx) in SUFFIXES.iter().enumerate() {
                if let Some(ip) = model.param_index(&format!("base_{sfx}")) {
                    cols[k] = jm.column(ip).into_owned();
                }
            }
        }
        cols
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        let mut v = vec![EffectParameter::new(
            "t_change",
            "s",
            self.t_change,
            f64::NAN,
        )];
        for (k, n) in ["dx", "dy", "dz"].iter().enumerate() {
            v.push(EffectParameter::new(n, "mm", c.v(k), c.s(k)));
        }
        for (k, n) in ["drx", "dry", "drz"].iter().enumerate() {
            v.push(EffectParameter::new(
                n,
                "deg",
                c.v(3 + k).to_degrees(),
                c.s(3 + k).to_degrees(),
            ));
        }
        v
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&File {
            t_change_s: self.t_change,
            dx_mm: c.v(0),
            dy_mm: c.v(1),
            dz_mm: c.v(2),
            drx_deg: c.v(3).to_degrees(),
            dry_deg: c.v(4).to_degrees(),
            drz_deg: c.v(5).to_degrees(),
            std: c
                .std
                .iter()
                .enumerate()
                .map(|(k, v)| to_file(k, *v))
                .collect(),
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        let shift = Vector3::new(c.v(0), c.v(1), c.v(2)).norm();
        let turn = Vector3::new(c.v(3), c.v(4), c.v(5)).norm().to_degrees();
        format!(
            "the tracker or the robot base moved at t = {:.1} s, by {} mm and {}°",
            self.t_change,
            super::plain_number(shift, 4),
            super::plain_number(turn, 4)
        )
    }
}

impl Family for BaseShift {
    const KIND: &'static str = "base_shift";
    type File = File;
    fn from_file(_e: &CalEffect, f: File) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        Ok((
            BaseShift {
                t_change: f.t_change_s,
            },
            vec![
                f.dx_mm,
                f.dy_mm,
                f.dz_mm,
                f.drx_deg.to_radians(),
                f.dry_deg.to_radians(),
                f.drz_deg.to_radians(),
            ],
            f.std
                .iter()
                .enumerate()
                .map(|(k, v)| from_file(k, *v))
                .collect(),
        ))
    }
    /// A grid of change points half-way between consecutive poses (needs ≥ 20 poses).
    fn global_candidates(
        _model: &KinematicModel,
        train: &[PoseObs],
        _opt: &crate::diagnose::Options,
    ) -> Vec<Vec<super::Block>> {
        let t0 = train.iter().map(|o| o.t).fold(f64::INFINITY, f64::min);
        let t1 = train.iter().map(|o| o.t).fold(f64::NEG_INFINITY, f64::max);
        if train.len() < 20 || t1 <= t0 {
            return vec![];
        }
        let mut ts: Vec<f64> = train.iter().map(|o| o.t).collect();
        ts.sort_by(|a, b| a.total_cmp(b));
        vec![(2..=18)
            .map(|k| {
                let i = k * (ts.len() - 1) / 20;
                // change point half-way between two consecutive poses
                let t = 0.5 * (ts[i] + ts[(i + 1).min(ts.len() - 1)]);
                BaseShift { t_change: t }.into()
            })
            .collect()]
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (
            BaseShift { t_change: 50.0 },
            vec![0.3, -0.2, 0.1, 2e-4, -1e-4, 3e-4],
        )
    }
}
