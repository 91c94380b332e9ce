//! Summary statistics of a dataset (what `robocal inspect` prints).
use std::collections::BTreeMap;

use serde::Serialize;

use super::types::{Dataset, Record};

/// Range of one joint over the pose records (degrees, as in the file).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JointRange {
    /// Joint name (from the chain, else `joint_{i}`).
    pub name: String,
    /// Smallest measured angle (deg).
    pub min_deg: f64,
    /// Largest measured angle (deg).
    pub max_deg: f64,
}

/// Marker visibility over the pose records.
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct MarkerStats {
    /// Pose records with a `marker` block.
    pub with_marker: usize,
    /// Of those, marked visible.
    pub visible: usize,
    /// Of those, marked not visible.
    pub not_visible: usize,
    /// Mean tracker fit RMS of the visible ones (mm).
    pub rms_mean_mm: Option<f64>,
    /// Largest tracker fit RMS of the visible ones (mm).
    pub rms_max_mm: Option<f64>,
}

/// Laser range readings over the pose records.
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct RangeStats {
    /// Pose records with a `range` field.
    pub with_range: usize,
    /// Of those, `null` (out of range / invalid).
    pub out_of_range: usize,
    /// Smallest valid reading (mm).
    pub min_mm: Option<f64>,
    /// Largest valid reading (mm).
    pub max_mm: Option<f64>,
}

/// Everything `robocal inspect` reports about a dataset. All maps are sorted by key.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    /// Header `format`.
    pub format: String,
    /// Header `robot.model`.
    pub robot_model: String,
    /// Number of joints.
    pub dof: Option<usize>,
    /// Header `created`.
    pub created: Option<String>,
    /// Number of records (header excluded).
    pub records: usize,
    /// Record counts by `kind`.
    pub by_kind: BTreeMap<String, usize>,
    /// Pose counts by `group` (`(none)` for records without one).
    pub poses_by_group: BTreeMap<String, usize>,
    /// Earliest and latest record time (s since `created`).
    pub time_span_s: Option<[f64; 2]>,
    /// Smallest and largest pose id.
    pub pose_ids: Option<[u64; 2]>,
    /// Pose records carrying measured joints `q`.
    pub poses_with_q: usize,
    /// Pose records carrying a controller `flange` pose.
    pub poses_with_flange: usize,
    /// Measured joint ranges, one per joint.
    pub joints: Vec<JointRange>,
    /// Marker visibility.
    pub marker: MarkerStats,
    /// Laser readings.
    pub range: RangeStats,
    /// Pose records with a saved camera `image`.
    pub poses_with_image: usize,
    /// Pose records with detected image `corners`.
    pub poses_with_corners: usize,
    /// Event counts by `what`.
    pub events: BTreeMap<String, usize>,
    /// Pivot frame counts by `tool` (`(none)` when unnamed).
    pub pivots_by_tool: BTreeMap<String, usize>,
    /// Reader warnings (a dropped torn last line).
    pub warnings: Vec<String>,
}

fn min_max(acc: &mut Option<[f64; 2]>, x: f64) {
    match acc {
        Some([lo, hi]) => {
            *lo = lo.min(x);
            *hi = hi.max(x);
        }
        None => *acc = Some([x, x]),
    }
}

impl Summary {
    /// Summarises `ds`; `warnings` are the reader's warnings (as text).
    pub fn of(ds: &Dataset, warnings: Vec<String>) -> Summary {
        let dof = ds.header.robot.dof();
        let names: Vec<String> = match &ds.header.robot.chain {
            Some(c) => c.iter().map(|j| j.name.clone()).collect(),
            None => (1..=dof.unwrap_or(0))
                .map(|i| format!("joint_{i}"))
                .collect(),
        };
        let mut by_kind = BTreeMap::new();
        let mut groups = BTreeMap::new();
        let mut events = BTreeMap::new();
        let mut pivots = BTreeMap::new();
        let mut span = None;
        let mut ids: Option<[u64; 2]> = None;
        let mut joint_acc: Vec<Option<[f64; 2]>> = vec![None; names.len()];
        let mut marker = MarkerStats::default();
        let mut range = RangeStats::default();
        let (mut rms_sum, mut rms_n) = (0.0, 0usize);
        let mut rms_max: Option<f64> = None;
        let mut range_acc = None;
        let (mut with_q, mut with_flange) = (0, 0);
        let (mut with_image, mut with_corners) = (0, 0);
        for r in &ds.records {
            let (kind, t) = match r {
                Record::Pose(p) => ("pose", p.t),
                Record::Pivot(p) => ("pivot", p.t),
                Record::Event(e) => ("event", e.t),
            };
            *by_kind.entry(kind.to_string()).or_insert(0) += 1;
            min_max(&mut span, t);
            match r {
                Record::Pose(p) => {
                    let g = p.group.clone().unwrap_or_else(|| "(none)".into());
                    *groups.entry(g).or_insert(0) += 1;
                    ids = Some(match ids {
                        Some([lo, hi]) => [lo.min(p.id), hi.max(p.id)],
                        None => [p.id, p.id],
                    });
                    if let Some(q) = &p.q {
                        with_q += 1;
                        for (acc, &x) in joint_acc.iter_mut().zip(q) {
                            min_max(acc, x);
                        }
                    }
                    if p.flange.is_some() {
                        with_flange += 1;
                    }
                    if let Some(m) = &p.marker {
                        marker.with_marker += 1;
                        if m.visible {
                            marker.visible += 1;
                            if let Some(rms) = m.rms {
                                rms_sum += rms;
                                rms_n += 1;
                                rms_max = Some(rms_max.map_or(rms, |x: f64| x.max(rms)));
                            }
                        } else {
                            marker.not_visible += 1;
                        }
                    }
                    if p.image.is_some() {
                        with_image += 1;
                    }
                    if p.corners.as_ref().is_some_and(|c| !c.is_empty()) {
                        with_corners += 1;
                    }
                    if let Some(rg) = p.range {
                        range.with_range += 1;
                        match rg {
                            Some(x) => min_max(&mut range_acc, x),
                            None => range.out_of_range += 1,
                        }
                    }
                }
                Record::Pivot(p) => {
                    let tool = p.tool.clone().unwrap_or_else(|| "(none)".into());
                    *pivots.entry(tool).or_insert(0) += 1;
                }
                Record::Event(e) => {
                    *events.entry(e.what.clone()).or_insert(0) += 1;
                }
            }
        }
        if rms_n > 0 {
            marker.rms_mean_mm = Some(rms_sum / rms_n as f64);
        }
        marker.rms_max_mm = rms_max;
        if let Some([lo, hi]) = range_acc {
            range.min_mm = Some(lo);
            range.max_mm = Some(hi);
        }
        let joints = names
            .into_iter()
            .zip(joint_acc)
            .filter_map(|(name, acc)| {
                acc.map(|[lo, hi]| JointRange {
                    name,
                    min_deg: lo,
                    max_deg: hi,
                })
            })
            .collect();
        Summary {
            format: ds.header.format.clone(),
            robot_model: ds.header.robot.model.clone(),
            dof,
            created: ds.header.created.clone(),
            records: ds.records.len(),
            by_kind,
            poses_by_group: groups,
            time_span_s: span,
            pose_ids: ids,
            poses_with_q: with_q,
            poses_with_flange: with_flange,
            joints,
            marker,
            range,
            poses_with_image: with_image,
            poses_with_corners: with_corners,
            events,
            pivots_by_tool: pivots,
            warnings,
        }
    }
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "format:   {}", self.format)?;
        write!(f, "robot:    {}", self.robot_model)?;
        match self.dof {
            Some(d) => writeln!(f, " ({d} joints)")?,
            None => writeln!(f)?,
        }
        if let Some(c) = &self.created {
            writeln!(f, "created:  {c}")?;
        }
        let kinds: Vec<String> = self
            .by_kind
            .iter()
            .map(|(k, n)| format!("{k} {n}"))
            .collect();
        writeln!(f, "records:  {} ({})", self.records, kinds.join(", "))?;
        if !self.poses_by_group.is_empty() {
            let g: Vec<String> = self
                .poses_by_group
                .iter()
                .map(|(k, n)| format!("{k} {n}"))
                .collect();
            writeln!(f, "groups:   {}", g.join(", "))?;
        }
        if let Some([lo, hi]) = self.pose_ids {
            writeln!(f, "pose ids: {lo}..={hi}")?;
        }
        if let Some([t0, t1]) = self.time_span_s {
            writeln!(
                f,
                "time:     {t0:.3} s .. {t1:.3} s ({:.1} min)",
                (t1 - t0) / 60.0
            )?;
        }
        writeln!(
            f,
            "poses with q: {}, with flange pose: {}",
            self.poses_with_q, self.poses_with_flange
        )?;
        if !self.joints.is_empty() {
            writeln!(f, "joint ranges (deg):")?;
            for j in &self.joints {
                writeln!(
                    f,
                    "  {:<10} {:>10.3} .. {:>10.3}",
                    j.name, j.min_deg, j.max_deg
                )?;
            }
        }
        let m = &self.marker;
        if m.with_marker > 0 {
            write!(
                f,
                "marker:   {} visible, {} not visible",
                m.visible, m.not_visible
            )?;
            if let (Some(mean), Some(max)) = (m.rms_mean_mm, m.rms_max_mm) {
                write!(f, "; fit rms mean {mean:.3} mm, max {max:.3} mm")?;
            }
            writeln!(f)?;
        }
        let r = &self.range;
        if r.with_range > 0 {
            write!(
                f,
                "laser:    {} readings, {} out of range",
                r.with_range, r.out_of_range
            )?;
            if let (Some(lo), Some(hi)) = (r.min_mm, r.max_mm) {
                write!(f, "; {lo:.3} .. {hi:.3} mm")?;
            }
            writeln!(f)?;
        }
        if self.poses_with_image > 0 || self.poses_with_corners > 0 {
            writeln!(
                f,
                "camera:   {} images, {} with detected corners",
                self.poses_with_image, self.poses_with_corners
            )?;
        }
        if !self.events.is_empty() {
            let e: Vec<String> = self
                .events
                .iter()
                .map(|(k, n)| format!("{k} {n}"))
                .collect();
            writeln!(f, "events:   {}", e.join(", "))?;
        }
        if !self.pivots_by_tool.is_empty() {
            let p: Vec<String> = self
                .pivots_by_tool
                .iter()
                .map(|(k, n)| format!("{k} {n}"))
                .collect();
            writeln!(f, "pivots:   {}", p.join(", "))?;
        }
        for w in &self.warnings {
            writeln!(f, "warning:  {w}")?;
        }
        Ok(())
    }
}
