//! Transmission errors of one joint: the ratio error `δθ_j = ε · q_j` (kind
//! `transmission_ratio`) and the ripple at harmonic `k` ≥ 3 of the joint's rotation (gear
//! tooth / bearing / harmonic-drive flexspline errors), `δθ_j = a sin kq + b cos kq` (kind
//! `transmission_ripple`; harmonics 1 and 2 are [`super::Eccentricity`]).
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::file::{self, lenient, EffectFileError};
use super::{
    amplitude_deg, deg_param, joint_angle, pm, q_at, spread, Coefs, EffectModel, Family, SinCosFile,
};
use crate::dataset::CalEffect;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// Transmission-ratio error of `joint` (1-based): one coefficient (1).
#[derive(Debug, Clone, PartialEq)]
pub struct Transmission {
    pub joint: usize,
}

/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct RatioFile {
    ratio_error_ppm: f64,
    #[serde(default = "file::nan", deserialize_with = "lenient")]
    std: f64,
}

impl EffectModel for Transmission {
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
        vec!["ratio error [1]".into()]
    }
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        match joint_angle(model, ctx, self.joint) {
            Some(q) => vec![(self.joint - 1, 0, q)],
            None => vec![],
        }
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        vec![EffectParameter::new(
            "ratio_error",
            "ppm",
            c.v(0) * 1e6,
            c.s(0) * 1e6,
        )]
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&RatioFile {
            ratio_error_ppm: c.v(0) * 1e6,
            std: c.s(0) * 1e6,
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        format!(
            "joint {}'s gear ratio differs from nominal by {} ppm{}: {}° of error over a 90° move",
            self.joint,
            super::plain_number(c.v(0) * 1e6, 1),
            pm(c.s(0) * 1e6, " ppm"),
            super::plain_number(c.v(0) * 90.0, 4)
        )
    }
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        let q = q_at(o, self.joint);
        (q.to_degrees(), format!("q{} (deg)", self.joint))
    }
}

impl Family for Transmission {
    const KIND: &'static str = "transmission_ratio";
    type File = RatioFile;
    fn from_file(
        e: &CalEffect,
        f: RatioFile,
    ) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        Ok((
            Transmission {
                joint: file::joint(e)?,
            },
            vec![f.ratio_error_ppm * 1e-6],
            vec![f.std * 1e-6],
        ))
    }
    fn joint_candidates(
        _model: &KinematicModel,
        _opt: &crate::diagnose::Options,
        j: usize,
    ) -> Vec<Vec<Self>> {
        vec![vec![Transmission { joint: j }]]
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (Transmission { joint: 4 }, vec![4e-4])
    }
}

/// Transmission ripple of `joint` (1-based) at `harmonic` cycles per turn: two
/// coefficients (rad).
#[derive(Debug, Clone, PartialEq)]
pub struct Ripple {
    pub joint: usize,
    pub harmonic: u32,
}

/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct RippleFile {
    #[serde(deserialize_with = "file::count")]
    harmonic: u64,
    #[serde(flatten)]
    pair: SinCosFile,
}

impl EffectModel for Ripple {
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
        vec![format!("sin {h}q [rad]"), format!("cos {h}q [rad]")]
    }
    fn label(&self) -> String {
        format!("{}(j{}, ×{})", Self::KIND, self.joint, self.harmonic)
    }
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        match joint_angle(model, ctx, self.joint) {
            Some(q) => {
                let k = f64::from(self.harmonic);
                vec![
                    (self.joint - 1, 0, (k * q).sin()),
                    (self.joint - 1, 1, (k * q).cos()),
                ]
            }
            None => vec![],
        }
    }
    fn check_identifiable(&self, _model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        let (joint, harmonic) = (self.joint, self.harmonic);
        if harmonic <= 4 {
            return Ok(());
        }
        // A high harmonic needs the joint to sweep at least one of its periods (else it is
        // a smooth function of q over the data, confounded with the offset and eccentricity).
        let sd = spread(train.iter().filter_map(|o| o.q.get(joint - 1).copied()));
        let period = std::f64::consts::TAU / f64::from(harmonic);
        if sd < period {
            return Err(format!(
                "joint {joint} moves less than one period of harmonic {harmonic} (sd {:.2}°, period {:.2}°)",
                sd.to_degrees(),
                period.to_degrees()
            ));
        }
        Ok(())
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        let h = self.harmonic;
        vec![
            deg_param(&format!("sin{h}"), c, 0),
            deg_param(&format!("cos{h}"), c, 1),
        ]
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&RippleFile {
            harmonic: u64::from(self.harmonic),
            pair: SinCosFile::of(c),
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        format!(
            "joint {}'s transmission ripples {} times per turn with an amplitude of {}°",
            self.joint,
            self.harmonic,
            super::plain_number(amplitude_deg(c), 4)
        )
    }
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        let q = q_at(o, self.joint);
        (
            (f64::from(self.harmonic) * q)
                .to_degrees()
                .rem_euclid(360.0),
            format!("phase {}·q{} (deg, mod 360)", self.harmonic, self.joint),
        )
    }
}

impl Family for Ripple {
    const KIND: &'static str = "transmission_ripple";
    type File = RippleFile;
    fn from_file(
        e: &CalEffect,
        f: RippleFile,
    ) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        if !(1..=100_000).contains(&f.harmonic) {
            return Err(EffectFileError::invalid(
                e,
                "\"harmonic\" must be an integer ≥ 1".into(),
            ));
        }
        let (c, std) = f.pair.coefs();
        Ok((
            Ripple {
                joint: file::joint(e)?,
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
        // A group, so every harmonic counts as a test.
        vec![opt
            .ripple_harmonics
            .iter()
            .map(|&harmonic| Ripple { joint: j, harmonic })
            .collect()]
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (
            Ripple {
                joint: 3,
                harmonic: 4,
            },
            vec![1.5e-4, -2.5e-5],
        )
    }
}
