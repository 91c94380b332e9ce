//! `robocal predict --calibration CAL.json --data DATA.jsonl [--out FILE.csv]`: a thin
//! adapter over [`crate::solve::predict`] (warnings go to stderr).
use std::path::PathBuf;

use anyhow::Context as _;

pub use crate::solve::predict::{
    predict_files, predict_files_warn, write_csv, PredictedPoint, Predictor,
};

/// Arguments of `robocal predict`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Calibration file (`robocal-calibration/1`).
    #[arg(long, value_name = "CAL.json")]
    pub calibration: PathBuf,
    /// Dataset (`robocal-dataset/1`) whose pose records are predicted.
    #[arg(long, value_name = "DATA.jsonl")]
    pub data: PathBuf,
    /// Write the CSV here instead of to stdout.
    #[arg(long, value_name = "FILE.csv")]
    pub out: Option<PathBuf>,
}

/// Run `robocal predict`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let (rows, warnings) = predict_files_warn(&args.calibration, &args.data)?;
    for w in &warnings {
        eprintln!("warning: {}: {w}", args.data.display());
    }
    match &args.out {
        Some(path) => {
            let f = std::fs::File::create(path)
                .with_context(|| format!("creating {}", path.display()))?;
            write_csv(std::io::BufWriter::new(f), &rows)
                .with_context(|| format!("writing {}", path.display()))?;
        }
        None => {
            let stdout = std::io::stdout();
            write_csv(stdout.lock(), &rows).context("writing to stdout")?;
        }
    }
    Ok(())
}
