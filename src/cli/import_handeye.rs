//! `robocal import ndi`: NDI Track's CSV export → `pivot` records ([`crate::import::ndi`]).
//!
//! `robocal import handeye`: an image folder + a pose list → a camera dataset, the declared
//! pose reading checked by the AX = XB spread test ([`crate::import::handeye`]). The
//! declaration comes from the command line or a small TOML manifest (`--manifest`); command
//! line flags override the manifest.
use std::path::{Path, PathBuf};

use anyhow::Context as _;

use crate::dataset::TargetHeader;
use crate::import::euler::EulerSeq;
use crate::import::generic::{AngleUnit, LengthUnit};
use crate::import::handeye::{import_handeye, Direction, HandeyeOptions, Layout, Reading};
use crate::solve::camera::Mount;

/// Arguments of `robocal import handeye`.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct HandeyeArgs {
    /// A TOML manifest with any of the keys below (snake_case: `images`, `poses`, `layout`,
    /// `unit`, `direction`, `euler_seq`, `angle_unit`, `board`, `square_mm`, `kind`,
    /// `marker_mm`, `dictionary`, `mount`); paths in it are relative to the manifest.
    #[arg(long, value_name = "M.toml")]
    pub manifest: Option<PathBuf>,
    /// The image folder (PNG, JPEG, BMP, TIFF, PGM; sorted by name).
    #[arg(long, value_name = "DIR")]
    pub images: Option<PathBuf>,
    /// The poses: one file (one pose per line, or chunks of the layout's count), or a folder
    /// with one file per pose (paired with the images by the number in the file names).
    #[arg(long, value_name = "FILE|DIR")]
    pub poses: Option<PathBuf>,
    /// matrix4-row, matrix4-col, rot9-row, rot9-col, quat-xyzw (x y z qx qy qz qw),
    /// quat-wxyz (x y z qw qx qy qz) or euler (x y z a b c; --euler-seq, --angle-unit).
    #[arg(long)]
    pub layout: Option<String>,
    /// Length unit of the translations: mm or m.
    #[arg(long)]
    pub unit: Option<String>,
    /// base-flange (each pose is the flange in the base: what controllers report; default) or
    /// flange-base.
    #[arg(long)]
    pub direction: Option<String>,
    /// Euler sequence, SciPy convention (uppercase intrinsic XYZ, lowercase extrinsic xyz).
    #[arg(long)]
    pub euler_seq: Option<String>,
    /// Euler angle unit: deg (default) or rad.
    #[arg(long)]
    pub angle_unit: Option<String>,
    /// Board inner corners COLSxROWS.
    #[arg(long, value_name = "COLSxROWS")]
    pub board: Option<String>,
    /// Board square edge (mm).
    #[arg(long, value_name = "MM")]
    pub square: Option<f64>,
    /// Board kind: chessboard (default) or charuco (then --marker and --dictionary).
    #[arg(long)]
    pub kind: Option<String>,
    /// ChArUco marker edge (mm).
    #[arg(long, value_name = "MM")]
    pub marker: Option<f64>,
    /// ChArUco ArUco dictionary (e.g. DICT_4X4_50).
    #[arg(long)]
    pub dictionary: Option<String>,
    /// Camera mount: flange (eye-in-hand, default) or base (eye-to-hand).
    #[arg(long)]
    pub mount: Option<String>,
    /// The dataset to write.
    #[arg(long, value_name = "D.jsonl")]
    pub out: PathBuf,
    /// Also write every N-th view (4th, 8th, …) to this held-out dataset instead.
    #[arg(long, value_name = "H.jsonl")]
    pub heldout: Option<PathBuf>,
    /// With --heldout: every N-th view is held out.
    #[arg(long, default_value_t = 4)]
    pub heldout_every: usize,
    /// No progress line.
    #[arg(long)]
    pub quiet: bool,
}

/// The manifest: the same declaration as the flags.
#[derive(Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Manifest {
    images: Option<PathBuf>,
    poses: Option<PathBuf>,
    layout: Option<String>,
    unit: Option<String>,
    direction: Option<String>,
    euler_seq: Option<String>,
    angle_unit: Option<String>,
    board: Option<String>,
    square_mm: Option<f64>,
    kind: Option<String>,
    marker_mm: Option<f64>,
    dictionary: Option<String>,
    mount: Option<String>,
}

fn need<T>(v: Option<T>, what: &str) -> anyhow::Result<T> {
    v.ok_or_else(|| {
        anyhow::anyhow!("{what} is not declared (give it on the command line or in the --manifest)")
    })
}

/// The options the flags and manifest declare.
pub fn options(a: &HandeyeArgs) -> anyhow::Result<HandeyeOptions> {
    let (m, dir) = match &a.manifest {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("{}: cannot read the manifest", p.display()))?;
            let m: Manifest =
                toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
            (m, p.parent().map(Path::to_path_buf).unwrap_or_default())
        }
        None => (Manifest::default(), PathBuf::new()),
    };
    let rel = |p: Option<PathBuf>| p.map(|p| dir.join(p));
    let images = need(
        a.images.clone().or(rel(m.images)),
        "the image folder (--images)",
    )?;
    let poses = need(a.poses.clone().or(rel(m.poses)), "the pose list (--poses)")?;
    let layout = need(a.layout.clone().or(m.layout), "the pose layout (--layout)")?;
    let unit: LengthUnit = need(a.unit.clone().or(m.unit), "the length unit (--unit mm|m)")?
        .parse()
        .map_err(anyhow::Error::msg)?;
    let direction: Direction = a
        .direction
        .clone()
        .or(m.direction)
        .unwrap_or_else(|| "base-flange".into())
        .parse()
        .map_err(anyhow::Error::msg)?;
    let euler = match a.euler_seq.clone().or(m.euler_seq) {
        Some(s) => {
            let seq: EulerSeq = s.parse().map_err(anyhow::Error::msg)?;
            let u: AngleUnit = a
                .angle_unit
                .clone()
                .or(m.angle_unit)
                .unwrap_or_else(|| "deg".into())
                .parse()
                .map_err(anyhow::Error::msg)?;
            Some((seq, u))
        }
        None => None,
    };
    let layout = Layout::parse(&layout, euler).map_err(anyhow::Error::msg)?;
    let (cols, rows) = crate::cell::parse_board(&need(
        a.board.clone().or(m.board),
        "the board's inner corners (--board COLSxROWS)",
    )?)
    .map_err(anyhow::Error::msg)?;
    let target = TargetHeader {
        kind: a
            .kind
            .clone()
            .or(m.kind)
            .unwrap_or_else(|| "chessboard".into()),
        cols,
        rows,
        square_mm: need(a.square.or(m.square_mm), "the square size (--square MM)")?,
        marker_mm: a.marker.or(m.marker_mm),
        dictionary: a.dictionary.clone().or(m.dictionary),
    };
    let mount = match a
        .mount
        .clone()
        .or(m.mount)
        .unwrap_or_else(|| "flange".into())
        .as_str()
    {
        "flange" => Mount::Flange,
        "base" => Mount::Base,
        o => anyhow::bail!("mount \"{o}\": expected flange (eye-in-hand) or base (eye-to-hand)"),
    };
    Ok(HandeyeOptions {
        images,
        poses,
        reading: Reading {
            layout,
            unit,
            direction,
        },
        target,
        mount,
        out: a.out.clone(),
        heldout_every: a.heldout_every,
        heldout: a.heldout.clone(),
    })
}

/// Run `robocal import handeye`.
pub fn exec(a: &HandeyeArgs) -> anyhow::Result<()> {
    let t0 = std::time::Instant::now();
    let o = options(a)?;
    let r = import_handeye(&o, !a.quiet)?;
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    for (img, why) in &r.unusable {
        eprintln!("no view: {img}: {why}");
    }
    println!(
        "{}×{} images, board found in {} of {} paired views",
        r.width,
        r.height,
        r.detected,
        r.written.iter().map(|w| w.1).sum::<usize>()
    );
    if !r.spreads.is_empty() {
        println!("board spread under each reading of the poses (RMS about the mean, best first):");
        for s in r.spreads.iter().take(6) {
            let mark = if s.reading == o.reading {
                "  <- declared"
            } else {
                ""
            };
            println!(
                "  {:>9.2} mm {:>7.3}°  {}{mark}",
                s.mm,
                s.deg,
                s.reading.name()
            );
        }
        if let Some(d) = r.spreads.iter().find(|s| s.reading == o.reading) {
            println!(
                "declared reading accepted: {:.2} mm / {:.3}° spread",
                d.mm, d.deg
            );
        }
    }
    for (p, n) in &r.written {
        println!("wrote {}: {n} views", p.display());
    }
    println!("{:.2} s", t0.elapsed().as_secs_f64());
    Ok(())
}

/// Arguments of `robocal import ndi`.
#[derive(Debug, Clone, clap::Args)]
pub struct NdiArgs {
    /// The NDI Track CSV export.
    #[arg(long)]
    pub input: PathBuf,
    /// The dataset to write (`pivot` records, one per tool and frame).
    #[arg(long, value_name = "D.jsonl")]
    pub out: PathBuf,
    /// Only the tool whose name contains this text.
    #[arg(long)]
    pub tool: Option<String>,
    /// Rate of the tracker's frame counter (Hz): t = (frame − first frame) / rate.
    #[arg(long, default_value_t = 60.0)]
    pub frame_rate: f64,
}

/// Run `robocal import ndi`.
pub fn exec_ndi(a: &NdiArgs) -> anyhow::Result<()> {
    let bytes =
        std::fs::read(&a.input).with_context(|| format!("{}: cannot read", a.input.display()))?;
    let text = String::from_utf8_lossy(&bytes);
    let file = a.input.display().to_string();
    let r = crate::import::ndi::parse_ndi(&text, &file, a.tool.as_deref(), a.frame_rate)?;
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    crate::dataset::write_dataset(&a.out, &r.dataset)?;
    crate::dataset::read_dataset(&a.out)?;
    for (name, n, v) in &r.tools {
        println!("tool \"{name}\": {n} frames, {v} with a pose");
    }
    println!(
        "wrote {} ({} pivot records)",
        a.out.display(),
        r.dataset.records.len()
    );
    Ok(())
}
