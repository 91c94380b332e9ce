//! NDI Combined API (Polaris Vega over TCP, Polaris Spectra / Vicra over serial).
//!
//! Layers: [`frame`] (pure data: replies, tracking records), [`codec`] (CRC-16/ARC, command
//! encoding, reply framing and the `BX` / `TX` / `PHSR` decoders; no I/O), [`client`] (the
//! session with deadlines, tool loading, tracking) and [`NdiTracker`] (the [`crate::MarkerTracker`]
//! capability).
//!
//! Units: translations in mm, rotations as unit quaternions (the wire's `Q0 Qx Qy Qz`).
//! Wire facts follow NDI's Combined API as implemented by `PlusToolkit/ndicapi` (the client
//! scikit-surgerynditracker uses).

pub mod client;
pub mod codec;
pub mod error;
pub mod frame;
pub mod tracker;

pub use client::{NdiClient, NdiConfig};
pub use error::Error;
pub use frame::{HandleRecord, HandleState, Reply, TrackingReply};
pub use tracker::{NdiTracker, ReplyMode};
