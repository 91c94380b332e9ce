//! `robocal devices --devices DEVICES.toml [--probe]`: list the devices of a device file
//! (format: [`crate::acquire::devices`]); with `--probe`, connect to each with its real driver
//! and print identity / state or the error kind. Read-only: nothing is ever moved, no
//! program is started, the arm is never taken.
use std::path::PathBuf;
use std::time::Duration;

use robocal_drivers::ErrorKind;

use crate::acquire::devices::{DeviceEntry, Protocol};

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

/// The outcome of probing one device.
#[derive(Debug, Clone, PartialEq)]
pub enum Probe {
    /// Reached: what it said.
    Ok(String),
    /// Not reached / refused: the driver's error kind and message.
    Failed(ErrorKind, String),
}

fn fail<E: robocal_drivers::DeviceError>(e: E) -> Probe {
    Probe::Failed(e.kind(), e.to_string())
}

fn deg(q: &[f64]) -> String {
    let v: Vec<String> = q.iter().map(|x| format!("{:.2}", x.to_degrees())).collect();
    format!("[{}]", v.join(", "))
}

/// Probes one device, read-only.
pub async fn probe(d: &DeviceEntry) -> Probe {
    let target = d.target();
    match d.protocol {
        Protocol::Bcap => {
            let mut cfg = robocal_drivers::bcap::DensoConfig::new(target);
            cfg.name = d.name.clone();
            match robocal_drivers::bcap::DensoArm::connect(cfg).await {
                Err(e) => fail(e),
                Ok(arm) => arm_probe(&arm).await,
            }
        }
        Protocol::Rtde => {
            let mut cfg = robocal_drivers::ur::UrConfig::new(target);
            cfg.name = d.name.clone();
            if let Some(p) = d.ports {
                cfg.rtde_port = p.rtde.unwrap_or(cfg.rtde_port);
                cfg.dashboard_port = p.dashboard.unwrap_or(cfg.dashboard_port);
                cfg.script_port = p.script.unwrap_or(cfg.script_port);
            }
            match robocal_drivers::ur::UrArm::connect(cfg).await {
                Err(e) => fail(e),
                Ok(arm) => arm_probe(&arm).await,
            }
        }
        Protocol::NdiTcp => {
            use robocal_drivers::ndi::{NdiClient, NdiConfig};
            match NdiClient::connect(&target, NdiConfig::default()).await {
                Err(e) => fail(e),
                Ok(c) => match c.version(0).await {
                    Ok(v) => Probe::Ok(format!("version: {}", v.trim().replace('\n', " | "))),
                    Err(e) => fail(e),
                },
            }
        }
        Protocol::NdiSerial => {
            use robocal_drivers::ndi::{NdiClient, NdiConfig};
            match NdiClient::open_serial(&target, NdiConfig::default()) {
                Err(e) => fail(e),
                Ok(c) => match c.version(0).await {
                    Ok(v) => Probe::Ok(format!("version: {}", v.trim().replace('\n', " | "))),
                    Err(e) => fail(e),
                },
            }
        }
        Protocol::DlRs1a => {
            use robocal_drivers::keyence::{KeyenceClient, KeyenceConfig};
            match KeyenceClient::open_serial(&target, KeyenceConfig::default()) {
                Err(e) => fail(e),
                Ok(c) => match c.read_all().await {
                    Ok(v) => Probe::Ok(format!("{} amplifier value(s): {v:?}", v.len())),
                    Err(e) => fail(e),
                },
            }
        }
        Protocol::PgmFolder => {
            match robocal_drivers::camera::FolderSource::open(std::path::Path::new(&target), false)
            {
                Ok(src) => Probe::Ok(format!("{src:?}")),
                Err(e) => fail(e),
            }
        }
        #[cfg(feature = "opencv")]
        Protocol::Opencv => {
            use robocal_drivers::camera::opencv::{CaptureConfig, VideoCaptureSource};
            use robocal_drivers::ImageSource;
            match VideoCaptureSource::open(CaptureConfig::new(target.clone())) {
                Err(e) => fail(e),
                Ok(src) => match src.grab().await {
                    Ok(img) => Probe::Ok(format!(
                        "{}×{} grey frame ({:?} mode)",
                        img.width,
                        img.height,
                        src.config().effective_mode()
                    )),
                    Err(e) => Probe::Failed(e.kind(), e.to_string()),
                },
            }
        }
        #[cfg(not(feature = "opencv"))]
        Protocol::Opencv => Probe::Failed(
            ErrorKind::Unsupported,
            "this robocal was built without OpenCV: rebuild with `cargo build --release \
             --features opencv` (needs libopencv-dev clang libclang-dev)"
                .into(),
        ),
        Protocol::OptotrakOapi => Probe::Failed(
            ErrorKind::Unsupported,
            "probing an Optotrak needs NDI's OAPI library (feature `optotrak`); not probed".into(),
        ),
    }
}

async fn arm_probe<A: robocal_drivers::Arm>(arm: &A) -> Probe {
    let state = match arm.state().await {
        Ok(s) => s,
        Err(e) => return Probe::Failed(e.kind(), e.to_string()),
    };
    match arm.joints().await {
        Ok(j) => Probe::Ok(format!(
            "mode {:?}, safety {:?}, {} joints at {} deg",
            state.mode,
            state.safety,
            j.q.len(),
            deg(&j.q)
        )),
        Err(e) => Probe::Failed(e.kind(), e.to_string()),
    }
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
    let mut listing = Vec::new();
    let rt = if args.probe {
        Some(
            tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()?,
        )
    } else {
        None
    };
    let mut failures = 0;
    for d in &file.devices {
        let role = format!("{:?}", d.role).to_lowercase();
        let proto = serde_json::to_value(d.protocol)
            .ok()
            .and_then(|v| v.as_str().map(str::to_string))
            .unwrap_or_default();
        let mut entry = serde_json::json!({
            "name": d.name, "role": role, "vendor": d.vendor, "protocol": proto,
            "target": d.target(), "model": d.model,
        });
        if !args.json {
            println!(
                "{:<12} {:<8} {:<18} {:<14} {}{}",
                d.name,
                role,
                d.vendor,
                proto,
                d.target(),
                d.model
                    .as_ref()
                    .map(|m| format!("  ({m})"))
                    .unwrap_or_default()
            );
        }
        let problems: Vec<String> = checked
            .problems_of(&d.name)
            .map(|p| p.message.clone())
            .collect();
        if !problems.is_empty() {
            // Listed with its problems; not probed, and counted as a probe failure (the
            // same device file `run --live` / `session --live` refuse before consent).
            if args.probe {
                failures += 1;
            }
            if !args.json {
                for m in &problems {
                    println!("    invalid: {m}");
                }
            }
            entry["problems"] = serde_json::json!(problems);
            if args.probe {
                entry["probe"] = serde_json::json!({"ok": false, "kind": "invalid", "message": problems.join("; ")});
            }
        } else if let Some(rt) = &rt {
            let r = rt.block_on(async {
                match tokio::time::timeout(timeout, probe(d)).await {
                    Ok(r) => r,
                    Err(_) => Probe::Failed(
                        ErrorKind::Timeout,
                        format!("no answer within {:.1} s", timeout.as_secs_f64()),
                    ),
                }
            });
            match r {
                Probe::Ok(s) => {
                    entry["probe"] = serde_json::json!({"ok": true, "message": s});
                    if !args.json {
                        println!("    ok: {s}");
                    }
                }
                Probe::Failed(kind, msg) => {
                    failures += 1;
                    entry["probe"] =
                        serde_json::json!({"ok": false, "kind": kind.to_string(), "message": msg});
                    if !args.json {
                        println!("    error ({kind}): {msg}");
                    }
                }
            }
        }
        listing.push(entry);
    }
    if let Some(sf) = &file.safety {
        if !args.json {
            println!("[safety]     {}", sf.summary());
        }
    }
    if args.json {
        println!(
            "{}",
            serde_json::json!({ "devices": listing, "safety": file.safety })
        );
    }
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
