//! How far a fitted effect's prediction grows outside the training poses.
//!
//! A block whose columns nearly cancel on the training poses can be fitted with large
//! coefficients of opposite signs: its prediction stays small on every training pose and
//! becomes large elsewhere. The real UR10 Series D, time-blocked (355 training poses in a
//! small workspace): `joint_compliance(j4)` lowered the training RMS by 0.7 % and predicted
//! 10.7 mm at the one upright held-out pose. This module measures, from training data
//! only, the largest displacement the effect predicts at probe poses drawn inside the box
//! of the training poses' joint ranges, relative to the largest it predicts at a training
//! pose; the selection ([`super::select_chain`]) leaves out an effect whose ratio exceeds
//! [`super::Options::max_extrapolation`].
use super::effects::apply_effects;
use super::fit::State;
use crate::solve::obs::PoseObs;

/// Number of probe poses.
pub const N_PROBES: usize = 512;

/// Largest displacement (mm) effect `k` of `state` adds at a probe pose, over the largest it
/// adds at a training pose (`None` without training poses or when the effect adds nothing
/// anywhere). Probes: joints uniform in the training poses' per-joint ranges (a fixed
/// low-discrepancy sequence, so the figure is reproducible), every other part of the
/// context (time, temperature, approach) taken from the training poses in turn.
pub fn ratio(state: &State, train: &[PoseObs], k: usize) -> Option<(f64, f64, f64)> {
    if train.is_empty() || k >= state.effects.len() {
        return None;
    }
    let mut without = state.effects.clone();
    without.remove(k);
    let disp = |ctx: &crate::solve::obs::PoseCtx| -> f64 {
        (apply_effects(&state.model, &state.effects, ctx)
            - apply_effects(&state.model, &without, ctx))
        .norm()
    };
    let on_train = train.iter().map(|o| disp(&o.ctx)).fold(0.0f64, f64::max);
    let dof = train[0].ctx.q.len();
    let (mut lo, mut hi) = (vec![f64::INFINITY; dof], vec![f64::NEG_INFINITY; dof]);
    for o in train {
        for ((l, h), &q) in lo.iter_mut().zip(hi.iter_mut()).zip(&o.ctx.q) {
            *l = l.min(q);
            *h = h.max(q);
        }
    }
    // Additive recurrence with the first primes' square roots (a Kronecker sequence).
    let alpha: Vec<f64> = [2.0f64, 3.0, 5.0, 7.0, 11.0, 13.0, 17.0, 19.0, 23.0, 29.0]
        .iter()
        .cycle()
        .take(dof)
        .map(|p| p.sqrt().fract())
        .collect();
    let mut on_probes = 0.0f64;
    for i in 0..N_PROBES {
        let mut ctx = train[i % train.len()].ctx.clone();
        for (((qj, a), l), h) in ctx.q.iter_mut().zip(&alpha).zip(&lo).zip(&hi) {
            *qj = l + (0.5 + (i + 1) as f64 * a).fract() * (h - l);
        }
        on_probes = on_probes.max(disp(&ctx));
    }
    (on_train > 0.0 && on_train.is_finite() && on_probes.is_finite())
        .then(|| (on_probes / on_train, on_train, on_probes))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::effects::{Block, Effect, Ripple};
    use crate::diagnose::MAX_EXTRAPOLATION;
    use crate::model::KinematicModel;
    use nalgebra::Point3;

    /// A ripple of joint 2 whose training poses all sit at its nodes (`sin 8q₂ = 0`)
    /// predicts nothing there and up to its amplitude between them: the ratio exceeds the
    /// default limit (the check is on by default). The same ripple on poses spread over the
    /// same range stays within a few times its largest training displacement.
    #[test]
    fn an_effect_that_vanishes_on_the_training_poses_is_flagged_by_default() {
        let model = KinematicModel::preset("ur5e").unwrap();
        let state = State {
            prior: None,
            model: model.clone(),
            effects: vec![Effect {
                block: Block::Ripple(Ripple {
                    joint: 2,
                    harmonic: 8,
                }),
                coefs: vec![0.05f64.to_radians(), 0.0],
                std: vec![f64::NAN; 2],
                tau_std: f64::NAN,
            }],
        };
        let pose = |k: usize, q2: f64| {
            let f = k as f64;
            let q: Vec<f64> = (0..6)
                .map(|i| {
                    if i == 1 {
                        q2
                    } else {
                        0.8 * ((f + 1.0) * (i as f64 + 1.3)).sin()
                    }
                })
                .collect();
            PoseObs::at(k as u64, f, q, Point3::origin())
        };
        let step = std::f64::consts::PI / 8.0;
        let at_nodes: Vec<PoseObs> = (0..60).map(|k| pose(k, -step * (k % 9) as f64)).collect();
        let spread: Vec<PoseObs> = (0..60)
            .map(|k| pose(k, -8.0 * step * k as f64 / 59.0))
            .collect();
        let nodes = ratio(&state, &at_nodes, 0).map(|r| r.0);
        let dense = ratio(&state, &spread, 0).unwrap().0;
        assert!(MAX_EXTRAPOLATION.is_finite(), "the check is off by default");
        assert!(
            nodes.is_none_or(|r| r > MAX_EXTRAPOLATION),
            "at the nodes: {nodes:?}"
        );
        assert!(dense < 3.0, "spread: {dense}");
    }
}
