//! The device file (`DEVICES.toml`) of a real cell: which arm, tracker, laser and camera,
//! how to reach each. Strict TOML (`deny_unknown_fields`), read by `robocal devices` (and
//! meant for `robocal run --devices`).
//!
//! ```toml
//! [[device]]
//! name = "vs060"            # unique
//! role = "arm"              # arm | tracker | laser | camera
//! vendor = "denso"          # denso | universal-robots | ndi | keyence | generic
//! protocol = "bcap"         # bcap | rtde | ndi-tcp | ndi-serial | optotrak-oapi | dl-rs1a | pgm-folder | opencv
//! address = "192.168.0.1:5007"   # host:port (bcap, ndi-tcp), host (rtde), or for opencv a
//!                                # camera index / `/dev/videoN` / stream URL / video file
//! # serial = "/dev/ttyUSB0"      # ndi-serial, dl-rs1a
//! # path = "images/"             # pgm-folder
//! # ports = { rtde = 30004, dashboard = 29999, script = 30003 }   # rtde only
//! # max_speed_deg_s = 90.0       # arms: the cell's speed limit (caps --speed-deg-s)
//! # max_accel_deg_s2 = 180.0     # arms: the cell's acceleration limit (caps --accel-deg-s2)
//! # mount = "flange"             # cameras: "flange" (eye-in-hand, default) or "base"
//! # tools = ["tools/probe.rom"]  # NDI trackers: tool definitions, relative to this file
//! # Trackers, roughly (a session plans the poses the tracker can see from it):
//! # tracker_in_base = { xyz_mm = [1700.0, 80.0, 650.0], rpy_deg = [180.0, -80.0, 0.0] }
//! # marker_on_flange = { xyz_mm = [25.0, -10.0, 110.0], rpy_deg = [0.0, 0.0, 30.0] }
//! # volume = "polaris-pyramid"   # polaris-pyramid | polaris-extended | optotrak | unbounded
//!
//! # A camera cell's calibration board (optional): written into the dataset header's `target`
//! # block by `robocal run`, and a camera session centres its shell of viewpoints on it.
//! [board]
//! kind = "chessboard"       # chessboard | charuco (then marker_mm and dictionary)
//! cols = 8                  # inner corners
//! rows = 5
//! square_mm = 30.0
//! center_mm = [-441.9, -133.3, 0.0]   # the board's centre in the robot base (sessions)
//!
//! # The cell's safety limits (optional; see `device_safety`): a plan may be stricter, never wider.
//! [safety]
//! table_z_mm = 0.0
//! table_clearance_mm = 50.0
//! envelope = { shape = "box", min = [-900.0, -900.0, 0.0], max = [900.0, 900.0, 1200.0] }
//! joint_limits_deg = [[-170, 170], [-120, 120], [-125, 155], [-270, 270], [-120, 120], [-360, 360]]
//! max_speed_deg_s = 60.0
//! ```
use std::path::Path;

use serde::{Deserialize, Serialize};

/// A device file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DevicesFile {
    /// The devices, in file order.
    #[serde(default, rename = "device")]
    pub devices: Vec<DeviceEntry>,
    /// The calibration board of a camera cell.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub board: Option<BoardEntry>,
    /// The cell's safety limits (`[safety]`: table, envelope, joint limits, speed cap).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub safety: Option<super::device_safety::SafetyEntry>,
}

/// The calibration board of a camera cell (`[board]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoardEntry {
    /// `chessboard` or `charuco`.
    #[serde(default = "chessboard")]
    pub kind: String,
    /// Inner corners per row / column.
    pub cols: u32,
    pub rows: u32,
    /// Square size (mm).
    pub square_mm: f64,
    /// ChArUco marker size (mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub marker_mm: Option<f64>,
    /// ChArUco dictionary (e.g. `DICT_4X4_50`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dictionary: Option<String>,
    /// The board's centre in the robot base (mm): where a camera session's viewpoints look.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub center_mm: Option<[f64; 3]>,
}

fn chessboard() -> String {
    "chessboard".into()
}

impl BoardEntry {
    /// The dataset header's `target` block.
    pub fn target(&self) -> crate::dataset::TargetHeader {
        crate::dataset::TargetHeader {
            kind: self.kind.clone(),
            cols: self.cols,
            rows: self.rows,
            square_mm: self.square_mm,
            marker_mm: self.marker_mm,
            dictionary: self.dictionary.clone(),
        }
    }
}

/// What a device does in the cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Role {
    /// The robot arm.
    Arm,
    /// The optical tracker.
    Tracker,
    /// The laser range sensor.
    Laser,
    /// A camera.
    Camera,
}

/// The wire protocol (and so the driver) of a device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Protocol {
    /// DENSO b-CAP over TCP.
    Bcap,
    /// Universal Robots RTDE + dashboard + script.
    Rtde,
    /// NDI API over TCP (Vega).
    NdiTcp,
    /// NDI API over a serial port (Polaris Spectra / Vicra, Aurora).
    NdiSerial,
    /// NDI Optotrak through the OAPI library.
    OptotrakOapi,
    /// KEYENCE DL-RS1A serial (IL-600 heads).
    DlRs1a,
    /// A folder of images (PGM; also PNG, JPEG, BMP, TIFF with feature `opencv`).
    #[serde(alias = "image-folder")]
    PgmFolder,
    /// An OpenCV `VideoCapture` camera or stream (feature `opencv`).
    Opencv,
}

impl Protocol {
    /// The role this protocol serves.
    pub fn role(self) -> Role {
        match self {
            Protocol::Bcap | Protocol::Rtde => Role::Arm,
            Protocol::NdiTcp | Protocol::NdiSerial | Protocol::OptotrakOapi => Role::Tracker,
            Protocol::DlRs1a => Role::Laser,
            Protocol::PgmFolder | Protocol::Opencv => Role::Camera,
        }
    }
}

/// Non-standard UR ports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UrPorts {
    /// RTDE port (30004).
    pub rtde: Option<u16>,
    /// Dashboard port (29999).
    pub dashboard: Option<u16>,
    /// Script port (30003).
    pub script: Option<u16>,
}

/// One device.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceEntry {
    /// Unique name.
    pub name: String,
    /// Role in the cell.
    pub role: Role,
    /// Vendor (free text, shown in listings).
    pub vendor: String,
    /// Protocol / driver.
    pub protocol: Protocol,
    /// Model (free text).
    #[serde(default)]
    pub model: Option<String>,
    /// `host:port` (bcap, ndi-tcp) or `host` (rtde).
    #[serde(default)]
    pub address: Option<String>,
    /// Serial device path (ndi-serial, dl-rs1a).
    #[serde(default)]
    pub serial: Option<String>,
    /// Folder (pgm-folder) or OAPI setup directory (optotrak-oapi).
    #[serde(default)]
    pub path: Option<String>,
    /// UR ports when not standard.
    #[serde(default)]
    pub ports: Option<UrPorts>,
    /// Tracker tool definitions (`.rom` files, relative to the device file), for NDI trackers.
    #[serde(default)]
    pub tools: Vec<String>,
    /// Arms: the cell's joint speed limit (deg/s); `robocal run --speed-deg-s` may not exceed it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_speed_deg_s: Option<f64>,
    /// Arms: the cell's joint acceleration limit (deg/s²); `--accel-deg-s2` may not exceed it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_accel_deg_s2: Option<f64>,
    /// Cameras: `flange` (eye-in-hand, the default) or `base` (eye-to-hand).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mount: Option<String>,
    /// Trackers: where the tracker stands in the robot base, roughly (its frame: −z looks
    /// into the measurement volume).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tracker_in_base: Option<PoseEntry>,
    /// Trackers: the marker's origin in the flange frame, roughly.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub marker_on_flange: Option<PoseEntry>,
    /// Trackers: the measurement volume (`polaris-pyramid`, `polaris-extended`, `optotrak`,
    /// `unbounded`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub volume: Option<String>,
}

/// A rough placement in a device file: translation (mm) and URDF roll-pitch-yaw (deg).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseEntry {
    /// Translation (mm).
    pub xyz_mm: [f64; 3],
    /// URDF roll-pitch-yaw (deg).
    #[serde(default)]
    pub rpy_deg: [f64; 3],
}

/// The measurement volumes a device file may name.
pub const VOLUMES: [&str; 4] = [
    "polaris-pyramid",
    "polaris-extended",
    "optotrak",
    "unbounded",
];

impl DeviceEntry {
    /// Where the device is reached, for listings.
    pub fn target(&self) -> String {
        self.address
            .clone()
            .or_else(|| self.serial.clone())
            .or_else(|| self.path.clone())
            .unwrap_or_else(|| "—".into())
    }
}

/// Errors of a device file.
#[derive(Debug, thiserror::Error)]
pub enum DevicesError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// Not valid TOML for the format.
    #[error("{path}: {message}")]
    Parse {
        /// The file.
        path: String,
        /// The parser's message.
        message: String,
    },
    /// Valid TOML, inconsistent content.
    #[error("{path}: device {device:?}: {message}")]
    Invalid {
        /// The file.
        path: String,
        /// The device name.
        device: String,
        /// What is wrong.
        message: String,
    },
}

impl DevicesFile {
    /// Parses and validates `text` (`path` only names the file in errors).
    pub fn parse(text: &str, path: &str) -> Result<Self, DevicesError> {
        let f: DevicesFile = toml::from_str(text).map_err(|e| DevicesError::Parse {
            path: path.into(),
            message: crate::schema::kind::with_toml_hint(
                &e,
                text,
                crate::schema::kind::TomlKind::DeviceFile,
            ),
        })?;
        f.validate(path)?;
        Ok(f)
    }

    /// Reads and validates a device file.
    pub fn read(path: impl AsRef<Path>) -> Result<Self, DevicesError> {
        let p = path.as_ref();
        let text = std::fs::read_to_string(p).map_err(|source| DevicesError::Io {
            path: p.display().to_string(),
            source,
        })?;
        Self::parse(&text, &p.display().to_string())
    }

    fn validate(&self, path: &str) -> Result<(), DevicesError> {
        if let Some(sf) = &self.safety {
            let arm = self.devices.iter().find(|d| d.role == Role::Arm);
            sf.validate(arm.and_then(|a| a.model.as_deref()))
                .map_err(|message| DevicesError::Invalid {
                    path: path.into(),
                    device: "[safety]".into(),
                    message,
                })?;
            if arm.is_none() {
                return Err(DevicesError::Invalid {
                    path: path.into(),
                    device: "[safety]".into(),
                    message: "a [safety] block without an arm (role = \"arm\")".into(),
                });
            }
        }
        if let Some(b) = &self.board {
            let bad = |message: String| DevicesError::Invalid {
                path: path.into(),
                device: "[board]".into(),
                message,
            };
            if b.cols < 2 || b.rows < 2 || b.cols > 200 || b.rows > 200 {
                return Err(bad(format!(
                    "cols = {}, rows = {}: the board's inner corners per row / column (2 – 200)",
                    b.cols, b.rows
                )));
            }
            if !(b.square_mm.is_finite() && b.square_mm >= 1.0 && b.square_mm <= 500.0) {
                return Err(bad(format!(
                    "square_mm = {}: the square size in millimetres (1 – 500; metres or \
                     centimetres typed?)",
                    b.square_mm
                )));
            }
            if let Some(c) = b.center_mm {
                if c.iter().any(|v| !v.is_finite() || v.abs() > 1.0e4) {
                    return Err(bad(format!(
                        "center_mm = {c:?}: the board's centre in the robot base, mm (|v| ≤ 10 m)"
                    )));
                }
            }
            crate::solve::camera::data::target_of(&b.target()).map_err(bad)?;
            if !self.devices.iter().any(|d| d.role == Role::Camera) {
                return Err(bad(
                    "a [board] without a camera device (role = \"camera\")".into()
                ));
            }
        }
        let mut names = std::collections::BTreeSet::new();
        for d in &self.devices {
            let bad = |message: String| DevicesError::Invalid {
                path: path.into(),
                device: d.name.clone(),
                message,
            };
            if d.name.trim().is_empty() {
                return Err(bad("empty name".into()));
            }
            if !names.insert(d.name.as_str()) {
                return Err(bad("name used twice".into()));
            }
            if d.protocol.role() != d.role {
                return Err(bad(format!(
                    "protocol {:?} is for role {:?}, not {:?}",
                    d.protocol,
                    d.protocol.role(),
                    d.role
                )));
            }
            let (need, field) = match d.protocol {
                Protocol::Bcap | Protocol::Rtde | Protocol::NdiTcp | Protocol::Opencv => {
                    (&d.address, "address")
                }
                Protocol::NdiSerial | Protocol::DlRs1a => (&d.serial, "serial"),
                Protocol::PgmFolder | Protocol::OptotrakOapi => (&d.path, "path"),
            };
            match need {
                Some(v) if !v.trim().is_empty() => {}
                _ => return Err(bad(format!("protocol {:?} needs `{field}`", d.protocol))),
            }
            let given = [
                ("address", d.address.is_some()),
                ("serial", d.serial.is_some()),
                ("path", d.path.is_some()),
            ];
            for (f, set) in given {
                if set && f != field {
                    return Err(bad(format!(
                        "`{f}` does not apply to protocol {:?} (give `{field}`)",
                        d.protocol
                    )));
                }
            }
            for (f, v) in [
                ("max_speed_deg_s", d.max_speed_deg_s),
                ("max_accel_deg_s2", d.max_accel_deg_s2),
            ] {
                if let Some(v) = v {
                    if d.role != Role::Arm {
                        return Err(bad(format!("`{f}` is for arms only")));
                    }
                    if !(v.is_finite() && v > 0.0 && v <= 1.0e5) {
                        return Err(bad(format!(
                            "`{f}` = {v}: a limit is a finite number > 0 (deg/s, deg/s²)"
                        )));
                    }
                }
            }
            if let Some(m) = &d.mount {
                if d.role != Role::Camera {
                    return Err(bad("`mount` is for cameras only".into()));
                }
                if m != "flange" && m != "base" {
                    return Err(bad(format!(
                        "mount = {m:?}: \"flange\" (eye-in-hand) or \"base\" (eye-to-hand)"
                    )));
                }
            }
            for (f, pose) in [
                ("tracker_in_base", d.tracker_in_base),
                ("marker_on_flange", d.marker_on_flange),
            ] {
                let Some(pose) = pose else { continue };
                if d.role != Role::Tracker {
                    return Err(bad(format!("`{f}` is for trackers only")));
                }
                let lim = if f == "tracker_in_base" { 1.0e4 } else { 1.0e3 };
                if pose.xyz_mm.iter().any(|v| !v.is_finite() || v.abs() > lim) {
                    return Err(bad(format!(
                        "{f}.xyz_mm = {:?}: millimetres, |v| ≤ {lim} (metres typed?)",
                        pose.xyz_mm
                    )));
                }
                if pose
                    .rpy_deg
                    .iter()
                    .any(|v| !v.is_finite() || v.abs() > 360.0)
                {
                    return Err(bad(format!(
                        "{f}.rpy_deg = {:?}: degrees, |v| ≤ 360",
                        pose.rpy_deg
                    )));
                }
            }
            if let Some(v) = &d.volume {
                if d.role != Role::Tracker {
                    return Err(bad("`volume` is for trackers only".into()));
                }
                if !VOLUMES.contains(&v.as_str()) {
                    return Err(bad(format!("volume = {v:?}: one of {VOLUMES:?}")));
                }
            }
            if d.ports.is_some() && d.protocol != Protocol::Rtde {
                return Err(bad("`ports` is for protocol rtde only".into()));
            }
            if matches!(d.protocol, Protocol::Bcap | Protocol::NdiTcp)
                && d.address.as_deref().is_some_and(|a| !a.contains(':'))
            {
                return Err(bad("address must be host:port".into()));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
[[device]]
name = "vs060"
role = "arm"
vendor = "denso"
protocol = "bcap"
address = "192.168.0.1:5007"

[[device]]
name = "vega"
role = "tracker"
vendor = "ndi"
protocol = "ndi-tcp"
address = "10.0.0.5:8765"

[[device]]
name = "il600"
role = "laser"
vendor = "keyence"
protocol = "dl-rs1a"
serial = "/dev/ttyUSB0"

[[device]]
name = "ur"
role = "arm"
vendor = "universal-robots"
protocol = "rtde"
address = "10.0.0.9"
ports = { rtde = 30004 }
"#;

    #[test]
    fn board_table_is_strict_and_validated() {
        let cam = "[[device]]\nname = \"cam\"\nrole = \"camera\"\nvendor = \"generic\"\n\
                   protocol = \"opencv\"\naddress = \"0\"\nmount = \"flange\"\n";
        let ok = format!(
            "{cam}\n[board]\nkind = \"charuco\"\ncols = 7\nrows = 4\nsquare_mm = 30.0\n\
             marker_mm = 22.0\ndictionary = \"DICT_4X4_50\"\ncenter_mm = [1.0, 2.0, 3.0]\n"
        );
        let f = DevicesFile::parse(&ok, "cell.toml").unwrap();
        let b = f.board.as_ref().unwrap();
        assert_eq!(b.target().kind, "charuco");
        assert_eq!(b.center_mm, Some([1.0, 2.0, 3.0]));
        assert_eq!(f.devices[0].mount.as_deref(), Some("flange"));
        let err = |t: String| DevicesFile::parse(&t, "cell.toml").unwrap_err().to_string();
        let board = "\n[board]\ncols = 8\nrows = 5\nsquare_mm = 30.0\n";
        // A board without a camera, a charuco board without its dictionary, an unknown field,
        // a bad mount, a mount on an arm.
        assert!(err(board.to_string()).contains("without a camera"));
        assert!(err(format!(
            "{cam}\n[board]\nkind = \"charuco\"\ncols = 8\nrows = 5\nsquare_mm = 30.0\n"
        ))
        .contains("cell.toml"));
        assert!(err(format!("{cam}{board}colour = 1\n")).contains("colour"));
        assert!(err(cam.replace("flange", "wrist")).contains("mount"));
        assert!(err(format!("{cam}{board}center_mm = [1.0, 2.0]\n")).contains("center_mm"));
        assert!(err(format!(
            "{cam}\n[board]\ncols = 1\nrows = 5\nsquare_mm = 30.0\n"
        ))
        .contains("inner corners"));
    }

    #[test]
    fn parses_and_rejects() {
        let f = DevicesFile::parse(GOOD, "t").unwrap();
        assert_eq!(f.devices.len(), 4);
        assert_eq!(f.devices[2].target(), "/dev/ttyUSB0");
        let cases = [
            (
                GOOD.replace("vendor = \"denso\"", "vendor = \"denso\"\nspeed = 3"),
                "unknown field",
            ),
            (GOOD.replace("name = \"vega\"", "name = \"vs060\""), "twice"),
            (
                GOOD.replace("role = \"laser\"", "role = \"arm\""),
                "is for role",
            ),
            (
                GOOD.replace("serial = \"/dev/ttyUSB0\"", ""),
                "needs `serial`",
            ),
            (GOOD.replace("10.0.0.5:8765", "10.0.0.5"), "host:port"),
            (
                GOOD.replace(
                    "serial = \"/dev/ttyUSB0\"",
                    "serial = \"/dev/x\"\naddress = \"a:1\"",
                ),
                "does not apply",
            ),
            (
                GOOD.replace("protocol = \"bcap\"", "protocol = \"modbus\""),
                "unknown variant",
            ),
        ];
        for (text, want) in cases {
            let e = DevicesFile::parse(&text, "t").unwrap_err().to_string();
            assert!(e.contains(want), "{e} (want {want})");
        }
    }
}
