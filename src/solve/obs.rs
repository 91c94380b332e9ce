//! Measurements extracted from `pose` records, in internal units (mm, rad).
use nalgebra::{Point3, UnitQuaternion, Vector3};

use crate::dataset::{reference, Dataset, PoseRecord};

/// One usable `pose` record: joints and the tracked marker.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseObs {
    pub id: u64,
    /// Seconds since the dataset's `created`.
    pub t: f64,
    /// Measured joints (rad).
    pub q: Vec<f64>,
    /// Commanded joints (rad), when recorded (approach direction for backlash effects).
    pub q_cmd: Option<Vec<f64>>,
    /// Marker origin in the tracker frame (mm).
    pub p: Point3<f64>,
    /// Marker orientation in the tracker frame, when recorded.
    pub quat: Option<UnitQuaternion<f64>>,
    pub point: Option<u64>,
    pub branch: Option<u64>,
    pub group: Option<String>,
    pub temp_c: Option<f64>,
}

/// Why a pose record was not used.
#[derive(Debug, Clone, PartialEq)]
pub struct Skipped {
    pub id: u64,
    pub reason: String,
}

fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl PoseObs {
    /// Convert one record; `Err` says why it is unusable (invisible marker, missing q, ...).
    pub fn from_record(r: &PoseRecord, dof: usize) -> Result<PoseObs, String> {
        Self::from_record_in(r, dof, false)
    }

    /// As [`PoseObs::from_record`]; with `in_reference` the marker is re-expressed in the
    /// frame of the record's reference body ([`crate::dataset::reference`]), and a record
    /// without a usable reference is refused.
    pub fn from_record_in(
        r: &PoseRecord,
        dof: usize,
        in_reference: bool,
    ) -> Result<PoseObs, String> {
        let mut o = Self::from_record_tracker(r, dof)?;
        if in_reference {
            let (p, quat) = reference::to_reference_frame(r, o.p, o.quat)?;
            o.p = p;
            o.quat = quat;
        }
        Ok(o)
    }

    fn from_record_tracker(r: &PoseRecord, dof: usize) -> Result<PoseObs, String> {
        let q = r.q.as_ref().ok_or("no `q`")?;
        if q.len() != dof {
            return Err(format!("`q` has {} joints, the robot {dof}", q.len()));
        }
        if !finite(q) {
            return Err("`q` is not finite".into());
        }
        let m = r.marker.as_ref().ok_or("no `marker`")?;
        if !m.visible {
            return Err("marker not visible".into());
        }
        let p = m.p.ok_or("marker without `p`")?;
        if !finite(&p) {
            return Err("marker `p` is not finite".into());
        }
        let quat = match m.quat {
            Some(w) if finite(&w) => {
                let v = nalgebra::Quaternion::new(w[0], w[1], w[2], w[3]);
                if (v.norm() - 1.0).abs() > 1e-3 {
                    return Err(format!("marker quaternion norm {:.4} is not 1", v.norm()));
                }
                Some(UnitQuaternion::from_quaternion(v))
            }
            Some(_) => return Err("marker `quat` is not finite".into()),
            None => None,
        };
        let q_cmd = r
            .q_cmd
            .as_ref()
            .filter(|c| c.len() == dof && finite(c))
            .map(|c| c.iter().map(|d| d.to_radians()).collect());
        Ok(PoseObs {
            id: r.id,
            t: r.t,
            q: q.iter().map(|d| d.to_radians()).collect(),
            q_cmd,
            p: Point3::from(Vector3::new(p[0], p[1], p[2])),
            quat,
            point: r.point,
            branch: r.branch,
            group: r.group.clone(),
            temp_c: r.temp_c,
        })
    }
}

/// Which pose records to take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Split {
    /// Every pose record.
    All,
    /// Records whose group is not `validation` (the training set).
    Train,
    /// Records with group `validation`.
    Validation,
}

/// Whether the observations of `ds` are expressed in the reference body's frame (any of its
/// poses carries a `reference`, see [`crate::dataset::reference`]).
pub fn uses_reference(ds: &Dataset) -> bool {
    reference::any_reference(ds.poses())
}

/// Refuses a held-out dataset whose markers are in another frame than the training data's
/// (one carries a reference body, the other not).
pub fn check_same_frame(train: &Dataset, heldout: &Dataset) -> Result<(), String> {
    match (uses_reference(train), uses_reference(heldout)) {
        (true, false) => Err("the training data carries a reference body (markers are expressed in its frame) but the held-out file does not: held-out markers would be in the tracker frame".into()),
        (false, true) => Err("the held-out file carries a reference body (markers are expressed in its frame) but the training data does not: held-out markers would be in another frame".into()),
        _ => Ok(()),
    }
}

/// Usable observations of a dataset and the records skipped (with reasons). When any pose
/// of `ds` carries a `reference` body, every marker is re-expressed in its frame and poses
/// without one are skipped (frames are never mixed).
pub fn observations(ds: &Dataset, dof: usize, split: Split) -> (Vec<PoseObs>, Vec<Skipped>) {
    let in_ref = uses_reference(ds);
    let mut out = Vec::new();
    let mut skipped = Vec::new();
    for r in ds.poses() {
        let is_val = r.group.as_deref() == Some("validation");
        let take = match split {
            Split::All => true,
            Split::Train => !is_val,
            Split::Validation => is_val,
        };
        if !take {
            continue;
        }
        match PoseObs::from_record_in(r, dof, in_ref) {
            Ok(o) => out.push(o),
            Err(reason) => skipped.push(Skipped { id: r.id, reason }),
        }
    }
    (out, skipped)
}
