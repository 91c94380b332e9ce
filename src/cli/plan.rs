//! `robocal plan`.

/// Arguments of `robocal plan`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `robocal plan`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    super::not_yet("plan")
}
