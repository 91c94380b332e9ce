//! The registration glue between files and the solvers: a tracker noise model read from its
//! file, the registration file of a surface fit, CT points mapped into the tracker frame
//! (`robocal register` / `robocal predict --points`).
use anyhow::Context as _;

use super::{self as reg, file, icp, points, RegistrationFile};

/// Reads a tracker model file.
pub fn load_model(path: &std::path::Path) -> anyhow::Result<reg::StereoTrackerModel> {
    let text =
        crate::fsio::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let m: reg::StereoTrackerModel = serde_json::from_str(&text).with_context(|| {
        format!(
            "{}: not a tracker model (baseline_mm, focal_px, disparity_sigma_px, pixel_sigma_px)",
            path.display()
        )
    })?;
    m.validate()?;
    Ok(m)
}

/// The registration file of a surface registration.
pub fn surface_file(
    r: &icp::IcpResult,
    pts: &[points::NamedPoint],
    targets: &[(String, nalgebra::Point3<f64>)],
    mesh_name: &str,
    trim: f64,
) -> RegistrationFile {
    let arr = |p: &nalgebra::Point3<f64>| [p.x, p.y, p.z];
    let n = pts.len();
    let inlier_d: Vec<f64> = r
        .residuals
        .iter()
        .filter(|x| x.inlier)
        .map(|x| x.distance_mm.abs())
        .collect();
    let dist = crate::register::check::mean_sd(&inlier_d);
    RegistrationFile {
        format: reg::REGISTRATION_FORMAT.into(),
        kind: "surface".into(),
        t_tracker_ct: file::TransformWithCov {
            matrix: reg::paired::iso_to_rows(&r.t_tracker_ct).to_vec(),
            covariance: Some(file::cov_to_file(&r.cov)),
            covariance_order: Some(file::COV_ORDER.into()),
            covariance_ct: None,
            covariance_tracker: None,
        },
        fre_mm: r.rms_mm,
        fle_mm: r.rms_mm * (n as f64 / (n as f64 - 6.0).max(1.0)).sqrt(),
        n_points: n,
        points: pts
            .iter()
            .zip(&r.residuals)
            .map(|(p, res)| file::PointResidual {
                name: p.name.clone(),
                ct: arr(&res.ct),
                tracker: arr(&p.p),
                residual_mm: res.distance_mm.abs(),
                inlier: Some(res.inlier),
            })
            .collect(),
        targets: targets
            .iter()
            .map(|(name, x)| {
                let j = reg::paired::point_jacobian(&r.t_tracker_ct, x);
                let c = j * r.cov * j.transpose();
                file::TargetTre {
                    name: name.clone(),
                    ct: arr(x),
                    tracker: arr(&(r.t_tracker_ct * x)),
                    tre_rms_mm: c.trace().sqrt(),
                    ellipsoid95_mm: file::ellipsoid95(&c),
                }
            })
            .collect(),
        unpaired: Vec::new(),
        icp: Some(file::IcpSummary {
            mesh: mesh_name.into(),
            points: n,
            inliers: r.inliers,
            trim_fraction: trim,
            starts: r.starts,
            iterations: r.iterations,
            rms_mm: r.rms_mm,
            runner_up_rms_mm: r.runner_up_rms_mm,
            runner_up_angle_deg: r.runner_up_angle_deg,
            distance_mean_mm: Some(dist.0).filter(|x| x.is_finite()),
            distance_sd_mm: Some(dist.1).filter(|x| x.is_finite()),
        }),
        notes: None,
        check_points: Vec::new(),
    }
}

/// `robocal predict --calibration registration.json --points P.csv`: CT points into the
/// tracker frame.
pub fn predict_points(
    cal: &std::path::Path,
    pts: &std::path::Path,
) -> anyhow::Result<Vec<points::NamedPoint>> {
    let f = RegistrationFile::load(cal)?;
    let t = f.transform()?;
    Ok(points::read_points_csv(pts)?
        .into_iter()
        .map(|p| points::NamedPoint { p: t * p.p, ..p })
        .collect())
}
