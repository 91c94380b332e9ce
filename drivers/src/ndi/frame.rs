//! Pure data types of the NDI Combined API (no I/O, no parsing).

/// One reply from the tracker, after framing and CRC checks.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// `OKAY`.
    Okay,
    /// `ERRORxx`: the device refused the command with code `xx`.
    Error(u8),
    /// `RESET` (after a serial BREAK).
    Reset,
    /// Any other text reply (CRC stripped; may contain `\n` between lines).
    Text(String),
    /// A binary reply body (`BX`): the bytes between the 6-byte header and the body CRC.
    Binary(Vec<u8>),
}

/// The state of one port handle in a tracking reply.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HandleState {
    /// A transform: quaternion `[q0, qx, qy, qz]`, translation (mm), fit RMS error (mm).
    Valid {
        /// `[q0, qx, qy, qz]` as sent (not re-normalised).
        q: [f64; 4],
        /// Translation (mm).
        t: [f64; 3],
        /// RMS fit error (mm).
        rms: f64,
    },
    /// Enabled but not seen.
    Missing,
    /// Not enabled.
    Disabled,
}

/// One handle's record in a `BX` / `TX` reply.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandleRecord {
    /// Port handle (1..=255).
    pub handle: u8,
    /// Transform or status.
    pub state: HandleState,
    /// Port status bits (0x01 tool in port, 0x10 initialized, 0x20 enabled, 0x40 out of volume,
    /// 0x80 partially in volume); 0 when the device sent none (disabled).
    pub port_status: u32,
    /// The tracker's frame counter (60 Hz on Polaris); 0 when the device sent none.
    pub frame: u32,
}

/// Port status bit: out of the characterised volume.
pub const PORT_OUT_OF_VOLUME: u32 = 0x40;
/// Port status bit: partially out of volume.
pub const PORT_PARTIALLY_IN_VOLUME: u32 = 0x80;

/// A decoded `BX` or `TX` reply (option 0x0001, optionally 0x0800).
#[derive(Debug, Clone, PartialEq)]
pub struct TrackingReply {
    /// One record per reported handle (UNOCCUPIED handles are skipped).
    pub handles: Vec<HandleRecord>,
    /// System status word.
    pub system_status: u16,
}

/// One entry of a `PHSR` reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PortHandleStatus {
    /// Handle.
    pub handle: u8,
    /// 3-hex-digit status.
    pub status: u16,
}

/// Human description of an NDI `ERRORxx` code (subset from the Combined API / ndicapi.h).
pub fn error_description(code: u8) -> &'static str {
    match code {
        0x01 => "invalid command",
        0x02 => "command too long",
        0x03 => "command too short",
        0x04 => "invalid CRC calculated for command",
        0x05 => "time-out on command execution",
        0x06 => "unable to set up new communication parameters",
        0x07 => "incorrect number of command parameters",
        0x08 => "invalid port handle selected",
        0x09 => "invalid mode selected",
        0x0A => "invalid LED selected",
        0x0B => "invalid LED state selected",
        0x0C => "command is invalid while in the current operating mode",
        0x0D => "no tool is assigned to the selected port handle",
        0x0E => "selected port handle not initialized",
        0x0F => "selected port handle not enabled",
        0x10 => "system not initialized",
        0x11 => "unable to stop tracking",
        0x12 => "unable to start tracking",
        0x13 => "unable to initialize port handle",
        0x1F => "SROM device write failed",
        0x23 => "parameter out of range",
        0x28 => "too many tools enabled",
        0x2B => "port handle not allocated",
        0x2C => "port handle unoccupied",
        0x2D => "all port handles allocated",
        0x33 => "feature not available",
        0x3B => "file not found",
        0x40 => "tool definition file error",
        0x42 => "device not present",
        0xF1 => "too much environmental infrared",
        _ => "unknown error code",
    }
}
