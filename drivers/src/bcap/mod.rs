//! DENSO b-CAP (ORiN2; RC8 / RC8A / COBOTTA / RC9) over TCP 5007.
//!
//! Layers: [`frame`] (packets, VARIANTs, function ids, HRESULTs), [`codec`] (bytes, LE, capped
//! allocations), [`client`] (session: serials, deadlines, `S_EXECUTING`), [`arm::DensoArm`]
//! (capability traits). Units: the wire speaks degrees and millimetres; the traits radians and
//! millimetres.
//!
//! # Safety
//! The raw client and [`arm::DensoArm`] move the robot without limit checks: the engine must
//! only hold a DENSO arm wrapped by [`crate::safety::guard`].

pub mod arm;
pub mod client;
pub mod codec;
pub mod error;
pub mod frame;

pub use arm::{DensoArm, DensoConfig};
pub use client::BcapClient;
pub use error::BcapError;
pub use frame::{Packet, Variant};

/// Joint speed that `SPEED=100` stands for (deg/s). Shared convention of the driver and the
/// simulator; a real controller scales by its own per-axis maxima.
pub const NOMINAL_MAX_VEL_DEG_S: f64 = 180.0;
/// Joint acceleration that `ACCEL=100` stands for (deg/s²).
pub const NOMINAL_MAX_ACC_DEG_S2: f64 = 360.0;
