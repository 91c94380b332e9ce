//! Issue 32: the fast bootstrap (per-pose normal blocks reused across subsets, a Gauss–Newton
//! step per subset with an exactness check and LM fallback) gives the statistics of exact LM
//! refits of the very same subsets; identification cost grows linearly with the poses.
use std::path::PathBuf;

use robocal::dataset::Dataset;
use robocal::solve::bootstrap::{
    bootstrap, BootstrapMethod, BootstrapOptions, SubsetSize, AUDIT_TOL_SIGMA,
};
use robocal::solve::kinematics::{identify, IdentOptions};

fn data(p: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(p)
}

#[test]
fn fast_bootstrap_matches_exact_refits() {
    let train = Dataset::load(data("kin-geometric/train.jsonl")).unwrap();
    let held = Dataset::load(data("kin-geometric/heldout.jsonl")).unwrap();
    let res = identify(
        &train,
        &IdentOptions {
            heldout: Some(held),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(res.train_obs.len(), 500);
    let opts = |method| BootstrapOptions {
        k: 300,
        subset: SubsetSize::Count(200),
        seed: 32,
        method,
        ..Default::default()
    };
    let fast = bootstrap(&res, &[], &opts(BootstrapMethod::Fast)).unwrap();
    let exact = bootstrap(&res, &[], &opts(BootstrapMethod::Exact)).unwrap();
    assert_eq!(
        fast.method,
        BootstrapMethod::Fast,
        "the audit refused the fast path"
    );
    assert_eq!(exact.method, BootstrapMethod::Exact);
    assert_eq!((fast.n_failed, exact.n_failed), (0, 0));
    assert_eq!(fast.samples.len(), 300);
    let audit = fast.audit_max_sigma.unwrap();
    assert!(audit <= AUDIT_TOL_SIGMA, "audit {audit}");
    // Same subsets (same seed): the statistics, and every single fit, agree.
    let mut worst_mean = 0.0f64;
    let mut worst_std = 0.0f64;
    let mut worst_fit = 0.0f64;
    for (i, name) in exact.names.iter().enumerate() {
        assert_eq!(&fast.names[i], name);
        let (f, e) = (&fast.summaries[i], &exact.summaries[i]);
        assert!(e.std > 0.0, "{name}");
        worst_mean = worst_mean.max((f.mean - e.mean).abs() / e.std);
        worst_std = worst_std.max((f.std / e.std - 1.0).abs());
        for (sf, se) in fast.samples.iter().zip(&exact.samples) {
            worst_fit = worst_fit.max((sf[i] - se[i]).abs() / e.std);
        }
    }
    println!(
        "fast vs exact bootstrap (300 × 200 of 500): mean within {:.2e} σ, σ within {:.2e}, \
         every fit within {:.2e} σ; {} LM fallbacks, {} FK passes, audit {:.2e} σ; {:.3} s vs {:.3} s",
        worst_mean, worst_std, worst_fit, fast.n_fallback, fast.n_chord_passes, audit, fast.elapsed_s, exact.elapsed_s
    );
    assert!(worst_mean <= 0.01, "mean off by {worst_mean} σ");
    assert!(worst_std <= 0.05, "σ off by {worst_std}");
    assert!(worst_fit <= 0.05, "a subset fit off by {worst_fit} σ");
}
