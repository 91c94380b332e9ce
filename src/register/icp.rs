//! Surface registration CT ↔ tracker: trimmed point-to-plane ICP of digitised surface points
//! (tracker frame) onto a CT mesh, multi-start so that a rough start does not end in a wrong
//! local minimum.
//!
//! The mesh is sampled densely (spacing ≤ `sample_spacing_mm`) and indexed in an R*-tree
//! (`rstar`); each sample carries its triangle's normal, so the point-to-plane residual is
//! the exact distance to the nearest sample's triangle plane. Each ICP iteration fixes the
//! correspondences, keeps the `trim_fraction` of closest points and solves the 6-parameter
//! point-to-plane problem ([`PointToPlane`]) on the one LM solver.
//!
//! Internally the solved transform is `S = T_ct_tracker` (tracker points onto the mesh);
//! the result is reported as `T_tracker_ct = S⁻¹` with its covariance re-expressed for the
//! left perturbation of `T_tracker_ct`.
#![allow(clippy::type_complexity)] // (points, normals, ...) tuples of parallel vectors
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3, Vector6,
};
use rstar::primitives::GeomWithData;
use rstar::RTree;

use super::mesh::Mesh;
use super::paired::perturb;
use super::{skew, so3_left_jacobian, RegisterError};
use crate::solve::lm::{self, LmOptions, LsqProblem};

type Sample = GeomWithData<[f64; 3], usize>;

/// A mesh sampled for nearest-point queries.
pub struct SurfaceIndex {
    tree: RTree<Sample>,
    points: Vec<Point3<f64>>,
    normals: Vec<Vector3<f64>>,
}

impl SurfaceIndex {
    /// Samples every triangle on a barycentric grid with spacing ≤ `spacing_mm`.
    pub fn new(mesh: &Mesh, spacing_mm: f64) -> Result<Self, RegisterError> {
        if !(spacing_mm.is_finite() && spacing_mm > 0.0) {
            return Err(RegisterError::Invalid(format!(
                "sample spacing must be > 0 mm, got {spacing_mm}"
            )));
        }
        let mut points = Vec::new();
        let mut normals = Vec::new();
        for k in 0..mesh.triangles.len() {
            let (n, area) = mesh.normal_area(k);
            if area <= 0.0 {
                continue;
            }
            let [a, b, c] = mesh.triangles[k].map(|i| mesh.vertices[i]);
            let longest = (b - a).norm().max((c - b).norm()).max((a - c).norm());
            let m = ((longest / spacing_mm).ceil() as usize).clamp(1, 200);
            for i in 0..=m {
                for j in 0..=(m - i) {
                    let (u, v) = (i as f64 / m as f64, j as f64 / m as f64);
                    points.push(a + (b - a) * u + (c - a) * v);
                    normals.push(n);
                }
            }
        }
        if points.is_empty() {
            return Err(RegisterError::Degenerate(
                "the mesh has no triangle with a non-zero area".into(),
            ));
        }
        let tree = RTree::bulk_load(
            points
                .iter()
                .enumerate()
                .map(|(i, p)| GeomWithData::new([p.x, p.y, p.z], i))
                .collect(),
        );
        Ok(SurfaceIndex {
            tree,
            points,
            normals,
        })
    }

    /// Nearest sample: (index, point, normal).
    pub fn nearest(&self, p: &Point3<f64>) -> (usize, Point3<f64>, Vector3<f64>) {
        let i = self
            .tree
            .nearest_neighbor(&[p.x, p.y, p.z])
            .map(|s| s.data)
            .unwrap_or(0);
        (i, self.points[i], self.normals[i])
    }

    /// Centroid of the samples.
    pub fn centroid(&self) -> Point3<f64> {
        Point3::from(
            self.points
                .iter()
                .fold(Vector3::zeros(), |s, p| s + p.coords)
                / self.points.len() as f64,
        )
    }
}

/// Point-to-plane problem with fixed correspondences: residual
/// `n_iᵀ (Exp(ω) R₀ x_i + t₀ + t − p_i)`.
pub struct PointToPlane<'a> {
    pub s0: Isometry3<f64>,
    pub x: &'a [Point3<f64>],
    pub p: &'a [Point3<f64>],
    pub n: &'a [Vector3<f64>],
}

impl LsqProblem for PointToPlane<'_> {
    fn n_params(&self) -> usize {
        6
    }
    fn residuals(&self, v: &DVector<f64>) -> DVector<f64> {
        let s = perturb(&self.s0, v.as_slice());
        DVector::from_iterator(
            self.x.len(),
            self.x
                .iter()
                .zip(self.p)
                .zip(self.n)
                .map(|((x, p), n)| n.dot(&(s * x - p))),
        )
    }
    fn residuals_jacobian(&self, v: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let w = Vector3::new(v[0], v[1], v[2]);
        let jl = so3_left_jacobian(&w);
        let rot = UnitQuaternion::from_scaled_axis(w) * self.s0.rotation;
        let mut j = DMatrix::zeros(self.x.len(), 6);
        for (i, x) in self.x.iter().enumerate() {
            let rx = rot * x.coords;
            let dw = (-skew(&rx) * jl).transpose() * self.n[i];
            for k in 0..3 {
                j[(i, k)] = dw[k];
                j[(i, 3 + k)] = self.n[i][k];
            }
        }
        (self.residuals(v), j)
    }
}

/// ICP options.
#[derive(Debug, Clone, Copy)]
pub struct IcpOptions {
    /// Fraction of points kept each iteration of the multi-start search (closest first); the
    /// final fit keeps every point within [`ROBUST_CUT`] robust σ of the surface.
    pub trim_fraction: f64,
    pub max_iter: usize,
    /// Mesh sample spacing (mm).
    pub sample_spacing_mm: f64,
    /// Start rotations about the point centroid added around the initial guess (deg).
    pub start_angles_deg: [f64; 2],
}

impl Default for IcpOptions {
    fn default() -> Self {
        IcpOptions {
            trim_fraction: 0.9,
            max_iter: 60,
            sample_spacing_mm: 1.0,
            start_angles_deg: [20.0, 40.0],
        }
    }
}

/// One point's residual at the end.
#[derive(Debug, Clone)]
pub struct IcpPointResidual {
    /// Closest mesh point (CT).
    pub ct: Point3<f64>,
    /// Signed point-to-plane distance (mm).
    pub distance_mm: f64,
    pub inlier: bool,
}

/// Result of a surface registration.
#[derive(Debug, Clone)]
pub struct IcpResult {
    pub t_tracker_ct: Isometry3<f64>,
    /// Covariance of the left perturbation `(ω, t)` of `T_tracker_ct` (rad, mm).
    pub cov: Matrix6<f64>,
    /// Inlier RMS point-to-plane distance (mm).
    pub rms_mm: f64,
    pub inliers: usize,
    pub iterations: usize,
    pub starts: usize,
    pub runner_up_rms_mm: Option<f64>,
    pub runner_up_angle_deg: Option<f64>,
    pub residuals: Vec<IcpPointResidual>,
}

struct Run {
    s: Isometry3<f64>,
    rms: f64,
    iters: usize,
}

fn trimmed_correspondences(
    idx: &SurfaceIndex,
    pts: &[Point3<f64>],
    s: &Isometry3<f64>,
    keep: usize,
) -> (Vec<usize>, Vec<Point3<f64>>, Vec<Vector3<f64>>, Vec<f64>) {
    let mut c: Vec<(usize, Point3<f64>, Vector3<f64>, f64)> = pts
        .iter()
        .enumerate()
        .map(|(i, x)| {
            let q = s * x;
            let (_, p, n) = idx.nearest(&q);
            (i, p, n, (q - p).norm_squared())
        })
        .collect();
    c.sort_by(|a, b| a.3.total_cmp(&b.3));
    c.truncate(keep);
    let mut ids = Vec::with_capacity(keep);
    let mut ps = Vec::with_capacity(keep);
    let mut ns = Vec::with_capacity(keep);
    let mut d = Vec::with_capacity(keep);
    for (i, p, n, d2) in c {
        ids.push(i);
        ps.push(p);
        ns.push(n);
        d.push(d2);
    }
    (ids, ps, ns, d)
}

fn run_icp(idx: &SurfaceIndex, pts: &[Point3<f64>], s0: Isometry3<f64>, o: &IcpOptions) -> Run {
    let keep = ((pts.len() as f64 * o.trim_fraction).ceil() as usize).clamp(6, pts.len());
    let mut s = s0;
    let mut iters = 0;
    let lmo = LmOptions {
        max_iter: 10,
        ..LmOptions::default()
    };
    for _ in 0..o.max_iter {
        iters += 1;
        let (ids, ps, ns, _) = trimmed_correspondences(idx, pts, &s, keep);
        let xs: Vec<Point3<f64>> = ids.iter().map(|&i| pts[i]).collect();
        let prob = PointToPlane {
            s0: s,
            x: &xs,
            p: &ps,
            n: &ns,
        };
        let rep = lm::minimize(&prob, DVector::zeros(6), &lmo);
        if !rep.termination.converged() && rep.termination != lm::Termination::MaxIterations {
            break;
        }
        let step_rot = Vector3::new(rep.x[0], rep.x[1], rep.x[2]).norm();
        // Translation step measured at the points' centroid.
        let c = xs.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / xs.len() as f64;
        let s_new = perturb(&s, rep.x.as_slice());
        let step_t = (s_new * Point3::from(c) - s * Point3::from(c)).norm();
        s = s_new;
        if step_rot < 1e-7 && step_t < 1e-5 {
            break;
        }
    }
    let (ids, ps, ns, _) = trimmed_correspondences(idx, pts, &s, keep);
    let rms = (ids
        .iter()
        .zip(ps.iter().zip(&ns))
        .map(|(&i, (p, n))| n.dot(&(s * pts[i] - p)).powi(2))
        .sum::<f64>()
        / keep as f64)
        .sqrt();
    Run { s, rms, iters }
}

/// Outlier cut of the final surface fit, in robust σ (1.4826 · median |distance|). Generous:
/// a stereo tracker's noise differs with the surface normal's angle to the line of sight, so
/// the distances are not one Gaussian; a gross outlier (a probe off the skin, a mis-touch) is
/// tens of σ away.
pub const ROBUST_CUT: f64 = 5.0;

/// How many points the final fit keeps at `s`: those within [`ROBUST_CUT`] robust σ of the
/// surface (at least 6, and at least half: a robust scale needs a majority of inliers).
fn robust_keep(idx: &SurfaceIndex, pts: &[Point3<f64>], s: &Isometry3<f64>) -> usize {
    let mut d: Vec<f64> = pts
        .iter()
        .map(|x| {
            let q = s * x;
            let (_, p, n) = idx.nearest(&q);
            n.dot(&(q - p)).abs()
        })
        .collect();
    d.sort_by(f64::total_cmp);
    let sigma = 1.4826 * d[d.len() / 2];
    let cut = ROBUST_CUT * sigma.max(1e-9);
    d.iter()
        .filter(|x| **x <= cut)
        .count()
        .max(pts.len().div_ceil(2))
        .clamp(6.min(pts.len()), pts.len())
}

/// Smallest eigenvalue of the normalised point-to-plane normal matrix, relative to the
/// largest, below which a registration is refused as sliding.
pub const MIN_CONSTRAINT_RATIO: f64 = 1e-3;

/// The weakest direction of the normal matrix `g` (columns scaled by `d`: rotations as
/// displacements at the lever arm; rows 0..3 rotation about the points' centroid, 3..6
/// translation, in the CT frame mapped by `r_ct_tracker`): its eigenvalue relative to the
/// largest, and the direction in words.
fn weakest_direction(
    g: &DMatrix<f64>,
    d: &[f64],
    r_ct_tracker: &UnitQuaternion<f64>,
) -> (f64, String) {
    let e = g.clone().symmetric_eigen();
    let (mut imin, mut imax) = (0, 0);
    for i in 0..e.eigenvalues.len() {
        if e.eigenvalues[i] < e.eigenvalues[imin] {
            imin = i;
        }
        if e.eigenvalues[i] > e.eigenvalues[imax] {
            imax = i;
        }
    }
    let ratio = (e.eigenvalues[imin] / e.eigenvalues[imax].max(1e-300)).max(0.0);
    let v: Vec<f64> = (0..6).map(|k| e.eigenvectors[(k, imin)] / d[k]).collect();
    // In the tracker frame (where the points were digitised): rotation / translation parts.
    let w = r_ct_tracker.inverse() * Vector3::new(v[0], v[1], v[2]);
    let t = r_ct_tracker.inverse() * Vector3::new(v[3], v[4], v[5]);
    // Compare a rotation with a translation at 100 mm lever arm.
    let words = if w.norm() * 100.0 > t.norm() {
        let a = w.normalize();
        format!(
            "rotation about the axis ({:.2}, {:.2}, {:.2}) through the points' centroid (tracker frame)",
            a.x, a.y, a.z
        )
    } else {
        let a = t.normalize();
        format!(
            "translation along ({:.2}, {:.2}, {:.2}) (tracker frame)",
            a.x, a.y, a.z
        )
    };
    (ratio, words)
}

/// Diagonal of the bounding box of `pts` (mm; 0 when empty or not finite).
fn extent(pts: &[Point3<f64>]) -> f64 {
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for p in pts {
        lo = lo.inf(&p.coords);
        hi = hi.sup(&p.coords);
    }
    let d = (hi - lo).norm();
    if d.is_finite() {
        d
    } else {
        0.0
    }
}

/// The digitised points lie on the surface, so they cannot span much more than the mesh: a
/// mesh 1000× smaller than the points is in metres (files use mm), and the reverse, points
/// spanning a thousandth of a mesh of anatomy, are.
pub fn check_units(mesh: &Mesh, pts: &[Point3<f64>]) -> Result<(), RegisterError> {
    let (m, p) = (extent(&mesh.vertices), extent(pts));
    if m > 0.0 && p > 10.0 * m {
        return Err(RegisterError::Invalid(format!(
            "the mesh spans {m:.4} (bounding-box diagonal) while the digitised surface points on \
             it span {p:.1} mm: the mesh looks like metres (an STL / PLY export in m); files use \
             mm: rescale the mesh by 1000"
        )));
    }
    if p > 0.0 && m > 10.0 && p < 0.002 * m {
        return Err(RegisterError::Invalid(format!(
            "the digitised surface points span {p:.4} while the mesh spans {m:.1} mm: the \
             points look like metres; files use mm"
        )));
    }
    Ok(())
}

/// Registers surface points `pts` (tracker frame) onto `mesh` (CT frame). `init` is a guess
/// of `T_tracker_ct`; without one, 24 axis-aligned orientations about the centroids are
/// tried (fine for whole-surface scans, a guess is needed for partial ones).
pub fn register_surface(
    mesh: &Mesh,
    pts: &[Point3<f64>],
    init: Option<&Isometry3<f64>>,
    o: &IcpOptions,
) -> Result<IcpResult, RegisterError> {
    check_units(mesh, pts)?;
    let idx = SurfaceIndex::new(mesh, o.sample_spacing_mm)?;
    register_surface_indexed(&idx, pts, init, o)
}

/// As [`register_surface`] with a prepared index (many registrations on one mesh).
pub fn register_surface_indexed(
    idx: &SurfaceIndex,
    pts: &[Point3<f64>],
    init: Option<&Isometry3<f64>>,
    o: &IcpOptions,
) -> Result<IcpResult, RegisterError> {
    if pts.len() < 6 {
        return Err(RegisterError::Degenerate(format!(
            "{} surface points; ICP needs at least 6 (use 50+ spread over distinctive anatomy)",
            pts.len()
        )));
    }
    if let Some(p) = pts.iter().find(|p| !p.coords.iter().all(|x| x.is_finite())) {
        return Err(RegisterError::Invalid(format!(
            "non-finite surface point {p:?}"
        )));
    }
    if !(0.3..=1.0).contains(&o.trim_fraction) {
        return Err(RegisterError::Invalid(format!(
            "trim fraction must be in [0.3, 1], got {}",
            o.trim_fraction
        )));
    }
    super::paired::check_layout(pts, "surface points")?;
    let c = Point3::from(pts.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / pts.len() as f64);
    // Start set, as S = T_ct_tracker.
    let mut starts: Vec<Isometry3<f64>> = Vec::new();
    let about_centroid = |s: &Isometry3<f64>, r: UnitQuaternion<f64>| -> Isometry3<f64> {
        // Rotate the mapped points about their centroid: S' = Tr(Sc) R Tr(-Sc) S.
        let sc = s * c;
        Isometry3::from_parts(Translation3::from(sc.coords), r)
            * Isometry3::from_parts(Translation3::from(-sc.coords), UnitQuaternion::identity())
            * s
    };
    match init {
        Some(t) => {
            let s0 = t.inverse();
            starts.push(s0);
            let mut axes: Vec<Vector3<f64>> = vec![Vector3::x(), Vector3::y(), Vector3::z()];
            for sx in [-1.0, 1.0] {
                for sy in [-1.0, 1.0] {
                    for sz in [-1.0, 1.0] {
                        axes.push(Vector3::new(sx, sy, sz).normalize());
                    }
                }
            }
            for ang in o.start_angles_deg {
                for (k, a) in axes.iter().enumerate() {
                    if k >= 3 && ang > o.start_angles_deg[0] {
                        continue;
                    }
                    for sgn in [-1.0, 1.0] {
                        if k >= 3 && sgn < 0.0 {
                            continue;
                        }
                        starts.push(about_centroid(
                            &s0,
                            UnitQuaternion::from_scaled_axis(a * (sgn * ang.to_radians())),
                        ));
                    }
                }
            }
        }
        None => {
            let mc = idx.centroid();
            for r in cube_rotations() {
                let s = Isometry3::from_parts(Translation3::from(mc.coords - r * c.coords), r);
                starts.push(s);
            }
        }
    }
    let runs: Vec<Run> = {
        use rayon::prelude::*;
        starts
            .par_iter()
            .map(|s| run_icp(idx, pts, *s, o))
            .collect()
    };
    let best = runs
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.rms.total_cmp(&b.1.rms))
        .map(|(i, _)| i)
        .ok_or_else(|| RegisterError::Solver("no ICP start".into()))?;
    let bs = runs[best].s;
    let runner = runs
        .iter()
        .filter(|r| {
            r.s.rotation.angle_to(&bs.rotation).to_degrees() > 2.0
                || (r.s * c - bs * c).norm() > 2.0
        })
        .min_by(|a, b| a.rms.total_cmp(&b.rms));
    // The trimmed search found the pose; the final fit drops only what the data show to be
    // outliers (point-to-plane distance beyond ROBUST_CUT robust σ), so a clean surface keeps
    // every point instead of a fixed fraction.
    // `trim_fraction = 1` is the user's "keep every point".
    let robust = |s: &Isometry3<f64>| {
        if o.trim_fraction >= 1.0 {
            pts.len()
        } else {
            robust_keep(idx, pts, s)
        }
    };
    let keep = robust(&bs);
    let refined = run_icp(
        idx,
        pts,
        bs,
        &IcpOptions {
            trim_fraction: keep as f64 / pts.len() as f64,
            ..*o
        },
    );
    let bs = refined.s;
    let keep = robust(&bs).max(keep);
    let (ids, ps, ns, _) = trimmed_correspondences(idx, pts, &bs, keep);
    let xs: Vec<Point3<f64>> = ids.iter().map(|&i| pts[i]).collect();
    let prob = PointToPlane {
        s0: bs,
        x: &xs,
        p: &ps,
        n: &ns,
    };
    let (r_final, j) = prob.residuals_jacobian(&DVector::zeros(6));
    let rms = (r_final.norm_squared() / keep as f64).sqrt();
    let dof = (keep as f64 - 6.0).max(1.0);
    let s2 = rms * rms * keep as f64 / dof;
    let jtj = j.transpose() * &j;
    // Degeneracy in a well-conditioned frame: rotations about the mapped centroid, columns
    // normalised (a sphere or plane patch leaves a null direction).
    let sc = bs * c;
    let mut jc = DMatrix::zeros(xs.len(), 6);
    for (i, x) in xs.iter().enumerate() {
        let dw = (bs * x - sc).cross(&ns[i]);
        for k in 0..3 {
            jc[(i, k)] = dw[k];
            jc[(i, 3 + k)] = ns[i][k];
        }
    }
    // Rotations as displacements at the points' RMS lever arm `l` (mm), so a weak direction
    // is one that moves the points little against the surface, rotation or translation.
    let l = (xs.iter().map(|x| (bs * x - sc).norm_squared()).sum::<f64>() / xs.len() as f64)
        .sqrt()
        .max(1e-9);
    let lever = [l, l, l, 1.0, 1.0, 1.0];
    let mut gl = jc.transpose() * &jc;
    for a in 0..6 {
        for b in 0..6 {
            gl[(a, b)] /= lever[a] * lever[b];
        }
    }
    let mut g = jc.transpose() * &jc;
    let d: Vec<f64> = (0..6).map(|k| g[(k, k)].max(1e-300).sqrt()).collect();
    for a in 0..6 {
        for b in 0..6 {
            g[(a, b)] /= d[a] * d[b];
        }
    }
    // The weakest direction relative to the strongest (in the normalised frame): a surface
    // that slides exactly gives 0, one that nearly slides (a shallow feature on a plane, a
    // nearly cylindrical patch) a small ratio: its fit along that direction is noise.
    let (ratio, weakest) = weakest_direction(&gl, &lever, &bs.rotation);
    let well_posed = ratio >= MIN_CONSTRAINT_RATIO && g.symmetric_eigenvalues().min() > 1e-8;
    let cov_s = jtj
        .clone()
        .try_inverse()
        .filter(|m| m.iter().all(|x| x.is_finite()) && well_posed)
        .ok_or_else(|| {
            RegisterError::Degenerate(format!(
                "the surface points do not constrain all 6 degrees of freedom: the surface can \
                 slide by {weakest} (its constraint is {ratio:.1e} of the strongest, need ≥ \
                 {MIN_CONSTRAINT_RATIO:.0e}; a plane, sphere or cylinder patch, or one shallow \
                 feature): digitise more distinctive anatomy"
            ))
        })?
        * s2;
    let cov_s = Matrix6::from_iterator(cov_s.iter().copied());
    let t = bs.inverse();
    let cov = invert_covariance(&bs, &cov_s);
    let inlier: std::collections::HashSet<usize> = ids.iter().copied().collect();
    let residuals = pts
        .iter()
        .enumerate()
        .map(|(i, x)| {
            let q = bs * x;
            let (_, p, n) = idx.nearest(&q);
            IcpPointResidual {
                ct: p,
                distance_mm: n.dot(&(q - p)),
                inlier: inlier.contains(&i),
            }
        })
        .collect();
    Ok(IcpResult {
        t_tracker_ct: t,
        cov,
        rms_mm: rms,
        inliers: keep,
        iterations: runs[best].iters,
        starts: starts.len(),
        runner_up_rms_mm: runner.map(|r| r.rms),
        runner_up_angle_deg: runner.map(|r| r.s.rotation.angle_to(&bs.rotation).to_degrees()),
        residuals,
    })
}

/// Covariance of the left perturbation of `S⁻¹` from that of `S` (linear map by central
/// differences of the exact inverse).
pub fn invert_covariance(s: &Isometry3<f64>, cov_s: &Matrix6<f64>) -> Matrix6<f64> {
    let t = s.inverse();
    let h = 1e-6;
    let mut g = Matrix6::zeros();
    for k in 0..6 {
        let mut dp = [0.0; 6];
        dp[k] = h;
        let mut dm = [0.0; 6];
        dm[k] = -h;
        let tp = perturb(s, &dp).inverse();
        let tm = perturb(s, &dm).inverse();
        let d = |ti: &Isometry3<f64>| -> Vector6<f64> {
            let w = (ti.rotation * t.rotation.inverse()).scaled_axis();
            let dt = ti.translation.vector - t.translation.vector;
            Vector6::new(w.x, w.y, w.z, dt.x, dt.y, dt.z)
        };
        g.set_column(k, &((d(&tp) - d(&tm)) / (2.0 * h)));
    }
    g * cov_s * g.transpose()
}

/// The 24 rotations of the cube.
fn cube_rotations() -> Vec<UnitQuaternion<f64>> {
    let mut out: Vec<UnitQuaternion<f64>> = Vec::new();
    let axes: [Vector3<f64>; 6] = [
        Vector3::x(),
        Vector3::y(),
        Vector3::z(),
        -Vector3::x(),
        -Vector3::y(),
        -Vector3::z(),
    ];
    for a in axes {
        for b in axes {
            if a.dot(&b).abs() > 0.5 {
                continue;
            }
            let c = a.cross(&b);
            let m = nalgebra::Matrix3::from_columns(&[a, b, c]);
            let q = UnitQuaternion::from_matrix(&m);
            if !out.iter().any(|o| o.angle_to(&q) < 1e-6) {
                out.push(q);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_to_plane_jacobian_matches_fd() {
        let x = vec![
            Point3::new(10.0, 20.0, -5.0),
            Point3::new(-30.0, 5.0, 40.0),
            Point3::new(7.0, -9.0, 2.0),
        ];
        let p = vec![Point3::new(1.0, 2.0, 3.0); 3];
        let n = vec![
            Vector3::new(0.0, 0.6, 0.8),
            Vector3::x(),
            Vector3::new(0.48, 0.6, 0.64),
        ];
        let prob = PointToPlane {
            s0: Isometry3::new(Vector3::new(5.0, -3.0, 100.0), Vector3::new(0.4, -0.2, 1.1)),
            x: &x,
            p: &p,
            n: &n,
        };
        let v = DVector::from_vec(vec![0.05, 0.1, -0.2, 1.0, -2.0, 0.5]);
        let (_, ja) = prob.residuals_jacobian(&v);
        let jn = lm::numeric_jacobian(|v| prob.residuals(v), &v, 1e-6);
        assert!((&ja - &jn).norm() / ja.norm() < 1e-7);
    }

    /// A 200 mm cube (12 triangles).
    fn cube() -> Mesh {
        let mut vertices = Vec::new();
        for &x in &[0.0, 200.0] {
            for &y in &[0.0, 200.0] {
                for &z in &[0.0, 200.0] {
                    vertices.push(Point3::new(x, y, z));
                }
            }
        }
        let v = |x: usize, y: usize, z: usize| x * 4 + y * 2 + z;
        let quad = |a, b, c, d| [[a, b, c], [a, c, d]];
        let mut triangles = Vec::new();
        for t in [
            quad(v(0, 0, 0), v(0, 1, 0), v(1, 1, 0), v(1, 0, 0)),
            quad(v(0, 0, 1), v(1, 0, 1), v(1, 1, 1), v(0, 1, 1)),
            quad(v(0, 0, 0), v(1, 0, 0), v(1, 0, 1), v(0, 0, 1)),
            quad(v(0, 1, 0), v(0, 1, 1), v(1, 1, 1), v(1, 1, 0)),
            quad(v(0, 0, 0), v(0, 0, 1), v(0, 1, 1), v(0, 1, 0)),
            quad(v(1, 0, 0), v(1, 1, 0), v(1, 1, 1), v(1, 0, 1)),
        ] {
            triangles.extend(t);
        }
        Mesh {
            vertices,
            triangles,
        }
    }

    #[test]
    fn points_on_one_face_are_refused_as_sliding() {
        // 60 points on the top face (z = 200) of a cube: they fix z and two tilts, nothing else.
        let pts: Vec<Point3<f64>> = (0..60)
            .map(|i| {
                let (a, b) = ((i % 8) as f64, (i / 8) as f64);
                Point3::new(20.0 + 20.0 * a, 15.0 + 22.0 * b, 200.0)
            })
            .collect();
        let init = Isometry3::translation(3.0, -2.0, 1.0);
        let e = register_surface(&cube(), &pts, Some(&init), &IcpOptions::default()).unwrap_err();
        assert!(e.to_string().contains("do not constrain"), "{e}");
    }

    /// A 160 mm square grid surface `z = f(x, y)` (mm).
    fn grid(f: impl Fn(f64, f64) -> f64) -> Mesh {
        let n = 40;
        let h = 160.0 / n as f64;
        let mut vertices = Vec::new();
        for i in 0..=n {
            for k in 0..=n {
                let (x, y) = (-80.0 + i as f64 * h, -80.0 + k as f64 * h);
                vertices.push(Point3::new(x, y, f(x, y)));
            }
        }
        let v = |i: usize, k: usize| i * (n + 1) + k;
        let mut triangles = Vec::new();
        for i in 0..n {
            for k in 0..n {
                triangles.push([v(i, k), v(i + 1, k), v(i + 1, k + 1)]);
                triangles.push([v(i, k), v(i + 1, k + 1), v(i, k + 1)]);
            }
        }
        Mesh {
            vertices,
            triangles,
        }
    }

    fn points_on(f: impl Fn(f64, f64) -> f64) -> Vec<Point3<f64>> {
        (0..100)
            .map(|i| {
                let (x, y) = (
                    -60.0 + 12.0 * (i % 10) as f64,
                    -60.0 + 12.0 * (i / 10) as f64,
                );
                Point3::new(x, y, f(x, y))
            })
            .collect()
    }

    #[test]
    fn a_nearly_sliding_surface_is_refused_naming_the_direction() {
        // A plane with one 0.5 mm bump: every point constrains z and the tilts, the bump's
        // gentle slopes hardly fix x, y and the rotation about z.
        let f = |x: f64, y: f64| 0.5 * (-(x * x + y * y) / 800.0).exp();
        let init = Isometry3::translation(0.5, -0.3, 0.2);
        let e = register_surface(&grid(f), &points_on(f), Some(&init), &IcpOptions::default())
            .unwrap_err();
        let m = e.to_string();
        assert!(
            m.contains("slide by") && m.contains("of the strongest"),
            "{m}"
        );
        // A distinctive surface (two bumps and a ridge) is accepted.
        let g = |x: f64, y: f64| {
            25.0 * (-((x - 30.0).powi(2) + (y - 20.0).powi(2)) / 600.0).exp()
                + 15.0 * (-((x + 35.0).powi(2) + (y + 25.0).powi(2)) / 300.0).exp()
                + 0.08 * x
        };
        let r =
            register_surface(&grid(g), &points_on(g), Some(&init), &IcpOptions::default()).unwrap();
        assert!(
            r.t_tracker_ct.translation.vector.norm() < 0.05,
            "{:?}",
            r.t_tracker_ct
        );
    }

    #[test]
    fn a_mesh_in_metres_is_refused() {
        let g = |x: f64, y: f64| 20.0 * (-((x - 30.0).powi(2) + y * y) / 600.0).exp() + 0.1 * x;
        let mut m = grid(g);
        for v in &mut m.vertices {
            v.coords /= 1000.0;
        }
        let e = register_surface(&m, &points_on(g), None, &IcpOptions::default()).unwrap_err();
        assert!(e.to_string().contains("metres"), "{e}");
    }

    #[test]
    fn cube_group_has_24() {
        assert_eq!(cube_rotations().len(), 24);
    }
}
