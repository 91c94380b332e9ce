//! The simulated tracker's state machine: one command line in, reply bytes out.

use super::wire::{self, Command, CommandError, HandleOut, Record};
use crate::world::control::Fault;
use crate::world::WorldHandle;
use robocal_drivers::{MarkerToTracker, ToolObservation, ToolStatus, TrackerFrame};
use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex};

/// Where the simulated tracker's frames come from (the world's tracker model in a
/// simulation; fixed poses in unit tests). The `k`-th tool of a frame is reported on the
/// `k`-th port handle the host allocated with `PHRQ`.
pub trait TrackerSource: Send + Sync + 'static {
    /// The next frame (advances the source's time by one tracker period).
    fn tracker_frame(&self) -> TrackerFrame;
    /// The next wire fault to apply to a reply, if any.
    fn take_fault(&self) -> Option<Fault> {
        None
    }
    /// The clock that paces injected delays (the world's; `None` = tokio's wall clock).
    fn clock(&self) -> Option<Arc<dyn robocal_drivers::Clock>> {
        None
    }
}

/// Tracker `index` of a world; wire faults are those queued for device `name`.
#[derive(Clone)]
pub struct WorldTracker {
    /// The world.
    pub world: WorldHandle,
    /// Tracker index.
    pub index: usize,
    /// Device name used for fault injection (`world.control().inject(name, ..)`).
    pub name: String,
}

impl TrackerSource for WorldTracker {
    fn tracker_frame(&self) -> TrackerFrame {
        self.world.tracker_frame_of(self.index)
    }
    fn take_fault(&self) -> Option<Fault> {
        self.world.take_fault(&self.name)
    }
    fn clock(&self) -> Option<Arc<dyn robocal_drivers::Clock>> {
        Some(self.world.clock())
    }
}

/// Fixed poses, a frame counter incrementing per frame.
#[derive(Debug, Default)]
pub struct StaticTracker {
    tools: Mutex<Vec<ToolStatus>>,
    frame: Mutex<u64>,
    faults: Mutex<VecDeque<Fault>>,
}

impl StaticTracker {
    /// A source reporting `tools` in order.
    pub fn new(tools: Vec<ToolStatus>) -> Self {
        Self {
            tools: Mutex::new(tools),
            frame: Mutex::new(0),
            faults: Mutex::default(),
        }
    }
    /// Queue a one-shot wire fault.
    pub fn inject(&self, fault: Fault) {
        lock(&self.faults).push_back(fault);
    }
    /// Replace the statuses.
    pub fn set(&self, tools: Vec<ToolStatus>) {
        *lock(&self.tools) = tools;
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl TrackerSource for StaticTracker {
    fn tracker_frame(&self) -> TrackerFrame {
        let mut f = lock(&self.frame);
        *f += 1;
        TrackerFrame {
            frame_number: *f,
            t: *f as f64 / 60.0,
            tools: lock(&self.tools)
                .iter()
                .enumerate()
                .map(|(i, s)| ToolObservation {
                    tool: format!("tool{i}"),
                    status: *s,
                })
                .collect(),
        }
    }
    fn take_fault(&self) -> Option<Fault> {
        lock(&self.faults).pop_front()
    }
}

/// Simulator settings.
#[derive(Debug, Clone)]
pub struct SimNdiConfig {
    /// The `Freeze Tag:` line of `VER:0` (scikit-surgerynditracker uses `TX` for
    /// ` Polaris Vega 008` and a few others, else `BX`).
    pub freeze_tag: String,
    /// Maximum number of port handles.
    pub max_handles: usize,
}

impl Default for SimNdiConfig {
    fn default() -> Self {
        Self {
            freeze_tag: " Polaris Vega 007".into(),
            max_handles: 16,
        }
    }
}

#[derive(Debug, Clone, Default)]
struct Port {
    rom: Vec<u8>,
    /// Tool index in the source's frame (allocation order among live handles).
    tool_index: usize,
    initialized: bool,
    enabled: bool,
}

/// The device state (shared by every connection to one simulated tracker).
pub struct NdiDevice {
    source: Arc<dyn TrackerSource>,
    config: SimNdiConfig,
    initialized: bool,
    tracking: bool,
    ports: BTreeMap<u8, Port>,
    /// Every command word received, in order (for tests).
    pub log: Vec<String>,
}

impl NdiDevice {
    /// The source's clock, if it has one.
    pub fn clock(&self) -> Option<Arc<dyn robocal_drivers::Clock>> {
        self.source.clock()
    }
}

/// What the transport should do with a reply.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    /// Write these bytes in a single write.
    Send(Vec<u8>),
    /// Write nothing.
    Nothing,
    /// Serial only: after sending the OKAY, change to this baud.
    SendThenBaud(Vec<u8>, u32),
    /// Write these bytes after `f64` seconds.
    Delayed(Vec<u8>, f64),
    /// Close the link.
    Drop,
}

impl NdiDevice {
    /// A device over `source`.
    pub fn new(source: Arc<dyn TrackerSource>, config: SimNdiConfig) -> Self {
        Self {
            source,
            config,
            initialized: false,
            tracking: false,
            ports: BTreeMap::new(),
            log: Vec::new(),
        }
    }

    /// Handle one command line (without `\r`) and produce the output, with faults applied.
    pub fn handle_line(&mut self, line: &[u8]) -> Output {
        let (reply, baud) = self.reply_to(line);
        let reply = match self.source.take_fault() {
            None => reply,
            Some(Fault::DropLink) => return Output::Drop,
            Some(Fault::Silence { .. }) => return Output::Nothing,
            Some(Fault::Delay { secs }) => return Output::Delayed(reply, secs),
            Some(Fault::ErrorReply { code }) => wire::error_reply(code as u8),
            Some(Fault::Truncated) => reply[..reply.len() / 2].to_vec(),
            Some(Fault::Garbage { bytes }) => bytes,
            Some(Fault::BadCrc) => {
                let mut r = reply;
                let n = r.len();
                if r.first() == Some(&0xC4) && n >= 2 {
                    r[n - 1] ^= 0x5A;
                } else if n >= 2 {
                    // Last CRC hex digit (before `\r`): change it to another hex digit.
                    r[n - 2] = if r[n - 2] == b'0' { b'1' } else { b'0' };
                }
                r
            }
        };
        match baud {
            Some(b) => Output::SendThenBaud(reply, b),
            None => Output::Send(reply),
        }
    }

    fn reply_to(&mut self, line: &[u8]) -> (Vec<u8>, Option<u32>) {
        let cmd = match wire::parse_command(line) {
            Ok(c) => c,
            Err(CommandError::BadCrc) => return (wire::error_reply(0x04), None),
            Err(CommandError::Invalid) => return (wire::error_reply(0x01), None),
        };
        self.log.push(cmd.word.clone());
        match self.execute(&cmd) {
            Ok(Reply::Text(t)) => (wire::text_reply(&t), None),
            Ok(Reply::Binary(b)) => (wire::binary_reply(&b), None),
            Ok(Reply::OkayThenBaud(b)) => (wire::text_reply("OKAY"), Some(b)),
            Err(code) => (wire::error_reply(code), None),
        }
    }

    fn handle_param(&self, p: &str) -> Result<u8, u8> {
        let h = p
            .get(..2)
            .and_then(|s| u8::from_str_radix(s, 16).ok())
            .ok_or(0x07u8)?;
        if self.ports.contains_key(&h) {
            Ok(h)
        } else {
            Err(0x2B)
        }
    }

    fn execute(&mut self, cmd: &Command) -> Result<Reply, u8> {
        let p = cmd.params.as_str();
        let okay = || Ok(Reply::Text("OKAY".into()));
        match cmd.word.as_str() {
            "INIT" => {
                self.initialized = true;
                self.tracking = false;
                okay()
            }
            "COMM" => {
                let baud = match p.as_bytes().first() {
                    Some(b'0') => 9600,
                    Some(b'1') => 14400,
                    Some(b'2') => 19200,
                    Some(b'3') => 38400,
                    Some(b'4') => 57600,
                    Some(b'5') => 115200,
                    Some(b'6') => 921600,
                    Some(b'7') => 1228739,
                    Some(b'A') | Some(b'a') => 230400,
                    _ => return Err(0x06),
                };
                if p.len() != 5 {
                    return Err(0x07);
                }
                Ok(Reply::OkayThenBaud(baud))
            }
            "VER" => Ok(Reply::Text(format!(
                "Polaris Vega Control Firmware (simulated by robocal)\nNorthern Digital Inc.\nFreeze Tag:{}\nFreeze Date: 01/01/2024\n(C) Northern Digital Inc.\n",
                self.config.freeze_tag
            ))),
            "GETINFO" => Ok(Reply::Text(format!("{p}=1.0.0 (simulated)"))),
            "APIREV" => Ok(Reply::Text("G.001.005".into())),
            "BEEP" => Ok(Reply::Text("1".into())),
            _ if !self.initialized => Err(0x10),
            "PHSR" => {
                let which = if p.is_empty() {
                    0
                } else {
                    u8::from_str_radix(p, 16).map_err(|_| 0x07u8)?
                };
                let list: Vec<(u8, u16)> = self
                    .ports
                    .iter()
                    .filter(|(_, port)| match which {
                        0 => true,
                        1 => false,
                        2 => !port.initialized,
                        3 => port.initialized && !port.enabled,
                        4 => port.enabled,
                        _ => false,
                    })
                    .map(|(h, port)| {
                        let mut s = 0x01u16;
                        if port.initialized {
                            s |= 0x10;
                        }
                        if port.enabled {
                            s |= 0x20;
                        }
                        (*h, s)
                    })
                    .collect();
                if which > 4 {
                    return Err(0x23);
                }
                let mut s = format!("{:02X}", list.len());
                for (h, st) in list {
                    s.push_str(&format!("{h:02X}{st:03X}"));
                }
                Ok(Reply::Text(s))
            }
            "PHF" => {
                let h = self.handle_param(p)?;
                self.ports.remove(&h);
                okay()
            }
            "PHRQ" => {
                if p.len() != 14 {
                    return Err(0x07);
                }
                if self.ports.len() >= self.config.max_handles {
                    return Err(0x2D);
                }
                let h = (1u8..=255).find(|h| !self.ports.contains_key(h)).ok_or(0x2Du8)?;
                // The smallest tool index not held by a live handle (freed handles give
                // their tool back, so a reconnecting host finds the same tools again).
                let tool_index = (0..)
                    .find(|i| !self.ports.values().any(|p| p.tool_index == *i))
                    .unwrap_or(0);
                self.ports.insert(
                    h,
                    Port {
                        tool_index,
                        ..Port::default()
                    },
                );
                Ok(Reply::Text(format!("{h:02X}")))
            }
            "PVWR" => {
                if p.len() != 2 + 4 + 128 {
                    return Err(0x07);
                }
                let h = self.handle_param(p)?;
                let addr = usize::from_str_radix(&p[2..6], 16).map_err(|_| 0x07u8)?;
                if !addr.is_multiple_of(64) || addr >= 64 * 1024 {
                    return Err(0x23);
                }
                let mut data = Vec::with_capacity(64);
                for i in 0..64 {
                    let b = u8::from_str_radix(&p[6 + 2 * i..8 + 2 * i], 16).map_err(|_| 0x07u8)?;
                    data.push(b);
                }
                let port = self.ports.get_mut(&h).ok_or(0x2Bu8)?;
                if port.rom.len() < addr + 64 {
                    port.rom.resize(addr + 64, 0);
                }
                port.rom[addr..addr + 64].copy_from_slice(&data);
                okay()
            }
            "PINIT" => {
                let h = self.handle_param(p)?;
                let port = self.ports.get_mut(&h).ok_or(0x2Bu8)?;
                if port.rom.is_empty() {
                    return Err(0x0D);
                }
                port.initialized = true;
                okay()
            }
            "PENA" => {
                let h = self.handle_param(p)?;
                if !matches!(p.get(2..), Some("D") | Some("S") | Some("B")) {
                    return Err(0x09);
                }
                let port = self.ports.get_mut(&h).ok_or(0x2Bu8)?;
                if !port.initialized {
                    return Err(0x0E);
                }
                port.enabled = true;
                okay()
            }
            "PDIS" => {
                let h = self.handle_param(p)?;
                if let Some(port) = self.ports.get_mut(&h) {
                    port.enabled = false;
                }
                okay()
            }
            "TSTART" => {
                self.tracking = true;
                okay()
            }
            "TSTOP" => {
                self.tracking = false;
                okay()
            }
            "BX" | "TX" => {
                if !self.tracking {
                    return Err(0x0C);
                }
                let options = if p.is_empty() {
                    1
                } else {
                    u16::from_str_radix(p, 16).map_err(|_| 0x07u8)?
                };
                if options & 0x0001 == 0 || options & !0x0801 != 0 {
                    // Only transforms (+ out-of-volume reporting) are simulated.
                    return Err(0x23);
                }
                let handles = self.tracking_records();
                if cmd.word == "BX" {
                    Ok(Reply::Binary(wire::bx_body(&handles, 0)))
                } else {
                    Ok(Reply::Text(wire::tx_text(&handles, 0)))
                }
            }
            _ => Err(0x01),
        }
    }

    fn tracking_records(&mut self) -> Vec<HandleOut> {
        let frame = self.source.tracker_frame();
        let frame_no = frame.frame_number as u32;
        self.ports
            .iter()
            .filter(|(_, p)| p.initialized)
            .map(|(&handle, port)| {
                let base = 0x01 | 0x10 | if port.enabled { 0x20 } else { 0 };
                let status = frame
                    .tools
                    .get(port.tool_index)
                    .map_or(ToolStatus::Missing, |t| t.status);
                let (record, port_status) = if !port.enabled {
                    (Record::Disabled, base)
                } else {
                    match status {
                        ToolStatus::Visible { pose, rms_mm } => (transform(&pose, rms_mm), base),
                        // The world gives no pose outside the volume: report MISSING with
                        // the out-of-volume bit (what a tracker does without option 0800).
                        ToolStatus::OutOfVolume => (Record::Missing, base | 0x40),
                        ToolStatus::Missing => (Record::Missing, base),
                        ToolStatus::Disabled => (Record::Disabled, base),
                    }
                };
                HandleOut {
                    handle,
                    record,
                    port_status,
                    frame: frame_no,
                }
            })
            .collect()
    }
}

fn transform(pose: &MarkerToTracker, rms: f64) -> Record {
    let q = pose.0.rotation.quaternion();
    // NDI reports q0 >= 0.
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    let t = pose.0.translation.vector;
    Record::Transform {
        q: [s * q.w, s * q.i, s * q.j, s * q.k],
        t: [t.x, t.y, t.z],
        rms,
    }
}

enum Reply {
    Text(String),
    Binary(Vec<u8>),
    OkayThenBaud(u32),
}
