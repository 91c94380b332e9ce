//! `registration.json` (`robocal-registration/1`): the CT → tracker transform with its
//! covariance, FRE / FLE, predicted TRE at targets and the per-point residuals. One typed
//! serde schema for writer and reader. Units: mm and degrees.
//!
//! `T_tracker_ct.covariance` is the 6×6 row-major covariance of the left perturbation
//! `(ω_x, ω_y, ω_z, t_x, t_y, t_z)` in **degrees and mm** (`T = (Exp(ω) R, t + δt)`,
//! tracker frame).
use std::path::Path;

use nalgebra::{Isometry3, Matrix6, Point3};
use serde::{Deserialize, Serialize};

use super::paired::{iso_to_rows, rows_to_iso, PairedRegistration};
use super::{io_err, RegisterError};

/// Format tag of a registration file.
pub use crate::schema::REGISTRATION_FORMAT;

/// A transform with covariance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransformWithCov {
    /// 4×4 row-major (mm).
    pub matrix: Vec<f64>,
    /// 6×6 row-major covariance of `(ω deg, t mm)` (left perturbation).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covariance: Option<Vec<f64>>,
    /// Covariance order and units (documentation in the file).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covariance_order: Option<String>,
    /// CT-localisation part of the covariance (same layout).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covariance_ct: Option<Vec<f64>>,
    /// Tracker-localisation part of the covariance (same layout).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covariance_tracker: Option<Vec<f64>>,
}

/// One fiducial / surface point and its residual.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointResidual {
    pub name: String,
    /// CT point (mm); for a surface point: the closest mesh point (CT).
    pub ct: [f64; 3],
    /// Tracker point (mm).
    pub tracker: [f64; 3],
    /// Residual length (mm): `|T·ct − tracker|` (paired) or point-to-plane distance (surface).
    pub residual_mm: f64,
    /// Surface points: whether the trimmed ICP used this point at the end.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inlier: Option<bool>,
}

/// Predicted TRE at one target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetTre {
    pub name: String,
    pub ct: [f64; 3],
    /// Target mapped into the tracker frame (mm).
    pub tracker: [f64; 3],
    /// Predicted RMS TRE (mm): Fitzpatrick–West for paired fiducials without a noise model,
    /// else `√trace` of the propagated covariance.
    pub tre_rms_mm: f64,
    /// Half-axes (mm) of the 95 % error ellipsoid, largest first.
    pub ellipsoid95_mm: [f64; 3],
}

/// ICP summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IcpSummary {
    pub mesh: String,
    pub points: usize,
    pub inliers: usize,
    pub trim_fraction: f64,
    pub starts: usize,
    pub iterations: usize,
    /// RMS point-to-plane distance of the inliers (mm).
    pub rms_mm: f64,
    /// Second-best start's RMS (mm): close to `rms_mm` with a different pose = ambiguous.
    pub runner_up_rms_mm: Option<f64>,
    /// Angle (deg) between the best and runner-up solutions.
    pub runner_up_angle_deg: Option<f64>,
    /// Point-to-surface distance of the inliers (absolute, mm): mean and sd.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distance_mean_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distance_sd_mm: Option<f64>,
}

/// `robocal-registration/1`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegistrationFile {
    /// Always `robocal-registration/1`.
    pub format: String,
    /// `paired` or `surface`.
    pub kind: String,
    #[serde(rename = "T_tracker_ct")]
    pub t_tracker_ct: TransformWithCov,
    /// RMS fiducial registration error (mm) (surface: inlier RMS point-to-plane distance).
    pub fre_mm: f64,
    /// Estimated RMS fiducial localisation error (mm).
    pub fle_mm: f64,
    pub n_points: usize,
    #[serde(default)]
    pub points: Vec<PointResidual>,
    #[serde(default)]
    pub targets: Vec<TargetTre>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub unpaired: Vec<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub icp: Option<IcpSummary>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub notes: Option<String>,
    /// Check points (`register --check-ct … --check-tracker …`): points not used by the fit,
    /// known in CT and measured in the tracker, with their error through the registration.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub check_points: Vec<crate::register::check::CheckPoint>,
}

/// The order string written into files.
pub const COV_ORDER: &str =
    "wx_deg,wy_deg,wz_deg,tx_mm,ty_mm,tz_mm (left perturbation, tracker frame)";

/// Internal (rad, mm) covariance → file (deg, mm) row-major.
pub fn cov_to_file(c: &Matrix6<f64>) -> Vec<f64> {
    let s = [
        1f64.to_degrees(),
        1f64.to_degrees(),
        1f64.to_degrees(),
        1.0,
        1.0,
        1.0,
    ];
    let mut o = Vec::with_capacity(36);
    for r in 0..6 {
        for k in 0..6 {
            o.push(c[(r, k)] * s[r] * s[k]);
        }
    }
    o
}

/// File (deg, mm) row-major → internal (rad, mm).
pub fn cov_from_file(v: &[f64], what: &str) -> Result<Matrix6<f64>, RegisterError> {
    if v.len() != 36 || !v.iter().all(|x| x.is_finite()) {
        return Err(RegisterError::Invalid(format!(
            "{what}: covariance must be 36 finite numbers (6×6 row-major), got {}",
            v.len()
        )));
    }
    let s = [
        1f64.to_radians(),
        1f64.to_radians(),
        1f64.to_radians(),
        1.0,
        1.0,
        1.0,
    ];
    let mut m = Matrix6::zeros();
    for r in 0..6 {
        for k in 0..6 {
            m[(r, k)] = v[6 * r + k] * s[r] * s[k];
        }
    }
    if (m - m.transpose()).norm() > 1e-9 * m.norm().max(1e-300)
        || m.symmetric_eigenvalues().min() < -1e-12 * m.norm()
    {
        return Err(RegisterError::Invalid(format!(
            "{what}: covariance is not symmetric positive semi-definite"
        )));
    }
    Ok(m)
}

/// 95 % ellipsoid half-axes of a 3×3 covariance (χ²₃(0.95) = 7.8147), largest first.
pub fn ellipsoid95(c: &nalgebra::Matrix3<f64>) -> [f64; 3] {
    let k = 7.814_727_903_251_178f64.sqrt();
    let mut e: Vec<f64> = c
        .symmetric_eigenvalues()
        .iter()
        .map(|x| k * x.max(0.0).sqrt())
        .collect();
    e.sort_by(|a, b| b.total_cmp(a));
    [e[0], e[1], e[2]]
}

fn arr(p: &Point3<f64>) -> [f64; 3] {
    [p.x, p.y, p.z]
}

impl RegistrationFile {
    /// The file of a paired registration, with TRE at `targets` (name, CT point).
    pub fn from_paired(r: &PairedRegistration, targets: &[(String, Point3<f64>)]) -> Self {
        let points = r
            .names
            .iter()
            .enumerate()
            .map(|(i, n)| PointResidual {
                name: n.clone(),
                ct: arr(&r.ct[i]),
                tracker: arr(&r.tracker[i]),
                residual_mm: r.residuals[i].norm(),
                inlier: None,
            })
            .collect();
        let targets = targets
            .iter()
            .map(|(n, p)| {
                let c = r.target_cov(p);
                TargetTre {
                    name: n.clone(),
                    ct: arr(p),
                    tracker: arr(&(r.t_tracker_ct * p)),
                    tre_rms_mm: if r.weighted {
                        c.trace().sqrt()
                    } else {
                        r.tre_fw(p)
                    },
                    ellipsoid95_mm: ellipsoid95(&c),
                }
            })
            .collect();
        RegistrationFile {
            format: REGISTRATION_FORMAT.into(),
            kind: "paired".into(),
            t_tracker_ct: TransformWithCov {
                matrix: iso_to_rows(&r.t_tracker_ct).to_vec(),
                covariance: Some(cov_to_file(&r.cov)),
                covariance_order: Some(COV_ORDER.into()),
                covariance_ct: r.cov_ct.as_ref().map(cov_to_file),
                covariance_tracker: r.cov_tracker.as_ref().map(cov_to_file),
            },
            fre_mm: r.fre_mm,
            fle_mm: r.fle_mm,
            n_points: r.names.len(),
            points,
            targets,
            unpaired: r.unpaired.clone(),
            icp: None,
            notes: None,
            check_points: Vec::new(),
        }
    }

    /// The transform `T_tracker_ct`.
    pub fn transform(&self) -> Result<Isometry3<f64>, RegisterError> {
        rows_to_iso(&self.t_tracker_ct.matrix, "T_tracker_ct.matrix")
    }

    /// Covariance (rad, mm), if present.
    pub fn covariance(&self) -> Result<Option<Matrix6<f64>>, RegisterError> {
        self.t_tracker_ct
            .covariance
            .as_deref()
            .map(|v| cov_from_file(v, "T_tracker_ct.covariance"))
            .transpose()
    }

    /// Writes the file (pretty JSON).
    pub fn save(&self, path: &Path) -> Result<(), RegisterError> {
        let s = serde_json::to_string_pretty(self)
            .map_err(|e| RegisterError::Invalid(format!("serialising: {e}")))?;
        crate::fsio::write(path, s + "\n").map_err(|e| io_err(path, e))
    }

    /// Reads and checks a registration file.
    pub fn load(path: &Path) -> Result<Self, RegisterError> {
        let text = crate::fsio::read_to_string(path).map_err(|e| io_err(path, e))?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parses and checks registration JSON text.
    pub fn parse(text: &str, file: &str) -> Result<Self, RegisterError> {
        let f: RegistrationFile = serde_json::from_str(text).map_err(|e| RegisterError::Input {
            file: file.into(),
            line: e.line(),
            msg: crate::schema::kind::with_other_kind(
                format_args!("{e} (expected a `{REGISTRATION_FORMAT}` file)"),
                text,
                REGISTRATION_FORMAT,
            ),
        })?;
        if f.format != REGISTRATION_FORMAT {
            return Err(RegisterError::Input {
                file: file.into(),
                line: 1,
                msg: format!(
                    "field `format`: `{}` is not `{REGISTRATION_FORMAT}`",
                    f.format
                ),
            });
        }
        f.transform().map_err(|e| RegisterError::Input {
            file: file.into(),
            line: 0,
            msg: e.to_string(),
        })?;
        f.covariance().map_err(|e| RegisterError::Input {
            file: file.into(),
            line: 0,
            msg: e.to_string(),
        })?;
        Ok(f)
    }
}

/// Reads an initial transform for ICP: a registration file, or any JSON whose
/// `T_tracker_ct.matrix` is a 4×4 row-major in mm.
pub fn load_init(path: &Path) -> Result<Isometry3<f64>, RegisterError> {
    let text = crate::fsio::read_to_string(path).map_err(|e| io_err(path, e))?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| RegisterError::Input {
        file: path.display().to_string(),
        line: e.line(),
        msg: crate::schema::kind::with_other_kind(&e, &text, REGISTRATION_FORMAT),
    })?;
    let m = v
        .get("T_tracker_ct")
        .and_then(|t| t.get("matrix"))
        .and_then(|m| m.as_array())
        .ok_or_else(|| RegisterError::Input {
            file: path.display().to_string(),
            line: 0,
            msg: "no `T_tracker_ct.matrix` (4×4 row-major, mm)".into(),
        })?;
    let vals: Option<Vec<f64>> = m.iter().map(|x| x.as_f64()).collect();
    let vals = vals.ok_or_else(|| RegisterError::Input {
        file: path.display().to_string(),
        line: 0,
        msg: "`T_tracker_ct.matrix` must hold 16 numbers".into(),
    })?;
    rows_to_iso(&vals, &format!("{}: T_tracker_ct.matrix", path.display()))
}
