//! Zhang's closed-form initialisation: one plane-to-image homography per view (normalised
//! DLT), the image of the absolute conic from the homographies, `K` from it, and each
//! view's board pose from `K⁻¹H`. Falls back to a principal point at the image centre and
//! square pixels (one focal length from the same constraints) when the views are too close to
//! parallel for the five-parameter conic.
use nalgebra::{DMatrix, Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Smallest-eigenvalue eigenvector of a symmetric matrix.
fn null_vector(ata: &DMatrix<f64>) -> nalgebra::DVector<f64> {
    let e = ata.clone().symmetric_eigen();
    let (imin, _) = e
        .eigenvalues
        .iter()
        .enumerate()
        .fold((0, f64::MAX), |a, (i, &v)| if v < a.1 { (i, v) } else { a });
    e.eigenvectors.column(imin).into_owned()
}

/// Hartley normalisation of 2-D points: the similarity `T` with `T·p` centred, mean norm √2.
fn normaliser(pts: &[[f64; 2]]) -> Matrix3<f64> {
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p[0]).sum::<f64>() / n,
        pts.iter().map(|p| p[1]).sum::<f64>() / n,
    );
    let d = pts
        .iter()
        .map(|p| ((p[0] - mx).powi(2) + (p[1] - my).powi(2)).sqrt())
        .sum::<f64>()
        / n;
    let s = if d > 0.0 { 2f64.sqrt() / d } else { 1.0 };
    Matrix3::new(s, 0.0, -s * mx, 0.0, s, -s * my, 0.0, 0.0, 1.0)
}

/// Homography `H` with `[u v 1]ᵀ ∝ H [X Y 1]ᵀ` from ≥ 4 correspondences.
pub fn homography(plane: &[[f64; 2]], image: &[[f64; 2]]) -> Option<Matrix3<f64>> {
    if plane.len() < 4 || plane.len() != image.len() {
        return None;
    }
    let (tp, ti) = (normaliser(plane), normaliser(image));
    let mut ata = DMatrix::<f64>::zeros(9, 9);
    for (p, q) in plane.iter().zip(image) {
        let a = tp * Vector3::new(p[0], p[1], 1.0);
        let b = ti * Vector3::new(q[0], q[1], 1.0);
        let (x, y) = (a.x / a.z, a.y / a.z);
        let (u, v) = (b.x / b.z, b.y / b.z);
        let r1 = [-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u];
        let r2 = [0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v];
        for r in [r1, r2] {
            for i in 0..9 {
                for j in 0..9 {
                    ata[(i, j)] += r[i] * r[j];
                }
            }
        }
    }
    let h = null_vector(&ata);
    let hn = Matrix3::from_row_slice(h.as_slice());
    let h = ti.try_inverse()? * hn * tp;
    let s = h[(2, 2)];
    if !s.is_finite() || s.abs() < 1e-300 {
        return None;
    }
    Some(h / s)
}

fn vij(h: &Matrix3<f64>, i: usize, j: usize) -> [f64; 6] {
    let (a, b) = (h.column(i), h.column(j));
    [
        a[0] * b[0],
        a[0] * b[1] + a[1] * b[0],
        a[1] * b[1],
        a[2] * b[0] + a[0] * b[2],
        a[2] * b[1] + a[1] * b[2],
        a[2] * b[2],
    ]
}

/// Zhang's closed form (zero skew). `None` when the conic is not positive definite.
/// `(cx0, cy0, s)` precondition the pixel frame (image centre and a scale ~ the image width):
/// the conic is solved for `N⁻¹ H` with `N = [[s, 0, cx0], [0, s, cy0], [0, 0, 1]]`, so its
/// entries are all of order one.
pub fn zhang_k(hs: &[Matrix3<f64>], cx0: f64, cy0: f64, s: f64) -> Option<Matrix3<f64>> {
    if hs.len() < 3 {
        return None;
    }
    let n = Matrix3::new(s, 0.0, cx0, 0.0, s, cy0, 0.0, 0.0, 1.0);
    let ni = n.try_inverse()?;
    let hs: Vec<Matrix3<f64>> = hs.iter().map(|h| ni * h).collect();
    let hs = &hs[..];
    let mut ata = DMatrix::<f64>::zeros(6, 6);
    let mut add = |r: [f64; 6]| {
        for i in 0..6 {
            for j in 0..6 {
                ata[(i, j)] += r[i] * r[j];
            }
        }
    };
    for h in hs {
        // Scale each H so the rows are comparable.
        let h = h / h.column(0).norm().max(1e-300);
        let (v12, v11, v22) = (vij(&h, 0, 1), vij(&h, 0, 0), vij(&h, 1, 1));
        add(v12);
        add(std::array::from_fn(|k| v11[k] - v22[k]));
        // zero skew: B12 = 0
        add([0.0, 10.0, 0.0, 0.0, 0.0, 0.0]);
    }
    let b = null_vector(&ata);
    let b = if b[0] < 0.0 { -b } else { b };
    let (b11, b12, b22, b13, b23, b33) = (b[0], b[1], b[2], b[3], b[4], b[5]);
    let den = b11 * b22 - b12 * b12;
    if den <= 0.0 || b11 <= 0.0 {
        return None;
    }
    let v0 = (b12 * b13 - b11 * b23) / den;
    let lam = b33 - (b13 * b13 + v0 * (b12 * b13 - b11 * b23)) / b11;
    if lam / b11 <= 0.0 {
        return None;
    }
    let alpha = (lam / b11).sqrt();
    let beta = (lam * b11 / den).sqrt();
    let u0 = -b13 * alpha * alpha / lam;
    let k = n * Matrix3::new(alpha, 0.0, u0, 0.0, beta, v0, 0.0, 0.0, 1.0);
    k.iter().all(|x| x.is_finite()).then_some(k)
}

/// One focal length with the principal point fixed at `(cx, cy)` and square pixels.
pub fn focal_centered(hs: &[Matrix3<f64>], cx: f64, cy: f64) -> Option<Matrix3<f64>> {
    let c = Matrix3::new(1.0, 0.0, -cx, 0.0, 1.0, -cy, 0.0, 0.0, 1.0);
    // Each constraint: a·w + b = 0 with w = 1/f².
    let (mut aa, mut ab) = (0.0, 0.0);
    for h in hs {
        let h = c * h;
        let h = h / h.column(0).norm().max(1e-300);
        let (h1, h2) = (h.column(0), h.column(1));
        let rows = [
            (h1[0] * h2[0] + h1[1] * h2[1], h1[2] * h2[2]),
            (
                h1[0] * h1[0] + h1[1] * h1[1] - h2[0] * h2[0] - h2[1] * h2[1],
                h1[2] * h1[2] - h2[2] * h2[2],
            ),
        ];
        for (a, b) in rows {
            aa += a * a;
            ab += a * b;
        }
    }
    let w = -ab / aa;
    if !(w.is_finite() && w > 0.0) {
        return None;
    }
    let f = 1.0 / w.sqrt();
    Some(Matrix3::new(f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0))
}

/// Board pose in the camera frame from `K` and the view's homography (board z towards the
/// camera's half-space: the board lies in front of the camera).
pub fn pose_from_h(k: &Matrix3<f64>, h: &Matrix3<f64>) -> Option<Isometry3<f64>> {
    let m = k.try_inverse()? * h;
    let l = 1.0 / m.column(0).norm();
    let l = if m[(2, 2)] * l < 0.0 { -l } else { l };
    let r1 = m.column(0) * l;
    let r2 = m.column(1) * l;
    let r3 = r1.cross(&r2);
    let t = m.column(2) * l;
    let r = Matrix3::from_columns(&[r1, r2, r3]);
    let svd = r.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut ro = u * vt;
    if ro.determinant() < 0.0 {
        ro = -ro;
    }
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(ro));
    Some(Isometry3::from_parts(Translation3::from(t), rot))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn zhang_recovers_k_from_exact_views() {
        let k = Matrix3::new(900.0, 0.0, 330.0, 0.0, 910.0, 235.0, 0.0, 0.0, 1.0);
        let plane: Vec<[f64; 2]> = (0..6)
            .flat_map(|j| (0..8).map(move |i| [i as f64 * 30.0, j as f64 * 30.0]))
            .collect();
        let mut hs = vec![];
        for (n, rv) in [
            [0.3, 0.1, 0.2],
            [-0.2, 0.35, 1.0],
            [0.1, -0.3, 2.5],
            [0.25, 0.25, -1.0],
        ]
        .iter()
        .enumerate()
        {
            let pose = Isometry3::from_parts(
                Translation3::new(-100.0 + n as f64 * 10.0, -70.0, 600.0),
                UnitQuaternion::from_scaled_axis(Vector3::from(*rv)),
            );
            let img: Vec<[f64; 2]> = plane
                .iter()
                .map(|p| {
                    let c = k * (pose * Point3::new(p[0], p[1], 0.0)).coords;
                    [c.x / c.z, c.y / c.z]
                })
                .collect();
            let h = homography(&plane, &img).unwrap();
            let back = pose_from_h(&k, &h).unwrap();
            assert!((back.translation.vector - pose.translation.vector).norm() < 1e-6);
            hs.push(h);
        }
        let kk = zhang_k(&hs, 320.0, 240.0, 640.0).unwrap();
        assert!((kk - k).abs().max() < 1e-4, "{kk}");
        let kc = focal_centered(&hs, 330.0, 235.0).unwrap();
        // Square pixels assumed: a rough focal length only (the LM refines it).
        assert!((kc[(0, 0)] - 905.0).abs() < 60.0, "{kc}");
    }
}
