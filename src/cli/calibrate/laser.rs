//! `robocal calibrate laser`: hand-eye calibration of a laser range sensor from planes (seed 000).

use anyhow::Context as _;
use std::path::PathBuf;

use crate::solve::laser;
use crate::solve::laser::stage::{load_heldout, scan_report};

/// Arguments of `robocal calibrate laser`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset with plane-labelled calibration poses (`plane`, `move`, `range`, flange or `q`);
    /// validation targets (`target`) in it are used for scoring.
    #[arg(long, value_name = "D.jsonl")]
    pub data: PathBuf,
    /// Output directory (`calibration.json`, `laser_report.json`).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Extra dataset with the 5-direction validation targets (held out).
    #[arg(long, value_name = "FILE")]
    pub heldout: Option<PathBuf>,
    /// CSV `id,x_mm,y_mm,z_mm` of true/reference points of the validation records (FRE/TRE,
    /// spot RMS).
    #[arg(long, value_name = "CSV")]
    pub truth: Option<PathBuf>,
    /// Huber threshold (mm) for the direct fit (robust loss; outliers are listed).
    #[arg(long, value_name = "MM")]
    pub huber: Option<f64>,
    /// Print the comparison as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// A scan to reconstruct with the final calibration (pose records with `range`; the
    /// `target` label names the face/surface of each point): the angles between faces (a
    /// known block checks the whole chain) and
    /// per-face flatness are printed and written to `scan_report.json`.
    #[arg(long, value_name = "SCAN.jsonl")]
    pub scan: Option<PathBuf>,
    /// The arm's kinematic calibration (`robocal calibrate kinematics` / a kinematic session's
    /// `deploy/calibration.json`): every flange pose is computed from the recorded joints
    /// through the identified arm (geometry) instead of the controller's nominal flange.
    #[arg(long, value_name = "CAL.json")]
    pub calibration: Option<PathBuf>,
    /// Write the reconstructed scan as a PLY point cloud (needs `--scan`).
    #[arg(long, value_name = "OUT.ply", requires = "scan")]
    pub ply: Option<PathBuf>,
}

/// Run `robocal calibrate laser`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let ds = crate::plausible::load_checked(&args.data)?;
    let arm = match &args.calibration {
        Some(c) => Some(laser::identified_arm(c, &ds, &args.data)?),
        None => None,
    };
    let obs = laser::observations_through(&ds, arm.as_ref())
        .with_context(|| format!("reading laser poses of {}", args.data.display()))?;
    let mut validation: Vec<laser::LaserObs> =
        obs.iter().filter(|o| o.target.is_some()).cloned().collect();
    let train: Vec<laser::LaserObs> = obs.iter().filter(|o| o.plane.is_some()).cloned().collect();
    if let Some(h) = &args.heldout {
        let hd = load_heldout(h, &ds, &args.data, arm.as_ref())?;
        validation.extend(hd);
    }
    let truth = match &args.truth {
        Some(p) => {
            let t = crate::schema::points_csv::read(p)?;
            laser::validate::check_truth_units(&t, &validation, p)?;
            Some(t)
        }
        None => None,
    };
    let cmp = laser::compare(&train, &validation, truth.as_ref(), args.huber)
        .context("laser hand-eye calibration")?;
    let beam = cmp.final_beam.context("no final beam")?;
    let mut cal = laser::calibration_file(ds.header.robot.clone(), &cmp)?;
    cal.extra.insert(
        "flange_poses".into(),
        match &args.calibration {
            Some(c) => format!("joints through the identified arm of {}", c.display()),
            None => "as recorded (the controller's nominal kinematics)".into(),
        }
        .into(),
    );
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    cal.save(args.out.join("calibration.json"))?;
    let report = cmp.to_report_file();
    crate::schema::write(&args.out.join("laser_report.json"), &report)?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print!("{}", laser::table(&cmp));
        println!(
            "final: r = ({:.3}, {:.3}, {:.3}) mm, v = ({:.6}, {:.6}, {:.6}); plane RMS {:.4} mm; {}",
            beam.r.x, beam.r.y, beam.r.z, beam.v.x, beam.v.y, beam.v.z, cmp.final_plane_rms_mm,
            cmp.final_termination
        );
        if !cmp.outliers.is_empty() {
            println!("outliers (ids): {:?}", cmp.outliers);
        }
        println!("wrote {}", args.out.join("calibration.json").display());
    }
    if let Some(scan) = &args.scan {
        print!(
            "{}",
            scan_report(&beam, scan, &args.out, args.ply.as_deref())?
        );
    }
    Ok(())
}
