//! Tool calibrations (seed 001 §2.3–2.4): pivot calibration of a probe tip (algebraic least
//! squares and sphere fit), guide-tool frame matching from forward/reverse mounted pin tips,
//! and tool identification with the identified arm (`M_i = B·F_i·T`, an `AX = XB` problem
//! on relative motions, then least squares). Lengths mm, angles rad.
use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Matrix6, Point3, Unit, Vector3, Vector6};

use super::lm::{self, LmOptions, LsqProblem};
use super::obs::PoseObs;
use super::{kinematics, rigid, stats, SolveError};
use crate::model::{KinematicModel, ParamGroup};

/// Result of a pivot calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct PivotResult {
    /// Probe tip in the marker frame (mm).
    pub tip_in_marker: Vector3<f64>,
    /// The fixed pivot point in the tracker frame (mm).
    pub pivot_point: Point3<f64>,
    /// RMS / max over frames of `|R_i·tip + p_i − pivot|` (mm).
    pub rms_mm: f64,
    pub max_mm: f64,
    /// Frames used.
    pub n: usize,
    /// `algebraic` or `sphere`.
    pub method: &'static str,
}

fn pivot_residuals(frames: &[Isometry3<f64>], tip: &Vector3<f64>, piv: &Point3<f64>) -> Vec<f64> {
    frames
        .iter()
        .map(|f| (f * Point3::from(*tip) - piv).norm())
        .collect()
}

fn finish(
    frames: &[Isometry3<f64>],
    tip: Vector3<f64>,
    piv: Point3<f64>,
    method: &'static str,
) -> PivotResult {
    let r = pivot_residuals(frames, &tip, &piv);
    PivotResult {
        tip_in_marker: tip,
        pivot_point: piv,
        rms_mm: stats::rms(&r),
        max_mm: r.iter().cloned().fold(0.0, f64::max),
        n: frames.len(),
        method,
    }
}

/// Algebraic one-step pivot calibration: least squares of `[R_i  −I]·[tip; pivot] = −p_i`.
/// Fails when the rotations do not span enough directions (rank < 6).
pub fn pivot_algebraic(frames: &[Isometry3<f64>]) -> Result<PivotResult, SolveError> {
    if frames.len() < 3 {
        return Err(SolveError::TooFewData {
            what: "pivot calibration".into(),
            need: 3,
            got: frames.len(),
        });
    }
    let mut ata = Matrix6::zeros();
    let mut atb = Vector6::zeros();
    for f in frames {
        let r = f.rotation.to_rotation_matrix().into_inner();
        let mut a = nalgebra::Matrix3x6::zeros();
        a.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        a.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(-Matrix3::identity()));
        ata += a.transpose() * a;
        atb += a.transpose() * (-f.translation.vector);
    }
    let sv = ata.singular_values();
    let (smax, smin) = (sv.max(), sv.min());
    if smin <= 1e-9 * smax {
        return Err(SolveError::Degenerate(
            "pivot: the marker rotations do not vary enough (rank < 6)".into(),
        ));
    }
    let x = ata
        .cholesky()
        .map(|c| c.solve(&atb))
        .ok_or_else(|| SolveError::Degenerate("pivot: singular normal equations".into()))?;
    Ok(finish(
        frames,
        Vector3::new(x[0], x[1], x[2]),
        Point3::new(x[3], x[4], x[5]),
        "algebraic",
    ))
}

/// Geometric sphere fit to points: centre and radius minimising `Σ(|p_i − c| − r)²`
/// (algebraic start `|p|² = 2c·p + k`, then Levenberg–Marquardt).
pub fn fit_sphere(points: &[Point3<f64>]) -> Result<(Point3<f64>, f64, f64), SolveError> {
    if points.len() < 4 {
        return Err(SolveError::TooFewData {
            what: "sphere fit".into(),
            need: 4,
            got: points.len(),
        });
    }
    let mut ata = nalgebra::Matrix4::zeros();
    let mut atb = nalgebra::Vector4::zeros();
    let c0 = points.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / points.len() as f64;
    for p in points {
        let v = p.coords - c0;
        let a = nalgebra::Vector4::new(2.0 * v.x, 2.0 * v.y, 2.0 * v.z, 1.0);
        ata += a * a.transpose();
        atb += a * v.norm_squared();
    }
    let sv = ata.singular_values();
    if sv.min() <= 1e-12 * sv.max() {
        return Err(SolveError::Degenerate(
            "sphere fit: points are coplanar or collinear".into(),
        ));
    }
    let s = ata
        .cholesky()
        .map(|c| c.solve(&atb))
        .ok_or_else(|| SolveError::Degenerate("sphere fit: singular".into()))?;
    let c = Vector3::new(s[0], s[1], s[2]);
    let r = (s[3] + c.norm_squared()).max(0.0).sqrt();
    let prob = SphereProblem {
        pts: points.iter().map(|p| p.coords - c0).collect(),
    };
    let rep = lm::minimize(
        &prob,
        DVector::from_vec(vec![c.x, c.y, c.z, r]),
        &LmOptions::default(),
    );
    let x = rep.x;
    let centre = Point3::new(x[0], x[1], x[2]) + c0;
    let res = prob.residuals(&x);
    Ok((centre, x[3].abs(), stats::rms(res.as_slice())))
}

/// Sphere fit as a least-squares problem (residual `|p_i − c| − r`).
pub struct SphereProblem {
    pub pts: Vec<Vector3<f64>>,
}

impl LsqProblem for SphereProblem {
    fn n_params(&self) -> usize {
        4
    }
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        let c = Vector3::new(x[0], x[1], x[2]);
        DVector::from_iterator(
            self.pts.len(),
            self.pts.iter().map(|p| (p - c).norm() - x[3]),
        )
    }
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let c = Vector3::new(x[0], x[1], x[2]);
        let mut j = DMatrix::zeros(self.pts.len(), 4);
        for (i, p) in self.pts.iter().enumerate() {
            let d = p - c;
            let n = d.norm().max(1e-300);
            for a in 0..3 {
                j[(i, a)] = -d[a] / n;
            }
            j[(i, 3)] = -1.0;
        }
        (self.residuals(x), j)
    }
}

/// Pivot calibration by a sphere fit to the marker origins (centre = pivot point), the tip
/// in the marker frame being the mean of `R_iᵀ(pivot − p_i)`.
pub fn pivot_sphere(frames: &[Isometry3<f64>]) -> Result<PivotResult, SolveError> {
    let pts: Vec<Point3<f64>> = frames
        .iter()
        .map(|f| Point3::from(f.translation.vector))
        .collect();
    let (c, _r, _rms) = fit_sphere(&pts)?;
    let tip = frames.iter().fold(Vector3::zeros(), |s, f| {
        s + f.inverse_transform_point(&c).coords
    }) / frames.len() as f64;
    Ok(finish(frames, tip, c, "sphere"))
}

/// Marker poses (tracker frame) of the `pivot` records of a dataset (visible, finite).
pub fn pivot_frames(ds: &crate::dataset::Dataset, tool: Option<&str>) -> Vec<Isometry3<f64>> {
    ds.records
        .iter()
        .filter_map(|r| match r {
            crate::dataset::Record::Pivot(p) => Some(p),
            _ => None,
        })
        .filter(|p| tool.is_none() || p.tool.as_deref() == tool)
        .filter(|p| p.marker.visible)
        .filter_map(|p| crate::plausible::quat::pose(&p.marker.p?, &p.marker.quat?).ok())
        .collect()
}

/// Guide (positioning/orienting) tool frame from the pin tips measured with the pin mounted
/// forward (`q1`) and reversed (`q2`) in the guide hole (both in the marker frame), and the
/// micrometer length `l1` of the hole (end face to end face), seed 001 §2.4 eq. (11)–(12).
#[derive(Debug, Clone, PartialEq)]
pub struct GuideFrame {
    /// Tool x axis: direction from Q1 to Q2 (the hole axis).
    pub axis: Unit<Vector3<f64>>,
    /// `L2 = |Q1Q2|`.
    pub l2: f64,
    /// How far each pin tip stands out of its end face: `(L2 − L1)/2`.
    pub protrusion: f64,
    /// Tool origin on the axis at the end face on Q1's side: `Q1 + (L2 − L1)/2 · x`.
    pub origin: Point3<f64>,
    /// Centre of the hole: `(Q1 + Q2)/2`.
    pub centre: Point3<f64>,
}

/// See [`GuideFrame`]. Fails when the tips coincide or `L2 ≤ L1` (the tips must stand out).
pub fn guide_tool_frame(
    q1: &Point3<f64>,
    q2: &Point3<f64>,
    l1: f64,
) -> Result<GuideFrame, SolveError> {
    let d = q2 - q1;
    let l2 = d.norm();
    if l2 < 1e-6 {
        return Err(SolveError::Degenerate(
            "guide tool: Q1 and Q2 coincide".into(),
        ));
    }
    if !(l1.is_finite() && l1 > 0.0) {
        return Err(SolveError::Invalid(format!(
            "guide tool: bad hole length L1 = {l1}"
        )));
    }
    if l2 <= l1 {
        return Err(SolveError::Degenerate(format!(
            "guide tool: tip distance L2 = {l2:.3} mm ≤ hole length L1 = {l1:.3} mm"
        )));
    }
    let axis = Unit::new_normalize(d);
    let e = 0.5 * (l2 - l1);
    Ok(GuideFrame {
        axis,
        l2,
        protrusion: e,
        origin: q1 + axis.into_inner() * e,
        centre: Point3::from((q1.coords + q2.coords) * 0.5),
    })
}

/// Result of [`tool_with_arm`].
#[derive(Debug, Clone)]
pub struct ToolFit {
    /// Tool (marker) pose in the flange frame.
    pub tool: Isometry3<f64>,
    /// Robot base in the tracker frame.
    pub base: Isometry3<f64>,
    pub rms_mm: f64,
    pub rms_rot_deg: f64,
}

/// Tool identification with an identified arm (seed 001 §2.3): marker poses
/// `M_i = B·F_i·T` with `F_i` the flange from the identified model. Closed form: relative
/// motions give `(F_i⁻¹F_j)·T = T·(M_i⁻¹M_j)` (`AX = XB`, Park–Martin), then `B` as the
/// mean of `M_i·T⁻¹·F_i⁻¹`; then least squares over `B` (6) and `T` (6) with the arm fixed.
pub fn tool_with_arm(arm: &KinematicModel, obs: &[PoseObs]) -> Result<ToolFit, SolveError> {
    let with_q: Vec<&PoseObs> = obs.iter().filter(|o| o.quat.is_some()).collect();
    if with_q.len() < 3 {
        return Err(SolveError::TooFewData {
            what: "tool identification (marker orientation needed)".into(),
            need: 3,
            got: with_q.len(),
        });
    }
    let f: Vec<Isometry3<f64>> = with_q.iter().map(|o| arm.flange_pose(&o.q)).collect();
    let m: Vec<Isometry3<f64>> = with_q
        .iter()
        .map(|o| {
            Isometry3::from_parts(
                nalgebra::Translation3::from(o.p.coords),
                o.quat.unwrap_or_default(),
            )
        })
        .collect();
    let mut a = Vec::new();
    let mut b = Vec::new();
    for i in 0..f.len() {
        let j = (i + 1) % f.len();
        a.push(f[i].inverse() * f[j]);
        b.push(m[i].inverse() * m[j]);
    }
    let t = rigid::solve_ax_xb(&a, &b)?;
    let bases: Vec<Isometry3<f64>> = f
        .iter()
        .zip(&m)
        .map(|(fi, mi)| mi * t.inverse() * fi.inverse())
        .collect();
    let base = rigid::mean_isometry(&bases);
    let mut model = arm.clone();
    model.set_base(&base);
    model.set_tool(&t);
    let names: Vec<(String, ParamGroup)> = model
        .params()
        .iter()
        .map(|p| (p.name.clone(), p.group))
        .collect();
    for (n, g) in &names {
        model.set_free(n, matches!(g, ParamGroup::Base | ParamGroup::Tool))?;
    }
    let owned: Vec<PoseObs> = with_q.into_iter().cloned().collect();
    let effects = [];
    let mut prob = kinematics::KinProblem::new(model, &owned, &effects);
    prob.orientation = Some(100.0);
    let rep = lm::minimize(&prob, prob.x0(), &LmOptions::default());
    let fitted = prob.model_at(&rep.x);
    let pos: Vec<f64> = owned
        .iter()
        .map(|o| (fitted.measured_point(&o.q) - o.p).norm())
        .collect();
    let rot: Vec<f64> = owned
        .iter()
        .map(|o| {
            fitted
                .measured_pose(&o.q)
                .rotation
                .angle_to(&o.quat.unwrap_or_default())
                .to_degrees()
        })
        .collect();
    Ok(ToolFit {
        tool: fitted.tool(),
        base: fitted.base(),
        rms_mm: stats::rms(&pos),
        rms_rot_deg: stats::rms(&rot),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn pivot_data(noise: f64, seed: u64) -> (Vec<Isometry3<f64>>, Vector3<f64>, Point3<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let tip = Vector3::new(3.0, -12.0, -160.0);
        let piv = Point3::new(120.0, -40.0, -1500.0);
        let nz = Normal::new(0.0, noise.max(1e-300)).unwrap();
        let frames = (0..80)
            .map(|_| {
                let axis = Vector3::new(
                    rng.random_range(-0.6..0.6),
                    rng.random_range(-0.6..0.6),
                    rng.random_range(-0.3..0.3),
                );
                let r = nalgebra::UnitQuaternion::from_scaled_axis(axis);
                let mut p = piv.coords - r * tip;
                if noise > 0.0 {
                    p += Vector3::new(
                        nz.sample(&mut rng),
                        nz.sample(&mut rng),
                        nz.sample(&mut rng),
                    );
                }
                Isometry3::from_parts(nalgebra::Translation3::from(p), r)
            })
            .collect();
        (frames, tip, piv)
    }

    #[test]
    fn pivot_methods_recover_tip_exactly_and_with_noise() {
        let (frames, tip, piv) = pivot_data(0.0, 1);
        for r in [
            pivot_algebraic(&frames).unwrap(),
            pivot_sphere(&frames).unwrap(),
        ] {
            assert!((r.tip_in_marker - tip).norm() < 1e-6, "{r:?}");
            assert!((r.pivot_point - piv).norm() < 1e-6, "{r:?}");
            assert!(r.rms_mm < 1e-6);
        }
        let (frames, tip, piv) = pivot_data(0.05, 2);
        for r in [
            pivot_algebraic(&frames).unwrap(),
            pivot_sphere(&frames).unwrap(),
        ] {
            assert!((r.tip_in_marker - tip).norm() < 0.3, "{r:?}");
            assert!((r.pivot_point - piv).norm() < 0.3, "{r:?}");
            assert!(r.rms_mm > 0.03 && r.rms_mm < 0.15, "{r:?}");
        }
    }

    #[test]
    fn pivot_without_rotation_is_degenerate() {
        let f = Isometry3::translation(1.0, 2.0, 3.0);
        let frames = vec![f; 10];
        assert!(matches!(
            pivot_algebraic(&frames),
            Err(SolveError::Degenerate(_))
        ));
        assert!(pivot_sphere(&frames).is_err());
        assert!(matches!(
            pivot_algebraic(&frames[..2]),
            Err(SolveError::TooFewData { .. })
        ));
    }

    #[test]
    fn sphere_problem_jacobian_matches_finite_differences() {
        let p = SphereProblem {
            pts: vec![
                Vector3::new(10.0, 0.0, 1.0),
                Vector3::new(-3.0, 8.0, 2.0),
                Vector3::new(1.0, -7.0, 5.0),
            ],
        };
        let x = DVector::from_vec(vec![0.5, 0.2, -0.3, 9.0]);
        let (_, ja) = p.residuals_jacobian(&x);
        let jn = lm::numeric_jacobian(|x| p.residuals(x), &x, 1e-6);
        assert!((ja - jn).amax() < 1e-7);
    }

    #[test]
    fn guide_tool_frame_geometry() {
        // Hole axis along marker (1,1,0)/√2, hole 40 mm long, tips stand out 5 mm each side.
        let x = Vector3::new(1.0, 1.0, 0.0).normalize();
        let face1 = Point3::new(10.0, 20.0, 30.0);
        let q1 = face1 - x * 5.0;
        let q2 = face1 + x * 45.0;
        let g = guide_tool_frame(&q1, &q2, 40.0).unwrap();
        assert!((g.axis.into_inner() - x).norm() < 1e-12);
        assert!((g.l2 - 50.0).abs() < 1e-12);
        assert!((g.protrusion - 5.0).abs() < 1e-12);
        assert!((g.origin - face1).norm() < 1e-12);
        assert!((g.centre - (face1 + x * 20.0)).norm() < 1e-12);
        assert!(guide_tool_frame(&q1, &q2, 60.0).is_err());
        assert!(guide_tool_frame(&q1, &q1, 10.0).is_err());
        assert!(guide_tool_frame(&q1, &q2, f64::NAN).is_err());
    }
}
