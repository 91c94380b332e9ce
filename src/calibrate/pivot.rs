//! The pivot calibration of `robocal calibrate pivot` as a library call: probe tip in the marker
//! frame and the pivot point, by algebraic least squares and by a sphere fit of the marker
//! origins on every frame, then robustly (outlier frames dropped by least median of squares +
//! robust scale) with 95 % bootstrap intervals and a verdict on which method to trust
//! (`solve::pivot_robust`). Writes `pivot.json` when asked; the CLI prints the result.
use std::path::PathBuf;

use anyhow::Context as _;

use crate::solve::pivot_robust::{pivot_robust, MethodEstimate, RobustOptions, RobustPivot};
use crate::solve::tool::{pivot_algebraic, pivot_frames, pivot_sphere, PivotResult};

/// What to calibrate and how.
#[derive(Debug, Clone, Default)]
pub struct PivotOptions {
    /// Dataset with `pivot` records.
    pub data: Option<PathBuf>,
    /// Or a table of tracked marker poses (3×4 rows, mm).
    pub matrices: Option<PathBuf>,
    /// Only records whose `tool` equals this name.
    pub tool: Option<String>,
    /// Write `DIR/pivot.json`.
    pub out: Option<PathBuf>,
    /// Fixed outlier cut on the 3-D tip residual (mm) instead of 3.37 robust σ.
    pub threshold_mm: Option<f64>,
    /// Bootstrap replicates for the 95 % intervals (at least 20 are drawn).
    pub bootstrap: usize,
    /// Block length (frames) of the moving-block bootstrap; 0 = ⌈n^(1/3)⌉, 1 = i.i.d.
    pub block: usize,
}

/// What the calibration found (and wrote).
#[derive(Debug, Clone)]
pub struct PivotCalibration {
    /// Frames used.
    pub frames: usize,
    /// Algebraic least squares on every frame.
    pub algebraic: PivotResult,
    /// Sphere fit on every frame.
    pub sphere: PivotResult,
    /// The robust fits, their intervals and the verdict.
    pub robust: RobustPivot,
    /// The bootstrap replicates drawn.
    pub bootstrap: usize,
    /// `pivot.json`'s content.
    pub file: crate::schema::PivotFile,
    /// Where it was written (with `out`).
    pub written: Option<PathBuf>,
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

/// The marker frames of `o`: the pose matrices, or the dataset's `pivot` records (of one
/// tool; the quaternion order checked from the pivot fit itself).
pub fn load(o: &PivotOptions) -> anyhow::Result<Vec<nalgebra::Isometry3<f64>>> {
    if let Some(m) = &o.matrices {
        let text =
            std::fs::read_to_string(m).with_context(|| format!("reading {}", m.display()))?;
        return Ok(crate::import::matrices::parse_pose_matrices(
            &m.display().to_string(),
            &text,
        )?);
    }
    let data = o
        .data
        .as_ref()
        .context("give --data D.jsonl or --matrices FRAMES.txt")?;
    let ds = crate::plausible::load_checked(data)
        .with_context(|| format!("reading {}", data.display()))?;
    if o.tool.is_none() {
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
    let frames = pivot_frames(&ds, o.tool.as_deref());
    anyhow::ensure!(
        !frames.is_empty(),
        "{}: no usable `pivot` records (visible, with p and quat){}",
        data.display(),
        o.tool
            .as_ref()
            .map(|t| format!(" for tool `{t}`"))
            .unwrap_or_default()
    );
    crate::plausible::quat::check_order_pivot(&frames, &data.display().to_string())
        .map_err(|e| anyhow::anyhow!(e))?;
    Ok(frames)
}

/// Runs the calibration (see the module docs).
pub fn calibrate(o: &PivotOptions) -> anyhow::Result<PivotCalibration> {
    let frames = load(o)?;
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
    let opt = RobustOptions {
        bootstrap: o.bootstrap.max(20),
        block: o.block,
        threshold_mm: o.threshold_mm,
        ..Default::default()
    };
    let rob = pivot_robust(&frames, &opt).context("robust pivot calibration")?;
    let mut results: Vec<_> = [&alg, &sph]
        .into_iter()
        .map(|r| schema_row(r, r.method.to_string(), None))
        .collect();
    for e in [&rob.algebraic, &rob.sphere] {
        results.push(schema_row(
            &e.fit,
            format!("robust-{}", e.fit.method),
            Some(e),
        ));
    }
    let file = crate::schema::PivotFile {
        format: crate::schema::PIVOT_FORMAT.into(),
        tool: o.tool.clone(),
        results,
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
    let mut written = None;
    if let Some(dir) = &o.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let path = dir.join("pivot.json");
        crate::schema::write(&path, &file)?;
        // Every file robocal writes loads back.
        crate::schema::read::<crate::schema::PivotFile>(&path)?;
        written = Some(path);
    }
    Ok(PivotCalibration {
        frames: frames.len(),
        algebraic: alg,
        sphere: sph,
        robust: rob,
        bootstrap: opt.bootstrap,
        file,
        written,
    })
}
