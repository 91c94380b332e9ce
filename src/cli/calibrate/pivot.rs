//! `robocal calibrate pivot --data D.jsonl [--tool NAME] [--out DIR]`: probe tip in the
//! marker frame and the pivot point from `pivot` records, by algebraic least squares and by
//! a sphere fit, with their RMS (seed 001 §2.4).
use std::path::PathBuf;

use anyhow::Context as _;

use crate::solve::tool::{pivot_algebraic, pivot_frames, pivot_sphere};

/// Arguments of `robocal calibrate pivot`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset with `pivot` records.
    #[arg(long, value_name = "D.jsonl")]
    pub data: PathBuf,
    /// Only records whose `tool` equals this name.
    #[arg(long)]
    pub tool: Option<String>,
    /// Write `DIR/pivot.json`.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

/// Run `robocal calibrate pivot`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let ds = crate::plausible::load_checked(&args.data)
        .with_context(|| format!("reading {}", args.data.display()))?;
    if args.tool.is_none() {
        // Records of two tools solved as one give a tip that belongs to neither.
        let mut tools: Vec<&str> = ds
            .records
            .iter()
            .filter_map(|r| match r {
                crate::dataset::Record::Pivot(p) => Some(p.tool.as_deref().unwrap_or("(unnamed)")),
                _ => None,
            })
            .collect();
        tools.sort_unstable();
        tools.dedup();
        anyhow::ensure!(
            tools.len() <= 1,
            "{}: `pivot` records of {} tools ({}): a pivot calibration is of one tool; choose it \
             with --tool NAME",
            args.data.display(),
            tools.len(),
            tools.join(", ")
        );
    }
    let frames = pivot_frames(&ds, args.tool.as_deref());
    anyhow::ensure!(
        !frames.is_empty(),
        "no usable `pivot` records (visible, with p and quat){}",
        args.tool
            .as_ref()
            .map(|t| format!(" for tool `{t}`"))
            .unwrap_or_default()
    );
    // Count rule: tip (3) + pivot point (3) from 3 equations per frame, twice over.
    let need = crate::solve::kinematics::poses_needed(6, 3);
    anyhow::ensure!(
        frames.len() >= need,
        "under-determined pivot calibration: {} usable pivot frames give {} equations for 6 \
         unknowns (tip 3, pivot point 3): at least {need} frames are needed; record {} more",
        frames.len(),
        3 * frames.len(),
        need - frames.len()
    );
    let alg = pivot_algebraic(&frames).context("algebraic pivot calibration")?;
    let sph = pivot_sphere(&frames).context("sphere-fit pivot calibration")?;
    let mut out = Vec::new();
    for r in [&alg, &sph] {
        println!(
            "{:9}: tip in marker [{:.4}, {:.4}, {:.4}] mm, pivot [{:.4}, {:.4}, {:.4}] mm, RMS {:.4} mm, max {:.4} mm ({} frames)",
            r.method,
            r.tip_in_marker.x,
            r.tip_in_marker.y,
            r.tip_in_marker.z,
            r.pivot_point.x,
            r.pivot_point.y,
            r.pivot_point.z,
            r.rms_mm,
            r.max_mm,
            r.n
        );
        out.push(crate::schema::PivotResult {
            method: r.method.to_string(),
            tip_in_marker_mm: [r.tip_in_marker.x, r.tip_in_marker.y, r.tip_in_marker.z],
            pivot_point_mm: [r.pivot_point.x, r.pivot_point.y, r.pivot_point.z],
            rms_mm: r.rms_mm,
            max_mm: r.max_mm,
            frames: r.n,
        });
    }
    println!(
        "difference between methods: {:.4} mm",
        (alg.tip_in_marker - sph.tip_in_marker).norm()
    );
    if let Some(dir) = args.out {
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let path = dir.join("pivot.json");
        let v = crate::schema::PivotFile {
            format: crate::schema::PIVOT_FORMAT.into(),
            tool: args.tool.clone(),
            results: out,
        };
        crate::schema::write(&path, &v)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
