//! The cell: the one place that turns a scenario or a device file into connected drivers and
//! drives them through a plan into a run directory.
//!
//! - [`source`]: the one interface of a cell ([`CellSource`]: what its file states, its devices
//!   opened), implemented by `simulated::ScenarioCell` and [`live::DeviceFileCell`];
//! - [`run`]: the run directory (`robocal-run/1`: `run.json`, the plan and cell file copies, the
//!   dataset journal, `summary.json`), the dataset header, resume, the acquisition of a
//!   [`RunRequest`] ([`run::run`]);
//! - [`safety`]: the safety limits the arm is wrapped in, and the consent to move hardware;
//! - `simulated` (the simulators, in process or behind the real protocols on loopback /
//!   ptys: the only module that reaches them, through their truth-free face; built with the
//!   feature `sim` only, see [`without_simulators`]), [`live`] (real hardware);
//! - [`describe`]: a scenario or a device file read into the session's cell description;
//! - [`checks`]: the input checks of a run that need the cell (plan against the cell's robot,
//!   speed / acceleration caps within its limits).
//!
//! The acquisition engine ([`crate::acquire`]) sees only the device traits.
// Every public item of the cell says what it is: the cell is where a scenario or a device file
// becomes hardware, and an undocumented field there is a guess at the safety of a move.
#![warn(missing_docs)]

pub mod checks;
pub mod describe;
pub mod live;
pub mod run;
pub mod safety;
#[cfg(feature = "sim")]
pub mod simulated;
pub mod source;

pub use run::{
    parse_board, run, CameraUse, Interrupted, RunConfig, RunOutcome, RunProgress, RunRequest,
    RunStart,
};
pub use safety::{confirm_live, safety_limits, LiveConsent};
#[cfg(feature = "sim")]
pub use simulated::{sim_cell, wire_cell, SimCell};
pub use source::{
    CellInfo, CellSource, OpenCell, OpenOptions, StatedArm, StatedCamera, StatedCell,
};

/// The error of a `--sim` path (a dry run, `robocal sim serve`, a simulated session) in a build
/// without the simulators: `what` is what was asked for (`--sim SCENARIO.toml`, ...).
pub fn without_simulators(what: &str) -> anyhow::Error {
    anyhow::anyhow!(
        "{what}: this robocal was built without the simulators (feature `sim`); rebuild with \
         the default features (`cargo build --release`) for dry runs, or drive real hardware \
         with --devices CELL.toml --live"
    )
}
