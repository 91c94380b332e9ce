//! `robocal history [--robot SERIAL] [--db LOC] [--svg FILE]`: the sessions of one robot (or,
//! without `--robot`, the robots) from
//! the fleet history (SQLite file by default, PostgreSQL with a `postgres://` URL; see
//! [`crate::session::history`]): accuracy before / after and parameter drift per session.
use std::path::PathBuf;

use anyhow::Context as _;

use crate::session::history::{self, History};

/// Arguments of `robocal history`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Robot serial number (without it: the robots in the history).
    #[arg(long)]
    pub robot: Option<String>,
    /// History database: a SQLite file or a postgres:// URL (default: $ROBOCAL_DB, else
    /// $XDG_DATA_HOME/robocal/history.sqlite, i.e. ~/.local/share/robocal/history.sqlite).
    #[arg(long, value_name = "LOC")]
    pub db: Option<String>,
    /// Also write the accuracy plot as SVG.
    #[arg(long, value_name = "FILE.svg")]
    pub svg: Option<PathBuf>,
}

/// Run `robocal history`.
pub fn exec(a: Args) -> anyhow::Result<()> {
    let loc = history::location(a.db.as_deref());
    // A query: never creates or alters a database.
    let mut h =
        History::open_read_only(&loc).with_context(|| format!("opening the history {loc}"))?;
    let robots = h.robots()?;
    let Some(robot) = a.robot.clone() else {
        if robots.is_empty() {
            anyhow::bail!("{loc}: no session recorded yet");
        }
        println!("robots in {loc} (show one with --robot SERIAL):");
        for (serial, model, n) in &robots {
            println!("  {serial:<20} {model:<14} {n} session(s)");
        }
        return Ok(());
    };
    let rows = h.robot(&robot)?;
    if rows.is_empty() {
        // Suggest the serials that look alike (same letters ignoring case, or one contains
        // the other).
        let want = robot.to_lowercase();
        let near: Vec<&str> = robots
            .iter()
            .map(|r| r.0.as_str())
            .filter(|s| {
                let l = s.to_lowercase();
                l.contains(&want) || want.contains(&l) || common_prefix(&l, &want) >= 4
            })
            .collect();
        let all: Vec<&str> = robots.iter().map(|r| r.0.as_str()).collect();
        anyhow::bail!(
            "{loc}: no session of robot {robot:?}{}",
            if !near.is_empty() {
                format!("; did you mean {}?", near.join(", "))
            } else if !all.is_empty() {
                format!("; robots recorded: {}", all.join(", "))
            } else {
                "; the history is empty".into()
            }
        );
    }
    print!("{}", history::table(&robot, &rows));
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
        crate::fsio::write(p, history::svg(&robot, &rows))
            .with_context(|| format!("writing {}", p.display()))?;
        println!("wrote {}", p.display());
    }
    Ok(())
}

fn common_prefix(a: &str, b: &str) -> usize {
    a.chars().zip(b.chars()).take_while(|(x, y)| x == y).count()
}
