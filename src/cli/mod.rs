//! Command-line interface: one file per subcommand, each a thin adapter over the library.
//!
//! Exit codes: 0 success, 1 failure, 2 usage error. Errors print with their context chain.

use clap::{Parser, Subcommand};
use std::ffi::OsString;

pub mod calibrate;
pub mod devices;
pub mod diagnose;
pub mod diagnose_camera;
pub mod inspect;
pub mod live_cell;
pub mod plan;
pub mod predict;
pub mod report;
pub mod run;
pub mod run_checks;
pub mod sim;
pub mod wire_cell;

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
    /// Generate, check and export a pose plan (never opens a device).
    Plan(plan::Args),
    /// Acquire a dataset: on real hardware with --live, or a dry run with --sim.
    Run(run::Args),
    /// Identify parameters from a dataset (nominal, kinematics, pivot, laser, ...).
    Calibrate(calibrate::Args),
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
}

/// Parse `args` and run; returns the process exit code.
pub fn run<I, T>(args: I) -> i32
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let cli = match Cli::try_parse_from(args) {
        Ok(c) => c,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return code;
        }
    };
    init_tracing();
    let result = match cli.command {
        Command::Plan(a) => plan::exec(a),
        Command::Run(a) => run::exec(a),
        Command::Calibrate(a) => calibrate::exec(a),
        Command::Diagnose(a) => diagnose::exec(a),
        Command::Predict(a) => predict::exec(a),
        Command::Report(a) => report::exec(a),
        Command::Inspect(a) => inspect::exec(a),
        Command::Sim(a) => sim::exec(a),
        Command::Devices(a) => devices::exec(a),
    };
    match result {
        Ok(()) => 0,
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
        .try_init();
}
