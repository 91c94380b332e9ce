//! `robocal calibrate <what>`: one file per calibration under `src/cli/calibrate/`.

pub mod camera;
pub mod kinematics;
pub mod laser;
pub mod navchain;
pub mod nominal;
pub mod pivot;
pub mod rcm;
pub mod robot_world;
pub mod tool;

/// Arguments of `robocal calibrate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub what: What,
}

/// What to calibrate.
#[derive(Debug, clap::Subcommand)]
pub enum What {
    /// Nominal model with only the tracker→base and flange→marker transforms fitted (the "before").
    Nominal(nominal::Args),
    /// Full kinematic identification (MDH + Hayati, base, tool), bootstrap, metrics.
    Kinematics(kinematics::Args),
    /// Pivot calibration of a probe tip from `pivot` records.
    Pivot(pivot::Args),
    /// Laser range sensor hand-eye calibration from planes (seed 000).
    Laser(laser::Args),
    /// Endoscope camera hand-eye from the instrument shaft under a remote centre of motion (seed 002).
    Rcm(rcm::Args),
    /// Tracker ↔ robot base (AX = YB: Shah, Li, Tsai; LM refinement; on-site check).
    RobotWorld(robot_world::Args),
    /// Camera intrinsics + hand-eye (seed 004): every closed form side by side, then the
    /// maximum-likelihood refinement on raw corner reprojection.
    Camera(camera::Args),
    /// Tool (marker) on the flange and base with the identified arm fixed, and the guide
    /// tool's frame from the pin forward / reversed, with uncertainty.
    Tool(tool::Args),
    /// Seed 003's 6-n-6 correction network on top of a kinematic calibration (stored in the
    /// calibration file, applied by `predict`).
    Navchain(navchain::Args),
}

/// Run `robocal calibrate`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    match args.what {
        What::Nominal(a) => nominal::exec(a),
        What::Kinematics(a) => kinematics::exec(a),
        What::Pivot(a) => pivot::exec(a),
        What::Laser(a) => laser::exec(a),
        What::Rcm(a) => rcm::exec(a),
        What::RobotWorld(a) => robot_world::exec(a),
        What::Camera(a) => camera::exec(a),
        What::Tool(a) => tool::exec(a),
        What::Navchain(a) => navchain::exec(a),
    }
}
