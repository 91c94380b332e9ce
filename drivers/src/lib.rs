//! Device capability traits, safety wrappers and real protocol clients.
//!
//! Each protocol is layered `frame` (pure data) / `codec` (bytes, no I/O) / `client`
//! (session, sequencing, deadlines). Every device error maps to a shared [`ErrorKind`]
//! so the acquisition engine can decide retry / skip / abort without knowing the vendor.
#![warn(missing_docs)]

pub mod bcap;
pub mod camera;
pub mod error;
pub mod fake;
pub mod keyence;
mod link;
pub mod ndi;
pub mod optotrak;
pub mod safety;
pub mod traits;
pub mod ur;

pub use error::{DeviceError, DriverError, DriverResult, ErrorKind};
pub use traits::*;
