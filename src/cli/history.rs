//! `robocal history --robot SERIAL [--db LOC] [--svg FILE]`: the sessions of one robot from
//! the fleet history (SQLite file by default, PostgreSQL with a `postgres://` URL; see
//! [`crate::session::history`]): accuracy before / after and parameter drift per session.
use std::path::PathBuf;

use anyhow::Context as _;

use crate::session::history::{self, History};

/// Arguments of `robocal history`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Robot serial number.
    #[arg(long)]
    pub robot: String,
    /// History database: a SQLite file or a postgres:// URL (default: $ROBOCAL_DB, else
    /// robocal-history.sqlite).
    #[arg(long, value_name = "LOC")]
    pub db: Option<String>,
    /// Also write the accuracy plot as SVG.
    #[arg(long, value_name = "FILE.svg")]
    pub svg: Option<PathBuf>,
}

/// Run `robocal history`.
pub fn exec(a: Args) -> anyhow::Result<()> {
    let loc = history::location(a.db.as_deref());
    // A query: never creates or alters a database (issue 26 §8).
    let mut h =
        History::open_read_only(&loc).with_context(|| format!("opening the history {loc}"))?;
    let rows = h.robot(&a.robot)?;
    if rows.is_empty() {
        anyhow::bail!("{loc}: no session of robot {:?}", a.robot);
    }
    print!("{}", history::table(&a.robot, &rows));
    // Parameter drift: each arm parameter's change from nominal, per session.
    let mut names: Vec<(String, String)> = rows
        .iter()
        .flat_map(|r| r.params.iter().map(|p| (p.0.clone(), p.1.clone())))
        .filter(|(n, _)| !(n.starts_with("base") || n.starts_with("tool")))
        .collect();
    names.sort();
    names.dedup();
    if !names.is_empty() {
        println!("parameter change from nominal per session (oldest first):");
        for (n, u) in &names {
            let v: Vec<String> = rows
                .iter()
                .map(|r| {
                    r.params
                        .iter()
                        .find(|p| &p.0 == n)
                        .map_or("—".into(), |p| format!("{:+.4}", p.2))
                })
                .collect();
            println!("  {n:<8} {u:<3} {}", v.join("  "));
        }
    }
    if let Some(p) = &a.svg {
        crate::fsio::write(p, history::svg(&a.robot, &rows))
            .with_context(|| format!("writing {}", p.display()))?;
        println!("wrote {}", p.display());
    }
    Ok(())
}
