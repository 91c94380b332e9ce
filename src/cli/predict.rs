//! `robocal predict --calibration CAL.json --data DATA.jsonl [--out FILE.csv]`: a thin
//! adapter over [`crate::solve::predict`] (warnings go to stderr).
use std::path::PathBuf;

use anyhow::Context as _;

use crate::dataset::{CalibrationFile, CalibrationKind};

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
    #[arg(long, value_name = "DATA.jsonl", required_unless_present = "points")]
    pub data: Option<PathBuf>,
    /// CT points (CSV `name,x_mm,y_mm,z_mm`) mapped into the tracker frame by a
    /// `robocal-registration/1` calibration; writes CSV `name,x_mm,y_mm,z_mm`.
    #[arg(long, value_name = "P.csv", conflicts_with = "data")]
    pub points: Option<PathBuf>,
    /// The other pose records of the same session (e.g. a diagnosis' training file): used
    /// only for where the arm came from before each pose when records carry no `q_prev`
    /// (backlash), as the diagnosis does.
    #[arg(long, value_name = "SESSION.jsonl", requires = "data")]
    pub session: Option<PathBuf>,
    /// Write the CSV here instead of to stdout.
    #[arg(long, value_name = "FILE.csv")]
    pub out: Option<PathBuf>,
}

/// Run `robocal predict`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    if let Some(pts) = &args.points {
        let rows = crate::register::run::predict_points(&args.calibration, pts)?;
        return match &args.out {
            Some(path) => {
                let mut buf = Vec::new();
                crate::register::write_points_csv(&mut buf, &rows)
                    .with_context(|| format!("writing {}", path.display()))?;
                crate::fsio::write_atomic_ctx(path, &buf)
            }
            None => crate::register::write_points_csv(std::io::stdout().lock(), &rows)
                .context("writing to stdout"),
        };
    }
    if CalibrationFile::load(&args.calibration)?.kind() == CalibrationKind::Other("camera".into()) {
        return camera_exec(&args);
    }
    let Some(data) = &args.data else {
        anyhow::bail!(
            "give --data DATA.jsonl (pose records) or --points P.csv (with a registration)"
        );
    };
    let (rows, warnings) = crate::solve::predict::predict_files_in_session(
        &args.calibration,
        data,
        args.session.as_deref(),
    )?;
    for w in &warnings {
        eprintln!("warning: {}: {w}", data.display());
    }
    match &args.out {
        Some(path) => {
            let mut buf = Vec::new();
            write_csv(&mut buf, &rows).with_context(|| format!("writing {}", path.display()))?;
            crate::fsio::write_atomic_ctx(path, &buf)?;
        }
        None => {
            let stdout = std::io::stdout();
            write_csv(stdout.lock(), &rows).context("writing to stdout")?;
        }
    }
    Ok(())
}

/// `robocal predict` on a camera calibration: CSV `id,corner,u_px,v_px`.
fn camera_exec(args: &Args) -> anyhow::Result<()> {
    let Some(data) = &args.data else {
        anyhow::bail!(
            "a camera calibration predicts the corners of a dataset: give --data DATA.jsonl"
        );
    };
    let rows = crate::solve::camera::calfile::predict_rows(&args.calibration, data)?;
    let mut text = String::from("id,corner,u_px,v_px\n");
    for (id, c, uv) in rows {
        text += &format!("{id},{c},{:.6},{:.6}\n", uv[0], uv[1]);
    }
    match &args.out {
        Some(p) => {
            crate::fsio::write(p, text).with_context(|| format!("writing {}", p.display()))?
        }
        None => print!("{text}"),
    }
    Ok(())
}
