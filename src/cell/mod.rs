//! The cell: the one place that turns a scenario or a device file into connected drivers and
//! drives them through a plan into a run directory.
//!
//! - [`run`]: the run directory (`robocal-run/1`: `run.json`, the plan and cell file copies, the
//!   dataset journal, `summary.json`), the dataset header, resume, the acquisition of a
//!   [`RunRequest`] ([`run::run`]);
//! - [`safety`]: the safety limits the arm is wrapped in, and the consent to move hardware;
//! - [`sim`] (in-process simulators), [`wire`] (simulators behind the real protocols on
//!   loopback / ptys, the real drivers connected to them), [`live`] (real hardware);
//! - [`describe`]: a scenario or a device file read into the session's cell description;
//! - [`checks`]: the input checks of a run that need the cell (plan against the cell's robot,
//!   speed / acceleration caps within its limits).
//!
//! Only this module (and the evaluation harnesses in [`crate::trials`]) wires the simulators
//! in; the acquisition engine ([`crate::acquire`]) sees only the device traits.
pub mod checks;
pub mod describe;
pub mod live;
pub mod run;
pub mod safety;
pub mod sim;
pub mod wire;

pub use run::{
    parse_board, run, CameraUse, Interrupted, RunConfig, RunOutcome, RunProgress, RunRequest,
    RunStart,
};
pub use safety::{confirm_live, safety_limits, LiveConsent};
pub use sim::{sim_cell, sim_world, CellInfo};
pub use wire::wire_cell;
