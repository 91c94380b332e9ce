//! What a run reports at its end (`RUN_DIR/summary.json`).
use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// A planned pose that was not recorded, and why.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SkippedPose {
    /// The planned pose id.
    pub id: u64,
    /// Why (as in its `skip` event).
    pub reason: String,
}

/// Where the time went (s, on the devices' clock), summed over the poses of this
/// invocation.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct TimeBreakdown {
    /// Commanded motions (including retries).
    pub move_s: f64,
    /// Waiting for the arm and marker to settle.
    pub settle_s: f64,
    /// Tracker frames and laser readings.
    pub sample_s: f64,
    /// Everything else: controller queries, journal writes, fault handling, backoff.
    pub overhead_s: f64,
}

impl TimeBreakdown {
    /// Total of the four parts.
    pub fn total_s(&self) -> f64 {
        self.move_s + self.settle_s + self.sample_s + self.overhead_s
    }
}

/// The outcome of a run (or of all invocations of a resumed run).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct RunSummary {
    /// Poses in the plan.
    pub planned: usize,
    /// Pose records in the journal at the end.
    pub recorded: usize,
    /// Poses recorded by this invocation.
    pub recorded_now: usize,
    /// Poses already in the journal when this invocation started (resume).
    pub already_done: usize,
    /// Planned poses skipped for good, sorted by id.
    pub skipped: Vec<SkippedPose>,
    /// Planned poses still to do (the run stopped early or aborted).
    pub remaining: usize,
    /// Event counts by `what` over the whole journal.
    pub events: BTreeMap<String, usize>,
    /// Time of this invocation (s, devices' clock).
    pub time: TimeBreakdown,
    /// Poses per hour of this invocation (recorded or skipped, per device-clock hour).
    pub poses_per_hour: f64,
    /// Why the run stopped before the end, if it did.
    pub aborted: Option<String>,
    /// Stopped on request (Ctrl-C) after the record of this pose was durable (`None`: the
    /// pose loop was not interrupted, or no pose had been handled yet).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stopped_at: Option<u64>,
    /// Stopped on request (Ctrl-C) before the end.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub interrupted: bool,
}

impl std::fmt::Display for RunSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "poses: {} planned, {} recorded ({} now, {} before), {} skipped, {} remaining",
            self.planned,
            self.recorded,
            self.recorded_now,
            self.already_done,
            self.skipped.len(),
            self.remaining
        )?;
        let t = &self.time;
        writeln!(
            f,
            "time: {:.1} s (move {:.1}, settle {:.1}, sample {:.1}, overhead {:.1}); {:.0} poses/h",
            t.total_s(),
            t.move_s,
            t.settle_s,
            t.sample_s,
            t.overhead_s,
            self.poses_per_hour
        )?;
        if !self.events.is_empty() {
            let e: Vec<String> = self
                .events
                .iter()
                .map(|(k, n)| format!("{k} {n}"))
                .collect();
            writeln!(f, "events: {}", e.join(", "))?;
        }
        for s in &self.skipped {
            writeln!(f, "skipped pose {}: {}", s.id, s.reason)?;
        }
        if let Some(a) = &self.aborted {
            writeln!(f, "ABORTED: {a}")?;
        }
        Ok(())
    }
}
