//! `robocal capture pivot|points|poses --devices CELL.toml ...`: operator-guided acquisition
//! (thin adapter over `crate::capture`). Progress goes to stderr; Enter stops a pivot capture
//! and records a point or a pose when a terminal is attached; without one, each mode stops on
//! its own criteria. Nothing here commands the arm to move.
use std::io::IsTerminal as _;
use std::path::PathBuf;

use anyhow::Context as _;

use crate::capture::{self, Keys};

/// Arguments of `robocal capture`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub what: What,
}

/// The capture modes.
#[derive(Debug, clap::Subcommand)]
pub enum What {
    /// Pivot the probe in a divot; writes DIR/pivot.jsonl and runs `calibrate pivot` on it.
    Pivot(PivotArgs),
    /// Touch named fiducials with the calibrated probe; writes the `name,x_mm,y_mm,z_mm`
    /// table `register` reads (tracker frame).
    Points(PointsArgs),
    /// Teach poses by hand (UR: freedrive, needs --live; DENSO: read-only while the teach
    /// pendant holds the arm); writes `name,j1_deg,…`.
    Poses(PosesArgs),
}

/// Arguments of `robocal capture points`.
#[derive(Debug, clap::Args)]
pub struct PointsArgs {
    /// Device file with the tracker.
    #[arg(long, value_name = "CELL.toml")]
    pub devices: PathBuf,
    /// The probe's tool name.
    #[arg(long)]
    pub tool: String,
    /// The probe calibration (`capture pivot` / `calibrate pivot --out`): its trusted robust
    /// tip is used.
    #[arg(
        long,
        value_name = "pivot.json",
        required_unless_present = "tip_mm",
        conflicts_with = "tip_mm"
    )]
    pub pivot: Option<PathBuf>,
    /// Or the tip in the marker frame, `x,y,z` mm.
    #[arg(
        long,
        value_name = "X,Y,Z",
        value_delimiter = ',',
        allow_negative_numbers = true
    )]
    pub tip_mm: Option<Vec<f64>>,
    /// Fiducial names, in the order they are touched.
    #[arg(
        long,
        value_delimiter = ',',
        required_unless_present = "targets",
        conflicts_with = "targets"
    )]
    pub names: Option<Vec<String>>,
    /// Or the names of a `name,x_mm,y_mm,z_mm` table (e.g. the CT fiducials), in its order.
    #[arg(long, value_name = "T.csv")]
    pub targets: Option<PathBuf>,
    /// Output table.
    #[arg(long, value_name = "points.csv")]
    pub out: PathBuf,
    /// Still window averaged into a point (s).
    #[arg(long, default_value_t = 3.0)]
    pub hold_s: f64,
    /// Largest RMS spread of the tip over the window (mm).
    #[arg(long, default_value_t = 0.6)]
    pub still_mm: f64,
    /// Give up after this many seconds per point.
    #[arg(long, default_value_t = 60.0)]
    pub max_seconds_per_point: f64,
}

/// Arguments of `robocal capture poses`.
#[derive(Debug, clap::Args)]
pub struct PosesArgs {
    /// Device file with the arm.
    #[arg(long, value_name = "CELL.toml")]
    pub devices: PathBuf,
    /// Poses to record.
    #[arg(long, default_value_t = 4)]
    pub count: usize,
    /// Output table (`name,j1_deg,…`).
    #[arg(long, value_name = "poses.csv")]
    pub out: PathBuf,
    /// A UR is put in freedrive (the arm becomes hand-movable): only with --live.
    #[arg(long)]
    pub live: bool,
    /// Confirm --live without the prompt.
    #[arg(long)]
    pub yes: bool,
    /// Give up after this many seconds.
    #[arg(long, default_value_t = 600.0)]
    pub max_seconds: f64,
}

/// Arguments of `robocal capture pivot`.
#[derive(Debug, clap::Args)]
pub struct PivotArgs {
    /// Device file with the tracker (its `tools` list the probe's .rom).
    #[arg(long, value_name = "CELL.toml")]
    pub devices: PathBuf,
    /// The probe's tool name (its .rom file name without extension); needed when the tracker
    /// has several tools.
    #[arg(long)]
    pub tool: Option<String>,
    /// Output folder: pivot.jsonl (the frames) and pivot.json (the calibration).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Largest angle between two captured orientations needed (deg).
    #[arg(long, default_value_t = 40.0)]
    pub min_spread_deg: f64,
    /// Frames needed at least.
    #[arg(long, default_value_t = 600)]
    pub min_frames: usize,
    /// Give up after this many seconds.
    #[arg(long, default_value_t = 120.0)]
    pub max_seconds: f64,
    /// Largest movement of the pivot point within the capture (mm) before the divot counts as
    /// moving.
    #[arg(long, default_value_t = 0.5)]
    pub max_drift_mm: f64,
}

/// Enter on a terminal counts as a key press.
fn keys() -> Keys {
    let k = Keys::new();
    if std::io::stdin().is_terminal() {
        let k2 = k.clone();
        std::thread::spawn(move || {
            let mut line = String::new();
            while std::io::stdin().read_line(&mut line).is_ok_and(|n| n > 0) {
                k2.press();
                line.clear();
            }
        });
    }
    k
}

fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")
}

/// Run `robocal capture`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    match args.what {
        What::Pivot(a) => pivot(a),
        What::Points(a) => points(a),
        What::Poses(a) => poses(a),
    }
}

fn pivot(a: PivotArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        a.min_spread_deg.is_finite() && a.min_spread_deg > 0.0 && a.min_spread_deg < 180.0,
        "--min-spread-deg {}: give 0 < spread < 180",
        a.min_spread_deg
    );
    anyhow::ensure!(
        a.max_seconds.is_finite() && a.max_seconds > 0.0,
        "--max-seconds {}: give a positive number",
        a.max_seconds
    );
    anyhow::ensure!(
        a.max_drift_mm.is_finite() && a.max_drift_mm > 0.0,
        "--max-drift-mm {}: give a positive number",
        a.max_drift_mm
    );
    let cell = capture::cell::checked(&a.devices)?;
    let keys = keys();
    let opt = capture::pivot::PivotOptions {
        tool: a.tool.clone(),
        min_spread_deg: a.min_spread_deg,
        min_frames: a.min_frames,
        max_seconds: a.max_seconds,
        max_drift_mm: a.max_drift_mm,
        ..Default::default()
    };
    let clock = robocal_drivers::SystemClock::default();
    let (cap, tracker_name) = runtime()?.block_on(async {
        let (tracker, name) = capture::cell::open_tracker(&cell).await?;
        let c = capture::pivot::capture_pivot(&*tracker, &clock, &opt, &keys, &mut |l| {
            eprintln!("{l}")
        })
        .await?;
        anyhow::Ok((c, name))
    })?;
    eprintln!(
        "captured {} frames of {:?} ({} not seen), spread {:.1}°, {} of 8 tilt directions, divot \
         drift {:.2} mm (stopped: {})",
        cap.frames.len(),
        cap.tool,
        cap.missing,
        cap.spread_deg,
        cap.sectors,
        cap.drift_mm,
        cap.stopped
    );
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let data = a.out.join("pivot.jsonl");
    crate::dataset::write_dataset(&data, &capture::pivot::pivot_dataset(&cap, &tracker_name))
        .with_context(|| format!("writing {}", data.display()))?;
    println!("wrote {}", data.display());
    super::calibrate::pivot::exec(super::calibrate::pivot::Args {
        data: Some(data),
        matrices: None,
        tool: Some(cap.tool.clone()),
        out: Some(a.out.clone()),
        threshold_mm: None,
        bootstrap: 500,
        block: 0,
    })
}

/// The trusted robust tip of a `robocal-pivot/1` file.
fn tip_from_pivot(path: &std::path::Path) -> anyhow::Result<nalgebra::Vector3<f64>> {
    let pf: crate::schema::PivotFile = crate::schema::read(path)?;
    let want = pf
        .robust
        .as_ref()
        .map(|r| format!("robust-{}", r.trust))
        .unwrap_or_else(|| "algebraic".into());
    let r = pf
        .results
        .iter()
        .find(|r| r.method == want)
        .or_else(|| pf.results.first())
        .with_context(|| format!("{}: no pivot result", path.display()))?;
    eprintln!(
        "probe tip from {} ({}): [{:.3}, {:.3}, {:.3}] mm",
        path.display(),
        r.method,
        r.tip_in_marker_mm[0],
        r.tip_in_marker_mm[1],
        r.tip_in_marker_mm[2]
    );
    Ok(nalgebra::Vector3::from(r.tip_in_marker_mm))
}

fn points(a: PointsArgs) -> anyhow::Result<()> {
    for (v, name) in [
        (a.hold_s, "--hold-s"),
        (a.still_mm, "--still-mm"),
        (a.max_seconds_per_point, "--max-seconds-per-point"),
    ] {
        anyhow::ensure!(
            v.is_finite() && v > 0.0,
            "{name} {v}: give a positive number"
        );
    }
    let tip = match (&a.pivot, &a.tip_mm) {
        (Some(p), _) => tip_from_pivot(p)?,
        (None, Some(t)) => {
            anyhow::ensure!(
                t.len() == 3 && t.iter().all(|x| x.is_finite()),
                "--tip-mm {t:?}: three finite numbers x,y,z (mm)"
            );
            nalgebra::Vector3::new(t[0], t[1], t[2])
        }
        (None, None) => anyhow::bail!("give --pivot pivot.json or --tip-mm X,Y,Z"),
    };
    let names: Vec<String> = match (&a.names, &a.targets) {
        (Some(n), _) => n.iter().map(|s| s.trim().to_string()).collect(),
        (None, Some(t)) => crate::register::points::read_points_csv(t)?
            .into_iter()
            .map(|p| p.name)
            .collect(),
        (None, None) => anyhow::bail!("give --names F1,F2,… or --targets T.csv"),
    };
    anyhow::ensure!(
        !names.is_empty() && names.iter().all(|n| !n.is_empty()),
        "no fiducial names (an empty name in --names?)"
    );
    let mut seen = std::collections::HashSet::new();
    if let Some(d) = names.iter().find(|n| !seen.insert(n.as_str())) {
        anyhow::bail!("fiducial {d:?} named twice: each fiducial is touched once");
    }
    let cell = capture::cell::checked(&a.devices)?;
    let opt = capture::points::PointOptions {
        tool: a.tool.clone(),
        tip_mm: tip,
        hold_s: a.hold_s,
        still_mm: a.still_mm,
        max_seconds_per_point: a.max_seconds_per_point,
        ..Default::default()
    };
    let clock = robocal_drivers::SystemClock::default();
    let pts = runtime()?.block_on(async {
        let (tracker, _) = capture::cell::open_tracker(&cell).await?;
        capture::points::capture_points(&*tracker, &clock, &names, &opt, &mut |l| eprintln!("{l}"))
            .await
    })?;
    let named = capture::points::named_points(&pts);
    let mut buf = Vec::new();
    crate::register::points::write_points_csv(&mut buf, &named)?;
    crate::fsio::write_atomic(&a.out, &buf)
        .with_context(|| format!("writing {}", a.out.display()))?;
    // Every file robocal writes loads back.
    crate::register::points::read_points_csv(&a.out)?;
    println!(
        "wrote {} ({} points, tracker frame; spread {} mm RMS)",
        a.out.display(),
        pts.len(),
        pts.iter()
            .map(|p| format!("{}={:.3}", p.name, p.spread_mm))
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(())
}

fn poses(a: PosesArgs) -> anyhow::Result<()> {
    use crate::acquire::devices::{Protocol, Role};
    anyhow::ensure!(
        a.count >= 1 && a.count <= 1000,
        "--count {}: give 1 to 1000",
        a.count
    );
    anyhow::ensure!(
        a.max_seconds.is_finite() && a.max_seconds > 0.0,
        "--max-seconds {}: give a positive number",
        a.max_seconds
    );
    let cell = capture::cell::checked(&a.devices)?;
    let arm = capture::cell::entry(&cell, Role::Arm)?.clone();
    if arm.protocol == Protocol::Rtde {
        // Freedrive makes the arm movable by hand: the same rule as motion.
        anyhow::ensure!(
            a.live,
            "a UR is taught in freedrive, which releases the arm to the hand: add --live (and \
             --yes, or confirm at the prompt)"
        );
        eprintln!(
            "UR {:?} at {}: freedrive_mode() for up to {:.0} s; keep the arm clear of people's \
             heads, the emergency stop within reach",
            arm.name,
            arm.target(),
            a.max_seconds
        );
        crate::cell::safety::ask_yes(
            a.yes,
            "start freedrive",
            "re-run with --yes to put the arm in freedrive",
            "freedrive not started",
        )?;
    } else {
        eprintln!(
            "{:?}: read-only; move the arm with the teach pendant (hand-guiding / jog)",
            arm.name
        );
    }
    let opt = capture::poses::PoseOptions {
        count: a.count,
        on_key: std::io::stdin().is_terminal(),
        max_seconds: a.max_seconds,
        ..Default::default()
    };
    let keys = keys();
    let clock = robocal_drivers::SystemClock::default();
    let taught = runtime()?.block_on(capture::teach::teach_poses(
        &arm,
        &clock,
        &opt,
        &keys,
        &mut |l| eprintln!("{l}"),
    ))?;
    crate::fsio::write_atomic(&a.out, capture::poses::poses_csv(&taught).as_bytes())
        .with_context(|| format!("writing {}", a.out.display()))?;
    let text = crate::fsio::read_to_string(&a.out)?;
    capture::poses::read_poses_csv(&a.out.display().to_string(), &text)?;
    println!("wrote {} ({} poses)", a.out.display(), taught.len());
    Ok(())
}
