//! `robocal chain`: the predicted tool-tip error at CT targets and each link's share
//! (thin adapter over [`crate::chain::chain_report`]).
use std::path::PathBuf;

use anyhow::{bail, Context as _};
use nalgebra::{Matrix3, Matrix6};

use crate::chain::{chain_report, ChainInputs};
use crate::register::robot_world::RobotWorldFile;
use crate::register::{file::cov_from_file, points, RegistrationFile};

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
    let reg = RegistrationFile::load(&a.registration)?;
    let rw = RobotWorldFile::load(&a.robot_world)?;
    let (y, cov_y) = rw.y()?;
    let t = reg.transform()?;
    let cov_total = reg.covariance()?.unwrap_or_else(Matrix6::zeros);
    let (cov_ct, cov_trk) = match (
        &reg.t_tracker_ct.covariance_ct,
        &reg.t_tracker_ct.covariance_tracker,
    ) {
        (Some(c), Some(k)) => (
            cov_from_file(c, "T_tracker_ct.covariance_ct")?,
            cov_from_file(k, "T_tracker_ct.covariance_tracker")?,
        ),
        _ => {
            eprintln!("note: the registration's covariance is not split into CT and tracker parts (no noise model at registration): all of it is reported under `registration: CT localisation`");
            (cov_total, Matrix6::zeros())
        }
    };
    let cov_robot = match (&a.calibration, a.robot_sigma_mm) {
        (Some(path), _) => {
            let cal = crate::dataset::CalibrationFile::load(path)?;
            let q: Vec<f64> = a.joints_deg.iter().map(|d| d.to_radians()).collect();
            let (c, source) = crate::chain::robot_link_from_calibration(&cal, &q)
                .with_context(|| format!("{}", path.display()))?;
            println!(
                "robot link: {source} of {} at the given joints: tip RMS {:.4} mm",
                path.display(),
                c.trace().max(0.0).sqrt()
            );
            c
        }
        (None, Some(s)) => Matrix3::identity() * s.powi(2),
        (None, None) => {
            bail!("give --calibration calibration.json --joints-deg ... or --robot-sigma-mm")
        }
    };
    let inp = ChainInputs {
        t_tracker_ct: t,
        cov_reg_ct: cov_ct,
        cov_reg_tracker: cov_trk,
        t_base_tracker: y,
        cov_y,
        cov_robot,
        cov_tool: Matrix3::identity() * a.tool_sigma_mm.powi(2),
    };
    let targets: Vec<_> = points::read_points_csv(&a.targets)?
        .into_iter()
        .map(|p| (p.name, p.p))
        .collect();
    let r = chain_report(&inp, &targets, a.mc, a.seed)?;
    for t in &r.targets {
        println!(
            "{}: tip error {:.3} mm RMS (MC {:.3}), 95 % ellipsoid {:.3} x {:.3} x {:.3} mm, MC inside 95 %: {:.1} %",
            t.name,
            t.rms_mm,
            t.mc_rms_mm,
            t.ellipsoid95_mm[0],
            t.ellipsoid95_mm[1],
            t.ellipsoid95_mm[2],
            100.0 * t.mc_inside95
        );
        for l in &t.links {
            println!(
                "    {:<36} {:>7.3} mm  {:>5.1} %",
                l.link,
                l.rms_mm,
                100.0 * l.share
            );
        }
    }
    if let Some(out) = &a.out {
        r.save(out)
            .with_context(|| format!("writing {}", out.display()))?;
        println!("wrote {}", out.display());
    }
    Ok(())
}
