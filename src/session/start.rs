//! A new session directory from the cell file and the options (what `robocal session --sim |
//! --devices ... --out DIR` does before its first stage): the cell described, the kind of
//! session it makes, the acceptance spec and plan spec chosen and checked, every motion option
//! checked against the cell's limits, then `session.json` and the cell file copies written.
use std::path::PathBuf;

use anyhow::{bail, Context as _};

use crate::cell::describe::describe_devices;
#[cfg(feature = "sim")]
use crate::cell::describe::describe_scenario;
use crate::session::{self, AcceptSpec, Mode, SessionKind, SessionSetup};

/// The default plan spec (seed 001 annulus).
const DEFAULT_SPEC: &str = include_str!("../../plans/seed001-annulus.toml");
/// The default camera plan specs (seed 004 shell) per robot preset; the session centres the
/// shell on the cell's board.
const CAMERA_SPECS: [(&str, &str); 2] = [
    ("ur5e", include_str!("../../plans/seed004-ur5e-camera.toml")),
    (
        "denso-vs060",
        include_str!("../../plans/seed004-vs060-camera.toml"),
    ),
];
/// The default acceptance spec of a camera session.
const CAMERA_ACCEPT: &str = include_str!("../../accept/camera.toml");

/// What a new session is made of (the command line's `robocal session` options).
#[derive(Debug, Clone, Default)]
pub struct StartOptions {
    /// Dry run against the simulated cell of this scenario.
    pub sim: Option<PathBuf>,
    /// Real hardware described by this device file.
    pub devices: Option<PathBuf>,
    /// Real motion allowed on this invocation.
    pub live: bool,
    /// The session directory to create.
    pub out: Option<PathBuf>,
    /// Stop after planning.
    pub plan_only: bool,
    /// Acceptance criteria (default by session kind).
    pub accept: Option<PathBuf>,
    /// Plan spec (default by session kind).
    pub spec: Option<PathBuf>,
    /// Which arm of a multi-arm scenario.
    pub arm: Option<String>,
    /// Training poses (default 120; camera 24).
    pub poses: Option<usize>,
    /// Held-out points (default 40; camera 12).
    pub heldout_points: Option<usize>,
    /// Tracker frames averaged per pose.
    pub frames: usize,
    /// Joint speed cap (deg/s).
    pub speed_deg_s: f64,
    /// Joint acceleration cap (deg/s²).
    pub accel_deg_s2: f64,
    /// Operator's note.
    pub note: Option<String>,
    /// `kinematic`, `camera` or `laser` (default: from the cell).
    pub kind: Option<String>,
    /// Laser sessions: the arm's calibration of the same visit.
    pub arm_calibration: Option<PathBuf>,
    /// Locate the tracker with a few probe poses before planning (kinematic sessions).
    pub survey: bool,
    /// Close a kinematic session with seed 003's correction network.
    pub navchain: bool,
    /// Camera sessions: this many hand-guided poses locate the board before planning.
    pub teach_board: Option<usize>,
}

fn session_kind_name(k: SessionKind) -> &'static str {
    match k {
        SessionKind::Kinematic => "kinematic",
        SessionKind::Camera => "camera",
        SessionKind::Laser => "laser",
        SessionKind::Rcm => "rcm",
    }
}

/// Creates the session `a.out` (see the module docs); returns its directory, mode and whether
/// it stops after planning.
pub fn start(a: &StartOptions) -> anyhow::Result<(PathBuf, Mode, bool)> {
    let Some(dir) = &a.out else {
        bail!("--out DIR is required (or --resume DIR)");
    };
    let (mode, cell, cell_file, scenario_text, kind) = match (&a.sim, &a.devices) {
        #[cfg(not(feature = "sim"))]
        (Some(s), None) => {
            return Err(crate::cell::without_simulators(&format!(
                "--sim {}",
                s.display()
            )))
        }
        #[cfg(feature = "sim")]
        (Some(s), None) => {
            let arms = crate::cell::simulated::stated_scenario(s)?.arms;
            if arms.len() > 1 && a.arm.is_none() {
                eprintln!(
                    "note: {} has {} arms; this session calibrates {:?} (choose with --arm NAME)",
                    s.display(),
                    arms.len(),
                    arms[0].name
                );
            }
            let (cell, one) = describe_scenario(s, a.arm.as_deref())?;
            let arm = one.arms[0].name.clone();
            let laser = a.kind.as_deref() == Some("laser");
            let rcm = a.kind.as_deref() == Some("rcm")
                || (a.kind.is_none() && one.trackers.is_empty() && cell.endoscope.is_some());
            let kind = if laser {
                if one.lasers.is_empty() {
                    bail!(
                        "{}: arm {arm:?} carries no laser: a laser session needs a [[laser]] on it",
                        s.display(),
                    );
                }
                SessionKind::Laser
            } else if rcm {
                if cell.endoscope.is_none() {
                    bail!(
                        "{}: an RCM session needs an instrument (`[scene.instrument]`) and a \
                         camera fixed in the base (the endoscope)",
                        s.display()
                    );
                }
                SessionKind::Rcm
            } else if !one.trackers.is_empty() {
                SessionKind::Kinematic
            } else if !one.cameras.is_empty() {
                SessionKind::Camera
            } else {
                bail!(
                    "{}: arm {arm:?} has neither a tracker (kinematic session) nor a camera \
                     (camera session)",
                    s.display(),
                );
            };
            // The laser session records ranges only: the tracker and cameras stay off (a
            // marker out of view must not skip a laser pose); the RCM session records images
            // only: the tracker and lasers stay off.
            let only = if laser {
                crate::cell::simulated::Only::Ranges
            } else if kind == SessionKind::Rcm {
                crate::cell::simulated::Only::Images
            } else {
                crate::cell::simulated::Only::All
            };
            let text = crate::cell::simulated::one_arm_scenario(s, &arm, only)?;
            (Mode::Sim, cell, "scenario.toml", Some(text), kind)
        }
        (None, Some(d)) => {
            if !a.live && !a.plan_only {
                bail!(
                    "nothing moves without --live: add --live to drive {}, or use --sim SCENARIO.toml for a dry run",
                    d.display()
                );
            }
            // The same validation as `robocal devices --probe` and `run --live`, before
            // anything is created (and long before consent).
            let checked = crate::acquire::device_check::check_file(d)?;
            checked.require_valid()?;
            let (cell, kind) = describe_devices(d)?;
            let kind = if a.kind.as_deref() == Some("laser") {
                SessionKind::Laser
            } else {
                kind
            };
            let resolved =
                crate::acquire::device_check::resolved_toml(&checked.file, &checked.base)?;
            (Mode::Live, cell, "devices.toml", Some(resolved), kind)
        }
        _ => bail!("give --sim SCENARIO.toml (dry run) or --devices CELL.toml --live"),
    };
    let camera = kind == SessionKind::Camera;
    let laser = kind == SessionKind::Laser;
    let rcm = kind == SessionKind::Rcm;
    if let Some(k) = a
        .kind
        .as_deref()
        .filter(|k| !laser && *k != session_kind_name(kind))
    {
        bail!(
            "--kind {k}: the cell makes a {} session (give a cell with a {k} setup)",
            session_kind_name(kind)
        );
    }
    if a.arm_calibration.is_some() && !laser {
        bail!("--arm-calibration is for laser sessions (--kind laser)");
    }
    let accept = match &a.accept {
        Some(p) => {
            let spec = AcceptSpec::from_file(p)?;
            spec.check_kind(kind, &p.display().to_string())?;
            spec
        }
        None if camera => AcceptSpec::from_toml_str(CAMERA_ACCEPT, "accept/camera.toml")?,
        None if laser => AcceptSpec::from_toml_str(session::laser::ACCEPT, "accept/laser.toml")?,
        None if rcm => AcceptSpec::from_toml_str(session::rcm::ACCEPT, "accept/rcm.toml")?,
        None => AcceptSpec::default_surgical(),
    };
    // Every motion option against the cell's own limits before anything is created (a NaN
    // speed would be written as `null` into session.json and never resume).
    let cell_src = a
        .sim
        .as_ref()
        .or(a.devices.as_ref())
        .expect("checked above");
    crate::cell::checks::check_motion_options(
        if mode == Mode::Sim { "sim" } else { "live" },
        cell_src,
        a.arm.as_deref(),
        a.speed_deg_s,
        a.accel_deg_s2,
        a.frames,
    )?;
    let spec_text = match &a.spec {
        Some(p) => {
            crate::fsio::read_to_string(p).with_context(|| format!("reading {}", p.display()))?
        }
        None if camera => CAMERA_SPECS
            .iter()
            .find(|(m, _)| *m == cell.robot_model)
            .map(|(_, t)| t.to_string())
            .with_context(|| {
                format!(
                    "no default camera plan for robot {:?}: give --spec SPEC.toml with a [shell] \
                     (see plans/seed004-shell.toml)",
                    cell.robot_model
                )
            })?,
        None if laser => session::laser::SPEC.to_string(),
        None if rcm => session::rcm::SPEC.to_string(),
        None => DEFAULT_SPEC.to_string(),
    };
    let spec_name = a
        .spec
        .as_ref()
        .map_or("(default)".into(), |p| p.display().to_string());
    if laser {
        // One file with the planes and the five-direction plate (two plan generators).
        session::laser::parse_spec(&spec_text).with_context(|| format!("plan spec {spec_name}"))?;
    } else {
        let spec = crate::plan::PlanSpec::from_toml_str(&spec_text)
            .with_context(|| format!("plan spec {spec_name}"))?;
        if camera {
            session::camera::check_spec(&spec, &spec_name)?;
        }
        if rcm && spec.rcm.is_none() {
            bail!("plan spec {spec_name}: an RCM session needs an [rcm] table (see plans/seed002-rcm.toml)");
        }
    }
    // The arm's calibration is read (and checked against the cell's robot) before anything
    // is created.
    if let Some(c) = &a.arm_calibration {
        let cal = crate::dataset::CalibrationFile::load(c)
            .with_context(|| format!("--arm-calibration {}", c.display()))?;
        if cal.robot.model != cell.robot_model {
            bail!(
                "--arm-calibration {}: a calibration of robot {:?}, but the cell's arm is {:?}",
                c.display(),
                cal.robot.model,
                cell.robot_model
            );
        }
    }
    if a.survey {
        if kind != SessionKind::Kinematic {
            bail!(
                "--survey locates a tracker: it is for kinematic sessions (a cell with a tracker)"
            );
        }
        if mode == Mode::Live && !a.live {
            bail!("--survey moves the arm to its probe poses: add --live");
        }
    }
    if a.navchain && kind != SessionKind::Kinematic {
        bail!(
            "--navchain corrects a kinematic calibration: it is for kinematic sessions (this one \
             is {})",
            session_kind_name(kind)
        );
    }
    if let Some(n) = a.teach_board {
        if kind != SessionKind::Camera {
            bail!("--teach-board locates a camera's board: it is for camera sessions (a cell with a camera and a [board])");
        }
        if !(session::teach::MIN_POSES..=session::teach::MAX_POSES).contains(&n) {
            bail!(
                "--teach-board {n}: give {} to {} hand-guided poses (seed 004: 4)",
                session::teach::MIN_POSES,
                session::teach::MAX_POSES
            );
        }
        if mode == Mode::Live && !a.live {
            bail!("--teach-board reads the arm and the camera of the cell: add --live");
        }
    }
    let poses = a.poses.unwrap_or(if camera || rcm { 24 } else { 120 });
    let heldout_points = a
        .heldout_points
        .unwrap_or(if camera || rcm { 12 } else { 40 });
    if rcm {
        if poses < 6 || heldout_points < 4 {
            bail!("RCM session: --poses must be ≥ 6 and --heldout-points ≥ 4 (views)");
        }
    } else if camera {
        if poses < 6 || heldout_points < 3 {
            bail!("camera session: --poses must be ≥ 6 and --heldout-points ≥ 3 (views)");
        }
    } else if poses < 10 || heldout_points < 5 {
        bail!("--poses must be ≥ 10 and --heldout-points ≥ 5");
    }
    let setup = SessionSetup {
        mode,
        cell_file: cell_file.into(),
        spec_file: "spec.toml".into(),
        poses,
        heldout_points,
        frames: a.frames,
        speed_deg_s: a.speed_deg_s,
        accel_deg_s2: a.accel_deg_s2,
        operator_note: a.note.clone(),
        plan_only: a.plan_only,
        kind,
        arm_calibration: a
            .arm_calibration
            .as_ref()
            .map(|_| session::laser::ARM_CALIBRATION.to_string()),
        survey: a.survey,
        navchain: a.navchain,
        teach_board: a.teach_board.unwrap_or(0),
    };
    let src = cell_src;
    session::create(dir, setup, src, cell, &spec_text, accept)?;
    if let Some(c) = &a.arm_calibration {
        let bytes = crate::fsio::read(c).with_context(|| format!("reading {}", c.display()))?;
        session::write_atomic(&dir.join(session::laser::ARM_CALIBRATION), &bytes)?;
    }
    if let Some(text) = scenario_text {
        // The session runs on the single-arm scenario (the copy keeps the original's content
        // for the record as scenario-original.toml); a device file's copy has its tool files
        // resolved against the original's folder (devices-original.toml as given).
        let name = cell_file.trim_end_matches(".toml");
        std::fs::copy(src, dir.join(format!("{name}-original.toml")))?;
        session::write_atomic(&dir.join(cell_file), text.as_bytes())?;
    }
    Ok((dir.clone(), mode, a.plan_only))
}
