//! `robocal run`: acquire a dataset by driving the cell through a plan.
//!
//! ```text
//! robocal run --plan PLAN.json --sim SCENARIO.toml --out RUN_DIR [--virtual-clock]   # dry run
//! robocal run --plan PLAN.json --devices DEVICES.toml --live [--yes] --out RUN_DIR     # hardware
//! robocal run --resume RUN_DIR                                                         # continue
//! ```
//! `RUN_DIR` receives `dataset.jsonl` (the journal, `robocal-dataset/1`), `plan.json` and
//! the scenario / device file (copies), `run.json` (how to resume) and `summary.json`; runs
//! that record camera images also `dataset.images/pose-<id>.pgm` (named by the records).
//!
//! Camera: a cell with a camera (scenario `[[camera]]`, device-file role `camera`) records one
//! image per pose when the plan is a camera plan (a `shell` spec: camera viewpoints), or
//! always with `--camera`; never with `--no-camera`. `--board COLSxROWS` (inner corners)
//! sets the chessboard to detect (feature `opencv`); sim runs default to the scenario's board.
//!
//! This is the only place where the simulators are wired in: `--sim` builds the
//! `robocal_mocks` world in-process and adapts it to the device traits; the engine
//! (`crate::acquire`) only sees the traits.
use std::io::IsTerminal as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context as _};
use robocal_drivers::safety::{guard, ArmGeometry, SafetyLimits};
use robocal_drivers::{Arm, ImageSource, MarkerTracker, RangeSensor};
use robocal_mocks::scenario::ClockMode;
use robocal_mocks::sim::SimDevices;
use robocal_mocks::{Scenario, WorldHandle};
use serde::{Deserialize, Serialize};
use serde_json::json;

use crate::acquire::{
    self, AcquireOptions, CaptureOptions, Devices, FaultOptions, MoveSpeedOpt, PlannedPose,
    Progress, RunSummary, SampleOptions, SettleOptions,
};
use crate::dataset::{Header, Journal, DATASET_FORMAT};
use crate::model::KinematicModel;
use crate::plan::PlanFile;

/// Arguments of `robocal run`.
#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("live_target").args(["devices", "resume"])))]
pub struct Args {
    /// The plan (`robocal-plan/1`, written by `robocal plan --out`).
    #[arg(long, value_name = "PLAN.json", required_unless_present = "resume")]
    pub plan: Option<PathBuf>,
    /// Dry run against the simulated cell of this scenario: its devices serve the real
    /// protocols on loopback / ptys and the real drivers connect to them.
    #[arg(long, value_name = "SCENARIO.toml", conflicts_with_all = ["devices", "live"])]
    pub sim: Option<PathBuf>,
    /// Real hardware described by this device file (needs --live).
    #[arg(long, value_name = "DEVICES.toml")]
    pub devices: Option<PathBuf>,
    /// Allow real motion. Nothing moves on hardware without it: a fresh live run needs it
    /// with `--devices`, and so does `--resume` of a live run.
    #[arg(long, requires = "live_target")]
    pub live: bool,
    /// Do not ask for confirmation before moving real hardware.
    #[arg(long)]
    pub yes: bool,
    /// The run directory to create.
    #[arg(long, value_name = "RUN_DIR", required_unless_present = "resume")]
    pub out: Option<PathBuf>,
    /// Continue the run in this directory where it stopped.
    #[arg(long, value_name = "RUN_DIR", conflicts_with_all = ["plan", "sim", "devices", "out"])]
    pub resume: Option<PathBuf>,
    /// Simulated time jumps instead of passing on the wall clock (dry runs only).
    #[arg(long)]
    pub virtual_clock: bool,
    /// Joint speed cap (deg/s).
    #[arg(long, default_value_t = 60.0)]
    pub speed_deg_s: f64,
    /// Joint acceleration cap (deg/s²).
    #[arg(long, default_value_t = 120.0)]
    pub accel_deg_s2: f64,
    /// Tracker frames averaged per pose.
    #[arg(long, default_value_t = 30)]
    pub frames: usize,
    /// Stop after this many poses (resume later with --resume).
    #[arg(long)]
    pub max_poses: Option<usize>,
    /// Stop early when the skipped poses pass this fraction (0–1) of the poses handled
    /// (from a quarter of the plan on, at least 10), or of the whole plan: the tracker does not see the marker where
    /// the plan puts it. `robocal session` passes its accept spec's `skipped_fraction_max`.
    #[arg(long, value_name = "F")]
    pub max_skipped_fraction: Option<f64>,
    /// Progress as JSON lines on stdout instead of a progress bar.
    #[arg(long)]
    pub json: bool,
    /// Dry run with in-process simulated devices instead of the wire protocols (faster; does
    /// not exercise the drivers).
    #[arg(long)]
    pub in_process: bool,
    /// Record a camera image at every pose even when the plan is not a camera plan. By
    /// default the cell's camera (scenario `[[camera]]`, device-file role `camera`) is used
    /// only for camera-viewpoint plans (a `shell` spec, e.g. plans/seed004-shell.toml).
    /// Images go to RUN_DIR/dataset.images/pose-<id>.pgm.
    #[arg(long, conflicts_with_all = ["no_camera", "resume"])]
    pub camera: bool,
    /// Never use the camera, also for camera-viewpoint plans.
    #[arg(long, conflicts_with = "resume")]
    pub no_camera: bool,
    /// Chessboard to detect in each image, as inner corners COLSxROWS (a board of 9×6
    /// squares has 8x5 inner corners); fills the records' `corners` (needs a build with
    /// `--features opencv`). Sim runs default to the scenario's chessboard.
    #[arg(long, value_name = "COLSxROWS", value_parser = parse_board, conflicts_with_all = ["no_camera", "resume"])]
    pub board: Option<(u32, u32)>,
    /// The run's summary goes to stderr (a session's stdout starts with its verdict).
    #[arg(skip)]
    pub summary_to_stderr: bool,
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

const RUN_FORMAT: &str = "robocal-run/1";
const DATASET: &str = "dataset.jsonl";

// ----------------------------------------------------------------- simulator wiring

/// What a cell tells the dataset header besides the plan.
#[derive(Debug, Clone, Default)]
pub struct CellInfo {
    /// Arm serial number.
    pub serial: Option<String>,
    /// Tracker kind (`ndi-optotrak-certus`, ...).
    pub tracker_kind: Option<String>,
    /// Range sensor kind (`keyence-il600`).
    pub range_kind: Option<String>,
}

/// The in-process simulated devices of a world (`robocal_mocks::sim`): its first arm,
/// tracker, laser and camera, and its clock. The arm is NOT yet wrapped in the safety
/// decorators. (`robocal run` drops the camera when the run does not record images.)
pub fn sim_cell(world: &WorldHandle) -> anyhow::Result<(Devices, CellInfo)> {
    let scenario = world.scenario();
    let sim = SimDevices::of(world);
    let Some((_, arm)) = sim.arms.into_iter().next() else {
        bail!("scenario {:?} has no arm", scenario.name);
    };
    let tracker = sim
        .trackers
        .into_iter()
        .next()
        .map(|(_, t)| Arc::new(t) as Arc<dyn MarkerTracker>);
    let range = sim
        .lasers
        .into_iter()
        .next()
        .map(|(_, l)| Arc::new(l) as Arc<dyn RangeSensor>);
    let camera = sim
        .cameras
        .into_iter()
        .next()
        .map(|(_, c)| Arc::new(c) as Arc<dyn ImageSource>);
    let info = CellInfo {
        serial: world.arm_identity(0).map(|(_, s)| s),
        tracker_kind: scenario
            .trackers
            .first()
            .map(|t| t.kind.as_str().to_string()),
        range_kind: scenario.lasers.first().map(|l| l.kind.clone()),
    };
    let arm: Arc<dyn Arm> = Arc::new(arm);
    Ok((
        Devices {
            arm,
            tracker,
            range,
            clock: world.clock(),
            camera,
        },
        info,
    ))
}

fn sim_world(scenario_path: &Path, virtual_clock: bool) -> anyhow::Result<WorldHandle> {
    let mut scenario = Scenario::load(scenario_path)?;
    scenario.clock = if virtual_clock {
        ClockMode::Virtual
    } else {
        ClockMode::Real
    };
    WorldHandle::from_scenario(&scenario)
        .with_context(|| format!("building the world of {}", scenario_path.display()))
}

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

/// The header's `camera` and `target` blocks of a simulated cell (its first camera and its
/// chessboard; `board` overrides the inner corners). Live cells leave them to
/// `robocal calibrate camera --board --square` (the size comes from the images).
fn camera_header(
    header: &mut Header,
    scenario: &Path,
    board: Option<(u32, u32)>,
) -> anyhow::Result<()> {
    let s = Scenario::load(scenario)?;
    let Some(c) = s.cameras.first() else {
        return Ok(());
    };
    let cam = crate::dataset::CameraHeader {
        kind: "mono".into(),
        width: c.width,
        height: c.height,
        name: Some(c.name.clone()),
        mount: Some(if c.arm.is_some() { "flange" } else { "base" }.into()),
    };
    let target = s.scene.chessboard.as_ref().map(|b| {
        let (cols, rows) = board.unwrap_or((b.cols.saturating_sub(1), b.rows.saturating_sub(1)));
        crate::dataset::TargetHeader {
            kind: if b.charuco.is_some() {
                "charuco"
            } else {
                "chessboard"
            }
            .into(),
            cols,
            rows,
            square_mm: b.square_mm,
            marker_mm: b.charuco.as_ref().map(|m| m.marker_mm),
            dictionary: b.charuco.as_ref().map(|m| m.dictionary.clone()),
        }
    });
    header.set_camera(&cam, target.as_ref());
    Ok(())
}

/// The dataset header's `camera` and `target` blocks of a real cell: the image size from one
/// frame grabbed now (which also proves the camera answers before anything moves), the mount
/// and the board from the device file.
fn live_camera_header(
    header: &mut Header,
    devices_file: &Path,
    cam: &dyn robocal_drivers::traits::ImageSource,
    rt: &tokio::runtime::Runtime,
    board: Option<(u32, u32)>,
) -> anyhow::Result<()> {
    let f = crate::acquire::devices::DevicesFile::read(devices_file)?;
    let entry = f
        .devices
        .iter()
        .find(|d| d.role == crate::acquire::devices::Role::Camera);
    let img = rt.block_on(cam.grab()).with_context(|| {
        format!(
            "grabbing a first image from camera {:?} ({})",
            entry.map_or("?", |e| e.name.as_str()),
            devices_file.display()
        )
    })?;
    anyhow::ensure!(
        img.width > 0 && img.height > 0,
        "camera {:?} returned an empty image",
        entry.map_or("?", |e| e.name.as_str())
    );
    let cam = crate::dataset::CameraHeader {
        kind: "mono".into(),
        width: img.width,
        height: img.height,
        name: entry.map(|e| e.name.clone()),
        mount: Some(
            entry
                .and_then(|e| e.mount.clone())
                .unwrap_or_else(|| "flange".into()),
        ),
    };
    let target = f.board.as_ref().map(|b| {
        let mut t = b.target();
        if let Some((c, r)) = board {
            (t.cols, t.rows) = (c, r);
        }
        t
    });
    header.set_camera(&cam, target.as_ref());
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

/// The camera of a cell and, for a simulated cell, its chessboard as inner corners.
struct CellCamera {
    /// The camera's device name, if the cell has one.
    name: Option<String>,
    /// The scenario's chessboard (inner corners), sim cells only.
    board: Option<(u32, u32)>,
}

/// The camera of the cell described by `config` (a scenario for `sim`, else a device file).
fn cell_camera(mode: &str, config: &Path) -> anyhow::Result<CellCamera> {
    Ok(match mode {
        "sim" => {
            let s = Scenario::load(config)?;
            let board = s
                .scene
                .chessboard
                .as_ref()
                .filter(|b| b.cols >= 3 && b.rows >= 3)
                // OpenCV's chessboard detector cannot label a ChArUco board's corners:
                // ChArUco images are detected by `calibrate camera` (with their ids).
                .filter(|b| b.charuco.is_none())
                .map(|b| (b.cols - 1, b.rows - 1));
            CellCamera {
                name: s.cameras.first().map(|c| c.name.clone()),
                board,
            }
        }
        _ => {
            let f = crate::acquire::devices::DevicesFile::read(config)?;
            let cam = f
                .devices
                .iter()
                .find(|d| d.role == crate::acquire::devices::Role::Camera)
                .map(|d| d.name.clone());
            // A chessboard declared in the file is detected at capture time as in dry runs.
            let board = f
                .board
                .as_ref()
                .filter(|b| b.kind == "chessboard")
                .map(|b| (b.cols, b.rows));
            CellCamera { name: cam, board }
        }
    })
}

/// Safety limits of the plan's robot: its joint limits and the run's speed caps.
/// The safety limits of a run: the robot's joint limits, the speed caps, and — from the plan's
/// own constraints — the table plane and the Cartesian envelope, checked along every
/// joint-interpolated move at the flange and the tool point (the planner checks the same).
fn safety_limits(
    plan: &PlanFile,
    speed: MoveSpeedOpt,
) -> anyhow::Result<(SafetyLimits, Option<Arc<dyn ArmGeometry>>)> {
    let model = KinematicModel::from_robot_block(&plan.robot).context("the plan's robot")?;
    let (lower, upper) = model.joint_limits().into_iter().unzip();
    // The table and envelope come from the plan's spec (`spec.constraints`): limits that do
    // not read are an error, never a run with fewer checks. A plan without a spec or without
    // constraints (made by hand) runs with the joint limits and speed caps only, and says so.
    let constraints: crate::plan::spec::ConstraintSpec = match &plan.spec {
        serde_json::Value::Null => Default::default(),
        serde_json::Value::Object(m) => match m.get("constraints") {
            None => Default::default(),
            Some(c) => serde_json::from_value(c.clone()).map_err(|e| {
                anyhow::anyhow!(
                    "the plan's safety limits (`spec.constraints`: table plane, envelope) do \
                     not read: {e}; refusing to run without them (fix them or re-make the plan \
                     with `robocal plan`)"
                )
            })?,
        },
        other => bail!(
            "the plan's `spec` is {other}, not an object: its safety limits (table plane, \
             envelope) cannot be read; refusing to run without them"
        ),
    };
    if let Some(sp) = plan.spec.as_object().filter(|m| !m.is_empty()) {
        // A spec that is there must read whole: a typo elsewhere may hide a wrong limit.
        serde_json::from_value::<crate::plan::PlanSpec>(serde_json::Value::Object(sp.clone()))
            .map_err(|e| {
                anyhow::anyhow!(
                    "the plan's `spec` (which holds its safety limits: table plane, envelope) \
                     does not read: {e}; refusing to run without them (re-make the plan with \
                     `robocal plan`)"
                )
            })?;
    }
    if constraints.envelope.is_none() && constraints.table_z_mm.is_none() {
        eprintln!(
            "note: the plan sets no table plane or envelope: only the joint limits and speed \
             caps are checked"
        );
    }
    let (envelope, table) = (
        constraints.envelope.clone(),
        crate::plan::constraints::table_plane(&constraints),
    );
    let geometry: Option<Arc<dyn ArmGeometry>> = match (&envelope, &table) {
        (None, None) => None,
        _ => {
            let tool = plan
                .tool
                .to_iso()
                .unwrap_or_else(nalgebra::Isometry3::identity);
            let m = model.clone();
            Some(Arc::new(move |q: &[f64]| {
                let fl = m.flange_pose(q);
                vec![
                    nalgebra::Point3::from(fl.translation.vector),
                    nalgebra::Point3::from((fl * tool).translation.vector),
                ]
            }))
        }
    };
    Ok((
        SafetyLimits {
            joint_lower: lower,
            joint_upper: upper,
            max_vel: speed.max_vel,
            max_acc: speed.max_acc,
            envelope,
            table,
            path_step: 1f64.to_radians(),
        },
        geometry,
    ))
}

struct Reporter {
    json: bool,
    bar: Option<indicatif::ProgressBar>,
    /// Without a terminal: a line every `every` poses and at each skip.
    every: usize,
    /// The devices' clock is simulated (ETAs are labelled so).
    simulated: bool,
}

impl Reporter {
    fn new(json: bool, total: usize, done: usize, simulated: bool) -> Reporter {
        let bar = (!json && std::io::stderr().is_terminal()).then(|| {
            let b = indicatif::ProgressBar::new(total as u64);
            b.set_style(
                indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} poses, ETA {msg}")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            b.set_position(done as u64);
            b
        });
        Reporter {
            json,
            bar,
            every: (total / 10).max(1),
            simulated,
        }
    }

    fn report(&self, p: &Progress) {
        if self.json {
            println!("{}", json!({ "progress": p }));
        } else if let Some(b) = &self.bar {
            b.set_position(p.done as u64);
            let eta = p.eta_s.map_or("?".into(), |s| format!("{:.0} s", s));
            b.set_message(format!("{eta}, {:.0} poses/h", p.poses_per_hour));
        } else if !p.ok || p.done.is_multiple_of(self.every) || p.done == p.total {
            // No terminal (a log, CI, a pipe): plain lines, skips as they happen.
            let clock = if self.simulated {
                " (simulated clock)"
            } else {
                ""
            };
            let eta = p
                .eta_s
                .filter(|_| p.done < p.total)
                .map_or(String::new(), |s| format!(", ETA {s:.0} s{clock}"));
            let what = if p.ok { "" } else { ": skipped" };
            eprintln!(
                "  pose {} ({}/{}){what}; {} recorded, {} skipped{eta}",
                p.id, p.done, p.total, p.recorded, p.skipped
            );
        }
    }

    fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish();
        }
    }
}

/// Runs (or resumes) the acquisition in `dir` with the run configuration `cfg`.
fn acquire_in(
    dir: &Path,
    cfg: &RunConfig,
    args: &Args,
    consent: Option<&LiveConsent>,
) -> anyhow::Result<RunSummary> {
    let plan_path = dir.join(&cfg.plan);
    let plan = PlanFile::read(&plan_path).with_context(|| format!("{}", plan_path.display()))?;
    let config_path = dir.join(&cfg.config);
    super::run_checks::check_run_inputs(
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
    let mut served = None;
    let (mut devices, info) = match cfg.mode.as_str() {
        "sim" if args.in_process => {
            let world = sim_world(&config_path, cfg.virtual_clock)?;
            sim_cell(&world).with_context(|| format!("{}", config_path.display()))?
        }
        "sim" => {
            // The dry run proper: simulators serve the real protocols on loopback / ptys and
            // the real drivers connect to them.
            let world = sim_world(&config_path, cfg.virtual_clock)?;
            let (d, i, s) = rt
                .block_on(super::wire_cell::wire_cell(&world))
                .with_context(|| format!("{}", config_path.display()))?;
            served = Some(s);
            (d, i)
        }
        "live" => {
            let Some(consent) = consent else {
                bail!("nothing moves without --live and confirmation");
            };
            let dof = plan.poses.first().map_or(6, |p| p.q_deg.len());
            rt.block_on(super::live_cell::live_cell(
                &config_path,
                dof,
                cfg.camera,
                consent,
            ))
            .with_context(|| format!("connecting the devices of {}", config_path.display()))?
        }
        other => bail!("{}: unknown mode {other:?}", dir.join("run.json").display()),
    };
    if !cfg.camera {
        devices.camera = None;
    } else if devices.camera.is_none() {
        bail!(
            "{}: the run records camera images but {} has no camera",
            dir.join("run.json").display(),
            config_path.display()
        );
    }
    let (limits, geometry) = safety_limits(&plan, cfg.speed)?;
    // The transfers are planned against the very limits and geometry the guard checks.
    let transfer = acquire::TransferSafety {
        limits: Arc::new(limits.clone()),
        geometry: geometry.clone(),
    };
    devices.arm = guard(devices.arm.clone(), limits, geometry);
    let mut header = header_for(&plan, &info);
    if cfg.camera && cfg.mode == "sim" {
        camera_header(&mut header, &config_path, cfg.capture.board)?;
    } else if let Some(cam) = devices.camera.clone().filter(|_| cfg.camera) {
        live_camera_header(&mut header, &config_path, &*cam, &rt, cfg.capture.board)?;
    }
    let journal_path = dir.join(DATASET);
    let (mut journal, existing, warnings) = Journal::open_or_create(&journal_path, &header)?;
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    let poses: Vec<PlannedPose> = plan.poses.iter().map(PlannedPose::from).collect();
    let done = acquire::done_pose_ids(&existing).len();
    let reporter = Reporter::new(args.json, poses.len(), done, cfg.virtual_clock);
    let mut opts = options(cfg, args.max_poses);
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
    // Early stop: too many poses skipped for the verdict to pass (issue 28 §1).
    let skip_limit = args.max_skipped_fraction;
    let early_stop = opts.stop.clone();
    let mut early: Option<String> = None;
    let summary = rt.block_on(acquire::acquire(
        &devices,
        &poses,
        &mut journal,
        &existing,
        &opts,
        &mut |p| {
            reporter.report(p);
            if let (Some(lim), None) = (skip_limit, &early) {
                if let Some(why) = skipped_too_many(p, lim) {
                    early = Some(why);
                    early_stop.request();
                }
            }
        },
    ))?;
    reporter.finish();
    signals.abort();
    if let Some(s) = served {
        s.abort();
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
             fitted to them); `{}` continues this one as it is",
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

fn new_run(args: &Args) -> anyhow::Result<Started> {
    let (Some(plan_path), Some(dir)) = (&args.plan, &args.out) else {
        bail!("--plan and --out are required (or --resume RUN_DIR)");
    };
    if args.live && args.devices.is_none() {
        bail!("--live drives the hardware of --devices DEVICES.toml: give the device file");
    }
    let (mode, config_src) = match (&args.sim, &args.devices) {
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
    super::run_checks::check_run_inputs(
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
    let CellCamera {
        name: cam_name,
        board: scenario_board,
    } = cell_camera(mode, config_src)
        .with_context(|| format!("reading {}", config_src.display()))?;
    let camera = if args.no_camera {
        false
    } else if args.camera {
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
            args,
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
        dir: dir.clone(),
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

/// Proof that this invocation may move real hardware: it has `--live` and the user
/// confirmed (or gave `--yes`). Only [`confirm_live`] makes one; opening a live cell
/// ([`super::live_cell::live_cell`]) needs it.
#[derive(Debug)]
pub struct LiveConsent(());

/// Asks for consent to move real hardware: `--live` must be on this invocation, then the user
/// types `yes` (or `--yes` was given). Fails without opening anything: stdin not a terminal and
/// no `--yes`, or any other answer.
pub fn confirm_live(args: &Args, what: &str) -> anyhow::Result<LiveConsent> {
    if !args.live {
        bail!(
            "nothing moves without --live: add --live (and --yes, or confirm at the prompt) to \
             drive the hardware"
        );
    }
    // The question goes to stderr: stdout carries the run's (or session's) result.
    eprintln!("{what}");
    if !args.yes {
        use std::io::{BufRead as _, IsTerminal as _, Write as _};
        if !std::io::stdin().is_terminal() {
            bail!("confirmation needed: re-run with --yes to move the hardware");
        }
        eprint!("type `yes` to move the arm: ");
        std::io::stderr().flush().ok();
        let mut answer = String::new();
        std::io::stdin().lock().read_line(&mut answer)?;
        if answer.trim() != "yes" {
            bail!("not confirmed: nothing moved");
        }
    }
    Ok(LiveConsent(()))
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
fn resume_run(args: &Args, dir: &Path) -> anyhow::Result<Started> {
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
                args,
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

/// `robocal run` stopped on Ctrl-C after the current pose's record was durable (exit 130).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Interrupted(pub String);

/// Run `robocal run`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    if let Some(f) = args.max_skipped_fraction {
        anyhow::ensure!(
            f.is_finite() && (0.0..=1.0).contains(&f),
            "--max-skipped-fraction {f}: a fraction from 0 to 1 (0.1 = 10 % of the poses)"
        );
    }
    let started = match &args.resume {
        Some(dir) => resume_run(&args, dir)?,
        None => new_run(&args)?,
    };
    let (dir, cfg) = (started.dir.clone(), started.cfg.clone());
    let summary = acquire_in(&dir, &cfg, &args, started.consent.as_ref())?;
    if args.json {
        println!("{}", json!({ "summary": summary }));
    } else if args.summary_to_stderr {
        eprint!("{summary}");
        eprintln!("dataset: {}", dir.join(DATASET).display());
    } else {
        print!("{summary}");
        println!("dataset: {}", dir.join(DATASET).display());
    }
    if summary.interrupted {
        let at = summary.stopped_at.map_or_else(
            || "before the first pose".to_string(),
            |id| format!("at pose {id}"),
        );
        drop(started);
        return Err(Interrupted(format!(
            "stopped {at}; continue with `{}`",
            crate::fsio::resume_command(&dir)
        ))
        .into());
    }
    if let Some(reason) = &summary.aborted {
        bail!(
            "run aborted: {reason} (continue with `{}`)",
            crate::fsio::resume_command(&dir)
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The run's safety wrapper carries the plan's table and envelope: a move that swings the
    /// flange below the table is refused before it reaches the arm.
    #[test]
    fn run_guard_enforces_the_plans_table_and_envelope() {
        let spec_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("plans/seed001-annulus.toml");
        let mut spec =
            crate::plan::PlanSpec::from_toml_str(&crate::fsio::read_to_string(spec_path).unwrap())
                .unwrap();
        if let Some(a) = spec.annulus.as_mut() {
            a.points = 5;
        }
        let model = KinematicModel::preset("denso-vs060").unwrap();
        let robot = crate::dataset::RobotBlock {
            model: "denso-vs060".into(),
            serial: None,
            chain: None,
            flange: None,
            extra: Default::default(),
        };
        let plan = crate::plan::build_plan(&spec, robot, &model, &Default::default())
            .unwrap()
            .file;
        let (limits, geometry) = safety_limits(
            &plan,
            MoveSpeedOpt {
                max_vel: 1.0,
                max_acc: 2.0,
            },
        )
        .unwrap();
        assert!(limits.table.is_some() && limits.envelope.is_some());
        let geometry = geometry.expect("a geometry for the path check");
        // Upright (flange high above the table) to folded down over the table edge.
        let up = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let down = [0.0, 100f64.to_radians(), 100f64.to_radians(), 0.0, 0.0, 0.0];
        assert!(model.flange_pose(&down).translation.z < 0.0);
        let fake = robocal_drivers::fake::FakeArm::new(up.to_vec());
        let arm = guard(Arc::new(fake.clone()), limits, Some(geometry));
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let err = rt
            .block_on(arm.move_joints(&down, robocal_drivers::MoveSpeed::default()))
            .unwrap_err();
        assert_eq!(err.kind(), robocal_drivers::ErrorKind::SafetyViolation);
        assert!(fake.commands().is_empty());
        // Limits that do not read are an error, never a run without them.
        let speed = MoveSpeedOpt {
            max_vel: 1.0,
            max_acc: 2.0,
        };
        let mut bad = plan.clone();
        bad.spec["constraints"]["envelope"] = json!({"shape": "sphere", "r": 5});
        let e = safety_limits(&bad, speed)
            .err()
            .expect("refused")
            .to_string();
        assert!(e.contains("safety limits"), "{e}");
        let mut bad = plan.clone();
        bad.spec["constraints"]["table_z_mm"] = json!("low");
        assert!(safety_limits(&bad, speed).is_err());
        let mut bad = plan.clone();
        bad.spec["typo"] = json!(1);
        assert!(safety_limits(&bad, speed).is_err());
        let mut bad = plan.clone();
        bad.spec = json!([1, 2]);
        assert!(safety_limits(&bad, speed).is_err());
        // A hand-made plan without a spec has joint limits and speed caps only.
        let mut bare = plan.clone();
        bare.spec = json!({});
        let (l, g) = safety_limits(&bare, speed).unwrap();
        assert!(l.table.is_none() && l.envelope.is_none() && g.is_none());
    }
}
