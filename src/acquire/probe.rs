//! Read-only probes of a device file's devices (`robocal devices --probe`): connect to each
//! with its real driver and report identity / state or the driver's error kind. Nothing is
//! ever moved, no program is started, the arm is never taken. The CLI prints the reports.
use std::time::Duration;

use robocal_drivers::ndi::{NdiClient, NdiConfig};
use robocal_drivers::ErrorKind;

use crate::acquire::device_check::CheckedDevices;
use crate::acquire::device_safety::{check_current_joints, SafetyEntry};
use crate::acquire::devices::{DeviceEntry, Protocol};

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

/// Probes one device, read-only; an arm's current joints are checked against the device
/// file's `[safety]` block when there is one.
pub async fn probe(d: &DeviceEntry, safety: Option<&SafetyEntry>) -> Probe {
    let within = |q: &[f64]| match safety {
        Some(b) => check_current_joints(b, d.model.as_deref(), q),
        None => Ok(()),
    };
    let target = d.target();
    match d.protocol {
        Protocol::Bcap => {
            let mut cfg = robocal_drivers::bcap::DensoConfig::new(target);
            cfg.name = d.name.clone();
            match robocal_drivers::bcap::DensoArm::connect(cfg).await {
                Err(e) => fail(e),
                Ok(arm) => arm_probe(&arm, within).await,
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
                Ok(arm) => arm_probe(&arm, within).await,
            }
        }
        Protocol::NdiTcp => {
            ndi_probe(NdiClient::connect(&target, NdiConfig::default()).await).await
        }
        Protocol::NdiSerial => {
            ndi_probe(NdiClient::open_serial(&target, NdiConfig::default())).await
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

/// An NDI tracker's version reply, once connected (over TCP or a serial port).
async fn ndi_probe<T>(c: Result<NdiClient<T>, robocal_drivers::ndi::Error>) -> Probe
where
    T: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send,
{
    match c {
        Err(e) => fail(e),
        Ok(c) => match c.version(0).await {
            Ok(v) => Probe::Ok(format!("version: {}", v.trim().replace('\n', " | "))),
            Err(e) => fail(e),
        },
    }
}

async fn arm_probe<A: robocal_drivers::Arm>(
    arm: &A,
    within: impl Fn(&[f64]) -> Result<(), String>,
) -> Probe {
    let state = match arm.state().await {
        Ok(s) => s,
        Err(e) => return Probe::Failed(e.kind(), e.to_string()),
    };
    match arm.joints().await {
        Ok(j) => match within(&j.q) {
            Err(why) => Probe::Failed(
                ErrorKind::SafetyViolation,
                format!("{} joints at {} deg: {why}", j.q.len(), deg(&j.q)),
            ),
            Ok(()) => Probe::Ok(format!(
                "mode {:?}, safety {:?}, {} joints at {} deg",
                state.mode,
                state.safety,
                j.q.len(),
                deg(&j.q)
            )),
        },
        Err(e) => Probe::Failed(e.kind(), e.to_string()),
    }
}

/// One device of a device file as `robocal devices` lists it.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceReport {
    /// Name.
    pub name: String,
    /// Role (`arm`, `tracker`, ...).
    pub role: String,
    /// Vendor.
    pub vendor: String,
    /// Protocol as the file spells it.
    pub protocol: String,
    /// Address, port or path.
    pub target: String,
    /// Model preset.
    pub model: Option<String>,
    /// The device file's problems with this device (a device with problems is not probed).
    pub problems: Vec<String>,
    /// The probe's outcome (when probed and valid).
    pub probe: Option<Probe>,
    /// A probe was asked for.
    pub probed: bool,
}

impl DeviceReport {
    /// A probe was asked for and the device failed it (or was invalid).
    pub fn failed(&self) -> bool {
        self.probed && (!self.problems.is_empty() || matches!(self.probe, Some(Probe::Failed(..))))
    }

    /// The device as one entry of `robocal devices --json`.
    pub fn to_json(&self) -> serde_json::Value {
        let mut entry = serde_json::json!({
            "name": self.name, "role": self.role, "vendor": self.vendor, "protocol": self.protocol,
            "target": self.target, "model": self.model,
        });
        if !self.problems.is_empty() {
            entry["problems"] = serde_json::json!(self.problems);
            if self.probed {
                entry["probe"] = serde_json::json!({"ok": false, "kind": "invalid", "message": self.problems.join("; ")});
            }
        }
        match &self.probe {
            Some(Probe::Ok(s)) => entry["probe"] = serde_json::json!({"ok": true, "message": s}),
            Some(Probe::Failed(kind, msg)) => {
                entry["probe"] =
                    serde_json::json!({"ok": false, "kind": kind.to_string(), "message": msg})
            }
            None => {}
        }
        entry
    }
}

/// Lists (and with `probe`, probes within `timeout` each) the devices of a checked device
/// file, calling `each` on every report as it is made (a probe takes up to `timeout`).
pub fn probe_devices(
    checked: &CheckedDevices,
    probe: bool,
    timeout: Duration,
    mut each: impl FnMut(&DeviceReport),
) -> anyhow::Result<Vec<DeviceReport>> {
    let rt = if probe {
        Some(
            tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()?,
        )
    } else {
        None
    };
    let mut out = Vec::new();
    for d in &checked.file.devices {
        let problems: Vec<String> = checked
            .problems_of(&d.name)
            .map(|p| p.message.clone())
            .collect();
        // Listed with its problems; not probed, and counted as a probe failure (the same
        // device file `run --live` / `session --live` refuse before consent).
        let outcome = match &rt {
            Some(rt) if problems.is_empty() => Some(rt.block_on(async {
                match tokio::time::timeout(timeout, self::probe(d, checked.file.safety.as_ref()))
                    .await
                {
                    Ok(r) => r,
                    Err(_) => Probe::Failed(
                        ErrorKind::Timeout,
                        format!("no answer within {:.1} s", timeout.as_secs_f64()),
                    ),
                }
            })),
            _ => None,
        };
        let report = DeviceReport {
            name: d.name.clone(),
            role: format!("{:?}", d.role).to_lowercase(),
            vendor: d.vendor.clone(),
            protocol: serde_json::to_value(d.protocol)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string))
                .unwrap_or_default(),
            target: d.target(),
            model: d.model.clone(),
            problems,
            probe: outcome,
            probed: probe,
        };
        each(&report);
        out.push(report);
    }
    Ok(out)
}
