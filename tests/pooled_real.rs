//! The pooled multi-series diagnosis ([`robocal::diagnose::pooled`]) on the real UR10 (IPA
//! Series A, `../shared/data/real-ur10-ipa-grid`, read in place; SKIPPED loudly when
//! absent): the series cut into three time blocks standing for three sessions, every 8th
//! pose of each. Trained on the first two, the third registered on 40 of its poses spread
//! over it: the shared physical effects must predict it better than the shared geometry,
//! and joint 2's ×17 ripple fitted on either training block alone has the same phase.

use robocal::diagnose::effects::{Block, Effect, Ripple};
use robocal::diagnose::fit::fit;
use robocal::diagnose::pooled::{
    amplitude_phase, leave_one_series_out, load_series, start_states, PooledOptions, Registration,
};
use robocal::diagnose::Options;
use robocal::solve::obs::PoseObs;

#[test]
fn pooled_physics_carries_to_a_later_block_of_the_real_ur10() {
    let Some(dir) = crate::common::real_ur10_dir("the pooled diagnosis") else {
        return;
    };
    let (model, train, held) = load_series(&dir).expect("Series A loads");
    let mut all: Vec<PoseObs> = train.into_iter().chain(held).collect();
    all.sort_by(|a, b| a.ctx.t.total_cmp(&b.ctx.t));
    let third = all.len() / 3;
    let blocks: Vec<Vec<PoseObs>> = (0..3)
        .map(|k| {
            all[k * third..(k + 1) * third]
                .iter()
                .step_by(8)
                .cloned()
                .collect()
        })
        .collect();
    let refs: Vec<&[PoseObs]> = blocks[..2].iter().map(|v| v.as_slice()).collect();
    let r = leave_one_series_out(
        &model,
        &refs,
        &blocks[2],
        &Registration {
            n: 40,
            spread: true,
            offsets: true,
        },
        &Options::default(),
        &PooledOptions::default(),
    )
    .expect("pooled fit");
    eprintln!(
        "pooled on A's time blocks: geometric {:.4} / {:.4} mm, physical {:.4} / {:.4} mm (train / held-out), {}",
        r.geo_train,
        r.geo_heldout,
        r.phys_train,
        r.phys_heldout,
        r.steps.iter().map(|s| s.label.as_str()).collect::<Vec<_>>().join(", ")
    );
    assert_eq!((r.n_register, r.n_heldout), (40, blocks[2].len() - 40));
    assert!(
        r.steps
            .iter()
            .any(|s| s.label.starts_with("transmission_ripple")),
        "a shared ripple is found"
    );
    assert!(
        r.phys_heldout < 0.9 * r.geo_heldout,
        "the shared physics predicts the left-out block: {:.4} vs {:.4} mm",
        r.phys_heldout,
        r.geo_heldout
    );
    // Joint 2's ×17 ripple: one phase within the session.
    let phase = |obs: &[PoseObs]| {
        let mut st = start_states(&model, &[obs]).unwrap().remove(0);
        st.effects = vec![Effect::zero(Block::from(Ripple {
            joint: 2,
            harmonic: 17,
        }))];
        fit(&mut st, obs, 50);
        amplitude_phase(&st.effects[0]).unwrap()
    };
    let (a0, p0, _, s0) = phase(&blocks[0]);
    let (a1, p1, _, s1) = phase(&blocks[1]);
    let dp = (p1 - p0 + 540.0).rem_euclid(360.0) - 180.0;
    eprintln!("j2 ×17: {a0:.5}° at {p0:.0}° ± {s0:.0}°, {a1:.5}° at {p1:.0}° ± {s1:.0}°");
    assert!(a0 > 0.005 && a1 > 0.005, "the ripple is there: {a0} {a1}");
    assert!(dp.abs() < 30.0, "phase moved {dp:.0}° within one session");
}
