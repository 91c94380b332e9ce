//! `robocal run`: acquire a dataset by driving the cell through a plan (argument parsing and
//! printing; the run itself is [`crate::cell::run`]).
//!
//! ```text
//! robocal run --plan PLAN.json --sim SCENARIO.toml --out RUN_DIR [--virtual-clock]   # dry run
//! robocal run --plan PLAN.json --devices DEVICES.toml --live [--yes] --out RUN_DIR     # hardware
//! robocal run --resume RUN_DIR                                                         # continue
//! ```
//! `--camera` records an image at every pose, `--no-camera` never; `--board COLSxROWS` (inner
//! corners) sets the chessboard to detect (feature `opencv`).
use std::io::IsTerminal as _;
use std::path::PathBuf;

use anyhow::bail;
use serde_json::json;

use crate::acquire::Progress;
use crate::cell::{CameraUse, RunProgress, RunRequest, RunStart};

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
    #[arg(long, value_name = "COLSxROWS", value_parser = crate::cell::parse_board, conflicts_with_all = ["no_camera", "resume"])]
    pub board: Option<(u32, u32)>,
}

/// The progress of a run on the terminal: a bar, plain lines without a terminal, or JSON
/// lines (`--json`) on stdout.
pub(crate) struct Reporter {
    json: bool,
    bar: Option<indicatif::ProgressBar>,
    /// Without a terminal: a line every `every` poses and at each skip.
    every: usize,
    /// The devices' clock is simulated (ETAs are labelled so).
    simulated: bool,
}

impl Reporter {
    /// A reporter (`json`: JSON lines on stdout); sized when the acquisition starts.
    pub(crate) fn new(json: bool) -> Reporter {
        Reporter {
            json,
            bar: None,
            every: 1,
            simulated: false,
        }
    }
}

impl RunProgress for Reporter {
    fn start(&mut self, total: usize, done: usize, simulated: bool) {
        let json = self.json;
        let bar = (!json && std::io::stderr().is_terminal()).then(|| {
            let b = indicatif::ProgressBar::new(total as u64);
            b.set_style(
                indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} poses, ETA {msg}")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            b.set_position(done as u64);
            b
        });
        self.bar = bar;
        self.every = (total / 10).max(1);
        self.simulated = simulated;
    }

    fn pose(&mut self, p: &Progress) {
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

    fn finish(&mut self) {
        if let Some(b) = &self.bar {
            b.finish();
        }
    }
}

impl Args {
    /// The run this command line asks for.
    pub fn request(&self) -> anyhow::Result<RunRequest> {
        let start = match (&self.resume, &self.plan, &self.out) {
            (Some(dir), _, _) => RunStart::Resume(dir.clone()),
            (None, Some(plan), Some(out)) => RunStart::New {
                plan: plan.clone(),
                sim: self.sim.clone(),
                devices: self.devices.clone(),
                out: out.clone(),
            },
            _ => bail!("--plan and --out are required (or --resume RUN_DIR)"),
        };
        Ok(RunRequest {
            start,
            live: self.live,
            yes: self.yes,
            virtual_clock: self.virtual_clock,
            speed_deg_s: self.speed_deg_s,
            accel_deg_s2: self.accel_deg_s2,
            frames: self.frames,
            max_poses: self.max_poses,
            max_skipped_fraction: self.max_skipped_fraction,
            in_process: self.in_process,
            camera: if self.no_camera {
                CameraUse::Never
            } else if self.camera {
                CameraUse::Always
            } else {
                CameraUse::Auto
            },
            board: self.board,
        })
    }
}

/// Run `robocal run`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let out = crate::cell::run(&args.request()?, &mut Reporter::new(args.json))?;
    if args.json {
        println!("{}", json!({ "summary": out.summary }));
    } else {
        print!("{}", out.summary);
        println!("dataset: {}", out.dataset().display());
    }
    out.finished().map(|_| ())
}
