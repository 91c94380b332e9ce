//! `robocal register`: CT ↔ tracker registration (thin adapter over [`crate::register`]).
//!
//! - paired fiducials: `--ct CT.csv --tracker TRK.csv` (or `--tracker-data D.jsonl`: probe-tip
//!   records with a `target` label), optional `--tracker-model M.json` / `--ct-sigma-mm`;
//! - surface: `--ct-mesh MESH.ply|.stl --tracker TRK.csv [--init INIT.json]`.
//!
//! Writes `registration.json` (`robocal-registration/1`) and prints FRE, FLE and TRE. The
//! work is in [`crate::register::from_files`]; this file parses and prints.
use std::path::PathBuf;

use anyhow::bail;

use crate::register::from_files;
use crate::register::run::surface_file;
use crate::register::{icp, points, RegistrationFile};

/// Arguments of `robocal register`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// CT fiducials, CSV `name,x_mm,y_mm,z_mm` (paired mode).
    #[arg(long, value_name = "CT.csv", conflicts_with = "ct_mesh")]
    pub ct: Option<PathBuf>,
    /// CT surface mesh, STL or PLY (surface mode).
    #[arg(long, value_name = "MESH")]
    pub ct_mesh: Option<PathBuf>,
    /// Tracker points, CSV `name,x_mm,y_mm,z_mm` (fiducials paired by name, or surface points;
    /// surface points may also be a PLY point cloud, e.g. `calibrate laser --scan … --ply`).
    #[arg(long, value_name = "TRK.csv")]
    pub tracker: Option<PathBuf>,
    /// Tracker fiducials from a dataset's probe-tip records (`tip` + `target` label).
    #[arg(long, value_name = "D.jsonl", conflicts_with = "tracker")]
    pub tracker_data: Option<PathBuf>,
    /// Stereo tracker noise model (JSON: baseline_mm, focal_px, disparity_sigma_px,
    /// pixel_sigma_px[, floor_mm]): weights and the tracker share of the covariance.
    #[arg(long, value_name = "M.json")]
    pub tracker_model: Option<PathBuf>,
    /// CT fiducial localisation, 1σ per axis (mm).
    #[arg(long, value_name = "MM")]
    pub ct_sigma_mm: Option<f64>,
    /// Initial guess of T_tracker_ct for ICP (registration.json or any JSON with
    /// `T_tracker_ct.matrix`).
    #[arg(long, value_name = "INIT.json")]
    pub init: Option<PathBuf>,
    /// ICP: fraction of closest points kept in each iteration of the multi-start search; the
    /// final fit drops only the points the data show to be outliers (beyond 5 robust σ of
    /// the surface) and says how many; 1.0 keeps every point.
    #[arg(long, default_value_t = 0.9)]
    pub trim: f64,
    /// Check points in CT (CSV `name,x_mm,y_mm,z_mm`), not used by the fit: their error
    /// through the registration against `--check-tracker` (paired by name) is reported.
    #[arg(long, value_name = "C.csv", requires = "check_tracker")]
    pub check_ct: Option<PathBuf>,
    /// The same check points measured in the tracker (e.g. probe tip on the landmarks).
    #[arg(long, value_name = "C.csv", requires = "check_ct")]
    pub check_tracker: Option<PathBuf>,
    /// CT targets (CSV `name,x_mm,y_mm,z_mm`) to predict the TRE at.
    #[arg(long, value_name = "T.csv")]
    pub targets: Option<PathBuf>,
    /// Output file.
    #[arg(long, value_name = "registration.json")]
    pub out: PathBuf,
}

/// Run `robocal register`.
pub fn exec(a: Args) -> anyhow::Result<()> {
    let targets: Vec<(String, nalgebra::Point3<f64>)> = match &a.targets {
        Some(p) => points::read_points_csv(p)?
            .into_iter()
            .map(|n| (n.name, n.p))
            .collect(),
        None => Vec::new(),
    };
    let mut file = if let Some(ct) = &a.ct {
        let r = from_files::paired(
            ct,
            a.tracker.as_deref(),
            a.tracker_data.as_deref(),
            a.tracker_model.as_deref(),
            a.ct_sigma_mm,
        )?;
        for u in &r.unpaired {
            eprintln!("warning: unpaired fiducial {u}");
        }
        println!(
            "paired registration: {} fiducials, FRE {:.3} mm, FLE (est.) {:.3} mm{}",
            r.names.len(),
            r.fre_mm,
            r.fle_mm,
            if r.weighted {
                ", weighted by the noise model"
            } else {
                ""
            }
        );
        RegistrationFile::from_paired(&r, &targets)
    } else if let Some(mp) = &a.ct_mesh {
        let Some(tp) = &a.tracker else {
            bail!("surface mode needs --tracker TRK.csv (digitised surface points)")
        };
        let s = from_files::surface(mp, tp, a.init.as_deref(), a.trim)?;
        let (r, n) = (&s.result, s.points.len());
        println!(
            "surface registration: {} points ({} inliers, {} dropped as outliers beyond {} robust σ), RMS {:.3} mm, {} starts{}",
            n,
            r.inliers,
            n - r.inliers,
            icp::ROBUST_CUT,
            r.rms_mm,
            r.starts,
            match (r.runner_up_rms_mm, r.runner_up_angle_deg) {
                (Some(rr), Some(ang)) => format!(", runner-up RMS {rr:.3} mm at {ang:.1}°"),
                _ => String::new(),
            }
        );
        surface_file(r, &s.points, &targets, &mp.display().to_string(), s.trim)
    } else {
        bail!("give --ct CT.csv (paired fiducials) or --ct-mesh MESH (surface)")
    };
    if let Some(i) = &file.icp {
        if let (Some(m), Some(sd)) = (i.distance_mean_mm, i.distance_sd_mm) {
            println!("point-to-surface distance (inliers): {m:.3} ± {sd:.3} mm (mean ± sd)");
        }
    }
    if let (Some(c), Some(t)) = (&a.check_ct, &a.check_tracker) {
        file.check_points = check_points(&file, c, t)?;
    }
    for t in &file.targets {
        println!(
            "target {}: predicted TRE {:.3} mm RMS, 95 % ellipsoid {:.3} x {:.3} x {:.3} mm",
            t.name, t.tre_rms_mm, t.ellipsoid95_mm[0], t.ellipsoid95_mm[1], t.ellipsoid95_mm[2]
        );
    }
    file.save(&a.out)?;
    println!("wrote {}", a.out.display());
    Ok(())
}

/// The independent check points (`--check-ct` / `--check-tracker`) through the registration:
/// printed as mean ± sd and max, returned for the file.
fn check_points(
    file: &RegistrationFile,
    c: &std::path::Path,
    t: &std::path::Path,
) -> anyhow::Result<Vec<crate::register::check::CheckPoint>> {
    let (cp, unpaired) = crate::register::check::check_points(
        &file.transform()?,
        &points::read_points_csv(c)?,
        &points::read_points_csv(t)?,
        (&c.display().to_string(), &t.display().to_string()),
    )?;
    for u in &unpaired {
        eprintln!("warning: check point {u} on one side only");
    }
    let e: Vec<f64> = cp.iter().map(|x| x.error_mm).collect();
    let (m, sd) = crate::register::check::mean_sd(&e);
    println!(
        "check points: {}, error {m:.3} ± {sd:.3} mm (mean ± sd), max {:.3} mm",
        cp.len(),
        e.iter().cloned().fold(0.0, f64::max)
    );
    Ok(cp)
}
