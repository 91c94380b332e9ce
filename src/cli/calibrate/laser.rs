//! `robocal calibrate laser`.

/// Arguments of `robocal calibrate laser`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `robocal calibrate laser`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    super::super::not_yet("calibrate laser")
}
