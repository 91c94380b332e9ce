//! `robocal calibrate nominal --data D.jsonl --out DIR [--heldout FILE]`: the nominal chain
//! with only the tracker → robot-base (6) and flange → marker (3) transforms fitted, in
//! closed form then least squares (no initial guess needed). Writes `DIR/calibration.json`.
use std::path::PathBuf;

use anyhow::Context as _;

use crate::solve::calfile;
use crate::solve::nominal::{fit_nominal, NominalOptions};

/// Arguments of `robocal calibrate nominal`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset (`robocal-dataset/1`); pose records not in group `validation` are fitted.
    #[arg(long, value_name = "D.jsonl")]
    pub data: PathBuf,
    /// Output directory (created if missing); writes `calibration.json`.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Score on this file's pose records instead of the `validation` records of --data.
    #[arg(long, value_name = "FILE.jsonl")]
    pub heldout: Option<PathBuf>,
}

/// Run `robocal calibrate nominal`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    // Strict reader + plausibility; a held-out file must be for the same robot (a held-out
    // error of another robot's model would judge nothing).
    let (ds, held) = crate::plausible::load_with_heldout(&args.data, args.heldout.as_deref())?;
    let fit = fit_nominal(
        &ds,
        &NominalOptions {
            heldout: held.as_ref(),
        },
    )
    .context("nominal fit")?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let file = calfile::nominal_file(&ds.header.robot, &fit);
    let path = args.out.join("calibration.json");
    file.save(&path)
        .with_context(|| format!("writing {}", path.display()))?;
    println!(
        "nominal fit on {} poses ({}): train RMS {:.4} mm",
        fit.n_train,
        fit.termination.describe(),
        fit.train_rms_mm
    );
    match fit.heldout_rms_mm_before {
        Some(h) => println!(
            "held-out RMS {:.4} mm on {} poses (max {:.4} mm)",
            h,
            fit.n_heldout,
            fit.heldout_max_mm_before.unwrap_or(f64::NAN)
        ),
        None => println!("no held-out poses (no `validation` records and no --heldout)"),
    }
    if !fit.skipped.is_empty() {
        println!("skipped {} pose records:", fit.skipped.len());
        for s in fit.skipped.iter().take(10) {
            println!("  id {}: {}", s.id, s.reason);
        }
    }
    let b = fit.model.base();
    let t = fit.model.tool();
    let (rx, ry, rz) = b.rotation.euler_angles();
    println!(
        "base (robot base in tracker): xyz [{:.3}, {:.3}, {:.3}] mm, rpy [{:.4}, {:.4}, {:.4}] deg",
        b.translation.x,
        b.translation.y,
        b.translation.z,
        rx.to_degrees(),
        ry.to_degrees(),
        rz.to_degrees()
    );
    println!(
        "tool (marker in flange): xyz [{:.3}, {:.3}, {:.3}] mm",
        t.translation.x, t.translation.y, t.translation.z
    );
    println!("wrote {}", path.display());
    Ok(())
}
