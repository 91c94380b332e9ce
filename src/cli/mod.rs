//! Command-line interface: one file per subcommand, each a thin adapter over the library.
//!
//! Exit codes: 0 success, 1 failure, 2 usage error. Errors print with their context chain.

use clap::{Parser, Subcommand};
use std::ffi::OsString;

pub mod calibrate;
pub mod capture;
pub mod chain;
pub mod correct;
pub mod devices;
pub mod diagnose;
pub mod history;
pub mod import;
pub mod import_handeye;
pub mod inspect;
pub mod plan;
pub mod predict;
pub mod register;
pub mod report;
pub mod run;
pub mod session;
pub mod sim;

/// robocal: plan, acquire, calibrate and diagnose a robot calibration cell.
#[derive(Debug, Parser)]
#[command(name = "robocal", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// A whole calibration session: plan, acquire, calibrate, diagnose, validate, verdict, report.
    // First in `--help`: the main command.
    Session(session::Args),
    /// Generate, check and export a pose plan (never opens a device).
    Plan(plan::Args),
    /// Acquire a dataset: on real hardware with --live, or a dry run with --sim.
    Run(run::Args),
    /// Identify parameters from a dataset (nominal, kinematics, pivot, laser, ...).
    Calibrate(calibrate::Args),
    /// Operator-guided acquisition: pivot a probe, touch fiducials, teach poses by hand.
    Capture(capture::Args),
    /// Find the physical effect the model lacks, add it, report before/after.
    Diagnose(diagnose::Args),
    /// Predict marker positions / laser spots for the pose records of a dataset.
    Predict(predict::Args),
    /// Render a report from a calibration or diagnosis directory.
    Report(report::Args),
    /// Summarise a dataset file.
    Inspect(inspect::Args),
    /// Run the simulated devices of a scenario as protocol servers.
    Sim(sim::Args),
    /// List and probe configured devices.
    Devices(devices::Args),
    /// CT ↔ tracker registration: paired fiducials or surface ICP.
    Register(register::Args),
    /// Predicted tool-tip error at CT targets and each link's share.
    Chain(chain::Args),
    /// Fleet history of one robot: accuracy and parameter drift over its sessions.
    History(history::Args),
    /// Turn measurement files (IPA layout, generic CSV) into a robocal dataset.
    Import(import::Args),
    /// Desired tool poses → corrected joint targets through the identified model's IK.
    Correct(correct::Args),
}

/// Exit code of a command line that does not parse (BSD `EX_USAGE`): distinct from 1 (error)
/// and 2 (a session's FAIL / INCOMPLETE verdict).
pub const EXIT_USAGE: i32 = 64;

/// Parse `args` and run; returns the process exit code.
pub fn run<I, T>(args: I) -> i32
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let cli = match Cli::try_parse_from(args) {
        Ok(c) => c,
        Err(e) => {
            // A usage error is not a verdict: 64 (EX_USAGE), never 2 (FAIL / INCOMPLETE).
            let code = if e.use_stderr() { EXIT_USAGE } else { 0 };
            let _ = e.print();
            return code;
        }
    };
    init_tracing();
    let result = match cli.command {
        Command::Session(a) => {
            return match session::exec(a) {
                Ok(code) => code,
                // Ctrl-C during an acquisition: the pose is durable, the session resumable.
                Err(e) if e.chain().any(|c| c.is::<crate::cell::Interrupted>()) => {
                    eprintln!("{e:#}");
                    130
                }
                Err(e) => {
                    eprintln!("error: {e:#}");
                    1
                }
            };
        }
        Command::Plan(a) => plan::exec(a),
        Command::Run(a) => run::exec(a),
        Command::Calibrate(a) => calibrate::exec(a),
        Command::Capture(a) => capture::exec(a),
        Command::Diagnose(a) => diagnose::exec(a),
        Command::Predict(a) => predict::exec(a),
        Command::Report(a) => report::exec(a),
        Command::Inspect(a) => inspect::exec(a),
        Command::Sim(a) => sim::exec(a),
        Command::Devices(a) => devices::exec(a),
        Command::Register(a) => register::exec(a),
        Command::Chain(a) => chain::exec(a),
        Command::History(a) => history::exec(a),
        Command::Import(a) => import::exec(a),
        Command::Correct(a) => correct::exec(a),
    };
    match result {
        Ok(()) => 0,
        // `robocal run` stopped by Ctrl-C after a durable record: the shell's 128 + SIGINT.
        Err(e) if e.downcast_ref::<crate::cell::Interrupted>().is_some() => {
            eprintln!("{e}");
            130
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            1
        }
    }
}

fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_env("ROBOCAL_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        // No colour codes when the log goes to a file or a pipe.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .try_init();
}
