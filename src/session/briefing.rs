//! What a live session shows before it asks to move the arm: the plan is made
//! first, then the operator sees the poses left to acquire, the predicted duration, the box
//! the flange stays in and its lowest height against the table, the speed cap and every plan
//! warning — and only then is asked (or `--yes` stands for the answer).
use std::fmt::Write as _;
use std::path::Path;

use super::SessionFile;
use crate::plan::PlanFile;

/// One plan of the session as the briefing shows it.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanBrief {
    /// `train` or `validation`.
    pub set: String,
    pub poses: usize,
    /// Poses already recorded (or skipped for good) by an earlier invocation.
    pub done: usize,
    pub predicted_s: f64,
    /// Flange positions of the poses left: min / max per axis (mm, robot base).
    pub box_min_mm: [f64; 3],
    pub box_max_mm: [f64; 3],
    /// The table plane and the clearance the planner kept above it (mm), if the spec has one.
    pub table_z_mm: Option<f64>,
    pub clearance_mm: Option<f64>,
}

/// The session's plans as they stand in `dir` (the acquisition stages not yet done).
pub fn plans(dir: &Path, s: &SessionFile) -> anyhow::Result<Vec<PlanBrief>> {
    let mut out = Vec::new();
    for (stage, set) in [
        (None, "survey"),
        (Some(super::Stage::AcquireTrain), "train"),
        (Some(super::Stage::AcquireValidation), "validation"),
    ] {
        let path = dir.join("plan").join(format!("{set}.json"));
        let done = match stage {
            Some(st) => s.stages_done.contains(&st),
            // The survey's probe poses (`--survey`): shown until the survey is done; the
            // calibration plans are made after it, from what it found.
            None => s.survey.is_some() || !path.is_file(),
        };
        if done || (stage.is_some() && s.setup.survey && s.survey.is_none()) {
            continue;
        }
        let plan = PlanFile::read(&path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let journal = dir.join(format!("run-{set}")).join("dataset.jsonl");
        let done_ids = if journal.is_file() {
            crate::dataset::read_dataset(&journal)
                .map(|l| crate::acquire::done_pose_ids(&l.dataset.records))
                .unwrap_or_default()
        } else {
            Default::default()
        };
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in plan.poses.iter().filter(|p| !done_ids.contains(&p.id)) {
            for k in 0..3 {
                lo[k] = lo[k].min(p.flange.p[k]);
                hi[k] = hi[k].max(p.flange.p[k]);
            }
        }
        let c = &plan.spec["constraints"];
        out.push(PlanBrief {
            set: set.into(),
            poses: plan.poses.len(),
            done: done_ids.len().min(plan.poses.len()),
            predicted_s: plan.summary.timing.optimised_s,
            box_min_mm: lo,
            box_max_mm: hi,
            table_z_mm: c["table_z_mm"].as_f64(),
            clearance_mm: c["table_clearance_mm"].as_f64(),
        });
    }
    Ok(out)
}

/// The text shown before the consent question.
pub fn text(dir: &Path, s: &SessionFile) -> anyhow::Result<String> {
    let plans = plans(dir, s)?;
    let mut t = String::new();
    let arm = s
        .cell
        .robot_serial
        .as_deref()
        .unwrap_or(&s.cell.robot_model);
    if s.setup.survey && s.survey.is_none() {
        let _ = writeln!(
            t,
            "LIVE session {}: first a survey — probe poses that locate the tracker and the \
             marker; the calibration plan is made from what they find and shown before it \
             moves. Before anything moves:",
            dir.display()
        );
    } else {
        let _ = writeln!(
            t,
            "LIVE session {}: the plan is made; before anything moves:",
            dir.display()
        );
    }
    if let Some(v) = &s.survey {
        let _ = writeln!(t, "  {}", super::survey::words(v));
    }
    let _ = writeln!(
        t,
        "  arm: {arm} ({}{}){}",
        s.cell.robot_model,
        s.cell
            .controller
            .as_deref()
            .map(|c| format!(", {c}"))
            .unwrap_or_default(),
        s.cell
            .tracker
            .as_deref()
            .map(|x| format!("; tracker {x}"))
            .unwrap_or_default()
    );
    let left: usize = plans.iter().map(|p| p.poses - p.done).sum();
    let mut secs = 0.0;
    for p in &plans {
        let frac = if p.poses == 0 {
            0.0
        } else {
            (p.poses - p.done) as f64 / p.poses as f64
        };
        secs += p.predicted_s * frac;
        let _ = writeln!(
            t,
            "  {} poses: {} planned, {} left{}",
            p.set,
            p.poses,
            p.poses - p.done,
            if p.done > 0 {
                format!(" ({} done by an earlier run)", p.done)
            } else {
                String::new()
            }
        );
    }
    let _ = writeln!(
        t,
        "  {left} poses to move through; predicted acquisition {:.0} s (~{:.0} min)",
        secs,
        secs / 60.0
    );
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in plans.iter().filter(|p| p.poses > p.done) {
        for k in 0..3 {
            lo[k] = lo[k].min(p.box_min_mm[k]);
            hi[k] = hi[k].max(p.box_max_mm[k]);
        }
    }
    if lo[0].is_finite() {
        let _ = writeln!(
            t,
            "  workspace (flange, robot base): x {:.0} … {:.0}, y {:.0} … {:.0}, z {:.0} … {:.0} mm",
            lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]
        );
        let table = plans
            .iter()
            .find_map(|p| p.table_z_mm.map(|z| (z, p.clearance_mm)));
        let _ = match table {
            Some((z, c)) => writeln!(
                t,
                "  lowest flange height: z = {:.0} mm, {:.0} mm above the table (z = {z:.0} mm; \
                 planned clearance ≥ {:.0} mm)",
                lo[2],
                lo[2] - z,
                c.unwrap_or(0.0)
            ),
            None => writeln!(
                t,
                "  lowest flange height: z = {:.0} mm (the plan spec states no table)",
                lo[2]
            ),
        };
    }
    let _ = writeln!(
        t,
        "  speed cap: {} °/s per joint, acceleration {} °/s²",
        s.setup.speed_deg_s, s.setup.accel_deg_s2
    );
    if s.warnings.is_empty() {
        let _ = writeln!(t, "  plan warnings: none");
    } else {
        let _ = writeln!(t, "  plan warnings ({}):", s.warnings.len());
        for w in &s.warnings {
            let _ = writeln!(t, "    WARNING: {w}");
        }
    }
    Ok(t)
}
