//! `robocal calibrate kinematics --data D.jsonl --out DIR [--heldout FILE]
//! [--bootstrap K --subset M] [--huber C] [--orientation]`: full kinematic identification
//! (MDH + Hayati arm, tracker → base, flange → marker) with automatic identifiability,
//! held-out scores before/after, seed-001 metrics and an optional subset bootstrap.
//! Writes `DIR/calibration.json` (and `DIR/bootstrap.csv` with --bootstrap).
//! The work is in [`crate::calibrate::kinematics`]; this file parses and prints.
use std::path::PathBuf;

use crate::calibrate::kinematics::{
    calibrate, show, BootstrapReport, HeldoutMetrics, KinematicsCalibration, KinematicsOptions,
};

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

/// Run `robocal calibrate kinematics`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let r = calibrate(&KinematicsOptions {
        data: args.data,
        out: args.out,
        heldout: args.heldout,
        bootstrap: args.bootstrap,
        subset: args.subset,
        seed: args.seed,
        huber_mm: args.huber,
        orientation: args.orientation,
        fix: args.fix,
    })?;
    if args.json {
        println!("{}", std::fs::read_to_string(&r.calibration)?);
        return Ok(());
    }
    print_fit(&r);
    if let Some(m) = &r.metrics {
        print_metrics(m);
    }
    if let Some(b) = &r.bootstrap {
        print_bootstrap(b);
    }
    println!("wrote {}", r.calibration.display());
    println!("parameters (value ± std, nominal):");
    for p in r.ident.params.iter().filter(|p| p.free) {
        let (v, u) = show(p.value, p.unit);
        let (n, _) = show(p.nominal, p.unit);
        let s = p.std.map(|s| show(s, p.unit).0).unwrap_or(f64::NAN);
        println!(
            "  {:8} {:>12.5} ± {:.5} {u}  (nominal {:.5})",
            p.name, v, s, n
        );
    }
    Ok(())
}

/// The fit: iterations, RMS, held-out scores, identifiability, skipped and down-weighted poses.
fn print_fit(r: &KinematicsCalibration) {
    let res = &r.ident;
    println!(
        "identified {} parameters from {} poses: {} after {} iterations",
        res.x.len(),
        res.train_obs.len(),
        res.termination.describe(),
        res.iterations
    );
    println!(
        "train RMS {:.4} mm (nominal {:.4} mm), residual sigma {:.4} mm",
        res.train_rms_mm, res.train_rms_mm_before, res.sigma_mm
    );
    match &res.heldout {
        Some(h) => println!(
            "held-out ({}; {} poses): RMS {:.4} → {:.4} mm, max {:.4} → {:.4} mm",
            h.source.describe(),
            h.n,
            h.rms_before,
            h.rms_after,
            h.max_before,
            h.max_after
        ),
        None => println!("no held-out poses and too few poses for cross-validation"),
    }
    println!(
        "identifiability: condition number {:.1} (column-scaled), O1 {:.3e}, O3 {:.3e}",
        res.identifiability.condition, res.identifiability.o1, res.identifiability.o3
    );
    for f in &res.fixed {
        println!("  fixed {:8} {}", f.name, f.reason);
    }
    if !res.skipped.is_empty() {
        println!(
            "skipped {} pose records (first: id {} — {})",
            res.skipped.len(),
            res.skipped[0].id,
            res.skipped[0].reason
        );
    }
    if let Some(c) = res.huber_mm {
        println!("Huber {c} mm: {} poses down-weighted", res.outliers.len());
        for (id, e) in res.outliers.iter().take(20) {
            println!("  id {id}: {e:.3} mm");
        }
    }
}

/// Seed 001's metrics on the held-out poses, before → after.
fn print_metrics(m: &HeldoutMetrics) {
    let (sb, sa) = (&m.before, &m.after);
    if let (Some(b), Some(a)) = (&sb.relative, &sa.relative) {
        println!(
            "relative distance error: {:.4} % → {:.4} %",
            b.mean_pct, a.mean_pct
        );
    }
    if let (Some(b), Some(a)) = (&sb.coincidence, &sa.coincidence) {
        println!(
            "inverse-solution coincidence error ({} points): {:.4} → {:.4} mm",
            a.per_point.len(),
            b.mean_mm,
            a.mean_mm
        );
    } else {
        println!(
            "inverse-solution coincidence error: no held-out point reached by several IK branches"
        );
    }
    if let (Some(b), Some(a)) = (&sb.iso, &sa.iso) {
        println!(
            "ISO 9283 ({} repeated targets): AP {:.4} → {:.4} mm, RP {:.4} mm",
            a.targets, b.ap_mean_mm, a.ap_mean_mm, a.rp_mean_mm
        );
    }
}

/// The bootstrap's summary.
fn print_bootstrap(r: &BootstrapReport) {
    let b = &r.result;
    println!(
        "bootstrap: {} fits of {} poses in {:.2} s ({} failed); max |mean − full| = {:.2} σ",
        b.samples.len(),
        b.subset_size,
        b.elapsed_s,
        b.n_failed,
        b.max_mean_shift_sigma
    );
    if let Some(r) = r.heldout_rms_mm_mean_model {
        println!("held-out RMS of the subset-mean model: {r:.4} mm (full-data fit kept as final)");
    }
    if !b.non_normal.is_empty() {
        println!(
            "not normal at 1 % (Jarque–Bera): {}",
            b.non_normal.join(", ")
        );
    }
    println!("wrote {}", r.csv.display());
}
