//! `robocal calibrate pivot`.

/// Arguments of `robocal calibrate pivot`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `robocal calibrate pivot`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    super::super::not_yet("calibrate pivot")
}
