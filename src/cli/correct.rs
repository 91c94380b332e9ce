//! `robocal correct --calibration CAL.json --targets poses.csv [--format csv|urscript|pacscript]
//! [--out FILE]`: desired tool poses → corrected joint targets through the identified model's
//! inverse kinematics (thin adapter over [`crate::solve::correct`]). Writes a program or a
//! table; never opens a device.
use std::path::PathBuf;

use anyhow::Context as _;

use crate::dataset::{CalibrationFile, CalibrationKind};
use crate::solve::correct;

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
    let cal = CalibrationFile::load(&args.calibration)
        .with_context(|| format!("reading {}", args.calibration.display()))?;
    anyhow::ensure!(
        cal.kind() == CalibrationKind::Kinematic,
        "{}: a {:?} calibration; `correct` needs a kinematic calibration (robocal calibrate \
         kinematics / session)",
        args.calibration.display(),
        cal.kind()
    );
    for (v, what) in [
        (args.speed, "--speed"),
        (args.accel, "--accel"),
        (args.wait, "--wait"),
    ] {
        anyhow::ensure!(
            v.is_finite() && v > 0.0,
            "{what} must be a positive number, got {v}"
        );
    }
    match args.format {
        Format::Urscript => correct::check_script_motion(true, args.speed, args.accel)?,
        Format::Pacscript => correct::check_script_motion(false, args.speed, args.accel)?,
        Format::Csv => {}
    }
    if !cal.effects.is_empty() {
        eprintln!(
            "warning: {}: {} effect(s) beyond the geometry are not inverted by `correct` \
             (geometric IK only)",
            args.calibration.display(),
            cal.effects.len()
        );
    }
    let (calibrated, nominal) =
        correct::models_of(&cal).with_context(|| format!("{}", args.calibration.display()))?;
    let targets = correct::read_targets(&args.targets)?;
    // Seed 003's correction network of the file (`calibrate navchain`), when it has one.
    let net = crate::navchain::correction::from_calibration(&cal)
        .with_context(|| format!("{}", args.calibration.display()))?;
    let rows = match &net {
        Some(b) => {
            let (rows, largest) = crate::navchain::correct_targets::correct_targets_with_net(
                &calibrated,
                &nominal,
                &targets,
                b,
            )?;
            eprintln!(
                "the calibration's correction network (navchain_net, 6-{}-6) is applied: \
                 positions corrected by up to {largest:.3} mm",
                b.hidden
            );
            rows
        }
        None => correct::correct_targets(&calibrated, &nominal, &targets)?,
    };
    let errs: Vec<f64> = rows.iter().filter_map(|r| r.nominal_pos_err_mm).collect();
    eprintln!(
        "{} targets → {} corrected joint targets (every branch within the limits); the nominal \
         command would miss by RMS {:.3} mm, max {:.3} mm on the calibrated robot",
        targets.len(),
        rows.len(),
        crate::solve::stats::rms(&errs),
        errs.iter().cloned().fold(0.0, f64::max)
    );
    let name = args
        .targets
        .file_stem()
        .map_or("corrected".into(), |s| s.to_string_lossy().into_owned());
    let text = match args.format {
        Format::Csv => correct::to_csv(&rows)?,
        Format::Urscript => crate::plan::export::poses_to_urscript(
            &name,
            &correct::as_plan_poses(&rows),
            args.speed,
            args.accel,
            args.wait,
        ),
        Format::Pacscript => crate::plan::export::poses_to_pacscript(
            &name,
            &correct::as_plan_poses(&rows),
            args.speed,
            args.wait,
        ),
    };
    match &args.out {
        Some(p) => {
            crate::fsio::write_atomic_ctx(p, text.as_bytes())?;
            eprintln!("wrote {}", p.display());
            Ok(())
        }
        None => {
            print!("{text}");
            Ok(())
        }
    }
}
