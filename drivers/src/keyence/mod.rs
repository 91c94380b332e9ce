//! KEYENCE IL-series amplifier (IL-1000) with an IL-600 head, read through the DL-RS1A
//! RS-232C unit.
//!
//! Layers: [`frame`] (requests, replies, measured values), [`codec`] (ASCII lines, no I/O),
//! [`client`] (one command at a time with a deadline, resynchronising after garbage) and
//! [`Il600`] (the [`crate::RangeSensor`] capability).
//!
//! Wire facts (KEYENCE "DL-RS1A User's Manual (IL edition)", as quoted in
//! `docs/protocols.md` §3): 9600 8N1 by default, `\r\n` delimiter, `M0` / `MS` / `SR` / `SW` / `AW`
//! commands, `ER,<cmd>,<nn>` errors, IL-600 values as `±***.**` (mm), special values
//! `+EEE.EE` (amplifier error), `+999.99` / `-999.99` (display limits).
//!
//! Not confirmed from a primary source (the driver copes as stated):
//! * the string sent for the amplifier's `-----` display (no valid measurement): any
//!   non-numeric field made of the manual's value characters (`+ - . 0-9 A-Z`) other than
//!   `+EEE.EE` is read as "no measurement" → [`crate::RangeReading::OutOfRange`];
//! * the IL-edition reply timeout (the IG edition says 1 s, the FD-MH edition 500 ms): the
//!   default deadline is 1 s;
//! * whether the displayed value is relative to the head's reference distance (600 mm for
//!   the IL-600) depends on the amplifier's settings: [`Il600Config::offset_mm`] is added to
//!   the displayed value to give the distance (default 600 mm).

pub mod client;
pub mod codec;
pub mod error;
pub mod frame;

pub use client::{Il600, Il600Config, KeyenceClient, KeyenceConfig};
pub use error::Error;
pub use frame::{Reply, Request, Value};
