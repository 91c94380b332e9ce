//! The one observation type and builder of the crate: `pose` records turned into joint
//! contexts and marker measurements in internal units (mm, rad, s), used by `solve`,
//! `diagnose` and `predict`.
use nalgebra::{Point3, UnitQuaternion, Vector3};

use crate::dataset::{reference, Dataset, PoseRecord};

/// The joint side of one pose record: what the kinematics and every effect regressor need
/// besides the measurement (internal units: rad, s, °C). Shared by `solve`, `diagnose` and
/// `predict` (the one observation context of the crate).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PoseCtx {
    /// Record id (acquisition order within its file).
    pub id: u64,
    /// Seconds since the dataset's `created`.
    pub t: f64,
    /// Measured joints (rad).
    pub q: Vec<f64>,
    /// Commanded joints (rad), when recorded.
    pub q_cmd: Option<Vec<f64>>,
    /// The joints the move into this pose started from (rad), when recorded.
    pub q_prev: Option<Vec<f64>>,
    /// Approach direction of each joint: sign of `q_i − q_prev_i` (from the record's own
    /// `q_prev`, else from the pose before it in the session, see [`contexts_counted`]);
    /// `0` when unknown or the joint did not move.
    pub approach: Vec<f64>,
    /// Temperature (°C) when recorded.
    pub temp_c: Option<f64>,
    /// Joint velocity (rad/s) when recorded (`qd` field, deg/s in files).
    pub qd: Option<Vec<f64>>,
}

/// One usable `pose` record: its context (joints, time, temperature, approach signs) and
/// the tracked marker (in the reference body's frame when the session carries one).
/// Field access reaches the context directly (`o.q`, `o.t`) through `Deref`.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseObs {
    pub ctx: PoseCtx,
    /// Marker origin in the tracker (or reference-body) frame (mm).
    pub p: Point3<f64>,
    /// Marker orientation in the same frame, when recorded.
    pub quat: Option<UnitQuaternion<f64>>,
    pub point: Option<u64>,
    pub branch: Option<u64>,
    pub group: Option<String>,
}

impl std::ops::Deref for PoseObs {
    type Target = PoseCtx;
    fn deref(&self) -> &PoseCtx {
        &self.ctx
    }
}

impl PoseObs {
    /// An observation of `p` at joints `q` (rad) with no side data (tests, synthetic data).
    pub fn at(id: u64, t: f64, q: Vec<f64>, p: Point3<f64>) -> PoseObs {
        let n = q.len();
        PoseObs {
            ctx: PoseCtx {
                id,
                t,
                q,
                approach: vec![0.0; n],
                ..PoseCtx::default()
            },
            p,
            quat: None,
            point: None,
            branch: None,
            group: None,
        }
    }
}

/// Why a pose record was not used.
#[derive(Debug, Clone, PartialEq)]
pub struct Skipped {
    pub id: u64,
    pub reason: String,
    /// Left out only because the session is in a reference body's frame and this record
    /// has no usable reference.
    pub no_reference: bool,
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
            Some(w) => Some(
                crate::plausible::quat::unit_wxyz(&w).map_err(|e| format!("marker `quat`: {e}"))?,
            ),
            None => None,
        };
        let ctx = record_ctx(r, dof).ok_or("`q` is not usable")?;
        Ok(PoseObs {
            ctx,
            p: Point3::from(Vector3::new(p[0], p[1], p[2])),
            quat,
            point: r.point,
            branch: r.branch,
            group: r.group.clone(),
        })
    }
}

fn deg_vec(v: Option<&Vec<f64>>, dof: usize) -> Option<Vec<f64>> {
    v.filter(|c| c.len() == dof && finite(c))
        .map(|c| c.iter().map(|d| d.to_radians()).collect())
}

/// The context of one record on its own (approach from its own `q_prev` only); `None`
/// without usable joints.
fn record_ctx(r: &PoseRecord, dof: usize) -> Option<PoseCtx> {
    let q = deg_vec(r.q.as_ref(), dof)?;
    let q_prev = deg_vec(r.q_prev.as_ref(), dof);
    let mut approach = vec![0.0; dof];
    if let Some(pq) = &q_prev {
        for i in 0..dof {
            if (q[i] - pq[i]).abs() > MOVE_EPS {
                approach[i] = (q[i] - pq[i]).signum();
            }
        }
    }
    if let Some(a) = explicit_approach(r, dof) {
        approach = a;
    }
    let qd = r
        .extra
        .get("qd")
        .and_then(|v| v.as_array())
        .map(|v| v.iter().filter_map(|x| x.as_f64()).collect::<Vec<f64>>());
    Some(PoseCtx {
        id: r.id,
        t: r.t,
        q,
        q_cmd: deg_vec(r.q_cmd.as_ref(), dof),
        q_prev,
        approach,
        temp_c: r.temp_c.filter(|x| x.is_finite()),
        qd: deg_vec(qd.as_ref(), dof),
    })
}

/// Motions smaller than this (rad) do not change the approach direction.
const MOVE_EPS: f64 = 1e-6;

/// An explicit `approach` array on a record (signs per joint).
fn explicit_approach(r: &PoseRecord, dof: usize) -> Option<Vec<f64>> {
    let a = r.extra.get("approach")?.as_array()?;
    let s: Vec<f64> = a.iter().filter_map(|x| x.as_f64()).collect();
    (s.len() == dof).then(|| s.iter().map(|x| x.signum()).collect())
}

/// Contexts of every record that has joint angles, in acquisition order (sorted by `t`,
/// then `id`). The approach direction of joint `i` is `sign(q_i − q_prev_i)` from the
/// record's own `q_prev` (the joints the move into the pose started from); where a record
/// has no `q_prev` (or joint `i` did not move), it is taken from the pose measured just
/// before it in time, which is right only if nothing moved the arm in between — pass the
/// records of all files of one session together (train and held-out interleave in time).
/// An explicit `approach` array on a record (signs per joint) overrides both.
/// Each context is keyed by the record's address ([`record_key`]), not its `id`: ids of two
/// files of one session (e.g. two `robocal run` directories) may overlap.
/// Returns the contexts and how many records had neither `q_prev` nor `approach`.
pub fn contexts_counted(records: &[&PoseRecord], dof: usize) -> (Vec<(usize, PoseCtx)>, usize) {
    let mut v: Vec<(&PoseRecord, PoseCtx)> = records
        .iter()
        .filter(|p| p.t.is_finite())
        .filter_map(|p| record_ctx(p, dof).map(|c| (*p, c)))
        .collect();
    v.sort_by(|a, b| a.0.t.total_cmp(&b.0.t).then(a.0.id.cmp(&b.0.id)));
    let mut out = Vec::with_capacity(v.len());
    let mut prev: Option<Vec<f64>> = None;
    let mut inferred = 0;
    let mut last_sign = vec![0.0; dof];
    for (p, mut c) in v {
        let from = c.q_prev.as_ref().or(prev.as_ref());
        if let Some(pq) = from {
            for i in 0..dof {
                let dq = c.q[i] - pq[i];
                if dq.abs() > MOVE_EPS {
                    last_sign[i] = dq.signum();
                }
            }
        }
        let explicit = explicit_approach(p, dof);
        if c.q_prev.is_none() && explicit.is_none() {
            inferred += 1;
        }
        c.approach = explicit.unwrap_or_else(|| last_sign.clone());
        prev = Some(c.q.clone());
        out.push((record_key(p), c));
    }
    (out, inferred)
}

/// [`contexts_counted`] without the count.
pub fn contexts(records: &[&PoseRecord], dof: usize) -> Vec<(usize, PoseCtx)> {
    contexts_counted(records, dof).0
}

/// The context of one pose record within its dataset (approach direction from the records
/// before it in time, see [`contexts`]). `None` if the record has no usable joint angles.
pub fn record_context(rec: &PoseRecord, ds: &Dataset, dof: usize) -> Option<PoseCtx> {
    let session: Vec<&PoseRecord> = ds.poses().collect();
    contexts(&session, dof)
        .into_iter()
        .find(|(key, _)| *key == record_key(rec))
        .map(|(_, c)| c)
}

/// The warning printed when an effect needs the approach direction and `n` records carry
/// no `q_prev`.
pub fn q_prev_warning(n: usize, what: &str) -> String {
    format!(
        "{n} pose record(s) have no q_prev: {what} takes their approach direction from the previous record of the session in time (right only if the arm moved straight from that pose)"
    )
}

/// The identity of a record in memory (its address), unique across the files of a session.
pub fn record_key(p: &PoseRecord) -> usize {
    p as *const PoseRecord as usize
}

/// The warning for records left out because they lack a usable reference body.
pub fn reference_skip_warning(skipped: &[Skipped]) -> String {
    let s: Vec<&Skipped> = skipped.iter().filter(|s| s.no_reference).collect();
    format!(
        "{} pose record(s) left out: the session's markers are expressed in the reference body's frame and these have no usable reference (first: id {}: {})",
        s.len(),
        s.first().map_or(0, |s| s.id),
        s.first().map_or("", |s| s.reason.as_str())
    )
}

/// The one observation builder: usable observations among `records` (joints and a visible
/// marker), with contexts computed over `session` (all records of the session, see
/// [`contexts`]), sorted by time then id, and the records skipped with reasons. When any
/// record of `session` carries a `reference` body, every marker is re-expressed in its
/// frame ([`crate::dataset::reference`]) and records without a usable reference are
/// skipped with `no_reference` set (frames are never mixed).
pub fn session_observations(
    records: &[&PoseRecord],
    session: &[&PoseRecord],
    dof: usize,
) -> (Vec<PoseObs>, Vec<Skipped>) {
    let mut out = build(records, session, dof);
    out.0
        .sort_by(|a, b| a.t.total_cmp(&b.t).then(a.id.cmp(&b.id)));
    out
}

/// The training / held-out split of a session: the records of `main` outside the
/// `validation` group train; its `validation` records and every record of `extra` (a
/// held-out file) are held out. Contexts are computed over all records of both files.
/// Returns the training and held-out observations and the records skipped.
pub fn split_observations(
    main: &Dataset,
    extra: Option<&Dataset>,
    dof: usize,
) -> (Vec<PoseObs>, Vec<PoseObs>, Vec<Skipped>) {
    let mut session: Vec<&PoseRecord> = main.poses().collect();
    if let Some(x) = extra {
        session.extend(x.poses());
    }
    let is_val = |p: &PoseRecord| p.group.as_deref() == Some("validation");
    let train: Vec<&PoseRecord> = main.poses().filter(|p| !is_val(p)).collect();
    let mut held: Vec<&PoseRecord> = main.poses().filter(|p| is_val(p)).collect();
    if let Some(x) = extra {
        held.extend(x.poses());
    }
    let (train, mut skipped) = session_observations(&train, &session, dof);
    let (held, s2) = session_observations(&held, &session, dof);
    skipped.extend(s2);
    (train, held, skipped)
}

fn build(
    records: &[&PoseRecord],
    session: &[&PoseRecord],
    dof: usize,
) -> (Vec<PoseObs>, Vec<Skipped>) {
    let ctx = contexts(session, dof);
    let map: std::collections::HashMap<usize, PoseCtx> = ctx.into_iter().collect();
    let in_ref = reference::any_reference(session.iter().copied());
    let mut out = Vec::new();
    let mut skipped = Vec::new();
    for r in records {
        let mut o = match PoseObs::from_record_tracker(r, dof) {
            Ok(o) => o,
            Err(reason) => {
                skipped.push(Skipped {
                    id: r.id,
                    reason,
                    no_reference: false,
                });
                continue;
            }
        };
        if let Some(c) = map.get(&record_key(r)) {
            o.ctx = c.clone();
        }
        if in_ref {
            match reference::to_reference_frame(r, o.p, o.quat) {
                Ok((p, quat)) => {
                    o.p = p;
                    o.quat = quat;
                }
                Err(reason) => {
                    skipped.push(Skipped {
                        id: r.id,
                        reason,
                        no_reference: true,
                    });
                    continue;
                }
            }
        }
        out.push(o);
    }
    (out, skipped)
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

/// Usable observations of a dataset (file order) and the records skipped (with reasons),
/// through the one builder ([`session_observations`], the dataset as the session). When any
/// pose of `ds` carries a `reference` body, every marker is re-expressed in its frame and
/// poses without one are skipped (frames are never mixed).
pub fn observations(ds: &Dataset, dof: usize, split: Split) -> (Vec<PoseObs>, Vec<Skipped>) {
    let session: Vec<&PoseRecord> = ds.poses().collect();
    let records: Vec<&PoseRecord> = session
        .iter()
        .copied()
        .filter(|r| {
            let is_val = r.group.as_deref() == Some("validation");
            match split {
                Split::All => true,
                Split::Train => !is_val,
                Split::Validation => is_val,
            }
        })
        .collect();
    build(&records, &session, dof)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(id: u64, t: f64, q: [f64; 2]) -> String {
        format!(
            "{{\"kind\":\"pose\",\"id\":{id},\"t\":{t},\"q\":[{},{}],\"marker\":{{\"p\":[1,2,3]}}}}",
            q[0], q[1]
        )
    }

    #[test]
    fn approach_from_q_prev_or_session_order_and_torn_line() {
        let header = r#"{"format":"robocal-dataset/1","robot":{"model":"x","chain":[{"name":"j1","origin_xyz":[0,0,0],"origin_rpy":[0,0,0],"axis":[0,0,1]},{"name":"j2","origin_xyz":[0,0,100],"origin_rpy":[0,0,0],"axis":[0,1,0]}]}}"#;
        let text = format!(
            "{header}\n{}\n{}\n{}\n{}\n{{\"kind\":\"po",
            rec(0, 0.0, [0.0, 10.0]),
            rec(1, 1.0, [10.0, 5.0]),
            rec(2, 2.0, [5.0, 5.0]),
            // q_prev says joint 2 came from below although the previous pose is above.
            rec(3, 3.0, [4.0, 6.0]).replace("\"q\":", "\"q_prev\":[9,0],\"q\":"),
        );
        let l =
            crate::dataset::parse_dataset(text.as_bytes(), std::path::Path::new("mem")).unwrap();
        assert_eq!(l.dataset.poses().count(), 4);
        assert_eq!(l.warnings.len(), 1, "torn last line dropped with a warning");
        let refs: Vec<&PoseRecord> = l.dataset.poses().collect();
        let (ctx, inferred) = contexts_counted(&refs, 2);
        assert_eq!(inferred, 3, "three records without q_prev");
        let (obs, _) = session_observations(&refs, &refs, 2);
        assert_eq!(
            obs.iter().map(|o| o.id).collect::<Vec<_>>(),
            vec![0, 1, 2, 3]
        );
        assert_eq!(ctx.len(), 4);
        assert_eq!(obs[1].approach, vec![1.0, -1.0]);
        // joint 2 did not move from id 1 to id 2: keeps its last direction
        assert_eq!(obs[2].approach, vec![-1.0, -1.0]);
        // q_prev [9, 0] → [4, 6]: joint 1 from above (−), joint 2 from below (+)
        assert_eq!(obs[3].approach, vec![-1.0, 1.0]);
        // a bad line that is not the last is an error naming the line (strict reader)
        let bad = format!(
            "{header}\n{{\"kind\":\"pose\"}}\n{}\n",
            rec(0, 0.0, [0.0, 0.0])
        );
        let e = format!(
            "{:#}",
            crate::dataset::parse_dataset(bad.as_bytes(), std::path::Path::new("mem")).unwrap_err()
        );
        assert!(e.contains("mem:2"), "{e}");
    }

    #[test]
    fn reference_frame_and_records_without_reference_skipped() {
        let header = r#"{"format":"robocal-dataset/1","robot":{"model":"x","chain":[{"name":"j1","origin_xyz":[0,0,0],"origin_rpy":[0,0,0],"axis":[0,0,1]},{"name":"j2","origin_xyz":[0,0,100],"origin_rpy":[0,0,0],"axis":[0,1,0]}]}}"#;
        // reference body at (10, 20, 30) turned 90° about z: marker (1, 2, 3) in the tracker
        // is R_zᵀ((1,2,3) − (10,20,30)) = (−18, 9, −27) in the reference frame.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let with_ref = rec(0, 0.0, [0.0, 10.0]).replace(
            "\"marker\"",
            &format!("\"reference\":{{\"p\":[10,20,30],\"quat\":[{s},0,0,{s}]}},\"marker\""),
        );
        let text = format!("{header}\n{with_ref}\n{}\n", rec(1, 1.0, [1.0, 10.0]));
        let l =
            crate::dataset::parse_dataset(text.as_bytes(), std::path::Path::new("mem")).unwrap();
        let refs: Vec<&PoseRecord> = l.dataset.poses().collect();
        let (obs, skipped) = session_observations(&refs, &refs, 2);
        assert_eq!(obs.len(), 1);
        assert!(
            (obs[0].p - Point3::new(-18.0, 9.0, -27.0)).norm() < 1e-9,
            "{:?}",
            obs[0].p
        );
        assert_eq!(skipped.len(), 1);
        assert_eq!(skipped[0].id, 1);
        assert!(skipped[0].no_reference);
        assert!(
            skipped[0].reason.contains("no `reference`"),
            "{:?}",
            skipped
        );
        // without any reference in the session: the tracker frame, nothing skipped
        let only = vec![refs[1]];
        let (obs, skipped) = session_observations(&only, &only, 2);
        assert_eq!((obs.len(), skipped.len()), (1, 0));
        assert_eq!(obs[0].p, Point3::new(1.0, 2.0, 3.0));
    }
}
