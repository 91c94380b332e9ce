//! Check points of a registration (seed 000 §2.3.4, seed 003): points known in CT and measured
//! independently in the tracker (fiducials left out of the registration, or a probe's tip on
//! landmarks), mapped through the registration; their error is the registration's accuracy
//! where the points are, not its own fit. Also the mean ± sd of the point-to-surface distance a
//! surface registration leaves (what the seed reports beside the check points).
use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

use crate::register::points::NamedPoint;

/// One check point: CT and tracker coordinates (mm), the error `|T·ct − tracker|` (mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CheckPoint {
    pub name: String,
    pub ct: [f64; 3],
    pub tracker: [f64; 3],
    pub error_mm: f64,
}

/// Mean and sample standard deviation (NaN for an empty set; sd 0 for one value).
pub fn mean_sd(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let ss = v.iter().map(|x| (x - m).powi(2)).sum::<f64>();
    (m, (ss / (n - 1.0).max(1.0)).sqrt())
}

/// The check points paired by name (CT ↔ tracker) through `t_tracker_ct`. Names present on
/// one side only are returned second; no pair at all is an error naming both files.
pub fn check_points(
    t_tracker_ct: &Isometry3<f64>,
    ct: &[NamedPoint],
    tracker: &[NamedPoint],
    files: (&str, &str),
) -> anyhow::Result<(Vec<CheckPoint>, Vec<String>)> {
    let arr = |p: &Point3<f64>| [p.x, p.y, p.z];
    let mut out = Vec::new();
    let mut unpaired = Vec::new();
    for c in ct {
        match tracker.iter().find(|t| t.name == c.name) {
            Some(t) => out.push(CheckPoint {
                name: c.name.clone(),
                ct: arr(&c.p),
                tracker: arr(&t.p),
                error_mm: (t_tracker_ct * c.p - t.p).norm(),
            }),
            None => unpaired.push(c.name.clone()),
        }
    }
    unpaired.extend(
        tracker
            .iter()
            .filter(|t| !ct.iter().any(|c| c.name == t.name))
            .map(|t| t.name.clone()),
    );
    anyhow::ensure!(
        !out.is_empty(),
        "no check point of {} has the name of one in {} (points are paired by name)",
        files.0,
        files.1
    );
    Ok((out, unpaired))
}
