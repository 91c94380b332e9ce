//! A run: acquire a dataset by driving the cell through a plan, into a run directory.
//!
//! `RUN_DIR` receives `dataset.jsonl` (the journal, `robocal-dataset/1`), `plan.json` and
//! the scenario / device file (copies), `run.json` (how to resume) and `summary.json`; runs
//! that record camera images also `dataset.images/pose-<id>.pgm` (named by the records).
//!
//! Camera: a cell with a camera (scenario `[[camera]]`, device-file role `camera`) records one
//! image per pose when the plan is a camera plan (a `shell` spec: camera viewpoints), or
//! always with [`CameraUse::Always`]; never with [`CameraUse::Never`]. A board (inner corners)
//! sets the chessboard to detect (feature `opencv`); sim runs default to the scenario's board.
//!
//! Callers: `robocal run` (the command line) and the session's acquisition stages.
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context as _};
use robocal_drivers::safety::guard;
use serde::{Deserialize, Serialize};
use serde_json::json;

use super::safety::{confirm_live, safety_limits, LiveConsent};
use super::source::{source, CellInfo, OpenOptions, StatedCamera};
use crate::acquire::{
    self, AcquireOptions, CaptureOptions, FaultOptions, MoveSpeedOpt, PlannedPose, Progress,
    RunSummary, SampleOptions, SettleOptions,
};
use crate::dataset::{Header, Journal, DATASET_FORMAT};
use crate::plan::PlanFile;

/// Where a run starts: a new run directory, or the one to continue.
#[derive(Debug, Clone)]
pub enum RunStart {
    /// A new run of `plan` into `out` (created), on the simulated cell of the scenario `sim`
    /// or the hardware of the device file `devices` (exactly one of them).
    New {
        /// The plan (`robocal-plan/1`).
        plan: PathBuf,
        /// Dry run against the simulated cell of this scenario.
        sim: Option<PathBuf>,
        /// Real hardware described by this device file (needs `live`).
        devices: Option<PathBuf>,
        /// The run directory to create.
        out: PathBuf,
    },
    /// Continue the run in this directory where it stopped.
    Resume(PathBuf),
}

/// Whether a run records camera images.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum CameraUse {
    /// Only for camera-viewpoint plans (a `shell` spec), when the cell has a camera.
    #[default]
    Auto,
    /// At every pose, whatever the plan (the cell must have a camera).
    Always,
    /// Never, also for camera-viewpoint plans.
    Never,
}

/// Everything a run needs (what `robocal run` and a session's acquisition ask for).
#[derive(Debug, Clone)]
pub struct RunRequest {
    /// New run or resume.
    pub start: RunStart,
    /// Real motion allowed on this invocation (`--live`).
    pub live: bool,
    /// Consent given without asking (`--yes`).
    pub yes: bool,
    /// Simulated time jumps instead of passing on the wall clock (dry runs only).
    pub virtual_clock: bool,
    /// Joint speed cap (deg/s).
    pub speed_deg_s: f64,
    /// Joint acceleration cap (deg/s²).
    pub accel_deg_s2: f64,
    /// Tracker frames averaged per pose.
    pub frames: usize,
    /// Stop after this many poses (resume later).
    pub max_poses: Option<usize>,
    /// Stop early when the skipped poses pass this fraction (0–1).
    pub max_skipped_fraction: Option<f64>,
    /// Dry run with in-process simulated devices instead of the wire protocols.
    pub in_process: bool,
    /// Camera images (new runs only).
    pub camera: CameraUse,
    /// Chessboard inner corners to detect in each image (new runs only).
    pub board: Option<(u32, u32)>,
}

/// Where an acquisition's progress goes (the command line prints it; tests may ignore it).
pub trait RunProgress: Send {
    /// The acquisition starts: `total` poses in the plan, `done` of them already recorded;
    /// `simulated`: the devices run on a simulated clock.
    fn start(&mut self, total: usize, done: usize, simulated: bool);
    /// One pose handled.
    fn pose(&mut self, p: &Progress);
    /// The acquisition ended.
    fn finish(&mut self);
}

/// No progress output.
impl RunProgress for () {
    fn start(&mut self, _: usize, _: usize, _: bool) {}
    fn pose(&mut self, _: &Progress) {}
    fn finish(&mut self) {}
}

/// What one invocation of a run did: its directory and summary. [`RunOutcome::finished`]
/// turns an interrupted or aborted run into its error.
#[derive(Debug, Clone)]
pub struct RunOutcome {
    /// The run directory.
    pub dir: PathBuf,
    /// The summary of this invocation (also in `RUN_DIR/summary.json`).
    pub summary: RunSummary,
}

impl RunOutcome {
    /// The dataset journal of the run.
    pub fn dataset(&self) -> PathBuf {
        self.dir.join(DATASET)
    }

    /// The summary of a run that went through; [`Interrupted`] (Ctrl-C after a durable pose)
    /// or an error naming the reason when it stopped.
    pub fn finished(self) -> anyhow::Result<RunSummary> {
        let summary = self.summary;
        if summary.interrupted {
            let at = summary.stopped_at.map_or_else(
                || "before the first pose".to_string(),
                |id| format!("at pose {id}"),
            );
            return Err(Interrupted(format!(
                "stopped {at}; continue with `{}`",
                crate::fsio::resume_command(&self.dir)
            ))
            .into());
        }
        if let Some(reason) = &summary.aborted {
            bail!(
                "run aborted: {reason} (continue with `{}`)",
                crate::fsio::resume_command(&self.dir)
            );
        }
        Ok(summary)
    }
}

/// `--board COLSxROWS`: inner corners, each at least 2.
pub fn parse_board(s: &str) -> Result<(u32, u32), String> {
    let bad = || {
        format!(
            "{s:?} is not COLSxROWS: give the chessboard's inner corners, e.g. 8x5 for a \
             board of 9×6 squares"
        )
    };
    let (c, r) = s.trim().split_once(['x', 'X', '×']).ok_or_else(bad)?;
    let c: u32 = c.trim().parse().map_err(|_| bad())?;
    let r: u32 = r.trim().parse().map_err(|_| bad())?;
    if c < 2 || r < 2 || c > 1000 || r > 1000 {
        return Err(format!(
            "{s:?}: a chessboard needs 2 to 1000 inner corners each way (a board of 9×6 \
             squares has 8x5 inner corners)"
        ));
    }
    Ok((c, r))
}

/// `RUN_DIR/run.json`: everything `--resume` needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Always `robocal-run/1`.
    pub format: String,
    /// `sim` or `live`.
    pub mode: String,
    /// The plan copy, relative to the run directory.
    pub plan: String,
    /// The scenario / device file copy, relative to the run directory.
    pub config: String,
    /// Virtual clock (sim only).
    pub virtual_clock: bool,
    /// Speed caps.
    pub speed: MoveSpeedOpt,
    /// Settling detection.
    pub settle: SettleOptions,
    /// Sampling.
    pub sample: SampleOptions,
    /// Fault handling.
    pub faults: FaultOptions,
    /// Record a camera image at every pose (runs made before cameras: `false`).
    #[serde(default)]
    pub camera: bool,
    /// What is done with the images (chessboard detection).
    #[serde(default)]
    pub capture: CaptureOptions,
}

use crate::schema::RUN_FORMAT;
const DATASET: &str = "dataset.jsonl";

// ----------------------------------------------------------------- simulator wiring

// ----------------------------------------------------------------- run directory

use crate::fsio::write_atomic_ctx as write_atomic;

fn header_for(plan: &PlanFile, info: &CellInfo) -> Header {
    let mut robot = plan.robot.clone();
    if robot.serial.is_none() {
        robot.serial = info.serial.clone();
    }
    Header {
        format: DATASET_FORMAT.to_string(),
        created: Some(acquire::utc_now_iso()),
        robot,
        tool: Some(json!({"p": plan.tool.p, "quat": plan.tool.quat})),
        tracker: info.tracker_kind.as_ref().map(|k| json!({ "kind": k })),
        range_sensor: info.range_kind.as_ref().map(|k| json!({ "kind": k })),
        plan: Some(json!({ "name": plan.name })),
        notes: None,
        extra: serde_json::Map::new(),
    }
}

/// The dataset header's `camera` and `target` blocks: as the cell file states them (`board`
/// overrides the inner corners), the image size from one frame grabbed now when only an image
/// tells it (a real camera; the grab also proves the camera answers before anything moves).
fn camera_header(
    header: &mut Header,
    stated: &StatedCamera,
    cam: &dyn robocal_drivers::traits::ImageSource,
    rt: &tokio::runtime::Runtime,
    board: Option<(u32, u32)>,
    config: &Path,
) -> anyhow::Result<()> {
    let mut camera = stated.header.clone();
    if camera.width == 0 || camera.height == 0 {
        let img = rt.block_on(cam.grab()).with_context(|| {
            format!(
                "grabbing a first image from camera {:?} ({})",
                stated.name,
                config.display()
            )
        })?;
        anyhow::ensure!(
            img.width > 0 && img.height > 0,
            "camera {:?} returned an empty image",
            stated.name
        );
        (camera.width, camera.height) = (img.width, img.height);
    }
    let target = stated.target.clone().map(|mut t| {
        if let Some((c, r)) = board {
            (t.cols, t.rows) = (c, r);
        }
        t
    });
    header.set_camera(&camera, target.as_ref());
    Ok(())
}

fn options(cfg: &RunConfig, max_poses: Option<usize>) -> AcquireOptions {
    AcquireOptions {
        speed: cfg.speed,
        settle: cfg.settle,
        sample: cfg.sample.clone(),
        faults: cfg.faults,
        max_poses,
        capture: cfg.capture,
        ..AcquireOptions::default()
    }
}

/// Whether the plan is a camera plan: its spec has camera viewpoints (`shell`).
fn is_camera_plan(plan: &PlanFile) -> bool {
    serde_json::from_value::<crate::plan::PlanSpec>(plan.spec.clone())
        .is_ok_and(|sp| sp.shell.is_some())
}

/// Runs (or resumes) the acquisition in `dir` with the run configuration `cfg`.
fn acquire_in(
    dir: &Path,
    cfg: &RunConfig,
    req: &RunRequest,
    consent: Option<&LiveConsent>,
    progress: &mut dyn RunProgress,
) -> anyhow::Result<RunSummary> {
    let plan_path = dir.join(&cfg.plan);
    let plan = PlanFile::read(&plan_path).with_context(|| format!("{}", plan_path.display()))?;
    let config_path = dir.join(&cfg.config);
    super::checks::check_run_inputs(
        &plan,
        &plan_path,
        &cfg.mode,
        &config_path,
        cfg.speed.max_vel.to_degrees(),
        cfg.speed.max_acc.to_degrees(),
        cfg.sample.frames,
    )?;
    // One runtime for the whole run: the wire clients (and, in dry runs, the simulators'
    // servers) live on it.
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let cell = source(
        &cfg.mode,
        &config_path,
        OpenOptions {
            virtual_clock: cfg.virtual_clock,
            in_process: req.in_process,
            dof: plan.poses.first().map_or(6, |p| p.q_deg.len()),
            camera: cfg.camera,
        },
    )
    .with_context(|| format!("{}", dir.join("run.json").display()))?;
    let stated = cell.stated(None)?;
    let opened = cell.open(&rt, consent)?;
    let (mut devices, info) = (opened.devices, opened.info);
    if !cfg.camera {
        devices.camera = None;
    } else if devices.camera.is_none() {
        bail!(
            "{}: the run records camera images but {} has no camera",
            dir.join("run.json").display(),
            config_path.display()
        );
    }
    let (mut limits, geometry) = safety_limits(&plan, cfg.speed)?;
    // The cell's own joint limits (a device file's `[safety]`) narrow the robot's.
    crate::acquire::device_safety::narrow_joint_limits(
        &mut limits,
        stated.arm.robot.safety.as_ref(),
    );
    // The transfers are planned against the very limits and geometry the guard checks.
    let transfer = acquire::TransferSafety {
        limits: Arc::new(limits.clone()),
        geometry: geometry.clone(),
    };
    devices.arm = guard(devices.arm.clone(), limits, geometry);
    let mut header = header_for(&plan, &info);
    if let (Some(cam), Some(st)) = (devices.camera.clone(), &stated.camera) {
        camera_header(&mut header, st, &*cam, &rt, cfg.capture.board, &config_path)?;
    }
    let journal_path = dir.join(DATASET);
    let (mut journal, existing, warnings) = Journal::open_or_create(&journal_path, &header)?;
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    let poses: Vec<PlannedPose> = plan.poses.iter().map(PlannedPose::from).collect();
    let done = acquire::done_pose_ids(&existing).len();
    progress.start(poses.len(), done, cfg.virtual_clock);
    let mut opts = options(cfg, req.max_poses);
    opts.transfer = Some(transfer);
    // Ctrl-C: finish the current pose (its record durable), then stop; a second Ctrl-C
    // ends the process at once (the journal stays readable: records are whole lines).
    let stop = opts.stop.clone();
    let signals = rt.spawn(async move {
        loop {
            if tokio::signal::ctrl_c().await.is_err() {
                return;
            }
            if stop.requested() {
                eprintln!("second interrupt: stopping now");
                std::process::exit(130);
            }
            eprintln!("interrupt: stopping after the current pose (Ctrl-C again to stop now)");
            stop.request();
        }
    });
    // Early stop: too many poses skipped for the verdict to pass (an hour of acquisition
    // that cannot pass is not started over at the end).
    let skip_limit = req.max_skipped_fraction;
    let early_stop = opts.stop.clone();
    let mut early: Option<String> = None;
    let summary = rt.block_on(acquire::acquire(
        &devices,
        &poses,
        &mut journal,
        &existing,
        &opts,
        &mut |p| {
            progress.pose(p);
            if let (Some(lim), None) = (skip_limit, &early) {
                if let Some(why) = skipped_too_many(p, lim) {
                    early = Some(why);
                    early_stop.request();
                }
            }
        },
    ))?;
    progress.finish();
    signals.abort();
    if let Some(stop) = opened.stop {
        stop();
    }
    write_atomic(
        dir.join("summary.json"),
        serde_json::to_string_pretty(&crate::schema::RunSummaryFile::from(summary.clone()))?
            .as_bytes(),
    )?;
    if let Some(why) = early {
        let mut reasons = std::collections::BTreeMap::<&str, usize>::new();
        for k in &summary.skipped {
            *reasons.entry(k.reason.as_str()).or_default() += 1;
        }
        let top = reasons
            .iter()
            .max_by_key(|(_, n)| **n)
            .map(|(r, n)| format!("; most often: {r:?} ({n})"))
            .unwrap_or_default();
        bail!(
            "stopped early: {why}{top}. The tracker does not see the marker where the plan puts \
             it: check where the tracker stands (`tracker_in_base`) and the marker \
             (`marker_on_flange`) in the device file, then start a new session (its plan is \
             fitted to them; `robocal session --survey` locates the tracker with a few probe \
             poses first); `{}` continues this one as it is",
            crate::fsio::resume_command(dir)
        );
    }
    Ok(summary)
}

/// Whether the skipped poses already pass `limit` (a fraction): of the whole plan (the run
/// cannot end below it), or of the poses handled once a quarter of the plan (at least 10
/// poses) is.
fn skipped_too_many(p: &Progress, limit: f64) -> Option<String> {
    let pct = |a: usize, b: usize| 100.0 * a as f64 / b.max(1) as f64;
    if p.total > 0 && p.skipped as f64 > limit * p.total as f64 {
        return Some(format!(
            "{} of the plan's {} poses skipped ({:.0} %), more than the {:.0} % allowed",
            p.skipped,
            p.total,
            pct(p.skipped, p.total),
            100.0 * limit
        ));
    }
    // A few early skips are not a trend: a quarter of the plan (at least 10 poses) handled
    // and at least 3 skipped.
    let enough = p.done >= (p.total / 4).max(10) && p.skipped >= 3;
    if enough && p.done < p.total && p.skipped as f64 > limit * p.done as f64 {
        return Some(format!(
            "{} of the first {} poses skipped ({:.0} %), more than the {:.0} % allowed",
            p.skipped,
            p.done,
            pct(p.skipped, p.done),
            100.0 * limit
        ));
    }
    None
}

fn new_run(
    args: &RunRequest,
    plan_path: &Path,
    sim: Option<&PathBuf>,
    devices: Option<&PathBuf>,
    dir: &Path,
) -> anyhow::Result<Started> {
    if args.live && devices.is_none() {
        bail!("--live drives the hardware of --devices DEVICES.toml: give the device file");
    }
    let (mode, config_src) = match (sim, devices) {
        (Some(s), None) => ("sim", s),
        (None, Some(d)) => {
            if !args.live {
                bail!("nothing moves without --live: add --live to drive {}, or use --sim SCENARIO.toml for a dry run", d.display());
            }
            ("live", d)
        }
        _ => bail!("give --sim SCENARIO.toml (dry run) or --devices DEVICES.toml --live"),
    };
    if args.virtual_clock && mode != "sim" {
        bail!("--virtual-clock is for --sim dry runs only");
    }
    // Check the plan before creating anything.
    let plan = PlanFile::read(plan_path).with_context(|| format!("{}", plan_path.display()))?;
    super::checks::check_run_inputs(
        &plan,
        plan_path,
        mode,
        config_src,
        args.speed_deg_s,
        args.accel_deg_s2,
        args.frames,
    )?;
    // An existing directory may be in use by another run: say so (with its PID) first.
    let early_lock = if dir.is_dir() {
        Some(crate::fsio::DirLock::acquire(dir)?)
    } else {
        None
    };
    if dir.join(DATASET).exists() {
        bail!(
            "{} already holds a dataset: continue it with `{}`",
            dir.display(),
            crate::fsio::resume_command(dir)
        );
    }
    let stated_camera = source(mode, config_src, OpenOptions::default())?
        .stated(None)
        .with_context(|| format!("reading {}", config_src.display()))?
        .camera;
    let cam_name = stated_camera.as_ref().map(|c| c.name.clone());
    let scenario_board = stated_camera.and_then(|c| c.detect);
    let camera = if args.camera == CameraUse::Never {
        false
    } else if args.camera == CameraUse::Always {
        if cam_name.is_none() {
            bail!(
                "--camera: {} has no camera (add a [[camera]] to the scenario, or a device with \
                 role = \"camera\" to the device file)",
                config_src.display()
            );
        }
        true
    } else {
        let camera_plan = is_camera_plan(&plan);
        if let (Some(c), false) = (&cam_name, camera_plan) {
            eprintln!(
                "note: camera {c:?} not used: plan {:?} is not a camera-viewpoint plan (add \
                 --camera to record images anyway)",
                plan.name
            );
        }
        cam_name.is_some() && camera_plan
    };
    let board = args.board.or(scenario_board.filter(|_| camera));
    if args.board.is_some() && !camera {
        bail!(
            "--board: this run records no camera images (the plan is not a camera plan or the \
             cell has no camera); add --camera"
        );
    }
    if camera && board.is_some() && !cfg!(feature = "opencv") {
        eprintln!(
            "note: images are saved without `corners`; `robocal calibrate camera` detects the \
             board in them (pure-Rust detector; OpenCV's with `--features opencv`)"
        );
    }
    // The device file checked as `devices --probe` checks it, before consent.
    let checked = if mode == "live" {
        let c = crate::acquire::device_check::check_file(config_src)?;
        c.require_valid()?;
        Some(c)
    } else {
        None
    };
    let consent = if mode == "live" {
        Some(confirm_live(
            args.live,
            args.yes,
            &format!(
                "will move the arm through {} poses of plan {:?} at ≤ {} °/s",
                plan.poses.len(),
                plan.name,
                args.speed_deg_s
            ),
        )?)
    } else {
        None
    };
    crate::fsio::create_dir_durable(dir).with_context(|| format!("creating {}", dir.display()))?;
    // Exclusive for the whole run; a second process on this directory stops here.
    let lock = match early_lock {
        Some(l) => l,
        None => crate::fsio::DirLock::acquire(dir)?,
    };
    if dir.join(DATASET).exists() {
        bail!(
            "{} already holds a dataset: continue it with `{}`",
            dir.display(),
            crate::fsio::resume_command(dir)
        );
    }
    let config_name = if mode == "sim" {
        "scenario.toml"
    } else {
        "devices.toml"
    };
    let copy = |src: &Path, name: &str| -> anyhow::Result<()> {
        let bytes = crate::fsio::read(src).with_context(|| format!("reading {}", src.display()))?;
        write_atomic(dir.join(name), &bytes)
    };
    copy(plan_path, "plan.json")?;
    match &checked {
        // The copy names the original's tool files by absolute path (they are resolved
        // against the original device file's folder, not the run directory).
        Some(c) => write_atomic(
            dir.join(config_name),
            crate::acquire::device_check::resolved_toml(&c.file, &c.base)?.as_bytes(),
        )?,
        None => copy(config_src, config_name)?,
    }
    let sample = SampleOptions {
        frames: args.frames.max(1),
        min_frames: (args.frames / 3).max(1),
        ..SampleOptions::default()
    };
    let cfg = RunConfig {
        format: RUN_FORMAT.into(),
        mode: mode.into(),
        plan: "plan.json".into(),
        config: config_name.into(),
        virtual_clock: args.virtual_clock,
        speed: MoveSpeedOpt {
            max_vel: args.speed_deg_s.to_radians(),
            max_acc: args.accel_deg_s2.to_radians(),
        },
        settle: SettleOptions::default(),
        sample,
        faults: FaultOptions::default(),
        camera,
        capture: CaptureOptions { board },
    };
    // run.json last: a directory with run.json is complete enough to resume.
    write_atomic(
        dir.join("run.json"),
        serde_json::to_string_pretty(&cfg)?.as_bytes(),
    )?;
    Ok(Started {
        dir: dir.to_path_buf(),
        cfg,
        consent,
        _lock: lock,
    })
}

fn load_run(dir: &Path) -> anyhow::Result<RunConfig> {
    let p = dir.join("run.json");
    let text = crate::fsio::read_to_string(&p)
        .with_context(|| format!("{} is not a run directory (no run.json)", dir.display()))?;
    let cfg: RunConfig = serde_json::from_str(&text).with_context(|| format!("{}", p.display()))?;
    if cfg.format != RUN_FORMAT {
        bail!(
            "{}: format {:?} is not {RUN_FORMAT}",
            p.display(),
            cfg.format
        );
    }
    Ok(cfg)
}

/// A run ready to acquire: its directory (locked for as long as this lives), configuration
/// and, for a live run, the consent to move.
struct Started {
    dir: PathBuf,
    cfg: RunConfig,
    consent: Option<LiveConsent>,
    _lock: crate::fsio::DirLock,
}

/// `--resume DIR`: lock the directory, read its run.json and, for a live run, ask for the
/// same consent as a fresh live run — all before any device is opened.
fn resume_run(args: &RunRequest, dir: &Path) -> anyhow::Result<Started> {
    if !dir.join("run.json").is_file() {
        bail!("{} is not a run directory (no run.json)", dir.display());
    }
    let lock = crate::fsio::DirLock::acquire(dir)?;
    let cfg = load_run(dir)?;
    let consent = match cfg.mode.as_str() {
        "live" => {
            crate::acquire::device_check::check_file(&dir.join(&cfg.config))?.require_valid()?;
            let plan_path = dir.join(&cfg.plan);
            let plan =
                PlanFile::read(&plan_path).with_context(|| format!("{}", plan_path.display()))?;
            let journal = dir.join(DATASET);
            let done = crate::dataset::read_dataset(&journal)
                .map(|l| acquire::done_pose_ids(&l.dataset.records).len())
                .unwrap_or(0);
            let left = plan.poses.len().saturating_sub(done);
            Some(confirm_live(
                args.live,
                args.yes,
                &format!(
                    "resuming live run {}: will move the arm through the {left} remaining poses of \
                     plan {:?} at ≤ {:.0} °/s",
                    dir.display(),
                    plan.name,
                    cfg.speed.max_vel.to_degrees()
                ),
            )?)
        }
        _ => {
            if args.live {
                bail!(
                    "--live: {} is a dry run ({}); resume it without --live",
                    dir.display(),
                    cfg.mode
                );
            }
            None
        }
    };
    Ok(Started {
        dir: dir.to_path_buf(),
        cfg,
        consent,
        _lock: lock,
    })
}

/// A run stopped on Ctrl-C after the current pose's record was durable (exit 130).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Interrupted(pub String);

/// Start (or resume) the run `req` and acquire until the plan is done or the run stops;
/// progress goes to `progress`. The run directory is locked for the call. An interrupted or
/// aborted run is an `Ok` outcome here ([`RunOutcome::finished`] makes it the error), so the
/// caller can show its summary first.
pub fn run(req: &RunRequest, progress: &mut dyn RunProgress) -> anyhow::Result<RunOutcome> {
    if let Some(f) = req.max_skipped_fraction {
        anyhow::ensure!(
            f.is_finite() && (0.0..=1.0).contains(&f),
            "--max-skipped-fraction {f}: a fraction from 0 to 1 (0.1 = 10 % of the poses)"
        );
    }
    let started = match &req.start {
        RunStart::Resume(dir) => resume_run(req, dir)?,
        RunStart::New {
            plan,
            sim,
            devices,
            out,
        } => new_run(req, plan, sim.as_ref(), devices.as_ref(), out)?,
    };
    let summary = acquire_in(
        &started.dir,
        &started.cfg,
        req,
        started.consent.as_ref(),
        progress,
    )?;
    Ok(RunOutcome {
        dir: started.dir.clone(),
        summary,
    })
}
