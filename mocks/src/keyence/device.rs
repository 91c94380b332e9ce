//! The DL-RS1A state machine: one command line in, one reply out.

use crate::world::control::Fault;
use crate::world::WorldHandle;
use robocal_drivers::{Clock, RangeReading};
use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex};

/// What the head sees for one sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LaserSample {
    /// Distance from the head (mm).
    Distance(f64),
    /// No valid measurement (too little / too much light, outside the range).
    OutOfRange,
    /// The amplifier is in an error state (`+EEE.EE`).
    AmplifierError,
}

/// Where the simulated amplifier's samples come from.
pub trait LaserSource: Send + Sync + 'static {
    /// One sample (advances the source's time by one sampling period).
    fn sample(&self) -> LaserSample;
    /// The next wire fault, if any.
    fn take_fault(&self) -> Option<Fault> {
        None
    }
    /// The clock pacing reply delays (`None`: tokio's wall clock).
    fn clock(&self) -> Option<Arc<dyn Clock>> {
        None
    }
}

/// Laser `index` of a world; wire faults are those queued for device `name`.
#[derive(Clone)]
pub struct WorldLaser {
    /// The world.
    pub world: WorldHandle,
    /// Laser index.
    pub index: usize,
    /// Device name for fault injection.
    pub name: String,
}

impl LaserSource for WorldLaser {
    fn sample(&self) -> LaserSample {
        match self.world.laser_reading_of(self.index) {
            RangeReading::Distance(d) => LaserSample::Distance(d),
            RangeReading::OutOfRange => LaserSample::OutOfRange,
        }
    }
    fn take_fault(&self) -> Option<Fault> {
        self.world.take_fault(&self.name)
    }
    fn clock(&self) -> Option<Arc<dyn Clock>> {
        Some(self.world.clock())
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Scripted samples: the queue first, then `default` forever.
#[derive(Debug)]
pub struct StaticLaser {
    queue: Mutex<VecDeque<LaserSample>>,
    default: Mutex<LaserSample>,
    faults: Mutex<VecDeque<Fault>>,
}

impl StaticLaser {
    /// Always `default` unless samples are queued.
    pub fn new(default: LaserSample) -> Self {
        Self {
            queue: Mutex::default(),
            default: Mutex::new(default),
            faults: Mutex::default(),
        }
    }
    /// Queue one sample.
    pub fn push(&self, s: LaserSample) {
        lock(&self.queue).push_back(s);
    }
    /// Queue a one-shot wire fault.
    pub fn inject(&self, f: Fault) {
        lock(&self.faults).push_back(f);
    }
}

impl LaserSource for StaticLaser {
    fn sample(&self) -> LaserSample {
        lock(&self.queue)
            .pop_front()
            .unwrap_or(*lock(&self.default))
    }
    fn take_fault(&self) -> Option<Fault> {
        lock(&self.faults).pop_front()
    }
}

/// Simulator settings.
#[derive(Debug, Clone)]
pub struct SimKeyenceConfig {
    /// Number of amplifiers (ID 00 is fed by the source; expansion units read `+000.00`).
    pub amplifiers: u8,
    /// The displayed value is the distance minus this (mm; the IL-600's reference distance).
    pub reference_mm: f64,
    /// What the unit sends for "no valid measurement" (the manual's string is unverified).
    pub no_measurement: String,
    /// Delay before each reply (s).
    pub reply_delay_s: f64,
}

impl Default for SimKeyenceConfig {
    fn default() -> Self {
        Self {
            amplifiers: 1,
            reference_mm: 600.0,
            no_measurement: "-FFFF.FF".into(),
            reply_delay_s: 0.002,
        }
    }
}

/// What the transport does with a reply.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    /// Write these bytes (after the configured reply delay).
    Send(Vec<u8>),
    /// Write these bytes after `f64` seconds.
    Delayed(Vec<u8>, f64),
    /// Write nothing.
    Nothing,
}

/// Data numbers that are read-only on the IL amplifier (033, 036-044, 050, 051).
fn read_only(data_no: u16) -> bool {
    matches!(data_no, 33 | 36..=44 | 50 | 51)
}

/// The simulated unit.
pub struct DlRs1aDevice {
    source: Arc<dyn LaserSource>,
    config: SimKeyenceConfig,
    written: BTreeMap<(u8, u16), String>,
    /// Every command received (first field), in order.
    pub log: Vec<String>,
}

impl DlRs1aDevice {
    /// A unit over `source`.
    pub fn new(source: Arc<dyn LaserSource>, config: SimKeyenceConfig) -> Self {
        Self {
            source,
            config,
            written: BTreeMap::new(),
            log: Vec::new(),
        }
    }

    /// The source's clock.
    pub fn clock(&self) -> Option<Arc<dyn Clock>> {
        self.source.clock()
    }

    /// Reply delay (s).
    pub fn reply_delay_s(&self) -> f64 {
        self.config.reply_delay_s
    }

    /// `±***.**` for the IL-600 (mm), with the display limits.
    fn format(&self, s: LaserSample) -> String {
        match s {
            LaserSample::AmplifierError => "+EEE.EE".into(),
            LaserSample::OutOfRange => self.config.no_measurement.clone(),
            LaserSample::Distance(d) => {
                let v = d - self.config.reference_mm;
                if !v.is_finite() {
                    return self.config.no_measurement.clone();
                }
                let hundredths = (v * 100.0).round();
                if hundredths >= 99999.0 {
                    "+999.99".into()
                } else if hundredths <= -99999.0 {
                    "-999.99".into()
                } else {
                    let sign = if hundredths < 0.0 { '-' } else { '+' };
                    let a = hundredths.abs() as u64;
                    format!("{sign}{:03}.{:02}", a / 100, a % 100)
                }
            }
        }
    }

    fn values(&self) -> Vec<(LaserSample, String)> {
        let s = self.source.sample();
        let mut v = vec![(s, self.format(s))];
        for _ in 1..self.config.amplifiers {
            v.push((
                LaserSample::Distance(self.config.reference_mm),
                "+000.00".into(),
            ));
        }
        v
    }

    /// Handle one line (without delimiter); faults applied.
    pub fn handle_line(&mut self, line: &[u8]) -> Output {
        let text = String::from_utf8_lossy(line).into_owned();
        let cmd: String = text
            .split(',')
            .next()
            .unwrap_or("")
            .chars()
            .take(2)
            .collect();
        self.log.push(cmd.clone());
        let reply = self.reply(&text);
        let wire = |s: String| format!("{s}\r\n").into_bytes();
        let fault = self.source.take_fault();
        match fault {
            None => Output::Send(wire(reply)),
            // A pty cannot be hung up from the unit's side; a dropped link looks like silence.
            Some(Fault::DropLink) | Some(Fault::Silence { .. }) => Output::Nothing,
            Some(Fault::Delay { secs }) => Output::Delayed(wire(reply), secs),
            Some(Fault::ErrorReply { code }) => {
                Output::Send(wire(format!("ER,{cmd},{:02}", code.rem_euclid(100))))
            }
            Some(Fault::Garbage { bytes }) => Output::Send(bytes),
            Some(Fault::Truncated) => {
                let w = wire(reply);
                Output::Send(w[..w.len() / 2].to_vec())
            }
            // The protocol has no checksum: corrupt one character of the data instead.
            Some(Fault::BadCrc) => {
                let mut w = wire(reply);
                if let Some(p) = w.iter().rposition(|b| b.is_ascii_digit()) {
                    w[p] = b'?';
                }
                Output::Send(w)
            }
        }
    }

    fn reply(&mut self, text: &str) -> String {
        let f: Vec<&str> = text.split(',').collect();
        let cmd = f[0];
        let er = |code: u8| format!("ER,{},{code:02}", &cmd[..cmd.len().min(2)]);
        let id_ok = |s: &str| s.len() == 2 && s.bytes().all(|b| b.is_ascii_digit());
        let dno_ok = |s: &str| s.len() == 3 && s.bytes().all(|b| b.is_ascii_digit());
        match cmd {
            "M0" => {
                if f.len() != 1 {
                    return er(21);
                }
                let v: Vec<String> = self.values().into_iter().map(|(_, s)| s).collect();
                format!("M0,{}", v.join(","))
            }
            "MS" => {
                if f.len() != 1 {
                    return er(21);
                }
                let v: Vec<String> = self
                    .values()
                    .into_iter()
                    .map(|(s, txt)| {
                        // Judgment output bits: 0x01 HI, 0x02 LO, 0x04 GO, 0x08 alarm.
                        let out = match s {
                            LaserSample::Distance(_) => 4,
                            LaserSample::OutOfRange | LaserSample::AmplifierError => 8,
                        };
                        format!("{out:02},{txt}")
                    })
                    .collect();
                format!("MS,{}", v.join(","))
            }
            "SR" => {
                if f.len() != 3 {
                    return er(21);
                }
                if !id_ok(f[1]) || !dno_ok(f[2]) {
                    return er(22);
                }
                let id: u8 = f[1].parse().unwrap_or(99);
                let dno: u16 = f[2].parse().unwrap_or(999);
                if id >= self.config.amplifiers {
                    return er(65);
                }
                let data = match dno {
                    33 => "00000".to_string(),
                    36 => "04".to_string(),
                    37..=41 => {
                        let (_, s) = self.values().swap_remove(usize::from(id));
                        s
                    }
                    42 => "+00.000".to_string(),
                    43 | 44 | 50 | 51 => "0".to_string(),
                    _ => match self.written.get(&(id, dno)) {
                        Some(v) => v.clone(),
                        None => return er(22),
                    },
                };
                format!("SR,{},{},{data}", f[1], f[2])
            }
            "SW" => {
                if f.len() != 4 {
                    return er(21);
                }
                if !id_ok(f[1]) || !dno_ok(f[2]) || f[3].is_empty() || f[3].len() > 10 {
                    return er(22);
                }
                let id: u8 = f[1].parse().unwrap_or(99);
                let dno: u16 = f[2].parse().unwrap_or(999);
                if id >= self.config.amplifiers {
                    return er(65);
                }
                if read_only(dno) {
                    return er(22);
                }
                self.written.insert((id, dno), f[3].to_string());
                format!("SW,{},{}", f[1], f[2])
            }
            "AW" => {
                if f.len() != 3 {
                    return er(21);
                }
                if !dno_ok(f[1]) || f[2].is_empty() || f[2].len() > 10 {
                    return er(22);
                }
                let dno: u16 = f[1].parse().unwrap_or(999);
                if read_only(dno) {
                    return er(22);
                }
                for id in 0..self.config.amplifiers {
                    self.written.insert((id, dno), f[2].to_string());
                }
                format!("AW,{}", f[1])
            }
            _ => er(0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dev(sample: LaserSample) -> DlRs1aDevice {
        DlRs1aDevice::new(
            Arc::new(StaticLaser::new(sample)),
            SimKeyenceConfig::default(),
        )
    }

    fn text(o: Output) -> String {
        match o {
            Output::Send(b) => String::from_utf8(b).unwrap(),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn formats_il600_values_and_limits() {
        let mut d = dev(LaserSample::Distance(723.456));
        assert_eq!(text(d.handle_line(b"M0")), "M0,+123.46\r\n");
        let mut d = dev(LaserSample::Distance(599.0));
        assert_eq!(text(d.handle_line(b"M0")), "M0,-001.00\r\n");
        let mut d = dev(LaserSample::Distance(2000.0));
        assert_eq!(text(d.handle_line(b"M0")), "M0,+999.99\r\n");
        let mut d = dev(LaserSample::AmplifierError);
        assert_eq!(text(d.handle_line(b"M0")), "M0,+EEE.EE\r\n");
    }

    #[test]
    fn errors_per_the_manual() {
        let mut d = dev(LaserSample::Distance(600.0));
        assert_eq!(text(d.handle_line(b"XX")), "ER,XX,00\r\n");
        assert_eq!(text(d.handle_line(b"SR,05,037")), "ER,SR,65\r\n");
        assert_eq!(text(d.handle_line(b"SR,00")), "ER,SR,21\r\n");
        assert_eq!(text(d.handle_line(b"SW,00,037,+1")), "ER,SW,22\r\n");
        assert_eq!(text(d.handle_line(b"SW,00,001,5")), "SW,00,001\r\n");
        assert_eq!(text(d.handle_line(b"SR,00,001")), "SR,00,001,5\r\n");
        assert_eq!(text(d.handle_line(b"SR,00,038")), "SR,00,038,+000.00\r\n");
        assert_eq!(text(d.handle_line(b"MS")), "MS,04,+000.00\r\n");
    }
}
