//! Figures of the kinematic identification on the reference datasets (`tests/data/kin-*`):
//! nominal ("before") and identified ("after") held-out RMS against the simulator's
//! noise-free `truth.csv`, timing of one fit, identifiability report.
//!
//! `cargo run --release --example ident_kin_geometric`
use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use robocal::dataset::Dataset;
use robocal::solve::kinematics::{identify, IdentOptions};
use robocal::solve::nominal::{fit_nominal, NominalOptions};

fn read_csv(path: &Path) -> HashMap<u64, [f64; 3]> {
    let text = std::fs::read_to_string(path).expect("csv");
    text.lines()
        .skip(1)
        .filter_map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            Some((
                v.first()?.parse().ok()?,
                [v[1].parse().ok()?, v[2].parse().ok()?, v[3].parse().ok()?],
            ))
        })
        .collect()
}

fn rms_vs(
    truth: &HashMap<u64, [f64; 3]>,
    pred: impl Iterator<Item = (u64, nalgebra::Point3<f64>)>,
) -> (f64, usize) {
    let mut s = 0.0;
    let mut n = 0;
    for (id, p) in pred {
        if let Some(t) = truth.get(&id) {
            s += (p - nalgebra::Point3::new(t[0], t[1], t[2])).norm_squared();
            n += 1;
        }
    }
    ((s / n.max(1) as f64).sqrt(), n)
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    for case in ["kin-geometric", "kin-compliance-j2"] {
        let dir = root.join(case);
        let train = Dataset::load(dir.join("train.jsonl")).expect("train");
        let held = Dataset::load(dir.join("heldout.jsonl")).expect("heldout");
        let truth = read_csv(&dir.join("truth.csv"));
        let nominal_csv = read_csv(&dir.join("nominal.csv"));
        let t0 = Instant::now();
        let nom = fit_nominal(
            &train,
            &NominalOptions {
                heldout: Some(&held),
            },
        )
        .expect("nominal");
        let t_nom = t0.elapsed();
        let hobs: Vec<_> = held
            .poses()
            .filter_map(|r| robocal::solve::PoseObs::from_record(r, nom.model.dof()).ok())
            .collect();
        let (nom_vs_truth, n) = rms_vs(
            &truth,
            hobs.iter().map(|o| (o.id, nom.model.measured_point(&o.q))),
        );
        let (nom_vs_ref, _) = rms_vs(
            &nominal_csv,
            hobs.iter().map(|o| (o.id, nom.model.measured_point(&o.q))),
        );
        let opts = IdentOptions {
            heldout: Some(held.clone()),
            ..Default::default()
        };
        let t1 = Instant::now();
        let res = identify(&train, &opts).expect("identify");
        let t_id = t1.elapsed();
        let (after_vs_truth, _) = rms_vs(
            &truth,
            hobs.iter().map(|o| (o.id, res.model.measured_point(&o.q))),
        );
        // Timing of the bare fit (nominal init + identifiability + LM), median of 5.
        let chain = robocal::model::KinematicModel::from_robot_block(&train.header.robot).unwrap();
        let (tobs, _) = robocal::solve::obs::observations(
            &train,
            chain.dof(),
            robocal::solve::obs::Split::Train,
        );
        let mut times: Vec<f64> = (0..5)
            .map(|_| {
                let t = Instant::now();
                let f = robocal::solve::kinematics::core_fit(&chain, &tobs, &opts).expect("fit");
                std::hint::black_box(&f.x);
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        times.sort_by(f64::total_cmp);
        println!(
            "one fit of {} poses ({} free params): {:.1} ms (median of 5)",
            tobs.len(),
            res.x.len(),
            times[2]
        );
        println!(
            "== {case} ({} train poses, {n} held-out poses)",
            nom.n_train
        );
        println!(
            "nominal fit: {:.1} ms, train RMS {:.4} mm, held-out RMS vs measured {:.4} mm",
            t_nom.as_secs_f64() * 1e3,
            nom.train_rms_mm,
            nom.heldout_rms_mm_before.unwrap_or(f64::NAN)
        );
        println!("nominal prediction vs reference nominal.csv: RMS {nom_vs_ref:.5} mm");
        println!("BEFORE held-out RMS vs truth.csv: {nom_vs_truth:.4} mm");
        println!("AFTER  held-out RMS vs truth.csv: {after_vs_truth:.4} mm");
        println!(
            "identify: {:.1} ms total ({} free params, {} iterations, {}), train RMS {:.4} mm, sigma {:.4} mm",
            t_id.as_secs_f64() * 1e3,
            res.x.len(),
            res.iterations,
            res.termination.describe(),
            res.train_rms_mm,
            res.sigma_mm
        );
        if let Some(h) = &res.heldout {
            println!(
                "held-out vs measured: before {:.4} mm (max {:.3}), after {:.4} mm (max {:.3})",
                h.rms_before, h.max_before, h.rms_after, h.max_after
            );
        }
        println!(
            "identifiability: cond {:.1}, O1 {:.3e}, O3 {:.3e}; fixed:",
            res.identifiability.condition, res.identifiability.o1, res.identifiability.o3
        );
        for f in &res.fixed {
            println!("  {:8} {}", f.name, f.reason);
        }
        let minsine = res
            .identifiability
            .kept
            .iter()
            .map(|(k, s)| (res.identifiability.names[*k].clone(), *s))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        println!(
            "  weakest kept column: {minsine:?}; weakest direction {:?}",
            res.identifiability.weakest
        );
    }
}
