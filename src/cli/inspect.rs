//! `robocal inspect`.

/// Arguments of `robocal inspect`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `robocal inspect`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    super::not_yet("inspect")
}
