//! `robocal report`.

/// Arguments of `robocal report`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `robocal report`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    super::not_yet("report")
}
