//! Shaft axis as a Plücker line from the two image boundary lines of a cylinder (seed 002,
//! step 1), and common-perpendicular points of pairs of lines (seed 002, step 2).
//!
//! The seed's equations are images in the source text; what is implemented here is the
//! construction they describe, derived in full: each boundary segment `x₁x₂` (undistorted
//! pixels) is the image line `l = x₁ × x₂`; its back-projected plane through the camera
//! centre has the normal `n = Kᵀ l` (unit). The two planes are tangent to the cylinder, so
//! with `n₁·n₂ > 0` the boundary matrix `Cb = [n₁ n₂]` has the SVD `U Σ Vᵀ` with
//! `Σ = (√2 cos α, √2 sin α)` (α = half angle between the planes), the axis direction is the
//! last column of `U` (`∝ n₁ × n₂`) and the moment is
//! `m = r_C · √(Σ₁² + Σ₂²) / Σ₂ · U₁` (`|m|` = distance of the axis from the camera centre
//! `= r_C / sin α`).
use nalgebra::{Matrix3, Matrix3x2, Point3, Vector3};

use super::RcmError;

/// Pinhole intrinsics (pixels) of the undistorted image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pinhole {
    /// Focal lengths.
    pub fx: f64,
    /// Focal lengths.
    pub fy: f64,
    /// Principal point.
    pub cx: f64,
    /// Principal point.
    pub cy: f64,
}

impl Pinhole {
    /// `K`.
    pub fn k(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }
    /// Normalised ray `K⁻¹ (u, v, 1)`.
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }
    /// Pixel of a camera-frame point.
    pub fn project(&self, p: &Vector3<f64>) -> [f64; 2] {
        [self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy]
    }
}

/// An oriented 3-D line: unit direction `d`, moment `m = p × d`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Line {
    /// Unit direction.
    pub d: Vector3<f64>,
    /// Moment.
    pub m: Vector3<f64>,
}

impl Line {
    /// The line through `p` along `d` (normalised).
    pub fn through(p: &Vector3<f64>, d: &Vector3<f64>) -> Line {
        let d = d.normalize();
        Line { d, m: p.cross(&d) }
    }
    /// The point of the line closest to the origin.
    pub fn foot(&self) -> Vector3<f64> {
        self.d.cross(&self.m)
    }
    /// Distance of a point from the line.
    pub fn distance(&self, p: &Vector3<f64>) -> f64 {
        (p.cross(&self.d) - self.m).norm()
    }
    /// The same line with the opposite direction.
    pub fn flipped(&self) -> Line {
        Line {
            d: -self.d,
            m: -self.m,
        }
    }
    /// The rigidly transformed line (`p ↦ R p + t`).
    pub fn transformed(&self, iso: &nalgebra::Isometry3<f64>) -> Line {
        let d = iso.rotation * self.d;
        let p = iso * Point3::from(self.foot());
        Line::through(&p.coords, &d)
    }
}

/// Homogeneous image line through the two end points of a segment `[u1, v1, u2, v2]`.
pub fn image_line(seg: &[f64; 4]) -> Vector3<f64> {
    Vector3::new(seg[0], seg[1], 1.0).cross(&Vector3::new(seg[2], seg[3], 1.0))
}

/// The shaft axis (camera frame, mm) of a cylinder of radius `r` from its two boundary
/// segments (seed 002 step 1). The direction's sign is arbitrary (fixed later from the RCM);
/// of the two mirror lines the one in front of the camera, near the observed segments, is
/// returned.
pub fn axis_from_boundaries(k: &Pinhole, segs: &[[f64; 4]; 2], r: f64) -> Result<Line, RcmError> {
    for s in segs {
        let len = ((s[2] - s[0]).powi(2) + (s[3] - s[1]).powi(2)).sqrt();
        if len.is_nan() || len < 2.0 {
            return Err(RcmError::BadLines(format!(
                "a boundary segment is {len:.2} px long (need ≥ 2 px between its end points)"
            )));
        }
    }
    let km = k.k();
    let n1 = (km.transpose() * image_line(&segs[0])).normalize();
    let mut n2 = (km.transpose() * image_line(&segs[1])).normalize();
    if n1.dot(&n2) < 0.0 {
        n2 = -n2;
    }
    if n1.dot(&n2) > 1.0 - 1e-12 {
        return Err(RcmError::BadLines(
            "the two boundary lines coincide: the shaft's width in the image is zero".into(),
        ));
    }
    // Boundary matrix and its SVD (seed: Cb with the intrinsics, U Σ Vᵀ).
    let cb = Matrix3x2::from_columns(&[n1, n2]);
    let svd = cb.svd(true, false);
    let u = svd.u.expect("u requested");
    let (mut s1, mut s2) = (svd.singular_values[0], svd.singular_values[1]);
    let mut u1 = u.column(0).into_owned();
    if s2 > s1 {
        std::mem::swap(&mut s1, &mut s2);
        u1 = u.column(1).into_owned();
    }
    let d = n1.cross(&n2).normalize();
    let sin_a = s2 / (s1 * s1 + s2 * s2).sqrt();
    if sin_a < 1e-4 {
        return Err(RcmError::BadLines(format!(
            "the two boundary lines are (nearly) the same line: the axis would be {:.0} radii away",
            1.0 / sin_a.max(1e-300)
        )));
    }
    let m = u1 * (r * (s1 * s1 + s2 * s2).sqrt() / s2);
    let cand = [Line { d, m }, Line { d, m: -m }];
    // The observed shaft: ray through the mean of the end points.
    let mu = (segs[0][0] + segs[0][2] + segs[1][0] + segs[1][2]) / 4.0;
    let mv = (segs[0][1] + segs[0][3] + segs[1][1] + segs[1][3]) / 4.0;
    let ray = k.ray(mu, mv).normalize();
    let score = |l: &Line| -> f64 {
        // Distance between the ray (through the origin) and the line, and depth along the ray.
        let c = ray.cross(&l.d);
        let dist = if c.norm() < 1e-12 {
            l.m.norm()
        } else {
            (l.m.dot(&ray)).abs() / c.norm()
        };
        let front = if l.foot().dot(&ray) > 0.0 { 0.0 } else { 1e9 };
        dist + front
    };
    Ok(if score(&cand[0]) <= score(&cand[1]) {
        cand[0]
    } else {
        cand[1]
    })
}

/// The two feet of the common perpendicular of `a` and `b`: (point on `a`, point on `b`).
/// `None` when the lines are (nearly) parallel.
pub fn common_perpendicular(a: &Line, b: &Line) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let c = a.d.cross(&b.d);
    let c2 = c.norm_squared();
    if c2 < 1e-12 {
        return None;
    }
    // Plücker form of the closest points.
    let pa = (-a.m.cross(&b.d.cross(&c)) + a.d * b.m.dot(&c)) / c2;
    let pb = (b.m.cross(&a.d.cross(&c)) - b.d * a.m.dot(&c)) / c2;
    Some((pa, pb))
}

/// The point closest (least squares) to all lines and the RMS distance of the lines from it.
pub fn nearest_point(lines: &[Line]) -> Option<(Vector3<f64>, f64)> {
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for l in lines {
        let p = Matrix3::identity() - l.d * l.d.transpose();
        a += p;
        b += p * l.foot();
    }
    let sv = a.symmetric_eigenvalues();
    if sv.min() < 1e-9 * sv.max().max(1e-300) {
        return None;
    }
    let x = a.try_inverse()? * b;
    let rms =
        (lines.iter().map(|l| l.distance(&x).powi(2)).sum::<f64>() / lines.len() as f64).sqrt();
    Some((x, rms))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tangent segments of a cylinder computed by sampling the surface (independent of the
    /// tangent-plane algebra above).
    fn boundary(k: &Pinhole, l: &Line, r: f64) -> [[f64; 4]; 2] {
        let e1 = l.d.cross(&Vector3::new(0.3, 0.9, 0.1)).normalize();
        let e2 = l.d.cross(&e1);
        let p0 = l.foot();
        // For each cross-section, the extreme image points are the tangent points: scan θ.
        let mut out = [[0.0; 4]; 2];
        for (si, s) in [-20.0, 30.0].iter().enumerate() {
            let a = p0 + l.d * *s;
            let ac = a; // camera at origin
            let (aa, bb) = (e1.dot(&ac), e2.dot(&ac));
            let rr = (aa * aa + bb * bb).sqrt();
            let phi = bb.atan2(aa);
            let dth = (-r / rr).acos();
            for (k2, th) in [phi + dth, phi - dth].iter().enumerate() {
                let x = a + (e1 * th.cos() + e2 * th.sin()) * r;
                let px = k.project(&x);
                out[k2][2 * si] = px[0];
                out[k2][2 * si + 1] = px[1];
            }
        }
        out
    }

    #[test]
    fn axis_recovered_from_exact_silhouettes() {
        let k = Pinhole {
            fx: 800.0,
            fy: 790.0,
            cx: 320.0,
            cy: 240.0,
        };
        let truth = Line::through(
            &Vector3::new(10.0, -5.0, 90.0),
            &Vector3::new(0.4, 0.3, 0.5),
        );
        let segs = boundary(&k, &truth, 4.0);
        let l = axis_from_boundaries(&k, &segs, 4.0).unwrap();
        let l = if l.d.dot(&truth.d) < 0.0 {
            l.flipped()
        } else {
            l
        };
        assert!((l.d - truth.d).norm() < 1e-9, "{:?} vs {:?}", l.d, truth.d);
        assert!((l.m - truth.m).norm() < 1e-7, "{:?} vs {:?}", l.m, truth.m);
    }

    #[test]
    fn coincident_lines_are_an_error() {
        let k = Pinhole {
            fx: 800.0,
            fy: 800.0,
            cx: 320.0,
            cy: 240.0,
        };
        let s = [10.0, 10.0, 200.0, 100.0];
        let e = axis_from_boundaries(&k, &[s, s], 4.0).unwrap_err();
        assert!(e.to_string().contains("coincide"), "{e}");
        let e = axis_from_boundaries(&k, &[s, [5.0, 5.0, 5.5, 5.0]], 4.0).unwrap_err();
        assert!(e.to_string().contains("long"), "{e}");
    }

    #[test]
    fn common_perpendicular_of_skew_lines() {
        let a = Line::through(&Vector3::new(0.0, 0.0, 0.0), &Vector3::x());
        let b = Line::through(&Vector3::new(0.0, 2.0, 5.0), &Vector3::z());
        let (pa, pb) = common_perpendicular(&a, &b).unwrap();
        assert!((pa - Vector3::new(0.0, 0.0, 0.0)).norm() < 1e-12);
        assert!((pb - Vector3::new(0.0, 2.0, 0.0)).norm() < 1e-12);
        assert!(common_perpendicular(&a, &a).is_none());
    }
}
