//! A whole calibration session in one call (`robocal session`): plan → acquire the training
//! and the separate validation set → calibrate → diagnose → validate → verdict → report.
//!
//! The session directory holds every stage's output and `session.json`
//! (`robocal-session/1`, [`SessionFile`]), rewritten after each stage, so `--resume DIR`
//! continues at whichever stage stopped (acquisition resumes pose by pose as `robocal run
//! --resume` does). The cell (simulated or real devices) is supplied by the caller as a
//! [`Cell`]: this module never opens a device and never sees the simulator's truth.
//!
//! Layout of `DIR`:
//! `session.json`, `accept.toml`, `spec.toml` (the plan spec as used), `plan/train.json`,
//! `plan/validation.json` (+ `.txt` summaries, `.script` / `.pcs` exports),
//! `run-train/`, `run-validation/` (run directories), `calibrate/calibration.json`,
//! `diagnose/` (diagnosis, effect plots, final calibration), `deploy/` (calibration file and
//! URDF of the calibrated geometry), `report.html`.
//! Units: mm, degrees, seconds in every file.
pub mod accept;
pub mod approach;
pub mod briefing;
pub mod camera;
pub mod camera_intervals;
pub mod camera_plots;
pub mod deploy;
pub mod deploy_score;
pub mod history;
pub mod laser;
pub mod navchain;
pub mod rcm;
pub mod start;
pub mod survey;
pub mod svg;
pub mod teach;
pub mod verify;

use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _};
use serde::{Deserialize, Serialize};
use sha2::Digest as _;

use crate::acquire::RunSummary;
use crate::dataset::{Dataset, RobotBlock};
use crate::model::{KinematicModel, Unit};
use crate::plan::{self, cell::CellGeometry, export, PlanOptions, PlanSpec};
use crate::solve::kinematics::{identify, IdentOptions};
use crate::solve::{calfile, metrics};
pub use accept::{AcceptSpec, Measured, Verdict, VerdictKind};

/// `session.json` format tag.
pub use crate::schema::SESSION_FORMAT;

/// The stages, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Stage {
    Plan,
    AcquireTrain,
    AcquireValidation,
    Calibrate,
    Diagnose,
    Validate,
    /// Command the calibrated robot at held-out targets and measure (what a hospital accepts
    /// a robot on).
    Verify,
    Report,
}

impl Stage {
    /// All stages in order.
    pub const ALL: [Stage; 8] = [
        Stage::Plan,
        Stage::AcquireTrain,
        Stage::AcquireValidation,
        Stage::Calibrate,
        Stage::Diagnose,
        Stage::Validate,
        Stage::Verify,
        Stage::Report,
    ];
}

/// `sim` (dry run on the simulated cell) or `live` (hardware).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    Sim,
    Live,
}

/// What the cell file says about the cell (robot, controller, sensors, geometry).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CellDescription {
    /// Robot preset (`denso-vs060`, `ur5e`).
    pub robot_model: String,
    /// Robot serial number.
    pub robot_serial: Option<String>,
    /// Controller / protocol (`bcap`, `rtde`).
    pub controller: Option<String>,
    /// Tracker kind and serial / device name.
    pub tracker: Option<String>,
    pub tracker_serial: Option<String>,
    /// Other sensors (laser, camera), one line each.
    #[serde(default)]
    pub sensors: Vec<String>,
    /// Marker (tool) origin in the flange frame, as the cell file states it.
    pub marker_on_flange: Option<plan::spec::FrameSpec>,
    /// Home joint angles (deg).
    pub home_deg: Option<Vec<f64>>,
    /// Where the tracker stands, its volume, occluders (if the cell file says).
    pub geometry: Option<CellGeometry>,
    /// Tracker frame rate (Hz), for the time model.
    pub tracker_rate_hz: Option<f64>,
    /// Arm settling time after a move (s), for the time model.
    pub settle_s: Option<f64>,
    /// The camera and its board, for a camera session.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<camera::CameraCell>,
    /// The endoscope (intrinsics) and the instrument's shaft, for an RCM session.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub endoscope: Option<rcm::EndoscopeCell>,
    /// The cell's safety limits (a device file's `[safety]`): the plan stays inside them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub safety: Option<crate::acquire::device_safety::SafetyEntry>,
}

/// How the session was started (everything `--resume` needs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SessionSetup {
    pub mode: Mode,
    /// The cell file copy in the session directory (`scenario.toml` / `devices.toml`).
    pub cell_file: String,
    /// The plan spec copy (`spec.toml`).
    pub spec_file: String,
    /// Training poses kept by D-optimal selection.
    pub poses: usize,
    /// Validation (held-out) points.
    pub heldout_points: usize,
    /// Tracker frames averaged per pose.
    pub frames: usize,
    /// Joint speed / acceleration caps (deg/s, deg/s²).
    pub speed_deg_s: f64,
    pub accel_deg_s2: f64,
    /// Operator's note for the report.
    pub operator_note: Option<String>,
    /// Stop after planning.
    pub plan_only: bool,
    /// What the session calibrates (sessions written before camera sessions: kinematic).
    #[serde(default)]
    pub kind: SessionKind,
    /// Laser sessions: the arm's kinematic calibration of the same visit (copy in the session
    /// directory): the laser spots go through the identified arm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arm_calibration: Option<String>,
    /// Locate the tracker and the marker with a few probe poses before planning
    /// (`--survey`, [`survey`]).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub survey: bool,
    /// Close the kinematic session with seed 003's correction network (`--navchain`,
    /// [`navchain`]).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub navchain: bool,
    /// Camera sessions: hand-guided poses that locate the board before planning
    /// (`--teach-board N`, [`teach`]); 0: none.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub teach_board: usize,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// What a session calibrates.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SessionKind {
    /// The arm's kinematics, measured by a tracker (seed 001).
    #[default]
    Kinematic,
    /// A camera's intrinsics and hand-eye from board images (seed 004).
    Camera,
    /// A laser range sensor's beam on the flange from calibration planes (seed 000).
    Laser,
    /// An endoscope's hand-eye from the images of an instrument pivoting about a trocar
    /// (seed 002).
    Rcm,
}

/// One dataset of the session and its SHA-256.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetRef {
    /// `train` or `validation`.
    pub role: String,
    /// Path relative to the session directory.
    pub path: String,
    /// SHA-256 of the file (hex).
    pub sha256: String,
    /// Pose records in it.
    pub records: usize,
}

/// A skipped pose and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Skip {
    /// `train` or `validation`.
    pub set: String,
    pub id: u64,
    pub reason: String,
}

/// A fitted parameter: change from nominal and 95 % interval (file units mm / deg).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParamChange {
    pub name: String,
    /// `mm` or `deg`.
    pub unit: String,
    pub nominal: f64,
    pub value: f64,
    /// 1.96 σ (None when the covariance is unavailable).
    pub ci95: Option<f64>,
}

/// An effect found by the diagnosis, in plain words.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EffectFound {
    /// Kind key (`joint-compliance`, ...).
    pub kind: String,
    /// One sentence for a field engineer.
    pub words: String,
    /// Held-out RMS before / after adding it (mm).
    pub heldout_rms_mm_before: Option<f64>,
    pub heldout_rms_mm_after: Option<f64>,
    /// Camera effects: held-out reprojection RMS before / after adding it (px).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heldout_rms_px_before: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heldout_rms_px_after: Option<f64>,
    /// Its residual plot (relative path), if any.
    pub plot: Option<String>,
}

/// Held-out error of one pose (mm), before and after.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseError {
    pub id: u64,
    pub before_mm: f64,
    pub after_mm: f64,
    /// Joint angles (deg).
    pub q_deg: Vec<f64>,
}

/// `session.json` (`robocal-session/1`). The verdict is its first field.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SessionFile {
    /// `PASS`, `FAIL` or `INCOMPLETE`.
    pub verdict: VerdictKind,
    /// The verdict in one line (failed criteria named).
    pub verdict_line: String,
    /// Always `robocal-session/1`.
    pub format: String,
    /// When the session started / last finished a stage (UTC ISO 8601).
    pub created: String,
    pub updated: String,
    pub setup: SessionSetup,
    pub cell: CellDescription,
    pub accept: AcceptSpec,
    /// Stages finished, in order.
    pub stages_done: Vec<Stage>,
    /// Planned poses (training + validation) and how many were skipped in acquisition.
    pub poses_planned: usize,
    pub poses_skipped: usize,
    /// Candidate poses the planner dropped and why (key → count), training + validation.
    pub plan_rejects: std::collections::BTreeMap<String, usize>,
    pub skipped: Vec<Skip>,
    /// The planner's predicted acquisition time (s) and the measured one (devices' clock).
    pub predicted_duration_s: f64,
    pub duration_s: Option<f64>,
    /// Headline held-out numbers (mm).
    pub heldout_rms_mm_before: Option<f64>,
    pub heldout_rms_mm_after: Option<f64>,
    /// Every number the verdict used.
    pub measured: Measured,
    /// The verdict with each criterion.
    pub judgement: Option<Verdict>,
    /// The datasets and their SHA-256 (every artifact of the session records them).
    pub datasets: Vec<DatasetRef>,
    pub params: Vec<ParamChange>,
    pub effects: Vec<EffectFound>,
    pub heldout_errors: Vec<PoseError>,
    /// Files to deploy (relative paths).
    pub deploy: Vec<String>,
    /// What each deployed file delivers on its own on the held-out poses, judged against the
    /// same spec (the verdict is the diagnosed model's; a URDF holds the geometry only).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub deploy_accuracy: Vec<deploy_score::ArtifactAccuracy>,
    /// Warnings collected on the way.
    pub warnings: Vec<String>,
    /// Camera sessions: the camera calibration (intrinsics, hand-eye, target pose with their
    /// uncertainties, every method side by side, held-out pixels before / after diagnosis).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<camera::CameraSummary>,
    /// The `verify` stage: commanded-vs-measured before / after, coincidence error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub verify: Option<verify::VerifySummary>,
    /// Laser sessions: the beam, the methods side by side on the held-out targets, the
    /// seed's figures beside ours.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laser: Option<laser::LaserSummary>,
    /// RCM sessions: the endoscope hand-eye, held-out silhouettes, the detector's refusals.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rcm: Option<rcm::RcmSummary>,
    /// `--survey`: where the probe poses found the tracker and the marker (the plan uses it).
    pub survey: Option<survey::SurveySummary>,
    /// `--navchain`: seed 003's correction network beside the physical diagnosis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub navchain: Option<navchain::NavchainSummary>,
    /// `--teach-board`: where the hand-guided views found the board (the plan uses it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub teach: Option<teach::TeachSummary>,
}

impl SessionFile {
    /// Read and check the format tag.
    pub fn load(path: &Path) -> anyhow::Result<SessionFile> {
        let text = crate::fsio::read_to_string(path)
            .with_context(|| format!("{} is not a session directory", path.display()))?;
        let f: SessionFile =
            serde_json::from_str(&text).with_context(|| format!("{}", path.display()))?;
        if f.format != SESSION_FORMAT {
            bail!(
                "{}: format {:?} is not {SESSION_FORMAT}",
                path.display(),
                f.format
            );
        }
        Ok(f)
    }

    /// Write atomically.
    pub fn save(&self, path: &Path) -> anyhow::Result<()> {
        write_atomic(path, serde_json::to_string_pretty(self)?.as_bytes())
    }

    /// The dataset fingerprint `{role: sha256}` every artifact of this session carries.
    pub fn dataset_hashes(&self) -> serde_json::Value {
        let mut m = serde_json::Map::new();
        for d in &self.datasets {
            m.insert(d.role.clone(), serde_json::Value::String(d.sha256.clone()));
        }
        serde_json::Value::Object(m)
    }

    fn done(&self, s: Stage) -> bool {
        self.stages_done.contains(&s)
    }
}

/// The devices of a session, supplied by the caller (the CLI wires the simulator or the
/// hardware): acquire (or resume) a plan into a run directory.
pub trait Cell {
    /// Run the plan at `plan` into `run_dir`, resuming if `run_dir` already holds a run.
    /// Returns the summary of this invocation.
    fn acquire(&mut self, plan: &Path, run_dir: &Path) -> anyhow::Result<RunSummary>;
    /// The survey's probe poses ([`survey`]): as [`Cell::acquire`], but skipped poses are
    /// expected (finding where the tracker sees is the point) and never stop the run early.
    fn acquire_probes(&mut self, plan: &Path, run_dir: &Path) -> anyhow::Result<RunSummary> {
        self.acquire(plan, run_dir)
    }
    /// The teach step ([`teach`]): `count` hand-guided poses and an image at each, read
    /// without commanding the arm.
    fn teach_views(&mut self, count: usize, log: Log) -> anyhow::Result<Vec<teach::TaughtView>> {
        let _ = (count, log);
        bail!("this cell cannot read hand-guided poses")
    }
}

/// Write a file atomically and durably ([`crate::fsio::write_atomic`]), creating its directory.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    if let Some(p) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(p).with_context(|| format!("creating {}", p.display()))?;
    }
    crate::fsio::write_atomic_ctx(path, bytes)
}

/// SHA-256 of a file, hex.
pub fn sha256_file(path: &Path) -> anyhow::Result<String> {
    let bytes = crate::fsio::read(path).with_context(|| format!("reading {}", path.display()))?;
    Ok(sha256_hex(&bytes))
}

/// SHA-256 of bytes, hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    let d = sha2::Sha256::digest(bytes);
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// The plan spec of a session: the given spec with the cell's geometry, marker, home and
/// time model (speed caps of the run, sampling at the tracker's rate, the arm's settling).
pub fn fit_spec_to_cell(
    spec: &mut PlanSpec,
    cell: &CellDescription,
    setup: &SessionSetup,
) -> Vec<String> {
    let mut notes = Vec::new();
    if let Some(g) = &cell.geometry {
        spec.cell = Some(g.clone());
        spec.tracker = None;
        notes.push("visibility from the cell file's tracker pose, volume and occluders".into());
    } else {
        notes.push(
            "the cell file does not say where the tracker stands: visibility from the plan spec"
                .into(),
        );
    }
    if let Some(m) = &cell.marker_on_flange {
        spec.tool = m.clone();
    }
    if let Some(h) = &cell.home_deg {
        spec.timing.home_deg = Some(h.clone());
    }
    spec.timing.speed_deg_s = vec![setup.speed_deg_s];
    spec.timing.accel_deg_s2 = vec![setup.accel_deg_s2];
    let rate = cell.tracker_rate_hz.unwrap_or(60.0).max(1.0);
    // The engine's time per pose besides the move (see `acquire::engine`): the arm settles
    // (the detector needs its window of polls after the arm's own settling), then the tracker
    // frames are averaged.
    let settle_opts = crate::acquire::SettleOptions::default();
    spec.timing.settle_s = cell.settle_s.unwrap_or(0.3)
        + settle_opts.poll_s * settle_opts.window as f64
        + settle_opts.window as f64 / rate;
    spec.timing.sample_s = setup.frames as f64 / rate;
    if let Some(sf) = &cell.safety {
        notes.extend(crate::acquire::device_safety::fit_constraints(
            &mut spec.constraints,
            sf,
        ));
    }
    if setup.kind == SessionKind::Camera {
        notes.extend(camera::fit_shell(spec, cell, setup));
    }
    notes
}

/// The validation spec: the same spec, another seed, group `validation`, `points` points.
pub fn validation_spec(spec: &PlanSpec, points: usize) -> PlanSpec {
    let mut v = spec.clone();
    v.name = format!("{}-validation", spec.name);
    v.seed = spec.seed.wrapping_add(1);
    v.group = "validation".into();
    if let Some(a) = v.annulus.as_mut() {
        a.points = points;
    }
    if let Some(sh) = v.shell.as_mut() {
        // Other viewpoints than the training shell's: random inside the strata (another
        // seed), about `points` of them.
        sh.jitter = true;
        sh.strata = camera::shell_strata(points, 1);
    }
    v
}

pub(crate) fn rel(dir: &Path, p: &Path) -> String {
    p.strip_prefix(dir)
        .unwrap_or(p)
        .to_string_lossy()
        .replace('\\', "/")
}

/// Starts a new session: creates `dir`, copies the cell file, spec and acceptance spec.
#[allow(clippy::too_many_arguments)]
pub fn create(
    dir: &Path,
    setup: SessionSetup,
    cell_src: &Path,
    cell: CellDescription,
    spec_text: &str,
    accept: AcceptSpec,
) -> anyhow::Result<SessionFile> {
    if dir.join("session.json").exists() {
        bail!(
            "{} already holds a session: continue it with `robocal session --resume {}`",
            dir.display(),
            dir.display()
        );
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let bytes =
        crate::fsio::read(cell_src).with_context(|| format!("reading {}", cell_src.display()))?;
    write_atomic(&dir.join(&setup.cell_file), &bytes)?;
    write_atomic(&dir.join(&setup.spec_file), spec_text.as_bytes())?;
    write_atomic(
        &dir.join("accept.toml"),
        toml::to_string(&accept)?.as_bytes(),
    )?;
    let now = crate::acquire::utc_now_iso();
    let f = SessionFile {
        verdict: VerdictKind::Incomplete,
        verdict_line: "INCOMPLETE: session started".into(),
        format: SESSION_FORMAT.into(),
        created: now.clone(),
        updated: now,
        setup,
        cell,
        accept,
        stages_done: vec![],
        poses_planned: 0,
        poses_skipped: 0,
        plan_rejects: Default::default(),
        skipped: vec![],
        predicted_duration_s: 0.0,
        duration_s: None,
        heldout_rms_mm_before: None,
        heldout_rms_mm_after: None,
        measured: Measured::default(),
        judgement: None,
        datasets: vec![],
        params: vec![],
        effects: vec![],
        heldout_errors: vec![],
        deploy: vec![],
        deploy_accuracy: vec![],
        warnings: vec![],
        camera: None,
        verify: None,
        laser: None,
        rcm: None,
        survey: None,
        navchain: None,
        teach: None,
    };
    f.save(&dir.join("session.json"))?;
    Ok(f)
}

/// What a stage prints (the CLI shows it).
pub type Log<'a> = &'a mut dyn FnMut(&str);

/// What the stages of one invocation hand each other in memory: each dataset read once (and
/// checked against the SHA-256 the session recorded), the kinematic identification run once.
/// A resumed session fills it on first use.
#[derive(Default)]
pub struct Work {
    datasets: std::collections::BTreeMap<String, (PathBuf, crate::dataset::Loaded)>,
    ident: Option<crate::solve::kinematics::IdentResult>,
    camera: camera::CameraWork,
}

impl Work {
    /// The session's `role` dataset (`train`, `validation`): read on first use, its SHA-256
    /// checked against `session.json`.
    pub fn dataset(
        &mut self,
        dir: &Path,
        s: &SessionFile,
        role: &str,
    ) -> anyhow::Result<&(PathBuf, crate::dataset::Loaded)> {
        if !self.datasets.contains_key(role) {
            let d = s
                .datasets
                .iter()
                .find(|d| d.role == role)
                .with_context(|| format!("no {role} dataset in the session"))?;
            let p = dir.join(&d.path);
            let bytes =
                crate::fsio::read(&p).with_context(|| format!("reading {}", p.display()))?;
            let sha = sha256_hex(&bytes);
            if sha != d.sha256 {
                bail!(
                    "{}: SHA-256 {sha} is not the {} recorded in session.json: the dataset changed since it was acquired",
                    p.display(),
                    d.sha256
                );
            }
            let loaded = crate::dataset::parse_dataset(&bytes, &p)
                .with_context(|| format!("{}", p.display()))?;
            self.datasets.insert(role.to_string(), (p, loaded));
        }
        Ok(&self.datasets[role])
    }

    /// The kinematic identification of the training set (held out: the validation set), run
    /// once per invocation.
    pub fn identification(
        &mut self,
        dir: &Path,
        s: &SessionFile,
    ) -> anyhow::Result<&crate::solve::kinematics::IdentResult> {
        if self.ident.is_none() {
            let val = self.dataset(dir, s, "validation")?.1.dataset.clone();
            let train = &self.dataset(dir, s, "train")?.1.dataset;
            let opts = IdentOptions {
                heldout: Some(val),
                ..Default::default()
            };
            let res = identify(train, &opts).context("kinematic identification")?;
            self.ident = Some(res);
        }
        Ok(self.ident.as_ref().expect("set above"))
    }
}

/// Runs (or continues) the session in `dir` up to the end (or the plan, with `plan_only`).
pub fn run(dir: &Path, cell: &mut dyn Cell, log: Log) -> anyhow::Result<SessionFile> {
    let path = dir.join("session.json");
    let mut s = SessionFile::load(&path)?;
    if s.setup.kind == SessionKind::Laser {
        return laser::run(dir, s, cell, log);
    }
    if s.setup.kind == SessionKind::Rcm {
        return rcm::run(dir, s, cell, log);
    }
    let mut work = Work::default();
    let step = |s: &mut SessionFile, st: Stage| stage_done(dir, s, st);
    if s.setup.survey && !s.done(Stage::Plan) {
        survey::run(dir, &mut s, cell, &mut *log)?;
    }
    if s.setup.teach_board > 0 && !s.done(Stage::Plan) {
        teach::run(dir, &mut s, cell, &mut *log)?;
    }
    if !s.done(Stage::Plan) {
        log("plan: training and validation poses fitted to the cell");
        plan_stage(dir, &mut s, &mut *log)?;
        step(&mut s, Stage::Plan)?;
    }
    if s.setup.plan_only {
        return Ok(s);
    }
    for (stage, set) in [
        (Stage::AcquireTrain, "train"),
        (Stage::AcquireValidation, "validation"),
    ] {
        if s.done(stage) {
            continue;
        }
        let loaded = acquire_set(dir, &mut s, cell, set, &mut *log)?;
        work.datasets.insert(set.to_string(), loaded);
        step(&mut s, stage)?;
    }
    let cam = s.setup.kind == SessionKind::Camera;
    if !s.done(Stage::Calibrate) {
        if cam {
            log("calibrate: camera intrinsics + hand-eye (maximum likelihood) on the training images");
            camera::calibrate_stage(dir, &mut s, &mut work, &mut *log)?;
        } else {
            log("calibrate: kinematic identification on the training poses");
            calibrate_stage(dir, &mut s, &mut work)?;
        }
        step(&mut s, Stage::Calibrate)?;
    }
    if !s.done(Stage::Diagnose) {
        log("diagnose: residual → physical effect → add it");
        diagnose_stage(dir, &mut s, &mut work, &mut *log)?;
        step(&mut s, Stage::Diagnose)?;
    }
    if !s.done(Stage::Validate) {
        if cam {
            log("validate: held-out images, reprojection before / after the diagnosis");
            camera::validate_stage(dir, &mut s, &mut work)?;
        } else {
            log("validate: held-out poses, before / after");
            validate_stage(dir, &mut s, &mut work)?;
        }
        step(&mut s, Stage::Validate)?;
    }
    if s.setup.navchain && !cam && s.navchain.is_none() {
        log(
            "navchain: seed 003's correction network on the training poses, scored on the held-out",
        );
        navchain::stage(dir, &mut s, &mut work)?;
        s.save(&path)?;
    }
    if !s.done(Stage::Verify) {
        if !cam {
            log("verify: command the calibrated robot at the held-out targets, measure");
        }
        verify::verify_stage(dir, &mut s, &mut work, cell, &mut *log)?;
        step(&mut s, Stage::Verify)?;
    }
    if !s.done(Stage::Report) {
        step(&mut s, Stage::Report)?;
        let html = crate::report::html::render_session(dir, &s)?;
        write_atomic(&dir.join("report.html"), html.as_bytes())?;
        s.save(&path)?;
    }
    Ok(s)
}

/// The last stages of a session whose held-out data are its verification (laser, RCM):
/// `verify` commands nothing; `report` writes `report.html`.
pub(crate) fn close_without_verify(dir: &Path, s: &mut SessionFile) -> anyhow::Result<()> {
    if !s.done(Stage::Verify) {
        stage_done(dir, s, Stage::Verify)?;
    }
    if !s.done(Stage::Report) {
        stage_done(dir, s, Stage::Report)?;
        let html = crate::report::html::render_session(dir, s)?;
        write_atomic(&dir.join("report.html"), html.as_bytes())?;
        s.save(&dir.join("session.json"))?;
    }
    Ok(())
}

/// Acquire (or resume) the plan `plan/{set}.json` into `run-{set}/` and record the dataset as
/// role `set` in the session (skips, duration, SHA-256). Does not mark a stage done.
pub(crate) fn acquire_set(
    dir: &Path,
    s: &mut SessionFile,
    cell: &mut dyn Cell,
    set: &str,
    log: Log,
) -> anyhow::Result<(PathBuf, crate::dataset::Loaded)> {
    log(&format!("acquire: {set} poses"));
    let plan_path = dir.join("plan").join(format!("{set}.json"));
    let run_dir = dir.join(format!("run-{set}"));
    let summary = cell.acquire(&plan_path, &run_dir).with_context(|| {
        format!(
            "acquiring the {set} poses (continue with `robocal session --resume {}`)",
            dir.display()
        )
    })?;
    *s.duration_s.get_or_insert(0.0) += summary.time.total_s();
    if let Some(reason) = &summary.aborted {
        s.save(&dir.join("session.json"))?;
        bail!(
            "{set} acquisition stopped: {reason} (continue with `robocal session --resume {}`)",
            dir.display()
        );
    }
    s.skipped.retain(|k| k.set != set);
    s.skipped.extend(summary.skipped.iter().map(|k| Skip {
        set: set.into(),
        id: k.id,
        reason: k.reason.clone(),
    }));
    s.poses_skipped = s.skipped.len();
    let ds_path = run_dir.join("dataset.jsonl");
    // Read once: hashed and parsed from the same bytes, kept for the later stages.
    let bytes =
        crate::fsio::read(&ds_path).with_context(|| format!("reading {}", ds_path.display()))?;
    let loaded = crate::dataset::parse_dataset(&bytes, &ds_path)
        .with_context(|| format!("{}", ds_path.display()))?;
    let ds = &loaded.dataset;
    if s.cell.robot_serial.is_none() {
        s.cell.robot_serial = ds.header.robot.serial.clone();
    }
    s.datasets.retain(|d| d.role != set);
    s.datasets.push(DatasetRef {
        role: set.into(),
        path: rel(dir, &ds_path),
        sha256: sha256_hex(&bytes),
        records: ds.poses().count(),
    });
    log(&format!(
        "  {} recorded, {} skipped, {:.0} s",
        summary.recorded,
        summary.skipped.len(),
        summary.time.total_s()
    ));
    Ok((ds_path, loaded))
}

/// Mark `st` done, re-judge and save `session.json`.
pub(crate) fn stage_done(dir: &Path, s: &mut SessionFile, st: Stage) -> anyhow::Result<()> {
    if !s.stages_done.contains(&st) {
        s.stages_done.push(st);
    }
    s.updated = crate::acquire::utc_now_iso();
    judge_into(s);
    s.save(&dir.join("session.json"))
}

/// Recompute the verdict from what is measured so far.
pub fn judge_into(s: &mut SessionFile) {
    let missing: Vec<String> = Stage::ALL
        .iter()
        .filter(|st| **st != Stage::Report && !s.stages_done.contains(st))
        .map(|st| {
            format!(
                "stage {} not done",
                serde_json::to_value(st)
                    .unwrap_or_default()
                    .as_str()
                    .unwrap_or("?")
            )
        })
        .collect();
    let mut m = s.measured.clone();
    m.poses_planned = s.poses_planned;
    m.poses_skipped = s.poses_skipped;
    s.measured = m.clone();
    let v = accept::judge_kind(&s.accept, &m, missing, s.setup.kind);
    s.verdict = v.verdict;
    s.verdict_line = v.line();
    s.heldout_rms_mm_before = m.heldout_rms_mm_before;
    s.heldout_rms_mm_after = m.heldout_rms_mm_after;
    s.judgement = Some(v);
}

fn plan_stage(dir: &Path, s: &mut SessionFile, log: Log) -> anyhow::Result<()> {
    let spec_path = dir.join(&s.setup.spec_file);
    let mut spec = PlanSpec::from_file(&spec_path)
        .with_context(|| format!("reading {}", spec_path.display()))?;
    for n in fit_spec_to_cell(&mut spec, &s.cell, &s.setup) {
        log(&format!("  {n}"));
    }
    let robot = RobotBlock {
        model: s.cell.robot_model.clone(),
        serial: s.cell.robot_serial.clone(),
        chain: None,
        flange: None,
        extra: Default::default(),
    };
    let mut model = KinematicModel::from_robot_block(&robot).context("the cell's robot")?;
    crate::acquire::device_safety::narrow_model(&mut model, s.cell.safety.as_ref())?;
    let vspec = validation_spec(&spec, s.setup.heldout_points);
    let train = plan::build_plan(
        &spec,
        robot.clone(),
        &model,
        &PlanOptions {
            // Camera viewpoints are a stratified shell (seed 004), not a D-optimal selection.
            select: (s.setup.kind == SessionKind::Kinematic).then_some(s.setup.poses),
        },
    )?;
    let val = plan::build_plan(&vspec, robot, &model, &PlanOptions::default())?;
    let pdir = dir.join("plan");
    let mut rejects = std::collections::BTreeMap::new();
    let mut predicted = 0.0;
    let tm = plan::TimeModel::from_spec(&spec.timing, model.dof());
    let (speed, accel) = (tm.vmax[0], tm.amax[0]);
    let wait = spec.timing.settle_s + spec.timing.sample_s;
    for (name, out) in [("train", &train), ("validation", &val)] {
        let f = &out.file;
        if f.poses.is_empty() {
            bail!("the {name} plan has no feasible pose in this cell: check the spec against the cell file");
        }
        write_atomic(
            &pdir.join(format!("{name}.json")),
            serde_json::to_string_pretty(f)?.as_bytes(),
        )?;
        write_atomic(
            &pdir.join(format!("{name}.txt")),
            export::summary_text(&f.summary).as_bytes(),
        )?;
        // Robot programs only when every move passes the run's safety path check.
        if f.summary.path_violations == 0 {
            write_atomic(
                &pdir.join(format!("{name}.script")),
                export::to_urscript(f, speed, accel, wait).as_bytes(),
            )?;
            write_atomic(
                &pdir.join(format!("{name}.pcs")),
                export::to_pacscript(f, 20.0, wait).as_bytes(),
            )?;
        } else {
            s.warnings.push(format!(
                "{name} plan: {} moves fail the safety path check; no URScript / PacScript exported",
                f.summary.path_violations
            ));
        }
        for (k, v) in &f.summary.rejects {
            *rejects.entry(k.clone()).or_insert(0) += v;
        }
        predicted += f.summary.timing.optimised_s;
        // A camera plan is not a kinematic identification: its identifiability warnings
        // (null directions of the kinematic Jacobian) do not apply.
        let camera = s.setup.kind == SessionKind::Camera;
        s.warnings.extend(
            f.summary
                .warnings
                .iter()
                .filter(|w| !(camera && w.contains("identification Jacobian")))
                .map(|w| format!("{name} plan: {w}")),
        );
        log(&format!(
            "  {name}: {} poses, {:.0} s predicted",
            f.poses.len(),
            f.summary.timing.optimised_s
        ));
    }
    s.poses_planned = train.file.poses.len() + val.file.poses.len();
    s.plan_rejects = rejects;
    s.predicted_duration_s = predicted;
    Ok(())
}

pub(crate) fn load_ds(
    dir: &Path,
    s: &SessionFile,
    role: &str,
) -> anyhow::Result<(PathBuf, Dataset)> {
    let d = s
        .datasets
        .iter()
        .find(|d| d.role == role)
        .with_context(|| format!("no {role} dataset in the session"))?;
    let p = dir.join(&d.path);
    let sha = sha256_file(&p)?;
    if sha != d.sha256 {
        bail!(
            "{}: SHA-256 {sha} is not the {} recorded in session.json: the dataset changed since it was acquired",
            p.display(),
            d.sha256
        );
    }
    let ds = Dataset::load(&p).with_context(|| format!("{}", p.display()))?;
    Ok((p, ds))
}

fn calibrate_stage(dir: &Path, s: &mut SessionFile, work: &mut Work) -> anyhow::Result<()> {
    work.identification(dir, s)?;
    let res = work.ident.as_ref().expect("identified above");
    let robot = &work.datasets["train"].1.dataset.header.robot;
    let mut file = calfile::ident_file(robot, res);
    file.extra.insert("datasets".into(), s.dataset_hashes());
    std::fs::create_dir_all(dir.join("calibrate"))?;
    file.save(dir.join("calibrate").join("calibration.json"))
        .context("writing calibrate/calibration.json")?;
    s.params = res
        .params
        .iter()
        .filter(|p| p.free)
        .map(|p| {
            let k = match p.unit {
                Unit::Mm => 1.0,
                Unit::Rad => 1f64.to_degrees(),
            };
            ParamChange {
                name: p.name.clone(),
                unit: match p.unit {
                    Unit::Mm => "mm".into(),
                    Unit::Rad => "deg".into(),
                },
                nominal: p.nominal * k,
                value: p.value * k,
                ci95: p.std.map(|sd| 1.96 * sd * k),
            }
        })
        .collect();
    // Base / tool parameters are not the robot's: the acceptance bounds the arm's.
    let arm = |n: &str| !(n.starts_with("base") || n.starts_with("tool"));
    let max_ci = |unit: &str| {
        s.params
            .iter()
            .filter(|p| p.unit == unit && arm(&p.name))
            .filter_map(|p| p.ci95)
            .fold(None, |m: Option<f64>, c| Some(m.map_or(c, |m| m.max(c))))
    };
    s.measured.param_ci95_mm = max_ci("mm");
    s.measured.param_ci95_deg = max_ci("deg");
    Ok(())
}

fn diagnose_stage(
    dir: &Path,
    s: &mut SessionFile,
    work: &mut Work,
    log: Log,
) -> anyhow::Result<()> {
    let out = dir.join("diagnose");
    let summary = if s.setup.kind == SessionKind::Camera {
        // The calibrate stage's views and result, in memory (calibrated here only when that
        // stage ran in an earlier invocation).
        camera::camera_set(work, dir, s, "train")?;
        camera::camera_set(work, dir, s, "validation")?;
        let base = work.camera.calibrated.take();
        let (train, held) = (&work.camera.sets["train"], &work.camera.sets["validation"]);
        crate::diagnose::camera_stage::run_loaded(train, Some(held), base, &out)?
    } else {
        work.dataset(dir, s, "train")?;
        work.dataset(dir, s, "validation")?;
        let (train, val) = (&work.datasets["train"], &work.datasets["validation"]);
        crate::diagnose::stage::run_loaded(
            &crate::diagnose::stage::DiagnoseRequest {
                data: train.0.clone(),
                out: out.clone(),
                heldout: Some(val.0.clone()),
                ..Default::default()
            },
            &train.1,
            Some(&val.1),
        )?
    };
    // Every artifact records the datasets it came from.
    for name in ["diagnosis.json", "calibration.json"] {
        let p = out.join(name);
        let text = crate::fsio::read_to_string(&p).with_context(|| format!("{}", p.display()))?;
        let mut v: serde_json::Value =
            serde_json::from_str(&text).with_context(|| format!("{}", p.display()))?;
        if let Some(o) = v.as_object_mut() {
            o.insert("datasets".into(), s.dataset_hashes());
        }
        write_atomic(&p, serde_json::to_string_pretty(&v)?.as_bytes())?;
    }
    log(&format!("  {}", summary.lines().next().unwrap_or("")));
    let diag: crate::schema::DiagnosisFile = crate::schema::read(&out.join("diagnosis.json"))?;
    s.effects = effects_in_words(&diag, &out, dir);
    if s.setup.kind == SessionKind::Camera {
        camera::after_diagnosis(dir, s, &diag)?;
    }
    Ok(())
}

/// The effects of a `diagnosis.json` ([`crate::schema::DiagnosisFile`], every sensor) in
/// plain words.
pub fn effects_in_words(
    diag: &crate::schema::DiagnosisFile,
    out: &Path,
    dir: &Path,
) -> Vec<EffectFound> {
    diag.effects
        .iter()
        .enumerate()
        .map(|(i, st)| {
            let kind = st.kind.clone();
            // A kinematic effect of the registry says itself what it found, with its size
            // (read back from the entry it wrote into the calibration); the camera and
            // laser findings by kind, with their parameters.
            let (what, coefs) = what_was_found(st);
            let (unit, _, _, hb, ha) = st.rms_with_unit();
            let prec = if unit == "px" { 4 } else { 3 };
            let mut effect_on = match (hb, ha) {
                (Some(b), Some(a)) if a <= b => format!(
                    "; compensating it cut the held-out error from {b:.prec$} to {a:.prec$} {unit}"
                ),
                (Some(b), Some(a)) => format!(
                    "; compensating it RAISED the held-out error from {b:.prec$} to {a:.prec$} {unit} (WORSE)"
                ),
                _ => String::new(),
            };
            if let (Some(mm), Some(deg)) = (st.hand_eye_change_mm, st.hand_eye_change_deg) {
                effect_on += &format!("; the hand-eye moved {mm:.3} mm, {deg:.4}°");
            }
            let coef_text = if coefs.is_empty() {
                String::new()
            } else {
                format!(" ({})", coefs.join(", "))
            };
            let plot = out.join(format!("effect_{}_{}.svg", i + 1, kind));
            let px = unit == "px";
            EffectFound {
                kind: kind.clone(),
                words: format!("{what}{coef_text}{effect_on}."),
                heldout_rms_mm_before: if px { None } else { hb },
                heldout_rms_mm_after: if px { None } else { ha },
                heldout_rms_px_before: if px { hb } else { None },
                heldout_rms_px_after: if px { ha } else { None },
                plot: plot.is_file().then(|| rel(dir, &plot)),
            }
        })
        .collect()
}

/// One finding in plain words and, for camera and laser findings, their parameters.
fn what_was_found(st: &crate::schema::DiagnosedEffect) -> (String, Vec<String>) {
    match crate::diagnose::effects::Effect::from_cal(&st.calibration) {
        Ok(e) if crate::diagnose::effects::EffectModel::kind(&e.block) == st.kind => {
            (e.sentence(), vec![])
        }
        _ => (sensor_effect_in_words(&st.kind), parameters_in_words(st)),
    }
}

/// What a camera or laser finding means, in plain words (kinematic effects have their own
/// sentences: [`crate::diagnose::effects::EffectModel::sentence`]).
fn sensor_effect_in_words(kind: &str) -> String {
    match kind {
        "target_scale" => {
            "the board is printed at another scale than its declared square size".to_string()
        }
        "target_flatness" => "the board is not flat (it sags or bows)".to_string(),
        "arm_kinematics" => "the arm's joint zeros and link dimensions differ from nominal \
                             (identified through the camera, so the hand-eye no longer absorbs \
                             them)"
            .to_string(),
        "distortion" => "the lens distorts more than the chosen distortion model".to_string(),
        "laser_scale" => "the laser's range reading is scaled (it reads long or short in \
                          proportion to the distance)"
            .to_string(),
        "laser_incidence" => "the laser's range reading is biased when the beam meets the \
                              surface obliquely"
            .to_string(),
        "laser_nonlinearity" => "the laser's range reading bends away from a straight line \
                                 over its measuring range"
            .to_string(),
        other => format!("effect {other}"),
    }
}

/// The parameters of a finding: `name = value ± ci unit`.
fn parameters_in_words(st: &crate::schema::DiagnosedEffect) -> Vec<String> {
    st.parameters
        .iter()
        .map(|p| {
            let num = crate::diagnose::effects::plain_number;
            let unit = if p.unit == "1" {
                String::new()
            } else {
                format!(" {}", p.unit)
            };
            match p.std {
                Some(sd) => format!(
                    "{} = {} ± {}{unit}",
                    p.name,
                    num(p.value, 4),
                    num(1.96 * sd, 4)
                ),
                None => format!("{} = {}{unit}", p.name, num(p.value, 4)),
            }
        })
        .collect()
}

fn validate_stage(dir: &Path, s: &mut SessionFile, work: &mut Work) -> anyhow::Result<()> {
    // "Before": the nominal chain with the tracker → base and flange → marker transforms
    // fitted (what the robot does today); "after": the diagnosed model (geometry + effects),
    // whose held-out predictions the diagnosis wrote.
    let res = work.identification(dir, s)?;
    let obs = &res.heldout_obs;
    if obs.is_empty() {
        bail!("no usable held-out pose in the validation dataset");
    }
    let pred_before: Vec<_> = obs
        .iter()
        .map(|o| res.nominal.measured_point(&o.q))
        .collect();
    let csv = dir.join("diagnose").join("heldout_predictions.csv");
    // Written by this session's diagnose stage: read through the one point-table schema; a
    // missing file (no diagnosis) falls back to the geometric calibration, a damaged one is an
    // error, never a silently shorter table.
    let after: std::collections::HashMap<u64, nalgebra::Point3<f64>> = if csv.exists() {
        crate::schema::points_csv::read(&csv)?
    } else {
        Default::default()
    };
    let pred_after: Vec<_> = obs
        .iter()
        .map(|o| {
            after
                .get(&o.id)
                .copied()
                .unwrap_or_else(|| res.model.measured_point(&o.q))
        })
        .collect();
    if after.is_empty() {
        s.warnings.push(
            "no diagnosis predictions: the held-out \"after\" is the geometric calibration".into(),
        );
    }
    let meas: Vec<_> = obs.iter().map(|o| o.p).collect();
    let err = |pred: &[nalgebra::Point3<f64>]| -> Vec<f64> {
        pred.iter()
            .zip(&meas)
            .map(|(p, m)| (p - m).norm())
            .collect()
    };
    let (eb, ea) = (err(&pred_before), err(&pred_after));
    let rms = |e: &[f64]| crate::solve::stats::rms(e);
    let max = |e: &[f64]| e.iter().cloned().fold(0.0, f64::max);
    let rb = metrics::relative_distance(&pred_before, &meas, 50.0);
    let ra = metrics::relative_distance(&pred_after, &meas, 50.0);
    let m = &mut s.measured;
    m.heldout_poses = obs.len();
    m.heldout_rms_mm_before = Some(rms(&eb));
    m.heldout_rms_mm_after = Some(rms(&ea));
    m.heldout_max_mm_before = Some(max(&eb));
    m.heldout_max_mm_after = Some(max(&ea));
    m.relative_distance_pct_before = rb.map(|r| r.mean_pct);
    m.relative_distance_pct_after = ra.map(|r| r.mean_pct);
    s.heldout_errors = obs
        .iter()
        .zip(eb.iter().zip(&ea))
        .map(|(o, (b, a))| PoseError {
            id: o.id,
            before_mm: *b,
            after_mm: *a,
            q_deg: o.q.iter().map(|x| x.to_degrees()).collect(),
        })
        .collect();
    // What to deploy: the calibration file (geometry + effects) and the URDF of the geometry.
    let ddir = dir.join("deploy");
    std::fs::create_dir_all(&ddir)?;
    let final_cal = dir.join("diagnose").join("calibration.json");
    let cal_src = if final_cal.is_file() {
        final_cal
    } else {
        dir.join("calibrate").join("calibration.json")
    };
    let bytes = crate::fsio::read(&cal_src).with_context(|| format!("{}", cal_src.display()))?;
    write_atomic(&ddir.join("calibration.json"), &bytes)?;
    let cal = crate::dataset::CalibrationFile::load(ddir.join("calibration.json"))
        .context("reading deploy/calibration.json back")?;
    // The URDF carries no effects, so it holds the geometry fitted without them (the calibrate
    // stage's): the diagnosed geometry was fitted jointly with its effects and is biased
    // without them (lab: 1.647 mm held-out alone, worse than nominal, against 0.735 mm).
    let geometric_cal = dir.join("calibrate").join("calibration.json");
    let urdf_cal = if geometric_cal.is_file() {
        crate::dataset::CalibrationFile::load(&geometric_cal)
            .with_context(|| format!("reading {} back", geometric_cal.display()))?
    } else {
        cal
    };
    let mut model = KinematicModel::from_robot_block(&urdf_cal.robot)?;
    model.apply_cal_params(&urdf_cal.params)?;
    let name = format!(
        "{}-{}",
        s.cell.robot_model,
        s.cell.robot_serial.as_deref().unwrap_or("calibrated")
    );
    let urdf = deploy::urdf(&model, &name, &s.dataset_hashes());
    write_atomic(&ddir.join("robot.urdf"), urdf.as_bytes())?;
    s.deploy = vec!["deploy/calibration.json".into(), "deploy/robot.urdf".into()];
    // Each artifact on its own: the calibration file through `robocal predict` (geometry +
    // effects: the "after" above) and the URDF (the same geometry, no effects).
    let urdf_pred: Vec<_> = obs.iter().map(|o| model.measured_point(&o.q)).collect();
    let mut effects: Vec<&str> = s.effects.iter().map(|e| e.kind.as_str()).collect();
    effects.sort_unstable();
    effects.dedup();
    let cal_contains = if effects.is_empty() {
        "calibrated geometry".to_string()
    } else {
        format!("calibrated geometry + {}", effects.join(", "))
    };
    s.deploy_accuracy = deploy_score::score(
        s,
        &meas,
        &[
            deploy_score::Candidate {
                artifact: "deploy/calibration.json",
                contains: cal_contains,
                how: "applied by `robocal predict` / `correct`",
                predicted: &pred_after,
            },
            deploy_score::Candidate {
                artifact: "deploy/robot.urdf",
                contains: "geometry only, fitted without effects".into(),
                how: "loaded by ROS / the navigation software in place of the nominal model",
                predicted: &urdf_pred,
            },
        ],
    );
    for a in s.deploy_accuracy.iter().filter(|a| !a.passes) {
        s.warnings.push(format!(
            "{} alone fails the spec: held-out RMS {:.4} mm ({})",
            a.artifact,
            a.heldout_rms_mm,
            a.fails.join("; ")
        ));
    }
    Ok(())
}

#[cfg(test)]
mod effects_in_words_tests {
    use super::*;
    use crate::diagnose::effects::{registry_examples, EffectModel};

    /// Every effect of the registry, as a diagnosis writes it, is said in plain words with
    /// its size (never the generic `effect <kind>`, no parameter identifiers), and so is
    /// every camera and laser finding kind.
    #[test]
    fn every_effect_kind_is_said_in_plain_words() {
        let model = KinematicModel::preset("denso-vs060").unwrap();
        for e in registry_examples(&model) {
            let st = crate::schema::DiagnosedEffect {
                kind: e.block.kind().into(),
                joint: e.block.joint(),
                label: e.block.label(),
                parameters: e.parameters(),
                evidence: Default::default(),
                train_rms_mm_before: None,
                train_rms_mm_after: None,
                heldout_rms_mm_before: None,
                heldout_rms_mm_after: None,
                train_rms_px_before: None,
                train_rms_px_after: None,
                heldout_rms_px_before: None,
                heldout_rms_px_after: None,
                hand_eye_change_mm: None,
                hand_eye_change_deg: None,
                calibration: e.to_cal(),
            };
            let (what, coefs) = what_was_found(&st);
            assert!(coefs.is_empty(), "{}: {coefs:?}", st.kind);
            assert!(!what.starts_with("effect "), "{}: {what}", st.kind);
            assert!(
                !what.contains('_') && !what.contains('@'),
                "{}: {what}",
                st.kind
            );
            assert!(
                what.chars().any(|c| c.is_ascii_digit()),
                "{}: {what}",
                st.kind
            );
        }
        for kind in [
            "target_scale",
            "target_flatness",
            "arm_kinematics",
            "distortion",
            "laser_scale",
            "laser_incidence",
            "laser_nonlinearity",
        ] {
            let w = sensor_effect_in_words(kind);
            assert!(!w.starts_with("effect ") && !w.contains('_'), "{kind}: {w}");
        }
    }
}
