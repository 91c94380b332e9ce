//! The live cell: real drivers connected to the hardware named in a device file
//! (`robocal run --devices DEVICES.toml --live`). Read-only until the engine moves the arm,
//! and every motion then goes through the safety decorators `robocal run` wraps around the arm.

use anyhow::{bail, Context as _};
use std::path::Path;
use std::sync::Arc;

use crate::acquire::devices::{DeviceEntry, DevicesFile, Protocol, Role};
use crate::acquire::Devices;
use robocal_drivers::bcap::{DensoArm, DensoConfig};
use robocal_drivers::keyence::{Il600, Il600Config, KeyenceClient, KeyenceConfig};
use robocal_drivers::ndi::{NdiConfig, NdiTracker, ReplyMode};
use robocal_drivers::ur::{UrArm, UrConfig};
use robocal_drivers::{Arm, Clock, ImageSource, MarkerTracker, RangeSensor, SystemClock};

fn first(file: &DevicesFile, role: Role) -> Option<&DeviceEntry> {
    file.devices.iter().find(|d| d.role == role)
}

fn tool_roms(d: &DeviceEntry, base: &Path) -> anyhow::Result<Vec<(String, Vec<u8>)>> {
    Ok(crate::acquire::device_check::tool_roms(d, base)?
        .into_iter()
        .map(|r| (r.name, r.bytes))
        .collect())
}

/// Open the camera of device entry `c`: `pgm-folder` → [`FolderSource`] over `path`
/// (relative to the device file), `opencv` → an OpenCV `VideoCapture` on `address` (feature
/// `opencv`).
///
/// [`FolderSource`]: robocal_drivers::camera::FolderSource
fn open_camera(
    c: &DeviceEntry,
    base: &Path,
    clock: Arc<dyn Clock>,
) -> anyhow::Result<Arc<dyn ImageSource>> {
    Ok(match c.protocol {
        Protocol::PgmFolder => {
            let dir = base.join(c.path.as_deref().unwrap_or("."));
            let src =
                robocal_drivers::camera::FolderSource::open(&dir, false).with_context(|| {
                    format!("image folder camera {:?} at {}", c.name, dir.display())
                })?;
            Arc::new(src.with_clock(clock))
        }
        #[cfg(feature = "opencv")]
        Protocol::Opencv => {
            use robocal_drivers::camera::opencv::{CaptureConfig, VideoCaptureSource};
            let target = c.address.clone().unwrap_or_else(|| c.target());
            Arc::new(
                VideoCaptureSource::open_with_clock(CaptureConfig::new(target.clone()), clock)
                    .with_context(|| format!("OpenCV camera {:?} at {target}", c.name))?,
            )
        }
        #[cfg(not(feature = "opencv"))]
        Protocol::Opencv => bail!(
            "device {:?}: protocol opencv needs a robocal built with OpenCV: rebuild with \
             `cargo build --release --features opencv` (needs libopencv-dev clang libclang-dev), \
             or record with protocol pgm-folder",
            c.name
        ),
        other => bail!("device {:?}: protocol {other:?} is not a camera", c.name),
    })
}

/// Connect the first arm, tracker and laser of the device file at `path` with the real
/// drivers, and with `camera` its first camera. The arm is NOT wrapped in the safety
/// decorators here (the caller does it).
///
/// `_consent` proves that this invocation has `--live` and the user's confirmation (or
/// `--yes`): it can only be made by [`crate::cell::confirm_live`], so no code path opens
/// the hardware for motion without them.
pub async fn live_cell(
    path: &Path,
    dof: usize,
    camera: bool,
    _consent: &crate::cell::LiveConsent,
) -> anyhow::Result<(Devices, super::CellInfo)> {
    // The same validation as `robocal devices` and the session (done before consent there;
    // repeated here because the file may have changed since).
    let checked = crate::acquire::device_check::check_file(path)?;
    checked.require_valid()?;
    let (file, base) = (&checked.file, checked.base.as_path());
    let Some(a) = first(file, Role::Arm) else {
        bail!("{}: no arm device", path.display());
    };
    let arm: Arc<dyn Arm> = match a.protocol {
        Protocol::Bcap => {
            let mut cfg = DensoConfig::new(a.target());
            cfg.name = a.name.clone();
            cfg.dof = dof;
            Arc::new(
                DensoArm::connect(cfg)
                    .await
                    .with_context(|| format!("b-CAP arm {:?} at {}", a.name, a.target()))?,
            )
        }
        Protocol::Rtde => {
            let mut cfg = UrConfig::new(a.target());
            cfg.name = a.name.clone();
            if let Some(p) = a.ports {
                cfg.rtde_port = p.rtde.unwrap_or(cfg.rtde_port);
                cfg.dashboard_port = p.dashboard.unwrap_or(cfg.dashboard_port);
                cfg.script_port = p.script.unwrap_or(cfg.script_port);
            }
            Arc::new(
                UrArm::connect(cfg)
                    .await
                    .with_context(|| format!("UR arm {:?} at {}", a.name, a.target()))?,
            )
        }
        other => bail!("device {:?}: protocol {other:?} is not an arm", a.name),
    };
    let tracker: Option<Arc<dyn MarkerTracker>> = match first(file, Role::Tracker) {
        None => None,
        Some(t) => Some(match t.protocol {
            Protocol::NdiTcp | Protocol::NdiSerial => {
                let serial = t.protocol == Protocol::NdiSerial;
                let roms = tool_roms(t, base)?;
                let (cfg, mode) = (NdiConfig::default(), ReplyMode::Binary);
                let what = || {
                    format!(
                        "NDI tracker {:?} {} {} ({} and start-up)",
                        t.name,
                        if serial { "on" } else { "at" },
                        t.target(),
                        if serial { "open" } else { "connect" }
                    )
                };
                if serial {
                    let t = NdiTracker::open_serial(&t.target(), cfg, &roms, mode).await;
                    Arc::new(t.with_context(what)?)
                } else {
                    let t = NdiTracker::connect_tcp(&t.target(), cfg, &roms, mode).await;
                    Arc::new(t.with_context(what)?)
                }
            }
            Protocol::OptotrakOapi => bail!(
                "device {:?}: the Optotrak needs NDI's OAPI library (build with --features \
                 optotrak); live acquisition through it is not wired in this build",
                t.name
            ),
            other => bail!("device {:?}: protocol {other:?} is not a tracker", t.name),
        }),
    };
    let range: Option<Arc<dyn RangeSensor>> = match first(file, Role::Laser) {
        None => None,
        Some(l) => match l.protocol {
            Protocol::DlRs1a => {
                let client = KeyenceClient::open_serial(&l.target(), KeyenceConfig::default())
                    .with_context(|| format!("KEYENCE laser {:?} on {}", l.name, l.target()))?;
                Some(Arc::new(Il600::new(client, Il600Config::default())))
            }
            other => bail!("device {:?}: protocol {other:?} is not a laser", l.name),
        },
    };
    let clock: Arc<dyn Clock> = Arc::new(SystemClock::default());
    let camera = match (camera, first(file, Role::Camera)) {
        (false, _) | (true, None) => None,
        (true, Some(c)) => Some(open_camera(c, base, clock.clone())?),
    };
    let info = super::CellInfo {
        serial: None,
        tracker_kind: first(file, Role::Tracker).and_then(|t| t.model.clone()),
        range_kind: first(file, Role::Laser).and_then(|l| l.model.clone()),
    };
    Ok((
        Devices {
            arm,
            tracker,
            range,
            clock,
            camera,
        },
        info,
    ))
}

/// A device file as a run's cell.
#[derive(Debug, Clone)]
pub struct DeviceFileCell {
    path: std::path::PathBuf,
    opts: super::OpenOptions,
}

impl DeviceFileCell {
    /// The cell of the device file at `path`.
    pub fn new(path: &Path, opts: super::OpenOptions) -> Self {
        Self {
            path: path.to_path_buf(),
            opts,
        }
    }
}

impl super::CellSource for DeviceFileCell {
    /// The device file's arm (its `model` compared only when it names a built-in preset; the
    /// `[safety]` block's table, envelope, joint limits and caps) and first camera (size from its first image) with the `[board]`.
    fn stated(&self, _arm: Option<&str>) -> anyhow::Result<super::StatedCell> {
        use crate::plausible::limits::CellLimit;
        let config = &self.path;
        let f = DevicesFile::read(config)?;
        let arm = first(&f, Role::Arm);
        // A device file's `model` is free text: compared only when it names a built-in preset.
        let model = arm
            .and_then(|d| d.model.clone())
            .filter(|m| crate::dataset::preset_dof(m.trim()).is_some());
        let name = arm.map(|d| d.name.as_str()).unwrap_or("?");
        let limit = |v: Option<f64>, k: &str| {
            v.map(|value| CellLimit {
                value,
                source: format!("{}: device \"{name}\" {k}", config.display()),
            })
        };
        // The `[safety]` block's caps, when stricter than (or instead of) the arm entry's.
        let sf = f.safety.clone().unwrap_or_default();
        let stricter = |dev: Option<CellLimit>, v: Option<f64>, k: &str| match (dev, v) {
            (Some(d), Some(v)) if d.value <= v => Some(d),
            (d, None) => d,
            (_, Some(value)) => Some(CellLimit {
                value,
                source: format!("{}: [safety] {k}", config.display()),
            }),
        };
        let camera = first(&f, Role::Camera).map(|c| super::StatedCamera {
            name: c.name.clone(),
            header: crate::dataset::CameraHeader {
                kind: "mono".into(),
                // Known from the first image.
                width: 0,
                height: 0,
                name: Some(c.name.clone()),
                mount: Some(c.mount.clone().unwrap_or_else(|| "flange".into())),
            },
            target: f.board.as_ref().map(|b| b.target()),
            // A chessboard declared in the file is detected at capture time as in dry runs.
            detect: f
                .board
                .as_ref()
                .filter(|b| b.kind == "chessboard")
                .map(|b| (b.cols, b.rows)),
        });
        Ok(super::StatedCell {
            arm: super::StatedArm {
                robot: crate::plan::recheck::CellRobot {
                    source: format!("{}: device \"{name}\"", config.display()),
                    model,
                    safety: f.safety.as_ref().map(|b| b.cell_safety()),
                },
                vel: stricter(
                    limit(arm.and_then(|d| d.max_speed_deg_s), "max_speed_deg_s"),
                    sf.max_speed_deg_s,
                    "max_speed_deg_s",
                ),
                acc: stricter(
                    limit(arm.and_then(|d| d.max_accel_deg_s2), "max_accel_deg_s2"),
                    sf.max_accel_deg_s2,
                    "max_accel_deg_s2",
                ),
            },
            camera,
        })
    }

    fn open(
        &self,
        rt: &tokio::runtime::Runtime,
        consent: Option<&super::LiveConsent>,
    ) -> anyhow::Result<super::OpenCell> {
        let Some(consent) = consent else {
            bail!("nothing moves without --live and confirmation");
        };
        let (devices, info) = rt
            .block_on(live_cell(
                &self.path,
                self.opts.dof,
                self.opts.camera,
                consent,
            ))
            .with_context(|| format!("connecting the devices of {}", self.path.display()))?;
        Ok(super::OpenCell {
            devices,
            info,
            stop: None,
        })
    }
}
