//! `robocal calibrate kinematics`.

/// Arguments of `robocal calibrate kinematics`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `robocal calibrate kinematics`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    super::super::not_yet("calibrate kinematics")
}
