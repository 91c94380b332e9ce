//! `robocal diagnose`: argument parsing and printing over [`crate::diagnose::stage`] (fit the
//! geometric model, find the effect the residual points to, add it, report the held-out error
//! before and after).
//!
//! Writes `DIR/diagnosis.json`, `DIR/calibration.json` (`robocal-calibration/1` with the
//! effects, read by `robocal predict`), `DIR/report.md`, `DIR/heldout_predictions.csv`
//! (`id,x_mm,y_mm,z_mm` of every held-out pose, predicted with the full session context) and
//! one `DIR/effect_<n>_<kind>.svg` partial-residual plot per accepted effect.
use std::path::PathBuf;

use crate::diagnose::determined::GeometricTolerance;
use crate::diagnose::stage::{self, DiagnoseRequest};

/// Arguments of `robocal diagnose`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset (`robocal-dataset/1`); `group: validation` records are held out.
    #[arg(long)]
    pub data: PathBuf,
    /// Output directory (created).
    #[arg(long)]
    pub out: PathBuf,
    /// Start from this calibration's parameters instead of the header's nominal chain.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Held-out poses in a separate dataset of the same session.
    #[arg(long)]
    pub heldout: Option<PathBuf>,
    /// Do not add a nonparametric correction even if structured residual remains.
    #[arg(long)]
    pub no_nonparametric: bool,
    /// Only the physics-first chain: accept every physical effect that passes the
    /// significance, ΔBIC, time-blocked CV and independence tests (up to 6), even when it
    /// explains less than half of what a kernel regression explains, then add the correction
    /// for the rest. On an effect outside the library it may name a library effect that only
    /// resembles it. (The default runs this chain and the kernel-benchmark one and keeps the
    /// one whose final model predicts time-blocked folds of the training data better.)
    #[arg(long, conflicts_with = "kernel_benchmark")]
    pub physics_first: bool,
    /// Only the kernel-benchmark chain (the earlier default policy): a physical effect must
    /// explain half of what a kernel regression on joint space explains.
    #[arg(long)]
    pub kernel_benchmark: bool,
    /// Do not add the transmission error maps (each joint's gear error over its turn, many
    /// harmonics with a smoothness prior) after the named effects.
    #[arg(long)]
    pub no_transmission_map: bool,
    /// Standard deviations of the prior that holds the geometric parameters near their
    /// nominal values, as `MM,DEG` (default 5,0.5): a parameter the poses determine is
    /// unaffected; one they hardly see (a narrow workspace, joints that always move together)
    /// stays near nominal and is named. Widen it for an arm whose nominal model is known to be
    /// far off.
    #[arg(long, value_name = "MM,DEG", value_parser = parse_geometric_prior, conflicts_with = "no_geometric_prior")]
    pub geometric_prior: Option<GeometricTolerance>,
    /// Fit every free geometric parameter without a prior (a narrow workspace may then move
    /// parameters the poses hardly see by degrees).
    #[arg(long)]
    pub no_geometric_prior: bool,
    /// Print `diagnosis.json` on stdout instead of the text summary.
    #[arg(long)]
    pub json: bool,
}

/// Run `robocal diagnose`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let out = stage::run(&args.request())?;
    if args.json {
        let p = args.out.join("diagnosis.json");
        match crate::fsio::read_to_string(&p) {
            Ok(text) => println!("{text}"),
            // Laser diagnoses write their own report file.
            Err(_) => println!("{}", serde_json::json!({ "summary": out })),
        }
    } else {
        println!("{out}");
    }
    Ok(())
}

impl Args {
    /// The diagnosis this command line asks for.
    pub fn request(&self) -> DiagnoseRequest {
        DiagnoseRequest {
            data: self.data.clone(),
            out: self.out.clone(),
            calibration: self.calibration.clone(),
            heldout: self.heldout.clone(),
            no_nonparametric: self.no_nonparametric,
            physics_first: self.physics_first,
            kernel_benchmark: self.kernel_benchmark,
            no_transmission_map: self.no_transmission_map,
            geometric_prior: self.geometric_prior,
            no_geometric_prior: self.no_geometric_prior,
        }
    }
}

/// `--geometric-prior MM,DEG`: two positive, finite numbers.
fn parse_geometric_prior(s: &str) -> Result<GeometricTolerance, String> {
    let bad = || {
        format!(
            "{s:?} is not MM,DEG: give the prior's standard deviations of lengths (mm) and angles (degrees), two positive numbers, e.g. 5,0.5"
        )
    };
    let (mm, deg) = s.split_once(',').ok_or_else(bad)?;
    let num = |v: &str| -> Result<f64, String> {
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite() && *x > 0.0)
            .ok_or_else(bad)
    };
    Ok(GeometricTolerance {
        mm: num(mm)?,
        deg: num(deg)?,
    })
}
