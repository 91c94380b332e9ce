//! The per-pose loop: move, settle, sample, record, with fault handling (see the module
//! docs of [`crate::acquire`]).
use std::collections::{BTreeMap, HashSet};
use std::future::Future;
use std::path::{Path, PathBuf};

use nalgebra::Point3;
use robocal_drivers::camera::pgm;
use robocal_drivers::{
    DriverError, DriverResult, ErrorKind, Image, JointState, RangeReading, SafetyState, ToolStatus,
};
use serde_json::{json, Map, Value};

use super::sample::{average_markers, average_range, MarkerAverage, MarkerSample};
use super::settle::{SettleSample, Settler};
use super::summary::{RunSummary, SkippedPose, TimeBreakdown};
use super::transfer::NoTransfer;
use super::{AcquireOptions, Devices, PlannedPose};
use crate::dataset::{DatasetError, EventRecord, FilePose, Journal, MarkerObs, PoseRecord, Record};

/// Progress after each pose (for a progress bar or `--json` progress lines).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Progress {
    /// Planned poses handled so far (recorded or skipped, this and earlier invocations).
    pub done: usize,
    /// Poses in the plan.
    pub total: usize,
    /// Pose records so far.
    pub recorded: usize,
    /// Poses skipped so far.
    pub skipped: usize,
    /// The pose just handled.
    pub id: u64,
    /// Whether it was recorded (else skipped).
    pub ok: bool,
    /// Time since this invocation started (s, devices' clock).
    pub elapsed_s: f64,
    /// Throughput of this invocation (poses per hour, devices' clock).
    pub poses_per_hour: f64,
    /// Estimated time to the end (s, devices' clock).
    pub eta_s: Option<f64>,
}

/// What stops a run with an error (device faults the engine handles become events).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AcquireError {
    /// The journal could not be written.
    #[error(transparent)]
    Journal(#[from] DatasetError),
    /// The plan does not fit the journal (dof, id order).
    #[error("plan pose {id}: {msg}")]
    Plan {
        /// The planned pose.
        id: u64,
        /// What is wrong.
        msg: String,
    },
}

/// Ids of planned poses that need no more work: recorded poses and poses skipped for
/// good (a `skip` event naming the id).
pub fn done_pose_ids(records: &[Record]) -> HashSet<u64> {
    records
        .iter()
        .filter_map(|r| match r {
            Record::Pose(p) => Some(p.id),
            Record::Event(e) if e.what == "skip" => e.id,
            _ => None,
        })
        .collect()
}

/// Start of the reason of a pose skipped because the pose itself breaks a safety limit (a
/// final skip: skips for a transient reason are retried once at the end of the run).
pub const UNSAFE_POSE: &str = "unsafe pose";

/// Why one pose ended without a record.
enum Outcome {
    Recorded,
    /// Skipped for a transient reason (retried once at the end of the run).
    Skipped(String),
    /// Skipped for good: the pose itself breaks a safety limit.
    Unsafe(String),
    Abort(String),
}

/// Result of a device call made under link-retry.
enum Step<T> {
    Ok(T),
    /// The device answered with an error that is not a link problem.
    Failed(DriverError),
    /// The link stayed down through every attempt.
    LinkLost(String),
}

/// Where the images of the journal at `journal` go: `<dir>/<stem>.images` (for
/// `run/dataset.jsonl`: `run/dataset.images`). Pose records name their image relative to
/// the journal's directory (`dataset.images/pose-12.pgm`).
pub fn images_dir(journal: &Path) -> PathBuf {
    let stem = journal
        .file_stem()
        .map_or_else(|| "dataset".into(), |s| s.to_string_lossy().into_owned());
    journal.with_file_name(format!("{stem}.images"))
}

/// File name of pose `id`'s image inside [`images_dir`].
pub fn image_file_name(id: u64) -> String {
    format!("pose-{id}.pgm")
}

use crate::fsio::{sync_dir, write_atomic as write_durably};

struct Run<'a> {
    dev: &'a Devices,
    opts: &'a AcquireOptions,
    journal: &'a mut Journal,
    t0_clock: f64,
    t_offset: f64,
    time: TimeBreakdown,
    skipped: Vec<SkippedPose>,
    events: BTreeMap<String, usize>,
    /// Tracker scatter (`spread_mm`) of the last poses, for the settling detector.
    spreads: Vec<f64>,
    /// Where pose images are written ([`images_dir`] of the journal).
    images_dir: PathBuf,
    /// Whether `images_dir` is known to exist (created and its parent fsync'd).
    images_dir_ready: bool,
    /// The plan's poses (rad): candidate postures for safe transfers.
    plan_q: Vec<Vec<f64>>,
    /// Those of `plan_q` that are safe to stand at (computed on first need).
    postures: Option<Vec<Vec<f64>>>,
    /// Successful recoveries (protective stop) so far: a transfer re-plans after one.
    recoveries: usize,
    /// Where the arm was when the next move starts (deg): the last measured joints, or the
    /// last target reached when nothing was measured there (the record's `q_prev`).
    last_q_deg: Option<Vec<f64>>,
    /// Links each device's driver had rebuilt on its own when last looked at
    /// ([`robocal_drivers::ArmStatus::link_recoveries`]): arm, tracker, laser.
    link_recoveries_seen: [u64; 3],
}

fn deg(v: &[f64]) -> Vec<f64> {
    v.iter().map(|x| x.to_degrees()).collect()
}

fn file_pose(iso: &nalgebra::Isometry3<f64>) -> FilePose {
    let t = iso.translation.vector;
    let q = iso.rotation.quaternion();
    FilePose {
        p: [t.x, t.y, t.z],
        quat: [q.w, q.i, q.j, q.k],
        extra: Map::new(),
    }
}

impl Run<'_> {
    /// Median tracker scatter of the last (up to 5) poses.
    fn noise_3d_mm(&self) -> Option<f64> {
        let mut v: Vec<f64> = self.spreads.iter().rev().take(5).copied().collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        Some(v[v.len() / 2])
    }

    fn now(&self) -> f64 {
        self.dev.clock.now()
    }

    /// Record time: seconds since the header's `created` (continues across resumes).
    fn t(&self) -> f64 {
        self.t_offset + (self.now() - self.t0_clock)
    }

    fn event(
        &mut self,
        what: &str,
        id: Option<u64>,
        reason: impl Into<String>,
    ) -> Result<(), AcquireError> {
        self.event_with(what, id, reason, Map::new())
    }

    /// An event record with extra fields.
    fn event_with(
        &mut self,
        what: &str,
        id: Option<u64>,
        reason: impl Into<String>,
        extra: Map<String, Value>,
    ) -> Result<(), AcquireError> {
        let reason = reason.into();
        tracing::info!(what, ?id, %reason, "event");
        let rec = Record::Event(EventRecord {
            t: self.t(),
            what: what.to_string(),
            id,
            reason: Some(reason),
            extra,
        });
        self.journal.append(&rec)?;
        *self.events.entry(what.to_string()).or_insert(0) += 1;
        Ok(())
    }

    /// Links rebuilt by the drivers on their own so far: arm, tracker, laser.
    fn link_recoveries_now(&self) -> [u64; 3] {
        [
            self.dev.arm.link_recoveries(),
            self.dev.tracker.as_ref().map_or(0, |t| t.link_recoveries()),
            self.dev.range.as_ref().map_or(0, |r| r.link_recoveries()),
        ]
    }

    /// A `fault` event for every link a driver lost and rebuilt inside a call that then
    /// succeeded (the caller saw no error, but the fault happened and belongs in the log).
    fn note_link_recoveries(&mut self, id: u64, what: &str) -> Result<(), AcquireError> {
        let now = self.link_recoveries_now();
        for (k, device) in ["arm", "tracker", "laser"].iter().enumerate() {
            for _ in self.link_recoveries_seen[k]..now[k] {
                self.event(
                    "fault",
                    Some(id),
                    format!("{device} link lost during {what}; the driver reconnected and the call succeeded"),
                )?;
            }
        }
        self.link_recoveries_seen = now;
        Ok(())
    }

    /// Runs `op`; on a link problem (`Disconnected` / `Timeout`) records a `fault` event,
    /// backs off exponentially and retries (drivers reconnect on their next call); records
    /// `resume` once the link answers again.
    async fn link<T, F, Fut>(
        &mut self,
        id: u64,
        what: &str,
        mut op: F,
    ) -> Result<Step<T>, AcquireError>
    where
        F: FnMut() -> Fut,
        Fut: Future<Output = DriverResult<T>>,
    {
        let f = self.opts.faults;
        let mut backoff = f.backoff_initial_s;
        let mut failures = 0u32;
        loop {
            let r = op().await;
            self.note_link_recoveries(id, what)?;
            match r {
                Ok(v) => {
                    if failures > 0 {
                        self.event(
                            "resume",
                            Some(id),
                            format!("link restored after {failures} failed attempt(s) ({what})"),
                        )?;
                    }
                    return Ok(Step::Ok(v));
                }
                Err(e) if e.kind().needs_reconnect() => {
                    failures += 1;
                    if failures == 1 {
                        self.event("fault", Some(id), format!("link lost during {what}: {e}"))?;
                    }
                    if failures >= f.link_attempts.max(1) {
                        return Ok(Step::LinkLost(format!(
                            "link lost during {what} after {failures} attempts: {e}"
                        )));
                    }
                    self.dev.clock.sleep(backoff).await;
                    backoff = (backoff * 2.0).min(f.backoff_max_s);
                }
                Err(e) => return Ok(Step::Failed(e)),
            }
        }
    }

    async fn joints(&mut self, id: u64) -> Result<Result<JointState, Outcome>, AcquireError> {
        let arm = self.dev.arm.clone();
        Ok(
            match self
                .link(id, "joint readout", || {
                    let arm = arm.clone();
                    async move { arm.joints().await }
                })
                .await?
            {
                Step::Ok(j) => Ok(j),
                Step::Failed(e) => Err(Outcome::Abort(format!("joint readout failed: {e}"))),
                Step::LinkLost(m) => Err(Outcome::Abort(m)),
            },
        )
    }

    /// Protective stop: pause, try to recover, resume. `Err(outcome)` aborts the run.
    async fn recover_stop(
        &mut self,
        id: u64,
        why: &str,
    ) -> Result<Result<(), Outcome>, AcquireError> {
        self.event("pause", Some(id), format!("protective stop: {why}"))?;
        let f = self.opts.faults;
        let arm = self.dev.arm.clone();
        for attempt in 1..=f.stop_recoveries.max(1) {
            self.dev.clock.sleep(f.stop_wait_s).await;
            let a = arm.clone();
            match self
                .link(id, "protective-stop recovery", || {
                    let a = a.clone();
                    async move { a.recover().await }
                })
                .await?
            {
                Step::LinkLost(m) => return Ok(Err(Outcome::Abort(m))),
                Step::Failed(e) if e.kind() == ErrorKind::Unsupported => {
                    return Ok(Err(Outcome::Abort(format!(
                        "protective stop needs a person: {e}"
                    ))))
                }
                Step::Failed(e) => {
                    tracing::warn!("recovery attempt {attempt} failed: {e}");
                    continue;
                }
                Step::Ok(()) => {}
            }
            let a = arm.clone();
            if let Step::Ok(st) = self
                .link(id, "arm state", || {
                    let a = a.clone();
                    async move { a.state().await }
                })
                .await?
            {
                if matches!(st.safety, SafetyState::Normal | SafetyState::Reduced) {
                    self.event(
                        "resume",
                        Some(id),
                        format!("recovered from protective stop (attempt {attempt})"),
                    )?;
                    self.recoveries += 1;
                    return Ok(Ok(()));
                }
            }
        }
        Ok(Err(Outcome::Abort(format!(
            "protective stop not recovered after {} attempts",
            f.stop_recoveries.max(1)
        ))))
    }

    /// Moves to `target` (rad) by a safe transfer ([`super::transfer`]): straight when the
    /// safety check passes along the straight move, else through one or two safe postures of
    /// the plan; re-planned from where the arm is after a recovery. Skips the pose for good
    /// only when the pose itself is unsafe. `Err(outcome)` = skip or abort.
    async fn move_to(
        &mut self,
        id: u64,
        target: &[f64],
    ) -> Result<Result<(), Outcome>, AcquireError> {
        let Some(safety) = self.opts.transfer.clone() else {
            return self.move_direct(id, target).await;
        };
        const MAX_PLANS: usize = 4;
        for _ in 0..MAX_PLANS {
            let from = match self.joints(id).await? {
                Ok(j) => j.q,
                Err(o) => return Ok(Err(o)),
            };
            if self.postures.is_none() {
                self.postures = Some(safety.safe_postures(&self.plan_q));
            }
            let postures = self.postures.as_deref().unwrap_or(&[]);
            let legs = match safety.plan(postures, &from, target) {
                Ok(l) => l,
                Err(NoTransfer::UnsafeTarget(v)) => {
                    return Ok(Err(Outcome::Unsafe(format!("{UNSAFE_POSE}: {v}"))))
                }
                Err(NoTransfer::UnsafeStart(v)) => {
                    self.event(
                        "pause",
                        Some(id),
                        format!("the arm stands at an unsafe posture: {v}"),
                    )?;
                    return Ok(Err(Outcome::Abort(format!(
                        "the arm stands at an unsafe posture ({v}): bring it back inside the \
                         envelope, above the table, then resume"
                    ))));
                }
                Err(NoTransfer::NoPath) => {
                    return Ok(Err(Outcome::Skipped(
                        "unreachable: no safe transfer from the arm's position".into(),
                    )))
                }
            };
            if legs.len() > 1 {
                self.event(
                    "note",
                    Some(id),
                    format!(
                        "safe transfer through {} intermediate posture(s)",
                        legs.len() - 1
                    ),
                )?;
            }
            let recoveries = self.recoveries;
            let n = legs.len();
            let mut replan = false;
            for (k, leg) in legs.iter().enumerate() {
                if let Err(o) = self.move_direct(id, leg).await? {
                    return Ok(Err(o));
                }
                if self.recoveries != recoveries && k + 1 < n {
                    replan = true;
                    break;
                }
            }
            if !replan {
                return Ok(Ok(()));
            }
        }
        Ok(Err(Outcome::Skipped(format!(
            "unreachable: transfer interrupted by recoveries {MAX_PLANS} times"
        ))))
    }

    /// Moves straight (joint-interpolated) to `target` (rad). `Err(outcome)` = skip or abort.
    async fn move_direct(
        &mut self,
        id: u64,
        target: &[f64],
    ) -> Result<Result<(), Outcome>, AcquireError> {
        let speed = self.opts.speed.into();
        let arm = self.dev.arm.clone();
        let mut stops = 0u32;
        let mut relinked = false;
        loop {
            // Never command a move into a stopped controller.
            let a = arm.clone();
            match self
                .link(id, "arm state", || {
                    let a = a.clone();
                    async move { a.state().await }
                })
                .await?
            {
                Step::LinkLost(m) => return Ok(Err(Outcome::Abort(m))),
                Step::Failed(e) => return Ok(Err(Outcome::Abort(format!("arm state: {e}")))),
                Step::Ok(st) => match st.safety {
                    SafetyState::Normal | SafetyState::Reduced => {}
                    SafetyState::ProtectiveStop => {
                        stops += 1;
                        if stops > self.opts.faults.stop_recoveries.max(1) {
                            return Ok(Err(Outcome::Abort("repeated protective stops".into())));
                        }
                        if let Err(o) = self.recover_stop(id, "before move").await? {
                            return Ok(Err(o));
                        }
                        continue;
                    }
                    SafetyState::EmergencyStop | SafetyState::Fault => {
                        self.event("fault", Some(id), format!("arm in {:?}", st.safety))?;
                        return Ok(Err(Outcome::Abort(format!(
                            "arm in {:?}: needs a person",
                            st.safety
                        ))));
                    }
                },
            }
            let start = self.now();
            let target_v = target.to_vec();
            let a = arm.clone();
            let events_before = self.events.get("fault").copied().unwrap_or(0);
            let step = self
                .link(id, "move", || {
                    let a = a.clone();
                    let t = target_v.clone();
                    async move { a.move_joints(&t, speed).await }
                })
                .await?;
            relinked |= self.events.get("fault").copied().unwrap_or(0) > events_before;
            self.time.move_s += self.now() - start;
            match step {
                Step::Ok(()) => break,
                Step::LinkLost(m) => return Ok(Err(Outcome::Abort(m))),
                Step::Failed(e) => match e.kind() {
                    ErrorKind::SafetyStop => {
                        stops += 1;
                        if stops > self.opts.faults.stop_recoveries.max(1) {
                            return Ok(Err(Outcome::Abort("repeated protective stops".into())));
                        }
                        if let Err(o) = self.recover_stop(id, &e.to_string()).await? {
                            return Ok(Err(o));
                        }
                    }
                    // Refused by the safety wrappers: for good (the transfer planner only
                    // sends moves the same check passes, so this is the pose itself).
                    ErrorKind::SafetyViolation => {
                        return Ok(Err(Outcome::Unsafe(format!("unreachable: {e}"))))
                    }
                    _ => return Ok(Err(Outcome::Skipped(format!("unreachable: {e}")))),
                },
            }
        }
        if relinked {
            // The link dropped during the move: re-verify where the arm is.
            let js = match self.joints(id).await? {
                Ok(j) => j,
                Err(o) => return Ok(Err(o)),
            };
            let off =
                js.q.iter()
                    .zip(target)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
            if off > self.opts.faults.position_tol_rad {
                self.event(
                    "note",
                    Some(id),
                    format!(
                        "after link restore the arm is {:.4}° off target: moving again",
                        off.to_degrees()
                    ),
                )?;
                return Box::pin(self.move_direct(id, target)).await;
            }
            self.event("note", Some(id), "position re-verified after link restore")?;
        }
        Ok(Ok(()))
    }

    async fn marker_position(&mut self, id: u64) -> Result<Option<Point3<f64>>, AcquireError> {
        let Some(tr) = self.dev.tracker.clone() else {
            return Ok(None);
        };
        let step = self
            .link(id, "tracker frame", || {
                let tr = tr.clone();
                async move { tr.frame().await }
            })
            .await?;
        Ok(match step {
            Step::Ok(f) => match f.tool(self.opts.sample.tool.as_deref()) {
                Some(ToolStatus::Visible { pose, .. }) => {
                    Some(Point3::from(pose.0.translation.vector))
                }
                _ => None,
            },
            Step::Failed(e) if e.kind() != ErrorKind::NotVisible => {
                self.event(
                    "fault",
                    Some(id),
                    format!("tracker frame failed while settling, frame dropped: {e}"),
                )?;
                None
            }
            _ => None,
        })
    }

    /// Waits until the arm and marker are still. Returns the last joint state.
    async fn settle(&mut self, id: u64) -> Result<Result<JointState, Outcome>, AcquireError> {
        let o = self.opts.settle;
        let start = self.now();
        let mut settler = Settler::new(o, self.noise_3d_mm());
        let last = loop {
            let js = match self.joints(id).await? {
                Ok(j) => j,
                Err(o) => return Ok(Err(o)),
            };
            let marker = self.marker_position(id).await?;
            let settled = settler.push(SettleSample {
                q: js.q.clone(),
                qd: js.qd.clone(),
                marker,
            });
            if settled {
                break js;
            }
            if self.now() - start > o.timeout_s {
                self.event(
                    "note",
                    Some(id),
                    format!("not settled after {:.1} s; measuring anyway", o.timeout_s),
                )?;
                break js;
            }
            self.dev.clock.sleep(o.poll_s).await;
        };
        self.time.settle_s += self.now() - start;
        Ok(Ok(last))
    }

    /// Averages tracker frames; `Ok(None)` when the marker stayed invisible (after retries).
    async fn sample_marker(
        &mut self,
        id: u64,
    ) -> Result<Result<Option<MarkerAverage>, Outcome>, AcquireError> {
        let Some(tr) = self.dev.tracker.clone() else {
            return Ok(Ok(None));
        };
        let s = self.opts.sample.clone();
        let tries = self.opts.faults.marker_retries + 1;
        for attempt in 1..=tries {
            let start = self.now();
            let mut samples = Vec::with_capacity(s.frames);
            for _ in 0..s.frames.max(1) {
                let step = self
                    .link(id, "tracker frame", || {
                        let tr = tr.clone();
                        async move { tr.frame().await }
                    })
                    .await?;
                match step {
                    Step::Ok(f) => {
                        if let Some(ToolStatus::Visible { pose, rms_mm }) =
                            f.tool(s.tool.as_deref())
                        {
                            samples.push(MarkerSample {
                                pose: pose.0,
                                rms_mm: *rms_mm,
                            });
                        }
                    }
                    Step::Failed(e) if e.kind() == ErrorKind::NotVisible => {}
                    Step::Failed(e) => {
                        self.event(
                            "fault",
                            Some(id),
                            format!("tracker frame failed, frame dropped: {e}"),
                        )?;
                    }
                    Step::LinkLost(m) => return Ok(Err(Outcome::Abort(m))),
                }
            }
            self.time.sample_s += self.now() - start;
            if samples.len() >= s.min_frames.max(1) {
                let avg = average_markers(&samples, s.outlier_k, s.outlier_floor_mm);
                if let Some(a) = &avg {
                    self.spreads.push(a.spread_mm);
                }
                return Ok(Ok(avg));
            }
            if attempt < tries {
                self.event(
                    "retry",
                    Some(id),
                    format!(
                        "marker visible in {}/{} frames (try {attempt} of {tries})",
                        samples.len(),
                        s.frames
                    ),
                )?;
                self.dev
                    .clock
                    .sleep(self.opts.faults.marker_retry_wait_s)
                    .await;
            }
        }
        Ok(Err(Outcome::Skipped(format!(
            "marker not visible after {tries} tries"
        ))))
    }

    /// Averaged laser reading: `Some(Some(mm))`, `Some(None)` = out of range, `None` = no laser.
    async fn sample_range(
        &mut self,
        id: u64,
    ) -> Result<Result<Option<Option<f64>>, Outcome>, AcquireError> {
        let Some(laser) = self.dev.range.clone() else {
            return Ok(Ok(None));
        };
        let n = self.opts.sample.laser_readings.max(1);
        let start = self.now();
        let mut valid = Vec::with_capacity(n);
        for _ in 0..n {
            let step = self
                .link(id, "laser reading", || {
                    let l = laser.clone();
                    async move { l.read_range().await }
                })
                .await?;
            match step {
                Step::Ok(RangeReading::Distance(d)) if d.is_finite() => valid.push(d),
                Step::Ok(_) => {}
                Step::Failed(e) => self.event(
                    "fault",
                    Some(id),
                    format!("laser reading failed, reading dropped: {e}"),
                )?,
                Step::LinkLost(m) => return Ok(Err(Outcome::Abort(m))),
            }
        }
        self.time.sample_s += self.now() - start;
        let avg = average_range(&valid, n);
        if avg.is_none() {
            self.event(
                "fault",
                Some(id),
                format!("laser out of range ({}/{n} readings valid)", valid.len()),
            )?;
        }
        Ok(Ok(Some(avg)))
    }

    /// One camera image: `Ok(None)` when there is no camera or it failed with a non-link
    /// error (then a `fault` event says so and the pose is recorded without an image). Link
    /// drops are retried like the laser's; a link that stays down aborts the run (resumable).
    async fn grab_image(
        &mut self,
        id: u64,
    ) -> Result<Result<Option<Image>, Outcome>, AcquireError> {
        let Some(cam) = self.dev.camera.clone() else {
            return Ok(Ok(None));
        };
        let start = self.now();
        let step = self
            .link(id, "camera grab", || {
                let c = cam.clone();
                async move { c.grab().await }
            })
            .await?;
        self.time.sample_s += self.now() - start;
        match step {
            Step::Ok(img) => {
                let n = u64::from(img.width) * u64::from(img.height);
                if n == 0 || img.data.len() as u64 != n {
                    self.event(
                        "fault",
                        Some(id),
                        format!(
                            "camera image malformed ({}×{} with {} bytes); pose recorded without an image",
                            img.width,
                            img.height,
                            img.data.len()
                        ),
                    )?;
                    return Ok(Ok(None));
                }
                Ok(Ok(Some(img)))
            }
            Step::Failed(e) => {
                self.event(
                    "fault",
                    Some(id),
                    format!("camera grab failed: {e}; pose recorded without an image"),
                )?;
                Ok(Ok(None))
            }
            Step::LinkLost(m) => Ok(Err(Outcome::Abort(m))),
        }
    }

    /// Saves pose `id`'s image as binary PGM in [`images_dir`]; returns its path relative to
    /// the journal's directory. Durable before it returns (the record naming it comes after).
    fn save_image(&mut self, id: u64, img: &Image) -> Result<String, AcquireError> {
        let dir = self.images_dir.clone();
        let io = |file: &Path, error| {
            AcquireError::Journal(DatasetError::Io {
                file: file.to_path_buf(),
                error,
            })
        };
        if !self.images_dir_ready {
            if !dir.is_dir() {
                std::fs::create_dir_all(&dir).map_err(|e| io(&dir, e))?;
                let parent = dir.parent().unwrap_or(Path::new("."));
                sync_dir(parent).map_err(|e| io(parent, e))?;
            }
            self.images_dir_ready = true;
        }
        let name = image_file_name(id);
        let path = dir.join(&name);
        write_durably(&path, &pgm::encode(img.width, img.height, &img.data))
            .map_err(|e| io(&path, e))?;
        let dir_name = dir
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        Ok(format!("{dir_name}/{name}"))
    }

    /// The chessboard's inner corners in `img` (feature `opencv`, board configured);
    /// `None` with a `note` event when the board is not found.
    #[cfg(feature = "opencv")]
    fn corners(&mut self, id: u64, img: &Image) -> Result<Option<Vec<[f64; 2]>>, AcquireError> {
        use robocal_drivers::camera::opencv::{find_chessboard, Detector};
        let Some((cols, rows)) = self.opts.capture.board else {
            return Ok(None);
        };
        match find_chessboard(img, cols, rows, Detector::Classic) {
            Ok(Some(c)) => Ok(Some(c)),
            Ok(None) => {
                self.event(
                    "note",
                    Some(id),
                    format!("chessboard ({cols}×{rows} inner corners) not found in the image"),
                )?;
                Ok(None)
            }
            Err(e) => {
                self.event(
                    "note",
                    Some(id),
                    format!("chessboard detection failed: {e}"),
                )?;
                Ok(None)
            }
        }
    }

    /// Without feature `opencv` no corners are detected (the images are still saved).
    #[cfg(not(feature = "opencv"))]
    fn corners(&mut self, _id: u64, _img: &Image) -> Result<Option<Vec<[f64; 2]>>, AcquireError> {
        Ok(None)
    }

    async fn pose(&mut self, p: &PlannedPose) -> Result<Outcome, AcquireError> {
        let target: Vec<f64> = p.q_deg.iter().map(|d| d.to_radians()).collect();
        let q_prev = self.last_q_deg.take();
        if let Err(o) = self.move_to(p.id, &target).await? {
            return Ok(o);
        }
        self.last_q_deg = Some(p.q_deg.clone());
        if let Err(o) = self.settle(p.id).await? {
            return Ok(o);
        }
        let t = self.t();
        let marker = match self.sample_marker(p.id).await? {
            Ok(m) => m,
            Err(o) => return Ok(o),
        };
        let range = match self.sample_range(p.id).await? {
            Ok(r) => r,
            Err(o) => return Ok(o),
        };
        let image = match self.grab_image(p.id).await? {
            Ok(i) => i,
            Err(o) => return Ok(o),
        };
        // Joints and the controller's flange pose at measurement time.
        let js = match self.joints(p.id).await? {
            Ok(j) => j,
            Err(o) => return Ok(o),
        };
        self.last_q_deg = Some(deg(&js.q));
        let arm = self.dev.arm.clone();
        let flange = match self
            .link(p.id, "flange pose", || {
                let a = arm.clone();
                async move { a.flange_pose().await }
            })
            .await?
        {
            Step::Ok(f) => Some(file_pose(&f.0)),
            Step::Failed(e) => {
                tracing::warn!("pose {}: no controller flange pose: {e}", p.id);
                None
            }
            Step::LinkLost(m) => return Ok(Outcome::Abort(m)),
        };
        let mut extra = Map::new();
        if let Some(b) = p.block {
            extra.insert("block".into(), json!(b));
        }
        if let Some(l) = &p.label {
            extra.insert("label".into(), json!(l));
        }
        let marker_obs = marker.map(|m| {
            let mut me = Map::new();
            me.insert("spread_mm".into(), json!(m.spread_mm));
            if m.rejected > 0 {
                me.insert("rejected".into(), json!(m.rejected));
            }
            let fp = file_pose(&m.pose);
            MarkerObs {
                p: Some(fp.p),
                quat: Some(fp.quat),
                rms: Some(m.rms_mm),
                visible: true,
                frames: Some(m.kept as u32),
                extra: me,
            }
        });
        // The image file is durable before the record naming it is appended: a kill leaves
        // at worst an orphan image, which the resumed run overwrites.
        let (image, corners) = match &image {
            Some(img) => {
                let rel = self.save_image(p.id, img)?;
                (Some(rel), self.corners(p.id, img)?)
            }
            None => (None, None),
        };
        let rec = PoseRecord {
            id: p.id,
            t,
            point: p.point,
            branch: p.branch,
            group: p.group.clone(),
            q_cmd: Some(p.q_deg.clone()),
            q: Some(deg(&js.q)),
            q_prev,
            flange,
            marker: marker_obs,
            reference: None,
            range,
            temp_c: None,
            plane: p.plane.clone(),
            move_kind: p.move_kind.clone(),
            target: p.target.clone(),
            image,
            corners,
            tip: None,
            extra,
        };
        // Written whole and fsync'd before the next motion starts.
        self.journal.append(&Record::Pose(rec))?;
        Ok(Outcome::Recorded)
    }
}

/// Runs the plan's remaining poses and appends to `journal`.
///
/// `existing` are the records already in the journal (empty for a fresh run): recorded
/// and skipped poses are not repeated. A device fault the engine cannot handle (link down
/// through every attempt, protective stop not recoverable, emergency stop) ends the run
/// with `summary.aborted` set; it can be resumed later.
pub async fn acquire(
    dev: &Devices,
    poses: &[PlannedPose],
    journal: &mut Journal,
    existing: &[Record],
    opts: &AcquireOptions,
    progress: &mut (dyn FnMut(&Progress) + Send),
) -> Result<RunSummary, AcquireError> {
    let dof = journal.header().robot.dof().unwrap_or(0);
    let mut prev = None;
    for p in poses {
        if p.q_deg.len() != dof {
            return Err(AcquireError::Plan {
                id: p.id,
                msg: format!(
                    "{} joint targets, the robot has {dof} joints",
                    p.q_deg.len()
                ),
            });
        }
        if prev.is_some_and(|q| p.id <= q) {
            return Err(AcquireError::Plan {
                id: p.id,
                msg: "pose ids must increase".into(),
            });
        }
        prev = Some(p.id);
    }
    let done = done_pose_ids(existing);
    let mut events: BTreeMap<String, usize> = BTreeMap::new();
    let mut skipped_before = Vec::new();
    let mut recorded_before = 0usize;
    let mut t_offset: f64 = 0.0;
    for r in existing {
        match r {
            Record::Pose(p) => {
                recorded_before += 1;
                t_offset = t_offset.max(p.t);
            }
            Record::Event(e) => {
                *events.entry(e.what.clone()).or_insert(0) += 1;
                t_offset = t_offset.max(e.t);
                if e.what == "skip" {
                    if let Some(id) = e.id {
                        skipped_before.push(SkippedPose {
                            id,
                            reason: e.reason.clone().unwrap_or_default(),
                        });
                    }
                }
            }
            Record::Pivot(p) => t_offset = t_offset.max(p.t),
        }
    }
    let todo: Vec<&PlannedPose> = poses.iter().filter(|p| !done.contains(&p.id)).collect();
    let t0 = dev.clock.now();
    let images = images_dir(journal.path());
    let mut run = Run {
        dev,
        opts,
        journal,
        t0_clock: t0,
        t_offset,
        time: TimeBreakdown::default(),
        skipped: Vec::new(),
        events: BTreeMap::new(),
        spreads: Vec::new(),
        images_dir: images,
        images_dir_ready: false,
        plan_q: poses
            .iter()
            .map(|p| p.q_deg.iter().map(|d| d.to_radians()).collect())
            .collect(),
        postures: None,
        recoveries: 0,
        last_q_deg: None,
        link_recoveries_seen: [0; 3],
    };
    run.link_recoveries_seen = run.link_recoveries_now();
    if !existing.is_empty() {
        run.event(
            "resume",
            None,
            format!(
                "resuming: {} of {} planned poses already done",
                poses.len() - todo.len(),
                poses.len()
            ),
        )?;
    }
    let mut recorded_now = 0usize;
    let mut handled = 0usize;
    let mut aborted = None;
    let mut interrupted = opts.stop.requested();
    let mut stopped_at = None;
    let limit = opts.max_poses.unwrap_or(usize::MAX);
    // Pose ids recorded, and the skip history (transient skips are retried once at the end).
    let mut recorded_ids: HashSet<u64> = HashSet::new();
    let mut retry = RetryBook::default();
    for r in existing {
        match r {
            Record::Pose(p) => {
                recorded_ids.insert(p.id);
            }
            Record::Event(e) if e.what == "skip" => {
                if let Some(id) = e.id {
                    retry.note(id, &e.extra);
                }
            }
            _ => {}
        }
    }
    // The main pass over the plan, then the transient skips once more.
    let main: Vec<(&PlannedPose, bool)> = todo.iter().map(|p| (*p, false)).collect();
    let mut queue = main.into_iter().collect::<std::collections::VecDeque<_>>();
    let mut main_left = todo.len();
    let mut retries_queued = false;
    loop {
        if queue.is_empty()
            && !retries_queued
            && aborted.is_none()
            && !interrupted
            && handled < limit
        {
            retries_queued = true;
            if main_left == 0 {
                for p in poses {
                    if !recorded_ids.contains(&p.id) && retry.pending(p.id) {
                        queue.push_back((p, true));
                    }
                }
                if !queue.is_empty() {
                    run.event(
                        "note",
                        None,
                        format!(
                            "retrying {} pose(s) skipped for a transient reason",
                            queue.len()
                        ),
                    )?;
                }
            }
        }
        let Some((p, is_retry)) = queue.pop_front() else {
            break;
        };
        if interrupted || handled >= limit {
            break;
        }
        let skip = match run.pose(p).await? {
            Outcome::Recorded => {
                recorded_now += 1;
                recorded_ids.insert(p.id);
                None
            }
            Outcome::Skipped(reason) => Some((reason, true)),
            Outcome::Unsafe(reason) => Some((reason, false)),
            Outcome::Abort(reason) => {
                run.event("fault", Some(p.id), format!("run aborted: {reason}"))?;
                aborted = Some(reason);
                break;
            }
        };
        if let Some((reason, transient)) = skip {
            let mut extra = Map::new();
            if is_retry {
                extra.insert("retried".into(), json!(true));
            } else if transient {
                extra.insert("transient".into(), json!(true));
            }
            run.event_with("skip", Some(p.id), reason.clone(), extra.clone())?;
            retry.note(p.id, &extra);
            run.skipped.push(SkippedPose { id: p.id, reason });
        }
        handled += 1;
        if !is_retry {
            main_left -= 1;
        }
        let elapsed = run.now() - t0;
        let pph = if elapsed > 0.0 {
            handled as f64 * 3600.0 / elapsed
        } else {
            0.0
        };
        let left = main_left + queue.len();
        progress(&Progress {
            done: poses.len() - todo.len() + (todo.len() - main_left),
            total: poses.len(),
            recorded: recorded_before + recorded_now,
            skipped: skipped_before.len() + run.skipped.len(),
            id: p.id,
            ok: run.skipped.last().is_none_or(|s| s.id != p.id),
            elapsed_s: elapsed,
            poses_per_hour: pph,
            eta_s: (pph > 0.0).then(|| left as f64 * 3600.0 / pph),
        });
        // Ctrl-C: the pose's record (or skip event) is durable; stop here.
        if opts.stop.requested() {
            interrupted = true;
            stopped_at = Some(p.id);
            break;
        }
    }
    let elapsed = run.now() - t0;
    let mut time = run.time;
    time.overhead_s = (elapsed - time.move_s - time.settle_s - time.sample_s).max(0.0);
    for (k, n) in &run.events {
        *events.entry(k.clone()).or_insert(0) += n;
    }
    // Skipped for good: not recorded (a retried pose may have been recorded after all); the
    // latest reason per id.
    let mut last_reason: BTreeMap<u64, String> = BTreeMap::new();
    for s in skipped_before.into_iter().chain(run.skipped) {
        last_reason.insert(s.id, s.reason);
    }
    let skipped: Vec<SkippedPose> = last_reason
        .into_iter()
        .filter(|(id, _)| !recorded_ids.contains(id))
        .map(|(id, reason)| SkippedPose { id, reason })
        .collect();
    let pending_retries = poses
        .iter()
        .filter(|p| !recorded_ids.contains(&p.id) && retry.pending(p.id))
        .count();
    let remaining = main_left + pending_retries;
    Ok(RunSummary {
        planned: poses.len(),
        recorded: recorded_before + recorded_now,
        recorded_now,
        already_done: poses.len() - todo.len(),
        skipped,
        remaining,
        events,
        time,
        poses_per_hour: if elapsed > 0.0 {
            handled as f64 * 3600.0 / elapsed
        } else {
            0.0
        },
        aborted,
        stopped_at,
        interrupted,
    })
}

/// The skip history of a run: which skipped poses are still to be retried once at the end.
#[derive(Default)]
struct RetryBook {
    /// Skipped for a transient reason, not yet retried.
    transient: HashSet<u64>,
    /// Retried (and skipped again), or skipped for good.
    settled: HashSet<u64>,
}

impl RetryBook {
    /// Notes one `skip` event of pose `id` with the event's extra fields.
    fn note(&mut self, id: u64, extra: &Map<String, Value>) {
        let flag = |k: &str| extra.get(k).and_then(Value::as_bool).unwrap_or(false);
        if flag("retried") {
            self.settled.insert(id);
        } else if flag("transient") {
            self.transient.insert(id);
        } else {
            // A skip event without flags (final, or written before retries existed).
            self.settled.insert(id);
        }
    }

    /// Whether pose `id` still has its retry coming.
    fn pending(&self, id: u64) -> bool {
        self.transient.contains(&id) && !self.settled.contains(&id)
    }
}

/// A JSON value for a progress line (`--json`).
pub fn progress_json(p: &Progress) -> Value {
    serde_json::to_value(p).unwrap_or(Value::Null)
}
