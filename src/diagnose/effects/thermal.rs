//! Thermal drift by a driver (time, an exponential warm-up, or the temperature): the offset
//! of one joint drifts, `δθ_j = κ · x` ([`JointDrift`]), or every link length grows,
//! `a_i, d_i ← (1 + g·x)·a_i, d_i` ([`LengthDrift`]); both are kind `thermal_drift` in
//! files (with and without a joint).
use nalgebra::{Matrix3xX, Point3, Vector3};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::file::{self, lenient, EffectFileError};
use super::{growth_column, joint_columns, pm, Coefs, Driver, EffectModel, Family};
use crate::dataset::CalEffect;
use crate::model::KinematicModel;
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

const KIND: &str = "thermal_drift";

/// Thermal offset drift of `joint` (1-based): one coefficient (rad per driver unit).
#[derive(Debug, Clone, PartialEq)]
pub struct JointDrift {
    pub joint: usize,
    pub driver: Driver,
}

/// Thermal growth of every link length: one coefficient (1 per driver unit).
#[derive(Debug, Clone, PartialEq)]
pub struct LengthDrift {
    pub driver: Driver,
}

/// The driver in files: `driver` (`time`, `warm_up`, `temp_c`) and its reference.
#[derive(Debug, Default, Serialize, Deserialize)]
struct DriverFile {
    #[serde(default)]
    driver: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    t0_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    tau_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    t0_c: Option<f64>,
}

impl DriverFile {
    fn of(d: &Driver) -> Self {
        match *d {
            Driver::Time { t0_s } => DriverFile {
                driver: Some("time".into()),
                t0_s: Some(t0_s),
                ..Default::default()
            },
            Driver::WarmUp { t0_s, tau_s } => DriverFile {
                driver: Some("warm_up".into()),
                t0_s: Some(t0_s),
                tau_s: Some(tau_s),
                ..Default::default()
            },
            Driver::Temp { t0_c } => DriverFile {
                driver: Some("temp_c".into()),
                t0_c: Some(t0_c),
                ..Default::default()
            },
        }
    }
    fn driver(&self, e: &CalEffect) -> Result<Driver, EffectFileError> {
        let need = |v: Option<f64>, k: &str| {
            v.filter(|x| x.is_finite()).ok_or_else(|| {
                EffectFileError::invalid(e, format!("missing or bad number \"{k}\""))
            })
        };
        Ok(match self.driver.as_deref() {
            Some("temp_c") => Driver::Temp {
                t0_c: need(self.t0_c, "t0_c")?,
            },
            Some("warm_up") => Driver::WarmUp {
                t0_s: need(self.t0_s, "t0_s")?,
                tau_s: need(self.tau_s, "tau_s")?.max(1e-9),
            },
            _ => Driver::Time {
                t0_s: need(self.t0_s, "t0_s")?,
            },
        })
    }
}

/// The parameters of a drift as `calibration.json` holds them: one rate per driver unit; the
/// file names the unit in the key.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct RateFile {
    #[serde(flatten)]
    driver: DriverFile,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    target: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    deg_per_hour: Option<f64>,
    #[serde(default, rename = "deg_per_K", skip_serializing_if = "Option::is_none")]
    deg_per_k: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    deg_per_full_warm_up: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    ppm_per_hour: Option<f64>,
    #[serde(default, rename = "ppm_per_K", skip_serializing_if = "Option::is_none")]
    ppm_per_k: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    ppm_per_full_warm_up: Option<f64>,
    #[serde(default = "file::nan", deserialize_with = "lenient")]
    std: f64,
}

impl RateFile {
    /// The rate slot (`deg_per_<unit>` or `ppm_per_<unit>`) of a driver unit.
    fn slot(&mut self, deg: bool, unit: &str) -> &mut Option<f64> {
        match (deg, unit) {
            (true, "hour") => &mut self.deg_per_hour,
            (true, "K") => &mut self.deg_per_k,
            (true, _) => &mut self.deg_per_full_warm_up,
            (false, "hour") => &mut self.ppm_per_hour,
            (false, "K") => &mut self.ppm_per_k,
            (false, _) => &mut self.ppm_per_full_warm_up,
        }
    }
    fn rate(
        mut f: RateFile,
        e: &CalEffect,
        deg: bool,
    ) -> Result<(Driver, f64, f64), EffectFileError> {
        let d = f.driver.driver(e)?;
        let unit = d.unit();
        let key = format!("{}_per_{unit}", if deg { "deg" } else { "ppm" });
        let rate = f.slot(deg, unit).filter(|x| x.is_finite()).ok_or_else(|| {
            EffectFileError::invalid(e, format!("missing or bad number \"{key}\""))
        })?;
        Ok((d, rate, f.std))
    }
    fn write(d: &Driver, deg: bool, rate: f64, std: f64) -> Map<String, Value> {
        let mut f = RateFile {
            driver: DriverFile::of(d),
            target: (!deg).then(|| "link_lengths".to_string()),
            std,
            ..Default::default()
        };
        *f.slot(deg, d.unit()) = Some(rate);
        file::to_params(&f)
    }
}

fn tau_param(d: &Driver, tau_std: f64) -> Option<EffectParameter> {
    match d {
        Driver::WarmUp { tau_s, .. } => Some(EffectParameter::new("tau", "s", *tau_s, tau_std)),
        _ => None,
    }
}

/// "per hour", "per K of temperature rise", "over a full warm-up (time constant 1800 s)".
fn per_driver(d: &Driver) -> String {
    match d {
        Driver::Time { .. } => "per hour".into(),
        Driver::Temp { .. } => "per K of temperature rise".into(),
        Driver::WarmUp { tau_s, .. } => {
            format!("over a full warm-up (time constant {tau_s:.0} s)")
        }
    }
}

fn driver_axis(d: &Driver, o: &PoseObs) -> (f64, String) {
    (d.value(&o.ctx), format!("{} ({})", d.label(), d.unit()))
}

/// Whether the session spans the driver (a minute, or 0.5 °C with every record's `temp_c`).
fn check_driver(d: &Driver, train: &[PoseObs]) -> Result<(), String> {
    let (lo, hi) = match d {
        Driver::Temp { .. } => {
            let t: Vec<f64> = train.iter().filter_map(|o| o.temp_c).collect();
            if t.len() < train.len() || t.is_empty() {
                return Err("not every record carries temp_c".into());
            }
            (
                t.iter().copied().fold(f64::INFINITY, f64::min),
                t.iter().copied().fold(f64::NEG_INFINITY, f64::max) - 0.5,
            )
        }
        _ => (
            train.iter().map(|o| o.t).fold(f64::INFINITY, f64::min),
            train.iter().map(|o| o.t).fold(f64::NEG_INFINITY, f64::max) - 60.0,
        ),
    };
    if hi > lo {
        Ok(())
    } else {
        Err("the session spans less than a minute (or 0.5 °C)".into())
    }
}

impl EffectModel for JointDrift {
    fn kind(&self) -> &'static str {
        KIND
    }
    fn joint(&self) -> Option<usize> {
        Some(self.joint)
    }
    fn n_params(&self) -> usize {
        1
    }
    fn param_names(&self) -> Vec<String> {
        vec![format!("rate [rad/{}]", self.driver.unit())]
    }
    fn label(&self) -> String {
        format!("{KIND}(j{}, {})", self.joint, self.driver.label())
    }
    fn joint_features(&self, model: &KinematicModel, ctx: &PoseCtx) -> Vec<(usize, usize, f64)> {
        if self.joint >= 1 && self.joint <= model.dof() {
            vec![(self.joint - 1, 0, self.driver.value(ctx))]
        } else {
            vec![]
        }
    }
    fn check_identifiable(&self, _model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        check_driver(&self.driver, train)
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        let mut v = vec![EffectParameter::new(
            "rate",
            &format!("deg/{}", self.driver.unit()),
            c.v(0).to_degrees(),
            c.s(0).to_degrees(),
        )];
        v.extend(tau_param(&self.driver, c.tau_std));
        v
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        RateFile::write(&self.driver, true, c.v(0).to_degrees(), c.s(0).to_degrees())
    }
    fn sentence(&self, c: &Coefs) -> String {
        format!(
            "joint {}'s zero drifts {}°{} {} as the robot warms",
            self.joint,
            super::plain_number(c.v(0).to_degrees(), 4),
            pm(c.s(0).to_degrees(), "°"),
            per_driver(&self.driver)
        )
    }
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        driver_axis(&self.driver, o)
    }
}

impl Family for JointDrift {
    const KIND: &'static str = KIND;
    fn claims(e: &CalEffect) -> bool {
        e.kind == KIND && e.joint.is_some()
    }
    type File = RateFile;
    fn from_file(
        e: &CalEffect,
        f: RateFile,
    ) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        let (driver, rate, std) = RateFile::rate(f, e, true)?;
        Ok((
            JointDrift {
                joint: file::joint(e)?,
                driver,
            },
            vec![rate.to_radians()],
            vec![std.to_radians()],
        ))
    }
    /// The drifts of every joint and of the link lengths, by each driver: a time-driven
    /// drift is either linear or an exponential warm-up with an unknown time constant, so one
    /// group per (kind, joint) holds the linear drift and a log grid of τ (every grid point
    /// counts as a test); the accepted τ is refined by [`crate::diagnose::refine_tau`].
    fn global_candidates(
        model: &KinematicModel,
        train: &[PoseObs],
        _opt: &crate::diagnose::Options,
    ) -> Vec<Vec<super::Block>> {
        let n = model.dof();
        let t0 = train.iter().map(|o| o.t).fold(f64::INFINITY, f64::min);
        let t1 = train.iter().map(|o| o.t).fold(f64::NEG_INFINITY, f64::max);
        let mut drivers = vec![Driver::Time { t0_s: t0 }];
        if train.iter().any(|o| o.temp_c.is_some()) {
            let lo = train
                .iter()
                .filter_map(|o| o.temp_c)
                .fold(f64::INFINITY, f64::min);
            drivers.push(Driver::Temp { t0_c: lo });
        }
        let taus = crate::diagnose::tau_grid(t1 - t0);
        let mut groups = Vec::new();
        for d in &drivers {
            let variants: Vec<Driver> = match d {
                Driver::Time { t0_s } => std::iter::once(*d)
                    .chain(
                        taus.iter()
                            .map(|&tau_s| Driver::WarmUp { t0_s: *t0_s, tau_s }),
                    )
                    .collect(),
                _ => vec![*d],
            };
            for j in 1..=n {
                groups.push(
                    variants
                        .iter()
                        .map(|&driver| JointDrift { joint: j, driver }.into())
                        .collect(),
                );
            }
            groups.push(
                variants
                    .iter()
                    .map(|&driver| LengthDrift { driver }.into())
                    .collect(),
            );
        }
        groups
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (
            JointDrift {
                joint: 2,
                driver: Driver::WarmUp {
                    t0_s: 0.0,
                    tau_s: 900.0,
                },
            },
            vec![6e-4],
        )
    }
}

impl EffectModel for LengthDrift {
    fn kind(&self) -> &'static str {
        KIND
    }
    fn n_params(&self) -> usize {
        1
    }
    fn param_names(&self) -> Vec<String> {
        vec![format!("growth [1/{}]", self.driver.unit())]
    }
    fn label(&self) -> String {
        format!("{KIND}(link lengths, {})", self.driver.label())
    }
    fn growth_driver(&self, ctx: &PoseCtx) -> Option<f64> {
        Some(self.driver.value(ctx))
    }
    fn columns(
        &self,
        model: &KinematicModel,
        jm: &Matrix3xX<f64>,
        _p: &Point3<f64>,
        ctx: &PoseCtx,
    ) -> Vec<Vector3<f64>> {
        let mut cols = joint_columns(self, model, jm, ctx);
        growth_column(model, jm, self.driver.value(ctx), &mut cols[0]);
        cols
    }
    fn check_identifiable(&self, _model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        check_driver(&self.driver, train)
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        let mut v = vec![EffectParameter::new(
            "growth",
            &format!("ppm/{}", self.driver.unit()),
            c.v(0) * 1e6,
            c.s(0) * 1e6,
        )];
        v.extend(tau_param(&self.driver, c.tau_std));
        v
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        RateFile::write(&self.driver, false, c.v(0) * 1e6, c.s(0) * 1e6)
    }
    fn sentence(&self, c: &Coefs) -> String {
        format!(
            "every link of the robot grows {} ppm{} {} as it warms ({} mm over a 1 m link)",
            super::plain_number(c.v(0) * 1e6, 2),
            pm(c.s(0) * 1e6, " ppm"),
            per_driver(&self.driver),
            super::plain_number(c.v(0) * 1e3, 4)
        )
    }
    fn plot_driver(&self, _model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        driver_axis(&self.driver, o)
    }
}

impl Family for LengthDrift {
    const KIND: &'static str = KIND;
    fn claims(e: &CalEffect) -> bool {
        e.kind == KIND && e.joint.is_none()
    }
    type File = RateFile;
    fn from_file(
        e: &CalEffect,
        f: RateFile,
    ) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        let (driver, rate, std) = RateFile::rate(f, e, false)?;
        Ok((LengthDrift { driver }, vec![rate * 1e-6], vec![std * 1e-6]))
    }
    fn example(_model: &KinematicModel) -> (Self, Vec<f64>) {
        (
            LengthDrift {
                driver: Driver::Time { t0_s: 0.0 },
            },
            vec![2e-4],
        )
    }
}
