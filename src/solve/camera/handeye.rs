//! The five classical closed-form hand-eye solutions of `A X = X B`, side by side.
//!
//! Eye-in-hand: `F_i` flange in base, `T_i` target in camera (from the intrinsic calibration's
//! board poses), `X` camera in flange. `F_i X T_i` is the target in the base for every view,
//! so for a pair `(i, j)`: `A = F_j⁻¹ F_i`, `B = T_j T_i⁻¹`, `A X = X B`. Eye-to-hand uses the
//! same code with `F_i⁻¹` (see [`super::Mount`]).
//!
//! * Tsai–Lenz (1989): modified Rodrigues vectors, rotation then translation by least squares.
//! * Park–Martin (1994): rotation from `M = Σ β αᵀ`, `R = (MᵀM)^{-½} Mᵀ` (log map).
//! * Horaud–Dornaika (1995): unit quaternion, smallest eigenvector of `Σ Qᵢᵀ Qᵢ`.
//! * Andreff et al. (1999): linear Kronecker formulation of rotation and translation at once.
//! * Daniilidis (1999): dual quaternions, SVD of the stacked `6×8` screw constraints.
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix4, Quaternion, Rotation3, Translation3,
    UnitQuaternion, Vector3,
};

use super::geom::skew;

/// A closed-form hand-eye method.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    TsaiLenz,
    ParkMartin,
    Horaud,
    Andreff,
    Daniilidis,
}

impl Method {
    /// Every method, in the order reports list them.
    pub const ALL: [Method; 5] = [
        Method::TsaiLenz,
        Method::ParkMartin,
        Method::Horaud,
        Method::Andreff,
        Method::Daniilidis,
    ];
    /// Name in reports and files.
    pub fn name(self) -> &'static str {
        match self {
            Method::TsaiLenz => "tsai-lenz",
            Method::ParkMartin => "park-martin",
            Method::Horaud => "horaud",
            Method::Andreff => "andreff",
            Method::Daniilidis => "daniilidis",
        }
    }
}

/// Motion pairs `(A, B)` of the views: every pair `i < j` whose relative rotation is at
/// least `min_deg` (pairs of almost parallel views carry no rotation axis information).
pub fn motion_pairs(
    flange: &[Isometry3<f64>],
    target_in_cam: &[Isometry3<f64>],
    min_deg: f64,
) -> Vec<(Isometry3<f64>, Isometry3<f64>)> {
    let mut out = vec![];
    for i in 0..flange.len() {
        for j in i + 1..flange.len() {
            let a = flange[j].inverse() * flange[i];
            let b = target_in_cam[j] * target_in_cam[i].inverse();
            if a.rotation.angle().to_degrees() >= min_deg {
                out.push((a, b));
            }
        }
    }
    out
}

/// Solve `A X = X B` with `method`. `None` when the pairs do not determine `X`.
pub fn solve(method: Method, pairs: &[(Isometry3<f64>, Isometry3<f64>)]) -> Option<Isometry3<f64>> {
    if pairs.len() < 2 {
        return None;
    }
    let x = match method {
        Method::TsaiLenz => with_translation(pairs, tsai_rotation(pairs)?)?,
        Method::ParkMartin => with_translation(pairs, park_rotation(pairs)?)?,
        Method::Horaud => with_translation(pairs, horaud_rotation(pairs)?)?,
        Method::Andreff => andreff(pairs)?,
        Method::Daniilidis => daniilidis(pairs)?,
    };
    (x.translation.vector.iter().all(|v| v.is_finite())
        && x.rotation.coords.iter().all(|v| v.is_finite()))
    .then_some(x)
}

/// Least-squares translation given the rotation: `(R_A − I) t = R t_B − t_A`.
fn with_translation(
    pairs: &[(Isometry3<f64>, Isometry3<f64>)],
    r: Rotation3<f64>,
) -> Option<Isometry3<f64>> {
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for (a, b) in pairs {
        let m = a.rotation.to_rotation_matrix().matrix() - Matrix3::identity();
        let rhs = r * b.translation.vector - a.translation.vector;
        ata += m.transpose() * m;
        atb += m.transpose() * rhs;
    }
    let t = ata.try_inverse()? * atb;
    Some(Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_rotation_matrix(&r),
    ))
}

fn tsai_rotation(pairs: &[(Isometry3<f64>, Isometry3<f64>)]) -> Option<Rotation3<f64>> {
    // Modified Rodrigues vector P = 2 sin(θ/2) n.
    let pr = |q: &UnitQuaternion<f64>| {
        let q = if q.w < 0.0 {
            -q.into_inner()
        } else {
            q.into_inner()
        };
        2.0 * q.imag()
    };
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for (a, b) in pairs {
        let (pa, pb) = (pr(&a.rotation), pr(&b.rotation));
        let m = skew(&(pa + pb));
        let rhs = pb - pa;
        ata += m.transpose() * m;
        atb += m.transpose() * rhs;
    }
    let pc1 = ata.try_inverse()? * atb;
    let pc = 2.0 * pc1 / (1.0 + pc1.norm_squared()).sqrt();
    let n2 = pc.norm_squared();
    let r = (1.0 - n2 / 2.0) * Matrix3::identity()
        + 0.5 * (pc * pc.transpose() + (4.0 - n2).max(0.0).sqrt() * skew(&pc));
    Some(orthonormal(&r))
}

fn orthonormal(m: &Matrix3<f64>) -> Rotation3<f64> {
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u.unwrap(), svd.v_t.unwrap());
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    Rotation3::from_matrix_unchecked(u * d * vt)
}

fn park_rotation(pairs: &[(Isometry3<f64>, Isometry3<f64>)]) -> Option<Rotation3<f64>> {
    // R α = β with α = log R_B, β = log R_A: M = Σ β αᵀ... solve R = argmin Σ‖β − R α‖².
    let mut m = Matrix3::zeros();
    for (a, b) in pairs {
        let (al, be) = (b.rotation.scaled_axis(), a.rotation.scaled_axis());
        m += be * al.transpose();
    }
    // R = (MᵀM)^{-½} Mᵀ  for M = Σ α βᵀ; with our M = Σ β αᵀ that is  R = M (MᵀM)^{-½}.
    let mtm = m.transpose() * m;
    let e = mtm.symmetric_eigen();
    if e.eigenvalues.iter().any(|&v| v <= 1e-300) {
        return None;
    }
    let inv_sqrt = e.eigenvectors
        * Matrix3::from_diagonal(&e.eigenvalues.map(|v| 1.0 / v.sqrt()))
        * e.eigenvectors.transpose();
    Some(orthonormal(&(m * inv_sqrt)))
}

/// Left and right quaternion multiplication matrices in `(w, x, y, z)` order.
fn qmat(q: &Quaternion<f64>, left: bool) -> Matrix4<f64> {
    let (w, x, y, z) = (q.w, q.i, q.j, q.k);
    if left {
        Matrix4::new(w, -x, -y, -z, x, w, -z, y, y, z, w, -x, z, -y, x, w)
    } else {
        Matrix4::new(w, -x, -y, -z, x, w, z, -y, y, -z, w, x, z, y, -x, w)
    }
}

fn pos_w(q: &UnitQuaternion<f64>) -> Quaternion<f64> {
    if q.w < 0.0 {
        -q.into_inner()
    } else {
        q.into_inner()
    }
}

fn horaud_rotation(pairs: &[(Isometry3<f64>, Isometry3<f64>)]) -> Option<Rotation3<f64>> {
    // q_A q_X = q_X q_B  ⇔  (L(q_A) − R(q_B)) q_X = 0.
    let mut s = Matrix4::zeros();
    for (a, b) in pairs {
        let m = qmat(&pos_w(&a.rotation), true) - qmat(&pos_w(&b.rotation), false);
        s += m.transpose() * m;
    }
    let e = s.symmetric_eigen();
    let (imin, _) = e
        .eigenvalues
        .iter()
        .enumerate()
        .fold((0, f64::MAX), |a, (i, &v)| if v < a.1 { (i, v) } else { a });
    let v = e.eigenvectors.column(imin);
    let q = UnitQuaternion::from_quaternion(Quaternion::new(v[0], v[1], v[2], v[3]));
    Some(q.to_rotation_matrix())
}

fn andreff(pairs: &[(Isometry3<f64>, Isometry3<f64>)]) -> Option<Isometry3<f64>> {
    // Unknowns: row-major vec(R) (9) and t (3).
    // R_A R − R R_B = 0      →  (R_A ⊗ I − I ⊗ R_Bᵀ) vec(R) = 0
    // (R_A − I) t − R t_B = −t_A →  −(I ⊗ t_Bᵀ) vec(R) + (R_A − I) t = −t_A
    let mut ata = DMatrix::<f64>::zeros(12, 12);
    let mut atb = DVector::<f64>::zeros(12);
    let i3 = Matrix3::<f64>::identity();
    for (a, b) in pairs {
        let ra = *a.rotation.to_rotation_matrix().matrix();
        let rb = *b.rotation.to_rotation_matrix().matrix();
        let mut m = DMatrix::<f64>::zeros(12, 12);
        let mut rhs = DVector::<f64>::zeros(12);
        for r in 0..3 {
            for c in 0..3 {
                for k in 0..3 {
                    for l in 0..3 {
                        // row (r,k) col (c,l)
                        let v = ra[(r, c)] * i3[(k, l)] - i3[(r, c)] * rb[(l, k)];
                        m[(3 * r + k, 3 * c + l)] = v;
                    }
                }
            }
        }
        let tb = b.translation.vector;
        for r in 0..3 {
            for l in 0..3 {
                m[(9 + r, 3 * r + l)] = -tb[l];
            }
            for c in 0..3 {
                m[(9 + r, 9 + c)] = ra[(r, c)] - i3[(r, c)];
            }
            rhs[9 + r] = -a.translation.vector[r];
        }
        ata += m.transpose() * &m;
        atb += m.transpose() * rhs;
    }
    let x = ata.clone().cholesky().map(|c| c.solve(&atb)).or_else(|| {
        let svd = ata.svd(true, true);
        svd.solve(&atb, 1e-12).ok()
    })?;
    let r = Matrix3::from_row_slice(&x.as_slice()[..9]);
    // Scale-normalise (the homogeneous rotation block is fixed only by the translations).
    let r = orthonormal(&(r / r.determinant().abs().cbrt().max(1e-300)));
    with_translation(pairs, r)
}

fn daniilidis(pairs: &[(Isometry3<f64>, Isometry3<f64>)]) -> Option<Isometry3<f64>> {
    // Dual quaternion (q, q') of a pose: q rotation, q' = ½ (0, t) q.
    let dq = |p: &Isometry3<f64>| {
        let q = pos_w(&p.rotation);
        let t = p.translation.vector;
        let qd = Quaternion::new(0.0, t.x, t.y, t.z) * q * 0.5;
        (q, qd)
    };
    let mut tt = DMatrix::<f64>::zeros(8, 8);
    for (a, b) in pairs {
        let ((qa, qad), (qb, qbd)) = (dq(a), dq(b));
        let (av, bv, adv, bdv) = (qa.imag(), qb.imag(), qad.imag(), qbd.imag());
        let mut s = DMatrix::<f64>::zeros(6, 8);
        let blk =
            |s: &mut DMatrix<f64>, r0: usize, c0: usize, x: &Vector3<f64>, y: &Vector3<f64>| {
                let d = x - y;
                let k = skew(&(x + y));
                for r in 0..3 {
                    s[(r0 + r, c0)] = d[r];
                    for c in 0..3 {
                        s[(r0 + r, c0 + 1 + c)] = k[(r, c)];
                    }
                }
            };
        blk(&mut s, 0, 0, &av, &bv);
        blk(&mut s, 3, 0, &adv, &bdv);
        blk(&mut s, 3, 4, &av, &bv);
        tt += s.transpose() * s;
    }
    let e = tt.symmetric_eigen();
    let mut idx: Vec<usize> = (0..8).collect();
    idx.sort_by(|&i, &j| e.eigenvalues[i].total_cmp(&e.eigenvalues[j]));
    let v1 = e.eigenvectors.column(idx[0]).into_owned();
    let v2 = e.eigenvectors.column(idx[1]).into_owned();
    let (u1, w1) = (v1.rows(0, 4).into_owned(), v1.rows(4, 4).into_owned());
    let (u2, w2) = (v2.rows(0, 4).into_owned(), v2.rows(4, 4).into_owned());
    // λ1 u1 + λ2 u2 unit and orthogonal to λ1 w1 + λ2 w2: with s = λ1/λ2
    // s² u1ᵀw1 + s (u1ᵀw2 + u2ᵀw1) + u2ᵀw2 = 0.
    let (a, b, c) = (u1.dot(&w1), u1.dot(&w2) + u2.dot(&w1), u2.dot(&w2));
    let roots: Vec<f64> = if a.abs() < 1e-14 {
        vec![-c / b]
    } else {
        let disc = (b * b - 4.0 * a * c).max(0.0).sqrt();
        vec![(-b + disc) / (2.0 * a), (-b - disc) / (2.0 * a)]
    };
    let norm = |s: f64| s * s * u1.dot(&u1) + 2.0 * s * u1.dot(&u2) + u2.dot(&u2);
    let s = roots
        .into_iter()
        .filter(|s| s.is_finite())
        .max_by(|x, y| norm(*x).total_cmp(&norm(*y)))?;
    let l2 = 1.0 / norm(s).sqrt();
    let l1 = s * l2;
    let q = &u1 * l1 + &u2 * l2;
    let qd = &w1 * l1 + &w2 * l2;
    let q = Quaternion::new(q[0], q[1], q[2], q[3]);
    let qd = Quaternion::new(qd[0], qd[1], qd[2], qd[3]);
    let t = (qd * q.conjugate() * 2.0).imag();
    Some(Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_quaternion(q),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(rv: [f64; 3], t: [f64; 3]) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_scaled_axis(Vector3::from(rv)),
        )
    }

    #[test]
    fn every_method_recovers_an_exact_hand_eye() {
        let x = pose([0.1, -0.2, 0.3], [5.0, 50.0, 40.0]);
        let target = pose([0.0, 0.0, 0.4], [-500.0, -150.0, 0.0]);
        let mut fl = vec![];
        let mut tc = vec![];
        for k in 0..8 {
            let f = pose(
                [
                    3.0 + 0.2 * (k as f64).sin(),
                    0.3 * (k as f64 * 1.3).cos(),
                    0.7 * k as f64,
                ],
                [-400.0 + 20.0 * k as f64, -100.0, 500.0 - 10.0 * k as f64],
            );
            fl.push(f);
            tc.push((f * x).inverse() * target);
        }
        let pairs = motion_pairs(&fl, &tc, 1.0);
        for m in Method::ALL {
            let e = solve(m, &pairs).unwrap_or_else(|| panic!("{m:?} failed"));
            let (dt, dr) = super::super::geom::pose_error(&e, &x);
            assert!(dt < 1e-6 && dr < 1e-6, "{m:?}: {dt} mm {dr} deg");
        }
    }
}
