//! Pure data of the DL-RS1A protocol.

/// A command to the DL-RS1A.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Request {
    /// `M0`: measured values of every amplifier.
    M0,
    /// `MS`: control outputs and measured values of every amplifier.
    Ms,
    /// `SR,<id>,<data no>`: read one item of one amplifier.
    Sr {
        /// Amplifier ID (00 main unit, 01..14 expansion units).
        id: u8,
        /// Data number (e.g. 037 judgment value, 038 internal measurement value).
        data_no: u16,
    },
    /// `SW,<id>,<data no>,<value>`: write one item.
    Sw {
        /// Amplifier ID.
        id: u8,
        /// Data number.
        data_no: u16,
        /// Value text.
        value: String,
    },
    /// `AW,<data no>,<value>`: write one item to all amplifiers.
    Aw {
        /// Data number.
        data_no: u16,
        /// Value text.
        value: String,
    },
}

impl Request {
    /// The two-letter command (`M0`, `MS`, `SR`, `SW`, `AW`).
    pub fn command(&self) -> &'static str {
        match self {
            Request::M0 => "M0",
            Request::Ms => "MS",
            Request::Sr { .. } => "SR",
            Request::Sw { .. } => "SW",
            Request::Aw { .. } => "AW",
        }
    }
}

/// One measured-value field.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// A number (mm for the IL-600).
    Measured(f64),
    /// `+EEE.EE`: the amplifier is in an error state.
    AmplifierError,
    /// `+999.99` (IL-600 form): at or above the upper display limit.
    UpperLimit,
    /// `-999.99`: at or below the lower display limit.
    LowerLimit,
    /// Any other non-numeric field (the `-----` display; exact string unverified).
    NoMeasurement(String),
}

/// A reply line.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// `M0,<v00>,<v01>,...`.
    M0(Vec<Value>),
    /// `MS,<out00>,<v00>,<out01>,<v01>,...`: control output (2 digits) and value per amplifier.
    Ms(Vec<(u8, Value)>),
    /// `SR,<id>,<data no>,<data>`.
    Sr {
        /// Amplifier ID.
        id: u8,
        /// Data number.
        data_no: u16,
        /// Data as sent.
        data: String,
    },
    /// `SW,<id>,<data no>`.
    Sw {
        /// Amplifier ID.
        id: u8,
        /// Data number.
        data_no: u16,
    },
    /// `AW,<data no>`.
    Aw {
        /// Data number.
        data_no: u16,
    },
    /// `ER,<cmd>,<nn>`: the unit refused the command.
    Er {
        /// The command it refers to.
        command: String,
        /// Error number (00 invalid command, 20 data length, 21 parameter count,
        /// 22 parameter, 29 communication, 65 ID, 66 expansion line, 67 write control).
        code: u8,
    },
}

/// Human description of a DL-RS1A error number.
pub fn error_description(code: u8) -> &'static str {
    match code {
        0 => "invalid command",
        20 => "data length error (delimiter)",
        21 => "wrong number of parameters",
        22 => "parameter error",
        29 => "RS-232C communication error",
        65 => "ID number error (no amplifier with that ID)",
        66 => "expansion line error",
        67 => "write control error (read-only switch)",
        _ => "unknown error number",
    }
}
