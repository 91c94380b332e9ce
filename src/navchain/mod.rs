//! The error transfer of seed 003 ("误差传递模型", docs/seeds.md): how far from a point planned in CT the
//! tool tip lands, and which link of the chain is to blame.
//!
//! The planned CT target `x` is sent to the robot base as `p = Y · T · x` (`T =
//! T_tracker_ct` from [`crate::register`], `Y = T_base_tracker` from the robot-world
//! registration); the robot (calibrated kinematics) then places the tool tip there. The tip
//! error is the sum of
//!
//! - **registration, CT localisation**: fiducial localisation in the CT image → `T`,
//! - **registration, tracker localisation**: the tracker's own stereo error (depth ∝ z²,
//!   [`crate::register::StereoTrackerModel`]) at the fiducials → `T`,
//! - **tracker → robot**: the covariance of `Y` (robot-world refinement),
//! - **robot**: the calibrated robot's positioning covariance at the tip (from the
//!   calibration's bootstrap / held-out error),
//! - **tool**: the tip offset uncertainty (pivot calibration).
//!
//! [`chain_report`] propagates these to first order (`Σ = Σ_k J_k Σ_k J_kᵀ`) and by Monte
//! Carlo through the exact transforms (they must agree), gives the 95 % ellipsoid and each
//! link's share of the variance. It is the library entry `robocal chain` and a session's
//! closing chain report call.
pub mod compare;
pub mod correct_targets;
pub mod correction;
pub mod nn;

use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, SymmetricEigen, Vector3, Vector6};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::register::file::ellipsoid95;
use crate::register::paired::{perturb, point_jacobian};
use crate::register::RegisterError;

/// χ²₃ at 0.95.
pub const CHI2_3_95: f64 = 7.814_727_903_251_178;

/// The links of the chain (first-order inputs, internal units rad / mm).
#[derive(Debug, Clone)]
pub struct ChainInputs {
    /// `T_tracker_ct`.
    pub t_tracker_ct: Isometry3<f64>,
    /// CT-localisation part of the registration covariance (left perturbation).
    pub cov_reg_ct: Matrix6<f64>,
    /// Tracker-localisation part of the registration covariance.
    pub cov_reg_tracker: Matrix6<f64>,
    /// `T_base_tracker`.
    pub t_base_tracker: Isometry3<f64>,
    /// Covariance of `Y` (left perturbation).
    pub cov_y: Matrix6<f64>,
    /// Robot tip positioning covariance in the base (mm²).
    pub cov_robot: Matrix3<f64>,
    /// Tool tip offset covariance (mm²; isotropic in practice, so frame-free).
    pub cov_tool: Matrix3<f64>,
}

/// Link names in report order.
pub const LINKS: [&str; 5] = [
    "registration: CT localisation",
    "registration: tracker localisation",
    "tracker -> robot (Y)",
    "robot kinematics",
    "tool tip",
];

/// One link's contribution at a target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkShare {
    pub link: String,
    /// RMS (3-D) error of this link alone (mm).
    pub rms_mm: f64,
    /// Share of the total variance (0–1).
    pub share: f64,
}

/// The predicted tool-tip error at one CT target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetReport {
    pub name: String,
    pub ct: [f64; 3],
    /// Planned point in the robot base (mm).
    pub base: [f64; 3],
    /// First-order RMS (3-D) tip error (mm).
    pub rms_mm: f64,
    /// 95 % ellipsoid half-axes (mm), largest first, and the axes (unit, base frame).
    pub ellipsoid95_mm: [f64; 3],
    pub ellipsoid_axes: [[f64; 3]; 3],
    /// First-order covariance (mm², base frame, row-major).
    pub covariance: [f64; 9],
    pub links: Vec<LinkShare>,
    /// Monte Carlo: mean error (mm), RMS (mm), samples, relative difference of the MC
    /// covariance from the first-order one (Frobenius), and the fraction of MC samples
    /// inside the first-order 95 % ellipsoid.
    pub mc_mean_mm: [f64; 3],
    pub mc_rms_mm: f64,
    pub mc_samples: usize,
    pub mc_cov_rel_diff: f64,
    pub mc_inside95: f64,
}

/// `chain.json` (`robocal-chain/1`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChainReport {
    pub format: String,
    pub targets: Vec<TargetReport>,
    /// Mean share of each link over the targets.
    pub mean_shares: Vec<LinkShare>,
}

/// Format tag of `chain.json`.
pub use crate::schema::CHAIN_FORMAT;

/// The five link covariances (base frame, mm²) at CT target `x`.
pub fn link_covariances(inp: &ChainInputs, x: &Point3<f64>) -> [Matrix3<f64>; 5] {
    let q = inp.t_tracker_ct * x;
    let ry = inp
        .t_base_tracker
        .rotation
        .to_rotation_matrix()
        .into_inner();
    let jt = ry * point_jacobian(&inp.t_tracker_ct, x);
    let jy = point_jacobian(&inp.t_base_tracker, &q);
    [
        jt * inp.cov_reg_ct * jt.transpose(),
        jt * inp.cov_reg_tracker * jt.transpose(),
        jy * inp.cov_y * jy.transpose(),
        inp.cov_robot,
        inp.cov_tool,
    ]
}

fn sampler6(c: &Matrix6<f64>) -> Matrix6<f64> {
    // Symmetric square root (works for semi-definite covariances).
    let e = SymmetricEigen::new(*c);
    let d = Matrix6::from_diagonal(&e.eigenvalues.map(|v| v.max(0.0).sqrt()));
    e.eigenvectors * d * e.eigenvectors.transpose()
}

fn sampler3(c: &Matrix3<f64>) -> Matrix3<f64> {
    let e = SymmetricEigen::new(*c);
    let d = Matrix3::from_diagonal(&e.eigenvalues.map(|v| v.max(0.0).sqrt()));
    e.eigenvectors * d * e.eigenvectors.transpose()
}

fn n6<R: rand::Rng>(rng: &mut R) -> Vector6<f64> {
    Vector6::from_fn(|_, _| StandardNormal.sample(rng))
}
fn n3<R: rand::Rng>(rng: &mut R) -> Vector3<f64> {
    Vector3::from_fn(|_, _| StandardNormal.sample(rng))
}

/// Checks the inputs (finite, covariances symmetric PSD).
pub fn validate(inp: &ChainInputs) -> Result<(), RegisterError> {
    let psd6 = |c: &Matrix6<f64>, w: &str| -> Result<(), RegisterError> {
        if !c.iter().all(|x| x.is_finite())
            || (c - c.transpose()).norm() > 1e-9 * c.norm().max(1e-300)
            || c.symmetric_eigenvalues().min() < -1e-9 * c.norm()
        {
            return Err(RegisterError::Invalid(format!(
                "chain: {w} covariance is not symmetric positive semi-definite"
            )));
        }
        Ok(())
    };
    let psd3 = |c: &Matrix3<f64>, w: &str| -> Result<(), RegisterError> {
        if !c.iter().all(|x| x.is_finite())
            || (c - c.transpose()).norm() > 1e-9 * c.norm().max(1e-300)
            || c.symmetric_eigenvalues().min() < -1e-9 * c.norm()
        {
            return Err(RegisterError::Invalid(format!(
                "chain: {w} covariance is not symmetric positive semi-definite"
            )));
        }
        Ok(())
    };
    psd6(&inp.cov_reg_ct, "registration (CT)")?;
    psd6(&inp.cov_reg_tracker, "registration (tracker)")?;
    psd6(&inp.cov_y, "tracker -> robot")?;
    psd3(&inp.cov_robot, "robot")?;
    psd3(&inp.cov_tool, "tool")?;
    Ok(())
}

/// The chain report for CT targets (name, point): first order and Monte Carlo
/// (`mc_samples`, deterministic `seed`).
pub fn chain_report(
    inp: &ChainInputs,
    targets: &[(String, Point3<f64>)],
    mc_samples: usize,
    seed: u64,
) -> Result<ChainReport, RegisterError> {
    validate(inp)?;
    if targets.is_empty() {
        return Err(RegisterError::Invalid("chain: no targets".into()));
    }
    let s_ct = sampler6(&inp.cov_reg_ct);
    let s_trk = sampler6(&inp.cov_reg_tracker);
    let s_y = sampler6(&inp.cov_y);
    let s_rob = sampler3(&inp.cov_robot);
    let s_tool = sampler3(&inp.cov_tool);
    let mut out = Vec::new();
    let mut share_acc = [0.0; 5];
    for (ti, (name, x)) in targets.iter().enumerate() {
        let parts = link_covariances(inp, x);
        let total: Matrix3<f64> = parts.iter().sum();
        let tr = total.trace();
        let links: Vec<LinkShare> = parts
            .iter()
            .enumerate()
            .map(|(k, c)| LinkShare {
                link: LINKS[k].into(),
                rms_mm: c.trace().max(0.0).sqrt(),
                share: if tr > 0.0 { c.trace() / tr } else { 0.0 },
            })
            .collect();
        for (k, l) in links.iter().enumerate() {
            share_acc[k] += l.share;
        }
        let planned = inp.t_base_tracker * (inp.t_tracker_ct * x);
        // Monte Carlo through the exact transforms.
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ (ti as u64).wrapping_mul(0x9E37_79B9));
        let mut sum = Vector3::zeros();
        let mut sq = Matrix3::zeros();
        let mut errs = Vec::with_capacity(mc_samples);
        for _ in 0..mc_samples {
            let dt = s_ct * n6(&mut rng) + s_trk * n6(&mut rng);
            let dy = s_y * n6(&mut rng);
            let t = perturb(&inp.t_tracker_ct, dt.as_slice());
            let y = perturb(&inp.t_base_tracker, dy.as_slice());
            let e = y * (t * x) - planned + s_rob * n3(&mut rng) + s_tool * n3(&mut rng);
            sum += e;
            sq += e * e.transpose();
            errs.push(e);
        }
        let m = mc_samples.max(1) as f64;
        let mean = sum / m;
        let mc_cov = sq / m - mean * mean.transpose();
        let inv = total.try_inverse();
        let inside = match inv {
            Some(inv) => {
                errs.iter()
                    .filter(|e| (e.transpose() * inv * *e)[(0, 0)] <= CHI2_3_95)
                    .count() as f64
                    / m
            }
            None => f64::NAN,
        };
        let eig = SymmetricEigen::new(total);
        let mut order: Vec<usize> = (0..3).collect();
        order.sort_by(|a, b| eig.eigenvalues[*b].total_cmp(&eig.eigenvalues[*a]));
        let axes = [0, 1, 2].map(|k| {
            let v = eig.eigenvectors.column(order[k]);
            [v[0], v[1], v[2]]
        });
        let mut cov9 = [0.0; 9];
        for r in 0..3 {
            for c in 0..3 {
                cov9[3 * r + c] = total[(r, c)];
            }
        }
        out.push(TargetReport {
            name: name.clone(),
            ct: [x.x, x.y, x.z],
            base: [planned.x, planned.y, planned.z],
            rms_mm: tr.max(0.0).sqrt(),
            ellipsoid95_mm: ellipsoid95(&total),
            ellipsoid_axes: axes,
            covariance: cov9,
            links,
            mc_mean_mm: [mean.x, mean.y, mean.z],
            mc_rms_mm: (sq.trace() / m).sqrt(),
            mc_samples,
            mc_cov_rel_diff: (mc_cov - total).norm() / total.norm().max(1e-300),
            mc_inside95: inside,
        });
    }
    let nt = targets.len() as f64;
    let mean_shares = (0..5)
        .map(|k| LinkShare {
            link: LINKS[k].into(),
            rms_mm: (out.iter().map(|t| t.links[k].rms_mm.powi(2)).sum::<f64>() / nt).sqrt(),
            share: share_acc[k] / nt,
        })
        .collect();
    Ok(ChainReport {
        format: CHAIN_FORMAT.into(),
        targets: out,
        mean_shares,
    })
}

/// Robot tip positioning covariance from a calibrated model and per-parameter standard
/// deviations (e.g. the bootstrap's), at joint configuration `q` (rad): `J diag(σ²) Jᵀ`
/// with `J` the tip's derivative w.r.t. the model parameters (independent parameters).
pub fn robot_tip_covariance(
    model: &crate::model::KinematicModel,
    param_std: &[f64],
    q: &[f64],
) -> Result<Matrix3<f64>, RegisterError> {
    let (_, j) = model.point_param_jacobian(q);
    if param_std.len() != j.ncols() {
        return Err(RegisterError::Invalid(format!(
            "robot link: {} parameter sigmas for {} parameters",
            param_std.len(),
            j.ncols()
        )));
    }
    let mut c = Matrix3::zeros();
    for (k, s) in param_std.iter().enumerate() {
        let col = j.column(k);
        c += col * col.transpose() * (s * s);
    }
    Ok(c)
}

/// Robot tip covariance (mm²) from a full parameter covariance `cov` (internal units
/// mm / rad, rows and columns named by `names`) at joint configuration `q` (rad):
/// `J Σ Jᵀ` over the entries that are model parameters (effect parameters of the bootstrap,
/// which the geometric model does not carry, are left out).
pub fn robot_tip_covariance_full(
    model: &crate::model::KinematicModel,
    names: &[String],
    cov: &nalgebra::DMatrix<f64>,
    q: &[f64],
) -> Result<Matrix3<f64>, RegisterError> {
    let n = names.len();
    if cov.nrows() != n || cov.ncols() != n {
        return Err(RegisterError::Invalid(format!(
            "robot link: covariance is {}x{} for {n} names",
            cov.nrows(),
            cov.ncols()
        )));
    }
    if cov.iter().any(|v| !v.is_finite()) {
        return Err(RegisterError::Invalid(
            "robot link: covariance has a non-finite entry".into(),
        ));
    }
    let (_, j) = model.point_param_jacobian(q);
    // J restricted to the named entries (zero column for names the model does not have).
    let mut jn = nalgebra::Matrix3xX::zeros(n);
    for (k, name) in names.iter().enumerate() {
        if let Some(i) = model.param_index(name) {
            jn.set_column(k, &j.column(i));
        }
    }
    Ok(&jn * cov * jn.transpose())
}

/// The robot link of the chain from a `robocal-calibration/1` file at joint configuration
/// `q` (rad): the bootstrap's full parameter covariance (`bootstrap.covariance`, written by
/// `calibrate kinematics --bootstrap`) if present, else the per-parameter bootstrap σ, else
/// the LM σ (`std`), as independent parameters. Returns the tip covariance (mm², robot
/// base) and which source was used.
pub fn robot_link_from_calibration(
    cal: &crate::dataset::CalibrationFile,
    q: &[f64],
) -> Result<(Matrix3<f64>, &'static str), RegisterError> {
    let mut model = crate::model::KinematicModel::from_robot_block(&cal.robot)
        .map_err(|e| RegisterError::Invalid(format!("robot link: {e}")))?;
    model
        .apply_cal_params(&cal.params)
        .map_err(|e| RegisterError::Invalid(format!("robot link: {e}")))?;
    if q.len() != model.dof() {
        return Err(RegisterError::Invalid(format!(
            "robot link: {} joint values for a {}-joint robot",
            q.len(),
            model.dof()
        )));
    }
    // The joints must be a pose the robot can take (degrees, inside its limits): 800° or
    // radians would give the uncertainty of a pose that does not exist.
    let tol = crate::plausible::dataset::JOINT_LIMIT_TOL_DEG.to_radians();
    for (k, (&x, &(lo, hi))) in q.iter().zip(&model.joint_limits()).enumerate() {
        if !x.is_finite() || x < lo - tol || x > hi + tol {
            return Err(RegisterError::Invalid(format!(
                "--joints-deg: joint {} = {}° is outside the robot's limits [{:.1}°, {:.1}°] \
                 ({}): give the pose in degrees",
                k + 1,
                x.to_degrees(),
                lo.to_degrees(),
                hi.to_degrees(),
                cal.robot.model
            )));
        }
    }
    if let Some(c) = cal.extra.get("bootstrap").and_then(|b| b.get("covariance")) {
        let fc: BootstrapCovariance = serde_json::from_value(c.clone()).map_err(|e| {
            RegisterError::Invalid(format!("calibration: `bootstrap.covariance`: {e}"))
        })?;
        let n = fc.names.len();
        if fc.matrix.len() != n * n {
            return Err(RegisterError::Invalid(format!(
                "calibration: `bootstrap.covariance.matrix` has {} entries for {n} names (want {})",
                fc.matrix.len(),
                n * n
            )));
        }
        let m = nalgebra::DMatrix::from_row_slice(n, n, &fc.matrix);
        let c = robot_tip_covariance_full(&model, &fc.names, &m, q)?;
        return Ok((c, "bootstrap covariance"));
    }
    let mut std = vec![0.0; model.params().len()];
    let mut source = "LM std (parameters treated as independent: correlated kinematic parameters make this an over-estimate; prefer `--bootstrap`'s covariance)";
    let mut with_sigma = 0usize;
    for p in &cal.params {
        let Some(i) = model.param_index(&p.name) else {
            continue;
        };
        let boot = p
            .extra
            .get("bootstrap")
            .and_then(|b| b.get("std"))
            .and_then(|v| v.as_f64());
        if boot.is_some() {
            source = "bootstrap std (parameters treated as independent: an over-estimate when they are correlated)";
        }
        let Some(s) = boot.or(p.std) else { continue };
        if !(s.is_finite() && s >= 0.0) {
            return Err(RegisterError::Invalid(format!(
                "calibration: parameter `{}`: std {s} is not a finite number ≥ 0",
                p.name
            )));
        }
        let u = p.unit.trim().to_ascii_lowercase();
        std[i] = if matches!(u.as_str(), "deg" | "degree" | "degrees") {
            s.to_radians()
        } else if u == "m" {
            s * 1000.0
        } else {
            s
        };
        with_sigma += 1;
    }
    if with_sigma == 0 {
        // A calibration without any uncertainty would make the robot link exactly zero: a
        // confident wrong answer.
        return Err(RegisterError::Invalid(
            "calibration: no parameter carries an uncertainty (`std` or `bootstrap`), so the \
             robot link cannot be estimated: use the calibration written by `robocal calibrate \
             kinematics` (with `--bootstrap` for the full covariance), or give a tool-tip σ"
                .into(),
        ));
    }
    Ok((robot_tip_covariance(&model, &std, q)?, source))
}

/// `bootstrap.covariance` of a calibration file: the covariance of the bootstrap's subset
/// fits, internal units (mm, rad), row-major.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BootstrapCovariance {
    /// Always `"mm, rad"`.
    pub units: String,
    pub names: Vec<String>,
    pub matrix: Vec<f64>,
}

impl BootstrapCovariance {
    /// Sample covariance of `samples[k][i]` (entry `i` of fit `k`).
    pub fn from_samples(names: &[String], samples: &[Vec<f64>]) -> Self {
        let n = names.len();
        let k = samples.len();
        let mut mean = vec![0.0; n];
        for s in samples {
            for i in 0..n {
                mean[i] += s[i] / k as f64;
            }
        }
        let mut m = vec![0.0; n * n];
        if k > 1 {
            for s in samples {
                for i in 0..n {
                    for j in 0..n {
                        m[i * n + j] += (s[i] - mean[i]) * (s[j] - mean[j]) / (k - 1) as f64;
                    }
                }
            }
        }
        BootstrapCovariance {
            units: "mm, rad".into(),
            names: names.to_vec(),
            matrix: m,
        }
    }
}

impl ChainReport {
    /// Writes `chain.json`.
    pub fn save(&self, path: &std::path::Path) -> Result<(), RegisterError> {
        let s = serde_json::to_string_pretty(self)
            .map_err(|e| RegisterError::Invalid(format!("serialising: {e}")))?;
        crate::fsio::write(path, s + "\n").map_err(|e| RegisterError::Io {
            path: path.display().to_string(),
            source: e,
        })
    }
    /// Reads `chain.json`.
    pub fn load(path: &std::path::Path) -> Result<Self, RegisterError> {
        let text = crate::fsio::read_to_string(path).map_err(|e| RegisterError::Io {
            path: path.display().to_string(),
            source: e,
        })?;
        let r: ChainReport = serde_json::from_str(&text).map_err(|e| RegisterError::Input {
            file: path.display().to_string(),
            line: e.line(),
            msg: crate::schema::kind::with_other_kind(&e, &text, CHAIN_FORMAT),
        })?;
        if r.format != CHAIN_FORMAT {
            return Err(RegisterError::Input {
                file: path.display().to_string(),
                line: 1,
                msg: format!("`format` is not `{CHAIN_FORMAT}`"),
            });
        }
        Ok(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_order_and_monte_carlo_agree() {
        let d6 = |r: f64, t: f64| {
            Matrix6::from_diagonal(&Vector6::new(r * r, r * r, r * r, t * t, t * t, t * t))
        };
        let inp = ChainInputs {
            t_tracker_ct: Isometry3::new(
                Vector3::new(0.0, 0.0, -1600.0),
                Vector3::new(0.3, 0.1, 2.0),
            ),
            cov_reg_ct: d6(3e-4, 0.1),
            cov_reg_tracker: d6(2e-4, 0.08),
            t_base_tracker: Isometry3::new(
                Vector3::new(1500.0, 0.0, 500.0),
                Vector3::new(0.0, -1.5, 0.0),
            ),
            cov_y: d6(1e-4, 0.1),
            cov_robot: Matrix3::identity() * 0.04,
            cov_tool: Matrix3::identity() * 0.01,
        };
        let r = chain_report(
            &inp,
            &[("t".into(), Point3::new(20.0, -30.0, 50.0))],
            20_000,
            1,
        )
        .unwrap();
        let t = &r.targets[0];
        assert!(t.mc_cov_rel_diff < 0.05, "{}", t.mc_cov_rel_diff);
        assert!((t.mc_inside95 - 0.95).abs() < 0.01, "{}", t.mc_inside95);
        let s: f64 = t.links.iter().map(|l| l.share).sum();
        assert!((s - 1.0).abs() < 1e-12);
    }

    /// The robot link from a full parameter covariance: first order `J Σ Jᵀ` agrees with
    /// Monte Carlo over sampled parameter vectors pushed through the model's forward
    /// kinematics, and the correlations matter (the diagonal-only link differs).
    #[test]
    fn robot_link_full_covariance_first_order_matches_monte_carlo() {
        let model = crate::model::presets::preset("vs060").unwrap();
        let q = [0.3, -0.4, 1.2, 0.2, 0.7, -0.5];
        let free: Vec<usize> = (0..model.params().len())
            .filter(|&i| model.params()[i].free)
            .collect();
        let names: Vec<String> = free
            .iter()
            .map(|&i| model.params()[i].name.clone())
            .collect();
        let n = names.len();
        // A correlated covariance: Σ = L Lᵀ, L lower-triangular with sizes of a calibration.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut l = nalgebra::DMatrix::<f64>::zeros(n, n);
        for i in 0..n {
            let s = match model.params()[free[i]].unit {
                crate::model::Unit::Mm => 0.02,
                crate::model::Unit::Rad => 2e-5,
            };
            for j in 0..=i {
                let z: f64 = StandardNormal.sample(&mut rng);
                l[(i, j)] = s * if i == j { 1.0 } else { 0.5 * z };
            }
        }
        let cov = &l * l.transpose();
        let c1 = robot_tip_covariance_full(&model, &names, &cov, &q).unwrap();
        let p0 = model.measured_point(&q);
        let mut cm = Matrix3::zeros();
        let trials = 20_000;
        let v0 = model.param_values();
        let mut m = model.clone();
        for _ in 0..trials {
            let z = nalgebra::DVector::from_fn(n, |_, _| StandardNormal.sample(&mut rng));
            let dz = &l * z;
            let mut v = v0.clone();
            for (k, &i) in free.iter().enumerate() {
                v[i] += dz[k];
            }
            m.set_param_values(&v);
            let d = m.measured_point(&q) - p0;
            cm += d * d.transpose() / trials as f64;
        }
        let rel = (cm - c1).norm() / c1.norm();
        let diag: Vec<f64> = (0..n).map(|i| cov[(i, i)].sqrt()).collect();
        let mut std_all = vec![0.0; model.params().len()];
        for (k, &i) in free.iter().enumerate() {
            std_all[i] = diag[k];
        }
        let cd = robot_tip_covariance(&model, &std_all, &q).unwrap();
        let rel_diag = (cd - c1).norm() / c1.norm();
        println!(
            "robot link: first order RMS {:.4} mm, MC RMS {:.4} mm, |MC − FO|/|FO| {rel:.3}; diagonal-only RMS {:.4} mm (|Δ|/|FO| {rel_diag:.3})",
            c1.trace().sqrt(),
            cm.trace().sqrt(),
            cd.trace().sqrt()
        );
        assert!(rel < 0.05, "{rel}");
        assert!(rel_diag > 0.05, "{rel_diag}");
    }
}

/// Where the robot link of a chain evaluation comes from.
#[derive(Debug, Clone, Copy)]
pub enum RobotLinkSource<'a> {
    /// A calibration file (its bootstrap covariance, else per-parameter std) propagated to the
    /// tool tip at these joints (deg).
    Calibration {
        path: &'a std::path::Path,
        joints_deg: &'a [f64],
    },
    /// An isotropic tool-tip σ (mm).
    SigmaMm(f64),
}

/// The files of a chain evaluation: what `robocal chain` and a session's closing chain stage
/// read.
#[derive(Debug, Clone, Copy)]
pub struct ChainFiles<'a> {
    /// CT → tracker registration (`robocal-registration/1`).
    pub registration: &'a std::path::Path,
    /// Tracker → robot base (`robocal calibrate robot-world`).
    pub robot_world: &'a std::path::Path,
    /// CT targets (`name,x_mm,y_mm,z_mm`).
    pub targets: &'a std::path::Path,
    pub robot: RobotLinkSource<'a>,
    /// Tool-tip offset σ (mm).
    pub tool_sigma_mm: f64,
}

/// Read the chain's files, build the links and evaluate every CT target with `mc` Monte Carlo
/// draws. `notes` receives what the user should be told (where the robot link came from, a
/// registration without a CT / tracker split).
pub fn chain_from_files(
    f: &ChainFiles,
    mc: usize,
    seed: u64,
    notes: &mut Vec<String>,
) -> anyhow::Result<ChainReport> {
    use crate::register::file::cov_from_file;
    use crate::register::robot_world::RobotWorldFile;
    use crate::register::{points, RegistrationFile};
    use anyhow::{bail, Context as _};
    let sigma = match f.robot {
        RobotLinkSource::SigmaMm(s) => s,
        RobotLinkSource::Calibration { .. } => 0.0,
    };
    for (v, n) in [(sigma, "robot σ"), (f.tool_sigma_mm, "tool σ")] {
        if !(v.is_finite() && v >= 0.0) {
            bail!("{n} must be a finite number ≥ 0 (mm), got {v}");
        }
    }
    if mc == 0 || mc > 10_000_000 {
        bail!("the Monte Carlo draws must be in 1..=10000000, got {mc}");
    }
    let reg = RegistrationFile::load(f.registration)?;
    let rw = RobotWorldFile::load(f.robot_world)?;
    let (y, cov_y) = rw.y()?;
    let t = reg.transform()?;
    let cov_total = reg.covariance()?.unwrap_or_else(Matrix6::zeros);
    let (cov_ct, cov_trk) = match (
        &reg.t_tracker_ct.covariance_ct,
        &reg.t_tracker_ct.covariance_tracker,
    ) {
        (Some(c), Some(k)) => (
            cov_from_file(c, "T_tracker_ct.covariance_ct")?,
            cov_from_file(k, "T_tracker_ct.covariance_tracker")?,
        ),
        _ => {
            notes.push("the registration's covariance is not split into CT and tracker parts (no noise model at registration): all of it is reported under `registration: CT localisation`".into());
            (cov_total, Matrix6::zeros())
        }
    };
    let cov_robot = match f.robot {
        RobotLinkSource::Calibration { path, joints_deg } => {
            let cal = crate::dataset::CalibrationFile::load(path)?;
            let q: Vec<f64> = joints_deg.iter().map(|d| d.to_radians()).collect();
            let (c, source) = robot_link_from_calibration(&cal, &q)
                .with_context(|| format!("{}", path.display()))?;
            notes.push(format!(
                "robot link: {source} of {} at joints {:?} deg: tip RMS {:.4} mm",
                path.display(),
                joints_deg,
                c.trace().max(0.0).sqrt()
            ));
            c
        }
        RobotLinkSource::SigmaMm(s) => Matrix3::identity() * s.powi(2),
    };
    let inp = ChainInputs {
        t_tracker_ct: t,
        cov_reg_ct: cov_ct,
        cov_reg_tracker: cov_trk,
        t_base_tracker: y,
        cov_y,
        cov_robot,
        cov_tool: Matrix3::identity() * f.tool_sigma_mm.powi(2),
    };
    let targets: Vec<_> = points::read_points_csv(f.targets)?
        .into_iter()
        .map(|p| (p.name, p.p))
        .collect();
    Ok(chain_report(&inp, &targets, mc, seed)?)
}

/// The report as text: one line per target and one per link.
pub fn report_text(r: &ChainReport) -> String {
    let mut s = String::new();
    for t in &r.targets {
        s += &format!(
            "{}: tip error {:.3} mm RMS (MC {:.3}), 95 % ellipsoid {:.3} x {:.3} x {:.3} mm, MC inside 95 %: {:.1} %\n",
            t.name,
            t.rms_mm,
            t.mc_rms_mm,
            t.ellipsoid95_mm[0],
            t.ellipsoid95_mm[1],
            t.ellipsoid95_mm[2],
            100.0 * t.mc_inside95
        );
        for l in &t.links {
            s += &format!(
                "    {:<36} {:>7.3} mm  {:>5.1} %\n",
                l.link,
                l.rms_mm,
                100.0 * l.share
            );
        }
    }
    s
}
