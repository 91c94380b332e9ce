//! The arm's wrist orientation from the laser's own data (the beam is the longer lever).
//!
//! A laser on the flange is a long lever: a flange orientation error of 0.05° moves a spot
//! 250–750 mm away by 0.2–0.7 mm, while the tracker's marker, ~110 mm from the flange, sees
//! the same error as a tenth of a millimetre. The kinematic calibration of the same visit
//! therefore leaves the arm's orientation parameters with standard deviations that are small
//! for the marker but large for the beam: the beam alone is right (0.05 mm from the true beam
//! with an exact arm) yet the five-direction spread stays at the arm's orientation error.
//!
//! The fix is a joint maximum-a-posteriori fit: the arm's free joint parameters (prior = the
//! kinematic calibration's values and standard deviations), the beam, the calibration planes
//! and one unknown point per *selection* target (the five directions of a target must agree),
//! minimising
//!
//! `Σ (n_k·x_i + c_k)² / σ² + Σ |x_j − p_t|² / σ² + Σ (θ − θ₀)² / σ_θ²`
//!
//! with `x = F(θ, q) (r + d v)` the spot through the arm. [`Identifiability`] gives the
//! evidence: the singular values of the laser rows of the Jacobian with the arm parameters
//! scaled by their prior σ (a singular value above 1 = a direction the laser data pins
//! better than the kinematic calibration did), for the planes alone and with the targets.
//! Never reads the world's truth: the prior is the calibration file, the data the ranges.
use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector, Isometry3, Point3, Unit, Vector3};

use super::{Beam, IdentifiedArm, LaserError, LaserObs, Plane};
use crate::dataset::{CalParam, CalibrationFile, Dataset};
use crate::model::{ParamGroup, Unit as ParamUnit};
use crate::solve::lm::{minimize, LmOptions, LsqProblem};
use crate::solve::obs::PoseCtx;

/// Prior σ of an arm parameter the calibration file gives no σ for (mm / deg).
pub const DEFAULT_PRIOR_MM: f64 = 0.5;
pub const DEFAULT_PRIOR_DEG: f64 = 0.2;
/// Weight of the unit-norm rows (`|v| = 1`, `|n_k| = 1`).
const NORM_WEIGHT: f64 = 1e4;

/// One laser observation with the joints it was taken at.
#[derive(Debug, Clone)]
pub struct ArmObs {
    pub ctx: PoseCtx,
    pub obs: LaserObs,
}

/// Laser observations of `ds` with their joint contexts (records without usable joints or
/// without a range are skipped).
pub fn arm_observations(ds: &Dataset, arm: &IdentifiedArm) -> Result<Vec<ArmObs>, LaserError> {
    let recs: Vec<&crate::dataset::PoseRecord> = ds.poses().collect();
    let ctx: BTreeMap<u64, PoseCtx> = crate::solve::obs::contexts(&recs, arm.model.dof())
        .into_iter()
        .map(|(_, c)| (c.id, c))
        .collect();
    Ok(super::observations_through(ds, Some(arm))?
        .into_iter()
        .filter_map(|o| {
            ctx.get(&o.id).map(|c| ArmObs {
                ctx: c.clone(),
                obs: o,
            })
        })
        .collect())
}

/// Options of [`refine`].
#[derive(Debug, Clone)]
pub struct RefineOptions {
    /// Multiplies every prior σ (1 = the calibration file's σ).
    pub prior_scale: f64,
    /// Floor of the laser point σ (mm); the σ used is the start fit's plane RMS, floored.
    pub min_sigma_mm: f64,
}

impl Default for RefineOptions {
    fn default() -> Self {
        RefineOptions {
            prior_scale: 1.0,
            min_sigma_mm: 0.02,
        }
    }
}

/// Singular values of the laser rows of the Jacobian (arm columns scaled by their prior σ,
/// the other columns by the laser σ): how many arm directions the data pins.
#[derive(Debug, Clone, PartialEq)]
pub struct Identifiability {
    /// Arm parameters refined (names).
    pub arm_params: Vec<String>,
    /// Planes only: the singular values of the arm block after projecting out the beam and
    /// planes (descending), and how many exceed 1.
    pub planes_sv: Vec<f64>,
    pub planes_pinned: usize,
    /// Planes + selection targets.
    pub with_targets_sv: Vec<f64>,
    pub with_targets_pinned: usize,
}

/// Result of [`refine`].
#[derive(Debug, Clone)]
pub struct Refined {
    pub arm: IdentifiedArm,
    pub beam: Beam,
    pub planes: Vec<(String, Plane)>,
    /// Arm parameters and their change (name, internal unit: mm or rad, Δ).
    pub changes: Vec<(String, ParamUnit, f64)>,
    /// Point-to-plane RMS (mm) before / after; selection spread (mean, mm) before / after.
    pub plane_rms_before_mm: f64,
    pub plane_rms_after_mm: f64,
    pub selection_spread_before_mm: f64,
    pub selection_spread_after_mm: f64,
    pub sigma_mm: f64,
    pub identifiability: Identifiability,
    pub termination: String,
}

struct Problem<'a> {
    arm: &'a IdentifiedArm,
    /// Indices (into `params()`) of the refined arm parameters.
    idx: Vec<usize>,
    theta0: DVector<f64>,
    prior_sd: DVector<f64>,
    /// Plane observations per plane, target observations per target.
    planes: Vec<Vec<&'a ArmObs>>,
    targets: Vec<Vec<&'a ArmObs>>,
    sigma: f64,
}

impl Problem<'_> {
    fn na(&self) -> usize {
        self.idx.len()
    }
    fn n_params(&self) -> usize {
        self.na() + 6 + 4 * self.planes.len() + 3 * self.targets.len()
    }
    fn arm_at(&self, theta: &[f64]) -> IdentifiedArm {
        let mut a = self.arm.clone();
        let mut v = a.model.param_values();
        for (k, &i) in self.idx.iter().enumerate() {
            v[i] = theta[k];
        }
        a.model.set_param_values(&v);
        a
    }
    fn all_obs(&self) -> impl Iterator<Item = &ArmObs> {
        self.planes
            .iter()
            .flatten()
            .chain(self.targets.iter().flatten())
            .copied()
    }
    fn flanges(&self, theta: &[f64]) -> Vec<Isometry3<f64>> {
        let a = self.arm_at(theta);
        self.all_obs().map(|o| a.flange(&o.ctx)).collect()
    }
    fn laser_rows(&self) -> usize {
        self.planes.iter().map(|p| p.len()).sum::<usize>()
            + 3 * self.targets.iter().map(|t| t.len()).sum::<usize>()
    }
    /// Laser rows (scaled by 1/σ) at flanges `f` and the non-arm unknowns `x` (full vector).
    fn laser_residuals(&self, f: &[Isometry3<f64>], x: &DVector<f64>) -> DVector<f64> {
        let na = self.na();
        let r: Vector3<f64> = x.fixed_rows::<3>(na).into_owned();
        let v: Vector3<f64> = x.fixed_rows::<3>(na + 3).into_owned();
        let mut out = DVector::zeros(self.laser_rows());
        let (mut row, mut k_obs) = (0, 0);
        for (k, pts) in self.planes.iter().enumerate() {
            let n: Vector3<f64> = x.fixed_rows::<3>(na + 6 + 4 * k).into_owned();
            let c = x[na + 9 + 4 * k];
            for o in pts {
                let s = f[k_obs] * Point3::from(r + v * o.obs.d);
                out[row] = (n.dot(&s.coords) + c) / self.sigma;
                row += 1;
                k_obs += 1;
            }
        }
        let t0 = na + 6 + 4 * self.planes.len();
        for (t, pts) in self.targets.iter().enumerate() {
            let p: Vector3<f64> = x.fixed_rows::<3>(t0 + 3 * t).into_owned();
            for o in pts {
                let s = f[k_obs] * Point3::from(r + v * o.obs.d);
                let e = (s.coords - p) / self.sigma;
                out.rows_mut(row, 3).copy_from(&e);
                row += 3;
                k_obs += 1;
            }
        }
        out
    }
    /// The laser rows' Jacobian (numeric in the arm, forward differences; the rest analytic
    /// by the same differences: the rows are linear or bilinear in them).
    fn laser_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let na = self.na();
        let theta: Vec<f64> = x.rows(0, na).iter().copied().collect();
        let f0 = self.flanges(&theta);
        let r0 = self.laser_residuals(&f0, x);
        let mut j = DMatrix::zeros(r0.len(), self.n_params());
        for k in 0..self.n_params() {
            let h = if k < na {
                match self.arm.model.params()[self.idx[k]].unit {
                    ParamUnit::Mm => 1e-5,
                    ParamUnit::Rad => 1e-8,
                }
            } else {
                1e-6
            };
            let mut xp = x.clone();
            xp[k] += h;
            let rp = if k < na {
                let mut th = theta.clone();
                th[k] += h;
                self.laser_residuals(&self.flanges(&th), &xp)
            } else {
                self.laser_residuals(&f0, &xp)
            };
            j.set_column(k, &((rp - &r0) / h));
        }
        (r0, j)
    }
}

impl LsqProblem for Problem<'_> {
    fn n_params(&self) -> usize {
        Problem::n_params(self)
    }
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        let na = self.na();
        let theta: Vec<f64> = x.rows(0, na).iter().copied().collect();
        let l = self.laser_residuals(&self.flanges(&theta), x);
        let mut out = DVector::zeros(l.len() + na + 1 + self.planes.len());
        out.rows_mut(0, l.len()).copy_from(&l);
        for k in 0..na {
            out[l.len() + k] = (x[k] - self.theta0[k]) / self.prior_sd[k];
        }
        let v: Vector3<f64> = x.fixed_rows::<3>(na + 3).into_owned();
        out[l.len() + na] = NORM_WEIGHT * (v.norm_squared() - 1.0);
        for k in 0..self.planes.len() {
            let n: Vector3<f64> = x.fixed_rows::<3>(na + 6 + 4 * k).into_owned();
            out[l.len() + na + 1 + k] = NORM_WEIGHT * (n.norm_squared() - 1.0);
        }
        out
    }
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let na = self.na();
        let (_, jl) = self.laser_jacobian(x);
        let r = self.residuals(x);
        let m = r.len();
        let mut j = DMatrix::zeros(m, self.n_params());
        j.rows_mut(0, jl.nrows()).copy_from(&jl);
        let l = jl.nrows();
        for k in 0..na {
            j[(l + k, k)] = 1.0 / self.prior_sd[k];
        }
        for c in 0..3 {
            j[(l + na, na + 3 + c)] = NORM_WEIGHT * 2.0 * x[na + 3 + c];
        }
        for k in 0..self.planes.len() {
            for c in 0..3 {
                let col = na + 6 + 4 * k + c;
                j[(l + na + 1 + k, col)] = NORM_WEIGHT * 2.0 * x[col];
            }
        }
        (r, j)
    }
}

/// The σ of each refined arm parameter (internal units) from the calibration file: its `std`
/// times `scale`, else the defaults.
fn prior_sd(cal: &CalibrationFile, name: &str, unit: ParamUnit, scale: f64) -> f64 {
    let from_file = cal
        .params
        .iter()
        .find(|p: &&CalParam| p.name == name)
        .and_then(|p| p.std.map(|s| (s, p.unit.trim().to_ascii_lowercase())))
        .and_then(|(s, u)| match (unit, u.as_str()) {
            (ParamUnit::Mm, "mm") => Some(s),
            (ParamUnit::Mm, "m") => Some(s * 1000.0),
            (ParamUnit::Rad, "deg" | "degree" | "degrees") => Some(s.to_radians()),
            (ParamUnit::Rad, "rad" | "radian" | "radians") => Some(s),
            _ => None,
        })
        .filter(|s| s.is_finite() && *s > 0.0);
    let d = match unit {
        ParamUnit::Mm => DEFAULT_PRIOR_MM,
        ParamUnit::Rad => DEFAULT_PRIOR_DEG.to_radians(),
    };
    // A bootstrap σ far below what a marker can see is not a prior to trust at the beam's
    // range: floor it at a tenth of the default.
    (from_file.unwrap_or(d) * scale).max(0.1 * d * scale)
}

/// Singular values (descending) of the arm block of `j` after projecting out the other
/// columns (the beam, planes and target points are nuisance unknowns).
fn arm_block_sv(j: &DMatrix<f64>, na: usize) -> Vec<f64> {
    let a = j.columns(0, na).into_owned();
    let b = j.columns(na, j.ncols() - na).into_owned();
    let proj = match nalgebra::SVD::try_new(b.clone(), true, false, 1e-12, 1000) {
        Some(svd) => {
            let u = svd.u.expect("u requested");
            let smax = svd.singular_values.max();
            let keep: Vec<usize> = (0..svd.singular_values.len())
                .filter(|&i| svd.singular_values[i] > smax * 1e-10)
                .collect();
            let uk = DMatrix::from_fn(u.nrows(), keep.len(), |r, c| u[(r, keep[c])]);
            &a - &uk * (uk.transpose() * &a)
        }
        None => a,
    };
    let mut sv: Vec<f64> = nalgebra::SVD::try_new(proj, false, false, 1e-12, 1000)
        .map(|s| s.singular_values.iter().copied().collect())
        .unwrap_or_default();
    sv.sort_by(|a, b| b.total_cmp(a));
    sv
}

fn plane_rms(
    planes: &[(String, Plane)],
    beam: &Beam,
    obs: &[Vec<&ArmObs>],
    arm: &IdentifiedArm,
) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for ((_, p), pts) in planes.iter().zip(obs) {
        for o in pts {
            let e = p.distance(&beam.spot(&arm.flange(&o.ctx), o.obs.d));
            s += e * e;
            n += 1;
        }
    }
    (s / n.max(1) as f64).sqrt()
}

fn mean_spread(beam: &Beam, targets: &[Vec<&ArmObs>], arm: &IdentifiedArm) -> f64 {
    let by: BTreeMap<String, Vec<LaserObs>> = targets
        .iter()
        .enumerate()
        .map(|(k, t)| {
            (
                k.to_string(),
                t.iter()
                    .map(|o| LaserObs {
                        flange: arm.flange(&o.ctx),
                        ..o.obs.clone()
                    })
                    .collect(),
            )
        })
        .collect();
    let s = super::five_direction_spread(beam, &by);
    s.iter().map(|x| x.1).sum::<f64>() / s.len().max(1) as f64
}

/// Refines the arm's free joint parameters jointly with the beam, the planes and the
/// selection targets' points (see the module docs). `train` are the planes' observations
/// (labelled `plane`; `outliers` ids are left out), `selection` the selection targets'
/// (labelled `target`), `cal` the arm's calibration file (the prior's σ), `start` the beam
/// and planes of the fit through the unrefined arm.
pub fn refine(
    arm: &IdentifiedArm,
    cal: &CalibrationFile,
    train: &[ArmObs],
    selection: &[ArmObs],
    outliers: &[u64],
    start: (&Beam, &[(String, Plane)]),
    opts: &RefineOptions,
) -> Result<Refined, LaserError> {
    let (beam0, planes0) = start;
    let planes: Vec<Vec<&ArmObs>> = planes0
        .iter()
        .map(|(name, _)| {
            train
                .iter()
                .filter(|o| o.obs.plane.as_deref() == Some(name) && !outliers.contains(&o.obs.id))
                .collect()
        })
        .collect();
    let mut by_t: BTreeMap<&str, Vec<&ArmObs>> = BTreeMap::new();
    for o in selection {
        if let Some(t) = o.obs.target.as_deref() {
            by_t.entry(t).or_default().push(o);
        }
    }
    let targets: Vec<Vec<&ArmObs>> = by_t.into_values().filter(|v| v.len() >= 3).collect();
    let idx: Vec<usize> = arm
        .model
        .free_indices()
        .into_iter()
        .filter(|&i| matches!(arm.model.params()[i].group, ParamGroup::Joint(_)))
        .collect();
    if idx.is_empty() {
        return Err(LaserError::Calibration(
            "the arm calibration has no free joint parameter to refine".into(),
        ));
    }
    let npts: usize = planes.iter().map(|p| p.len()).sum();
    if npts < 6 + 3 * planes.len() {
        return Err(LaserError::TooFewData {
            what: "arm refinement (plane points)".into(),
            need: 6 + 3 * planes.len(),
            got: npts,
        });
    }
    let pv = arm.model.param_values();
    let theta0 = DVector::from_iterator(idx.len(), idx.iter().map(|&i| pv[i]));
    let prior = DVector::from_iterator(
        idx.len(),
        idx.iter().map(|&i| {
            let p = &arm.model.params()[i];
            prior_sd(cal, &p.name, p.unit, opts.prior_scale)
        }),
    );
    let rms0 = plane_rms(planes0, beam0, &planes, arm);
    let sigma = rms0.max(opts.min_sigma_mm);
    let spread0 = mean_spread(beam0, &targets, arm);
    let mut prob = Problem {
        arm,
        idx,
        theta0: theta0.clone(),
        prior_sd: prior,
        planes,
        targets: Vec::new(),
        sigma,
    };
    // Start: the arm as calibrated, the start beam and planes, each target's mean spot.
    let na = prob.na();
    let mut x = DVector::zeros(na + 6 + 4 * planes0.len());
    x.rows_mut(0, na).copy_from(&theta0);
    x.fixed_rows_mut::<3>(na).copy_from(&beam0.r);
    x.fixed_rows_mut::<3>(na + 3)
        .copy_from(&beam0.v.into_inner());
    for (k, (_, p)) in planes0.iter().enumerate() {
        x.fixed_rows_mut::<3>(na + 6 + 4 * k)
            .copy_from(&p.n.into_inner());
        x[na + 9 + 4 * k] = p.c;
    }
    // Identifiability of the arm with the planes alone, then with the targets.
    let scale = |j: &mut DMatrix<f64>, p: &Problem| {
        for k in 0..p.na() {
            let s = p.prior_sd[k];
            j.column_mut(k).scale_mut(s);
        }
    };
    let (_, mut jp) = prob.laser_jacobian(&x);
    scale(&mut jp, &prob);
    let planes_sv = arm_block_sv(&jp, na);
    prob.targets = targets;
    let mut xt = x.clone().resize_vertically(prob.n_params(), 0.0);
    let t0 = na + 6 + 4 * planes0.len();
    for (t, pts) in prob.targets.iter().enumerate() {
        let c = pts
            .iter()
            .map(|o| beam0.spot(&arm.flange(&o.ctx), o.obs.d).coords)
            .sum::<Vector3<f64>>()
            / pts.len() as f64;
        xt.fixed_rows_mut::<3>(t0 + 3 * t).copy_from(&c);
    }
    let (_, mut jt) = prob.laser_jacobian(&xt);
    scale(&mut jt, &prob);
    let with_targets_sv = arm_block_sv(&jt, na);
    let rep = minimize(&prob, xt, &LmOptions::default());
    if !rep.termination.converged() || !rep.x.iter().all(|v| v.is_finite()) {
        return Err(LaserError::Degenerate(format!(
            "arm refinement: {}",
            rep.termination.describe()
        )));
    }
    let xr = &rep.x;
    let theta: Vec<f64> = xr.rows(0, na).iter().copied().collect();
    let refined = prob.arm_at(&theta);
    let beam = Beam {
        r: xr.fixed_rows::<3>(na).into_owned(),
        v: Unit::new_normalize(xr.fixed_rows::<3>(na + 3).into_owned()),
    };
    let planes: Vec<(String, Plane)> = planes0
        .iter()
        .enumerate()
        .map(|(k, (name, _))| {
            let n: Vector3<f64> = xr.fixed_rows::<3>(na + 6 + 4 * k).into_owned();
            let norm = n.norm();
            (
                name.clone(),
                Plane {
                    n: Unit::new_normalize(n),
                    c: xr[na + 9 + 4 * k] / norm,
                },
            )
        })
        .collect();
    let changes = prob
        .idx
        .iter()
        .enumerate()
        .map(|(k, &i)| {
            let p = &arm.model.params()[i];
            (p.name.clone(), p.unit, theta[k] - theta0[k])
        })
        .collect();
    let pinned = |sv: &[f64]| sv.iter().filter(|s| **s > 1.0).count();
    let names = prob
        .idx
        .iter()
        .map(|&i| arm.model.params()[i].name.clone())
        .collect();
    Ok(Refined {
        plane_rms_before_mm: rms0,
        plane_rms_after_mm: plane_rms(&planes, &beam, &prob.planes, &refined),
        selection_spread_before_mm: spread0,
        selection_spread_after_mm: mean_spread(&beam, &prob.targets, &refined),
        sigma_mm: sigma,
        identifiability: Identifiability {
            arm_params: names,
            planes_pinned: pinned(&planes_sv),
            planes_sv,
            with_targets_pinned: pinned(&with_targets_sv),
            with_targets_sv,
        },
        termination: rep.termination.describe().to_string(),
        arm: refined,
        beam,
        planes,
        changes,
    })
}

/// A copy of the arm's calibration file with the refined parameters' values (σ kept from the
/// kinematic calibration; the file says where the values come from).
pub fn refined_calibration(cal: &CalibrationFile, r: &Refined) -> CalibrationFile {
    let mut out = cal.clone();
    for (name, unit, delta) in &r.changes {
        if let Some(p) = out.params.iter_mut().find(|p| &p.name == name) {
            let u = p.unit.trim().to_ascii_lowercase();
            p.value += match (unit, u.as_str()) {
                (ParamUnit::Rad, "deg" | "degree" | "degrees") => delta.to_degrees(),
                (ParamUnit::Mm, "m") => delta / 1000.0,
                _ => *delta,
            };
        }
    }
    out.extra.insert(
        "arm_refined_by_laser".into(),
        format!(
            "joint parameters refined jointly with the laser beam from the calibration planes and \
             the selection targets (prior: this arm's kinematic calibration); plane RMS {:.4} -> \
             {:.4} mm, selection spread {:.4} -> {:.4} mm",
            r.plane_rms_before_mm,
            r.plane_rms_after_mm,
            r.selection_spread_before_mm,
            r.selection_spread_after_mm
        )
        .into(),
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::KinematicModel;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn empty_cal() -> CalibrationFile {
        let robot = crate::dataset::RobotBlock::named("denso-vs060");
        CalibrationFile::new(robot, Vec::new())
    }

    fn arm(model: KinematicModel) -> IdentifiedArm {
        IdentifiedArm {
            model,
            effects: Vec::new(),
            applied: Vec::new(),
            left_out: Vec::new(),
        }
    }

    /// Planes data through a `truth` arm whose wrist is off by 0.15°: the refinement from the
    /// nominal arm (prior 0.2°) finds the wrist, and the spots of a held-out pose set agree.
    #[test]
    fn the_planes_find_a_wrist_error_the_prior_allows() {
        let nominal = KinematicModel::preset("denso-vs060").unwrap();
        let mut true_model = nominal.clone();
        for (n, d) in [("phi5", 0.15f64), ("alpha5", -0.1), ("phi4", 0.08)] {
            let v = true_model.param(n).unwrap();
            true_model.set_param(n, v + d.to_radians()).unwrap();
        }
        let mut start = nominal.clone();
        for p in ["phi4", "alpha4", "phi5", "alpha5", "a5", "d5"] {
            start.set_free(p, true).unwrap();
        }
        let beam = Beam {
            r: Vector3::new(0.9, 40.7, 38.6),
            v: Unit::new_normalize(Vector3::new(0.006, -0.004, 1.0)),
        };
        let planes = [
            (
                "P1",
                Vector3::new(0.0, 0.0, 1.0),
                Point3::new(420.0, 0.0, -250.0),
            ),
            (
                "P2",
                Vector3::new(-1.0, 0.0, 0.0),
                Point3::new(950.0, 0.0, 250.0),
            ),
            (
                "P3",
                Vector3::new(0.0, 1.0, 0.0),
                Point3::new(350.0, -850.0, 250.0),
            ),
        ];
        let home = [0.0f64, 0.0, 90.0, 0.0, 45.0, 0.0];
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut obs: Vec<ArmObs> = Vec::new();
        let mut counts = [0usize; 3];
        let mut id = 0;
        while counts.iter().any(|c| *c < 40) && id < 200_000 {
            id += 1;
            let q: Vec<f64> = home
                .iter()
                .map(|h| (h + rng.random_range(-90.0..90.0f64)).to_radians())
                .collect();
            let f = true_model.flange_pose(&q);
            let o = f * Point3::from(beam.r);
            let u = f.rotation * beam.v.into_inner();
            for (k, (name, n, through)) in planes.iter().enumerate() {
                let den = u.dot(n);
                if counts[k] >= 40 || den > -0.5 {
                    continue;
                }
                let d = (through - o).dot(n) / den;
                if !(300.0..900.0).contains(&d) {
                    continue;
                }
                counts[k] += 1;
                let ctx = PoseCtx {
                    id,
                    q: q.clone(),
                    approach: vec![0.0; 6],
                    ..Default::default()
                };
                obs.push(ArmObs {
                    ctx,
                    obs: LaserObs {
                        id,
                        flange: nominal.flange_pose(&q),
                        d: d + 0.02 * (rng.random::<f64>() - 0.5),
                        plane: Some(name.to_string()),
                        move_kind: None,
                        block: None,
                        target: None,
                        group: None,
                    },
                });
            }
        }
        assert!(counts.iter().all(|c| *c >= 40), "{counts:?}");
        let start_arm = arm(start);
        // Start from the plain fit through the nominal arm.
        let plain: Vec<LaserObs> = obs.iter().map(|o| o.obs.clone()).collect();
        let by = super::super::by_plane(&plain);
        let lists: Vec<Vec<LaserObs>> = by.values().cloned().collect();
        let p0: Vec<Plane> = planes
            .iter()
            .map(|(_, n, t)| Plane {
                n: Unit::new_normalize(*n),
                c: -n.dot(&t.coords),
            })
            .collect();
        let fit = super::super::fit_direct(&lists, &beam, &p0, Default::default()).unwrap();
        let named: Vec<(String, Plane)> = by.keys().cloned().zip(fit.planes.clone()).collect();
        let cal = empty_cal();
        let r = refine(
            &start_arm,
            &cal,
            &obs,
            &[],
            &[],
            (&fit.beam, &named),
            &RefineOptions::default(),
        )
        .unwrap();
        assert!(r.plane_rms_before_mm > 0.1, "{}", r.plane_rms_before_mm);
        assert!(r.plane_rms_after_mm < 0.05, "{}", r.plane_rms_after_mm);
        assert!(
            r.identifiability.planes_pinned >= 4,
            "{:?}",
            r.identifiability
        );
        // The refined arm's flange orientation matches the truth's over the whole sample.
        let worst = obs
            .iter()
            .map(|o| {
                let a = r.arm.flange(&o.ctx).rotation;
                let b = true_model.flange_pose(&o.ctx.q).rotation;
                let n = nominal.flange_pose(&o.ctx.q).rotation;
                ((a.inverse() * b).angle(), (n.inverse() * b).angle())
            })
            .fold((0.0f64, 0.0f64), |m, (a, n)| (m.0.max(a), m.1.max(n)));
        assert!(
            worst.0 < 0.25 * worst.1,
            "orientation error refined {:.4}° vs nominal {:.4}°",
            worst.0.to_degrees(),
            worst.1.to_degrees()
        );
        // The file keeps the refined values in its own units.
        let mut base = CalibrationFile::new(cal.robot.clone(), start_arm.model.to_cal_params());
        base.params.retain(|p| p.name == "phi5");
        let out = refined_calibration(&base, &r);
        let d = r.changes.iter().find(|c| c.0 == "phi5").unwrap().2;
        assert!((out.params[0].value - base.params[0].value - d.to_degrees()).abs() < 1e-9);
    }

    #[test]
    fn prior_sd_reads_the_file_units_and_floors() {
        let mut cal = empty_cal();
        let p = |name: &str, std: f64, unit: &str| CalParam {
            name: name.into(),
            value: 0.0,
            std: Some(std),
            unit: unit.into(),
            free: true,
            extra: Default::default(),
        };
        cal.params = vec![p("phi5", 0.125, "deg"), p("a6", 0.0001, "mm")];
        let s = prior_sd(&cal, "phi5", ParamUnit::Rad, 1.0);
        assert!((s - 0.125f64.to_radians()).abs() < 1e-12);
        assert!((prior_sd(&cal, "a6", ParamUnit::Mm, 1.0) - 0.1 * DEFAULT_PRIOR_MM).abs() < 1e-12);
        assert!((prior_sd(&cal, "d5", ParamUnit::Mm, 2.0) - 2.0 * DEFAULT_PRIOR_MM).abs() < 1e-12);
    }
}
