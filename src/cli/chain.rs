//! `robocal chain`: the predicted tool-tip error at CT targets and each link's share
//! (thin adapter over [`crate::navchain::chain_report`]).
use std::path::PathBuf;

use anyhow::{bail, Context as _};

use crate::navchain::{chain_from_files, report_text, ChainFiles, RobotLinkSource};

/// Arguments of `robocal chain`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// CT → tracker registration (`robocal-registration/1`).
    #[arg(long, value_name = "registration.json")]
    pub registration: PathBuf,
    /// Tracker → robot registration (`robocal-robot-world/1`, from `calibrate robot-world`).
    #[arg(long, value_name = "robot_world.json")]
    pub robot_world: PathBuf,
    /// CT targets, CSV `name,x_mm,y_mm,z_mm`.
    #[arg(long, value_name = "T.csv")]
    pub targets: PathBuf,
    /// Robot calibration (`robocal-calibration/1` from `calibrate kinematics`): the robot
    /// link is its bootstrap parameter covariance (`--bootstrap`; else the per-parameter
    /// σ) propagated to the tip at `--joints-deg`.
    #[arg(
        long,
        value_name = "calibration.json",
        requires = "joints_deg",
        conflicts_with = "robot_sigma_mm"
    )]
    pub calibration: Option<PathBuf>,
    /// Joint configuration (deg, comma-separated) where the robot reaches the targets.
    #[arg(
        long,
        value_name = "Q1,Q2,...",
        value_delimiter = ',',
        allow_hyphen_values = true
    )]
    pub joints_deg: Vec<f64>,
    /// Fallback without a calibration: robot tip positioning error, 1σ per axis (mm)
    /// (e.g. held-out RMS/√3).
    #[arg(long, value_name = "MM", required_unless_present = "calibration")]
    pub robot_sigma_mm: Option<f64>,
    /// Tool tip offset uncertainty, 1σ per axis (mm) (pivot calibration).
    #[arg(long, value_name = "MM", default_value_t = 0.0)]
    pub tool_sigma_mm: f64,
    /// Monte Carlo samples per target.
    #[arg(long, default_value_t = 20_000)]
    pub mc: usize,
    /// Monte Carlo seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write `chain.json` here.
    #[arg(long, value_name = "chain.json")]
    pub out: Option<PathBuf>,
}

/// Run `robocal chain`.
pub fn exec(a: Args) -> anyhow::Result<()> {
    for (v, n) in [
        (a.robot_sigma_mm.unwrap_or(0.0), "--robot-sigma-mm"),
        (a.tool_sigma_mm, "--tool-sigma-mm"),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            bail!("{n} must be a finite number ≥ 0 (mm), got {v}");
        }
    }
    if a.mc == 0 || a.mc > 10_000_000 {
        bail!("--mc must be in 1..=10000000");
    }
    let robot = match (&a.calibration, a.robot_sigma_mm) {
        (Some(path), _) => RobotLinkSource::Calibration {
            path,
            joints_deg: &a.joints_deg,
        },
        (None, Some(s)) => RobotLinkSource::SigmaMm(s),
        (None, None) => {
            bail!("give --calibration calibration.json --joints-deg ... or --robot-sigma-mm")
        }
    };
    let files = ChainFiles {
        registration: &a.registration,
        robot_world: &a.robot_world,
        targets: &a.targets,
        robot,
        tool_sigma_mm: a.tool_sigma_mm,
    };
    let mut notes = Vec::new();
    let r = chain_from_files(&files, a.mc, a.seed, &mut notes)?;
    for n in &notes {
        if n.starts_with("robot link") {
            println!("{n}");
        } else {
            eprintln!("note: {n}");
        }
    }
    print!("{}", report_text(&r));
    if let Some(out) = &a.out {
        r.save(out)
            .with_context(|| format!("writing {}", out.display()))?;
        println!("wrote {}", out.display());
    }
    Ok(())
}
