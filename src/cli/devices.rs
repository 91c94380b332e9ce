//! `robocal devices`.

/// Arguments of `robocal devices`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `robocal devices`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    super::not_yet("devices")
}
