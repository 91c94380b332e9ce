//! b-CAP packets and VARIANTs as pure data (`docs/protocols.md` §2.2–2.5; DENSO `orin_bcap`
//! `C/include/bcap_common.h`, `Python/bCAPClient/bcapclient.py`).

/// Start of a packet.
pub const SOH: u8 = 0x01;
/// End of a packet.
pub const EOT: u8 = 0x04;
/// Bytes of a packet without arguments (SOH, len, serial, reserved, id, argc, EOT).
pub const MIN_PACKET: usize = 16;
/// Largest packet this crate accepts (allocation cap; real packets are far smaller).
pub const MAX_PACKET: usize = 1 << 20;
/// Deepest nesting of VARIANT arrays accepted.
pub const MAX_DEPTH: usize = 4;

/// Function ids used here (protocols.md §2.3).
pub mod func {
    /// Service_Start(BSTR option).
    pub const SERVICE_START: i32 = 1;
    /// Service_Stop().
    pub const SERVICE_STOP: i32 = 2;
    /// Controller_Connect(name, provider, machine, option) → handle.
    pub const CONTROLLER_CONNECT: i32 = 3;
    /// Controller_Disconnect(handle).
    pub const CONTROLLER_DISCONNECT: i32 = 4;
    /// Controller_GetRobot(handle, name, option) → robot handle.
    pub const CONTROLLER_GET_ROBOT: i32 = 7;
    /// Controller_GetVariable(handle, name, option) → variable handle.
    pub const CONTROLLER_GET_VARIABLE: i32 = 9;
    /// Controller_GetRobotNames(handle, option) → BSTR array.
    pub const CONTROLLER_GET_ROBOT_NAMES: i32 = 13;
    /// Controller_Execute(handle, command, param) → VARIANT.
    pub const CONTROLLER_EXECUTE: i32 = 17;
    /// Robot_GetVariable(robot, name, option) → variable handle.
    pub const ROBOT_GET_VARIABLE: i32 = 62;
    /// Robot_Execute(robot, command, param) → VARIANT.
    pub const ROBOT_EXECUTE: i32 = 64;
    /// Robot_Halt(robot, option).
    pub const ROBOT_HALT: i32 = 70;
    /// Robot_Move(robot, I4 comp, pose, option).
    pub const ROBOT_MOVE: i32 = 72;
    /// Robot_Release(robot).
    pub const ROBOT_RELEASE: i32 = 84;
    /// Variable_GetValue(variable) → VARIANT.
    pub const VARIABLE_GET_VALUE: i32 = 101;
    /// Variable_PutValue(variable, VARIANT).
    pub const VARIABLE_PUT_VALUE: i32 = 102;
    /// Variable_Release(variable).
    pub const VARIABLE_RELEASE: i32 = 111;
}

/// HRESULTs (protocols.md §2.5; `orin_bcap` `dn_common.h`, `orinexception.py`).
pub mod hresult {
    /// Success.
    pub const S_OK: i32 = 0;
    /// Success, false.
    pub const S_FALSE: i32 = 1;
    /// Still executing (keepalive reply; the final reply follows).
    pub const S_EXECUTING: i32 = 0x0000_0900;
    /// Not implemented.
    pub const E_NOTIMPL: i32 = 0x8000_4001_u32 as i32;
    /// Unspecified failure.
    pub const E_FAIL: i32 = 0x8000_4005_u32 as i32;
    /// Access denied (e.g. arm not taken).
    pub const E_ACCESSDENIED: i32 = 0x8007_0005_u32 as i32;
    /// Bad handle.
    pub const E_HANDLE: i32 = 0x8007_0006_u32 as i32;
    /// Invalid argument.
    pub const E_INVALIDARG: i32 = 0x8007_0057_u32 as i32;
    /// Unexpected.
    pub const E_UNEXPECTED: i32 = 0x8000_FFFF_u32 as i32;
    /// The controller's invoke timeout expired.
    pub const E_TIMEOUT: i32 = 0x8000_0900_u32 as i32;
    /// Service not started.
    pub const E_NOT_CONNECTED: i32 = 0x8000_0902_u32 as i32;
    /// Unknown command name.
    pub const E_INVALID_CMD_NAME: i32 = 0x8000_0904_u32 as i32;
    /// Unsupported VARIANT type.
    pub const E_CAO_VARIANT_TYPE_NOSUPPORT: i32 = 0x8000_0203_u32 as i32;
    /// Unknown object name.
    pub const E_CAO_OBJECT_NOTFOUND: i32 = 0x8000_0204_u32 as i32;
    /// Command failed.
    pub const E_CAO_CMD_EXECUTE: i32 = 0x8000_020B_u32 as i32;
    /// A request arrived while another was executing.
    pub const E_BUSY_PROC: i32 = 0x8091_00AA_u32 as i32;
    /// Motor off / servo not ready (**simulator code**: the exact RC8 value is UNVERIFIED).
    pub const E_SIM_MOTOR_OFF: i32 = 0x8320_0041_u32 as i32;
    /// Motion stopped by a protective stop / collision detection (**simulator code**, UNVERIFIED).
    pub const E_SIM_PROTECTIVE_STOP: i32 = 0x8350_0121_u32 as i32;
    /// Target outside the joint range (**simulator code**, UNVERIFIED).
    pub const E_SIM_OUT_OF_RANGE: i32 = 0x8420_1482_u32 as i32;

    /// A short name for a known code.
    pub fn name(code: i32) -> &'static str {
        match code {
            S_OK => "S_OK",
            S_FALSE => "S_FALSE",
            S_EXECUTING => "S_EXECUTING",
            E_NOTIMPL => "E_NOTIMPL",
            E_FAIL => "E_FAIL",
            E_ACCESSDENIED => "E_ACCESSDENIED",
            E_HANDLE => "E_HANDLE",
            E_INVALIDARG => "E_INVALIDARG",
            E_UNEXPECTED => "E_UNEXPECTED",
            E_TIMEOUT => "E_TIMEOUT",
            E_NOT_CONNECTED => "E_NOT_CONNECTED",
            E_INVALID_CMD_NAME => "E_INVALID_CMD_NAME",
            E_CAO_VARIANT_TYPE_NOSUPPORT => "E_CAO_VARIANT_TYPE_NOSUPPORT",
            E_CAO_OBJECT_NOTFOUND => "E_CAO_OBJECT_NOTFOUND",
            E_CAO_CMD_EXECUTE => "E_CAO_CMD_EXECUTE",
            E_BUSY_PROC => "E_BUSY_PROC",
            E_SIM_MOTOR_OFF => "motor off",
            E_SIM_PROTECTIVE_STOP => "motion stopped (protective stop)",
            E_SIM_OUT_OF_RANGE => "target out of range",
            _ => "controller error",
        }
    }
}

/// VARIANT type codes (protocols.md §2.2).
pub mod vt {
    /// VT_EMPTY.
    pub const EMPTY: u16 = 0;
    /// VT_NULL.
    pub const NULL: u16 = 1;
    /// VT_I2.
    pub const I2: u16 = 2;
    /// VT_I4.
    pub const I4: u16 = 3;
    /// VT_R4.
    pub const R4: u16 = 4;
    /// VT_R8.
    pub const R8: u16 = 5;
    /// VT_CY.
    pub const CY: u16 = 6;
    /// VT_DATE.
    pub const DATE: u16 = 7;
    /// VT_BSTR.
    pub const BSTR: u16 = 8;
    /// VT_ERROR.
    pub const ERROR: u16 = 10;
    /// VT_BOOL.
    pub const BOOL: u16 = 11;
    /// VT_VARIANT (only inside arrays).
    pub const VARIANT: u16 = 12;
    /// VT_UI1.
    pub const UI1: u16 = 17;
    /// VT_UI2.
    pub const UI2: u16 = 18;
    /// VT_UI4.
    pub const UI4: u16 = 19;
    /// VT_I8.
    pub const I8: u16 = 20;
    /// VT_UI8.
    pub const UI8: u16 = 21;
    /// Array flag.
    pub const ARRAY: u16 = 0x2000;
}

/// A b-CAP VARIANT.
#[derive(Debug, Clone, PartialEq)]
pub enum Variant {
    /// VT_EMPTY ("no argument").
    Empty,
    /// VT_NULL.
    Null,
    /// VT_I2.
    I2(i16),
    /// VT_I4.
    I4(i32),
    /// VT_R4.
    R4(f32),
    /// VT_R8.
    R8(f64),
    /// VT_CY (int64).
    Cy(i64),
    /// VT_DATE (days since 1899-12-30).
    Date(f64),
    /// VT_BSTR (UTF-16LE on the wire).
    Bstr(String),
    /// VT_ERROR.
    Error(i32),
    /// VT_BOOL (-1 / 0 on the wire).
    Bool(bool),
    /// VT_UI1.
    Ui1(u8),
    /// VT_UI2.
    Ui2(u16),
    /// VT_UI4.
    Ui4(u32),
    /// VT_I8.
    I8(i64),
    /// VT_UI8.
    Ui8(u64),
    /// VT_I2 | VT_ARRAY.
    I2Array(Vec<i16>),
    /// VT_I4 | VT_ARRAY.
    I4Array(Vec<i32>),
    /// VT_R4 | VT_ARRAY.
    R4Array(Vec<f32>),
    /// VT_R8 | VT_ARRAY.
    R8Array(Vec<f64>),
    /// VT_BSTR | VT_ARRAY.
    BstrArray(Vec<String>),
    /// VT_BOOL | VT_ARRAY.
    BoolArray(Vec<bool>),
    /// VT_UI1 | VT_ARRAY (byte array).
    Ui1Array(Vec<u8>),
    /// VT_VARIANT | VT_ARRAY.
    VariantArray(Vec<Variant>),
}

impl Variant {
    /// A handle, whether sent as VT_I4 (Python client) or VT_UI4 (ROS), or smaller ints.
    pub fn as_handle(&self) -> Option<i32> {
        match *self {
            Variant::I4(v) => Some(v),
            Variant::Ui4(v) => i32::try_from(v).ok(),
            Variant::I2(v) => Some(v as i32),
            Variant::Ui2(v) => Some(v as i32),
            Variant::Ui1(v) => Some(v as i32),
            _ => None,
        }
    }
    /// Integer-valued scalars.
    pub fn as_i64(&self) -> Option<i64> {
        match *self {
            Variant::I2(v) => Some(v as i64),
            Variant::I4(v) | Variant::Error(v) => Some(v as i64),
            Variant::Ui1(v) => Some(v as i64),
            Variant::Ui2(v) => Some(v as i64),
            Variant::Ui4(v) => Some(v as i64),
            Variant::I8(v) | Variant::Cy(v) => Some(v),
            Variant::Ui8(v) => i64::try_from(v).ok(),
            Variant::Bool(b) => Some(if b { -1 } else { 0 }),
            Variant::R8(v) if v.fract() == 0.0 && v.abs() < 9e15 => Some(v as i64),
            Variant::R4(v) if v.fract() == 0.0 && v.abs() < 1e9 => Some(v as i64),
            _ => None,
        }
    }
    /// Numeric scalars as f64.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            Variant::R8(v) | Variant::Date(v) => Some(v),
            Variant::R4(v) => Some(v as f64),
            _ => self.as_i64().map(|v| v as f64),
        }
    }
    /// Numeric arrays as `Vec<f64>`.
    pub fn as_f64_vec(&self) -> Option<Vec<f64>> {
        match self {
            Variant::R8Array(v) => Some(v.clone()),
            Variant::R4Array(v) => Some(v.iter().map(|x| *x as f64).collect()),
            Variant::I4Array(v) => Some(v.iter().map(|x| *x as f64).collect()),
            Variant::I2Array(v) => Some(v.iter().map(|x| *x as f64).collect()),
            Variant::VariantArray(v) => v.iter().map(Variant::as_f64).collect(),
            _ => None,
        }
    }
    /// Integer arrays as `Vec<i64>`.
    pub fn as_i64_vec(&self) -> Option<Vec<i64>> {
        match self {
            Variant::I4Array(v) => Some(v.iter().map(|x| *x as i64).collect()),
            Variant::I2Array(v) => Some(v.iter().map(|x| *x as i64).collect()),
            Variant::Ui1Array(v) => Some(v.iter().map(|x| *x as i64).collect()),
            Variant::R8Array(v) => v.iter().map(|x| Variant::R8(*x).as_i64()).collect(),
            Variant::VariantArray(v) => v.iter().map(Variant::as_i64).collect(),
            _ => None,
        }
    }
    /// BSTR text.
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Variant::Bstr(s) => Some(s),
            _ => None,
        }
    }
    /// Booleans (VT_BOOL or any integer, non-zero = true).
    pub fn as_bool(&self) -> Option<bool> {
        match *self {
            Variant::Bool(b) => Some(b),
            _ => self.as_i64().map(|v| v != 0),
        }
    }
}

/// One b-CAP packet (request or reply; TCP, so no CRC).
#[derive(Debug, Clone, PartialEq)]
pub struct Packet {
    /// Serial number (1..65535, never 0 in requests).
    pub serial: u16,
    /// Reserved / version field (0 on TCP).
    pub reserved: u16,
    /// Request: function id; reply: HRESULT.
    pub code: i32,
    /// Arguments (request) or return values (reply).
    pub args: Vec<Variant>,
}

impl Packet {
    /// A request.
    pub fn request(serial: u16, func: i32, args: Vec<Variant>) -> Self {
        Self {
            serial,
            reserved: 0,
            code: func,
            args,
        }
    }
    /// A reply.
    pub fn reply(serial: u16, hresult: i32, args: Vec<Variant>) -> Self {
        Self {
            serial,
            reserved: 0,
            code: hresult,
            args,
        }
    }
}
