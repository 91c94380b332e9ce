//! `robocal calibrate pivot --data D.jsonl | --matrices FRAMES.txt [--tool NAME] [--out DIR]`:
//! probe tip in the marker frame and the pivot point, by algebraic least squares and by a
//! sphere fit of the marker origins on every frame, then robustly (outlier frames dropped by least
//! median of squares + robust scale) with 95 % bootstrap intervals and a verdict on which
//! method to trust (`solve::pivot_robust`).
use std::path::PathBuf;

use anyhow::Context as _;

use crate::solve::pivot_robust::{pivot_robust, Interval3, MethodEstimate, RobustOptions};
use crate::solve::tool::{pivot_algebraic, pivot_frames, pivot_sphere, PivotResult};

/// Arguments of `robocal calibrate pivot`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset with `pivot` records.
    #[arg(
        long,
        value_name = "D.jsonl",
        required_unless_present = "matrices",
        conflicts_with = "matrices"
    )]
    pub data: Option<PathBuf>,
    /// Or a table of tracked marker poses, one per line: the first three rows of the 4×4
    /// pose, row-major, mm (12 numbers, optionally after an id); `#` comments.
    #[arg(long, value_name = "FRAMES.txt")]
    pub matrices: Option<PathBuf>,
    /// Only records whose `tool` equals this name.
    #[arg(long)]
    pub tool: Option<String>,
    /// Write `DIR/pivot.json`.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Fixed outlier cut on the 3-D tip residual (mm) instead of 3.37 robust σ.
    #[arg(long, value_name = "MM")]
    pub threshold_mm: Option<f64>,
    /// Bootstrap replicates for the 95 % intervals.
    #[arg(long, default_value_t = 500)]
    pub bootstrap: usize,
    /// Block length (frames) of the moving-block bootstrap; 0 = ⌈n^(1/3)⌉, 1 = i.i.d.
    #[arg(long, default_value_t = 0)]
    pub block: usize,
}

fn row(r: &PivotResult) -> String {
    format!(
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
    )
}

fn ci(c: &Interval3) -> String {
    format!(
        "x [{:.3}, {:.3}] y [{:.3}, {:.3}] z [{:.3}, {:.3}]",
        c[0][0], c[0][1], c[1][0], c[1][1], c[2][0], c[2][1]
    )
}

fn schema_row(
    r: &PivotResult,
    method: String,
    est: Option<&MethodEstimate>,
) -> crate::schema::PivotResult {
    crate::schema::PivotResult {
        method,
        tip_in_marker_mm: [r.tip_in_marker.x, r.tip_in_marker.y, r.tip_in_marker.z],
        pivot_point_mm: [r.pivot_point.x, r.pivot_point.y, r.pivot_point.z],
        rms_mm: r.rms_mm,
        max_mm: r.max_mm,
        frames: r.n,
        rms_axis_mm: est.map(|e| e.rms_axis_mm),
        tip_ci95_mm: est.map(|e| e.tip_ci),
        pivot_ci95_mm: est.map(|e| e.pivot_ci),
    }
}

fn load(args: &Args) -> anyhow::Result<Vec<nalgebra::Isometry3<f64>>> {
    if let Some(m) = &args.matrices {
        let text =
            std::fs::read_to_string(m).with_context(|| format!("reading {}", m.display()))?;
        return Ok(crate::import::matrices::parse_pose_matrices(
            &m.display().to_string(),
            &text,
        )?);
    }
    let data = args
        .data
        .as_ref()
        .context("give --data D.jsonl or --matrices FRAMES.txt")?;
    let ds = crate::plausible::load_checked(data)
        .with_context(|| format!("reading {}", data.display()))?;
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
            data.display(),
            tools.len(),
            tools.join(", ")
        );
    }
    let frames = pivot_frames(&ds, args.tool.as_deref());
    anyhow::ensure!(
        !frames.is_empty(),
        "{}: no usable `pivot` records (visible, with p and quat){}",
        data.display(),
        args.tool
            .as_ref()
            .map(|t| format!(" for tool `{t}`"))
            .unwrap_or_default()
    );
    crate::plausible::quat::check_order_pivot(&frames, &data.display().to_string())
        .map_err(|e| anyhow::anyhow!(e))?;
    Ok(frames)
}

/// Run `robocal calibrate pivot`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let frames = load(&args)?;
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
    println!("every frame:");
    let mut out = Vec::new();
    for r in [&alg, &sph] {
        println!("  {}", row(r));
        out.push(schema_row(r, r.method.to_string(), None));
    }
    println!(
        "  difference between methods: {:.4} mm",
        (alg.tip_in_marker - sph.tip_in_marker).norm()
    );
    let opt = RobustOptions {
        bootstrap: args.bootstrap.max(20),
        block: args.block,
        threshold_mm: args.threshold_mm,
        ..Default::default()
    };
    let rob = pivot_robust(&frames, &opt).context("robust pivot calibration")?;
    println!(
        "robust: dropped {} of {} frames as outliers (3-D tip residual > {:.3} mm = 3.37 × robust σ {:.3} mm per axis{}); probe tilt up to {:.1}° from its mean axis",
        rob.dropped(),
        frames.len(),
        rob.threshold_mm,
        rob.sigma_mm,
        if args.threshold_mm.is_some() { ", cut fixed by --threshold-mm" } else { "" },
        rob.spread_deg
    );
    println!(
        "  every-frame algebraic RMS per axis {:.3} mm → robust {:.3} mm (per-axis convention of scikit-surgerycalibration)",
        rob.all_rms_axis_mm, rob.algebraic.rms_axis_mm
    );
    for e in [&rob.algebraic, &rob.sphere] {
        println!("  {}", row(&e.fit));
        println!("    tip 95 %:   {}", ci(&e.tip_ci));
        println!("    pivot 95 %: {}", ci(&e.pivot_ci));
        println!(
            "    held-out tip scatter (5 blocked folds): {:.3} mm RMS",
            e.cv_rms_mm
        );
    }
    println!(
        "  ({} bootstrap replicates over frames, blocks of {} consecutive frames)",
        opt.bootstrap, rob.block
    );
    println!(
        "  methods {} by {:.3} mm: trust {}: {}",
        if rob.disagree {
            "DISAGREE beyond their 95 % intervals"
        } else {
            "agree within their 95 % intervals"
        },
        rob.tip_difference_mm,
        rob.trust,
        rob.reason
    );
    for e in [&rob.algebraic, &rob.sphere] {
        out.push(schema_row(
            &e.fit,
            format!("robust-{}", e.fit.method),
            Some(e),
        ));
    }
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let path = dir.join("pivot.json");
        let v = crate::schema::PivotFile {
            format: crate::schema::PIVOT_FORMAT.into(),
            tool: args.tool.clone(),
            results: out,
            robust: Some(crate::schema::PivotRobust {
                frames_in: frames.len(),
                dropped: rob.dropped(),
                threshold_mm: rob.threshold_mm,
                sigma_mm: rob.sigma_mm,
                spread_deg: rob.spread_deg,
                bootstrap: opt.bootstrap,
                block: rob.block,
                disagree: rob.disagree,
                trust: rob.trust.into(),
                reason: rob.reason.clone(),
            }),
        };
        crate::schema::write(&path, &v)?;
        // Every file robocal writes loads back.
        crate::schema::read::<crate::schema::PivotFile>(&path)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
