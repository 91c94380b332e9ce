//! `robocal predict`.

/// Arguments of `robocal predict`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Run `robocal predict`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    super::not_yet("predict")
}
