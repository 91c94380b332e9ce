//! `robocal calibrate tool --arm CAL.json --data D.jsonl --out DIR [--bootstrap N]`: seed 001's
//! second step: the tool (marker) on the flange and the robot base in the tracker with the
//! identified arm held fixed (`solve::tool::tool_with_arm`: `AX = XB` closed form, then least
//! squares), with bootstrap standard deviations. Writes `DIR/calibration.json`: the arm of
//! CAL.json with the new base and tool (each with its std). With `--guide FWD.json,REV.json
//! --hole-mm L1`: the guide tool's frame from the pin tip measured forward and reversed (two
//! `pivot.json` files of `calibrate pivot`), with its Monte Carlo spread. The work is in
//! [`crate::calibrate::tool`]; this file parses and prints.
use std::path::PathBuf;

use anyhow::Context as _;
use nalgebra::{Point3, Vector3};

use crate::calibrate::tool::tool_with_arm;
use crate::solve::tool_boot::guide_with_spread;

/// Arguments of `robocal calibrate tool`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The identified arm (`robocal-calibration/1`, kinematic).
    #[arg(long, value_name = "CAL.json", required_unless_present = "guide")]
    pub arm: Option<PathBuf>,
    /// Pose records with joints and the marker's position and orientation.
    #[arg(long, value_name = "D.jsonl", required_unless_present = "guide")]
    pub data: Option<PathBuf>,
    /// Output directory: `calibration.json` (arm + new base and tool).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Bootstrap replicates over poses.
    #[arg(long, default_value_t = 200)]
    pub bootstrap: usize,
    /// Guide tool: the pin forward and reversed, two `pivot.json` files.
    #[arg(
        long,
        value_name = "FWD.json,REV.json",
        value_delimiter = ',',
        num_args = 2
    )]
    pub guide: Option<Vec<PathBuf>>,
    /// Guide tool: the hole's length end face to end face (mm, micrometer).
    #[arg(long, value_name = "MM", requires = "guide")]
    pub hole_mm: Option<f64>,
}

/// The trusted tip of a `pivot.json` and its per-axis std (95 % interval / 3.92).
fn pivot_tip(path: &std::path::Path) -> anyhow::Result<(Point3<f64>, Vector3<f64>)> {
    let f: crate::schema::PivotFile = crate::schema::read(path)?;
    let trust = f.robust.as_ref().map(|r| format!("robust-{}", r.trust));
    let r = trust
        .and_then(|t| f.results.iter().find(|r| r.method == t))
        .or_else(|| f.results.first())
        .with_context(|| format!("{}: no pivot result", path.display()))?;
    let s = match r.tip_ci95_mm {
        Some(c) => Vector3::from_fn(|a, _| (c[a][1] - c[a][0]) / 3.92),
        None => Vector3::zeros(),
    };
    Ok((Point3::from(r.tip_in_marker_mm), s))
}

fn guide(files: &[PathBuf], l1: Option<f64>) -> anyhow::Result<()> {
    let l1 = l1.context("--guide needs --hole-mm L1 (the hole's length, end face to end face)")?;
    let (q1, s1) = pivot_tip(&files[0])?;
    let (q2, s2) = pivot_tip(&files[1])?;
    let g = guide_with_spread(&q1, &q2, &s1, &s2, l1, 2000, 30).with_context(|| {
        format!(
            "guide tool from {} and {}",
            files[0].display(),
            files[1].display()
        )
    })?;
    let (a, o, c) = (g.frame.axis, g.frame.origin, g.frame.centre);
    println!(
        "guide tool (marker frame): axis [{:.5}, {:.5}, {:.5}] ± {:.3}°, origin [{:.3}, {:.3}, {:.3}] ± {:.3} mm, hole centre [{:.3}, {:.3}, {:.3}] mm",
        a.x, a.y, a.z, g.axis_std_deg, o.x, o.y, o.z, g.origin_std_mm, c.x, c.y, c.z
    );
    println!(
        "  tip distance L2 {:.3} mm, hole L1 {l1:.3} mm, each tip stands out {:.3} ± {:.3} mm",
        g.frame.l2, g.frame.protrusion, g.protrusion_std_mm
    );
    Ok(())
}

/// Run `robocal calibrate tool`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    if let Some(files) = &args.guide {
        guide(files, args.hole_mm)?;
        if args.arm.is_none() {
            return Ok(());
        }
    }
    let (Some(arm_path), Some(data)) = (&args.arm, &args.data) else {
        anyhow::bail!("give --arm CAL.json and --data D.jsonl");
    };
    let t = tool_with_arm(arm_path, data, args.bootstrap, args.out.as_deref())?;
    let b = &t.boot;
    println!(
        "tool with the identified arm on {} poses: RMS {:.4} mm, {:.4}° ({} bootstrap replicates)",
        t.with_quat, b.fit.rms_mm, b.fit.rms_rot_deg, b.replicates
    );
    for p in t
        .file
        .params
        .iter()
        .filter(|p| b.std.iter().any(|(n, _)| *n == p.name))
    {
        println!(
            "  {:8} {:>12.4} ± {:.4} {} (95 %: ± {:.4})",
            p.name,
            p.value,
            p.std.unwrap_or(f64::NAN),
            p.unit,
            1.96 * p.std.unwrap_or(f64::NAN)
        );
    }
    if let Some(path) = &t.written {
        println!("wrote {}", path.display());
    }
    Ok(())
}
