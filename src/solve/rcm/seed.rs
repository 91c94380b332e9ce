//! Seed 002 steps 2–4: the RCM-constrained joint refinement of the camera-frame shaft axes
//! (the loss over common-perpendicular points of every pair of axes) and the hand-eye
//! transform from the RCM point and the instrument directions.
//!
//! The loss (`LS_AS` in the seed; its image equation reconstructed from the text): for every
//! pose `i` the refined line `L̂ᵢ = (d̂ᵢ, m̂ᵢ)` stays near the measured `Lᵢ`, and passes through
//! the common-perpendicular foot `p̂ⱼᵢ` that every other refined axis `j` has towards it:
//! `Σᵢ ‖L̂ᵢ − Lᵢ‖² + w Σᵢ Σⱼ≠ᵢ ‖m̂ᵢ − [p̂ⱼᵢ]ₓ d̂ᵢ‖²`, minimised until the cost stops changing.
//! Directions are weighted by the line's distance from the camera so both terms are in mm.
use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

use super::dual::{self, cross, dot, scale, sub, unit, Dual, Real, V3};
use super::plucker::{common_perpendicular, nearest_point, Line};
use super::RcmError;
use crate::solve::lm::{self, LsqProblem};

/// Weight of the pair (RCM) terms against the measurement terms.
pub const PAIR_WEIGHT: f64 = 1.0;

/// The joint refinement of `k` lines (6 parameters each: a direction vector and a point).
pub struct SeedRefine {
    /// Measured lines.
    pub measured: Vec<Line>,
    /// Distance of each measured line from the camera (direction weights, mm).
    pub rho: Vec<f64>,
}

fn line_of<T: Real>(x: &[T]) -> (V3<T>, V3<T>) {
    let d = unit([x[0], x[1], x[2]]);
    let p = [x[3], x[4], x[5]];
    (d, cross(p, d))
}

/// Closest point on line `b` to line `a`, both `(d, m)`.
fn foot_on_b<T: Real>(a: (V3<T>, V3<T>), b: (V3<T>, V3<T>)) -> V3<T> {
    let c = cross(a.0, b.0);
    let c2 = dot(c, c);
    let t = dual::add(cross(b.1, cross(a.0, c)), scale(-dot(a.1, c), b.0));
    scale(T::c(1.0) / c2, t)
}

impl SeedRefine {
    fn line_res<T: Real>(&self, i: usize, x: &[T]) -> [T; 8] {
        let (d, m) = line_of(x);
        let l = &self.measured[i];
        let w = T::c(self.rho[i]);
        let dd = sub(d, dual::cv(l.d.into()));
        let dm = sub(m, dual::cv(l.m.into()));
        let v = [x[0], x[1], x[2]];
        let p = [x[3], x[4], x[5]];
        [
            w * dd[0],
            w * dd[1],
            w * dd[2],
            dm[0],
            dm[1],
            dm[2],
            w * (dot(v, v) - T::c(1.0)),
            dot(p, d),
        ]
    }
    fn pair_res<T: Real>(&self, xi: &[T], xj: &[T]) -> [T; 3] {
        let li = line_of(xi);
        let lj = line_of(xj);
        let p = foot_on_b(li, lj);
        let r = sub(li.1, cross(p, li.0));
        let w = T::c(PAIR_WEIGHT);
        [w * r[0], w * r[1], w * r[2]]
    }
    fn pairs(&self) -> Vec<(usize, usize)> {
        let k = self.measured.len();
        let mut v = Vec::new();
        for i in 0..k {
            for j in 0..k {
                if i != j && self.measured[i].d.cross(&self.measured[j].d).norm() > 1e-6 {
                    v.push((i, j));
                }
            }
        }
        v
    }
    /// Start point: the measured lines.
    pub fn x0(&self) -> DVector<f64> {
        let mut x = DVector::zeros(6 * self.measured.len());
        for (i, l) in self.measured.iter().enumerate() {
            let f = l.foot();
            x.rows_mut(6 * i, 6)
                .copy_from_slice(&[l.d.x, l.d.y, l.d.z, f.x, f.y, f.z]);
        }
        x
    }
    /// The refined lines of a parameter vector.
    pub fn lines(&self, x: &DVector<f64>) -> Vec<Line> {
        (0..self.measured.len())
            .map(|i| {
                let (d, m) = line_of(&x.as_slice()[6 * i..6 * i + 6]);
                Line {
                    d: Vector3::from(d),
                    m: Vector3::from(m),
                }
            })
            .collect()
    }
}

impl LsqProblem for SeedRefine {
    fn n_params(&self) -> usize {
        6 * self.measured.len()
    }
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        let xs = x.as_slice();
        let mut r = Vec::new();
        for i in 0..self.measured.len() {
            r.extend_from_slice(&self.line_res(i, &xs[6 * i..6 * i + 6]));
        }
        for (i, j) in self.pairs() {
            r.extend_from_slice(&self.pair_res(&xs[6 * i..6 * i + 6], &xs[6 * j..6 * j + 6]));
        }
        DVector::from_vec(r)
    }
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let k = self.measured.len();
        let pairs = self.pairs();
        let nr = 8 * k + 3 * pairs.len();
        let mut jac = DMatrix::zeros(nr, 6 * k);
        let mut r = DVector::zeros(nr);
        let xs = x.as_slice();
        for i in 0..k {
            let xd: Vec<Dual<6>> = (0..6).map(|a| Dual::var(xs[6 * i + a], a)).collect();
            for (row, v) in self.line_res(i, &xd).iter().enumerate() {
                r[8 * i + row] = v.a;
                for a in 0..6 {
                    jac[(8 * i + row, 6 * i + a)] = v.b[a];
                }
            }
        }
        for (n, (i, j)) in pairs.iter().enumerate() {
            let xi: Vec<Dual<12>> = (0..6).map(|a| Dual::var(xs[6 * i + a], a)).collect();
            let xj: Vec<Dual<12>> = (0..6).map(|a| Dual::var(xs[6 * j + a], 6 + a)).collect();
            for (row, v) in self.pair_res(&xi, &xj).iter().enumerate() {
                let rr = 8 * k + 3 * n + row;
                r[rr] = v.a;
                for a in 0..6 {
                    jac[(rr, 6 * i + a)] = v.b[a];
                    jac[(rr, 6 * j + a)] = v.b[6 + a];
                }
            }
        }
        (r, jac)
    }
}

/// The RCM point as the mean midpoint of the common perpendiculars of every pair of lines
/// (seed step 3), with the RMS half-length of those perpendiculars.
pub fn rcm_from_pairs(lines: &[Line]) -> Option<(Vector3<f64>, f64)> {
    let mut sum = Vector3::zeros();
    let mut ss = 0.0;
    let mut n = 0usize;
    for i in 0..lines.len() {
        for j in i + 1..lines.len() {
            if let Some((a, b)) = common_perpendicular(&lines[i], &lines[j]) {
                sum += (a + b) * 0.5;
                ss += ((a - b).norm() * 0.5).powi(2);
                n += 1;
            }
        }
    }
    (n > 0).then(|| (sum / n as f64, (ss / n as f64).sqrt()))
}

/// Refine the measured camera-frame axes under the RCM constraint.
pub fn refine(measured: &[Line]) -> Result<(Vec<Line>, lm::LmReport), RcmError> {
    let p = SeedRefine {
        measured: measured.to_vec(),
        rho: measured.iter().map(|l| l.m.norm().max(1.0)).collect(),
    };
    let rep = lm::minimize(&p, p.x0(), &lm::LmOptions::default());
    if !rep.termination.converged() {
        return Err(RcmError::Solver(format!(
            "seed RCM refinement: {}",
            rep.termination.describe()
        )));
    }
    Ok((p.lines(&rep.x), rep))
}

/// Orient every camera-frame axis from the RCM towards the observed (visible) part of the
/// shaft, whose points `seen[i]` (camera frame) lie beyond the trocar.
pub fn orient(lines: &[Line], rcm: &Vector3<f64>, seen: &[Vector3<f64>]) -> Vec<Line> {
    lines
        .iter()
        .zip(seen)
        .map(|(l, s)| {
            if (s - rcm).dot(&l.d) < 0.0 {
                l.flipped()
            } else {
                *l
            }
        })
        .collect()
}

/// Hand-eye (camera in base) from oriented camera axes, the robot's instrument axes and the
/// two RCM points: rotation registers the directions (SVD), translation `p_b − R p_c`.
pub fn hand_eye(
    cam: &[Line],
    base: &[Line],
    rcm_cam: &Vector3<f64>,
    rcm_base: &Vector3<f64>,
) -> Isometry3<f64> {
    let mut h = Matrix3::zeros();
    for (c, b) in cam.iter().zip(base) {
        h += b.d * c.d.transpose();
    }
    let r = crate::solve::rigid::project_rotation(&h);
    let q = UnitQuaternion::from_rotation_matrix(&r);
    let t = rcm_base - (q * rcm_cam);
    Isometry3::from_parts(Translation3::from(t), q)
}

/// RCM in the base from the robot's axes (least squares nearest point), with the RMS distance.
pub fn rcm_base(base: &[Line]) -> Option<(Vector3<f64>, f64)> {
    nearest_point(base)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_jacobian_matches_finite_differences() {
        let c = Vector3::new(5.0, -3.0, 120.0);
        let dirs = [
            Vector3::new(0.3, 0.2, 1.0),
            Vector3::new(-0.2, 0.25, 1.0),
            Vector3::new(0.1, -0.3, 1.0),
            Vector3::new(0.05, 0.1, 1.0),
        ];
        let measured: Vec<Line> = dirs
            .iter()
            .enumerate()
            .map(|(k, d)| Line::through(&(c + Vector3::new(0.3 * k as f64, -0.2, 0.1)), d))
            .collect();
        let p = SeedRefine {
            rho: measured.iter().map(|l| l.m.norm()).collect(),
            measured,
        };
        let x = p.x0().map(|v| v * 1.01 + 0.003);
        let (r, j) = p.residuals_jacobian(&x);
        assert!((r - p.residuals(&x)).norm() < 1e-12);
        let jn = lm::numeric_jacobian(|x| p.residuals(x), &x, 1e-6);
        let err = (&j - &jn).abs().max();
        assert!(
            err < 1e-5 * (1.0 + jn.abs().max()),
            "max |J - J_fd| = {err}"
        );
    }

    #[test]
    fn refinement_pulls_lines_through_one_point() {
        let c = Vector3::new(5.0, -3.0, 120.0);
        let mut measured = Vec::new();
        for k in 0..6 {
            let a = k as f64;
            let d = Vector3::new(0.3 * a.cos(), 0.3 * a.sin(), 1.0);
            let off = Vector3::new(0.5 * (a * 1.7).sin(), 0.5 * (a * 2.3).cos(), 0.0);
            measured.push(Line::through(&(c + off), &d));
        }
        let (_, before) = rcm_from_pairs(&measured).unwrap();
        let (lines, _) = refine(&measured).unwrap();
        let (p, after) = rcm_from_pairs(&lines).unwrap();
        assert!(after < 0.2 * before, "{before} -> {after}");
        assert!((p - c).norm() < 1.0, "{p:?}");
    }
}
