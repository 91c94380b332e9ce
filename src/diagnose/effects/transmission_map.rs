//! The transmission error map of one joint (kind `transmission_error_map`): the gear train's
//! angular transmission error as a function of the joint's own angle over a whole turn, a
//! Fourier series `δθ_j = Σ_{h=1..H} a_h cos hq + b_h sin hq` with many harmonics at once
//! (effects.md E6: strain-wave and gear-stage errors have output-rotation harmonics and
//! more). Where [`super::Ripple`] names one harmonic found by a test, the map takes every
//! harmonic up to `H` with a smoothness prior (a ridge on the coefficients, chosen by
//! time-blocked cross-validation: [`crate::diagnose::transmap`]); it is fitted after the
//! named effects, on what they leave, and never refitted without its prior. Outside the
//! training poses' range of its joint the map is held at the edge
//! ([`super::held`], as every effect): a Fourier series fitted on part of a turn says nothing
//! about the rest.
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::file::{self, EffectFileError};
use super::{joint_angle, q_at, Coefs, EffectModel, Family};
use crate::dataset::CalEffect;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// The most harmonics a file may declare (a map of 1,000 harmonics has 2,000 coefficients
/// per joint: far beyond what any calibration determines).
pub const MAX_MAP_HARMONICS: u64 = 1000;

/// The map of `joint` (1-based) with `harmonics` harmonics: `2·harmonics` coefficients
/// (rad), ordered `cos 1q, sin 1q, cos 2q, sin 2q, …`, fitted on angles `lo … hi` (rad).
#[derive(Debug, Clone, PartialEq)]
pub struct TransmissionMap {
    pub joint: usize,
    pub harmonics: u32,
    /// The joint's angle range of the poses the map was fitted on (rad).
    pub lo: f64,
    pub hi: f64,
}

/// The parameters as `calibration.json` holds them (degrees).
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct MapFile {
    #[serde(deserialize_with = "file::count")]
    harmonics: u64,
    /// `a_h` of `cos hq`, h = 1…harmonics (deg). Read leniently (a non-number becomes NaN,
    /// a non-array empty) so that the checks of `from_file` name the field and the index.
    #[serde(deserialize_with = "file::lenient_vec")]
    cos_deg: Vec<f64>,
    /// `b_h` of `sin hq` (deg).
    #[serde(deserialize_with = "file::lenient_vec")]
    sin_deg: Vec<f64>,
    /// The joint's angle range the map was fitted on, `[min, max]` (deg).
    #[serde(deserialize_with = "file::lenient_vec")]
    range_deg: Vec<f64>,
    /// Standard deviations in coefficient order (`cos 1q, sin 1q, …`, deg; may be absent).
    #[serde(default, deserialize_with = "file::lenient_vec")]
    std_deg: Vec<f64>,
}

impl TransmissionMap {
    /// `δθ` (rad) of the map with coefficients `c` at joint angle `q` (rad).
    pub fn value(c: &[f64], q: f64) -> f64 {
        c.chunks(2)
            .enumerate()
            .map(|(k, ab)| {
                let (s, co) = ((k + 1) as f64 * q).sin_cos();
                ab[0] * co + ab.get(1).copied().unwrap_or(0.0) * s
            })
            .sum()
    }

    /// RMS and largest |δθ| (rad) over the fitted range (721 samples).
    fn size(&self, c: &[f64]) -> (f64, f64) {
        let n = 720;
        let v: Vec<f64> = (0..=n)
            .map(|i| Self::value(c, self.lo + (self.hi - self.lo) * i as f64 / n as f64))
            .collect();
        let rms = (v.iter().map(|x| x * x).sum::<f64>() / n as f64).sqrt();
        (rms, v.iter().fold(0.0f64, |m, x| m.max(x.abs())))
    }
}

impl EffectModel for TransmissionMap {
    fn kind(&self) -> &'static str {
        Self::KIND
    }
    fn joint(&self) -> Option<usize> {
        Some(self.joint)
    }
    fn n_params(&self) -> usize {
        2 * self.harmonics as usize
    }
    fn param_names(&self) -> Vec<String> {
        (1..=self.harmonics)
            .flat_map(|h| [format!("cos {h}q [rad]"), format!("sin {h}q [rad]")])
            .collect()
    }
    fn label(&self) -> String {
        format!("{}(j{}, ×1–{})", Self::KIND, self.joint, self.harmonics)
    }
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        let Some(q) = joint_angle(model, ctx, self.joint) else {
            return vec![];
        };
        let j = self.joint - 1;
        (0..self.harmonics as usize)
            .flat_map(|k| {
                let (s, c) = ((k + 1) as f64 * q).sin_cos();
                [(j, 2 * k, c), (j, 2 * k + 1, s)]
            })
            .collect()
    }
    /// The map's size over its range (the coefficients themselves are in `calibration.json`:
    /// a report listing 2·H coefficients per joint says nothing a reader can use).
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        let (rms, peak) = self.size(c.value);
        let arcsec = |x: f64| x.to_degrees() * 3600.0;
        vec![
            EffectParameter::new("rms_over_range", "arcsec", arcsec(rms), f64::NAN),
            EffectParameter::new("peak_over_range", "arcsec", arcsec(peak), f64::NAN),
        ]
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        let deg = |k: usize| -> Vec<f64> {
            c.value
                .iter()
                .skip(k)
                .step_by(2)
                .map(|x| x.to_degrees())
                .collect()
        };
        file::to_params(&MapFile {
            harmonics: u64::from(self.harmonics),
            cos_deg: deg(0),
            sin_deg: deg(1),
            range_deg: vec![self.lo.to_degrees(), self.hi.to_degrees()],
            std_deg: file::deg(c.std),
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        let (rms, peak) = self.size(c.value);
        format!(
            "joint {}'s gear train has an angular transmission error that varies with its angle \
             ({} harmonics, fitted with a smoothness prior over {:.0} … {:.0}°): {} arcsec RMS, \
             {} arcsec at its largest",
            self.joint,
            self.harmonics,
            self.lo.to_degrees(),
            self.hi.to_degrees(),
            super::plain_number(rms.to_degrees() * 3600.0, 1),
            super::plain_number(peak.to_degrees() * 3600.0, 1)
        )
    }
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        let q = q_at(o, self.joint);
        (q.to_degrees(), format!("q{} (deg)", self.joint))
    }
}

impl Family for TransmissionMap {
    const KIND: &'static str = "transmission_error_map";
    type File = MapFile;
    fn from_file(e: &CalEffect, f: MapFile) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        if !(1..=MAX_MAP_HARMONICS).contains(&f.harmonics) {
            return Err(EffectFileError::invalid(
                e,
                format!("\"harmonics\" must be an integer 1…{MAX_MAP_HARMONICS}"),
            ));
        }
        let h = f.harmonics as usize;
        for (name, v) in [("cos_deg", &f.cos_deg), ("sin_deg", &f.sin_deg)] {
            if v.len() != h {
                return Err(EffectFileError::invalid(
                    e,
                    format!("\"{name}\" has {} values but \"harmonics\" is {h}", v.len()),
                ));
            }
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(EffectFileError::invalid(
                    e,
                    format!("\"{name}\"[{i}] is not a finite number (degrees expected)"),
                ));
            }
        }
        let [lo, hi] = f.range_deg[..] else {
            return Err(EffectFileError::invalid(
                e,
                format!(
                    "\"range_deg\" needs 2 values [min, max] (got {})",
                    f.range_deg.len()
                ),
            ));
        };
        if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
            return Err(EffectFileError::invalid(
                e,
                format!(
                    "\"range_deg\" must be finite [min, max] with min ≤ max (got [{lo}, {hi}])"
                ),
            ));
        }
        let coefs: Vec<f64> = f
            .cos_deg
            .iter()
            .zip(&f.sin_deg)
            .flat_map(|(a, b)| [a.to_radians(), b.to_radians()])
            .collect();
        Ok((
            TransmissionMap {
                joint: file::joint(e)?,
                harmonics: f.harmonics as u32,
                lo: lo.to_radians(),
                hi: hi.to_radians(),
            },
            coefs,
            file::rad(&f.std_deg),
        ))
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (
            TransmissionMap {
                joint: 2,
                harmonics: 3,
                lo: -2.5,
                hi: 2.0,
            },
            vec![1.2e-4, -0.8e-4, 0.5e-4, 0.9e-4, -0.3e-4, 0.4e-4],
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::effects::Effect;
    use serde_json::json;

    fn entry(params: Value) -> CalEffect {
        CalEffect {
            kind: TransmissionMap::KIND.into(),
            joint: Some(2),
            params: params.as_object().unwrap().clone(),
            extra: Map::new(),
        }
    }

    /// The file form reads back to the same map; a declared harmonic count that does not
    /// match the arrays, a non-finite value or a reversed range is refused with the field
    /// named.
    #[test]
    fn the_file_form_round_trips_and_bad_maps_are_refused() {
        let (b, c) = TransmissionMap::example(&KinematicModel::preset("denso-vs060").unwrap());
        let e = Effect {
            coefs: c.clone(),
            std: vec![1e-6; c.len()],
            ..Effect::zero(b.clone().into())
        };
        let back = Effect::from_cal(&e.to_cal()).unwrap();
        assert_eq!(back.block, e.block);
        for (a, b) in back.coefs.iter().zip(&c) {
            assert!((a - b).abs() < 1e-15);
        }
        let ok = json!({"harmonics": 2, "cos_deg": [0.01, 0.0], "sin_deg": [0.0, 0.02], "range_deg": [-90.0, 45.0]});
        assert!(Effect::from_cal(&entry(ok.clone())).is_ok());
        let err = |v: Value| Effect::from_cal(&entry(v)).unwrap_err().to_string();
        let mut v = ok.clone();
        v["harmonics"] = json!(3);
        assert!(err(v).contains("\"cos_deg\" has 2 values but \"harmonics\" is 3"));
        let mut v = ok.clone();
        v["sin_deg"] = json!([0.0, null]);
        assert!(err(v).contains("\"sin_deg\"[1] is not a finite number"));
        let mut v = ok.clone();
        v["cos_deg"] = json!("0.01");
        assert!(err(v).contains("\"cos_deg\" has 0 values"));
        let mut v = ok.clone();
        v["range_deg"] = json!([45.0, -90.0]);
        assert!(err(v).contains("range_deg"));
        let mut v = ok;
        v["harmonics"] = json!(0);
        assert!(err(v).contains("harmonics"));
    }

    /// `value` is the series the regressors describe: the joint offsets of the effect at
    /// an angle equal the sum of its features times its coefficients.
    #[test]
    fn the_value_is_the_features_times_the_coefficients() {
        let model = KinematicModel::preset("denso-vs060").unwrap();
        let (b, c) = TransmissionMap::example(&model);
        for q2 in [-2.0, -0.3, 0.7, 1.9] {
            let ctx = PoseCtx {
                q: vec![0.1, q2, 0.2, 0.0, 0.5, 0.0],
                ..Default::default()
            };
            let f: f64 = b
                .joint_features(&model, &ctx)
                .iter()
                .map(|(j, k, x)| {
                    assert_eq!(*j, 1);
                    c[*k] * x
                })
                .sum();
            assert!((f - TransmissionMap::value(&c, q2)).abs() < 1e-15);
        }
    }
}
