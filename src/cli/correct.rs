//! `robocal correct --calibration CAL.json --targets poses.csv [--format csv|urscript|pacscript]
//! [--out FILE]`: desired tool poses → corrected joint targets through the identified model's
//! inverse kinematics (thin adapter over [`crate::calibrate::correct`]). Writes a program or a
//! table; never opens a device.
use std::path::PathBuf;

/// Output format of `robocal correct`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// Table: corrected and nominal joints (deg), nominal error, compensated pose.
    Csv,
    /// UR program: `movej` to each corrected joint target (rad).
    Urscript,
    /// DENSO PacScript: `Move P, J(...)` (deg).
    Pacscript,
}

/// Arguments of `robocal correct`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Kinematic calibration (`robocal-calibration/1`).
    #[arg(long, value_name = "CAL.json")]
    pub calibration: PathBuf,
    /// Desired tool poses in the robot base: `name,x_mm,y_mm,z_mm,qw,qx,qy,qz[,branch]`.
    #[arg(long, value_name = "poses.csv")]
    pub targets: PathBuf,
    #[arg(long, value_enum, default_value = "csv")]
    pub format: Format,
    /// Write here instead of stdout.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// URScript joint speed (rad/s) and acceleration (rad/s²); PacScript speed (%).
    #[arg(long, default_value_t = 0.2)]
    pub speed: f64,
    #[arg(long, default_value_t = 0.5)]
    pub accel: f64,
    /// Wait at each target (s).
    #[arg(long, default_value_t = 2.0)]
    pub wait: f64,
}

/// Run `robocal correct`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    use crate::calibrate::correct::{run, Options, Output};
    let output = match args.format {
        Format::Csv => Output::Csv,
        Format::Urscript => Output::Urscript,
        Format::Pacscript => Output::Pacscript,
    };
    let text = run(
        &Options {
            calibration: &args.calibration,
            targets: &args.targets,
            output,
            speed: args.speed,
            accel: args.accel,
            wait: args.wait,
        },
        &mut |l| eprintln!("{l}"),
    )?;
    match &args.out {
        Some(p) => {
            crate::fsio::write_atomic_ctx(p, text.as_bytes())?;
            eprintln!("wrote {}", p.display());
        }
        None => print!("{text}"),
    }
    Ok(())
}
