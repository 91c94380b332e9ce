//! `robocal inspect FILE [--json]`: summary of a dataset (record counts by kind and group,
//! time span, joint ranges, marker visibility, laser out-of-range count, events by `what`).
use std::path::PathBuf;

use crate::dataset::{read_dataset, Summary};

/// Arguments of `robocal inspect`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The dataset (`robocal-dataset/1`, JSON Lines).
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
    /// Print the summary as one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Run `robocal inspect`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let loaded = read_dataset(&args.file)?;
    let warnings = loaded.warnings.iter().map(ToString::to_string).collect();
    let summary = Summary::of(&loaded.dataset, warnings);
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!("file:     {}", args.file.display());
        print!("{summary}");
    }
    // The summary of a file is shown even when its values cannot be right; the file is then
    // refused as every command that uses it would (units, id order, corrupt values,
    // quaternions: the plausibility layer), so inspecting never vouches for a bad file.
    crate::plausible::check_dataset(&loaded.dataset, &args.file)
        .map_err(|e| anyhow::anyhow!("{e} (the summary above is of a file robocal refuses)"))?;
    Ok(())
}
