//! The two registrations of `robocal register` from their files: paired fiducials (CT table
//! against a tracker table or a dataset's probe-tip records, weighted by a tracker noise
//! model when given) and a surface (digitised points or a point cloud onto a CT mesh by
//! ICP). The CLI prints the results and writes `registration.json`.
use std::path::Path;

use anyhow::bail;

use super::run::load_model;
use super::{file, icp, mesh, points, PairedOptions, PairedRegistration};

/// Paired registration of the CT fiducials `ct` to the tracker's, read from the table
/// `tracker` or from the probe-tip records of the dataset `tracker_data` (exactly one).
pub fn paired(
    ct: &Path,
    tracker: Option<&Path>,
    tracker_data: Option<&Path>,
    tracker_model: Option<&Path>,
    ct_sigma_mm: Option<f64>,
) -> anyhow::Result<PairedRegistration> {
    let ct_pts = points::read_points_csv(ct)?;
    let trk = match (tracker, tracker_data) {
        (Some(t), None) => points::read_points_csv(t)?,
        (None, Some(d)) => {
            let ds = crate::dataset::Dataset::load(d)?;
            points::tip_points_from_dataset(&ds, &d.display().to_string())?
        }
        _ => bail!("paired mode needs --tracker TRK.csv or --tracker-data D.jsonl"),
    };
    let opts = PairedOptions {
        tracker_model: tracker_model.map(load_model).transpose()?,
        ct_sigma_mm,
    };
    Ok(super::register_paired(&ct_pts, &trk, &opts)?)
}

/// A surface registration and what it was made from.
#[derive(Debug, Clone)]
pub struct SurfaceFit {
    /// The ICP result.
    pub result: icp::IcpResult,
    /// The tracker's surface points.
    pub points: Vec<points::NamedPoint>,
    /// The trim fraction of the multi-start search.
    pub trim: f64,
}

/// Surface registration of the tracker's points `tracker` (table or PLY cloud) onto the CT
/// mesh `mesh`, from the initial guess in `init` when given.
pub fn surface(
    mesh: &Path,
    tracker: &Path,
    init: Option<&Path>,
    trim: f64,
) -> anyhow::Result<SurfaceFit> {
    let m = mesh::read_mesh(mesh)?;
    let pts = points::read_surface_points(tracker)?;
    let xyz: Vec<_> = pts.iter().map(|p| p.p).collect();
    let init = init.map(file::load_init).transpose()?;
    let o = icp::IcpOptions {
        trim_fraction: trim,
        ..icp::IcpOptions::default()
    };
    let result = icp::register_surface(&m, &xyz, init.as_ref(), &o)?;
    Ok(SurfaceFit {
        result,
        points: pts,
        trim: o.trim_fraction,
    })
}
