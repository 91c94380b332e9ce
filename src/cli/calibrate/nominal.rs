//! `robocal calibrate nominal`.

/// Arguments of `robocal calibrate nominal`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `robocal calibrate nominal`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    super::super::not_yet("calibrate nominal")
}
