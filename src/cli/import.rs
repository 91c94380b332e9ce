//! `robocal import ipa|csv`: thin adapter over [`crate::import`]. Reads the input, writes
//! the dataset atomically, prints what it wrote and every warning on stderr.
use std::path::PathBuf;

use anyhow::Context;

use crate::import::generic::{
    AngleUnit, BodyColumns, CsvMapping, LengthUnit, Orientation, TimeUnit,
};
use crate::import::ipa::IpaOptions;
use crate::import::serial_robots::{DifSign, SerialRobotsOptions};
use crate::import::{robot, EulerSeq, Imported, QuatOrder};

/// Arguments of `robocal import`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    pub what: What,
}

/// The input format.
// Parsed once per process: the size difference of the variants does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, clap::Subcommand)]
pub enum What {
    /// The IPA robot-accuracy layout (UR10 + Leica tracker + T-Mac; `measurements_*.csv`).
    Ipa(IpaArgs),
    /// Any delimited table with a column mapping.
    Csv(CsvArgs),
    /// `pauljac7700/serial_robots_datasets` (UR5 / WAM + laser tracker: target + error).
    SerialRobots(SerialRobotsArgs),
    /// Camera hand-eye: an image folder + the robot's flange poses (any common layout; the
    /// declared reading is checked by the AX = XB spread test).
    Handeye(crate::cli::import_handeye::HandeyeArgs),
    /// NDI Track's CSV export (per tool Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error, then the markers) →
    /// `pivot` records for `robocal calibrate pivot`.
    Ndi(crate::cli::import_handeye::NdiArgs),
}

/// The file arguments of the layout importers (`ipa`, `serial-robots`).
#[derive(Debug, clap::Args)]
pub struct LayoutFileArgs {
    /// The measurement file (`Series_X/measurements_*.csv` for `ipa`,
    /// `UR5/3D_UR5_uncalibrated_grid_cleaned.csv` or the like for `serial-robots`).
    #[arg(long)]
    pub input: PathBuf,
    /// The dataset to write (`robocal-dataset/1`).
    #[arg(long)]
    pub out: PathBuf,
    /// Every N-th pose goes to the `validation` group (0 = none).
    #[arg(long, default_value_t = 4)]
    pub heldout_every: usize,
}

/// `robocal import ipa`.
#[derive(Debug, clap::Args)]
pub struct IpaArgs {
    #[command(flatten)]
    pub file: LayoutFileArgs,
    /// Robot: `ur10` (default), a preset, a chain JSON (a header `robot` block) or a URDF.
    #[arg(long, default_value = "ur10")]
    pub robot: String,
}

/// `robocal import serial-robots`.
#[derive(Debug, clap::Args)]
pub struct SerialRobotsArgs {
    #[command(flatten)]
    pub file: LayoutFileArgs,
    /// Robot: `ur5` (default), a preset, a chain JSON or a URDF (7 joints for the WAM files).
    #[arg(long, default_value = "ur5")]
    pub robot: String,
    /// The sign of the `*_dif` columns: `actual-minus-target` (measured = target + dif) or
    /// `target-minus-actual`.
    #[arg(long, value_parser = parse::<DifSign>, default_value = "actual-minus-target")]
    pub dif: DifSign,
}

/// `robocal import csv`.
#[derive(Debug, clap::Args)]
pub struct CsvArgs {
    /// The table to import.
    #[arg(long)]
    pub input: PathBuf,
    /// The dataset to write (`robocal-dataset/1`).
    #[arg(long)]
    pub out: PathBuf,
    /// Robot: a preset (`ur10`, `ur5e`, `ur10e`, `denso-vs060`), a chain JSON or a URDF.
    #[arg(long)]
    pub robot: String,
    /// Joint columns in chain order (comma-separated).
    #[arg(long, value_delimiter = ',', required = true)]
    pub joints: Vec<String>,
    /// Unit of the joint columns.
    #[arg(long, value_parser = parse::<AngleUnit>)]
    pub joint_unit: AngleUnit,
    /// Marker position columns X,Y,Z (tracker frame).
    #[arg(long, value_delimiter = ',', required = true)]
    pub pos: Vec<String>,
    /// Unit of the position (and RMS) columns.
    #[arg(long, value_parser = parse::<LengthUnit>)]
    pub length_unit: LengthUnit,
    /// Marker quaternion columns (4, in --quat-order).
    #[arg(long, value_delimiter = ',', conflicts_with = "euler")]
    pub quat: Option<Vec<String>>,
    /// Order of the quaternion columns: wxyz (scalar first) or xyzw (scalar last).
    #[arg(long, value_parser = parse::<QuatOrder>, default_value = "wxyz")]
    pub quat_order: QuatOrder,
    /// Marker Euler angle columns (3, in sequence order).
    #[arg(long, value_delimiter = ',')]
    pub euler: Option<Vec<String>>,
    /// Euler sequence, SciPy convention: uppercase intrinsic (XYZ), lowercase extrinsic (xyz).
    #[arg(long, value_parser = parse::<EulerSeq>)]
    pub euler_seq: Option<EulerSeq>,
    /// Unit of the Euler angle columns.
    #[arg(long, value_parser = parse::<AngleUnit>, default_value = "deg")]
    pub euler_unit: AngleUnit,
    /// Time column (without one, t = row index and time effects cannot be tested).
    #[arg(long)]
    pub time: Option<String>,
    /// Unit of the time column.
    #[arg(long, value_parser = parse::<TimeUnit>, default_value = "s")]
    pub time_unit: TimeUnit,
    /// Temperature column (°C).
    #[arg(long)]
    pub temp: Option<String>,
    /// Tracker fit RMS column (length unit).
    #[arg(long)]
    pub rms: Option<String>,
    /// Reference body (fixed in the cell) position columns X,Y,Z.
    #[arg(long, value_delimiter = ',')]
    pub ref_pos: Option<Vec<String>>,
    /// Reference body quaternion columns (4, in --quat-order).
    #[arg(
        long,
        value_delimiter = ',',
        conflicts_with = "ref_euler",
        requires = "ref_pos"
    )]
    pub ref_quat: Option<Vec<String>>,
    /// Reference body Euler angle columns (3, --euler-seq / --euler-unit).
    #[arg(long, value_delimiter = ',', requires = "ref_pos")]
    pub ref_euler: Option<Vec<String>>,
    /// Field delimiter: one character, or `tab`.
    #[arg(long, default_value = ",")]
    pub delimiter: String,
    /// Numbers use a decimal comma (`1,5`; needs another delimiter).
    #[arg(long)]
    pub decimal_comma: bool,
    /// Every N-th pose goes to the `validation` group (0 = none).
    #[arg(long, default_value_t = 4)]
    pub heldout_every: usize,
}

fn parse<T: std::str::FromStr<Err = String>>(s: &str) -> Result<T, String> {
    s.parse()
}

/// Run `robocal import`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let (imported, out) = match args.what {
        What::Handeye(a) => return crate::cli::import_handeye::exec(&a),
        What::Ndi(a) => return crate::cli::import_handeye::exec_ndi(&a),
        What::Ipa(a) => {
            let text = read(&a.file.input)?;
            let opts = IpaOptions {
                heldout_every: a.file.heldout_every,
                robot: robot::resolve(&a.robot)?,
            };
            let file = a.file.input.display().to_string();
            (
                crate::import::ipa::parse_ipa(&text, &file, &opts)?,
                a.file.out,
            )
        }
        What::SerialRobots(a) => {
            let text = read(&a.file.input)?;
            let opts = SerialRobotsOptions {
                heldout_every: a.file.heldout_every,
                robot: robot::resolve(&a.robot)?,
                dif: a.dif,
            };
            let file = a.file.input.display().to_string();
            let imp = crate::import::serial_robots::parse_serial_robots(&text, &file, &opts)?;
            (imp, a.file.out)
        }
        What::Csv(a) => {
            let text = read(&a.input)?;
            let map = mapping(&a)?;
            let file = a.input.display().to_string();
            (
                crate::import::generic::parse_csv(&text, &file, &map)?,
                a.out,
            )
        }
    };
    for w in &imported.warnings {
        eprintln!("warning: {w}");
    }
    crate::dataset::write_dataset(&out, &imported.dataset)?;
    // Loads back through the strict reader (the import already checked the text).
    crate::dataset::read_dataset(&out)?;
    report(&imported, &out, started.elapsed().as_secs_f64());
    Ok(())
}

fn read(p: &std::path::Path) -> anyhow::Result<String> {
    let bytes = crate::fsio::read(p).with_context(|| format!("{}: cannot read", p.display()))?;
    String::from_utf8(bytes).map_err(|e| {
        anyhow::anyhow!(
            "{}: not UTF-8 text (byte {}): save it as UTF-8",
            p.display(),
            e.utf8_error().valid_up_to()
        )
    })
}

fn report(imp: &Imported, out: &std::path::Path, secs: f64) {
    let (n, v) = imp.counts();
    println!(
        "wrote {}: {n} poses ({} train, {v} validation), t from {}, {:.2} s",
        out.display(),
        n - v,
        if imp.times_real {
            "time stamps"
        } else {
            "the row index (no usable times)"
        },
        secs
    );
}

fn mapping(a: &CsvArgs) -> anyhow::Result<CsvMapping> {
    let delimiter = match a.delimiter.as_str() {
        "tab" | "\\t" | "\t" => b'\t',
        d if d.len() == 1 && d.is_ascii() => d.as_bytes()[0],
        d => anyhow::bail!("--delimiter \"{d}\": give one ASCII character or `tab`"),
    };
    let orient = |quat: &Option<Vec<String>>,
                  euler: &Option<Vec<String>>,
                  what: &str|
     -> anyhow::Result<Option<Orientation>> {
        Ok(match (quat, euler) {
            (Some(c), _) => Some(Orientation::Quat {
                cols: c.clone(),
                order: a.quat_order,
            }),
            (None, Some(c)) => Some(Orientation::Euler {
                cols: c.clone(),
                seq: a.euler_seq.ok_or_else(|| {
                    anyhow::anyhow!(
                        "{what} Euler columns need --euler-seq (e.g. XYZ intrinsic, xyz extrinsic)"
                    )
                })?,
                unit: a.euler_unit,
            }),
            (None, None) => None,
        })
    };
    Ok(CsvMapping {
        robot: robot::resolve(&a.robot)?,
        joints: a.joints.clone(),
        joint_unit: a.joint_unit,
        marker: BodyColumns {
            pos: a.pos.clone(),
            orientation: orient(&a.quat, &a.euler, "--euler")?,
        },
        length_unit: a.length_unit,
        time: a.time.clone().map(|c| (c, a.time_unit)),
        temp: a.temp.clone(),
        rms: a.rms.clone(),
        reference: match &a.ref_pos {
            Some(p) => Some(BodyColumns {
                pos: p.clone(),
                orientation: orient(&a.ref_quat, &a.ref_euler, "--ref-euler")?,
            }),
            None => None,
        },
        delimiter,
        decimal_comma: a.decimal_comma,
        heldout_every: a.heldout_every,
    })
}
