//! `robocal run`.

/// Arguments of `robocal run`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `robocal run`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    super::not_yet("run")
}
