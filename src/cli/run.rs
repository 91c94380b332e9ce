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
    /// Allow real motion. Nothing moves on hardware without it.
    #[arg(long, requires = "devices")]
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
            thermometer: None,
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

fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::File::open(&tmp)
        .and_then(|f| f.sync_all())
        .with_context(|| format!("syncing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

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
            kind: "chessboard".into(),
            cols,
            rows,
            square_mm: b.square_mm,
            marker_mm: None,
            dictionary: None,
        }
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
            CellCamera {
                name: cam,
                board: None,
            }
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
    let spec: Option<crate::plan::PlanSpec> = serde_json::from_value(plan.spec.clone()).ok();
    let (envelope, table) = match &spec {
        Some(sp) => (
            sp.constraints.envelope.clone(),
            crate::plan::constraints::table_plane(&sp.constraints),
        ),
        None => (None, None),
    };
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
}

impl Reporter {
    fn new(json: bool, total: usize, done: usize) -> Reporter {
        let bar = (!json && std::io::stderr().is_terminal()).then(|| {
            let b = indicatif::ProgressBar::new(total as u64);
            b.set_style(
                indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} poses, ETA {msg}")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            b.set_position(done as u64);
            b
        });
        Reporter { json, bar }
    }

    fn report(&self, p: &Progress) {
        if self.json {
            println!("{}", json!({ "progress": p }));
        } else if let Some(b) = &self.bar {
            b.set_position(p.done as u64);
            let eta = p.eta_s.map_or("?".into(), |s| format!("{:.0} s", s));
            b.set_message(format!("{eta}, {:.0} poses/h", p.poses_per_hour));
        }
    }

    fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish();
        }
    }
}

/// Runs (or resumes) the acquisition in `dir` with the run configuration `cfg`.
fn acquire_in(dir: &Path, cfg: &RunConfig, args: &Args) -> anyhow::Result<RunSummary> {
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
            let dof = plan.poses.first().map_or(6, |p| p.q_deg.len());
            rt.block_on(super::live_cell::live_cell(&config_path, dof, cfg.camera))
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
    devices.arm = guard(devices.arm.clone(), limits, geometry);
    let mut header = header_for(&plan, &info);
    if cfg.camera && cfg.mode == "sim" {
        camera_header(&mut header, &config_path, cfg.capture.board)?;
    }
    let journal_path = dir.join(DATASET);
    let (mut journal, existing, warnings) = Journal::open_or_create(&journal_path, &header)?;
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    let poses: Vec<PlannedPose> = plan.poses.iter().map(PlannedPose::from).collect();
    let done = acquire::done_pose_ids(&existing).len();
    let reporter = Reporter::new(args.json, poses.len(), done);
    let opts = options(cfg, args.max_poses);
    let summary = rt.block_on(acquire::acquire(
        &devices,
        &poses,
        &mut journal,
        &existing,
        &opts,
        &mut |p| reporter.report(p),
    ))?;
    reporter.finish();
    if let Some(s) = served {
        s.abort();
    }
    write_atomic(
        &dir.join("summary.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )?;
    Ok(summary)
}

fn new_run(args: &Args) -> anyhow::Result<(PathBuf, RunConfig)> {
    let (Some(plan_path), Some(dir)) = (&args.plan, &args.out) else {
        bail!("--plan and --out are required (or --resume RUN_DIR)");
    };
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
    if dir.join(DATASET).exists() {
        bail!(
            "{} already holds a dataset: continue it with `robocal run --resume {}`",
            dir.display(),
            dir.display()
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
            "note: chessboard corners are not detected by this build (rebuild with \
             `--features opencv`); images are saved without `corners`"
        );
    }
    if mode == "live" {
        println!(
            "will move the arm through {} poses of plan {:?} at ≤ {} °/s",
            plan.poses.len(),
            plan.name,
            args.speed_deg_s
        );
        if !args.yes {
            use std::io::{BufRead as _, IsTerminal as _, Write as _};
            if !std::io::stdin().is_terminal() {
                bail!("confirmation needed: re-run with --yes to move the hardware");
            }
            print!("type `yes` to move the arm: ");
            std::io::stdout().flush().ok();
            let mut answer = String::new();
            std::io::stdin().lock().read_line(&mut answer)?;
            if answer.trim() != "yes" {
                bail!("not confirmed: nothing moved");
            }
        }
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let config_name = if mode == "sim" {
        "scenario.toml"
    } else {
        "devices.toml"
    };
    let copy = |src: &Path, name: &str| -> anyhow::Result<()> {
        let bytes = std::fs::read(src).with_context(|| format!("reading {}", src.display()))?;
        write_atomic(&dir.join(name), &bytes)
    };
    copy(plan_path, "plan.json")?;
    copy(config_src, config_name)?;
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
        &dir.join("run.json"),
        serde_json::to_string_pretty(&cfg)?.as_bytes(),
    )?;
    Ok((dir.clone(), cfg))
}

fn load_run(dir: &Path) -> anyhow::Result<RunConfig> {
    let p = dir.join("run.json");
    let text = std::fs::read_to_string(&p)
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

/// Run `robocal run`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let (dir, cfg) = match &args.resume {
        Some(dir) => (dir.clone(), load_run(dir)?),
        None => new_run(&args)?,
    };
    let summary = acquire_in(&dir, &cfg, &args)?;
    if args.json {
        println!("{}", json!({ "summary": summary }));
    } else {
        print!("{summary}");
        println!("dataset: {}", dir.join(DATASET).display());
    }
    if let Some(reason) = &summary.aborted {
        bail!(
            "run aborted: {reason} (continue with `robocal run --resume {}`)",
            dir.display()
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
            crate::plan::PlanSpec::from_toml_str(&std::fs::read_to_string(spec_path).unwrap())
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
    }
}
