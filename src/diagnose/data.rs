//! Observations for the diagnosis: pose records turned into joint angles (rad), measured
//! marker points (mm, tracker frame) and the side data effects need (time, temperature,
//! approach direction per joint, joint velocity when recorded).
use nalgebra::Point3;
use std::path::Path;

use crate::dataset::{Header, PoseRecord, Record};

/// Side data of one pose that effect regressors use (internal units: rad, s, °C).
#[derive(Debug, Clone, PartialEq)]
pub struct ObsCtx {
    /// Record id (acquisition order).
    pub id: u64,
    /// Seconds since the header's `created`.
    pub t: f64,
    /// Measured joint angles (rad).
    pub q: Vec<f64>,
    /// Approach direction of each joint: sign of `q_i(k) − q_i(k−1)` in acquisition order
    /// (`0` when unknown or the joint did not move).
    pub approach: Vec<f64>,
    /// Temperature (°C) when recorded.
    pub temp_c: Option<f64>,
    /// Joint velocity (rad/s) when recorded (`qd` field, deg/s in files).
    pub qd: Option<Vec<f64>>,
}

/// One measured pose: context and the measured marker origin (mm, tracker frame).
#[derive(Debug, Clone, PartialEq)]
pub struct Obs {
    pub ctx: ObsCtx,
    pub y: Point3<f64>,
}

/// A loaded dataset: header and pose records in file order, read through the strict
/// dataset reader ([`crate::dataset::read_dataset`], torn-line rule included).
#[derive(Debug, Clone)]
pub struct Loaded {
    pub header: Header,
    pub poses: Vec<PoseRecord>,
    /// Warnings (e.g. a torn last line dropped).
    pub warnings: Vec<String>,
}

impl From<crate::dataset::Loaded> for Loaded {
    fn from(l: crate::dataset::Loaded) -> Self {
        Loaded {
            poses: l
                .dataset
                .records
                .into_iter()
                .filter_map(|r| match r {
                    Record::Pose(p) => Some(p),
                    _ => None,
                })
                .collect(),
            header: l.dataset.header,
            warnings: l.warnings.iter().map(ToString::to_string).collect(),
        }
    }
}

/// Read a `robocal-dataset/1` file with the strict reader (errors name file, line, field).
pub fn load_jsonl(path: &Path) -> anyhow::Result<Loaded> {
    Ok(crate::dataset::read_dataset(path)?.into())
}

/// Parse the text of a dataset (see [`load_jsonl`]); `label` names it in errors.
pub fn parse_jsonl(text: &str, label: &str) -> anyhow::Result<Loaded> {
    Ok(crate::dataset::parse_dataset(text.as_bytes(), Path::new(label))?.into())
}

/// Whether a pose record carries a usable marker measurement.
fn marker_point(p: &PoseRecord) -> Option<Point3<f64>> {
    let m = p.marker.as_ref()?;
    if !m.visible {
        return None;
    }
    let v = m.p?;
    v.iter()
        .all(|x| x.is_finite())
        .then(|| Point3::new(v[0], v[1], v[2]))
}

fn joint_rad(p: &PoseRecord, dof: usize) -> Option<Vec<f64>> {
    let q = p.q.as_ref()?;
    (q.len() == dof && q.iter().all(|x| x.is_finite()))
        .then(|| q.iter().map(|d| d.to_radians()).collect())
}

fn qd_rad(p: &PoseRecord, dof: usize) -> Option<Vec<f64>> {
    let v = p.extra.get("qd")?.as_array()?;
    let out: Vec<f64> = v.iter().filter_map(|x| x.as_f64()).collect();
    (out.len() == dof && out.iter().all(|x| x.is_finite()))
        .then(|| out.iter().map(|d| d.to_radians()).collect())
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
pub fn contexts_counted(records: &[&PoseRecord], dof: usize) -> (Vec<(usize, ObsCtx)>, usize) {
    let mut v: Vec<(&PoseRecord, Vec<f64>)> = records
        .iter()
        .filter_map(|p| joint_rad(p, dof).map(|q| (*p, q)))
        .filter(|(p, _)| p.t.is_finite())
        .collect();
    v.sort_by(|a, b| a.0.t.total_cmp(&b.0.t).then(a.0.id.cmp(&b.0.id)));
    let mut out = Vec::with_capacity(v.len());
    let mut prev: Option<Vec<f64>> = None;
    let mut inferred = 0;
    // Motions smaller than this (rad) do not change the approach direction.
    const MOVE_EPS: f64 = 1e-6;
    let mut last_sign = vec![0.0; dof];
    for (p, q) in v {
        let q_prev = p
            .q_prev
            .as_ref()
            .filter(|x| x.len() == dof && x.iter().all(|v| v.is_finite()))
            .map(|x| x.iter().map(|d| d.to_radians()).collect::<Vec<f64>>());
        let from = q_prev.as_ref().or(prev.as_ref());
        if let Some(pq) = from {
            for i in 0..dof {
                let dq = q[i] - pq[i];
                if dq.abs() > MOVE_EPS {
                    last_sign[i] = dq.signum();
                }
            }
        }
        let mut approach = last_sign.clone();
        let mut explicit = false;
        if let Some(a) = p.extra.get("approach").and_then(|a| a.as_array()) {
            let s: Vec<f64> = a.iter().filter_map(|x| x.as_f64()).collect();
            if s.len() == dof {
                approach = s.iter().map(|x| x.signum()).collect();
                explicit = true;
            }
        }
        if q_prev.is_none() && !explicit {
            inferred += 1;
        }
        prev = Some(q.clone());
        out.push((
            record_key(p),
            ObsCtx {
                id: p.id,
                t: p.t,
                q,
                approach,
                temp_c: p.temp_c.filter(|x| x.is_finite()),
                qd: qd_rad(p, dof),
            },
        ));
    }
    (out, inferred)
}

/// [`contexts_counted`] without the count.
pub fn contexts(records: &[&PoseRecord], dof: usize) -> Vec<(usize, ObsCtx)> {
    contexts_counted(records, dof).0
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

/// Observations (records with joints and a visible marker) from `records`, using the
/// contexts computed over `session` (all records of the session, see [`contexts`]).
/// When any record of `session` carries a `reference` body, every marker is re-expressed in
/// its frame ([`crate::dataset::reference`]) and records without a usable reference are
/// left out (frames are never mixed; [`observations_skipped`] says which and why).
pub fn observations(records: &[&PoseRecord], session: &[&PoseRecord], dof: usize) -> Vec<Obs> {
    let (out, skipped) = observations_skipped(records, session, dof);
    if !skipped.is_empty() {
        tracing::warn!("{}", reference_skip_warning(&skipped));
    }
    out
}

/// The warning for records left out because they lack a usable reference body.
pub fn reference_skip_warning(skipped: &[(u64, String)]) -> String {
    format!(
        "{} pose record(s) left out: the session's markers are expressed in the reference body's frame and these have no usable reference (first: id {}: {})",
        skipped.len(),
        skipped.first().map_or(0, |s| s.0),
        skipped.first().map_or("", |s| s.1.as_str())
    )
}

/// [`observations`] and the records with joints and a visible marker that were left out
/// because the session is in the reference frame and they have no usable reference
/// (`(id, reason)`).
pub fn observations_skipped(
    records: &[&PoseRecord],
    session: &[&PoseRecord],
    dof: usize,
) -> (Vec<Obs>, Vec<(u64, String)>) {
    let ctx = contexts(session, dof);
    let map: std::collections::HashMap<usize, &ObsCtx> = ctx.iter().map(|(k, c)| (*k, c)).collect();
    let in_ref = crate::dataset::reference::any_reference(session.iter().copied());
    let mut skipped = Vec::new();
    let mut out: Vec<Obs> = records
        .iter()
        .filter_map(|p| {
            let y = marker_point(p)?;
            let c = map.get(&record_key(p))?;
            let y = if in_ref {
                match crate::dataset::reference::to_reference_frame(p, y, None) {
                    Ok((y, _)) => y,
                    Err(reason) => {
                        skipped.push((p.id, reason));
                        return None;
                    }
                }
            } else {
                y
            };
            Some(Obs {
                ctx: (*c).clone(),
                y,
            })
        })
        .collect();
    out.sort_by(|a, b| a.ctx.t.total_cmp(&b.ctx.t).then(a.ctx.id.cmp(&b.ctx.id)));
    (out, skipped)
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
        let l = parse_jsonl(&text, "mem").unwrap();
        assert_eq!(l.poses.len(), 4);
        assert_eq!(l.warnings.len(), 1, "torn last line dropped with a warning");
        let refs: Vec<&PoseRecord> = l.poses.iter().collect();
        let (ctx, inferred) = contexts_counted(&refs, 2);
        assert_eq!(inferred, 3, "three records without q_prev");
        let obs = observations(&refs, &refs, 2);
        assert_eq!(
            obs.iter().map(|o| o.ctx.id).collect::<Vec<_>>(),
            vec![0, 1, 2, 3]
        );
        assert_eq!(ctx.len(), 4);
        assert_eq!(obs[1].ctx.approach, vec![1.0, -1.0]);
        // joint 2 did not move from id 1 to id 2: keeps its last direction
        assert_eq!(obs[2].ctx.approach, vec![-1.0, -1.0]);
        // q_prev [9, 0] → [4, 6]: joint 1 from above (−), joint 2 from below (+)
        assert_eq!(obs[3].ctx.approach, vec![-1.0, 1.0]);
        // a bad line that is not the last is an error naming the line (strict reader)
        let bad = format!(
            "{header}\n{{\"kind\":\"pose\"}}\n{}\n",
            rec(0, 0.0, [0.0, 0.0])
        );
        let e = format!("{:#}", parse_jsonl(&bad, "mem").unwrap_err());
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
        let l = parse_jsonl(&text, "mem").unwrap();
        let refs: Vec<&PoseRecord> = l.poses.iter().collect();
        let (obs, skipped) = observations_skipped(&refs, &refs, 2);
        assert_eq!(obs.len(), 1);
        assert!(
            (obs[0].y - Point3::new(-18.0, 9.0, -27.0)).norm() < 1e-9,
            "{:?}",
            obs[0].y
        );
        assert_eq!(skipped.len(), 1);
        assert_eq!(skipped[0].0, 1);
        assert!(skipped[0].1.contains("no `reference`"), "{:?}", skipped);
        // without any reference in the session: the tracker frame, nothing skipped
        let only = vec![refs[1]];
        let (obs, skipped) = observations_skipped(&only, &only, 2);
        assert_eq!((obs.len(), skipped.len()), (1, 0));
        assert_eq!(obs[0].y, Point3::new(1.0, 2.0, 3.0));
    }
}
