//! Acceptance specification (`ACCEPT.toml`, strict TOML) and the session verdict.
//!
//! Thresholds on the held-out validation set (mm, %, fractions): RMS and max error after
//! calibration, mean relative distance error, "must not get worse than nominal", skipped
//! fraction of the planned poses, and the largest 95 % half-interval of a parameter.
//! A criterion whose number is missing makes the verdict INCOMPLETE, never PASS.
use std::fmt;
use std::path::Path;

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Errors reading an acceptance specification.
#[derive(Debug, Error)]
pub enum AcceptError {
    /// The file cannot be read.
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    /// Not valid TOML or an unknown / mistyped field.
    #[error("{path}: {message}")]
    Parse { path: String, message: String },
    /// A threshold out of range.
    #[error("{path}: field `{field}`: {message}")]
    Invalid {
        path: String,
        field: String,
        message: String,
    },
}

/// `ACCEPT.toml`: the acceptance criteria of a use case. Every field is optional except the
/// name; an absent threshold is not checked.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AcceptSpec {
    /// Name of the use case (`surgical-navigation`, ...).
    pub name: String,
    /// The kind of session this spec judges: `kinematic` (tracker, mm) or `camera` (board
    /// images, px). Required in a spec file (a spec judging the wrong kind would check
    /// nothing); absent only in session files written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub session: Option<super::SessionKind>,
    /// Free text shown in the report.
    #[serde(default)]
    pub description: Option<String>,
    /// Held-out RMS position error after calibration must be ≤ this (mm).
    #[serde(default)]
    pub heldout_rms_mm_max: Option<f64>,
    /// Held-out largest position error after calibration must be ≤ this (mm).
    #[serde(default)]
    pub heldout_max_mm_max: Option<f64>,
    /// Held-out mean relative distance error after calibration must be ≤ this (%).
    #[serde(default)]
    pub relative_distance_pct_max: Option<f64>,
    /// Every held-out metric must be no worse after calibration than with the nominal model.
    #[serde(default = "yes")]
    pub must_improve: bool,
    /// Skipped poses / planned poses (training + validation) must be ≤ this (0..1).
    #[serde(default)]
    pub skipped_fraction_max: Option<f64>,
    /// The largest 95 % half-interval of a fitted length parameter must be ≤ this (mm).
    #[serde(default)]
    pub param_ci95_mm_max: Option<f64>,
    /// The largest 95 % half-interval of a fitted angle parameter must be ≤ this (deg).
    #[serde(default)]
    pub param_ci95_deg_max: Option<f64>,
    /// At least this many held-out poses (else INCOMPLETE).
    #[serde(default = "d_min_heldout")]
    pub min_heldout_poses: usize,
    /// Camera sessions: held-out reprojection RMS of the board corners after calibration
    /// and diagnosis must be ≤ this (px).
    #[serde(default)]
    pub heldout_reprojection_px_max: Option<f64>,
    /// Camera sessions: the largest 95 % half-interval of the hand-eye translation (mm).
    #[serde(default)]
    pub hand_eye_ci95_mm_max: Option<f64>,
    /// Camera sessions: the largest 95 % half-interval of the hand-eye rotation (deg).
    #[serde(default)]
    pub hand_eye_ci95_deg_max: Option<f64>,
    /// `verify` stage: commanded-vs-measured RMS with the calibrated IK must be ≤ this (mm).
    #[serde(default)]
    pub verified_rms_mm_max: Option<f64>,
    /// `verify` stage: verified after-RMS / predicted held-out after-RMS must be ≤ this
    /// (1.2: a calibration may verify at most 20 % worse than it predicts).
    #[serde(default)]
    pub verified_vs_predicted_max: Option<f64>,
    /// `verify` stage: seed 001's inverse-solution coincidence error with the calibrated IK
    /// (mean over targets of the largest distance between branches) must be ≤ this (mm).
    #[serde(default)]
    pub coincidence_mm_max: Option<f64>,
    /// Laser sessions: the mean five-direction spread of the calibrated beam's spots on the
    /// held-out validation targets (seed 000 §2.3.1) must be ≤ this (mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laser_spread_mm_max: Option<f64>,
    /// Laser sessions: the calibration data's point-to-plane RMS must be ≤ this (mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laser_plane_rms_mm_max: Option<f64>,
    /// RCM sessions: held-out RMS distance of the detected silhouette end points from the
    /// silhouettes the deployed hand-eye predicts (px).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rcm_heldout_px_max: Option<f64>,
    /// RCM sessions: the largest 95 % half-interval of the endoscope's position (mm) and
    /// rotation (deg) in the base.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rcm_hand_eye_ci95_mm_max: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rcm_hand_eye_ci95_deg_max: Option<f64>,
    /// RCM sessions: views the line detector refused / views acquired (0..1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rcm_refused_fraction_max: Option<f64>,
}

fn kind_name(k: super::SessionKind) -> &'static str {
    match k {
        super::SessionKind::Kinematic => "kinematic",
        super::SessionKind::Camera => "camera",
        super::SessionKind::Laser => "laser",
        super::SessionKind::Rcm => "rcm",
    }
}

fn yes() -> bool {
    true
}
fn d_min_heldout() -> usize {
    10
}

impl AcceptSpec {
    /// Parse and validate; `path` names the file in errors.
    pub fn from_toml_str(text: &str, path: &str) -> Result<AcceptSpec, AcceptError> {
        let spec: AcceptSpec = toml::from_str(text).map_err(|e| AcceptError::Parse {
            path: path.into(),
            message: crate::schema::kind::with_toml_hint(
                &e,
                text,
                crate::schema::kind::TomlKind::AcceptSpec,
            ),
        })?;
        let check = |field: &str, v: Option<f64>, max: f64| -> Result<(), AcceptError> {
            match v {
                Some(x) if !(x.is_finite() && x > 0.0 && x <= max) => Err(AcceptError::Invalid {
                    path: path.into(),
                    field: field.into(),
                    message: format!("{x} is not a positive number ≤ {max}"),
                }),
                _ => Ok(()),
            }
        };
        check("heldout_rms_mm_max", spec.heldout_rms_mm_max, 1e4)?;
        check("heldout_max_mm_max", spec.heldout_max_mm_max, 1e4)?;
        check(
            "relative_distance_pct_max",
            spec.relative_distance_pct_max,
            100.0,
        )?;
        check("skipped_fraction_max", spec.skipped_fraction_max, 1.0)?;
        check("param_ci95_mm_max", spec.param_ci95_mm_max, 1e4)?;
        check("param_ci95_deg_max", spec.param_ci95_deg_max, 360.0)?;
        check(
            "heldout_reprojection_px_max",
            spec.heldout_reprojection_px_max,
            1e3,
        )?;
        check("hand_eye_ci95_mm_max", spec.hand_eye_ci95_mm_max, 1e4)?;
        check("hand_eye_ci95_deg_max", spec.hand_eye_ci95_deg_max, 360.0)?;
        check("verified_rms_mm_max", spec.verified_rms_mm_max, 1e4)?;
        check(
            "verified_vs_predicted_max",
            spec.verified_vs_predicted_max,
            100.0,
        )?;
        check("coincidence_mm_max", spec.coincidence_mm_max, 1e4)?;
        check("laser_spread_mm_max", spec.laser_spread_mm_max, 1e4)?;
        check("laser_plane_rms_mm_max", spec.laser_plane_rms_mm_max, 1e4)?;
        check("rcm_heldout_px_max", spec.rcm_heldout_px_max, 1e3)?;
        check(
            "rcm_hand_eye_ci95_mm_max",
            spec.rcm_hand_eye_ci95_mm_max,
            1e4,
        )?;
        check(
            "rcm_hand_eye_ci95_deg_max",
            spec.rcm_hand_eye_ci95_deg_max,
            360.0,
        )?;
        check(
            "rcm_refused_fraction_max",
            spec.rcm_refused_fraction_max,
            1.0,
        )?;
        let invalid = |field: &str, message: String| AcceptError::Invalid {
            path: path.into(),
            field: field.into(),
            message,
        };
        let Some(kind) = spec.session else {
            return Err(invalid(
                "session",
                "missing: name the kind of session this spec judges, `session = \"kinematic\"` \
                 (tracker, mm), `session = \"camera\"` (board images, px), `session = \
                 \"laser\"` (range sensor on planes, mm) or `session = \"rcm\"` (endoscope \
                 under a trocar, px)"
                    .into(),
            ));
        };
        let (own, other) = spec.criteria(kind);
        if let Some((f, k)) = other.first() {
            return Err(invalid(
                f,
                format!(
                    "a criterion of {} sessions in a spec for {} sessions (`session = \"{}\"`): \
                     it would never be checked",
                    kind_name(*k),
                    kind_name(kind),
                    kind_name(kind)
                ),
            ));
        }
        if own.is_empty() {
            let need = match kind {
                super::SessionKind::Kinematic => {
                    "heldout_rms_mm_max, heldout_max_mm_max or relative_distance_pct_max"
                }
                super::SessionKind::Camera => "heldout_reprojection_px_max",
                super::SessionKind::Laser => "laser_spread_mm_max",
                super::SessionKind::Rcm => "rcm_heldout_px_max",
            };
            return Err(invalid(
                "session",
                format!(
                    "no accuracy criterion for a {} session: a verdict that checked nothing is \
                     not a PASS; give at least one of {need}",
                    kind_name(kind)
                ),
            ));
        }
        Ok(spec)
    }

    /// The accuracy criteria (fields) this spec sets for sessions of `kind`, and the
    /// criteria it sets that only sessions of another kind check (with that kind).
    fn criteria(
        &self,
        kind: super::SessionKind,
    ) -> (Vec<&'static str>, Vec<(&'static str, super::SessionKind)>) {
        let kin = [
            ("heldout_rms_mm_max", self.heldout_rms_mm_max),
            ("heldout_max_mm_max", self.heldout_max_mm_max),
            ("relative_distance_pct_max", self.relative_distance_pct_max),
            ("verified_rms_mm_max", self.verified_rms_mm_max),
            ("verified_vs_predicted_max", self.verified_vs_predicted_max),
            ("coincidence_mm_max", self.coincidence_mm_max),
            ("param_ci95_mm_max", self.param_ci95_mm_max),
            ("param_ci95_deg_max", self.param_ci95_deg_max),
        ];
        let cam = [
            (
                "heldout_reprojection_px_max",
                self.heldout_reprojection_px_max,
            ),
            ("hand_eye_ci95_mm_max", self.hand_eye_ci95_mm_max),
            ("hand_eye_ci95_deg_max", self.hand_eye_ci95_deg_max),
        ];
        let set = |v: &[(&'static str, Option<f64>)], accuracy: usize| {
            let all: Vec<&'static str> = v
                .iter()
                .filter(|(_, x)| x.is_some())
                .map(|(n, _)| *n)
                .collect();
            let acc: Vec<&'static str> = v[..accuracy]
                .iter()
                .filter(|(_, x)| x.is_some())
                .map(|(n, _)| *n)
                .collect();
            (acc, all)
        };
        let las = [
            ("laser_spread_mm_max", self.laser_spread_mm_max),
            ("laser_plane_rms_mm_max", self.laser_plane_rms_mm_max),
        ];
        let rcm = [
            ("rcm_heldout_px_max", self.rcm_heldout_px_max),
            ("rcm_hand_eye_ci95_mm_max", self.rcm_hand_eye_ci95_mm_max),
            ("rcm_hand_eye_ci95_deg_max", self.rcm_hand_eye_ci95_deg_max),
            ("rcm_refused_fraction_max", self.rcm_refused_fraction_max),
        ];
        use super::SessionKind as K;
        let all = [
            (K::Kinematic, set(&kin, 4)),
            (K::Camera, set(&cam, 1)),
            (K::Laser, set(&las, 1)),
            (K::Rcm, set(&rcm, 1)),
        ];
        let own = all
            .iter()
            .find(|(k, _)| *k == kind)
            .map(|(_, (acc, _))| acc.clone())
            .unwrap_or_default();
        let other = all
            .iter()
            .filter(|(k, _)| *k != kind)
            .flat_map(|(k, (_, every))| every.iter().map(move |f| (*f, *k)))
            .collect();
        (own, other)
    }

    /// Checks that this spec judges sessions of `kind` (before anything moves): a spec for
    /// the other kind would check nothing of this session.
    pub fn check_kind(&self, kind: super::SessionKind, path: &str) -> Result<(), AcceptError> {
        match self.session {
            Some(k) if k != kind => Err(AcceptError::Invalid {
                path: path.into(),
                field: "session".into(),
                message: format!(
                    "this spec judges {} sessions but the cell makes a {} session (a {} cell): \
                     give an accept spec with `session = \"{}\"` (accept/{}.toml)",
                    kind_name(k),
                    kind_name(kind),
                    match kind {
                        super::SessionKind::Kinematic => "tracker",
                        super::SessionKind::Camera => "camera without tracker",
                        super::SessionKind::Laser => "laser on calibration planes",
                        super::SessionKind::Rcm => "endoscope and instrument through a trocar",
                    },
                    kind_name(kind),
                    match kind {
                        super::SessionKind::Kinematic => "surgical",
                        super::SessionKind::Camera => "camera",
                        super::SessionKind::Laser => "laser",
                        super::SessionKind::Rcm => "rcm",
                    }
                ),
            }),
            _ => Ok(()),
        }
    }

    /// Read an `ACCEPT.toml` file.
    pub fn from_file(path: &Path) -> Result<AcceptSpec, AcceptError> {
        let text = crate::fsio::read_to_string(path).map_err(|source| AcceptError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// The shipped default (`accept/surgical.toml`).
    pub fn default_surgical() -> AcceptSpec {
        Self::from_toml_str(SURGICAL, "accept/surgical.toml").expect("shipped spec is valid")
    }
}

/// The shipped default acceptance spec (surgical navigation).
pub const SURGICAL: &str = include_str!("../../accept/surgical.toml");

/// The numbers a verdict is computed from (all held-out unless named otherwise).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Measured {
    /// Planned poses, training + validation.
    pub poses_planned: usize,
    /// Skipped poses, training + validation.
    pub poses_skipped: usize,
    /// Held-out poses scored.
    pub heldout_poses: usize,
    /// Held-out RMS (mm) with the nominal model and after calibration.
    pub heldout_rms_mm_before: Option<f64>,
    pub heldout_rms_mm_after: Option<f64>,
    /// Held-out max error (mm).
    pub heldout_max_mm_before: Option<f64>,
    pub heldout_max_mm_after: Option<f64>,
    /// Held-out mean relative distance error (%).
    pub relative_distance_pct_before: Option<f64>,
    pub relative_distance_pct_after: Option<f64>,
    /// Largest 95 % half-interval of a free length parameter (mm) and angle parameter (deg).
    pub param_ci95_mm: Option<f64>,
    pub param_ci95_deg: Option<f64>,
    /// Camera: held-out reprojection RMS (px) with the calibration and after the diagnosis.
    #[serde(default)]
    pub heldout_reprojection_px_before: Option<f64>,
    #[serde(default)]
    pub heldout_reprojection_px_after: Option<f64>,
    /// Camera: largest 95 % half-interval of the deployed hand-eye's translation (mm) and
    /// rotation (deg).
    #[serde(default)]
    pub hand_eye_ci95_mm: Option<f64>,
    #[serde(default)]
    pub hand_eye_ci95_deg: Option<f64>,
    /// Camera: whether independent data confirm the hand-eye interval. The held-out views
    /// calibrated on their own give a second hand-eye; its difference from the deployed one
    /// divided by the combined 95 % bound of the two (translation and rotation, the larger).
    /// ≤ 1: the stated interval holds; > 1: the hand-eye absorbs something the model lacks
    /// and its interval is optimistic.
    #[serde(default)]
    pub hand_eye_heldout_ratio: Option<f64>,
    /// `verify` stage: commanded-vs-measured RMS (mm) with the nominal IK and the calibrated
    /// IK, the largest after, seed 001's coincidence error before / after (mm), and verified
    /// after-RMS / predicted held-out after-RMS.
    #[serde(default)]
    pub verified_rms_mm_before: Option<f64>,
    #[serde(default)]
    pub verified_rms_mm_after: Option<f64>,
    #[serde(default)]
    pub verified_max_mm_after: Option<f64>,
    #[serde(default)]
    pub coincidence_mm_before: Option<f64>,
    #[serde(default)]
    pub coincidence_mm_after: Option<f64>,
    #[serde(default)]
    pub verified_vs_predicted: Option<f64>,
    /// Laser: mean (and sd over targets) five-direction spread (mm) on the held-out validation
    /// targets with the nominal beam mounting (before) and the calibrated beam (after).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laser_spread_mm_before: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laser_spread_mm_after: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laser_spread_sd_mm_after: Option<f64>,
    /// Laser: point-to-plane RMS of the calibration data with the calibrated beam (mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laser_plane_rms_mm: Option<f64>,
    /// RCM: held-out silhouette RMS (px) with seed 002's two-step hand-eye (before) and the
    /// ML hand-eye (after); views refused by the line detector / views acquired.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rcm_heldout_px_before: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rcm_heldout_px_after: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rcm_refused_fraction: Option<f64>,
}

impl Measured {
    /// The held-out metrics calibration made worse: `(name, before, after)`.
    pub fn worse(&self) -> Vec<(String, f64, f64)> {
        let mut v = Vec::new();
        let mut push = |name: &str, b: Option<f64>, a: Option<f64>| {
            if let (Some(b), Some(a)) = (b, a) {
                if a > b {
                    v.push((name.to_string(), b, a));
                }
            }
        };
        push(
            "held-out RMS (mm)",
            self.heldout_rms_mm_before,
            self.heldout_rms_mm_after,
        );
        push(
            "held-out max error (mm)",
            self.heldout_max_mm_before,
            self.heldout_max_mm_after,
        );
        push(
            "relative distance error (%)",
            self.relative_distance_pct_before,
            self.relative_distance_pct_after,
        );
        push(
            "held-out reprojection RMS (px)",
            self.heldout_reprojection_px_before,
            self.heldout_reprojection_px_after,
        );
        push(
            "held-out five-direction spread (mm)",
            self.laser_spread_mm_before,
            self.laser_spread_mm_after,
        );
        push(
            "held-out silhouette RMS (px)",
            self.rcm_heldout_px_before,
            self.rcm_heldout_px_after,
        );
        v
    }
}

/// PASS, FAIL or INCOMPLETE.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum VerdictKind {
    Pass,
    Fail,
    Incomplete,
}

impl fmt::Display for VerdictKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            VerdictKind::Pass => "PASS",
            VerdictKind::Fail => "FAIL",
            VerdictKind::Incomplete => "INCOMPLETE",
        })
    }
}

/// One criterion and how the session did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Criterion {
    /// What is checked, in words.
    pub name: String,
    /// The limit, in words (`≤ 0.5 mm`).
    pub limit: String,
    /// The session's value, in words (`0.21 mm`), or `missing`.
    pub value: String,
    /// `true` passed, `false` failed, `None` could not be evaluated.
    pub ok: Option<bool>,
}

/// The verdict with every criterion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    pub verdict: VerdictKind,
    /// The acceptance spec's name.
    pub accept: String,
    pub criteria: Vec<Criterion>,
    /// Held-out metrics that got worse with calibration (flagged everywhere).
    pub worse: Vec<String>,
    /// Why the verdict is INCOMPLETE (stages not run, data missing).
    #[serde(default)]
    pub incomplete: Vec<String>,
}

impl Verdict {
    /// `PASS`, `FAIL: a; b` or `INCOMPLETE: ...` in one line.
    pub fn line(&self) -> String {
        match self.verdict {
            VerdictKind::Pass => format!("PASS ({})", self.accept),
            VerdictKind::Fail => format!(
                "FAIL ({}): {}",
                self.accept,
                self.failed()
                    .iter()
                    .map(|c| format!("{} = {} (limit {})", c.name, c.value, c.limit))
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
            VerdictKind::Incomplete => {
                let mut why = self.incomplete.clone();
                why.extend(
                    self.criteria
                        .iter()
                        .filter(|c| c.ok.is_none())
                        .map(|c| format!("{} not measured", c.name)),
                );
                format!("INCOMPLETE ({}): {}", self.accept, why.join("; "))
            }
        }
    }

    /// The failed criteria.
    pub fn failed(&self) -> Vec<&Criterion> {
        self.criteria
            .iter()
            .filter(|c| c.ok == Some(false))
            .collect()
    }

    /// Process exit code: 0 PASS, 2 FAIL / INCOMPLETE.
    pub fn exit_code(&self) -> i32 {
        match self.verdict {
            VerdictKind::Pass => 0,
            _ => 2,
        }
    }
}

fn le(name: &str, unit: &str, v: Option<f64>, limit: Option<f64>, out: &mut Vec<Criterion>) {
    let Some(lim) = limit else { return };
    out.push(Criterion {
        name: name.into(),
        limit: format!("≤ {lim} {unit}"),
        value: v.map_or("missing".into(), |x| format!("{x:.4} {unit}")),
        ok: v.filter(|x| x.is_finite()).map(|x| x <= lim),
    });
}

/// Judge `m` against `spec`. `incomplete` lists stages that did not finish.
pub fn judge(spec: &AcceptSpec, m: &Measured, incomplete: Vec<String>) -> Verdict {
    judge_kind(spec, m, incomplete, super::SessionKind::Kinematic)
}

/// Judge `m` against `spec` for a session of `kind`: a kinematic session is judged by the
/// position criteria (mm, %), a camera session by the reprojection and hand-eye criteria
/// (px, mm, deg); both by "must improve", skipped poses and the held-out count. A camera
/// session judged by a spec without any camera criterion is INCOMPLETE, never PASS.
pub fn judge_kind(
    spec: &AcceptSpec,
    m: &Measured,
    incomplete: Vec<String>,
    kind: super::SessionKind,
) -> Verdict {
    let camera = kind == super::SessionKind::Camera;
    let laser = kind == super::SessionKind::Laser;
    let rcm = kind == super::SessionKind::Rcm;
    let mut c = Vec::new();
    let mut incomplete = incomplete;
    if camera {
        camera_criteria(spec, m, &mut c, &mut incomplete);
    } else if laser {
        laser_criteria(spec, m, &mut c, &mut incomplete);
    } else if rcm {
        rcm_criteria(spec, m, &mut c, &mut incomplete);
    } else {
        kinematic_criteria(spec, m, &mut c);
    }
    let worse = m.worse();
    if spec.must_improve {
        let have = if camera {
            m.heldout_reprojection_px_before.is_some() && m.heldout_reprojection_px_after.is_some()
        } else if laser {
            m.laser_spread_mm_before.is_some() && m.laser_spread_mm_after.is_some()
        } else if rcm {
            m.rcm_heldout_px_before.is_some() && m.rcm_heldout_px_after.is_some()
        } else {
            m.heldout_rms_mm_before.is_some() && m.heldout_rms_mm_after.is_some()
        };
        c.push(Criterion {
            name: if camera {
                "no held-out metric worse after the diagnosis".into()
            } else if laser {
                "held-out spread no worse than with the nominal beam mounting".into()
            } else if rcm {
                "held-out silhouettes no worse than with seed 002's two-step hand-eye".into()
            } else {
                "no held-out metric worse than nominal".into()
            },
            limit: "none worse".into(),
            value: if !have {
                "missing".into()
            } else if worse.is_empty() {
                "none worse".into()
            } else {
                worse
                    .iter()
                    .map(|(n, b, a)| format!("{n} {b:.4} → {a:.4} WORSE"))
                    .collect::<Vec<_>>()
                    .join(", ")
            },
            ok: have.then_some(worse.is_empty()),
        });
    }
    let frac = (m.poses_planned > 0).then(|| m.poses_skipped as f64 / m.poses_planned as f64);
    if let Some(lim) = spec.skipped_fraction_max {
        c.push(Criterion {
            name: "skipped poses".into(),
            limit: format!("≤ {:.1} %", lim * 100.0),
            value: frac.map_or("missing".into(), |f| {
                format!(
                    "{:.1} % ({} of {})",
                    f * 100.0,
                    m.poses_skipped,
                    m.poses_planned
                )
            }),
            ok: frac.map(|f| f <= lim),
        });
    }
    if !camera && !laser && !rcm {
        le(
            "parameter 95 % half-interval (lengths)",
            "mm",
            m.param_ci95_mm,
            spec.param_ci95_mm_max,
            &mut c,
        );
        le(
            "parameter 95 % half-interval (angles)",
            "deg",
            m.param_ci95_deg,
            spec.param_ci95_deg_max,
            &mut c,
        );
    }
    if m.heldout_poses < spec.min_heldout_poses {
        incomplete.push(format!(
            "only {} held-out poses (need ≥ {})",
            m.heldout_poses, spec.min_heldout_poses
        ));
    }
    let verdict = if c.iter().any(|x| x.ok == Some(false)) {
        VerdictKind::Fail
    } else if !incomplete.is_empty() || c.iter().any(|x| x.ok.is_none()) {
        VerdictKind::Incomplete
    } else {
        VerdictKind::Pass
    };
    Verdict {
        verdict,
        accept: spec.name.clone(),
        criteria: c,
        worse: worse
            .iter()
            .map(|(n, b, a)| format!("{n}: {b:.4} → {a:.4} (WORSE after calibration)"))
            .collect(),
        incomplete,
    }
}

/// The camera criteria: held-out reprojection, the hand-eye's 95 % half-intervals.
fn camera_criteria(
    spec: &AcceptSpec,
    m: &Measured,
    c: &mut Vec<Criterion>,
    incomplete: &mut Vec<String>,
) {
    if spec.heldout_reprojection_px_max.is_none()
        && spec.hand_eye_ci95_mm_max.is_none()
        && spec.hand_eye_ci95_deg_max.is_none()
    {
        incomplete.push(format!(
            "the acceptance spec {:?} has no camera criterion (heldout_reprojection_px_max, \
             hand_eye_ci95_mm_max, hand_eye_ci95_deg_max): see accept/camera.toml",
            spec.name
        ));
    }
    le(
        "held-out reprojection RMS",
        "px",
        m.heldout_reprojection_px_after,
        spec.heldout_reprojection_px_max,
        c,
    );
    le(
        "hand-eye 95 % half-interval (translation)",
        "mm",
        m.hand_eye_ci95_mm,
        spec.hand_eye_ci95_mm_max,
        c,
    );
    le(
        "hand-eye 95 % half-interval (rotation)",
        "deg",
        m.hand_eye_ci95_deg,
        spec.hand_eye_ci95_deg_max,
        c,
    );
    // An interval is only worth judging when independent data confirm it: whenever the spec
    // limits the hand-eye interval, the held-out views' own hand-eye must lie within it.
    if spec.hand_eye_ci95_mm_max.is_some() || spec.hand_eye_ci95_deg_max.is_some() {
        le(
            "hand-eye confirmed by the held-out views (difference / combined 95 % bound)",
            "×",
            m.hand_eye_heldout_ratio,
            Some(1.0),
            c,
        );
    }
}

/// The laser criteria: the held-out five-direction spread, the calibration planes' RMS.
fn laser_criteria(
    spec: &AcceptSpec,
    m: &Measured,
    c: &mut Vec<Criterion>,
    incomplete: &mut Vec<String>,
) {
    if spec.laser_spread_mm_max.is_none() && spec.laser_plane_rms_mm_max.is_none() {
        incomplete.push(format!(
            "the acceptance spec {:?} has no laser criterion (laser_spread_mm_max, \
             laser_plane_rms_mm_max): see accept/laser.toml",
            spec.name
        ));
    }
    le(
        "held-out five-direction spread (mean over targets)",
        "mm",
        m.laser_spread_mm_after,
        spec.laser_spread_mm_max,
        c,
    );
    le(
        "calibration planes' point-to-plane RMS",
        "mm",
        m.laser_plane_rms_mm,
        spec.laser_plane_rms_mm_max,
        c,
    );
}

/// The RCM criteria: held-out silhouettes, the endoscope hand-eye's interval (confirmed by
/// the held-out views on their own), the line detector's refusals.
fn rcm_criteria(
    spec: &AcceptSpec,
    m: &Measured,
    c: &mut Vec<Criterion>,
    incomplete: &mut Vec<String>,
) {
    if spec.rcm_heldout_px_max.is_none() {
        incomplete.push(format!(
            "the acceptance spec {:?} has no RCM criterion (rcm_heldout_px_max): see \
             accept/rcm.toml",
            spec.name
        ));
    }
    le(
        "held-out silhouette RMS (deployed hand-eye)",
        "px",
        m.rcm_heldout_px_after,
        spec.rcm_heldout_px_max,
        c,
    );
    le(
        "endoscope hand-eye 95 % half-interval (translation)",
        "mm",
        m.hand_eye_ci95_mm,
        spec.rcm_hand_eye_ci95_mm_max,
        c,
    );
    le(
        "endoscope hand-eye 95 % half-interval (rotation)",
        "deg",
        m.hand_eye_ci95_deg,
        spec.rcm_hand_eye_ci95_deg_max,
        c,
    );
    if spec.rcm_hand_eye_ci95_mm_max.is_some() || spec.rcm_hand_eye_ci95_deg_max.is_some() {
        le(
            "hand-eye confirmed by the held-out views (difference / combined 95 % bound)",
            "×",
            m.hand_eye_heldout_ratio,
            Some(1.0),
            c,
        );
    }
    le(
        "views refused by the line detector",
        "",
        m.rcm_refused_fraction,
        spec.rcm_refused_fraction_max,
        c,
    );
}

/// The kinematic (position) criteria.
fn kinematic_criteria(spec: &AcceptSpec, m: &Measured, c: &mut Vec<Criterion>) {
    le(
        "held-out RMS error",
        "mm",
        m.heldout_rms_mm_after,
        spec.heldout_rms_mm_max,
        c,
    );
    le(
        "held-out max error",
        "mm",
        m.heldout_max_mm_after,
        spec.heldout_max_mm_max,
        c,
    );
    le(
        "relative distance error",
        "%",
        m.relative_distance_pct_after,
        spec.relative_distance_pct_max,
        c,
    );
    le(
        "verified commanded-vs-measured RMS",
        "mm",
        m.verified_rms_mm_after,
        spec.verified_rms_mm_max,
        c,
    );
    le(
        "verified / predicted held-out RMS",
        "×",
        m.verified_vs_predicted,
        spec.verified_vs_predicted_max,
        c,
    );
    le(
        "inverse-solution coincidence error",
        "mm",
        m.coincidence_mm_after,
        spec.coincidence_mm_max,
        c,
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn good() -> Measured {
        Measured {
            poses_planned: 160,
            poses_skipped: 2,
            heldout_poses: 40,
            heldout_rms_mm_before: Some(0.7),
            heldout_rms_mm_after: Some(0.05),
            heldout_max_mm_before: Some(1.5),
            heldout_max_mm_after: Some(0.12),
            relative_distance_pct_before: Some(0.27),
            relative_distance_pct_after: Some(0.02),
            param_ci95_mm: Some(0.05),
            param_ci95_deg: Some(0.004),
            verified_rms_mm_before: Some(0.7),
            verified_rms_mm_after: Some(0.055),
            verified_max_mm_after: Some(0.13),
            coincidence_mm_before: Some(1.2),
            coincidence_mm_after: Some(0.05),
            verified_vs_predicted: Some(1.1),
            ..Default::default()
        }
    }

    #[test]
    fn verify_thresholds_fail_a_calibration_that_verifies_worse_than_predicted() {
        let s = AcceptSpec::default_surgical();
        let mut m = good();
        m.verified_vs_predicted = Some(1.5);
        let v = judge(&s, &m, vec![]);
        assert_eq!(v.verdict, VerdictKind::Fail, "{}", v.line());
        assert!(v.line().contains("verified / predicted"), "{}", v.line());
        let mut m = good();
        m.coincidence_mm_after = Some(0.8);
        assert_eq!(judge(&s, &m, vec![]).verdict, VerdictKind::Fail);
        let mut m = good();
        m.verified_rms_mm_after = None;
        assert_eq!(judge(&s, &m, vec![]).verdict, VerdictKind::Incomplete);
    }

    #[test]
    fn shipped_specs_parse_and_a_good_session_passes() {
        let s = AcceptSpec::default_surgical();
        let v = judge(&s, &good(), vec![]);
        assert_eq!(v.verdict, VerdictKind::Pass, "{}", v.line());
        assert_eq!(v.exit_code(), 0);
        for f in ["surgical.toml", "research.toml", "camera.toml"] {
            let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("accept").join(f);
            AcceptSpec::from_file(&p).unwrap();
        }
    }

    #[test]
    fn worse_relative_distance_fails_and_is_flagged() {
        let s = AcceptSpec::default_surgical();
        let mut m = good();
        m.relative_distance_pct_before = Some(0.27);
        m.relative_distance_pct_after = Some(0.77);
        let v = judge(&s, &m, vec![]);
        assert_eq!(v.verdict, VerdictKind::Fail);
        assert_eq!(v.exit_code(), 2);
        assert!(v.line().contains("WORSE"), "{}", v.line());
        assert_eq!(v.worse.len(), 1);
    }

    #[test]
    fn too_many_skipped_fails_and_missing_numbers_are_incomplete() {
        let s = AcceptSpec::default_surgical();
        let mut m = good();
        m.poses_skipped = 100;
        assert_eq!(judge(&s, &m, vec![]).verdict, VerdictKind::Fail);
        let mut m = good();
        m.heldout_rms_mm_after = None;
        let v = judge(&s, &m, vec![]);
        assert_eq!(v.verdict, VerdictKind::Incomplete, "{}", v.line());
        let v = judge(&s, &good(), vec!["validation run stopped".into()]);
        assert_eq!(v.verdict, VerdictKind::Incomplete);
    }

    #[test]
    fn strict_toml_names_the_bad_field() {
        let e = AcceptSpec::from_toml_str("name = \"x\"\nheldout_rms = 1.0\n", "a.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("a.toml") && e.contains("heldout_rms"), "{e}");
        let e = AcceptSpec::from_toml_str("name = \"x\"\nheldout_rms_mm_max = -1.0\n", "a.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("heldout_rms_mm_max"), "{e}");
    }

    #[test]
    fn a_spec_names_its_session_kind_and_an_accuracy_criterion_of_it() {
        use crate::session::SessionKind;
        // No kind; only a name; a kinematic spec with only camera criteria.
        for (text, needle) in [
            (
                "name = \"x\"\nheldout_rms_mm_max = 1.0\n",
                "session = \"kinematic\"",
            ),
            (
                "name = \"x\"\nsession = \"kinematic\"\n",
                "no accuracy criterion",
            ),
            (
                "name = \"x\"\nsession = \"camera\"\nskipped_fraction_max = 0.1\n",
                "heldout_reprojection_px_max",
            ),
            (
                "name = \"x\"\nsession = \"kinematic\"\nheldout_rms_mm_max = 1.0\n\
                 heldout_reprojection_px_max = 0.5\n",
                "never be checked",
            ),
        ] {
            let e = AcceptSpec::from_toml_str(text, "a.toml")
                .unwrap_err()
                .to_string();
            assert!(e.contains("a.toml") && e.contains(needle), "{text}: {e}");
        }
        let kin = AcceptSpec::default_surgical();
        assert_eq!(kin.session, Some(SessionKind::Kinematic));
        kin.check_kind(SessionKind::Kinematic, "s.toml").unwrap();
        let e = kin
            .check_kind(SessionKind::Camera, "s.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("judges kinematic sessions"), "{e}");
    }

    #[test]
    fn camera_sessions_are_judged_by_the_camera_criteria() {
        use crate::session::SessionKind;
        let cam = AcceptSpec::from_file(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("accept/camera.toml"),
        )
        .unwrap();
        let m = Measured {
            poses_planned: 36,
            heldout_poses: 12,
            heldout_reprojection_px_before: Some(0.5),
            heldout_reprojection_px_after: Some(0.18),
            hand_eye_ci95_mm: Some(0.29),
            hand_eye_ci95_deg: Some(0.04),
            hand_eye_heldout_ratio: Some(0.8),
            ..Default::default()
        };
        let v = judge_kind(&cam, &m, vec![], SessionKind::Camera);
        assert_eq!(v.verdict, VerdictKind::Pass, "{}", v.line());
        // A hand-eye interval the held-out views contradict: FAIL, naming the check; no
        // independent check at all: the interval cannot be judged (INCOMPLETE).
        let mut u = m.clone();
        u.hand_eye_heldout_ratio = Some(1.4);
        let v = judge_kind(&cam, &u, vec![], SessionKind::Camera);
        assert_eq!(v.verdict, VerdictKind::Fail, "{}", v.line());
        assert!(
            v.line().contains("confirmed by the held-out views"),
            "{}",
            v.line()
        );
        u.hand_eye_heldout_ratio = None;
        let v = judge_kind(&cam, &u, vec![], SessionKind::Camera);
        assert_eq!(v.verdict, VerdictKind::Incomplete, "{}", v.line());
        // The kinematic criteria do not apply to a camera session...
        assert!(v
            .criteria
            .iter()
            .all(|c| !c.limit.contains("mm") || c.name.contains("hand-eye")));
        // ...and a spec without any camera criterion cannot pass one.
        let v = judge_kind(
            &AcceptSpec::default_surgical(),
            &m,
            vec![],
            SessionKind::Camera,
        );
        assert_eq!(v.verdict, VerdictKind::Incomplete, "{}", v.line());
        assert!(v.line().contains("no camera criterion"), "{}", v.line());
        // Worse after the diagnosis, or above the limit: FAIL.
        let mut w = m.clone();
        w.heldout_reprojection_px_after = Some(0.6);
        let v = judge_kind(&cam, &w, vec![], SessionKind::Camera);
        assert_eq!(v.verdict, VerdictKind::Fail);
        assert_eq!(v.worse.len(), 1, "{:?}", v.worse);
        let e = AcceptSpec::from_toml_str(
            "name = \"x\"\nheldout_reprojection_px_max = 0.0\n",
            "a.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("heldout_reprojection_px_max"), "{e}");
    }
}
