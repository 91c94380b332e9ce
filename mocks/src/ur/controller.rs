//! The simulated UR controller state shared by the RTDE, dashboard and script servers.
//!
//! Motion, joint readings, the flange pose and protective stops come from the world; the
//! controller adds what only a UR controller has: power / brake state, the program runtime
//! state, RTDE registers, and the program runner (plain `movej`/`stopj` URScript, or the
//! register handshake of ur_rtde's `rtde_control` script).

use crate::world::{SafetyState, WorldHandle};
use robocal_drivers::ur::rtde::frame::{runtime_state, ControllerVersion, RobotMode, SafetyMode};
use robocal_drivers::MoveSpeed;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// The version every interface reports (RTDE `v`, dashboard `PolyscopeVersion`/`version`):
/// 5.11.x exercises ur_rtde's common path (register outputs need minor ≥ 4; 5.23+ switches to
/// the larger register recipe). Bytes as in `docs/protocols.md`'s `v` example.
pub const VERSION: ControllerVersion = ControllerVersion {
    major: 5,
    minor: 11,
    bugfix: 1,
    build: 0x1a9ec,
};

/// Number of RTDE int/double registers.
pub const REGISTERS: usize = 48;

/// Mutable controller state.
#[derive(Debug)]
pub struct CtrlState {
    /// Power / brake state (RUNNING = powered with brakes released).
    pub robot_mode: RobotMode,
    /// RTDE runtime_state.
    pub runtime: u32,
    /// Program loaded through the dashboard (`load`).
    pub loaded: Option<String>,
    /// `input_int_register_N`.
    pub in_int: [i32; REGISTERS],
    /// `input_double_register_N`.
    pub in_double: [f64; REGISTERS],
    /// `output_int_register_N`.
    pub out_int: [i32; REGISTERS],
    /// `output_double_register_N`.
    pub out_double: [f64; REGISTERS],
    /// Input bit registers 64..127.
    pub in_bits: u64,
    /// World time at which the current protective stop was first seen.
    pub pstop_since: Option<f64>,
    program: Option<tokio::task::JoinHandle<()>>,
    program_seq: u64,
}

/// The controller of one simulated UR arm.
pub struct Controller {
    /// The world.
    pub world: WorldHandle,
    /// Arm index in the world.
    pub arm: usize,
    /// Scenario device name (fault queue key for RTDE; `<device>/dashboard`, `<device>/script`).
    pub device: String,
    st: Mutex<CtrlState>,
    /// Signalled whenever an RTDE input register changes.
    pub inputs_changed: tokio::sync::Notify,
}

impl std::fmt::Debug for Controller {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Controller")
            .field("device", &self.device)
            .field("arm", &self.arm)
            .finish()
    }
}

/// One consistent view of the arm for an RTDE data package.
#[derive(Debug, Clone)]
pub struct Snapshot {
    /// World time (s).
    pub t: f64,
    /// Encoder angles (rad).
    pub q: Vec<f64>,
    /// Joint speeds (rad/s).
    pub qd: Vec<f64>,
    /// Controller's nominal flange pose (mm).
    pub flange: nalgebra::Isometry3<f64>,
    /// RTDE robot_mode.
    pub robot_mode: i32,
    /// RTDE safety_mode.
    pub safety_mode: i32,
    /// RTDE runtime_state.
    pub runtime: u32,
    /// Output int registers.
    pub out_int: [i32; REGISTERS],
    /// Output double registers.
    pub out_double: [f64; REGISTERS],
    /// Input int registers.
    pub in_int: [i32; REGISTERS],
    /// Input double registers.
    pub in_double: [f64; REGISTERS],
}

impl Controller {
    /// A controller for arm `arm`, powered and running, no program.
    pub fn new(world: WorldHandle, arm: usize, device: &str) -> Arc<Self> {
        let mut out_int = [0; REGISTERS];
        out_int[2] = -1;
        Arc::new(Self {
            world,
            arm,
            device: device.to_string(),
            st: Mutex::new(CtrlState {
                robot_mode: RobotMode::Running,
                runtime: runtime_state::STOPPED,
                loaded: None,
                in_int: [0; REGISTERS],
                in_double: [0.0; REGISTERS],
                out_int,
                out_double: [0.0; REGISTERS],
                in_bits: 0,
                pstop_since: None,
                program: None,
                program_seq: 0,
            }),
            inputs_changed: tokio::sync::Notify::new(),
        })
    }

    /// Lock the state.
    pub fn with<R>(&self, f: impl FnOnce(&mut CtrlState) -> R) -> R {
        let mut g = self.st.lock().unwrap_or_else(|e| e.into_inner());
        f(&mut g)
    }

    /// The serial number the dashboard reports: digits only (ur_rtde requires it), `20…`
    /// prefix (URCL expects it), derived from the scenario's serial.
    pub fn serial_digits(&self) -> String {
        let s = self
            .world
            .arm_identity(self.arm)
            .map(|(_, s)| s)
            .unwrap_or_default();
        let digits: String = s.chars().filter(|c| c.is_ascii_digit()).collect();
        if digits.starts_with("20") && digits.len() >= 8 {
            return digits;
        }
        let h = s.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
            (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
        });
        format!("20{:09}", h % 1_000_000_000)
    }

    /// The safety mode, taken from the world (protective stop) and remembered with its onset.
    pub fn safety_mode(&self) -> SafetyMode {
        let st = self.world.arm_state(self.arm);
        let m = match st.safety {
            SafetyState::Normal => SafetyMode::Normal,
            SafetyState::Reduced => SafetyMode::Reduced,
            SafetyState::ProtectiveStop => SafetyMode::ProtectiveStop,
            SafetyState::EmergencyStop => SafetyMode::RobotEmergencyStop,
            SafetyState::Fault => SafetyMode::Fault,
        };
        let now = self.world.now();
        self.with(|c| {
            if m == SafetyMode::ProtectiveStop {
                c.pstop_since.get_or_insert(now);
            } else {
                c.pstop_since = None;
            }
        });
        m
    }

    /// A consistent snapshot for one data package.
    pub fn snapshot(&self) -> Snapshot {
        let safety = self.safety_mode();
        let js = self.world.arm_joint_state(self.arm);
        let flange = self.world.arm_controller_flange(self.arm);
        let n = js.q.len();
        self.with(|c| Snapshot {
            t: js.t,
            qd: js.qd.clone().unwrap_or_else(|| vec![0.0; n]),
            q: js.q,
            flange,
            robot_mode: c.robot_mode.as_i32(),
            safety_mode: safety.as_i32(),
            runtime: c.runtime,
            out_int: c.out_int,
            out_double: c.out_double,
            in_int: c.in_int,
            in_double: c.in_double,
        })
    }

    /// Set an input register by name (ignored for names that are not registers).
    pub fn set_input(&self, name: &str, v: &robocal_drivers::ur::rtde::Value) {
        use robocal_drivers::ur::rtde::frame::register_index;
        use robocal_drivers::ur::rtde::Value;
        self.with(|c| {
            if let (Some(i), Value::Int32(x)) = (register_index(name, "input_int_register_"), v) {
                if i < REGISTERS {
                    c.in_int[i] = *x;
                }
            } else if let (Some(i), Value::Double(x)) =
                (register_index(name, "input_double_register_"), v)
            {
                if i < REGISTERS {
                    c.in_double[i] = *x;
                }
            } else if let (Some(i), Value::Bool(b)) =
                (register_index(name, "input_bit_register_"), v)
            {
                if (64..128).contains(&i) {
                    let bit = 1u64 << (i - 64);
                    if *b {
                        c.in_bits |= bit;
                    } else {
                        c.in_bits &= !bit;
                    }
                }
            }
        });
    }

    /// Stop the running program (if any) and the arm.
    pub fn stop_program(&self) {
        let had = self.with(|c| {
            c.program_seq += 1;
            c.runtime = runtime_state::STOPPED;
            c.out_int[0] = 0;
            c.program.take()
        });
        if let Some(h) = had {
            h.abort();
            self.world.arm_set_freedrive(self.arm, false);
            self.world.arm_stop(self.arm);
        }
    }

    /// Replace the running program with `text` (a complete `def … end` or a single line).
    pub fn run_program(self: &Arc<Self>, text: String) {
        self.stop_program();
        let me = self.clone();
        let seq = self.with(|c| {
            c.runtime = runtime_state::PLAYING;
            c.program_seq
        });
        let is_rtde_control = text
            .lines()
            .next()
            .is_some_and(|l| l.trim_start().starts_with("def rtde_control"));
        let handle = tokio::spawn(async move {
            let result = if is_rtde_control {
                me.rtde_control_loop(seq).await
            } else {
                me.run_statements(&text, seq).await
            };
            if let Err(e) = result {
                tracing::info!("{}: program stopped: {e}", me.device);
            }
            // Freedrive ends with the program that started it.
            if me.still_current(seq) {
                me.world.arm_set_freedrive(me.arm, false);
            }
            me.with(|c| {
                if c.program_seq == seq {
                    c.runtime = runtime_state::STOPPED;
                    c.program = None;
                }
            });
        });
        self.with(|c| {
            if c.program_seq == seq {
                c.program = Some(handle);
            } else {
                handle.abort();
            }
        });
    }

    fn still_current(&self, seq: u64) -> bool {
        self.with(|c| c.program_seq == seq)
    }

    /// Move and wait for arrival; fails on a protective stop or a refused target.
    async fn movej(&self, q: &[f64], speed: MoveSpeed) -> Result<(), String> {
        if self.with(|c| c.robot_mode) != RobotMode::Running {
            return Err("robot not powered / brakes engaged".into());
        }
        self.world
            .arm_start_move(self.arm, q, speed)
            .map_err(|e| e.to_string())?;
        self.wait_motion().await;
        if self.safety_mode() != SafetyMode::Normal {
            return Err("protective stop during motion".into());
        }
        Ok(())
    }

    async fn wait_motion(&self) {
        if self.world.is_virtual() {
            self.world.arm_wait_arrival(self.arm).await;
        } else {
            while self.world.arm_is_moving(self.arm) {
                tokio::time::sleep(Duration::from_millis(4)).await;
            }
        }
    }

    async fn run_statements(&self, text: &str, seq: u64) -> Result<(), String> {
        for line in text.lines() {
            if !self.still_current(seq) {
                return Ok(());
            }
            match parse_statement(line) {
                Statement::Skip => {}
                Statement::MoveJ { q, a, v } => {
                    self.movej(
                        &q,
                        MoveSpeed {
                            max_vel: v,
                            max_acc: a,
                        },
                    )
                    .await?
                }
                Statement::StopJ => self.world.arm_stop(self.arm),
                Statement::Freedrive(on) => {
                    if on && self.with(|c| c.robot_mode) != RobotMode::Running {
                        return Err("freedrive_mode(): robot not powered / brakes engaged".into());
                    }
                    self.world.arm_set_freedrive(self.arm, on);
                }
                Statement::Sleep(s) => {
                    if self.world.is_virtual() {
                        self.world.advance(s);
                    } else {
                        tokio::time::sleep(Duration::from_secs_f64(s.clamp(0.0, 3600.0))).await;
                    }
                }
                Statement::Unsupported(s) => {
                    return Err(format!("unsupported URScript statement: {s}"));
                }
            }
        }
        Ok(())
    }

    /// The register handshake of ur_rtde's `rtde_control.script` (`docs/protocols.md` §1.6).
    async fn rtde_control_loop(&self, seq: u64) -> Result<(), String> {
        let mut latched = false;
        loop {
            if !self.still_current(seq) {
                return Ok(());
            }
            let (cmd, d, i1) = self.with(|c| (c.in_int[0], c.in_double, c.in_int[1]));
            if cmd == 0 {
                self.with(|c| c.out_int[0] = 1);
                latched = false;
            } else if !latched {
                latched = true;
                match cmd {
                    // MOVEJ: q = d0..d5, speed d6, accel d7, async flag i1.
                    1 => {
                        let q = d[..6].to_vec();
                        let speed = MoveSpeed {
                            max_vel: d[6],
                            max_acc: d[7],
                        };
                        if i1 == 1 {
                            self.world
                                .arm_start_move(self.arm, &q, speed)
                                .map_err(|e| e.to_string())?;
                            self.with(|c| {
                                c.out_int[2] = 0x8000;
                                c.out_int[0] = 2;
                            });
                            self.wait_motion().await;
                            self.with(|c| c.out_int[2] = -1);
                        } else {
                            self.movej(&q, speed).await?;
                            self.with(|c| c.out_int[0] = 2);
                        }
                    }
                    // STOPL / STOPJ.
                    33 | 34 => {
                        self.world.arm_stop(self.arm);
                        self.with(|c| c.out_int[0] = 2);
                    }
                    // STOP_SCRIPT.
                    255 => return Ok(()),
                    // Real-time commands answer "ready" at once (no servo support here).
                    6 | 9 | 10 | 11 | 24..=27 | 38 | 58 | 66..=71 => {
                        self.with(|c| c.out_int[0] = 1);
                    }
                    // Cartesian motions need the controller's IK: not simulated.
                    2..=4 | 12 | 45 => {
                        return Err(format!("ur_rtde command {cmd} needs IK (not simulated)"));
                    }
                    // Configuration commands (payload, TCP, watchdog, …): accepted, no effect.
                    _ => self.with(|c| c.out_int[0] = 2),
                }
            }
            tokio::select! {
                _ = self.inputs_changed.notified() => {}
                _ = tokio::time::sleep(Duration::from_millis(2)) => {}
            }
        }
    }
}

/// A parsed URScript line.
#[derive(Debug, Clone, PartialEq)]
pub enum Statement {
    /// Blank, comment, `def`, `end`, `textmsg`, …
    Skip,
    /// `movej([q…], a=…, v=…)` (rad, rad/s², rad/s).
    MoveJ {
        /// Target (rad).
        q: Vec<f64>,
        /// Acceleration (rad/s²).
        a: f64,
        /// Speed (rad/s).
        v: f64,
    },
    /// `stopj(a)` / `stopl(a)`.
    StopJ,
    /// `sleep(s)`.
    Sleep(f64),
    /// `freedrive_mode()` (true) / `end_freedrive_mode()` (false): the arm follows the
    /// operator's hand until the program ends or it is ended.
    Freedrive(bool),
    /// Anything that would move the arm in a way this simulator does not model.
    Unsupported(String),
}

/// Parse one URScript line (only what the simulator executes).
pub fn parse_statement(line: &str) -> Statement {
    let l = line.trim();
    if l.is_empty()
        || l.starts_with('#')
        || l.starts_with("def ")
        || l.starts_with("sec ")
        || l == "end"
        || l.starts_with("textmsg(")
        || l.starts_with("popup(")
        || l.starts_with("set_")
        || l.starts_with("write_output")
    {
        return Statement::Skip;
    }
    if let Some(args) = call_args(l, "movej") {
        return parse_movej(&args).unwrap_or_else(|| Statement::Unsupported(l.to_string()));
    }
    if call_args(l, "stopj").is_some() || call_args(l, "stopl").is_some() {
        return Statement::StopJ;
    }
    if call_args(l, "freedrive_mode").is_some() {
        return Statement::Freedrive(true);
    }
    if call_args(l, "end_freedrive_mode").is_some() {
        return Statement::Freedrive(false);
    }
    if let Some(args) = call_args(l, "sleep") {
        return match args.trim().parse::<f64>() {
            Ok(s) if s.is_finite() && s >= 0.0 => Statement::Sleep(s),
            _ => Statement::Unsupported(l.to_string()),
        };
    }
    Statement::Unsupported(l.to_string())
}

fn call_args(l: &str, name: &str) -> Option<String> {
    let rest = l.strip_prefix(name)?.trim_start();
    let inner = rest.strip_prefix('(')?.strip_suffix(')')?;
    Some(inner.to_string())
}

fn parse_movej(args: &str) -> Option<Statement> {
    let open = args.find('[')?;
    let close = args.find(']')?;
    if close < open {
        return None;
    }
    let q: Vec<f64> = args[open + 1..close]
        .split(',')
        .map(|s| s.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .ok()?;
    if q.len() != 6 || q.iter().any(|x| !x.is_finite()) {
        return None;
    }
    // Defaults of URScript movej: a = 1.4 rad/s², v = 1.05 rad/s.
    let (mut a, mut v) = (1.4, 1.05);
    let mut positional = 0;
    for part in args[close + 1..]
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
    {
        let (key, val) = match part.split_once('=') {
            Some((k, v)) => (k.trim(), v.trim()),
            None => {
                positional += 1;
                (
                    if positional == 1 {
                        "a"
                    } else if positional == 2 {
                        "v"
                    } else {
                        ""
                    },
                    part,
                )
            }
        };
        let x: f64 = val.parse().ok()?;
        if !x.is_finite() || x <= 0.0 {
            if key == "t" || key == "r" {
                continue;
            }
            return None;
        }
        match key {
            "a" => a = x,
            "v" => v = x,
            _ => {}
        }
    }
    Some(Statement::MoveJ { q, a, v })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn movej_parsing() {
        assert_eq!(
            parse_statement("  movej([0.1, -1.5, 1.0, 0, 0.5, 0.25], a=1.2, v=0.5)"),
            Statement::MoveJ {
                q: vec![0.1, -1.5, 1.0, 0.0, 0.5, 0.25],
                a: 1.2,
                v: 0.5
            }
        );
        assert_eq!(
            parse_statement("movej([0,0,0,0,0,0], 2.0, 1.0)"),
            Statement::MoveJ {
                q: vec![0.0; 6],
                a: 2.0,
                v: 1.0
            }
        );
        assert!(matches!(
            parse_statement("movej([0,0,0], a=1, v=1)"),
            Statement::Unsupported(_)
        ));
        assert!(matches!(
            parse_statement("movel(p[0.1,0,0.3,0,3.14,0], a=1, v=0.1)"),
            Statement::Unsupported(_)
        ));
        assert_eq!(parse_statement("  stopj(2.0)"), Statement::StopJ);
        assert_eq!(parse_statement("def robocal_move():"), Statement::Skip);
        assert_eq!(parse_statement("  sleep(0.5)"), Statement::Sleep(0.5));
    }
}
