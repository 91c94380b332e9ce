//! `robocal sim`.

/// Arguments of `robocal sim`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `robocal sim`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    super::not_yet("sim")
}
