//! `robocal report --dir DIR [--out report.html|report.md] [--json]`: one report of what a
//! session wrote into DIR and its subdirectories (see [`crate::report`]).
//!
//! Markdown is always written: to `DIR/report.md` by default (or `DIR/session-report.md` when
//! DIR itself is a `robocal diagnose` output, whose own `report.md` is kept), to `--out` when
//! it ends in `.md`, and beside the HTML with the same stem when `--out` ends in `.html`
//! (`x.html` → `x.md`: never another file that happens to be called `report.md`).
//! The headline is printed last (or the whole report as JSON with `--json`). The HTML of a
//! folder that holds sessions is each session's own page ([`crate::report::sessions`]);
//! otherwise the Markdown as HTML with the plots inlined.
use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _};

use crate::report::gather;

/// Arguments of `robocal report`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The session directory (searched recursively).
    #[arg(long, value_name = "DIR")]
    pub dir: PathBuf,
    /// Also write HTML with the plots inlined (`x.html`), or choose the Markdown path (`x.md`).
    #[arg(long, value_name = "report.html")]
    pub out: Option<PathBuf>,
    /// Print the gathered report as JSON on stdout instead of the headline.
    #[arg(long)]
    pub json: bool,
}

fn write(path: &Path, text: &str) -> anyhow::Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("creating {}", parent.display()))?;
    }
    crate::fsio::write_atomic_ctx(path, text.as_bytes())
}

/// Run `robocal report`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    if !args.dir.is_dir() {
        bail!(
            "{}: not a directory ({}): --dir takes a run or session directory",
            args.dir.display(),
            crate::fsio::describe(&args.dir)
        );
    }
    let session = gather(&args.dir)?;
    if session.runs.is_empty()
        && session.datasets.is_empty()
        && session.calibrations.is_empty()
        && session.diagnoses.is_empty()
        && session.laser_reports.is_empty()
    {
        bail!(
            "{}: nothing to report (no run summary, dataset, calibration, diagnosis or laser \
             report in it or below it)",
            args.dir.display()
        );
    }
    let ext = args
        .out
        .as_ref()
        .and_then(|p| p.extension())
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    let (md_path, html_path) = match (&args.out, ext.as_deref()) {
        (None, _) => {
            let name = if args.dir.join("diagnosis.json").is_file() {
                "session-report.md"
            } else {
                "report.md"
            };
            (args.dir.join(name), None)
        }
        (Some(p), Some("md")) => (p.clone(), None),
        (Some(p), Some("html" | "htm")) => (p.with_extension("md"), Some(p.clone())),
        (Some(p), _) => bail!("--out {}: give a .html or .md path", p.display()),
    };
    write(&md_path, &session.markdown())?;
    // A folder of sessions: each session's own page (one report per session).
    let sessions = crate::report::sessions::sessions_in(&args.dir);
    let mut written = Vec::new();
    if let Some(h) = &html_path {
        if sessions.is_empty() {
            write(h, &session.html())?;
            written.push(h.clone());
        } else {
            for page in crate::report::sessions::pages(&sessions, h)? {
                write(&page.path, &page.html)?;
                written.push(page.path);
            }
        }
    }
    for w in &session.warnings {
        eprintln!("warning: {w}");
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&session.to_json())?);
    } else {
        println!("wrote {}", md_path.display());
        for h in &written {
            println!("wrote {}", h.display());
        }
        println!("{}", session.headline_text());
    }
    Ok(())
}
