//! Paired-point registration CT → tracker: closed-form least squares (Arun / Horn /
//! Umeyama without scale, reflection-safe through the SVD sign fix of
//! [`crate::solve::rigid::register_points`]), fiducial registration error (FRE), the
//! fiducial localisation error (FLE) estimate and the predicted target registration error
//! (TRE) of Fitzpatrick, West & Maurer (1998):
//!
//! `⟨FRE²⟩ = (1 − 2/N) ⟨FLE²⟩`, `⟨TRE²(r)⟩ = ⟨FLE²⟩/N · (1 + ⅓ Σ_k d_k² / f_k²)`,
//!
//! with `d_k` the distance of the target from the k-th principal axis of the fiducial
//! configuration and `f_k` the RMS distance of the fiducials from that axis.
//!
//! With a tracker noise model ([`StereoTrackerModel`], anisotropic, growing with depth) and
//! a CT localisation σ, the closed form is refined by weighted least squares on the one LM
//! solver ([`PairedProblem`]) and the covariance of the transform is split into the CT part
//! and the tracker part (the chain's two registration links). The transform covariance is
//! over a left perturbation `(ω, t)`: `T = (Exp(ω)·R₀, t₀ + t)` (rad, mm, tracker frame).
#![allow(clippy::type_complexity)] // (points, normals, ...) tuples of parallel vectors
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix3x6, Matrix6, Point3, Rotation3, Translation3,
    UnitQuaternion, Vector3,
};

use super::points::NamedPoint;
use super::tracker_model::StereoTrackerModel;
use super::{skew, so3_left_jacobian, RegisterError};
use crate::solve::lm::{self, LmOptions, LsqProblem};

/// Options of a paired registration.
#[derive(Debug, Clone, Default)]
pub struct PairedOptions {
    /// Tracker noise model: weights and the tracker share of the covariance.
    pub tracker_model: Option<StereoTrackerModel>,
    /// CT fiducial localisation, 1σ per axis (mm) (voxel size / √12 is a floor).
    pub ct_sigma_mm: Option<f64>,
}

/// Result of a paired registration.
#[derive(Debug, Clone)]
pub struct PairedRegistration {
    /// `T_tracker_ct`: maps CT points into the tracker frame.
    pub t_tracker_ct: Isometry3<f64>,
    /// Covariance of `(ω, t)` (rad, mm) of the left perturbation.
    pub cov: Matrix6<f64>,
    /// The CT-localisation part of `cov` (when a noise model was given).
    pub cov_ct: Option<Matrix6<f64>>,
    /// The tracker-localisation part of `cov` (when a noise model was given).
    pub cov_tracker: Option<Matrix6<f64>>,
    /// Paired names, CT points, tracker points, residuals `T·ct − tracker` (mm).
    pub names: Vec<String>,
    pub ct: Vec<Point3<f64>>,
    pub tracker: Vec<Point3<f64>>,
    pub residuals: Vec<Vector3<f64>>,
    /// RMS fiducial registration error (mm).
    pub fre_mm: f64,
    /// Estimated RMS (3-D) fiducial localisation error `FRE·√(N/(N−2))` (mm; ∞ for N = 3
    /// would be unbounded, so N = 3 reports FRE·√3).
    pub fle_mm: f64,
    /// Names present on only one side.
    pub unpaired: Vec<String>,
    /// Whether the weighted (noise-model) refinement was used.
    pub weighted: bool,
}

/// The `3 × 6` Jacobian of the mapped point `T·r` w.r.t. the left perturbation `(ω, t)`.
pub fn point_jacobian(t: &Isometry3<f64>, r: &Point3<f64>) -> Matrix3x6<f64> {
    let rr = t.rotation * r.coords;
    let mut j = Matrix3x6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(&rr)));
    j.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    j
}

/// Applies the left perturbation `(ω, t)` to `T`.
pub fn perturb(t: &Isometry3<f64>, d: &[f64]) -> Isometry3<f64> {
    let w = Vector3::new(d[0], d[1], d[2]);
    let dt = Vector3::new(d[3], d[4], d[5]);
    Isometry3::from_parts(
        Translation3::from(t.translation.vector + dt),
        UnitQuaternion::from_scaled_axis(w) * t.rotation,
    )
}

/// Weighted paired-point problem: residual `L_iᵀ (Exp(ω) R₀ a_i + t₀ + t − b_i)` with
/// `L_i L_iᵀ = Σ_i⁻¹` (whitened).
pub struct PairedProblem<'a> {
    pub t0: Isometry3<f64>,
    pub a: &'a [Point3<f64>],
    pub b: &'a [Point3<f64>],
    /// Whitening matrices (`Σ_i^{-1/2}`), one per point.
    pub w: Vec<Matrix3<f64>>,
}

impl LsqProblem for PairedProblem<'_> {
    fn n_params(&self) -> usize {
        6
    }
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        let t = perturb(&self.t0, x.as_slice());
        let mut r = DVector::zeros(3 * self.a.len());
        for (i, (pa, pb)) in self.a.iter().zip(self.b).enumerate() {
            let e = self.w[i] * ((t * pa) - pb);
            r.fixed_rows_mut::<3>(3 * i).copy_from(&e);
        }
        r
    }
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let w = Vector3::new(x[0], x[1], x[2]);
        let jl = so3_left_jacobian(&w);
        let rot = UnitQuaternion::from_scaled_axis(w) * self.t0.rotation;
        let mut jac = DMatrix::zeros(3 * self.a.len(), 6);
        for (i, pa) in self.a.iter().enumerate() {
            let ra = rot * pa.coords;
            let dw = -skew(&ra) * jl;
            let wi = self.w[i];
            jac.fixed_view_mut::<3, 3>(3 * i, 0).copy_from(&(wi * dw));
            jac.fixed_view_mut::<3, 3>(3 * i, 3).copy_from(&wi);
        }
        (self.residuals(x), jac)
    }
}

fn centroid(p: &[Point3<f64>]) -> Vector3<f64> {
    p.iter().fold(Vector3::zeros(), |s, q| s + q.coords) / p.len() as f64
}

fn rms_spread(p: &[Point3<f64>]) -> f64 {
    let c = centroid(p);
    (p.iter().map(|q| (q.coords - c).norm_squared()).sum::<f64>() / p.len() as f64).sqrt()
}

/// Pairs two named point lists by name (order of `ct`); returns names only on one side too.
pub fn pair_by_name(
    ct: &[NamedPoint],
    tracker: &[NamedPoint],
) -> (Vec<String>, Vec<Point3<f64>>, Vec<Point3<f64>>, Vec<String>) {
    let mut names = Vec::new();
    let mut a = Vec::new();
    let mut b = Vec::new();
    let mut unpaired = Vec::new();
    for c in ct {
        match tracker.iter().find(|t| t.name == c.name) {
            Some(t) => {
                names.push(c.name.clone());
                a.push(c.p);
                b.push(t.p);
            }
            None => unpaired.push(format!("{} (CT only)", c.name)),
        }
    }
    for t in tracker {
        if !ct.iter().any(|c| c.name == t.name) {
            unpaired.push(format!("{} (tracker only)", t.name));
        }
    }
    (names, a, b, unpaired)
}

/// Checks a fiducial configuration: ≥ 3 finite points, not collinear.
pub fn check_layout(a: &[Point3<f64>], what: &str) -> Result<(), RegisterError> {
    if a.len() < 3 {
        return Err(RegisterError::Degenerate(format!(
            "{what}: {} paired point(s); a rigid registration needs at least 3 non-collinear fiducials",
            a.len()
        )));
    }
    if let Some(p) = a.iter().find(|p| !p.coords.iter().all(|x| x.is_finite())) {
        return Err(RegisterError::Invalid(format!(
            "{what}: non-finite coordinate {p:?}"
        )));
    }
    let c = centroid(a);
    let mut m = Matrix3::zeros();
    for p in a {
        let d = p.coords - c;
        m += d * d.transpose();
    }
    let mut ev: Vec<f64> = m
        .symmetric_eigenvalues()
        .iter()
        .map(|x| x.max(0.0).sqrt())
        .collect();
    ev.sort_by(|x, y| y.total_cmp(x));
    if ev[0] <= 0.0 {
        return Err(RegisterError::Degenerate(format!(
            "{what}: all fiducials coincide"
        )));
    }
    if ev[1] < 0.01 * ev[0] {
        return Err(RegisterError::Degenerate(format!(
            "{what}: the fiducials are (nearly) collinear (spread across the line {:.3} mm vs {:.1} mm along it): the rotation about that line is undetermined; add a fiducial off the line",
            ev[1] / (a.len() as f64).sqrt(),
            ev[0] / (a.len() as f64).sqrt()
        )));
    }
    Ok(())
}

/// Registers CT fiducials onto tracker fiducials, paired by name.
pub fn register_paired(
    ct: &[NamedPoint],
    tracker: &[NamedPoint],
    opts: &PairedOptions,
) -> Result<PairedRegistration, RegisterError> {
    let (names, a, b, unpaired) = pair_by_name(ct, tracker);
    if a.len() < 3 {
        return Err(RegisterError::Degenerate(format!(
            "{} fiducial name(s) appear in both files (need ≥ 3){}",
            a.len(),
            if unpaired.is_empty() {
                String::new()
            } else {
                format!("; unpaired: {}", unpaired.join(", "))
            }
        )));
    }
    register_points_full(names, a, b, unpaired, opts)
}

/// As [`register_paired`] on already paired points.
pub fn register_points_full(
    names: Vec<String>,
    a: Vec<Point3<f64>>,
    b: Vec<Point3<f64>>,
    unpaired: Vec<String>,
    opts: &PairedOptions,
) -> Result<PairedRegistration, RegisterError> {
    check_layout(&a, "CT fiducials")?;
    check_layout(&b, "tracker fiducials")?;
    // Unit check: a rigid motion keeps the spread; a factor means mixed units.
    let (sa, sb) = (rms_spread(&a), rms_spread(&b));
    let ratio = sb / sa;
    if !(1.0 / 1.15..=1.15).contains(&ratio) {
        let hint = [
            (1000.0, "m vs mm"),
            (25.4, "inch vs mm"),
            (10.0, "cm vs mm"),
        ]
        .iter()
        .find(|(f, _)| (ratio / f - 1.0).abs() < 0.05 || (ratio * f - 1.0).abs() < 0.05)
        .map(|(_, h)| format!(" (looks like {h})"))
        .unwrap_or_default();
        return Err(RegisterError::Invalid(format!(
            "the tracker fiducials spread {sb:.3} vs {sa:.3} in CT (ratio {ratio:.4}): a rigid registration keeps distances, so the files use different units or the names pair different points{hint}"
        )));
    }
    let t0 = crate::solve::rigid::register_points(&a, &b)
        .map_err(|e| RegisterError::Degenerate(e.to_string()))?;
    let n = a.len();
    let residual_of = |t: &Isometry3<f64>| -> Vec<Vector3<f64>> {
        a.iter().zip(&b).map(|(pa, pb)| t * pa - pb).collect()
    };
    let mut t = t0;
    let mut weighted = false;
    let (mut cov, mut cov_ct, mut cov_tracker) = (Matrix6::zeros(), None, None);
    let model_given = opts.tracker_model.is_some() || opts.ct_sigma_mm.is_some();
    if model_given {
        if let Some(m) = &opts.tracker_model {
            m.validate()?;
        }
        let s_ct = opts.ct_sigma_mm.unwrap_or(0.0);
        if !(s_ct.is_finite() && s_ct >= 0.0) {
            return Err(RegisterError::Invalid(format!(
                "CT localisation sigma must be ≥ 0 mm, got {s_ct}"
            )));
        }
        let trk_cov: Vec<Matrix3<f64>> = b
            .iter()
            .map(|p| {
                opts.tracker_model
                    .map(|m| m.covariance(p))
                    .unwrap_or_else(Matrix3::zeros)
            })
            .collect();
        let ct_cov = Matrix3::identity() * (s_ct * s_ct);
        let total: Vec<Matrix3<f64>> = trk_cov.iter().map(|c| c + ct_cov).collect();
        let mut w = Vec::with_capacity(n);
        for (i, c) in total.iter().enumerate() {
            let inv = c.try_inverse().filter(|m| m.iter().all(|x| x.is_finite()));
            let Some(inv) = inv else {
                return Err(RegisterError::Invalid(format!(
                    "fiducial `{}`: zero noise in the model (give a CT sigma or a tracker floor)",
                    names[i]
                )));
            };
            let ch = inv
                .cholesky()
                .ok_or_else(|| RegisterError::Invalid("noise covariance not positive".into()))?;
            w.push(ch.l().transpose());
        }
        let prob = PairedProblem {
            t0,
            a: &a,
            b: &b,
            w,
        };
        let rep = lm::minimize(&prob, DVector::zeros(6), &LmOptions::default());
        if !rep.termination.converged() {
            return Err(RegisterError::Solver(rep.termination.describe().into()));
        }
        t = perturb(&t0, rep.x.as_slice());
        weighted = true;
        // Covariance at the solution (re-linearised around t).
        let mut jtwj = Matrix6::zeros();
        let mut parts = [Matrix6::zeros(), Matrix6::zeros()];
        let js: Vec<Matrix3x6<f64>> = a.iter().map(|p| point_jacobian(&t, p)).collect();
        let winv: Vec<Matrix3<f64>> = total
            .iter()
            .map(|c| c.try_inverse().unwrap_or_else(Matrix3::zeros))
            .collect();
        for i in 0..n {
            jtwj += js[i].transpose() * winv[i] * js[i];
        }
        let a_inv = jtwj
            .try_inverse()
            .ok_or_else(|| RegisterError::Degenerate("registration covariance singular".into()))?;
        for i in 0..n {
            let g = a_inv * js[i].transpose() * winv[i];
            // The CT error enters rotated into the tracker frame: R Σ_ct Rᵀ (isotropic here).
            parts[0] += g * ct_cov * g.transpose();
            parts[1] += g * trk_cov[i] * g.transpose();
        }
        cov = a_inv;
        cov_ct = Some(parts[0]);
        cov_tracker = Some(parts[1]);
    }
    let residuals = residual_of(&t);
    let fre2 = residuals.iter().map(|r| r.norm_squared()).sum::<f64>() / n as f64;
    let fre = fre2.sqrt();
    let fle = if n > 3 {
        fre * (n as f64 / (n as f64 - 2.0)).sqrt()
    } else {
        fre * 3f64.sqrt()
    };
    if fre > 0.1 * sa {
        return Err(RegisterError::Invalid(format!(
            "FRE {fre:.3} mm is {:.0} % of the fiducial spread ({sa:.1} mm): the names most likely pair different points (swapped labels?)",
            100.0 * fre / sa
        )));
    }
    if !model_given {
        let s2 = fle * fle / 3.0;
        let mut jtj = Matrix6::zeros();
        for p in &a {
            let j = point_jacobian(&t, p);
            jtj += j.transpose() * j;
        }
        cov = jtj
            .try_inverse()
            .ok_or_else(|| RegisterError::Degenerate("registration covariance singular".into()))?
            * s2;
    }
    Ok(PairedRegistration {
        t_tracker_ct: t,
        cov,
        cov_ct,
        cov_tracker,
        names,
        ct: a,
        tracker: b,
        residuals,
        fre_mm: fre,
        fle_mm: fle,
        unpaired,
        weighted,
    })
}

impl PairedRegistration {
    /// Fitzpatrick–West predicted RMS TRE (mm) at a CT target, from the FLE estimate.
    pub fn tre_fw(&self, r: &Point3<f64>) -> f64 {
        tre_fitzpatrick(&self.ct, self.fle_mm, r)
    }
    /// Covariance (mm², tracker frame) of the mapped target from the transform covariance.
    pub fn target_cov(&self, r: &Point3<f64>) -> Matrix3<f64> {
        let j = point_jacobian(&self.t_tracker_ct, r);
        j * self.cov * j.transpose()
    }
}

/// Fitzpatrick, West & Maurer (1998) predicted RMS TRE at `r` for fiducials `f` (CT frame)
/// with RMS (3-D) FLE `fle`.
pub fn tre_fitzpatrick(f: &[Point3<f64>], fle: f64, r: &Point3<f64>) -> f64 {
    let n = f.len() as f64;
    let c = centroid(f);
    let mut m = Matrix3::zeros();
    for p in f {
        let d = p.coords - c;
        m += d * d.transpose();
    }
    let eig = m.symmetric_eigen();
    let rc = r.coords - c;
    let mut s = 0.0;
    for k in 0..3 {
        let u = eig.eigenvectors.column(k).into_owned();
        // f_k²: mean squared distance of fiducials from axis k; d_k²: target's.
        let fk2 = f
            .iter()
            .map(|p| {
                let d = p.coords - c;
                (d - u * u.dot(&d)).norm_squared()
            })
            .sum::<f64>()
            / n;
        let dk2 = (rc - u * u.dot(&rc)).norm_squared();
        s += dk2 / fk2;
    }
    (fle * fle / n * (1.0 + s / 3.0)).sqrt()
}

/// Rotation + translation as a row-major 4×4 (mm).
pub fn iso_to_rows(t: &Isometry3<f64>) -> [f64; 16] {
    let m = t.to_homogeneous();
    let mut o = [0.0; 16];
    for r in 0..4 {
        for c in 0..4 {
            o[4 * r + c] = m[(r, c)];
        }
    }
    o
}

/// Row-major 4×4 (mm) → rigid transform; refuses non-rigid matrices.
pub fn rows_to_iso(m: &[f64], what: &str) -> Result<Isometry3<f64>, RegisterError> {
    if m.len() != 16 || !m.iter().all(|x| x.is_finite()) {
        return Err(RegisterError::Invalid(format!(
            "{what}: expected 16 finite numbers (4×4 row-major), got {}",
            m.len()
        )));
    }
    let r = Matrix3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
    let orth = (r.transpose() * r - Matrix3::identity()).norm();
    if orth > 1e-6 || r.determinant() < 0.0 {
        return Err(RegisterError::Invalid(format!(
            "{what}: the 3×3 block is not a rotation (‖RᵀR − I‖ = {orth:.2e}, det = {:.4})",
            r.determinant()
        )));
    }
    if (m[12].abs() + m[13].abs() + m[14].abs()) > 1e-9 || (m[15] - 1.0).abs() > 1e-9 {
        return Err(RegisterError::Invalid(format!(
            "{what}: the last row must be 0 0 0 1"
        )));
    }
    let rot = crate::solve::rigid::project_rotation(&r);
    Ok(Isometry3::from_parts(
        Translation3::new(m[3], m[7], m[11]),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rot.into_inner())),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    fn np(name: &str, p: Point3<f64>) -> NamedPoint {
        NamedPoint {
            name: name.into(),
            p,
            line: 0,
        }
    }

    fn fiducials() -> Vec<Point3<f64>> {
        vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(120.0, 10.0, 5.0),
            Point3::new(20.0, 140.0, -10.0),
            Point3::new(-60.0, 40.0, 90.0),
            Point3::new(70.0, -50.0, 60.0),
            Point3::new(-30.0, -80.0, -40.0),
        ]
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let f = fiducials();
        let t0 = Isometry3::new(
            Vector3::new(10.0, -400.0, -1500.0),
            Vector3::new(0.3, -1.0, 0.5),
        );
        let g: Vec<_> = f.iter().map(|p| t0 * p).collect();
        let m = StereoTrackerModel::polaris_like();
        let w = g
            .iter()
            .map(|p| {
                (m.covariance(p) + Matrix3::identity() * 0.01)
                    .try_inverse()
                    .unwrap()
                    .cholesky()
                    .unwrap()
                    .l()
                    .transpose()
            })
            .collect();
        let prob = PairedProblem {
            t0,
            a: &f,
            b: &g,
            w,
        };
        let x = DVector::from_vec(vec![0.02, -0.05, 0.1, 1.0, 2.0, -3.0]);
        let (_, ja) = prob.residuals_jacobian(&x);
        let jn = lm::numeric_jacobian(|x| prob.residuals(x), &x, 1e-6);
        let rel = (&ja - &jn).norm() / ja.norm();
        assert!(rel < 1e-7, "{rel}");
    }

    #[test]
    fn exact_recovery_reflection_safe_and_fw_equals_linearised_covariance() {
        let f = fiducials();
        let t = Isometry3::new(
            Vector3::new(100.0, -50.0, -1500.0),
            Vector3::new(2.0, 0.5, -0.7),
        );
        let ct: Vec<_> = f
            .iter()
            .enumerate()
            .map(|(i, p)| np(&format!("F{i}"), *p))
            .collect();
        // Tracker side in reversed order: pairing must be by name.
        let trk: Vec<_> = f
            .iter()
            .enumerate()
            .rev()
            .map(|(i, p)| {
                let e = Vector3::new(
                    (i as f64 * 0.37).sin(),
                    (i as f64).cos(),
                    0.3 - 0.1 * i as f64,
                ) * 0.2;
                np(&format!("F{i}"), t * p + e)
            })
            .collect();
        let r = register_paired(&ct, &trk, &PairedOptions::default()).unwrap();
        assert!(r.t_tracker_ct.rotation.angle_to(&t.rotation) < 0.01);
        assert!(r.fre_mm > 0.0 && r.fle_mm > r.fre_mm);
        for target in [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(300.0, -200.0, 100.0),
        ] {
            let fw = r.tre_fw(&target);
            let lin = r.target_cov(&target).trace().sqrt();
            assert!(
                (fw / lin - 1.0).abs() < 1e-9,
                "F&W {fw} vs linearised {lin}"
            );
        }
        // Noise-free: exact.
        let exact: Vec<_> = f
            .iter()
            .enumerate()
            .map(|(i, p)| np(&format!("F{i}"), t * p))
            .collect();
        let r = register_paired(&ct, &exact, &PairedOptions::default()).unwrap();
        assert!((r.t_tracker_ct.translation.vector - t.translation.vector).norm() < 1e-9);
        assert!(r.fre_mm < 1e-9);
    }

    #[test]
    fn fw_tre_matches_monte_carlo() {
        let f = fiducials();
        let t = Isometry3::new(Vector3::new(0.0, 0.0, -1500.0), Vector3::new(0.1, 0.2, 0.3));
        let target = Point3::new(150.0, 100.0, -120.0);
        let fle = 0.5; // RMS 3-D
        let s = fle / 3f64.sqrt();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mut acc, trials) = (0.0, 4000);
        for _ in 0..trials {
            let b: Vec<_> = f
                .iter()
                .map(|p| {
                    t * p
                        + Vector3::new(
                            rng.sample::<f64, _>(StandardNormal),
                            rng.sample::<f64, _>(StandardNormal),
                            rng.sample::<f64, _>(StandardNormal),
                        ) * s
                })
                .collect();
            let e = crate::solve::rigid::register_points(&f, &b).unwrap();
            acc += (e * target - t * target).norm_squared();
        }
        let mc = (acc / trials as f64).sqrt();
        let fw = tre_fitzpatrick(&f, fle, &target);
        assert!((mc / fw - 1.0).abs() < 0.05, "MC {mc} vs F&W {fw}");
        let _ = rng.random::<f64>();
    }

    #[test]
    fn refuses_degenerate_inputs() {
        let line: Vec<_> = (0..5)
            .map(|i| np(&format!("F{i}"), Point3::new(i as f64 * 30.0, 0.0, 0.0)))
            .collect();
        let e = register_paired(&line, &line, &PairedOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("collinear"), "{e}");
        let f = fiducials();
        let ct: Vec<_> = f
            .iter()
            .enumerate()
            .map(|(i, p)| np(&format!("F{i}"), *p))
            .collect();
        let e = register_paired(&ct[..2], &ct[..2], &PairedOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("need ≥ 3"), "{e}");
        let metres: Vec<_> = ct
            .iter()
            .map(|p| np(&p.name, Point3::from(p.p.coords / 1000.0)))
            .collect();
        let e = register_paired(&ct, &metres, &PairedOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("m vs mm"), "{e}");
        let mut swapped = ct.clone();
        swapped[0].name = "F1".into();
        swapped[1].name = "F0".into();
        let e = register_paired(&ct, &swapped, &PairedOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("swapped") || e.contains("different points"),
            "{e}"
        );
    }

    #[test]
    fn weighted_split_sums_to_total() {
        let f = fiducials();
        let t = Isometry3::new(
            Vector3::new(0.0, 100.0, -1800.0),
            Vector3::new(0.1, 0.2, 0.3),
        );
        let ct: Vec<_> = f
            .iter()
            .enumerate()
            .map(|(i, p)| np(&format!("F{i}"), *p))
            .collect();
        let trk: Vec<_> = f
            .iter()
            .enumerate()
            .map(|(i, p)| np(&format!("F{i}"), t * p))
            .collect();
        let o = PairedOptions {
            tracker_model: Some(StereoTrackerModel::polaris_like()),
            ct_sigma_mm: Some(0.2),
        };
        let r = register_paired(&ct, &trk, &o).unwrap();
        let sum = r.cov_ct.unwrap() + r.cov_tracker.unwrap();
        assert!((sum - r.cov).norm() / r.cov.norm() < 1e-9);
        assert!(r.weighted);
    }
}
