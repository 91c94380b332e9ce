//! `robocal devices --devices DEVICES.toml [--probe]`: list the devices of a device file
//! (format: [`crate::acquire::devices`]); with `--probe`, connect to each with its real driver
//! and print identity / state or the error kind. Read-only: nothing is ever moved, no
//! program is started, the arm is never taken.
//! The work is in [`crate::acquire::probe`]; this file parses and prints.
use std::path::PathBuf;
use std::time::Duration;

use crate::acquire::probe::{probe_devices, DeviceReport, Probe};

/// Arguments of `robocal devices`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The device file (strict TOML, `[[device]]` entries).
    #[arg(long, value_name = "DEVICES.toml")]
    pub devices: PathBuf,
    /// Connect to each device (read-only) and print its identity / state or the error kind.
    #[arg(long)]
    pub probe: bool,
    /// Per-device probe deadline (s).
    #[arg(long, default_value_t = 5.0)]
    pub timeout_s: f64,
    /// One JSON object on stdout: `{"devices": [{name, role, vendor, protocol, target, model,
    /// probe: {ok, kind, message}}]}`.
    #[arg(long)]
    pub json: bool,
}

/// Run `robocal devices`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    // A NaN / negative / infinite deadline is refused, not clamped (NaN used to panic).
    let timeout = crate::plausible::limits::seconds("--timeout-s", args.timeout_s, 600.0)
        .map_err(anyhow::Error::msg)?
        .max(Duration::from_millis(100));
    // The same validation as `run --live` and `session --live` (addresses, NDI tool files
    // resolved against the device file's folder): a device with a problem is not probed.
    let checked = crate::acquire::device_check::check_file(&args.devices)?;
    let file = &checked.file;
    if file.devices.is_empty() {
        if args.json {
            println!("{}", serde_json::json!({ "devices": [] }));
        } else {
            println!("{}: no devices", args.devices.display());
        }
        return Ok(());
    }
    let json = args.json;
    let reports = probe_devices(&checked, args.probe, timeout, |r| {
        if !json {
            print_report(r);
        }
    })?;
    if let Some(sf) = &file.safety {
        if !json {
            println!("[safety]     {}", sf.summary());
        }
    }
    if args.json {
        let listing: Vec<_> = reports.iter().map(DeviceReport::to_json).collect();
        println!(
            "{}",
            serde_json::json!({ "devices": listing, "safety": file.safety })
        );
    }
    let failures = reports.iter().filter(|r| r.failed()).count();
    if failures > 0 {
        anyhow::bail!(
            "{failures} of {} devices failed the probe",
            file.devices.len()
        );
    }
    if !checked.problems.is_empty() {
        eprintln!(
            "note: {} problem(s) above: `--probe`, `run --live` and `session --live` refuse \
             this device file until they are fixed",
            checked.problems.len()
        );
    }
    Ok(())
}

/// One device: its line, its problems or its probe's outcome.
fn print_report(r: &DeviceReport) {
    println!(
        "{:<12} {:<8} {:<18} {:<14} {}{}",
        r.name,
        r.role,
        r.vendor,
        r.protocol,
        r.target,
        r.model
            .as_ref()
            .map(|m| format!("  ({m})"))
            .unwrap_or_default()
    );
    for m in &r.problems {
        println!("    invalid: {m}");
    }
    match &r.probe {
        Some(Probe::Ok(s)) => println!("    ok: {s}"),
        Some(Probe::Failed(kind, msg)) => println!("    error ({kind}): {msg}"),
        None => {}
    }
}
