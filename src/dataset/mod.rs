//! `robocal-dataset/1` (JSON Lines) and `robocal-calibration/1` file types.
//!
//! The contract is `docs/dataset-format.md` (copied from the shared docs). Files use mm,
//! degrees, seconds; quaternions are `[w, x, y, z]`. Unknown fields are kept in `extra`
//! so a read → write round trip preserves them.

pub mod types;
pub use types::*;
