//! `robocal calibrate navchain --calibration CAL.json --data TRAIN.jsonl [--heldout H.jsonl]
//! --out DIR`: seed 003's 6–n–6 correction network trained on what the kinematic calibration
//! leaves, written into `DIR/calibration.json` (`robocal predict` applies it). Logic in
//! [`crate::navchain::correction`].
use std::path::PathBuf;

use anyhow::Context as _;

use crate::dataset::CalibrationFile;
use crate::navchain::nn::NetOptions;

/// Arguments of `robocal calibrate navchain`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The kinematic calibration the network corrects (`calibrate kinematics` or `diagnose`).
    #[arg(long, value_name = "CAL.json")]
    pub calibration: PathBuf,
    /// Training poses (`robocal-dataset/1`, same robot).
    #[arg(long, value_name = "D.jsonl")]
    pub data: PathBuf,
    /// Held-out poses: the RMS before / after the network is measured on them.
    #[arg(long, value_name = "H.jsonl")]
    pub heldout: Option<PathBuf>,
    /// Output directory (`calibration.json`).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Hidden neurons n.
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u64).range(1..=512))]
    pub hidden: u64,
    /// Training epochs (full-batch Adam).
    #[arg(long, default_value_t = 3000, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub epochs: u64,
    /// Random seed of the initial weights and the training noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// Run `robocal calibrate navchain`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let opts = NetOptions {
        hidden: args.hidden as usize,
        epochs: args.epochs as usize,
        seed: args.seed,
        ..NetOptions::default()
    };
    let cal = crate::navchain::correction::train_files(
        &args.calibration,
        &args.data,
        args.heldout.as_deref(),
        &opts,
    )?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let path = args.out.join("calibration.json");
    cal.save(&path)
        .with_context(|| format!("writing {}", path.display()))?;
    // Loads back, and the block reads back.
    let back = CalibrationFile::load(&path)?;
    let block = crate::navchain::correction::from_calibration(&back)?
        .context("the written calibration has no network block")?;
    println!("{}", crate::navchain::correction::summary(&block));
    println!("wrote {}", path.display());
    Ok(())
}
