//! `robocal diagnose`.

/// Arguments of `robocal diagnose`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `robocal diagnose`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    super::not_yet("diagnose")
}
