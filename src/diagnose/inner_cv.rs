//! When to stop adding physical effects, from the training poses alone: the time-blocked
//! cross-validation inside the training set, pose by pose.
//!
//! The physics-first chain of [`super::Policy::Best`] used to stop at a fixed number of
//! effects. With [`CvStop`] it stops when the next effect, refitted, no longer lowers the
//! time-blocked CV error of the training poses by more than `k_se` standard errors of that
//! lowering (the paired difference of the per-pose CV errors before and after the effect).
//! The linearised refit per fold is the one the chain's CV RMS uses
//! ([`super::stats::CvBase`]): the model and effect Jacobian at the refitted state, each
//! fold's coefficients from the other folds' rows.
use nalgebra::{DMatrix, DVector};

use super::fit::{stack, State};
use crate::solve::obs::PoseObs;

/// The stopping rule of the physics-first chain (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CvStop {
    /// An effect is kept when its CV gain exceeds this many standard errors.
    pub k_se: f64,
    /// Standard error from the per-fold mean differences (time blocks: the errors of
    /// neighbouring poses are correlated) instead of the per-pose ones.
    pub by_fold: bool,
    /// Each fold refits the effect coefficients only (the geometric parameters stay at the
    /// fit to every training pose): a time block left out can leave geometric parameters
    /// undetermined, and their extrapolation then swamps what the effects change.
    pub effects_only: bool,
    /// Each fold is predicted from the folds before it only (does an effect carry over to
    /// poses measured later?) instead of from every other fold.
    pub forward: bool,
}

/// Default of [`super::Options::physics_first_stop`].
pub const DEFAULT_CV_STOP: CvStop = CvStop {
    k_se: 1.0,
    by_fold: false,
    effects_only: true,
    forward: false,
};

/// Per-pose time-blocked CV errors of one state: `sq[i]` is the squared 3-D error of pose
/// `i` predicted by the linearised refit on the other folds; `fold[i]` its fold.
#[derive(Debug, Clone)]
pub struct PoseCv {
    pub sq: Vec<f64>,
    pub fold: Vec<usize>,
}

impl PoseCv {
    /// CV RMS per row (per axis, mm), as [`super::stats::CvBase::rms`] reports it.
    pub fn rms(&self) -> f64 {
        let v: Vec<f64> = self.sq.iter().copied().filter(|v| v.is_finite()).collect();
        (v.iter().sum::<f64>() / (3.0 * v.len().max(1) as f64)).sqrt()
    }
}

/// The per-pose CV errors of `state` on `train` (time-sorted) with `fold[i]` the fold of
/// pose `i` (`n_folds` folds). Normal equations with the columns scaled to unit norm and
/// directions below 1e-12 of the largest dropped, as [`super::stats::CvBase`] solves them.
pub fn pose_cv(state: &State, train: &[PoseObs], fold: &[usize], n_folds: usize) -> PoseCv {
    pose_cv_of(state, train, fold, n_folds, false, false)
}

/// One fold's normal-equation blocks (`JᵀJ`, `Jᵀr`) and its rows of `J` and `r`.
type FoldBlock = (DMatrix<f64>, DVector<f64>, DMatrix<f64>, DVector<f64>);

/// [`pose_cv`], with only the effect coefficients refitted per fold when `effects_only`,
/// and each fold predicted from the folds before it only when `forward` (the first fold's
/// poses are then not predicted: `sq` NaN).
pub fn pose_cv_of(
    state: &State,
    train: &[PoseObs],
    fold: &[usize],
    n_folds: usize,
    effects_only: bool,
    forward: bool,
) -> PoseCv {
    let (r, j) = stack(state, train);
    let mut j = if effects_only {
        let p0 = state.model.free_count();
        j.columns(p0, j.ncols() - p0).into_owned()
    } else {
        j
    };
    for mut c in j.column_iter_mut() {
        let n = c.norm();
        if n > 0.0 {
            c /= n;
        }
    }
    let p = j.ncols();
    // Each fold's rows, and their normal-equation blocks.
    let tests: Vec<Vec<usize>> = (0..n_folds)
        .map(|f| (0..train.len()).filter(|&i| fold[i] == f).collect())
        .collect();
    let blocks: Vec<FoldBlock> = tests
        .iter()
        .map(|t| {
            let rows: Vec<usize> = t
                .iter()
                .flat_map(|&i| [3 * i, 3 * i + 1, 3 * i + 2])
                .collect();
            let jt = j.select_rows(&rows);
            let rt = r.select_rows(&rows);
            (jt.transpose() * &jt, jt.transpose() * &rt, jt, rt)
        })
        .collect();
    let mut sq = vec![f64::NAN; train.len()];
    for (f, test) in tests.iter().enumerate() {
        let others = |g: usize| if forward { g < f } else { g != f };
        let n_rows: usize = (0..n_folds)
            .filter(|&g| others(g))
            .map(|g| 3 * tests[g].len())
            .sum();
        if forward && f == 0 {
            continue;
        }
        if test.is_empty() || p == 0 || n_rows <= p {
            // Nothing to refit (or too few rows to): the pose keeps its residual.
            for &i in test {
                sq[i] = (0..3).map(|a| r[3 * i + a].powi(2)).sum();
            }
            continue;
        }
        let mut m = DMatrix::zeros(p, p);
        let mut b = DVector::zeros(p);
        for (_, blk) in blocks.iter().enumerate().filter(|(g, _)| others(*g)) {
            m += &blk.0;
            b += &blk.1;
        }
        // Minimum-norm solution, directions below 1e-12 of the largest dropped.
        let svd = m.svd(true, true);
        let tol = 1e-12 * svd.singular_values.max();
        let x = svd.solve(&b, tol).unwrap_or_else(|_| DVector::zeros(p));
        let (_, _, jt, rt) = &blocks[f];
        let e: DVector<f64> = rt - jt * &x;
        for (k, &i) in test.iter().enumerate() {
            sq[i] = (0..3).map(|a| e[3 * k + a].powi(2)).sum();
        }
    }
    PoseCv {
        sq,
        fold: fold.to_vec(),
    }
}

/// The CV gain of going from `before` to `after` (mean per-pose squared error, mm²) and its
/// standard error under `rule`.
pub fn gain(before: &PoseCv, after: &PoseCv, rule: &CvStop) -> (f64, f64) {
    // Pairs of predicted poses only (a forward CV does not predict its first fold).
    let (d, fo): (Vec<f64>, Vec<usize>) = before
        .sq
        .iter()
        .zip(&after.sq)
        .zip(&before.fold)
        .filter(|((b, a), _)| b.is_finite() && a.is_finite())
        .map(|((b, a), f)| (b - a, *f))
        .unzip();
    let n = d.len();
    if n < 2 {
        return (0.0, f64::INFINITY);
    }
    let mean = d.iter().sum::<f64>() / n as f64;
    if !rule.by_fold {
        let var = d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        return (mean, (var / n as f64).sqrt());
    }
    let nf = before.fold.iter().copied().max().map_or(0, |m| m + 1);
    let fm: Vec<f64> = (0..nf)
        .filter_map(|f| {
            let v: Vec<f64> = d
                .iter()
                .zip(&fo)
                .filter(|(_, g)| **g == f)
                .map(|(v, _)| *v)
                .collect();
            (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
        })
        .collect();
    if fm.len() < 2 {
        return (mean, f64::INFINITY);
    }
    let k = fm.len() as f64;
    let m = fm.iter().sum::<f64>() / k;
    let var = fm.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (k - 1.0);
    (mean, (var / k).sqrt())
}

/// Whether the step from `before` to `after` lowers the CV error by more than the rule's
/// standard errors (and the figures: gain and standard error, mm²).
pub fn keeps(before: &PoseCv, after: &PoseCv, rule: &CvStop) -> (bool, f64, f64) {
    let (g, se) = gain(before, after, rule);
    (g > rule.k_se * se && g > 0.0, g, se)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::effects::{Block, Effect, Ripple};
    use crate::diagnose::fit::fit;
    use crate::diagnose::stats::CvBase;
    use crate::diagnose::{folds, row_folds};
    use crate::model::KinematicModel;
    use nalgebra::DMatrix;

    /// 300 poses of a UR5e whose joint 2 ripples 17 times per turn (0.3 mrad), measured
    /// with a deterministic ±0.02 mm disturbance.
    fn data() -> (KinematicModel, Vec<PoseObs>) {
        let mut model = KinematicModel::preset("ur5e").unwrap();
        model.fix_point_redundancies();
        let obs = (0..300u64)
            .map(|k| {
                let f = k as f64;
                let q = crate::diagnose::test_joints(f, 1.2, 1.3);
                let mut qt = q.clone();
                qt[1] += 3e-4 * (17.0 * q[1]).sin();
                let mut p = model.measured_point(&qt);
                for a in 0..3 {
                    p[a] += 0.02 * ((f * 7.919 + a as f64 * 1.047) * 12.9898).sin();
                }
                PoseObs::at(k, 10.0 * f, q, p)
            })
            .collect();
        (model, obs)
    }

    fn fitted(model: &KinematicModel, obs: &[PoseObs], blocks: &[Block]) -> State {
        let mut st = State {
            prior: None,
            model: model.clone(),
            effects: blocks.iter().cloned().map(Effect::zero).collect(),
        };
        fit(&mut st, obs, 50);
        st
    }

    /// The per-pose errors add up to the CV RMS the chain's policy uses.
    #[test]
    fn pose_errors_add_up_to_the_chain_cv() {
        let (model, obs) = data();
        let st = fitted(&model, &obs, &[]);
        let fo = folds(&obs, 5);
        let cv = pose_cv(&st, &obs, &fo, 5);
        let (r, j) = stack(&st, &obs);
        let base = CvBase::new(&j, &r, &row_folds(&fo), 5);
        let want = base.rms(&j, &DMatrix::zeros(r.len(), 0), &r);
        println!("per-pose CV RMS {:.6}, CvBase {want:.6} mm", cv.rms());
        assert!((cv.rms() - want).abs() < 1e-9 * want.max(1.0));
        assert!(cv.rms() > 0.0);
    }

    /// The ripple the data hold is kept; a second ripple the data do not hold is not, under
    /// either standard error.
    #[test]
    fn the_stop_keeps_an_effect_the_data_hold_and_not_one_they_lack() {
        let (model, obs) = data();
        let fo = folds(&obs, 5);
        let ripple = |joint, harmonic| Block::Ripple(Ripple { joint, harmonic });
        let geo = fitted(&model, &obs, &[]);
        let one = fitted(&model, &obs, &[ripple(2, 17)]);
        let two = fitted(&model, &obs, &[ripple(2, 17), ripple(3, 23)]);
        let (c0, c1, c2) = (
            pose_cv(&geo, &obs, &fo, 5),
            pose_cv(&one, &obs, &fo, 5),
            pose_cv(&two, &obs, &fo, 5),
        );
        println!(
            "inner CV RMS: geometric {:.4}, + ripple j2 {:.4}, + ripple j3 {:.4} mm",
            c0.rms(),
            c1.rms(),
            c2.rms()
        );
        for by_fold in [false, true] {
            let rule = CvStop {
                k_se: 1.0,
                by_fold,
                effects_only: false,
                forward: false,
            };
            let (keep, g, se) = keeps(&c0, &c1, &rule);
            assert!(keep, "by_fold {by_fold}: gain {g:.3e}, se {se:.3e}");
            let (keep, g, se) = keeps(&c1, &c2, &rule);
            assert!(!keep, "by_fold {by_fold}: gain {g:.3e}, se {se:.3e}");
        }
    }
}
