//! Harmonic-drive wave-generator harmonics of one joint: the wave generator turns `ratio`
//! times per output turn, and its errors repeat `harmonic` times per wave-generator turn (1:
//! wave-generator eccentricity, 2: the elliptical flexspline), so
//! `δθ_j = a sin(h·N·q) + b cos(h·N·q)`, `N = ratio` (kind `wave_generator`).
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::file::{self, EffectFileError};
use super::{
    amplitude_deg, deg_param, joint_angle, q_at, spread, Coefs, EffectModel, Family, SinCosFile,
};
use crate::dataset::CalEffect;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// Wave-generator harmonic `harmonic` of `joint` (1-based) with gear ratio `ratio`: two
/// coefficients (rad).
#[derive(Debug, Clone, PartialEq)]
pub struct WaveGenerator {
    pub joint: usize,
    pub ratio: f64,
    pub harmonic: u32,
}

/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct File {
    gear_ratio: f64,
    #[serde(deserialize_with = "file::count")]
    harmonic: u64,
    #[serde(flatten)]
    pair: SinCosFile,
}

impl EffectModel for WaveGenerator {
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
        let h = self.harmonic;
        vec![format!("sin {h}Nq [rad]"), format!("cos {h}Nq [rad]")]
    }
    fn label(&self) -> String {
        format!(
            "{}(j{}, {}×N, N={})",
            Self::KIND,
            self.joint,
            self.harmonic,
            self.ratio
        )
    }
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        match joint_angle(model, ctx, self.joint) {
            Some(q) => {
                let w = f64::from(self.harmonic) * self.ratio * q;
                vec![(self.joint - 1, 0, w.sin()), (self.joint - 1, 1, w.cos())]
            }
            None => vec![],
        }
    }
    fn check_identifiable(&self, _model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        // The phase h·N·q must cover the circle: the joint must move over more than one
        // wave-generator period across the poses.
        let (joint, ratio) = (self.joint, self.ratio);
        let sd = spread(train.iter().filter_map(|o| o.q.get(joint - 1).copied()));
        let period = std::f64::consts::TAU / (f64::from(self.harmonic) * ratio);
        if ratio.is_nan() || ratio <= 0.0 || sd < 2.0 * period {
            return Err(format!(
                "joint {joint} moves less than two wave-generator periods (sd {:.3}°, period {:.3}°)",
                sd.to_degrees(),
                period.to_degrees()
            ));
        }
        Ok(())
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        vec![
            EffectParameter::new("ratio", "1", self.ratio, f64::NAN),
            deg_param("sin", c, 0),
            deg_param("cos", c, 1),
        ]
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&File {
            gear_ratio: self.ratio,
            harmonic: u64::from(self.harmonic),
            pair: SinCosFile::of(c),
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        let times = match self.harmonic {
            1 => "once".to_string(),
            2 => "twice".to_string(),
            h => format!("{h} times"),
        };
        format!(
            "joint {}'s harmonic drive errs {times} per turn of its wave generator (gear ratio \
             {}) with an amplitude of {}°",
            self.joint,
            self.ratio,
            super::plain_number(amplitude_deg(c), 5)
        )
    }
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        let q = q_at(o, self.joint);
        let (h, r, j) = (self.harmonic, self.ratio, self.joint);
        (
            (f64::from(h) * r * q).to_degrees().rem_euclid(360.0),
            format!("wave-generator phase {h}·{r}·q{j} (deg, mod 360)"),
        )
    }
}

impl Family for WaveGenerator {
    const KIND: &'static str = "wave_generator";
    type File = File;
    fn from_file(e: &CalEffect, f: File) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        if !(1..=1000).contains(&f.harmonic) {
            return Err(EffectFileError::invalid(
                e,
                "\"harmonic\" must be an integer ≥ 1".into(),
            ));
        }
        if f.gear_ratio <= 0.0 {
            return Err(EffectFileError::invalid(
                e,
                format!("\"gear_ratio\" must be > 0 (got {})", f.gear_ratio),
            ));
        }
        let (c, std) = f.pair.coefs();
        Ok((
            WaveGenerator {
                joint: file::joint(e)?,
                ratio: f.gear_ratio,
                harmonic: f.harmonic as u32,
            },
            c,
            std,
        ))
    }
    fn joint_candidates(
        _model: &KinematicModel,
        opt: &crate::diagnose::Options,
        j: usize,
    ) -> Vec<Vec<Self>> {
        if opt.wave_gear_ratio.is_nan() || opt.wave_gear_ratio <= 0.0 {
            return vec![];
        }
        vec![crate::diagnose::WAVE_HARMONICS
            .iter()
            .map(|&harmonic| WaveGenerator {
                joint: j,
                ratio: opt.wave_gear_ratio,
                harmonic,
            })
            .collect()]
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (
            WaveGenerator {
                joint: 2,
                ratio: 101.0,
                harmonic: 2,
            },
            vec![5e-5, 1e-5],
        )
    }
}
