//! Columns of the base-shift candidates of a change-point refinement, computed once.
//!
//! A base shift (kind `base_shift`) at zero coefficients leaves every pose's model as it is
//! (`v + 0`), and its columns at a pose are the model Jacobian's base-parameter columns when
//! the pose is at or after `t_change`, zero before. So the columns of a shift at any
//! `t_change` are those of one shift before every pose with the earlier poses' rows zeroed:
//! the same numbers [`super::candidate_columns`] gives for each change point, without
//! building a Jacobian with six columns per change point (at 8,934 poses about 900 change
//! points, 4.7 GB and most of the round's time).
use nalgebra::DMatrix;

use super::candidate_columns;
use super::effects::{BaseShift, Block};
use super::fit::State;
use crate::solve::obs::PoseObs;

/// The base shift's columns before every pose (3 rows per pose, 6 columns) and the poses'
/// times.
pub struct ShiftColumns {
    all: DMatrix<f64>,
    times: Vec<f64>,
}

impl ShiftColumns {
    /// Columns of a base shift at −∞ at the current state.
    pub fn new(state: &State, train: &[PoseObs]) -> Self {
        let block: Block = BaseShift {
            t_change: f64::NEG_INFINITY,
        }
        .into();
        let all = candidate_columns(state, train, std::slice::from_ref(&block))
            .pop()
            .unwrap_or_else(|| DMatrix::zeros(3 * train.len(), 6));
        ShiftColumns {
            all,
            times: train.iter().map(|o| o.ctx.t).collect(),
        }
    }

    /// Columns of a base shift at `t_change`: the rows of the poses before it (and of
    /// poses without a valid time, which no shift applies to) zeroed.
    pub fn at(&self, t_change: f64) -> DMatrix<f64> {
        let mut g = self.all.clone();
        for (k, t) in self.times.iter().enumerate() {
            // the negation of `BaseShift::columns`' test `ctx.t >= t_change`
            if matches!(
                t.partial_cmp(&t_change),
                None | Some(std::cmp::Ordering::Less)
            ) {
                for a in 0..3 {
                    g.row_mut(3 * k + a).fill(0.0);
                }
            }
        }
        g
    }
}

/// Above this many mid-points a change point is refined in two levels ([`first_level`],
/// [`second_level`]); at or below it every mid-point is scored. Series C (2,080 training
/// poses) has about 210 mid-points between its coarse neighbours and the simulated suite
/// fewer, so they are scored exhaustively as before; 10,000 poses have about 1,000.
pub const TWO_LEVEL_ABOVE: usize = 400;

/// The mid-points (indices into `n` sorted ones) scored first, and the stride between
/// them: all of them (stride 1) up to [`TWO_LEVEL_ABOVE`], else every `k`-th with
/// `k = ⌈√n⌉` and the last one.
pub fn first_level(n: usize) -> (Vec<usize>, usize) {
    if n <= TWO_LEVEL_ABOVE {
        return ((0..n).collect(), 1);
    }
    let k = (n as f64).sqrt().ceil() as usize;
    let mut idx: Vec<usize> = (0..n).step_by(k).collect();
    if idx.last() != Some(&(n - 1)) {
        idx.push(n - 1);
    }
    (idx, k)
}

/// The mid-points scored second: every one within `stride` of position `pos` (where the
/// best change point so far lies among the `n` sorted mid-points) that the first level
/// (stride `stride`) did not score. Empty for stride 1 (the first level scored all).
pub fn second_level(n: usize, stride: usize, pos: usize) -> Vec<usize> {
    if stride <= 1 || n == 0 {
        return vec![];
    }
    let lo = pos.saturating_sub(stride);
    let hi = (pos + stride).min(n - 1);
    (lo..=hi)
        .filter(|&i| i % stride != 0 && i != n - 1)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::effects::{Effect, Ripple};
    use crate::model::KinematicModel;

    /// The masked columns are bit for bit the ones `candidate_columns` builds for each
    /// change point, on a state that already carries an effect, with unsorted times, a
    /// change point on a pose's time and one before / after every pose.
    #[test]
    fn masked_columns_equal_each_change_points_own() {
        let mut model = KinematicModel::preset("ur5e").unwrap();
        model.fix_point_redundancies();
        let train: Vec<PoseObs> = (0..60)
            .map(|k| {
                let f = k as f64;
                let q = crate::diagnose::test_joints(f, 1.1, 1.7);
                // times out of order: every 7th pose late
                let t = if k % 7 == 3 { 500.0 + f } else { 10.0 * f };
                PoseObs::at(k, t, q.clone(), model.measured_point(&q))
            })
            .collect();
        let mut ripple = Effect::zero(
            Ripple {
                joint: 1,
                harmonic: 2,
            }
            .into(),
        );
        ripple.coefs = vec![0.002, -0.001];
        let state = State {
            prior: None,
            model,
            effects: vec![ripple],
        };
        let sc = ShiftColumns::new(&state, &train);
        let ts = [-1.0, 0.0, 95.0, 100.0, 333.3, 505.0, 1e9];
        let blocks: Vec<Block> = ts
            .iter()
            .map(|&t_change| BaseShift { t_change }.into())
            .collect();
        let own = candidate_columns(&state, &train, &blocks);
        for (t, g) in ts.iter().zip(&own) {
            let m = sc.at(*t);
            assert_eq!(m.shape(), g.shape());
            let same = m
                .iter()
                .zip(g.iter())
                .all(|(a, b)| a.to_bits() == b.to_bits());
            assert!(same, "t_change {t}: masked columns differ");
        }
        // something was masked and something was not
        assert!(own[2].iter().any(|v| *v != 0.0) && own[2].iter().any(|v| *v == 0.0));
        assert!(own[6].iter().all(|v| *v == 0.0));
    }

    /// Up to the threshold every mid-point is scored once; above it the two levels score
    /// each index at most once, cover the whole neighbourhood of the best, and far fewer
    /// than all.
    #[test]
    fn two_levels_cover_the_best_neighbourhood_once() {
        let (all, k) = first_level(TWO_LEVEL_ABOVE);
        assert_eq!((all.len(), k), (TWO_LEVEL_ABOVE, 1));
        assert!(second_level(TWO_LEVEL_ABOVE, k, 7).is_empty());
        for n in [TWO_LEVEL_ABOVE + 1, 893, 1000, 1024, 5000] {
            let (first, k) = first_level(n);
            assert_eq!(first[0], 0);
            assert_eq!(*first.last().unwrap(), n - 1);
            for pos in [0, 1, k, n / 2, n - 2, n - 1, n] {
                let second = second_level(n, k, pos);
                let mut seen = first.clone();
                seen.extend(&second);
                let total = seen.len();
                seen.sort_unstable();
                seen.dedup();
                assert_eq!(seen.len(), total, "n {n}, pos {pos}: an index scored twice");
                assert!(seen.iter().all(|&i| i < n));
                for i in pos.saturating_sub(k)..=(pos + k).min(n - 1) {
                    assert!(seen.contains(&i), "n {n}, pos {pos}: {i} not scored");
                }
                assert!(total <= 4 * k + 2, "n {n}: {total} scored");
            }
        }
    }
}
