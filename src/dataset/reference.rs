//! Reference body (tracker drift): a rigid body fixed in the cell and re-measured by the same
//! tracker at every pose (`reference` of a pose record, tracker frame). Expressing the marker
//! in the reference body's frame, `p' = R_refᵀ (p − p_ref)`, `quat' = q_ref⁻¹ · quat`, removes
//! any motion of the tracker itself during the session (drift, a bumped tripod).
//!
//! The rule both kinematic observation builders follow: when any pose of a dataset (or of a
//! session) carries a reference, every pose is expressed in the reference frame and poses
//! without a usable reference are skipped with a reason — frames are never mixed.
use nalgebra::{Point3, UnitQuaternion, Vector3};

use super::types::PoseRecord;

/// Whether the record carries a `reference` block (visible or not).
pub fn has_reference(r: &PoseRecord) -> bool {
    r.reference.is_some()
}

/// Whether any of `records` carries a `reference` block: then the whole set is expressed in
/// the reference frame.
pub fn any_reference<'a>(records: impl IntoIterator<Item = &'a PoseRecord>) -> bool {
    records.into_iter().any(has_reference)
}

fn unit_quat(w: &[f64; 4], what: &str) -> Result<UnitQuaternion<f64>, String> {
    crate::plausible::quat::unit_wxyz(w).map_err(|e| format!("{what} `quat`: {e}"))
}

/// The reference body's pose in the tracker frame (`Err` says why it is unusable).
pub fn reference_pose(r: &PoseRecord) -> Result<(Point3<f64>, UnitQuaternion<f64>), String> {
    let m = r
        .reference
        .as_ref()
        .ok_or("no `reference` (other poses of this data carry one; frames are not mixed)")?;
    if !m.visible {
        return Err("reference body not visible".into());
    }
    let p = m.p.ok_or("reference without `p`")?;
    if !p.iter().all(|x| x.is_finite()) {
        return Err("reference `p` is not finite".into());
    }
    let q = m
        .quat
        .as_ref()
        .ok_or("reference without `quat` (its orientation defines the frame)")?;
    Ok((Point3::from(Vector3::from(p)), unit_quat(q, "reference")?))
}

/// A point and an optional orientation measured in the tracker frame, re-expressed in the
/// frame of the record's reference body.
pub fn to_reference_frame(
    r: &PoseRecord,
    p: Point3<f64>,
    quat: Option<UnitQuaternion<f64>>,
) -> Result<(Point3<f64>, Option<UnitQuaternion<f64>>), String> {
    let (p_ref, q_ref) = reference_pose(r)?;
    let inv = q_ref.inverse();
    Ok((Point3::from(inv * (p - p_ref)), quat.map(|q| inv * q)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::MarkerObs;
    use nalgebra::Isometry3;

    fn obs(iso: &Isometry3<f64>) -> MarkerObs {
        let q = iso.rotation.quaternion();
        MarkerObs {
            p: Some(iso.translation.vector.into()),
            quat: Some([q.w, q.i, q.j, q.k]),
            rms: None,
            visible: true,
            frames: None,
            extra: Default::default(),
        }
    }

    #[test]
    fn reference_frame_removes_a_tracker_motion() {
        let marker_cell = Isometry3::new(
            Vector3::new(300.0, -50.0, 1200.0),
            Vector3::new(0.1, 0.2, 0.3),
        );
        let ref_cell = Isometry3::new(
            Vector3::new(-400.0, 20.0, 1500.0),
            Vector3::new(-0.3, 0.0, 0.5),
        );
        let mut out = Vec::new();
        for drift in [
            Isometry3::identity(),
            Isometry3::new(
                Vector3::new(0.4, -0.3, 0.2),
                Vector3::new(0.001, -0.002, 0.003),
            ),
        ] {
            // What a tracker that moved by `drift` measures.
            let m = drift.inverse() * marker_cell;
            let rf = drift.inverse() * ref_cell;
            let rec: PoseRecord = serde_json::from_value(serde_json::json!({
                "id": 1, "t": 0.0, "q": [0.0], "marker": obs(&m), "reference": obs(&rf)
            }))
            .unwrap();
            let (p, q) =
                to_reference_frame(&rec, Point3::from(m.translation.vector), Some(m.rotation))
                    .unwrap();
            out.push((p, q.unwrap()));
        }
        assert!((out[0].0 - out[1].0).norm() < 1e-9, "{:?}", out);
        assert!(out[0].1.angle_to(&out[1].1) < 1e-12);
        // and equals ref⁻¹ · marker
        let want = ref_cell.inverse() * marker_cell;
        assert!((out[0].0.coords - want.translation.vector).norm() < 1e-9);
        // a pose without a reference is refused with a reason
        let rec: PoseRecord =
            serde_json::from_value(serde_json::json!({"id": 2, "t": 0.0, "q": [0.0]})).unwrap();
        let e = to_reference_frame(&rec, Point3::origin(), None).unwrap_err();
        assert!(e.contains("no `reference`"), "{e}");
    }
}
