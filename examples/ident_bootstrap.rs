//! Seed 001 §4.3 parameter averaging: `K` random subsets of `M` poses of
//! `tests/data/kin-geometric/train.jsonl`, fitted in parallel (rayon); prints the wall
//! time, the per-parameter distribution (mean, std, 95 % interval, Jarque–Bera p) and the
//! held-out error of the full-data fit vs the subset-mean model against `truth.csv`.
//!
//! `cargo run --release --example ident_bootstrap [-- K M]` (default K = 10000, M = 200)
use std::path::Path;

use robocal::dataset::Dataset;
use robocal::model::Unit;
use robocal::solve::bootstrap::{bootstrap, BootstrapOptions, SubsetSize};
use robocal::solve::kinematics::{identify, IdentOptions};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let k: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(10_000);
    let m = args.get(2).map(|s| s.as_str()).unwrap_or("200");
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/kin-geometric");
    let train = Dataset::load(dir.join("train.jsonl")).expect("train");
    let held = Dataset::load(dir.join("heldout.jsonl")).expect("heldout");
    let truth: std::collections::HashMap<u64, nalgebra::Point3<f64>> =
        std::fs::read_to_string(dir.join("truth.csv"))
            .expect("truth")
            .lines()
            .skip(1)
            .filter_map(|l| {
                let v: Vec<f64> = l.split(',').filter_map(|s| s.parse().ok()).collect();
                (v.len() == 4).then(|| (v[0] as u64, nalgebra::Point3::new(v[1], v[2], v[3])))
            })
            .collect();
    let res = identify(
        &train,
        &IdentOptions {
            heldout: Some(held),
            ..Default::default()
        },
    )
    .expect("identify");
    let bo = BootstrapOptions {
        k,
        subset: SubsetSize::parse(m).expect("subset"),
        seed: 1,
        ..Default::default()
    };
    let b = bootstrap(&res, &[], &bo).expect("bootstrap");
    println!(
        "bootstrap: {} subsets of {} of {} poses on {} threads: {:.2} s wall ({} failed)",
        k,
        b.subset_size,
        res.train_obs.len(),
        rayon::current_num_threads(),
        b.elapsed_s,
        b.n_failed
    );
    println!(
        "{:8} {:>12} {:>12} {:>10} {:>10} {:>25} {:>8}",
        "param", "full", "mean", "boot std", "cov std", "95% interval", "JB p"
    );
    for (i, name) in b.names.iter().enumerate() {
        let p = res.params.iter().find(|p| &p.name == name).expect("param");
        let f = |v: f64| match p.unit {
            Unit::Mm => v,
            Unit::Rad => v.to_degrees(),
        };
        let s = &b.summaries[i];
        println!(
            "{:8} {:>12.5} {:>12.5} {:>10.5} {:>10.5} [{:>11.5}, {:>11.5}] {:>8.3}",
            name,
            f(b.full[i]),
            f(s.mean),
            f(s.std),
            f(p.std.unwrap_or(f64::NAN)),
            f(s.q025),
            f(s.q975),
            s.normal_p
        );
    }
    println!(
        "max |mean − full| / boot std: {:.3}",
        b.max_mean_shift_sigma
    );
    println!("not normal at 1 %: {:?}", b.non_normal);
    let rms = |m: &robocal::model::KinematicModel| {
        let e: Vec<f64> = res
            .heldout_obs
            .iter()
            .map(|o| (m.measured_point(&o.q) - truth[&o.id]).norm())
            .collect();
        robocal::solve::stats::rms(&e)
    };
    println!(
        "held-out RMS vs truth.csv: full-data fit {:.5} mm, subset-mean model {:.5} mm",
        rms(&res.model),
        rms(&b.mean_model)
    );
}
