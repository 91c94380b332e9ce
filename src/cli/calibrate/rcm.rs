//! `robocal calibrate rcm --data D.jsonl --out DIR`: hand-eye calibration of an endoscope
//! camera from the instrument shaft under a remote-centre-of-motion constraint (seed 002).
use std::path::PathBuf;

use anyhow::Context as _;

use crate::dataset::{CalibrationFile, Dataset};
use crate::solve::rcm;

/// Arguments of `robocal calibrate rcm`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset with an endoscope `camera` and an `instrument` header block and pose records
    /// with `flange` (instrument frame in the base) and `shaft_lines`, or an `image` (the
    /// shaft's silhouettes are then detected in it; refused views are listed and skipped).
    #[arg(long, value_name = "D.jsonl")]
    pub data: PathBuf,
    /// Output directory (`calibration.json`, `rcm_report.json`).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Bootstrap resamples over poses for the uncertainty (0: covariance only).
    #[arg(long, default_value_t = 100)]
    pub bootstrap: usize,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Run `robocal calibrate rcm`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    crate::plausible::limits::bootstrap(args.bootstrap)?;
    let ds = Dataset::load(&args.data)?;
    let data = rcm::RcmData::from_dataset(&ds, &args.data)?;
    if !data.detected.is_empty() {
        let mut q: Vec<f64> = data.detected.iter().map(|(_, d)| d.sigma_px()).collect();
        q.sort_by(f64::total_cmp);
        eprintln!(
            "shaft lines detected in {} image(s): end-point 1-σ median {:.3} px, worst {:.3} px",
            q.len(),
            q[q.len() / 2],
            q[q.len() - 1]
        );
    }
    for r in &data.refused {
        eprintln!("warning: view refused by the line detector: {r}");
    }
    let res = rcm::calibrate(
        &data,
        &rcm::RcmOptions {
            bootstrap: args.bootstrap,
            seed: 2,
        },
    )
    .with_context(|| format!("RCM hand-eye calibration of {}", args.data.display()))?;
    let (cal, report) = rcm::report::calibration_file(&ds.header.robot, &data, &res);
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let cal_path = args.out.join("calibration.json");
    cal.save(&cal_path)?;
    // Everything robocal writes loads back.
    CalibrationFile::load(&cal_path)?;
    let rep_path = args.out.join("rcm_report.json");
    crate::fsio::write(&rep_path, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {}", rep_path.display()))?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print!("{}", rcm::report::text(&res));
        println!("wrote {} and {}", cal_path.display(), rep_path.display());
    }
    Ok(())
}
