//! `robocal calibrate kinematics --data D.jsonl --out DIR [--heldout FILE]
//! [--bootstrap K --subset M] [--huber C] [--orientation]`: full kinematic identification
//! (MDH + Hayati arm, tracker → base, flange → marker) with automatic identifiability,
//! held-out scores before/after, seed-001 metrics and an optional subset bootstrap.
//! Writes `DIR/calibration.json` (and `DIR/bootstrap.csv` with --bootstrap).
use std::io::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;
use serde_json::json;

use crate::model::Unit;
use crate::solve::bootstrap::{bootstrap, BootstrapOptions, SubsetSize};
use crate::solve::kinematics::{identify, IdentOptions};
use crate::solve::{calfile, metrics};

/// Arguments of `robocal calibrate kinematics`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset (`robocal-dataset/1`); pose records not in group `validation` are fitted.
    #[arg(long, value_name = "D.jsonl")]
    pub data: PathBuf,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Held-out poses (default: the `validation` records of --data, else 5-fold CV).
    #[arg(long, value_name = "FILE.jsonl")]
    pub heldout: Option<PathBuf>,
    /// Number of random-subset refits (seed 001: 10000; on site: 100).
    #[arg(long, value_name = "K")]
    pub bootstrap: Option<usize>,
    /// Subset size: a count (200) or a fraction (0.75 or 75%). Default 75%.
    #[arg(long, value_name = "M", default_value = "75%")]
    pub subset: String,
    /// Random seed of the bootstrap.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Huber threshold (mm) on the per-pose error; lists the down-weighted poses.
    #[arg(long, value_name = "C")]
    pub huber: Option<f64>,
    /// Also fit the marker orientation (tool gets 6 parameters).
    #[arg(long)]
    pub orientation: bool,
    /// Fix these parameters in addition to the automatic choice (comma separated).
    #[arg(long, value_delimiter = ',')]
    pub fix: Vec<String>,
    /// Print `calibration.json` on stdout instead of the text summary.
    #[arg(long)]
    pub json: bool,
}

fn show(v: f64, unit: Unit) -> (f64, &'static str) {
    match unit {
        Unit::Mm => (v, "mm"),
        Unit::Rad => (v.to_degrees(), "deg"),
    }
}

/// Run `robocal calibrate kinematics`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    crate::plausible::limits::bootstrap(args.bootstrap.unwrap_or(0))?;
    let quiet = args.json;
    macro_rules! say {
        ($($t:tt)*) => {
            if !quiet {
                println!($($t)*);
            }
        };
    }
    // Strict reader + plausibility; a held-out file must be for the same robot (a held-out
    // error of another robot's model would judge nothing).
    let (ds, held) = crate::plausible::load_with_heldout(&args.data, args.heldout.as_deref())?;
    if let Some(c) = args.huber {
        anyhow::ensure!(
            c.is_finite() && c > 0.0,
            "--huber must be a positive number of mm"
        );
    }
    let opts = IdentOptions {
        heldout: held,
        huber_mm: args.huber,
        orientation: args.orientation,
        fix: args.fix.clone(),
        ..Default::default()
    };
    let res = identify(&ds, &opts).context("kinematic identification")?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let mut file = calfile::ident_file(&ds.header.robot, &res);

    say!(
        "identified {} parameters from {} poses: {} after {} iterations",
        res.x.len(),
        res.train_obs.len(),
        res.termination.describe(),
        res.iterations
    );
    say!(
        "train RMS {:.4} mm (nominal {:.4} mm), residual sigma {:.4} mm",
        res.train_rms_mm,
        res.train_rms_mm_before,
        res.sigma_mm
    );
    match &res.heldout {
        Some(h) => say!(
            "held-out ({}; {} poses): RMS {:.4} → {:.4} mm, max {:.4} → {:.4} mm",
            h.source.describe(),
            h.n,
            h.rms_before,
            h.rms_after,
            h.max_before,
            h.max_after
        ),
        None => say!("no held-out poses and too few poses for cross-validation"),
    }
    say!(
        "identifiability: condition number {:.1} (column-scaled), O1 {:.3e}, O3 {:.3e}",
        res.identifiability.condition,
        res.identifiability.o1,
        res.identifiability.o3
    );
    for f in &res.fixed {
        say!("  fixed {:8} {}", f.name, f.reason);
    }
    if !res.skipped.is_empty() {
        say!(
            "skipped {} pose records (first: id {} — {})",
            res.skipped.len(),
            res.skipped[0].id,
            res.skipped[0].reason
        );
    }
    if let Some(c) = res.huber_mm {
        say!("Huber {c} mm: {} poses down-weighted", res.outliers.len());
        for (id, e) in res.outliers.iter().take(20) {
            say!("  id {id}: {e:.3} mm");
        }
    }
    // Seed-001 metrics on the held-out poses.
    if !res.heldout_obs.is_empty() {
        let pb: Vec<_> = res
            .heldout_obs
            .iter()
            .map(|o| res.nominal.measured_point(&o.q))
            .collect();
        let pa: Vec<_> = res
            .heldout_obs
            .iter()
            .map(|o| res.model.measured_point(&o.q))
            .collect();
        let sb = metrics::score(&res.heldout_obs, &pb);
        let sa = metrics::score(&res.heldout_obs, &pa);
        if let (Some(b), Some(a)) = (&sb.relative, &sa.relative) {
            say!(
                "relative distance error: {:.4} % → {:.4} %",
                b.mean_pct,
                a.mean_pct
            );
            file.metrics
                .insert("relative_distance_pct_before".into(), json!(b.mean_pct));
            file.metrics
                .insert("relative_distance_pct_after".into(), json!(a.mean_pct));
        }
        if let (Some(b), Some(a)) = (&sb.coincidence, &sa.coincidence) {
            say!(
                "inverse-solution coincidence error ({} points): {:.4} → {:.4} mm",
                a.per_point.len(),
                b.mean_mm,
                a.mean_mm
            );
            file.metrics
                .insert("coincidence_mm_before".into(), json!(b.mean_mm));
            file.metrics
                .insert("coincidence_mm_after".into(), json!(a.mean_mm));
        } else {
            say!("inverse-solution coincidence error: no held-out point reached by several IK branches");
        }
        if let (Some(b), Some(a)) = (&sb.iso, &sa.iso) {
            say!(
                "ISO 9283 ({} repeated targets): AP {:.4} → {:.4} mm, RP {:.4} mm",
                a.targets,
                b.ap_mean_mm,
                a.ap_mean_mm,
                a.rp_mean_mm
            );
            file.metrics
                .insert("iso9283_ap_mm_before".into(), json!(b.ap_mean_mm));
            file.metrics
                .insert("iso9283_ap_mm_after".into(), json!(a.ap_mean_mm));
            file.metrics
                .insert("iso9283_rp_mm".into(), json!(a.rp_mean_mm));
        }
    }
    if let Some(k) = args.bootstrap {
        let bo = BootstrapOptions {
            k,
            subset: SubsetSize::parse(&args.subset)?,
            seed: args.seed,
            ..Default::default()
        };
        let b = bootstrap(&res, &opts.effects, &bo).context("bootstrap")?;
        say!(
            "bootstrap: {} fits of {} poses in {:.2} s ({} failed); max |mean − full| = {:.2} σ",
            b.samples.len(),
            b.subset_size,
            b.elapsed_s,
            b.n_failed,
            b.max_mean_shift_sigma
        );
        let mut heldout_mean = None;
        if !res.heldout_obs.is_empty() {
            let e = crate::solve::kinematics::model_errors(&b.mean_model, &res.heldout_obs);
            let r = crate::solve::stats::rms(&e);
            say!("held-out RMS of the subset-mean model: {r:.4} mm (full-data fit kept as final)");
            heldout_mean = Some(r);
        }
        if !b.non_normal.is_empty() {
            say!(
                "not normal at 1 % (Jarque–Bera): {}",
                b.non_normal.join(", ")
            );
        }
        let path = args.out.join("bootstrap.csv");
        // Built in memory, then written atomically (a kill never leaves half a file).
        let mut w: Vec<u8> = Vec::new();
        writeln!(
            w,
            "name,unit,full,mean,std,q025,q975,skewness,excess_kurtosis,normal_p"
        )?;
        let units: std::collections::HashMap<&str, Unit> = res
            .params
            .iter()
            .map(|p| (p.name.as_str(), p.unit))
            .collect();
        for (i, name) in b.names.iter().enumerate() {
            let s = &b.summaries[i];
            let u = units.get(name.as_str()).copied().unwrap_or(Unit::Mm);
            let c = |v: f64| show(v, u).0;
            writeln!(
                w,
                "{name},{},{},{},{},{},{},{:.4},{:.4},{:.4}",
                show(0.0, u).1,
                c(b.full[i]),
                c(s.mean),
                c(s.std),
                c(s.q025),
                c(s.q975),
                s.skewness,
                s.excess_kurtosis,
                s.normal_p
            )?;
            if let Some(p) = file.params.iter_mut().find(|p| &p.name == name) {
                p.extra.insert(
                    "bootstrap".into(),
                    json!({"mean": c(s.mean), "std": c(s.std), "ci95": [c(s.q025), c(s.q975)], "normal_p": s.normal_p}),
                );
            }
        }
        crate::fsio::write_atomic_ctx(&path, &w)?;
        file.extra.insert(
            "bootstrap".into(),
            json!({"k": b.n_requested, "converged": b.samples.len(), "subset": b.subset_size,
                   "seed": args.seed, "seconds": b.elapsed_s,
                   "max_mean_shift_sigma": b.max_mean_shift_sigma,
                   "non_normal": b.non_normal, "heldout_rms_mm_mean_model": heldout_mean,
                   "covariance": crate::navchain::BootstrapCovariance::from_samples(&b.names, &b.samples),
                   "final": "full-data fit (the subset mean is reported per parameter)"}),
        );
        say!("wrote {}", path.display());
    }
    let path = args.out.join("calibration.json");
    file.save(&path)
        .with_context(|| format!("writing {}", path.display()))?;
    if quiet {
        println!("{}", std::fs::read_to_string(&path)?);
    }
    say!("wrote {}", path.display());
    say!("parameters (value ± std, nominal):");
    for p in res.params.iter().filter(|p| p.free) {
        let (v, u) = show(p.value, p.unit);
        let (n, _) = show(p.nominal, p.unit);
        let s = p.std.map(|s| show(s, p.unit).0).unwrap_or(f64::NAN);
        say!(
            "  {:8} {:>12.5} ± {:.5} {u}  (nominal {:.5})",
            p.name,
            v,
            s,
            n
        );
    }
    Ok(())
}
