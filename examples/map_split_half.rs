//! Split-half honesty of the transmission error maps on real data (issue 31 §4: "uncertainty
//! must survive a split-half check on real data").
//!
//! ```text
//! cargo run --release --example map_split_half -- [--max-train N] [--block F] SERIES ...
//! ```
//!
//! For every series the training poses (the first `N` with `--max-train`) are cut in two,
//! (a) alternate time blocks of `F` of the poses (default 0.05) and (b) first half / second
//! half; each half is diagnosed with the default options (scored on the series' held-out
//! poses) and, for every joint mapped in both, the two maps are compared on a 1° grid inside
//! both halves' training range: RMS of `δθ₁ − δθ₂`, RMS of each curve (arcsec), and the share
//! of grid points with `|δθ₁ − δθ₂| ≤ 2·sqrt(σ₁² + σ₂²)` (honest when ≥ 90 %).
//!
//! A `SERIES` is a directory holding `train.jsonl` + `heldout.jsonl` or one dataset file whose
//! `group: validation` records are held out (see `examples/real_policy.rs`). Without a series
//! the example reads `$ROBOCAL_REAL_DATA` or `../shared/data/real-ur10-ipa-grid` and says
//! SKIPPED when absent. Real data is never copied into the repository.
use std::path::PathBuf;
use std::time::Instant;

use robocal::diagnose::pooled::load_series;
use robocal::diagnose::Options;

#[path = "common/map_pair.rs"]
mod map_pair;
use map_pair::with_and_without_maps;
#[path = "common/split_half.rs"]
mod split_half;
use split_half::{split_half, text, Split};

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let mut max_train = usize::MAX;
    let mut block = 0.05;
    let mut series: Vec<PathBuf> = Vec::new();
    while let Some(a) = args.next() {
        let mut num = |what: &str| -> anyhow::Result<f64> {
            args.next()
                .and_then(|v| v.parse().ok())
                .ok_or_else(|| anyhow::anyhow!("{what} needs a number"))
        };
        match a.as_str() {
            "--max-train" => max_train = num("--max-train")? as usize,
            "--block" => block = num("--block")?,
            s if s.starts_with("--") => anyhow::bail!("unknown option {s}"),
            _ => series.push(PathBuf::from(a)),
        }
    }
    if !(block > 0.0 && block < 0.5) {
        anyhow::bail!("--block must lie in (0, 0.5): {block}");
    }
    if series.is_empty() {
        let dir = std::env::var_os("ROBOCAL_REAL_DATA")
            .map(PathBuf::from)
            .unwrap_or_else(|| PathBuf::from("../shared/data/real-ur10-ipa-grid"));
        if !dir.join("train.jsonl").is_file() {
            println!(
                "*** SKIPPED: real data absent ({}): no split-half check ***",
                dir.display()
            );
            return Ok(());
        }
        series.push(dir);
    }
    let opt = Options::default();
    for s in &series {
        let (model, mut train, mut held) = load_series(s)?;
        let name = s
            .file_stem()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if train.len() > max_train {
            // Keep the held-out poses of the same time span.
            train.truncate(max_train);
            let t_end = train.last().map_or(f64::NEG_INFINITY, |o| o.ctx.t);
            held.retain(|o| o.ctx.t <= t_end);
        }
        let t0 = Instant::now();
        let (with, without) = with_and_without_maps(&model, &train, &held, &opt)?;
        let f = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{v:.4}"));
        println!(
            "{name}, all {} training poses, {} held out: held-out RMS with the maps {} mm (H {}), without {} mm, geometric {} mm ({:.1} s)",
            train.len(),
            held.len(),
            f(with.heldout_rms_final),
            with
                .transmission_map
                .as_ref()
                .map_or("—".to_string(), |m| m.chosen.harmonics.to_string()),
            f(without.heldout_rms_final),
            f(with.heldout_rms_geometric),
            t0.elapsed().as_secs_f64()
        );
        for split in [Split::Alternate(block), Split::Halves] {
            let t0 = Instant::now();
            let r = split_half(&model, &train, &held, split, &opt)?;
            print!("{}", text(&name, &r));
            println!(
                "({} training poses, {} held out, {:.1} s)\n",
                train.len(),
                held.len(),
                t0.elapsed().as_secs_f64()
            );
        }
    }
    Ok(())
}
