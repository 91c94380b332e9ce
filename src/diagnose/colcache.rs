//! Candidate columns from one evaluation of the state per pose.
//!
//! A candidate's columns are those of the problem's Jacobian with the candidate appended at
//! zero coefficients ([`super::candidate_columns`]); a zero effect changes neither the
//! prediction nor the pose's model, point and parameter Jacobian ([`effects::pose_base`]).
//! So the state is evaluated once per pose ([`StateColumns::new`]: its pose model, point,
//! parameter Jacobian, tracker scale and the model's frames at the measured angles), and
//! each candidate then only computes its own columns from that: not the whole Jacobian of
//! the model and every other candidate, and no forward kinematics per mass point. The
//! values are bit-identical to the Jacobian's (the same operations on the same inputs; a
//! test checks it against [`super::fit::stack`]).
use nalgebra::DMatrix;
use rayon::prelude::*;

use super::effects::{self, Block, EffectModel, PoseBase};
use super::fit::State;
use crate::model::PoseFrames;
use crate::solve::obs::PoseObs;

/// The per-pose evaluation of one state that candidate columns are computed from.
pub struct StateColumns<'a> {
    poses: Vec<(PoseBase<'a>, PoseFrames)>,
}

impl<'a> StateColumns<'a> {
    /// Evaluate `state` at every pose of `obs` (in parallel).
    pub fn new(state: &'a State, obs: &[PoseObs]) -> StateColumns<'a> {
        let consts = state.model.consts();
        let poses = obs
            .par_iter()
            .map(|o| {
                let b = effects::pose_base(&state.model, Some(&consts), &state.effects, &o.ctx);
                let f = b.m.pose_frames(&o.ctx.q);
                (b, f)
            })
            .collect();
        StateColumns { poses }
    }

    /// Whether the columns of `blocks` can be taken from the per-pose evaluation: a block
    /// without coefficients is not a zero effect (an empty coefficient list is not skipped
    /// in the prediction), so its columns need the whole Jacobian.
    pub fn applies(blocks: &[Block]) -> bool {
        blocks.iter().all(|b| b.n_params() > 0)
    }

    /// Each block's columns (`3·poses × n_params`, rows x, y, z per pose in `obs` order), the
    /// blocks in parallel. `obs` must be the poses of [`StateColumns::new`].
    pub fn columns(&self, obs: &[PoseObs], blocks: &[Block]) -> Vec<DMatrix<f64>> {
        blocks.par_iter().map(|b| self.block(obs, b)).collect()
    }

    fn block(&self, obs: &[PoseObs], b: &Block) -> DMatrix<f64> {
        let n = b.n_params();
        let zeros = vec![0.0; n];
        let mut g = DMatrix::zeros(3 * obs.len(), n);
        for (k, ((base, f), o)) in self.poses.iter().zip(obs).enumerate() {
            let raw = effects::block_columns_in(b, f, &base.m, &base.jm_pose, &base.p, &o.ctx);
            let cols = effects::scaled_columns(b, &zeros, raw, &base.p, base.s, &o.ctx);
            for (c, v) in cols.iter().enumerate().take(n) {
                for a in 0..3 {
                    g[(3 * k + a, c)] = v[a];
                }
            }
        }
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::effects::{registry_examples, Effect};
    use crate::diagnose::fit::stack;
    use crate::diagnose::test_obs;
    use crate::model::KinematicModel;

    /// The per-pose columns equal the trailing columns of the whole Jacobian with the
    /// blocks appended at zero, bit for bit: for a block of every family, at a state
    /// without effects and at one with an effect of every family fitted (frame effects,
    /// the tracker scale and point displacements included).
    #[test]
    fn columns_are_bit_identical_to_the_whole_jacobian() {
        let mut model = KinematicModel::preset("denso-vs060").unwrap();
        model.fix_point_redundancies();
        let obs = test_obs(&model, 15);
        let examples = registry_examples(&model);
        let blocks: Vec<Block> = examples
            .iter()
            .map(|e| e.block.clone())
            .filter(|b| b.n_params() > 0)
            .collect();
        assert!(blocks.len() >= 12, "{} blocks", blocks.len());
        let mut compared = 0;
        for effects in [vec![], examples] {
            let state = State {
                prior: None,
                model: model.clone(),
                effects,
            };
            let fast = StateColumns::new(&state, &obs).columns(&obs, &blocks);
            let mut st = state.clone();
            let mut off =
                st.model.free_count() + st.effects.iter().map(|e| e.coefs.len()).sum::<usize>();
            st.effects.extend(blocks.iter().cloned().map(Effect::zero));
            let (_, j) = stack(&st, &obs);
            for (b, g) in blocks.iter().zip(&fast) {
                let n = b.n_params();
                let whole = j.columns(off, n).into_owned();
                assert!(g.iter().any(|v| *v != 0.0), "{}: all zero", b.label());
                assert_eq!(g, &whole, "{}", b.label());
                off += n;
                compared += 1;
            }
        }
        assert_eq!(compared, 2 * blocks.len());
    }
}
