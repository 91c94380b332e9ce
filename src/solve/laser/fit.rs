//! The four laser hand-eye estimators (see the module docs of [`super`]).

use super::{Beam, LaserError, LaserObs, MoveKind, Plane};
use crate::solve::lm::{minimize, LmOptions, LmReport, LsqProblem};
use nalgebra::{DMatrix, DVector, Matrix3, Point3, Unit, Vector3};

/// A unit 3-vector (plane normal, beam direction).
type UnitVec = Unit<Vector3<f64>>;

/// Translation groups of one plane: translate poses sharing one orientation (within 0.05°),
/// each group as (initial pose = lowest id, then the others). This covers both layouts of
/// seed 000: one group per block (each block its own orientation) and the seed's three
/// translation groups whose orientation is fixed across the blocks.
fn translation_groups(obs: &[LaserObs]) -> Vec<Vec<&LaserObs>> {
    let mut groups: Vec<Vec<&LaserObs>> = Vec::new();
    let mut sorted: Vec<&LaserObs> = obs
        .iter()
        .filter(|o| o.move_kind == Some(MoveKind::Translate))
        .collect();
    sorted.sort_by_key(|o| o.id);
    let tol = 0.05f64.to_radians();
    for o in sorted {
        match groups
            .iter_mut()
            .find(|g| g[0].flange.rotation.angle_to(&o.flange.rotation) < tol)
        {
            Some(g) => g.push(o),
            None => groups.push(vec![o]),
        }
    }
    groups.retain(|g| g.len() >= 2);
    groups
}

fn smallest_right_singular_vector(a: &DMatrix<f64>) -> Option<(DVector<f64>, f64, f64)> {
    // Eigen-decomposition of AᵀA (small: 12×12 or 4×4) is enough and cheap.
    let ata = a.tr_mul(a);
    let eig = ata.symmetric_eigen();
    let (mut imin, mut imax) = (0, 0);
    for i in 0..eig.eigenvalues.len() {
        if eig.eigenvalues[i] < eig.eigenvalues[imin] {
            imin = i;
        }
        if eig.eigenvalues[i] > eig.eigenvalues[imax] {
            imax = i;
        }
    }
    let v = eig.eigenvectors.column(imin).into_owned();
    if !v.iter().all(|x| x.is_finite()) {
        return None;
    }
    // Ratio of the two smallest eigenvalues tells whether the null space is one-dimensional.
    let mut ev: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    ev.sort_by(f64::total_cmp);
    Some((
        v,
        ev[0].max(0.0),
        ev.get(1).copied().unwrap_or(0.0).max(0.0),
    ))
}

/// Seed 000 §1.3 closed form on ONE plane.
///
/// Step 1 (eq. 13, in the base frame): for a translation pair `(0, j)` of a group with
/// orientation `R₀`, the two spots lie on the plane, so `n_bᵀ(Δt_j + Δd_j R₀ v) = 0`. This is
/// linear in `z = (n_b, N = n_b vᵀ)` (12 unknowns, homogeneous): `z` is the null vector of the
/// stacked rows, `n_b` its first three entries and `v ∝ Nᵀ n_b`. Unlike eq. 14 (which needs
/// three independent translations per group) this pools all groups of the plane.
/// Step 2 (eq. 15): with `n_b`, `v` known, every pose of the plane gives one linear equation
/// `(R_jᵀ n_b)·r + c = −d_j (R_jᵀ n_b)·v − n_b·t_j` in `(r, c)`.
pub fn closed_form_single_plane(obs: &[LaserObs]) -> Result<(Beam, Plane), LaserError> {
    let groups = translation_groups(obs);
    let (n, v) = match per_group_normals(&groups) {
        Some(nv) => nv,
        None => pooled_normal_and_direction(&groups)?,
    };
    let (r, c) = solve_r_and_offset(obs, &n, &v)?;
    let mut plane = Plane { n, c };
    orient_plane(&mut plane, obs);
    Ok((Beam { r, v }, plane))
}

/// The seed's own route (eq. 14 then eq. 13): each translation group with at least three
/// independent translations gives, in its initial flange frame, `w = [Σ t tᵀ]⁻¹ Σ t Δd` with the
/// plane normal `m = w / |w|` and the constraint `w·v = −1`; three or more groups in different
/// orientations give `v` by least squares. `None` when fewer than three groups qualify.
fn per_group_normals(groups: &[Vec<&LaserObs>]) -> Option<(UnitVec, UnitVec)> {
    let mut rows: Vec<(Vector3<f64>, Vector3<f64>)> = Vec::new(); // (w in flange frame, n_b)
    for g in groups {
        if g.len() < 4 {
            continue;
        }
        let o0 = g[0];
        let r0 = o0.flange.rotation;
        let mut tt = Matrix3::zeros();
        let mut tb = Vector3::zeros();
        for oj in &g[1..] {
            let t = r0.inverse() * (oj.flange.translation.vector - o0.flange.translation.vector);
            tt += t * t.transpose();
            tb += t * (oj.d - o0.d);
        }
        let eig = tt.symmetric_eigen();
        let (lo, hi) = (eig.eigenvalues.min(), eig.eigenvalues.max());
        if !(hi > 0.0 && lo / hi > 1e-4) {
            continue;
        }
        let w = tt.try_inverse()? * tb;
        if w.norm().is_nan() || w.norm() <= 1e-12 {
            continue;
        }
        rows.push((w, r0 * (w / w.norm())));
    }
    if rows.len() < 3 {
        return None;
    }
    let a = DMatrix::from_fn(rows.len(), 3, |i, j| rows[i].0[j]);
    let b = DVector::from_element(rows.len(), -1.0);
    let svd = a.svd(true, true);
    if svd.singular_values.min() <= svd.singular_values.max() * 1e-6 {
        return None;
    }
    let v = svd.solve(&b, 0.0).ok()?;
    let v = Vector3::new(v[0], v[1], v[2]);
    let n = rows.iter().fold(Vector3::zeros(), |acc, (_, nb)| {
        acc + if nb.dot(&rows[0].1) < 0.0 { -nb } else { *nb }
    });
    Some((Unit::try_new(n, 1e-12)?, Unit::try_new(v, 1e-12)?))
}

/// Pooled route for groups with only two translations each (e.g. one group per block):
/// `n_bᵀ(Δt + Δd R₀ v) = 0` is linear in `(n_b, N = n_b vᵀ)`; the null vector gives both.
fn pooled_normal_and_direction(
    groups: &[Vec<&LaserObs>],
) -> Result<(UnitVec, UnitVec), LaserError> {
    let mut rows: Vec<[f64; 12]> = Vec::new();
    for g in groups {
        let o0 = g[0];
        let r0 = o0.flange.rotation.to_rotation_matrix();
        let r0 = r0.matrix();
        for oj in &g[1..] {
            let dt = oj.flange.translation.vector - o0.flange.translation.vector;
            let dd = oj.d - o0.d;
            let mut row = [0.0; 12];
            row[..3].copy_from_slice(dt.as_slice());
            for a in 0..3 {
                for b in 0..3 {
                    row[3 + 3 * a + b] = dd * r0[(a, b)];
                }
            }
            rows.push(row);
        }
    }
    if rows.len() < 11 {
        return Err(LaserError::TooFewData {
            what: "single-plane closed form (translation pairs)".into(),
            need: 11,
            got: rows.len(),
        });
    }
    // Column scaling keeps the mm-scale translation columns and range columns comparable.
    let mut a = DMatrix::from_fn(rows.len(), 12, |i, j| rows[i][j]);
    let scale: Vec<f64> = (0..12).map(|j| a.column(j).norm().max(1e-12)).collect();
    for (j, s) in scale.iter().enumerate() {
        a.column_mut(j).scale_mut(1.0 / s);
    }
    let (mut z, l0, l1) = smallest_right_singular_vector(&a)
        .ok_or_else(|| LaserError::Degenerate("non-finite closed-form system".into()))?;
    if l1 <= 1e-12 || l0 / l1 > 0.5 {
        return Err(LaserError::Degenerate(
            "the translation moves do not determine the plane normal and the beam direction \
             (too few distinct orientations or translations)"
                .into(),
        ));
    }
    for (j, s) in scale.iter().enumerate() {
        z[j] /= s;
    }
    let n = Vector3::new(z[0], z[1], z[2]);
    let nn = n.norm();
    if nn < 1e-12 {
        return Err(LaserError::Degenerate("zero plane normal".into()));
    }
    let big_n = Matrix3::from_fn(|a, b| z[3 + 3 * a + b]);
    let v = big_n.transpose() * n;
    if v.norm() < 1e-12 {
        return Err(LaserError::Degenerate("zero beam direction".into()));
    }
    Ok((Unit::new_normalize(n), Unit::new_normalize(v)))
}

/// Eq. 15 generalised: least squares for `(r, c)` given the plane normal and the beam direction.
fn solve_r_and_offset(
    obs: &[LaserObs],
    n: &Unit<Vector3<f64>>,
    v: &Unit<Vector3<f64>>,
) -> Result<(Vector3<f64>, f64), LaserError> {
    if obs.len() < 4 {
        return Err(LaserError::TooFewData {
            what: "beam origin (eq. 15)".into(),
            need: 4,
            got: obs.len(),
        });
    }
    let mut a = DMatrix::zeros(obs.len(), 4);
    let mut b = DVector::zeros(obs.len());
    for (i, o) in obs.iter().enumerate() {
        let m = o.flange.rotation.inverse() * n.into_inner();
        a[(i, 0)] = m.x;
        a[(i, 1)] = m.y;
        a[(i, 2)] = m.z;
        a[(i, 3)] = 1.0;
        b[i] = -o.d * m.dot(v) - n.dot(&o.flange.translation.vector);
    }
    let svd = a.svd(true, true);
    let sv = &svd.singular_values;
    let (smax, smin) = (sv.max(), sv.min());
    if smin <= smax * 1e-9 {
        return Err(LaserError::Degenerate(
            "the poses of this plane do not rotate enough to determine the beam origin".into(),
        ));
    }
    let x = svd
        .solve(&b, 0.0)
        .map_err(|e| LaserError::Degenerate(e.to_string()))?;
    Ok((Vector3::new(x[0], x[1], x[2]), x[3]))
}

/// Sign convention: the normal points toward the sensor (the flange origins).
fn orient_plane(plane: &mut Plane, obs: &[LaserObs]) {
    let s: f64 = obs
        .iter()
        .map(|o| plane.distance(&Point3::from(o.flange.translation.vector)))
        .sum();
    if s < 0.0 {
        plane.n = -plane.n;
        plane.c = -plane.c;
    }
}

/// The plane through `pts` by PCA (centroid + direction of least variance).
pub fn pca_plane(pts: &[Point3<f64>]) -> Option<Plane> {
    if pts.len() < 3 {
        return None;
    }
    let c = pts.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / pts.len() as f64;
    let mut cov = Matrix3::zeros();
    for p in pts {
        let d = p.coords - c;
        cov += d * d.transpose();
    }
    let eig = cov.symmetric_eigen();
    let imin = eig.eigenvalues.imin();
    let n = Unit::new_normalize(eig.eigenvectors.column(imin).into_owned());
    Some(Plane { n, c: -n.dot(&c) })
}

/// One iteration of the data selection.
#[derive(Debug, Clone, PartialEq)]
pub struct SelectionStep {
    /// Iteration (0 = all data).
    pub iteration: usize,
    /// Points used.
    pub n_points: usize,
    /// Score of the parameters (mean 5-direction spread, mm; lower is better).
    pub score: f64,
    /// Id dropped after this iteration, if any.
    pub dropped: Option<u64>,
}

/// The trace of [`select_data`].
#[derive(Debug, Clone, PartialEq)]
pub struct SelectionTrace {
    /// Every iteration.
    pub steps: Vec<SelectionStep>,
    /// The iteration kept.
    pub best_iteration: usize,
}

/// Seed 000 §1.4 / §2.2 data selection on one plane: repeatedly drop the point farthest from
/// the PCA plane of the measured spots (computed with the current parameters), refit, and keep
/// the parameters with the lowest `score` (the seed scores by the 5-direction spread of the
/// validation targets). Stops when the closed form no longer has enough data, or after
/// `max_drop` drops.
pub fn select_data(
    obs: &[LaserObs],
    score: &dyn Fn(&Beam) -> f64,
    max_drop: usize,
) -> Result<(Beam, Plane, SelectionTrace), LaserError> {
    let mut current: Vec<LaserObs> = obs.to_vec();
    let (mut beam, mut plane) = closed_form_single_plane(&current)?;
    let mut best = (beam, plane, score(&beam), 0usize);
    let mut steps = Vec::new();
    let mut iteration = 0;
    loop {
        let s = score(&beam);
        if s < best.2 {
            best = (beam, plane, s, iteration);
        }
        let spots: Vec<Point3<f64>> = current.iter().map(|o| beam.spot(&o.flange, o.d)).collect();
        let Some(pca) = pca_plane(&spots) else { break };
        let (iworst, _) = spots
            .iter()
            .enumerate()
            .map(|(i, p)| (i, pca.distance(p).abs()))
            .fold((0, -1.0), |acc, x| if x.1 > acc.1 { x } else { acc });
        if iteration >= max_drop {
            steps.push(SelectionStep {
                iteration,
                n_points: current.len(),
                score: s,
                dropped: None,
            });
            break;
        }
        let dropped = current[iworst].id;
        steps.push(SelectionStep {
            iteration,
            n_points: current.len(),
            score: s,
            dropped: Some(dropped),
        });
        let mut next = current.clone();
        next.remove(iworst);
        match closed_form_single_plane(&next) {
            Ok((b, p)) => {
                beam = b;
                plane = p;
                current = next;
                iteration += 1;
            }
            Err(_) => {
                if let Some(last) = steps.last_mut() {
                    last.dropped = None;
                }
                break;
            }
        }
    }
    Ok((
        best.0,
        best.1,
        SelectionTrace {
            steps,
            best_iteration: best.3,
        },
    ))
}

/// Layout of the parameter vector shared by the multi-plane problems:
/// `[r (3), v (3), (n_i (3), c_i) per plane]`.
fn pack(beam: &Beam, planes: &[Plane]) -> DVector<f64> {
    let mut x = DVector::zeros(6 + 4 * planes.len());
    x.fixed_rows_mut::<3>(0).copy_from(&beam.r);
    x.fixed_rows_mut::<3>(3).copy_from(&beam.v.into_inner());
    for (i, p) in planes.iter().enumerate() {
        x.fixed_rows_mut::<3>(6 + 4 * i)
            .copy_from(&p.n.into_inner());
        x[9 + 4 * i] = p.c;
    }
    x
}

fn unpack(x: &DVector<f64>, n_planes: usize) -> (Beam, Vec<Plane>) {
    let beam = Beam {
        r: x.fixed_rows::<3>(0).into_owned(),
        v: Unit::new_normalize(x.fixed_rows::<3>(3).into_owned()),
    };
    let planes = (0..n_planes)
        .map(|i| {
            let n = x.fixed_rows::<3>(6 + 4 * i).into_owned();
            let norm = n.norm();
            Plane {
                n: Unit::new_normalize(n),
                c: x[9 + 4 * i] / norm,
            }
        })
        .collect();
    (beam, planes)
}

/// Weight of the unit-norm constraint rows (mm per unit of `|v|² − 1`).
const NORM_WEIGHT: f64 = 1.0e4;

/// Point-to-plane (coplanarity) and, optionally, closed-form consistency residuals over several planes.
struct MultiPlane<'a> {
    planes: Vec<Vec<&'a LaserObs>>,
    /// (plane index, initial, other) translation pairs for the consistency term.
    pairs: Vec<(usize, &'a LaserObs, &'a LaserObs)>,
    alpha: f64,
    beta: f64,
    /// Per-point weights of the coplanarity rows (IRLS for Huber), same order as the points.
    weights: Vec<f64>,
    /// Range-correction regressors (effects): the corrected range of point i is
    /// `d_i + Σ_k e_k g_k[i]`, with the `e_k` appended to the parameter vector.
    range_terms: Vec<Vec<f64>>,
}

impl MultiPlane<'_> {
    fn n_points(&self) -> usize {
        self.planes.iter().map(|p| p.len()).sum()
    }
}

impl LsqProblem for MultiPlane<'_> {
    fn n_params(&self) -> usize {
        6 + 4 * self.planes.len() + self.range_terms.len()
    }
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        self.residuals_jacobian(x).0
    }
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let np = self.planes.len();
        let m = self.n_points() + self.pairs.len() + 1 + np;
        let mut r = DVector::zeros(m);
        let ne = 6 + 4 * np;
        let mut j = DMatrix::zeros(m, ne + self.range_terms.len());
        let rr: Vector3<f64> = x.fixed_rows::<3>(0).into_owned();
        let v: Vector3<f64> = x.fixed_rows::<3>(3).into_owned();
        let mut row = 0;
        for (k, pts) in self.planes.iter().enumerate() {
            let n: Vector3<f64> = x.fixed_rows::<3>(6 + 4 * k).into_owned();
            let c = x[9 + 4 * k];
            for o in pts {
                let w = self.beta * self.weights[row];
                let rot = o.flange.rotation;
                let d = o.d
                    + self
                        .range_terms
                        .iter()
                        .enumerate()
                        .map(|(e, g)| x[ne + e] * g[row])
                        .sum::<f64>();
                let xb = rot * (rr + v * d) + o.flange.translation.vector;
                r[row] = w * (n.dot(&xb) + c);
                let m_f = rot.inverse() * n; // normal in the flange frame
                for a in 0..3 {
                    j[(row, a)] = w * m_f[a];
                    j[(row, 3 + a)] = w * d * m_f[a];
                    j[(row, 6 + 4 * k + a)] = w * xb[a];
                }
                j[(row, 9 + 4 * k)] = w;
                let nv = m_f.dot(&v);
                for (e, g) in self.range_terms.iter().enumerate() {
                    j[(row, ne + e)] = w * g[row] * nv;
                }
                row += 1;
            }
        }
        for (k, o0, oj) in &self.pairs {
            let n: Vector3<f64> = x.fixed_rows::<3>(6 + 4 * k).into_owned();
            let dd = oj.d - o0.d;
            let dt = oj.flange.translation.vector - o0.flange.translation.vector;
            let r0v = o0.flange.rotation * v;
            r[row] = self.alpha * (dd * n.dot(&r0v) + n.dot(&dt));
            let dv = o0.flange.rotation.inverse() * n * dd;
            let dn = r0v * dd + dt;
            for a in 0..3 {
                j[(row, 3 + a)] = self.alpha * dv[a];
                j[(row, 6 + 4 * k + a)] = self.alpha * dn[a];
            }
            row += 1;
        }
        r[row] = NORM_WEIGHT * (v.norm_squared() - 1.0);
        for a in 0..3 {
            j[(row, 3 + a)] = NORM_WEIGHT * 2.0 * v[a];
        }
        row += 1;
        for k in 0..np {
            let n: Vector3<f64> = x.fixed_rows::<3>(6 + 4 * k).into_owned();
            r[row] = NORM_WEIGHT * (n.norm_squared() - 1.0);
            for a in 0..3 {
                j[(row, 6 + 4 * k + a)] = NORM_WEIGHT * 2.0 * n[a];
            }
            row += 1;
        }
        (r, j)
    }
}

/// Result of a multi-plane fit.
#[derive(Debug, Clone)]
pub struct MultiPlaneFit {
    /// The beam.
    pub beam: Beam,
    /// Fitted planes (same order as the input plane list).
    pub planes: Vec<Plane>,
    /// Point-to-plane RMS over the points used (mm).
    pub rms_mm: f64,
    /// Standard deviations of `r` (mm) and `v` from the covariance, when computable.
    pub std: Option<[f64; 6]>,
    /// Solver report.
    pub report: LmReport,
    /// Ids whose Huber weight fell below 0.5 (outliers), sorted.
    pub outliers: Vec<u64>,
    /// Fitted range-correction coefficients `e_k` (same order as the regressors).
    pub range_coefs: Vec<f64>,
    /// Their standard deviations, when computable.
    pub range_coef_std: Vec<f64>,
    /// Sum of squared (unweighted) point-to-plane distances (mm²).
    pub rss: f64,
}

fn plane_lists(obs_by_plane: &[Vec<LaserObs>]) -> Vec<Vec<&LaserObs>> {
    obs_by_plane.iter().map(|p| p.iter().collect()).collect()
}

fn finish(
    prob: &MultiPlane<'_>,
    report: LmReport,
    obs_by_plane: &[Vec<LaserObs>],
) -> MultiPlaneFit {
    let np = obs_by_plane.len();
    let (beam, mut planes) = unpack(&report.x, np);
    for (p, o) in planes.iter_mut().zip(obs_by_plane) {
        orient_plane(p, o);
    }
    let ne = 6 + 4 * np;
    let range_coefs: Vec<f64> = (0..prob.range_terms.len())
        .map(|e| report.x[ne + e])
        .collect();
    let mut d2 = 0.0;
    let mut cnt = 0usize;
    for (p, pts) in planes.iter().zip(obs_by_plane) {
        for o in pts {
            let d = o.d
                + range_coefs
                    .iter()
                    .zip(&prob.range_terms)
                    .map(|(e, g)| e * g[cnt])
                    .sum::<f64>();
            d2 += p.distance(&beam.spot(&o.flange, d)).powi(2);
            cnt += 1;
        }
    }
    let rms = (d2 / cnt.max(1) as f64).sqrt();
    // Covariance σ² (JᵀJ)⁻¹, σ² from the (weighted) point rows of the final residual.
    let npts = prob.n_points();
    let mut range_coef_std = vec![f64::NAN; range_coefs.len()];
    let std = {
        let jac = &report.jacobian;
        let jtj = jac.tr_mul(jac);
        let dof = npts.saturating_sub(5 + 3 * np + range_coefs.len()).max(1) as f64;
        let sigma2 = report.residuals.rows(0, npts).norm_squared() / dof;
        jtj.try_inverse().map(|inv| {
            for (e, s) in range_coef_std.iter_mut().enumerate() {
                *s = (inv[(ne + e, ne + e)].max(0.0) * sigma2).sqrt();
            }
            let mut s = [0.0; 6];
            for (k, sk) in s.iter_mut().enumerate() {
                *sk = (inv[(k, k)].max(0.0) * sigma2).sqrt();
            }
            s
        })
    };
    let mut outliers: Vec<u64> = Vec::new();
    let mut k = 0;
    for pts in &prob.planes {
        for o in pts {
            if prob.weights[k] < 0.5 {
                outliers.push(o.id);
            }
            k += 1;
        }
    }
    outliers.sort_unstable();
    MultiPlaneFit {
        beam,
        planes,
        rms_mm: rms,
        std,
        report,
        outliers,
        range_coefs,
        range_coef_std,
        rss: d2,
    }
}

/// Seed 000 eq. 16–18: Levenberg–Marquardt over the three (or more) planes from the mean of
/// the single-plane results; objective = closed-form consistency of every translation pair
/// (weight `alpha = 1`) + coplanarity of every spot (weight `beta`, raised as the seed does),
/// with `|v| = 1` and `|n_i| = 1` as stiff penalty rows and the normals' sign fixed afterwards.
pub fn fit_orthogonal_planes(
    obs_by_plane: &[Vec<LaserObs>],
    start: &Beam,
    start_planes: &[Plane],
) -> Result<MultiPlaneFit, LaserError> {
    if obs_by_plane.len() != start_planes.len() || obs_by_plane.is_empty() {
        return Err(LaserError::Degenerate(
            "one start plane per plane of data is needed".into(),
        ));
    }
    let planes = plane_lists(obs_by_plane);
    let mut pairs = Vec::new();
    for (k, pts) in obs_by_plane.iter().enumerate() {
        for g in translation_groups(pts) {
            for oj in &g[1..] {
                pairs.push((k, g[0], *oj));
            }
        }
    }
    let npts = planes.iter().map(|p| p.len()).sum();
    let prob = MultiPlane {
        planes,
        pairs,
        alpha: 1.0,
        beta: 2.0,
        weights: vec![1.0; npts],
        range_terms: Vec::new(),
    };
    let report = minimize(&prob, pack(start, start_planes), &LmOptions::default());
    if !report.termination.converged() {
        return Err(LaserError::Degenerate(format!(
            "orthogonal-plane fit: {}",
            report.termination.describe()
        )));
    }
    Ok(finish(&prob, report, obs_by_plane))
}

/// Options of the direct fit.
#[derive(Debug, Clone, Default)]
pub struct DirectOptions {
    /// Huber threshold (mm); `None` = plain least squares.
    pub huber_mm: Option<f64>,
    /// Range-correction regressors `g_k` (one value per point, in plane-then-point order):
    /// the corrected range is `d + Σ e_k g_k`; the fitted `e_k` are [`MultiPlaneFit::range_coefs`].
    pub range_terms: Vec<Vec<f64>>,
}

/// Direct maximum-likelihood fit: joint least squares over `r`, `v` and every plane `(n_i, c_i)`
/// minimising the point-to-plane distance of all raw data; Huber loss by iteratively
/// reweighted least squares when asked.
pub fn fit_direct(
    obs_by_plane: &[Vec<LaserObs>],
    start: &Beam,
    start_planes: &[Plane],
    opts: DirectOptions,
) -> Result<MultiPlaneFit, LaserError> {
    if obs_by_plane.len() != start_planes.len() || obs_by_plane.is_empty() {
        return Err(LaserError::Degenerate(
            "one start plane per plane of data is needed".into(),
        ));
    }
    let planes = plane_lists(obs_by_plane);
    let npts: usize = planes.iter().map(|p| p.len()).sum();
    if npts < 6 + 3 * planes.len() {
        return Err(LaserError::TooFewData {
            what: "direct fit (points)".into(),
            need: 6 + 3 * planes.len(),
            got: npts,
        });
    }
    let mut prob = MultiPlane {
        planes,
        pairs: Vec::new(),
        alpha: 0.0,
        beta: 1.0,
        weights: vec![1.0; npts],
        range_terms: opts.range_terms.clone(),
    };
    let x0 = pack(start, start_planes);
    let mut x = x0.resize_vertically(6 + 4 * start_planes.len() + opts.range_terms.len(), 0.0);
    let rounds = if opts.huber_mm.is_some() { 6 } else { 1 };
    let mut report = None;
    for _ in 0..rounds {
        let rep = minimize(&prob, x.clone(), &LmOptions::default());
        if !rep.termination.converged() {
            return Err(LaserError::Degenerate(format!(
                "direct fit: {}",
                rep.termination.describe()
            )));
        }
        x = rep.x.clone();
        if let Some(k) = opts.huber_mm {
            // Huber IRLS weights on the unweighted distances (sqrt because rows are scaled).
            let (beam, pl) = unpack(&x, prob.planes.len());
            let mut i = 0;
            for (p, pts) in pl.iter().zip(&prob.planes) {
                for o in pts {
                    let e = p.distance(&beam.spot(&o.flange, o.d)).abs();
                    prob.weights[i] = if e <= k { 1.0 } else { (k / e).sqrt() };
                    i += 1;
                }
            }
        }
        report = Some(rep);
    }
    let report = report.expect("at least one round");
    Ok(finish(&prob, report, obs_by_plane))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Synthetic plane data in the seed's layout (15 blocks × 3 translations + 1 rotation).
    pub(crate) fn synth(
        beam: &Beam,
        plane: &Plane,
        label: &str,
        seed: u64,
        range_noise: f64,
    ) -> Vec<LaserObs> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut out = Vec::new();
        let mut id = seed * 1000;
        // A frame on the plane.
        let n = plane.n.into_inner();
        let u = n
            .cross(&Vector3::x())
            .try_normalize(1e-6)
            .unwrap_or_else(|| n.cross(&Vector3::y()).normalize());
        let w = n.cross(&u);
        let p0 = -n * plane.c;
        for block in 0..15u64 {
            let centre =
                p0 + u * rng.random_range(-150.0..150.0) + w * rng.random_range(-150.0..150.0);
            // Beam direction in base: tilted from -n by up to 20°.
            let tilt = UnitQuaternion::from_scaled_axis(
                u * rng.random_range(-0.3..0.3) + w * rng.random_range(-0.3..0.3),
            );
            let beam_dir_base = tilt * (-n);
            // Orientation R with R v = beam_dir_base, random roll about it.
            let align = UnitQuaternion::rotation_between(&beam.v.into_inner(), &beam_dir_base)
                .unwrap_or_else(UnitQuaternion::identity);
            let roll = UnitQuaternion::from_axis_angle(
                &Unit::new_normalize(beam_dir_base),
                rng.random_range(-1.0..1.0),
            );
            let rot = roll * align;
            let stand = rng.random_range(450.0..750.0);
            for k in 0..4 {
                let (rot_k, target) = if k < 3 {
                    let off = u * rng.random_range(-20.0..20.0) + w * rng.random_range(-20.0..20.0);
                    (rot, centre + off)
                } else {
                    let extra = UnitQuaternion::from_scaled_axis(
                        u * rng.random_range(-0.4..0.4) + w * rng.random_range(-0.4..0.4),
                    );
                    (extra * rot, centre)
                };
                let dir = rot_k * beam.v.into_inner();
                let d = stand
                    + if k < 3 {
                        rng.random_range(-30.0..30.0)
                    } else {
                        0.0
                    };
                // Flange so that r + d v lands on `target` … then shift along the beam to the plane.
                let t = target - rot_k * (beam.r + beam.v.into_inner() * d);
                let f = Isometry3::from_parts(Translation3::from(t), rot_k);
                // Exact range to the plane from this flange pose.
                let origin = f * Point3::from(beam.r);
                let denom = n.dot(&dir);
                let d_true = -(n.dot(&origin.coords) + plane.c) / denom;
                out.push(LaserObs {
                    id,
                    flange: f,
                    d: d_true + range_noise * rng.random_range(-1.0..1.0),
                    plane: Some(label.into()),
                    move_kind: Some(if k < 3 {
                        MoveKind::Translate
                    } else {
                        MoveKind::Rotate
                    }),
                    block: Some(block),
                    target: None,
                    group: Some("train".into()),
                });
                id += 1;
            }
        }
        out
    }

    pub(crate) fn truth() -> (Beam, Vec<Plane>) {
        let beam = Beam {
            r: Vector3::new(37.2, -14.6, 86.3),
            v: Unit::new_normalize(Vector3::new(0.0081, -0.0043, 1.0)),
        };
        let planes = vec![
            Plane {
                n: Unit::new_normalize(Vector3::new(-1.0, -1.0, 0.0)),
                c: 800.0 / 2f64.sqrt(),
            },
            Plane {
                n: Unit::new_normalize(Vector3::new(-1.0, 1.0, 0.0)),
                c: 800.0 / 2f64.sqrt(),
            },
            Plane {
                n: Vector3::z_axis(),
                c: -50.0,
            },
        ];
        (beam, planes)
    }

    #[test]
    fn closed_form_is_exact_without_noise() {
        let (beam, planes) = truth();
        for (i, p) in planes.iter().enumerate() {
            let obs = synth(&beam, p, "P", i as u64 + 1, 0.0);
            let (b, pl) = closed_form_single_plane(&obs).unwrap();
            assert!((b.r - beam.r).norm() < 1e-6, "r {:?}", b.r);
            assert!((b.v.into_inner() - beam.v.into_inner()).norm() < 1e-9);
            assert!((pl.n.into_inner().dot(&p.n).abs() - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn multi_plane_jacobian_matches_finite_differences() {
        let (beam, planes) = truth();
        let data: Vec<Vec<LaserObs>> = planes
            .iter()
            .enumerate()
            .map(|(i, p)| synth(&beam, p, "P", i as u64 + 1, 0.05))
            .collect();
        let lists = plane_lists(&data);
        let mut pairs = Vec::new();
        for (k, pts) in data.iter().enumerate() {
            for g in translation_groups(pts) {
                for oj in &g[1..] {
                    pairs.push((k, g[0], *oj));
                }
            }
        }
        let n: usize = lists.iter().map(|l| l.len()).sum();
        let prob = MultiPlane {
            planes: lists,
            pairs,
            alpha: 1.0,
            beta: 2.0,
            weights: vec![1.0; n],
            range_terms: vec![(0..n).map(|i| 400.0 + i as f64).collect()],
        };
        let x = pack(&beam, &planes);
        let len = x.len();
        let mut x = x.resize_vertically(len + 1, 1e-3);
        x[0] += 0.3;
        x[4] += 0.01;
        x[7] += 0.02;
        let (_, ja) = prob.residuals_jacobian(&x);
        let jn = crate::solve::lm::numeric_jacobian(|x| prob.residuals(x), &x, 1e-6);
        let err = (&ja - &jn).abs().max();
        assert!(
            err < 1e-3 * ja.abs().max().max(1.0),
            "max Jacobian error {err}"
        );
    }

    #[test]
    fn direct_fit_recovers_the_beam_from_a_perturbed_start() {
        let (beam, planes) = truth();
        let data: Vec<Vec<LaserObs>> = planes
            .iter()
            .enumerate()
            .map(|(i, p)| synth(&beam, p, "P", i as u64 + 1, 0.02))
            .collect();
        let start = Beam {
            r: beam.r + Vector3::new(3.0, -2.0, 5.0),
            v: Unit::new_normalize(beam.v.into_inner() + Vector3::new(0.01, 0.01, 0.0)),
        };
        let fit = fit_direct(&data, &start, &planes, DirectOptions::default()).unwrap();
        assert!(
            (fit.beam.r - beam.r).norm() < 0.1,
            "r error {}",
            (fit.beam.r - beam.r).norm()
        );
        assert!(fit.beam.v.angle(&beam.v) < 2e-4);
        assert!(fit.rms_mm < 0.05, "rms {}", fit.rms_mm);
        // An outlier is flagged with the Huber loss and does not pull the fit.
        let mut bad = data.clone();
        bad[0][5].d += 25.0;
        let fit = fit_direct(
            &bad,
            &start,
            &planes,
            DirectOptions {
                huber_mm: Some(0.1),
                ..Default::default()
            },
        )
        .unwrap();
        assert!(fit.outliers.contains(&bad[0][5].id), "{:?}", fit.outliers);
        assert!((fit.beam.r - beam.r).norm() < 0.2);
    }
}
