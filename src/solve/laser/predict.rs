//! Laser spots of a whole file under a laser calibration, with every effect the laser
//! diagnosis applies: `laser_scale` and `laser_nonlinearity` on every reading, and
//! `laser_incidence` on the validation records (those with a `target` label), whose surface
//! is the plane of their uncorrected spots (the PCA plane), as the diagnosis computes its
//! held-out spread (`effects::diagnose`). A record without a target has no known surface:
//! its incidence term is not applied (see [`incidence_note`]).
use nalgebra::Point3;

use super::fit::pca_plane;
use super::{effects, record_flange, Beam, LaserError};
use crate::dataset::{CalEffect, PoseRecord};
use crate::model::KinematicModel;

/// The spot (robot base frame, mm) of every record of `recs` (None: no range reading).
pub fn predict_spots(
    beam: &Beam,
    effects: &[CalEffect],
    recs: &[&PoseRecord],
    model: Option<&KinematicModel>,
) -> Result<Vec<Option<Point3<f64>>>, LaserError> {
    let mut raw = Vec::with_capacity(recs.len());
    for rec in recs {
        raw.push(match rec.range {
            Some(Some(d)) if d.is_finite() => Some((record_flange(rec, model)?, d)),
            _ => None,
        });
    }
    let incidence = effects.iter().any(|e| e.kind == "laser_incidence");
    let plate = if incidence {
        let spots: Vec<Point3<f64>> = recs
            .iter()
            .zip(&raw)
            .filter(|(r, _)| r.target.is_some())
            .filter_map(|(_, x)| x.as_ref().map(|(f, d)| beam.spot(f, *d)))
            .collect();
        pca_plane(&spots)
    } else {
        None
    };
    Ok(recs
        .iter()
        .zip(raw)
        .map(|(rec, x)| {
            let (flange, d) = x?;
            let cos_g = plate.as_ref().filter(|_| rec.target.is_some()).map(|p| {
                let dir = flange.rotation * beam.v.into_inner();
                p.n.dot(&dir).abs().min(1.0)
            });
            Some(beam.spot(&flange, effects::corrected_range(d, effects, cos_g)))
        })
        .collect())
}

/// The warning of a prediction whose file has a `laser_incidence` effect and records without
/// a validation `target` (None when there is nothing to say).
pub fn incidence_note(effects: &[CalEffect], recs: &[&PoseRecord]) -> Option<String> {
    let n = recs.iter().filter(|r| r.target.is_none()).count();
    (n > 0 && effects.iter().any(|e| e.kind == "laser_incidence")).then(|| {
        format!(
            "laser_incidence is applied to the records with a validation `target` only (their \
             surface is the plane of their spots); {n} record(s) without one are predicted \
             without the incidence term"
        )
    })
}
