//! Laser-side effects the plain beam model lacks (`docs/effects.md` E8, E9): range scale
//! (`laser_scale`), incidence-angle bias (`laser_incidence`) and a range nonlinearity
//! (`laser_nonlinearity`, a quadratic Legendre term over the range window).
//!
//! Each candidate is a range-correction regressor `g(point)`: the corrected range is
//! `d + Σ e_k g_k`. Candidates are scored against the residual the current model leaves with a
//! nested-model F-test (Bonferroni over the candidates) and ΔBIC, added one at a time with a
//! joint refit of beam, planes and all accepted effects, until nothing significant remains.

use super::fit::{fit_direct, pca_plane, DirectOptions, MultiPlaneFit};
use super::{by_plane, by_target, Beam, LaserError, LaserObs, Plane};
use crate::dataset::CalEffect;
use crate::solve::inference::f_sf;
use nalgebra::Point3;
use serde::Serialize;
use serde_json::{json, Map, Value};

/// The candidate effects, in the contract's names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum LaserEffectKind {
    /// Range scale: `g = d − d_ref`.
    Scale,
    /// Incidence-angle bias: `g = 1 − cos γ`, γ between the beam and the surface normal.
    Incidence,
    /// Quadratic range nonlinearity: `g = P₂((d − d_mid) / half_window) · half_window`.
    Nonlinearity,
}

impl LaserEffectKind {
    /// The effect name in files (`docs/dataset-format.md`; `laser_nonlinearity` is new).
    pub fn name(self) -> &'static str {
        match self {
            LaserEffectKind::Scale => "laser_scale",
            LaserEffectKind::Incidence => "laser_incidence",
            LaserEffectKind::Nonlinearity => "laser_nonlinearity",
        }
    }
    const ALL: [LaserEffectKind; 3] = [
        LaserEffectKind::Scale,
        LaserEffectKind::Incidence,
        LaserEffectKind::Nonlinearity,
    ];
}

/// Reference values of the regressors (fixed from the training data).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RangeRef {
    /// Mean training range (mm), the pivot of the scale term.
    pub d_ref_mm: f64,
    /// Centre of the training range span (mm).
    pub d_mid_mm: f64,
    /// Half the training range span (mm).
    pub half_span_mm: f64,
}

impl RangeRef {
    fn of(obs: &[LaserObs]) -> RangeRef {
        let n = obs.len().max(1) as f64;
        let mean = obs.iter().map(|o| o.d).sum::<f64>() / n;
        let lo = obs.iter().map(|o| o.d).fold(f64::INFINITY, f64::min);
        let hi = obs.iter().map(|o| o.d).fold(f64::NEG_INFINITY, f64::max);
        RangeRef {
            d_ref_mm: mean,
            d_mid_mm: 0.5 * (lo + hi),
            half_span_mm: (0.5 * (hi - lo)).max(1.0),
        }
    }
}

/// The regressor of `kind` for a reading `d` at incidence cosine `cos_g`.
pub fn regressor(kind: LaserEffectKind, r: &RangeRef, d: f64, cos_g: Option<f64>) -> f64 {
    match kind {
        LaserEffectKind::Scale => d - r.d_ref_mm,
        LaserEffectKind::Incidence => 1.0 - cos_g.unwrap_or(1.0),
        LaserEffectKind::Nonlinearity => {
            let x = (d - r.d_mid_mm) / r.half_span_mm;
            0.5 * (3.0 * x * x - 1.0) * r.half_span_mm
        }
    }
}

/// One accepted effect with its evidence.
#[derive(Debug, Clone, Serialize)]
pub struct LaserFinding {
    /// Effect name (`laser_scale`, …).
    pub kind: &'static str,
    /// Range-correction coefficient `e` (scale: unitless; incidence / nonlinearity: mm).
    pub coef: f64,
    /// Its standard deviation.
    pub coef_std: f64,
    /// The same in sensor terms: scale in ppm of the reading the sensor adds
    /// (`−e·10⁶`), incidence bias in mm at γ → 90° (`−e`).
    pub sensor_value: f64,
    /// Unit of `sensor_value`.
    pub sensor_unit: &'static str,
    /// Nested-model F statistic.
    pub f_stat: f64,
    /// Its p-value.
    pub p_value: f64,
    /// ΔBIC (negative favours the effect).
    pub delta_bic: f64,
    /// Point-to-plane RMS before / after adding it (mm).
    pub rms_before_mm: f64,
    /// After.
    pub rms_after_mm: f64,
    /// Mean 5-direction spread before / after (mm), when validation targets exist.
    pub spread_before_mm: Option<f64>,
    /// After.
    pub spread_after_mm: Option<f64>,
}

/// The result of the laser diagnosis.
#[derive(Debug, Clone, Serialize)]
pub struct LaserDiagnosis {
    /// Effects added, in order.
    pub findings: Vec<LaserFinding>,
    /// Candidates tested in the last round (name, F, p, ΔBIC), none significant.
    pub last_round: Vec<(String, f64, f64, f64)>,
    /// Point-to-plane RMS of the plain beam model (mm).
    pub rms_before_mm: f64,
    /// With the effects (mm).
    pub rms_after_mm: f64,
    /// Mean 5-direction spread of the plain model / with effects (mm).
    pub spread_before_mm: Option<f64>,
    /// With effects.
    pub spread_after_mm: Option<f64>,
    /// Range references of the regressors.
    pub range_ref: RangeRef,
    /// Final beam.
    #[serde(skip)]
    pub beam: Option<Beam>,
}

impl LaserDiagnosis {
    /// The effects in calibration-file form.
    pub fn cal_effects(&self) -> Vec<CalEffect> {
        self.findings
            .iter()
            .map(|f| {
                let mut params = Map::new();
                params.insert("coef".into(), json!(f.coef));
                params.insert("coef_std".into(), json!(f.coef_std));
                params.insert("d_ref_mm".into(), json!(self.range_ref.d_ref_mm));
                params.insert("d_mid_mm".into(), json!(self.range_ref.d_mid_mm));
                params.insert("half_span_mm".into(), json!(self.range_ref.half_span_mm));
                params.insert(
                    format!("sensor_{}", f.sensor_unit.replace(' ', "_")),
                    json!(f.sensor_value),
                );
                CalEffect {
                    kind: f.kind.to_string(),
                    joint: None,
                    params,
                    extra: Map::new(),
                }
            })
            .collect()
    }
}

impl LaserDiagnosis {
    /// `diagnosis.json` content ([`crate::schema::DiagnosisFile`]): the train residual is the
    /// point-to-plane distance, the held-out figure the mean 5-direction spread of the
    /// validation targets (both mm). ΔBIC is written with the sign convention of the file
    /// (positive favours the effect).
    pub fn to_file(&self, n_train: usize, n_heldout: usize) -> crate::schema::DiagnosisFile {
        use crate::schema::{self, fin, EffectParameter};
        let cal = self.cal_effects();
        let n_cand = LaserEffectKind::ALL.len();
        let effects = self
            .findings
            .iter()
            .zip(cal)
            .enumerate()
            .map(|(i, (f, c))| {
                let (name, unit, k) = match f.sensor_unit {
                    "ppm" => ("scale", "ppm", 1e6),
                    "mm at 90 deg" => ("bias_at_90deg", "mm", 1.0),
                    _ => ("p2_amplitude", "mm", 1.0),
                };
                schema::DiagnosedEffect {
                    kind: f.kind.into(),
                    joint: None,
                    label: f.kind.into(),
                    parameters: vec![EffectParameter::new(
                        name,
                        unit,
                        f.sensor_value,
                        f.coef_std * k,
                    )],
                    evidence: schema::Evidence {
                        candidate: f.kind.into(),
                        kind: f.kind.into(),
                        joint: None,
                        df: Some(1),
                        f: fin(f.f_stat),
                        p_value: fin(f.p_value),
                        tests: Some(n_cand - i),
                        delta_bic: fin(-f.delta_bic),
                        ..Default::default()
                    },
                    train_rms_mm_before: fin(f.rms_before_mm),
                    train_rms_mm_after: fin(f.rms_after_mm),
                    heldout_rms_mm_before: f.spread_before_mm.and_then(fin),
                    heldout_rms_mm_after: f.spread_after_mm.and_then(fin),
                    train_rms_px_before: None,
                    train_rms_px_after: None,
                    heldout_rms_px_before: None,
                    heldout_rms_px_after: None,
                    hand_eye_change_mm: None,
                    hand_eye_change_deg: None,
                    calibration: c,
                }
            })
            .collect();
        let last_round = self
            .last_round
            .iter()
            .map(|(name, f, p, dbic)| schema::Evidence {
                candidate: name.clone(),
                kind: name.clone(),
                df: Some(1),
                f: fin(*f),
                p_value: fin(*p),
                delta_bic: fin(-dbic),
                ..Default::default()
            })
            .collect::<Vec<_>>();
        schema::DiagnosisFile {
            format: schema::DIAGNOSIS_FORMAT.into(),
            sensor: schema::DiagnosisSensor::Laser,
            residual: "train: point-to-plane distance (mm); held-out: mean 5-direction spread of the validation targets (mm)".into(),
            n_train,
            n_heldout,
            n_heldout_excluded: 0,
            train_rms: schema::StageRms {
                nominal_mm: None,
                base_model_mm: fin(self.rms_before_mm),
                final_mm: fin(self.rms_after_mm),
                ..Default::default()
            },
            heldout_rms: schema::StageRms {
                nominal_mm: None,
                base_model_mm: self.spread_before_mm.and_then(fin),
                final_mm: self.spread_after_mm.and_then(fin),
                ..Default::default()
            },
            train_rms_near_heldout: None,
            effects,
            nonparametric_used: false,
            rounds: vec![last_round],
            not_identifiable: vec![],
            untestable: vec![],
            ambiguous_heldout: vec![],
            warnings: vec![],
            hand_eye_before: None,
            hand_eye_after: None,
        }
    }
}

/// Corrected range of a reading under the calibration-file effects that apply without a
/// surface normal (`laser_scale`, `laser_nonlinearity`); `laser_incidence` needs the surface
/// normal and is applied only when `cos_g` is given.
pub fn corrected_range(d: f64, effects: &[CalEffect], cos_g: Option<f64>) -> f64 {
    let mut out = d;
    for e in effects {
        let kind = match e.kind.as_str() {
            "laser_scale" => LaserEffectKind::Scale,
            "laser_incidence" if cos_g.is_some() => LaserEffectKind::Incidence,
            "laser_nonlinearity" => LaserEffectKind::Nonlinearity,
            _ => continue,
        };
        let get = |k: &str| e.params.get(k).and_then(Value::as_f64);
        let (Some(coef), Some(d_ref), Some(d_mid), Some(half)) = (
            get("coef"),
            get("d_ref_mm"),
            get("d_mid_mm"),
            get("half_span_mm"),
        ) else {
            continue;
        };
        let r = RangeRef {
            d_ref_mm: d_ref,
            d_mid_mm: d_mid,
            half_span_mm: half,
        };
        out += coef * regressor(kind, &r, d, cos_g);
    }
    out
}

fn cos_incidence(beam: &Beam, plane: &Plane, o: &LaserObs) -> f64 {
    let dir = o.flange.rotation * beam.v.into_inner();
    plane.n.dot(&dir).abs().min(1.0)
}

/// Build the regressor columns (plane-then-point order) for `kinds` under the current fit.
fn columns(
    kinds: &[LaserEffectKind],
    data: &[Vec<LaserObs>],
    beam: &Beam,
    planes: &[Plane],
    rr: &RangeRef,
) -> Vec<Vec<f64>> {
    kinds
        .iter()
        .map(|&k| {
            data.iter()
                .zip(planes)
                .flat_map(|(pts, pl)| {
                    pts.iter()
                        .map(move |o| regressor(k, rr, o.d, Some(cos_incidence(beam, pl, o))))
                })
                .collect()
        })
        .collect()
}

/// Mean 5-direction spread with range corrections; the validation plate normal (needed for
/// the incidence term) is the PCA plane of all validation spots.
fn spread_with(
    beam: &Beam,
    kinds: &[LaserEffectKind],
    coefs: &[f64],
    rr: &RangeRef,
    validation: &[LaserObs],
) -> Option<f64> {
    let targets = by_target(validation);
    if targets.is_empty() {
        return None;
    }
    let raw: Vec<Point3<f64>> = validation
        .iter()
        .map(|o| beam.spot(&o.flange, o.d))
        .collect();
    let plate = pca_plane(&raw)?;
    let mut total = 0.0;
    for obs in targets.values() {
        let pts: Vec<Point3<f64>> = obs
            .iter()
            .map(|o| {
                let cg = cos_incidence(beam, &plate, o);
                let d = o.d
                    + kinds
                        .iter()
                        .zip(coefs)
                        .map(|(k, e)| e * regressor(*k, rr, o.d, Some(cg)))
                        .sum::<f64>();
                beam.spot(&o.flange, d)
            })
            .collect();
        total += super::validate::spread(&pts);
    }
    Some(total / targets.len() as f64)
}

/// The sensor's own figure of a range coefficient `e` and its unit (the reading errs by
/// `−e · regressor`).
fn sensor_of(kind: LaserEffectKind, e: f64) -> (f64, &'static str) {
    match kind {
        LaserEffectKind::Scale => (-e * 1e6, "ppm"),
        LaserEffectKind::Incidence => (-e, "mm at 90 deg"),
        LaserEffectKind::Nonlinearity => (-e, "mm"),
    }
}

/// Significance level of the whole candidate family (Bonferroni-corrected per candidate).
const ALPHA: f64 = 0.001;

/// Diagnose the laser effects of a plane calibration dataset (see the module docs).
pub fn diagnose(
    train: &[LaserObs],
    validation: &[LaserObs],
    start: &Beam,
    start_planes: &[(String, Plane)],
) -> Result<LaserDiagnosis, LaserError> {
    let planes_map = by_plane(train);
    let labels: Vec<String> = start_planes.iter().map(|x| x.0.clone()).collect();
    let mut data: Vec<Vec<LaserObs>> = labels
        .iter()
        .map(|l| planes_map.get(l).cloned().unwrap_or_default())
        .collect();
    let mut base_planes: Vec<Plane> = start_planes.iter().map(|x| x.1).collect();
    // The validation targets lie on one plate: its spots are one more plane, and the only
    // data at large incidence (45°), which is what makes the incidence bias observable.
    if validation.len() >= 10 {
        let spots: Vec<Point3<f64>> = validation
            .iter()
            .map(|o| start.spot(&o.flange, o.d))
            .collect();
        if let Some(pl) = pca_plane(&spots) {
            let rms = (spots.iter().map(|p| pl.distance(p).powi(2)).sum::<f64>()
                / spots.len() as f64)
                .sqrt();
            if rms < 5.0 {
                data.push(validation.to_vec());
                base_planes.push(pl);
            }
        }
    }
    let all: Vec<LaserObs> = data.iter().flatten().cloned().collect();
    let rr = RangeRef::of(&all);
    let n = all.len() as f64;
    let base = fit_direct(&data, start, &base_planes, DirectOptions::default())?;
    let rms_before = (base.rss / n).sqrt();
    let spread_before = spread_with(&base.beam, &[], &[], &rr, validation);
    let mut kinds: Vec<LaserEffectKind> = Vec::new();
    let mut current: MultiPlaneFit = base;
    let mut findings = Vec::new();
    let mut last_round = Vec::new();
    loop {
        let candidates: Vec<LaserEffectKind> = LaserEffectKind::ALL
            .iter()
            .copied()
            .filter(|k| !kinds.contains(k))
            .collect();
        if candidates.is_empty() {
            break;
        }
        let p0 = (6 + 4 * data.len() + kinds.len()) as f64;
        let mut round = Vec::new();
        let mut best: Option<(f64, LaserEffectKind, MultiPlaneFit, f64, f64)> = None;
        for &cand in &candidates {
            let mut ks = kinds.clone();
            ks.push(cand);
            // Three passes: the incidence regressor depends on the fitted normals and beam.
            let mut fit = None;
            let (mut b, mut pl) = (current.beam, current.planes.clone());
            for _ in 0..3 {
                let cols = columns(&ks, &data, &b, &pl, &rr);
                let f = fit_direct(
                    &data,
                    &b,
                    &pl,
                    DirectOptions {
                        huber_mm: None,
                        range_terms: cols,
                    },
                )?;
                b = f.beam;
                pl = f.planes.clone();
                fit = Some(f);
            }
            let fit = fit.expect("three passes");
            let rss0 = current.rss;
            let rss1 = fit.rss.max(1e-300);
            let dof = (n - p0 - 1.0).max(1.0);
            let f_stat = ((rss0 - rss1).max(0.0)) / (rss1 / dof);
            let p = f_sf(f_stat, 1.0, dof);
            let dbic = n * (rss1 / rss0.max(1e-300)).ln() + n.ln();
            round.push((cand.name().to_string(), f_stat, p, dbic));
            let significant = p < ALPHA / candidates.len() as f64 && dbic < -10.0;
            if significant && best.as_ref().is_none_or(|x| f_stat > x.0) {
                best = Some((f_stat, cand, fit, p, dbic));
            }
        }
        let Some((f_stat, kind, fit, p, dbic)) = best else {
            last_round = round;
            break;
        };
        kinds.push(kind);
        let e = *fit.range_coefs.last().expect("one coefficient per effect");
        let e_std = *fit.range_coef_std.last().expect("one std per effect");
        let spread_after = spread_with(&fit.beam, &kinds, &fit.range_coefs, &rr, validation);
        let spread_prev = spread_with(
            &current.beam,
            &kinds[..kinds.len() - 1],
            &current.range_coefs,
            &rr,
            validation,
        );
        let (sensor_value, sensor_unit) = sensor_of(kind, e);
        findings.push(LaserFinding {
            kind: kind.name(),
            coef: e,
            coef_std: e_std,
            sensor_value,
            sensor_unit,
            f_stat,
            p_value: p,
            delta_bic: dbic,
            rms_before_mm: (current.rss / n).sqrt(),
            rms_after_mm: (fit.rss / n).sqrt(),
            spread_before_mm: spread_prev,
            spread_after_mm: spread_after,
        });
        current = fit;
    }
    // What is written is the final joint fit: every coefficient refitted with the effects
    // added after it (a finding's own step had only the earlier ones), so that the
    // calibration file reproduces the final spread.
    for ((f, k), (c, sd)) in findings
        .iter_mut()
        .zip(&kinds)
        .zip(current.range_coefs.iter().zip(&current.range_coef_std))
    {
        f.coef = *c;
        f.coef_std = *sd;
        f.sensor_value = sensor_of(*k, *c).0;
    }
    let spread_after = spread_with(&current.beam, &kinds, &current.range_coefs, &rr, validation);
    // Keep the planes' labels for the caller through the beam only; planes are in `current`.
    Ok(LaserDiagnosis {
        findings,
        last_round,
        rms_before_mm: rms_before,
        rms_after_mm: (current.rss / n).sqrt(),
        spread_before_mm: spread_before,
        spread_after_mm: spread_after,
        range_ref: rr,
        beam: Some(current.beam),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corrected_range_applies_scale_and_skips_incidence_without_a_normal() {
        let e = CalEffect {
            kind: "laser_scale".into(),
            joint: None,
            params: serde_json::from_value(
                json!({"coef": -1e-3, "d_ref_mm": 500.0, "d_mid_mm": 500.0, "half_span_mm": 150.0}),
            )
            .unwrap(),
            extra: Map::new(),
        };
        assert!(
            (corrected_range(600.0, std::slice::from_ref(&e), None) - (600.0 - 0.1)).abs() < 1e-12
        );
        let mut inc = e.clone();
        inc.kind = "laser_incidence".into();
        assert_eq!(
            corrected_range(600.0, std::slice::from_ref(&inc), None),
            600.0
        );
        assert!((corrected_range(600.0, &[inc], Some(0.5)) - (600.0 - 0.5e-3)).abs() < 1e-12);
    }
}

#[cfg(test)]
mod detection_tests {
    use super::*;
    use crate::solve::laser::fit::tests::{synth, truth};

    fn data(scale: f64, incidence_mm: f64) -> (Vec<LaserObs>, Vec<(String, Plane)>, Beam) {
        let (beam, planes) = truth();
        let mut all = Vec::new();
        let mut labelled = Vec::new();
        for (i, p) in planes.iter().enumerate() {
            let label = format!("P{}", i + 1);
            let mut obs = synth(&beam, p, &label, i as u64 + 7, 0.02);
            for o in &mut obs {
                let cg = p.n.dot(&(o.flange.rotation * beam.v.into_inner())).abs();
                o.d = o.d * (1.0 + scale) + incidence_mm * (1.0 - cg);
            }
            all.extend(obs);
            labelled.push((label, *p));
        }
        (all, labelled, beam)
    }

    #[test]
    fn finds_a_hidden_range_scale_and_nothing_in_the_control() {
        let (obs, planes, beam) = data(2e-3, 0.0);
        let d = diagnose(&obs, &[], &beam, &planes).unwrap();
        assert_eq!(
            d.findings.first().map(|f| f.kind),
            Some("laser_scale"),
            "{:?}",
            d.findings
        );
        let ppm = d.findings[0].sensor_value;
        assert!((ppm - 2000.0).abs() < 100.0, "scale {ppm} ppm");
        assert!(d.rms_after_mm < 0.5 * d.rms_before_mm);
        let (obs, planes, beam) = data(0.0, 0.0);
        let d = diagnose(&obs, &[], &beam, &planes).unwrap();
        assert!(d.findings.is_empty(), "false positive: {:?}", d.findings);
    }

    #[test]
    fn finds_a_hidden_incidence_bias_with_its_coefficient() {
        let (obs, planes, beam) = data(0.0, 3.0);
        let d = diagnose(&obs, &[], &beam, &planes).unwrap();
        let f = d.findings.iter().find(|f| f.kind == "laser_incidence");
        let f = f.unwrap_or_else(|| panic!("not found: {:?} / {:?}", d.findings, d.last_round));
        assert!(
            (f.sensor_value - 3.0).abs() < 0.5,
            "incidence {} mm",
            f.sensor_value
        );
    }
}
