//! `robocal session`: a whole calibration session in one command (see [`crate::session`]).
//!
//! ```text
//! robocal session --sim SCENARIO.toml --out DIR [--arm NAME] [--accept ACCEPT.toml]   # dry run
//! robocal session --devices CELL.toml --live [--yes] --out DIR                          # hardware
//! robocal session --resume DIR                                                          # continue
//! robocal session --sim SCENARIO.toml --out DIR --plan-only                            # plan only
//! ```
//! Exit code: 0 PASS (or `--plan-only` done), 2 FAIL / INCOMPLETE, 1 error.
//! This adapter reads the cell file into a [`CellDescription`] and supplies the devices: the
//! acquisition is `robocal run`'s (same run directories, same safety wrappers, same resume).
use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _};

use crate::acquire::RunSummary;
use crate::session::{self, Mode, SessionKind, SessionSetup};

/// Arguments of `robocal session`.
#[derive(Debug, Clone, clap::Args)]
#[command(group(clap::ArgGroup::new("live_target").args(["devices", "resume"])))]
pub struct Args {
    /// Dry run against the simulated cell of this scenario.
    #[arg(long, value_name = "SCENARIO.toml", conflicts_with_all = ["devices", "live", "resume"])]
    pub sim: Option<PathBuf>,
    /// Real hardware described by this device file (needs --live).
    #[arg(long, value_name = "CELL.toml", conflicts_with = "resume")]
    pub devices: Option<PathBuf>,
    /// Allow real motion. Nothing moves on hardware without it: a live session needs it
    /// when it starts (with --devices) and again on every --resume that still moves the arm.
    #[arg(long, requires = "live_target")]
    pub live: bool,
    /// Do not ask for confirmation before moving real hardware (the plan, its warnings and
    /// the workspace are still printed before the first move).
    #[arg(long)]
    pub yes: bool,
    /// The session directory to create.
    #[arg(long, value_name = "DIR", required_unless_present = "resume")]
    pub out: Option<PathBuf>,
    /// Continue the session in this directory at whichever stage stopped.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["out", "spec", "accept", "plan_only"])]
    pub resume: Option<PathBuf>,
    /// Stop after planning (plans, summaries, URScript / PacScript in DIR/plan/).
    #[arg(long)]
    pub plan_only: bool,
    /// Acceptance criteria (strict TOML, see accept/*.toml); default accept/surgical.toml.
    #[arg(long, value_name = "ACCEPT.toml")]
    pub accept: Option<PathBuf>,
    /// Plan spec (default plans/seed001-annulus.toml); the cell file's geometry replaces its
    /// tracker and tool.
    #[arg(long, value_name = "SPEC.toml")]
    pub spec: Option<PathBuf>,
    /// Which arm of a multi-arm scenario (default: the first).
    #[arg(long, value_name = "NAME")]
    pub arm: Option<String>,
    /// Training poses kept (greedy D-optimal selection); camera cells: training viewpoints
    /// on the seed 004 shell; RCM cells: pivots about the trocar [default: 120; camera and RCM
    /// cells 24].
    #[arg(long)]
    pub poses: Option<usize>,
    /// Held-out validation points (separate plan, another seed); camera cells: held-out
    /// viewpoints; RCM cells: held-out pivots [default: 40; camera and RCM cells 12].
    #[arg(long)]
    pub heldout_points: Option<usize>,
    /// Tracker frames averaged per pose.
    #[arg(long, default_value_t = 30)]
    pub frames: usize,
    /// Joint speed cap (deg/s).
    #[arg(long, default_value_t = 60.0)]
    pub speed_deg_s: f64,
    /// Joint acceleration cap (deg/s²).
    #[arg(long, default_value_t = 120.0)]
    pub accel_deg_s2: f64,
    /// Operator's note for the report.
    #[arg(long, value_name = "TEXT")]
    pub note: Option<String>,
    /// Dry run with in-process simulated devices instead of the wire protocols (faster).
    #[arg(long)]
    pub in_process: bool,
    /// Fleet history to record the session in: a SQLite file or a postgres:// URL (default:
    /// $ROBOCAL_DB, else robocal-history.sqlite).
    #[arg(long, value_name = "LOC")]
    pub history: Option<String>,
    /// Do not record the session in the fleet history.
    #[arg(long, conflicts_with = "history")]
    pub no_history: bool,
    /// What the session calibrates: `kinematic` (tracker), `camera` (board images), `laser`
    /// (range sensor on calibration planes, seed 000) or `rcm` (endoscope hand-eye from an
    /// instrument pivoting about a trocar, seed 002) [default: from the cell: kinematic with a
    /// tracker, else rcm with an instrument and a fixed camera, else camera].
    #[arg(long, value_name = "KIND", value_parser = ["kinematic", "camera", "laser", "rcm"])]
    pub kind: Option<String>,
    /// Laser sessions: the arm's kinematic calibration of the same visit (a kinematic
    /// session's `deploy/calibration.json`): the laser spots go through the identified arm.
    #[arg(long, value_name = "CAL.json")]
    pub arm_calibration: Option<PathBuf>,
    /// Before planning, locate the tracker (and the marker on the flange) with a few safe
    /// probe poses that face the tracker's stated position; the plan then uses the surveyed
    /// pose. For a device file whose `tracker_in_base` is rough or missing (kinematic
    /// sessions; the probe poses are shown and confirmed like the plan).
    #[arg(long, conflicts_with = "resume")]
    pub survey: bool,
    /// Close a kinematic session with seed 003's correction network: trained on the
    /// training poses on top of the geometric calibration, scored on the held-out poses beside
    /// the physical diagnosis (report, `navchain/calibration.json`).
    #[arg(long, conflicts_with = "resume")]
    pub navchain: bool,
    /// Camera sessions (seed 004): before planning, the operator guides the arm by hand to N
    /// poses (4: the seed's) where the camera sees the whole board; their images locate the
    /// board in the base and the shell of viewpoints is centred on it. Nothing is commanded.
    #[arg(long, value_name = "N", conflicts_with = "resume")]
    pub teach_board: Option<usize>,
    /// Print session.json on stdout at the end.
    #[arg(long)]
    pub json: bool,
    /// End with the navigation-chain report (seed 003) for these CT targets
    /// (`name,x_mm,y_mm,z_mm`): the predicted tool-tip error at each target and each link's
    /// share, the calibrated robot's link being its measured held-out error; written to
    /// `DIR/chain.json`. Needs `--chain-registration` and `--chain-robot-world`.
    #[arg(long, value_name = "T.csv", requires_all = ["chain_registration", "chain_robot_world"])]
    pub chain_targets: Option<PathBuf>,
    /// CT → tracker registration for the chain (`robocal register`).
    #[arg(long, value_name = "registration.json", requires = "chain_targets")]
    pub chain_registration: Option<PathBuf>,
    /// Tracker → robot base for the chain (`robocal calibrate robot-world`).
    #[arg(long, value_name = "robot_world.json", requires = "chain_targets")]
    pub chain_robot_world: Option<PathBuf>,
    /// Tool-tip offset σ for the chain (mm; from the pivot calibration).
    #[arg(long, value_name = "MM", default_value_t = 0.0)]
    pub chain_tool_sigma_mm: f64,
    /// Joints (deg, comma-separated) where the robot reaches the chain's targets: the robot
    /// link (the calibration's bootstrap covariance) is propagated there (default: the
    /// held-out pose nearest the targets).
    #[arg(
        long,
        value_name = "Q1,Q2,...",
        value_delimiter = ',',
        allow_hyphen_values = true,
        requires = "chain_targets"
    )]
    pub chain_joints_deg: Option<Vec<f64>>,
}

/// The session's closing chain report (`--chain-targets`): the robot link is the session's
/// calibration with its bootstrap covariance ([`session::navchain::chain_robot_link`]); writes
/// `DIR/chain.json` and returns the text to print.
fn chain_stage(a: &Args, dir: &std::path::Path) -> anyhow::Result<Option<String>> {
    let (Some(targets), Some(reg), Some(rw)) = (
        &a.chain_targets,
        &a.chain_registration,
        &a.chain_robot_world,
    ) else {
        return Ok(None);
    };
    let s = session::SessionFile::load(&dir.join("session.json"))?;
    if !s
        .measured
        .heldout_rms_mm_after
        .is_some_and(|r| r.is_finite())
    {
        bail!(
            "the chain report needs the session's held-out RMS (validation stage): none measured"
        );
    }
    let link =
        session::navchain::chain_robot_link(dir, reg, rw, targets, a.chain_joints_deg.as_deref())?;
    let files = crate::navchain::ChainFiles {
        registration: reg,
        robot_world: rw,
        targets,
        robot: crate::navchain::RobotLinkSource::Calibration {
            path: &link.calibration,
            joints_deg: &link.joints_deg,
        },
        tool_sigma_mm: a.chain_tool_sigma_mm,
    };
    let mut notes = link.notes;
    let r = crate::navchain::chain_from_files(&files, 20_000, 1, &mut notes)
        .context("the session's chain report")?;
    let out = dir.join("chain.json");
    r.save(&out)
        .with_context(|| format!("writing {}", out.display()))?;
    let mut text = String::from("chain report (CT target → tool tip):\n");
    for n in &notes {
        text += &format!("  {n}\n");
    }
    text += &crate::navchain::report_text(&r);
    text += &format!("chain: {}\n", out.display());
    Ok(Some(text))
}

/// The devices of the session: `robocal run`'s acquisition on the session's cell file copy.
struct RunCell {
    kind: SessionKind,
    mode: Mode,
    cell_file: PathBuf,
    setup: SessionSetup,
    in_process: bool,
    /// `--yes` on this invocation.
    yes: bool,
    /// The session directory (the briefing reads its plans).
    dir: PathBuf,
    /// Live: what the operator consented to in this invocation (asked before the first move
    /// of the survey's probe poses, and again once the calibration plan is made):
    /// `Some(true)` the calibration plan, `Some(false)` the survey only.
    consented: Option<bool>,
    /// The accept spec's limit on skipped poses (the acquisition stops early past it).
    skipped_fraction_max: Option<f64>,
}

impl RunCell {
    /// Live sessions: after the plan, before the first move of this invocation, show what will
    /// happen (poses left, duration, workspace, lowest flange height, speed cap, every plan
    /// warning) and ask for a typed `yes` (or take `--yes`).
    fn consent(&mut self) -> anyhow::Result<()> {
        let planned = self.dir.join("plan").join("train.json").is_file();
        if self.mode != Mode::Live || self.consented == Some(planned) {
            return Ok(());
        }
        let s = session::SessionFile::load(&self.dir.join("session.json"))?;
        // The device file copy is checked again (it is a file a user can edit).
        crate::acquire::device_check::check_file(&self.cell_file)?.require_valid()?;
        // On stderr, with the progress: stdout starts with the verdict.
        eprint!("{}", session::briefing::text(&self.dir, &s)?);
        crate::cell::safety::ask_yes(
            self.yes,
            "move the arm",
            &format!(
                "re-run with --yes to move the hardware (`{}`)",
                resume_hint(&self.dir)
            ),
            "nothing moved",
        )?;
        if self.yes {
            eprintln!("--yes: moving the arm");
        }
        self.consented = Some(planned);
        Ok(())
    }
}

/// The command that continues a live session.
fn resume_hint(dir: &Path) -> String {
    format!("robocal session --resume {} --live --yes", dir.display())
}

impl session::Cell for RunCell {
    fn acquire(&mut self, plan: &Path, run_dir: &Path) -> anyhow::Result<RunSummary> {
        self.run_plan(plan, run_dir, self.skipped_fraction_max)
    }

    fn acquire_probes(&mut self, plan: &Path, run_dir: &Path) -> anyhow::Result<RunSummary> {
        self.run_plan(plan, run_dir, None)
    }

    fn teach_views(
        &mut self,
        count: usize,
        log: session::Log,
    ) -> anyhow::Result<Vec<session::teach::TaughtView>> {
        let live = self.mode == Mode::Live;
        let consent = live
            .then(|| {
                crate::cell::confirm_live(true, self.yes, "teach: robocal reads the arm's joints and the camera while you guide the arm by hand (nothing is commanded)")
            })
            .transpose()?;
        let mode = if live { "live" } else { "sim" };
        session::teach::capture_views(
            mode,
            &self.cell_file,
            count,
            self.in_process,
            consent.as_ref(),
            log,
        )
    }
}

impl RunCell {
    /// `robocal run`'s acquisition of `plan` into `run_dir` (consent first, when live),
    /// stopping early once `max_skipped_fraction` of the poses are skipped.
    fn run_plan(
        &mut self,
        plan: &Path,
        run_dir: &Path,
        max_skipped_fraction: Option<f64>,
    ) -> anyhow::Result<RunSummary> {
        self.consent()?;
        let resume = run_dir.join("run.json").is_file();
        let live = self.mode == Mode::Live;
        let req = crate::cell::RunRequest {
            start: if resume {
                crate::cell::RunStart::Resume(run_dir.to_path_buf())
            } else {
                crate::cell::RunStart::New {
                    plan: plan.to_path_buf(),
                    sim: (!live).then(|| self.cell_file.clone()),
                    devices: live.then(|| self.cell_file.clone()),
                    out: run_dir.to_path_buf(),
                }
            },
            // Consent was given above, in this invocation (with --live on its command line).
            live,
            yes: true,
            virtual_clock: !live,
            speed_deg_s: self.setup.speed_deg_s,
            accel_deg_s2: self.setup.accel_deg_s2,
            frames: self.setup.frames,
            max_poses: None,
            // Stop early once the verdict cannot pass on skipped poses.
            max_skipped_fraction,
            in_process: self.in_process,
            // Camera sessions plan camera viewpoints (a shell): the run records an image per
            // pose by default; kinematic sessions never use the camera.
            camera: if !resume && self.kind == SessionKind::Rcm {
                // An endoscope image at every RCM pose.
                crate::cell::CameraUse::Always
            } else if !resume && self.kind != SessionKind::Camera {
                crate::cell::CameraUse::Never
            } else {
                crate::cell::CameraUse::Auto
            },
            board: None,
        };
        let out = crate::cell::run(&req, &mut super::run::Reporter::new(false))?;
        // The run's summary goes to stderr: the session's stdout starts with its verdict.
        eprint!("{}", out.summary);
        eprintln!("dataset: {}", out.dataset().display());
        out.finished()
    }
}

/// Run `robocal session`; returns the exit code (0 PASS, 2 FAIL / INCOMPLETE).
///
/// A scenario with several arms (a fleet) and no `--arm` runs one session per arm in
/// `DIR/<arm>/` and prints the fleet table (how much each robot of a fleet gains): held-out absolute and relative
/// error before / after per robot and the mean improvement (also `DIR/fleet.md`).
pub fn exec(a: Args) -> anyhow::Result<i32> {
    let fleet_dir = match (&a.sim, &a.arm, &a.resume) {
        #[cfg(not(feature = "sim"))]
        (Some(sim), None, None) => {
            return Err(crate::cell::without_simulators(&format!(
                "--sim {}",
                sim.display()
            )))
        }
        #[cfg(feature = "sim")]
        (Some(sim), None, None) => {
            let arms = crate::cell::simulated::stated_scenario(sim)?.arms;
            (arms.len() > 1).then(|| {
                (
                    a.out.clone().unwrap_or_default(),
                    arms.iter().map(|x| x.name.clone()).collect::<Vec<_>>(),
                )
            })
        }
        (None, None, Some(d)) if d.join("fleet.json").is_file() => {
            let text = crate::fsio::read_to_string(d.join("fleet.json"))?;
            let arms: Vec<String> = serde_json::from_str::<serde_json::Value>(&text)?
                .get("arms")
                .and_then(|v| serde_json::from_value(v.clone()).ok())
                .context("fleet.json: no `arms` list")?;
            Some((d.clone(), arms))
        }
        _ => None,
    };
    let Some((dir, arms)) = fleet_dir else {
        return exec_one(a);
    };
    if a.resume.is_none() {
        if dir.join("fleet.json").exists() {
            bail!(
                "{} already holds a fleet session: continue it with `robocal session --resume {}`",
                dir.display(),
                dir.display()
            );
        }
        std::fs::create_dir_all(&dir)?;
        let sim = a.sim.as_ref().expect("a fleet starts from --sim");
        std::fs::copy(sim, dir.join("fleet-scenario.toml"))
            .with_context(|| format!("copying {}", sim.display()))?;
        session::write_atomic(
            &dir.join("fleet.json"),
            serde_json::to_string_pretty(&serde_json::json!({ "arms": arms }))?.as_bytes(),
        )?;
    }
    let mut worst = 0;
    let mut done = Vec::new();
    for arm in &arms {
        let sub = dir.join(arm);
        eprintln!("==> fleet: arm {arm} in {}", sub.display());
        let mut b = a.clone();
        if sub.join("session.json").is_file() {
            b.resume = Some(sub.clone());
            b.sim = None;
            b.out = None;
        } else {
            b.resume = None;
            b.out = Some(sub.clone());
            b.arm = Some(arm.clone());
            b.sim = Some(dir.join("fleet-scenario.toml"));
        }
        let code = exec_one(b)?;
        worst = worst.max(code);
        done.push(session::SessionFile::load(&sub.join("session.json"))?);
    }
    let mut table = fleet_table(&done);
    table.push_str(&session::verify::fleet_table(&done));
    print!("{table}");
    session::write_atomic(&dir.join("fleet.md"), table.as_bytes())?;
    Ok(worst)
}

/// The fleet table (the same calibration judged on every robot): per robot, held-out RMS and relative distance error before /
/// after and their improvement; the mean improvement last.
pub fn fleet_table(sessions: &[session::SessionFile]) -> String {
    use std::fmt::Write as _;
    let mut t = String::from(
        "| robot | verdict | held-out RMS before → after (mm) | improvement | relative distance before → after (%) | improvement |\n|---|---|---|---|---|---|\n",
    );
    let imp = |b: Option<f64>, a: Option<f64>| match (b, a) {
        (Some(b), Some(a)) if b > 0.0 => Some((b - a) / b * 100.0),
        _ => None,
    };
    let f = |v: Option<f64>, p: usize| v.map_or("—".into(), |x| format!("{x:.p$}"));
    let (mut ia, mut ir) = (Vec::new(), Vec::new());
    for s in sessions {
        let m = &s.measured;
        let a = imp(m.heldout_rms_mm_before, m.heldout_rms_mm_after);
        let r = imp(
            m.relative_distance_pct_before,
            m.relative_distance_pct_after,
        );
        ia.extend(a);
        ir.extend(r);
        let _ = writeln!(
            t,
            "| {} | {} | {} → {} | {} % | {} → {} | {} % |",
            s.cell.robot_serial.as_deref().unwrap_or("?"),
            s.verdict,
            f(m.heldout_rms_mm_before, 3),
            f(m.heldout_rms_mm_after, 3),
            f(a, 1),
            f(m.relative_distance_pct_before, 3),
            f(m.relative_distance_pct_after, 3),
            f(r, 1)
        );
    }
    let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    let _ = writeln!(
        t,
        "| mean | | | {} % | | {} % |",
        f(mean(&ia), 1),
        f(mean(&ir), 1)
    );
    t
}

/// The options used only after the acquisition (fleet history, chain files), checked before
/// anything is created or moves: a bad `--history` or `--chain-registration`
/// found after an hour of acquisition leaves a session without a verdict line.
fn check_late_options(a: &Args) -> anyhow::Result<()> {
    if !a.no_history {
        let loc = crate::session::history::location(a.history.as_deref());
        crate::session::history::check_location(&loc)
            .with_context(|| format!("the fleet history {loc} (--history / ROBOCAL_DB)"))?;
    }
    anyhow::ensure!(
        a.chain_tool_sigma_mm.is_finite() && a.chain_tool_sigma_mm >= 0.0,
        "--chain-tool-sigma-mm {}: a finite number ≥ 0 (mm)",
        a.chain_tool_sigma_mm
    );
    if let (Some(targets), Some(reg), Some(rw)) = (
        &a.chain_targets,
        &a.chain_registration,
        &a.chain_robot_world,
    ) {
        // Read and check every chain file now, exactly as the closing stage will.
        let files = crate::navchain::ChainFiles {
            registration: reg,
            robot_world: rw,
            targets,
            robot: crate::navchain::RobotLinkSource::SigmaMm(0.0),
            tool_sigma_mm: a.chain_tool_sigma_mm,
        };
        crate::navchain::chain_from_files(&files, 1, 1, &mut Vec::new())
            .context("checking the chain files (--chain-*) before the session starts")?;
    }
    Ok(())
}

/// The session-creating options of the command line.
fn start_options(a: &Args) -> session::start::StartOptions {
    session::start::StartOptions {
        sim: a.sim.clone(),
        devices: a.devices.clone(),
        live: a.live,
        out: a.out.clone(),
        plan_only: a.plan_only,
        accept: a.accept.clone(),
        spec: a.spec.clone(),
        arm: a.arm.clone(),
        poses: a.poses,
        heldout_points: a.heldout_points,
        frames: a.frames,
        speed_deg_s: a.speed_deg_s,
        accel_deg_s2: a.accel_deg_s2,
        note: a.note.clone(),
        kind: a.kind.clone(),
        arm_calibration: a.arm_calibration.clone(),
        survey: a.survey,
        navchain: a.navchain,
        teach_board: a.teach_board,
    }
}

fn exec_one(a: Args) -> anyhow::Result<i32> {
    check_late_options(&a)?;
    let dir = match &a.resume {
        Some(d) => d.clone(),
        None => session::start::start(&start_options(&a))?.0,
    };
    let s0 = session::SessionFile::load(&dir.join("session.json"))?;
    // The verify stage commands the arm too.
    let acquired = [
        session::Stage::AcquireTrain,
        session::Stage::AcquireValidation,
        session::Stage::Verify,
    ]
    .iter()
    .all(|st| s0.stages_done.contains(st));
    let moves = !(s0.setup.plan_only || acquired);
    match s0.setup.mode {
        Mode::Live if moves && !a.live => bail!(
            "{} is a live session with poses left to acquire: nothing moves without --live \
             (continue with `{}`)",
            dir.display(),
            resume_hint(&dir)
        ),
        Mode::Sim if a.live => bail!(
            "--live: {} is a dry run on the simulated cell; resume it without --live",
            dir.display()
        ),
        _ => {}
    }
    let mut cell = RunCell {
        kind: s0.setup.kind,
        mode: s0.setup.mode,
        cell_file: dir.join(&s0.setup.cell_file),
        setup: s0.setup.clone(),
        in_process: a.in_process,
        yes: a.yes,
        dir: dir.clone(),
        consented: None,
        skipped_fraction_max: s0.accept.skipped_fraction_max,
    };
    let mut log = |m: &str| eprintln!("==> {m}");
    let s = session::run(&dir, &mut cell, &mut log)?;
    if !s.setup.plan_only && !a.no_history {
        let loc = crate::session::history::location(a.history.as_deref());
        let mut h = crate::session::history::History::open(&loc)
            .with_context(|| format!("opening the history {loc}"))?;
        h.record(&s)
            .with_context(|| format!("recording the session in {loc}"))?;
        eprintln!("==> recorded in the fleet history {loc}");
    }
    let chain = if s.setup.plan_only {
        None
    } else {
        chain_stage(&a, &dir)?
    };
    print_result(&a, &s, &dir, chain.as_deref())?;
    Ok(if s.setup.plan_only {
        0
    } else {
        s.judgement.as_ref().map_or(2, |j| j.exit_code())
    })
}

/// What a session prints at its end: the verdict line first (or the plan written), the
/// figures, every WORSE line, what to deploy, the report, the chain report.
fn print_result(
    a: &Args,
    s: &session::SessionFile,
    dir: &Path,
    chain: Option<&str>,
) -> anyhow::Result<()> {
    if a.json {
        println!("{}", serde_json::to_string_pretty(s)?);
    } else if s.setup.plan_only {
        // Nothing was to be judged: no verdict line, exit 0.
        println!(
            "plan written: {} ({} poses planned; acquisition {:.0} s predicted)",
            dir.join("plan").display(),
            s.poses_planned,
            s.predicted_duration_s
        );
        for w in &s.warnings {
            println!("WARNING: {w}");
        }
    } else {
        println!("{}", s.verdict_line);
        println!(
            "poses: {} planned, {} skipped; acquisition {:.0} s predicted, {} measured",
            s.poses_planned,
            s.poses_skipped,
            s.predicted_duration_s,
            s.duration_s.map_or("—".into(), |d| format!("{d:.0} s"))
        );
        let f = |v: Option<f64>| v.map_or("—".into(), |x| format!("{x:.4}"));
        if let Some(c) = &s.camera {
            let b = c.diagnosed.as_ref().unwrap_or(&c.calibrated);
            let (x, sd) = (
                b.hand_eye.xyz_mm,
                b.hand_eye.std_mm.unwrap_or([f64::NAN; 3]),
            );
            println!(
                "camera: {} training + {} held-out views; held-out reprojection RMS {} px (calibration) → {} px (diagnosed); hand-eye xyz [{:.3}, {:.3}, {:.3}] ± [{:.3}, {:.3}, {:.3}] mm (1σ); fx {:.2} fy {:.2} px",
                c.views_train,
                c.views_heldout,
                f(s.measured.heldout_reprojection_px_before),
                f(s.measured.heldout_reprojection_px_after),
                x[0],
                x[1],
                x[2],
                sd[0],
                sd[1],
                sd[2],
                b.intrinsics.fx,
                b.intrinsics.fy
            );
        } else if let Some(l) = &s.laser {
            for line in session::laser::lines(l, &s.measured) {
                println!("{line}");
            }
        } else if let Some(r) = &s.rcm {
            for line in session::rcm::lines(r, &s.measured) {
                println!("{line}");
            }
        } else {
            println!(
                "held-out RMS {} → {} mm, max {} → {} mm, relative distance {} → {} %",
                f(s.measured.heldout_rms_mm_before),
                f(s.measured.heldout_rms_mm_after),
                f(s.measured.heldout_max_mm_before),
                f(s.measured.heldout_max_mm_after),
                f(s.measured.relative_distance_pct_before),
                f(s.measured.relative_distance_pct_after)
            );
            if let Some(v) = &s.verify {
                println!("{}", session::verify::line(v));
            }
            if let Some(n) = &s.navchain {
                println!("{}", session::navchain::text(n));
            }
        }
        for w in s.judgement.iter().flat_map(|j| j.worse.iter()) {
            println!("WORSE: {w}");
        }
        // What to deploy, each file with the accuracy it delivers alone (the verdict is the
        // diagnosed model's).
        for l in session::deploy_score::lines(s) {
            println!("{l}");
        }
        println!("report: {}", dir.join("report.html").display());
        if let Some(c) = chain {
            print!("{c}");
        }
    }
    Ok(())
}
