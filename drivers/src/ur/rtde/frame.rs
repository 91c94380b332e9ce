//! RTDE packages as pure data (no I/O, no bytes).
//!
//! Every RTDE package is `u16 size (BE, includes the 3 header bytes) | u8 type | payload`.
//! The same type letter carries a different payload in each direction, so there is one enum
//! per direction: [`Request`] (client → controller) and [`Reply`] (controller → client).
//! Source of every layout: UR's `RTDE_Python_Client_Library` `rtde/serialize.py` and
//! ur_rtde 1.6.5 `src/rtde.cpp` (see `docs/protocols.md` §1.2–1.3).

/// The RTDE protocol version this crate speaks.
pub const PROTOCOL_VERSION: u16 = 2;

/// Package type letters.
pub mod kind {
    /// `V` REQUEST_PROTOCOL_VERSION.
    pub const PROTOCOL_VERSION: u8 = b'V';
    /// `v` GET_URCONTROL_VERSION.
    pub const CONTROLLER_VERSION: u8 = b'v';
    /// `M` TEXT_MESSAGE.
    pub const TEXT_MESSAGE: u8 = b'M';
    /// `U` DATA_PACKAGE.
    pub const DATA: u8 = b'U';
    /// `O` CONTROL_PACKAGE_SETUP_OUTPUTS.
    pub const SETUP_OUTPUTS: u8 = b'O';
    /// `I` CONTROL_PACKAGE_SETUP_INPUTS.
    pub const SETUP_INPUTS: u8 = b'I';
    /// `S` CONTROL_PACKAGE_START.
    pub const START: u8 = b'S';
    /// `P` CONTROL_PACKAGE_PAUSE.
    pub const PAUSE: u8 = b'P';
}

/// An RTDE field type (all big-endian on the wire).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DataType {
    /// `BOOL`, 1 byte.
    Bool,
    /// `UINT8`.
    Uint8,
    /// `UINT32`.
    Uint32,
    /// `UINT64`.
    Uint64,
    /// `INT32`.
    Int32,
    /// `DOUBLE`.
    Double,
    /// `VECTOR3D`, 3 doubles.
    Vector3d,
    /// `VECTOR6D`, 6 doubles.
    Vector6d,
    /// `VECTOR6INT32`.
    Vector6Int32,
    /// `VECTOR6UINT32`.
    Vector6Uint32,
}

impl DataType {
    /// Every type.
    pub const ALL: [DataType; 10] = [
        DataType::Bool,
        DataType::Uint8,
        DataType::Uint32,
        DataType::Uint64,
        DataType::Int32,
        DataType::Double,
        DataType::Vector3d,
        DataType::Vector6d,
        DataType::Vector6Int32,
        DataType::Vector6Uint32,
    ];

    /// The name the controller uses in setup replies.
    pub fn name(self) -> &'static str {
        match self {
            DataType::Bool => "BOOL",
            DataType::Uint8 => "UINT8",
            DataType::Uint32 => "UINT32",
            DataType::Uint64 => "UINT64",
            DataType::Int32 => "INT32",
            DataType::Double => "DOUBLE",
            DataType::Vector3d => "VECTOR3D",
            DataType::Vector6d => "VECTOR6D",
            DataType::Vector6Int32 => "VECTOR6INT32",
            DataType::Vector6Uint32 => "VECTOR6UINT32",
        }
    }

    /// Parse a type name from a setup reply.
    pub fn from_name(s: &str) -> Option<Self> {
        DataType::ALL.into_iter().find(|t| t.name() == s)
    }

    /// Encoded size in bytes.
    pub fn size(self) -> usize {
        match self {
            DataType::Bool | DataType::Uint8 => 1,
            DataType::Uint32 | DataType::Int32 => 4,
            DataType::Uint64 | DataType::Double => 8,
            DataType::Vector3d => 24,
            DataType::Vector6d => 48,
            DataType::Vector6Int32 | DataType::Vector6Uint32 => 24,
        }
    }
}

/// One field value.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// `BOOL`.
    Bool(bool),
    /// `UINT8`.
    Uint8(u8),
    /// `UINT32`.
    Uint32(u32),
    /// `UINT64`.
    Uint64(u64),
    /// `INT32`.
    Int32(i32),
    /// `DOUBLE`.
    Double(f64),
    /// `VECTOR3D`.
    Vector3d([f64; 3]),
    /// `VECTOR6D`.
    Vector6d([f64; 6]),
    /// `VECTOR6INT32`.
    Vector6Int32([i32; 6]),
    /// `VECTOR6UINT32`.
    Vector6Uint32([u32; 6]),
}

impl Value {
    /// The type of this value.
    pub fn data_type(&self) -> DataType {
        match self {
            Value::Bool(_) => DataType::Bool,
            Value::Uint8(_) => DataType::Uint8,
            Value::Uint32(_) => DataType::Uint32,
            Value::Uint64(_) => DataType::Uint64,
            Value::Int32(_) => DataType::Int32,
            Value::Double(_) => DataType::Double,
            Value::Vector3d(_) => DataType::Vector3d,
            Value::Vector6d(_) => DataType::Vector6d,
            Value::Vector6Int32(_) => DataType::Vector6Int32,
            Value::Vector6Uint32(_) => DataType::Vector6Uint32,
        }
    }

    /// The zero value of a type.
    pub fn zero(t: DataType) -> Value {
        match t {
            DataType::Bool => Value::Bool(false),
            DataType::Uint8 => Value::Uint8(0),
            DataType::Uint32 => Value::Uint32(0),
            DataType::Uint64 => Value::Uint64(0),
            DataType::Int32 => Value::Int32(0),
            DataType::Double => Value::Double(0.0),
            DataType::Vector3d => Value::Vector3d([0.0; 3]),
            DataType::Vector6d => Value::Vector6d([0.0; 6]),
            DataType::Vector6Int32 => Value::Vector6Int32([0; 6]),
            DataType::Vector6Uint32 => Value::Vector6Uint32([0; 6]),
        }
    }

    /// Integer scalars as `i64`.
    pub fn as_i64(&self) -> Option<i64> {
        match *self {
            Value::Bool(b) => Some(b as i64),
            Value::Uint8(v) => Some(v as i64),
            Value::Uint32(v) => Some(v as i64),
            Value::Uint64(v) => i64::try_from(v).ok(),
            Value::Int32(v) => Some(v as i64),
            _ => None,
        }
    }

    /// Scalar doubles.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            Value::Double(v) => Some(v),
            _ => None,
        }
    }

    /// `VECTOR6D` values.
    pub fn as_vector6d(&self) -> Option<[f64; 6]> {
        match *self {
            Value::Vector6d(v) => Some(v),
            _ => None,
        }
    }
}

/// Controller software version from `v`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ControllerVersion {
    /// Major (3 = CB3, 5 = e-Series).
    pub major: u32,
    /// Minor.
    pub minor: u32,
    /// Bugfix.
    pub bugfix: u32,
    /// Build.
    pub build: u32,
}

impl std::fmt::Display for ControllerVersion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}.{}.{}.{}",
            self.major, self.minor, self.bugfix, self.build
        )
    }
}

/// A protocol-v2 text message (`M`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TextMessage {
    /// Message text (≤ 255 bytes on the wire).
    pub message: String,
    /// Source (≤ 255 bytes on the wire).
    pub source: String,
    /// 0 EXCEPTION, 1 ERROR, 2 WARNING, 3 INFO.
    pub level: u8,
}

/// Client → controller packages.
#[derive(Debug, Clone, PartialEq)]
pub enum Request {
    /// `V` + u16 version.
    ProtocolVersion(u16),
    /// `v`, empty.
    GetControllerVersion,
    /// `M`.
    Text(TextMessage),
    /// `O`: f64 frequency (Hz) + comma-separated names.
    SetupOutputs {
        /// Requested rate (Hz).
        frequency: f64,
        /// Variable names (empty trailing token already dropped).
        names: Vec<String>,
    },
    /// `I`: comma-separated input names.
    SetupInputs {
        /// Variable names.
        names: Vec<String>,
    },
    /// `S`.
    Start,
    /// `P`.
    Pause,
    /// `U`: input recipe id + raw fields (decode with the recipe's types).
    Data {
        /// Input recipe id.
        recipe_id: u8,
        /// Encoded fields.
        payload: Vec<u8>,
    },
}

/// Controller → client packages.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// `V` + u8 accepted.
    ProtocolVersion(bool),
    /// `v` + 4 × u32.
    ControllerVersion(ControllerVersion),
    /// `M`.
    Text(TextMessage),
    /// `O`: output recipe id + comma-separated type names (`NOT_FOUND` for unknown names).
    SetupOutputs {
        /// Output recipe id.
        recipe_id: u8,
        /// Type names in request order.
        types: Vec<String>,
    },
    /// `I`: input recipe id + type names (`IN_USE` / `NOT_FOUND` possible).
    SetupInputs {
        /// Input recipe id.
        recipe_id: u8,
        /// Type names in request order.
        types: Vec<String>,
    },
    /// `S` + u8 accepted.
    Start(bool),
    /// `P` + u8 accepted.
    Pause(bool),
    /// `U`: output recipe id + raw fields.
    Data {
        /// Output recipe id.
        recipe_id: u8,
        /// Encoded fields.
        payload: Vec<u8>,
    },
}

/// The RTDE type of a controller variable (protocols.md §1.3; URCL `data_package.cpp`, ur_rtde
/// `robot_state.cpp`). `None` for names the controller would answer `NOT_FOUND`.
pub fn variable_type(name: &str) -> Option<DataType> {
    use DataType::*;
    let t = match name {
        "timestamp"
        | "speed_scaling"
        | "target_speed_fraction"
        | "actual_momentum"
        | "actual_main_voltage"
        | "actual_robot_voltage"
        | "actual_robot_current"
        | "actual_execution_time"
        | "payload"
        | "standard_analog_input0"
        | "standard_analog_input1"
        | "standard_analog_output0"
        | "standard_analog_output1"
        | "speed_slider_fraction"
        | "standard_analog_output_0"
        | "standard_analog_output_1"
        | "tool_analog_input0"
        | "tool_analog_input1"
        | "tool_output_current"
        | "tool_temperature"
        | "io_current" => Double,
        "actual_q"
        | "target_q"
        | "actual_qd"
        | "target_qd"
        | "target_qdd"
        | "actual_TCP_pose"
        | "target_TCP_pose"
        | "actual_TCP_speed"
        | "target_TCP_speed"
        | "actual_TCP_force"
        | "target_current"
        | "target_moment"
        | "actual_current"
        | "joint_control_output"
        | "joint_temperatures"
        | "actual_joint_voltage"
        | "actual_current_as_torque"
        | "ft_raw_wrench"
        | "payload_inertia"
        | "tcp_offset"
        | "external_force_torque"
        | "actual_current_window" => Vector6d,
        "actual_tool_accelerometer" | "payload_cog" | "elbow_position" | "elbow_velocity" => {
            Vector3d
        }
        "robot_mode" | "safety_mode" | "safety_status" | "tool_mode" => Int32,
        "joint_mode" => Vector6Int32,
        "runtime_state"
        | "robot_status_bits"
        | "safety_status_bits"
        | "speed_slider_mask"
        | "output_bit_registers0_to_31"
        | "output_bit_registers32_to_63"
        | "input_bit_registers0_to_31"
        | "input_bit_registers32_to_63"
        | "tool_output_voltage"
        | "analog_io_types"
        | "tool_analog_input_types"
        | "euromap67_input_bits"
        | "euromap67_output_bits" => Uint32,
        "actual_digital_input_bits" | "actual_digital_output_bits" => Uint64,
        "standard_digital_output_mask"
        | "standard_digital_output"
        | "configurable_digital_output_mask"
        | "configurable_digital_output"
        | "tool_digital_output_mask"
        | "tool_digital_output"
        | "standard_analog_output_mask"
        | "standard_analog_output_type" => Uint8,
        _ => return register_type(name),
    };
    Some(t)
}

fn register_type(name: &str) -> Option<DataType> {
    let (prefix, t, lo, hi) = [
        ("output_int_register_", DataType::Int32, 0, 47),
        ("input_int_register_", DataType::Int32, 0, 47),
        ("output_double_register_", DataType::Double, 0, 47),
        ("input_double_register_", DataType::Double, 0, 47),
        ("output_bit_register_", DataType::Bool, 64, 127),
        ("input_bit_register_", DataType::Bool, 64, 127),
    ]
    .into_iter()
    .find(|(p, ..)| name.starts_with(p))?;
    let idx = &name[prefix.len()..];
    if idx.is_empty() || idx.len() > 3 || !idx.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let n: u32 = idx.parse().ok()?;
    (lo..=hi).contains(&n).then_some(t)
}

/// Parse a register name (`input_int_register_12` → `("input_int_register_", 12)`).
pub fn register_index(name: &str, prefix: &str) -> Option<usize> {
    let rest = name.strip_prefix(prefix)?;
    if rest.is_empty() || rest.len() > 3 || !rest.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    rest.parse().ok()
}

/// `robot_mode` values (protocols.md §1.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RobotMode {
    /// -1.
    NoController,
    /// 0.
    Disconnected,
    /// 1.
    ConfirmSafety,
    /// 2.
    Booting,
    /// 3.
    PowerOff,
    /// 4.
    PowerOn,
    /// 5.
    Idle,
    /// 6.
    Backdrive,
    /// 7.
    Running,
    /// 8.
    UpdatingFirmware,
}

impl RobotMode {
    const TABLE: [(RobotMode, i32, &'static str); 10] = [
        (RobotMode::NoController, -1, "NO_CONTROLLER"),
        (RobotMode::Disconnected, 0, "DISCONNECTED"),
        (RobotMode::ConfirmSafety, 1, "CONFIRM_SAFETY"),
        (RobotMode::Booting, 2, "BOOTING"),
        (RobotMode::PowerOff, 3, "POWER_OFF"),
        (RobotMode::PowerOn, 4, "POWER_ON"),
        (RobotMode::Idle, 5, "IDLE"),
        (RobotMode::Backdrive, 6, "BACKDRIVE"),
        (RobotMode::Running, 7, "RUNNING"),
        (RobotMode::UpdatingFirmware, 8, "UPDATING_FIRMWARE"),
    ];
    /// From the RTDE integer.
    pub fn from_i32(v: i32) -> Option<Self> {
        Self::TABLE.iter().find(|e| e.1 == v).map(|e| e.0)
    }
    /// The RTDE integer.
    pub fn as_i32(self) -> i32 {
        Self::TABLE.iter().find(|e| e.0 == self).map_or(-1, |e| e.1)
    }
    /// The dashboard name (`RUNNING`).
    pub fn name(self) -> &'static str {
        Self::TABLE.iter().find(|e| e.0 == self).map_or("", |e| e.2)
    }
    /// From the dashboard name.
    pub fn from_name(s: &str) -> Option<Self> {
        Self::TABLE.iter().find(|e| e.2 == s).map(|e| e.0)
    }
}

/// `safety_mode` values (protocols.md §1.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SafetyMode {
    /// 1.
    Normal,
    /// 2.
    Reduced,
    /// 3.
    ProtectiveStop,
    /// 4.
    Recovery,
    /// 5.
    SafeguardStop,
    /// 6.
    SystemEmergencyStop,
    /// 7.
    RobotEmergencyStop,
    /// 8.
    Violation,
    /// 9.
    Fault,
    /// 10.
    ValidateJointId,
    /// 11.
    Undefined,
    /// 12.
    AutomaticModeSafeguardStop,
    /// 13.
    SystemThreePositionEnablingStop,
}

impl SafetyMode {
    const TABLE: [(SafetyMode, i32, &'static str); 13] = [
        (SafetyMode::Normal, 1, "NORMAL"),
        (SafetyMode::Reduced, 2, "REDUCED"),
        (SafetyMode::ProtectiveStop, 3, "PROTECTIVE_STOP"),
        (SafetyMode::Recovery, 4, "RECOVERY"),
        (SafetyMode::SafeguardStop, 5, "SAFEGUARD_STOP"),
        (SafetyMode::SystemEmergencyStop, 6, "SYSTEM_EMERGENCY_STOP"),
        (SafetyMode::RobotEmergencyStop, 7, "ROBOT_EMERGENCY_STOP"),
        (SafetyMode::Violation, 8, "VIOLATION"),
        (SafetyMode::Fault, 9, "FAULT"),
        (SafetyMode::ValidateJointId, 10, "VALIDATE_JOINT_ID"),
        (SafetyMode::Undefined, 11, "UNDEFINED_SAFETY_MODE"),
        (
            SafetyMode::AutomaticModeSafeguardStop,
            12,
            "AUTOMATIC_MODE_SAFEGUARD_STOP",
        ),
        (
            SafetyMode::SystemThreePositionEnablingStop,
            13,
            "SYSTEM_THREE_POSITION_ENABLING_STOP",
        ),
    ];
    /// From the RTDE integer.
    pub fn from_i32(v: i32) -> Option<Self> {
        Self::TABLE.iter().find(|e| e.1 == v).map(|e| e.0)
    }
    /// The RTDE integer.
    pub fn as_i32(self) -> i32 {
        Self::TABLE.iter().find(|e| e.0 == self).map_or(11, |e| e.1)
    }
    /// The dashboard name (`PROTECTIVE_STOP`).
    pub fn name(self) -> &'static str {
        Self::TABLE.iter().find(|e| e.0 == self).map_or("", |e| e.2)
    }
    /// From the dashboard name.
    pub fn from_name(s: &str) -> Option<Self> {
        Self::TABLE.iter().find(|e| e.2 == s).map(|e| e.0)
    }
}

/// `runtime_state` values.
pub mod runtime_state {
    /// 0.
    pub const STOPPING: u32 = 0;
    /// 1.
    pub const STOPPED: u32 = 1;
    /// 2.
    pub const PLAYING: u32 = 2;
    /// 3.
    pub const PAUSING: u32 = 3;
    /// 4.
    pub const PAUSED: u32 = 4;
    /// 5.
    pub const RESUMING: u32 = 5;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variable_types_match_the_brief() {
        assert_eq!(variable_type("actual_q"), Some(DataType::Vector6d));
        assert_eq!(variable_type("robot_mode"), Some(DataType::Int32));
        assert_eq!(variable_type("runtime_state"), Some(DataType::Uint32));
        assert_eq!(
            variable_type("actual_digital_input_bits"),
            Some(DataType::Uint64)
        );
        assert_eq!(
            variable_type("output_int_register_47"),
            Some(DataType::Int32)
        );
        assert_eq!(variable_type("output_int_register_48"), None);
        assert_eq!(variable_type("input_bit_register_64"), Some(DataType::Bool));
        assert_eq!(variable_type("input_bit_register_63"), None);
        assert_eq!(variable_type("output_int_register_+1"), None);
        assert_eq!(variable_type("nonsense"), None);
    }

    #[test]
    fn enum_tables_round_trip() {
        for v in -1..=8 {
            assert_eq!(RobotMode::from_i32(v).unwrap().as_i32(), v);
        }
        for v in 1..=13 {
            let m = SafetyMode::from_i32(v).unwrap();
            assert_eq!(SafetyMode::from_name(m.name()), Some(m));
        }
    }
}
