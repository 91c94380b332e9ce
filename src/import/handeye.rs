//! `robocal import handeye`: an image folder plus the robot's flange poses in one of the
//! layouts labs keep them in → a camera dataset (`pose` records with `flange` and `image`, the
//! header's `camera` and `target` blocks, robot `"model": "none"`: no kinematic model needed).
//!
//! Pose layouts (numbers separated by spaces, tabs, commas or semicolons; `#` starts a
//! comment; a first line of words is a header and skipped; a file may hold one pose per line,
//! a pose spread over several lines, or a folder may hold one file per pose):
//! - `matrix4-row` / `matrix4-col`: the 4×4 homogeneous matrix, 16 numbers, row- or column-major;
//! - `rot9-row` / `rot9-col`: the 3×3 rotation, 9 numbers row- or column-major, then `x y z`;
//! - `quat-xyzw`: `x y z qx qy qz qw`; `quat-wxyz`: `x y z qw qx qy qz`;
//! - `euler`: `x y z a b c`, angles in the SciPy sequence `euler_seq` (uppercase intrinsic,
//!   lowercase extrinsic) and `angle_unit`.
//!
//! Lengths in `mm` or `m`; `direction` `base-flange` (each pose is the flange in the base,
//! base←flange, what controllers report) or `flange-base` (its inverse).
//!
//! The declaration is checked (the AX = XB spread test): the board is detected in every image,
//! its pose in the camera follows from closed-form intrinsics (Zhang), and for every candidate
//! reading of the numbers (both major orders / quaternion orders / Euler sequences, both units,
//! both directions) the hand-eye is solved (Park–Martin) and the board's pose in the base
//! (eye-in-hand; in the flange for eye-to-hand) is computed at every view. Under the right
//! reading the board stays put; when another reading keeps it far more still than the declared
//! one, the import is refused naming that reading.
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde_json::{json, Value};

use super::euler::{wxyz, EulerSeq, QuatOrder};
use super::generic::{AngleUnit, LengthUnit};
use super::ImportError;
use crate::dataset::TargetHeader;
use crate::solve::camera::{geom, handeye, zhang, Mount};

/// How far a rotation read from a file may be from orthonormal (‖RᵀR − I‖, det).
pub const ROT_TOL: f64 = 1e-2;
/// A candidate reading is "far more consistent" when the declared reading's board spread is
/// more than this factor above it, translation or rotation, and more than [`REFUSE_MM`] /
/// [`REFUSE_DEG`] above it.
pub const REFUSE_FACTOR: f64 = 3.0;
/// See [`REFUSE_FACTOR`] (mm).
pub const REFUSE_MM: f64 = 5.0;
/// See [`REFUSE_FACTOR`] (deg).
pub const REFUSE_DEG: f64 = 1.0;
/// Views with a detected board needed to check a declaration.
pub const MIN_CHECK_VIEWS: usize = 4;

/// How the numbers of one pose are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// 4×4 homogeneous matrix, row-major (`col_major: false`) or column-major.
    Matrix4 { col_major: bool },
    /// 3×3 rotation (row- or column-major), then the translation.
    Rot9 { col_major: bool },
    /// Translation then a quaternion in `order`.
    Quat(QuatOrder),
    /// Translation then three Euler angles.
    Euler(EulerSeq, AngleUnit),
}

impl Layout {
    /// Numbers per pose.
    pub fn count(self) -> usize {
        match self {
            Layout::Matrix4 { .. } => 16,
            Layout::Rot9 { .. } => 12,
            Layout::Quat(_) => 7,
            Layout::Euler(..) => 6,
        }
    }

    /// The name used on the command line and in the manifest.
    pub fn name(self) -> String {
        match self {
            Layout::Matrix4 { col_major: false } => "matrix4-row".into(),
            Layout::Matrix4 { col_major: true } => "matrix4-col".into(),
            Layout::Rot9 { col_major: false } => "rot9-row".into(),
            Layout::Rot9 { col_major: true } => "rot9-col".into(),
            Layout::Quat(QuatOrder::Xyzw) => "quat-xyzw".into(),
            Layout::Quat(QuatOrder::Wxyz) => "quat-wxyz".into(),
            Layout::Euler(s, u) => format!("euler (euler_seq {s}, angle_unit {})", u.name()),
        }
    }

    /// Parse a layout name; `euler` needs the sequence and unit.
    pub fn parse(s: &str, euler: Option<(EulerSeq, AngleUnit)>) -> Result<Layout, String> {
        Ok(match s {
            "matrix4" | "matrix4-row" => Layout::Matrix4 { col_major: false },
            "matrix4-col" => Layout::Matrix4 { col_major: true },
            "rot9-row" => Layout::Rot9 { col_major: false },
            "rot9-col" => Layout::Rot9 { col_major: true },
            "quat-xyzw" => Layout::Quat(QuatOrder::Xyzw),
            "quat-wxyz" => Layout::Quat(QuatOrder::Wxyz),
            "euler" => {
                let (seq, unit) = euler.ok_or_else(|| {
                    "layout \"euler\" needs the sequence (euler_seq, e.g. XYZ intrinsic or xyz extrinsic)".to_string()
                })?;
                Layout::Euler(seq, unit)
            }
            other => {
                return Err(format!(
                "layout \"{other}\": expected matrix4-row, matrix4-col, rot9-row, rot9-col, quat-xyzw, quat-wxyz or euler"
            ))
            }
        })
    }

    /// Every reading of the same numbers this layout could be confused with (itself first).
    fn alternatives(self) -> Vec<Layout> {
        match self {
            Layout::Matrix4 { col_major } => vec![
                self,
                Layout::Matrix4 {
                    col_major: !col_major,
                },
            ],
            Layout::Rot9 { col_major } => vec![
                self,
                Layout::Rot9 {
                    col_major: !col_major,
                },
            ],
            Layout::Quat(QuatOrder::Xyzw) => vec![self, Layout::Quat(QuatOrder::Wxyz)],
            Layout::Quat(QuatOrder::Wxyz) => vec![self, Layout::Quat(QuatOrder::Xyzw)],
            Layout::Euler(..) => {
                let mut v = vec![self];
                for s in [
                    "XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "XYX", "XZX", "YXY", "YZY", "ZXZ",
                    "ZYZ",
                ] {
                    for intrinsic in [true, false] {
                        let name = if intrinsic {
                            s.to_string()
                        } else {
                            s.to_lowercase()
                        };
                        if let Ok(seq) = name.parse::<EulerSeq>() {
                            for u in [AngleUnit::Deg, AngleUnit::Rad] {
                                let l = Layout::Euler(seq, u);
                                if !v.contains(&l) {
                                    v.push(l);
                                }
                            }
                        }
                    }
                }
                v
            }
        }
    }
}

/// Which transform the numbers are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// The flange in the base (base←flange).
    BaseFlange,
    /// The base in the flange (flange←base): inverted on import.
    FlangeBase,
}

impl Direction {
    /// The name used on the command line and in the manifest.
    pub fn name(self) -> &'static str {
        match self {
            Direction::BaseFlange => "base-flange",
            Direction::FlangeBase => "flange-base",
        }
    }
}

impl std::str::FromStr for Direction {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "base-flange" | "base<-flange" => Ok(Direction::BaseFlange),
            "flange-base" | "flange<-base" => Ok(Direction::FlangeBase),
            _ => Err(format!(
                "direction \"{s}\": expected base-flange (the flange in the base, what controllers report) or flange-base"
            )),
        }
    }
}

/// One complete reading of the pose numbers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Reading {
    pub layout: Layout,
    pub unit: LengthUnit,
    pub direction: Direction,
}

impl Reading {
    /// `layout, unit, direction` as a user would declare them.
    pub fn name(&self) -> String {
        format!(
            "layout {}, unit {}, direction {}",
            self.layout.name(),
            self.unit.name(),
            self.direction.name()
        )
    }

    /// The flange in the base (mm) from one pose's numbers.
    pub fn pose(&self, v: &[f64]) -> Result<Isometry3<f64>, String> {
        let n = self.layout.count();
        if v.len() != n {
            return Err(format!(
                "{} numbers, layout {} takes {n}",
                v.len(),
                self.layout.name()
            ));
        }
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(format!("value {} is not a finite number", i + 1));
        }
        let mm = match self.unit {
            LengthUnit::Mm => 1.0,
            LengthUnit::M => 1000.0,
        };
        let (rot, t) = match self.layout {
            Layout::Matrix4 { col_major } => {
                let at = |r: usize, c: usize| {
                    if col_major {
                        v[c * 4 + r]
                    } else {
                        v[r * 4 + c]
                    }
                };
                let last = [at(3, 0), at(3, 1), at(3, 2), at(3, 3)];
                if (last[0].abs() + last[1].abs() + last[2].abs()) > 1e-6
                    || (last[3] - 1.0).abs() > 1e-6
                {
                    return Err(format!(
                        "the last row of the 4×4 is {last:?}, not [0, 0, 0, 1] (the other major order?)"
                    ));
                }
                (
                    rotation(Matrix3::from_fn(at))?,
                    Vector3::new(at(0, 3), at(1, 3), at(2, 3)),
                )
            }
            Layout::Rot9 { col_major } => {
                let m = Matrix3::from_fn(|r, c| {
                    if col_major {
                        v[c * 3 + r]
                    } else {
                        v[r * 3 + c]
                    }
                });
                (rotation(m)?, Vector3::new(v[9], v[10], v[11]))
            }
            Layout::Quat(order) => {
                let q = order.quaternion([v[3], v[4], v[5], v[6]]);
                let q = crate::plausible::quat::unit_wxyz(&[q.w, q.i, q.j, q.k])
                    .map_err(|e| format!("{e} (or the wrong layout)"))?;
                (q, Vector3::new(v[0], v[1], v[2]))
            }
            Layout::Euler(seq, unit) => {
                let k = match unit {
                    AngleUnit::Deg => std::f64::consts::PI / 180.0,
                    AngleUnit::Rad => 1.0,
                };
                (
                    seq.rotation([v[3] * k, v[4] * k, v[5] * k]),
                    Vector3::new(v[0], v[1], v[2]),
                )
            }
        };
        let p = Isometry3::from_parts(Translation3::from(t * mm), rot);
        Ok(match self.direction {
            Direction::BaseFlange => p,
            Direction::FlangeBase => p.inverse(),
        })
    }

    /// Every reading the numbers could be confused with (this one first).
    pub fn candidates(&self) -> Vec<Reading> {
        let mut out = vec![];
        for layout in self.layout.alternatives() {
            for unit in [self.unit, other_unit(self.unit)] {
                for direction in [self.direction, other_direction(self.direction)] {
                    out.push(Reading {
                        layout,
                        unit,
                        direction,
                    });
                }
            }
        }
        out
    }
}

fn other_unit(u: LengthUnit) -> LengthUnit {
    match u {
        LengthUnit::Mm => LengthUnit::M,
        LengthUnit::M => LengthUnit::Mm,
    }
}

fn other_direction(d: Direction) -> Direction {
    match d {
        Direction::BaseFlange => Direction::FlangeBase,
        Direction::FlangeBase => Direction::BaseFlange,
    }
}

/// A proper rotation from a file's 3×3 (orthonormal within [`ROT_TOL`]), re-orthonormalised.
fn rotation(m: Matrix3<f64>) -> Result<UnitQuaternion<f64>, String> {
    let err = (m.transpose() * m - Matrix3::identity()).norm();
    let det = m.determinant();
    if err > ROT_TOL || (det - 1.0).abs() > ROT_TOL {
        return Err(format!(
            "the 3×3 is not a rotation (‖RᵀR − I‖ = {err:.3}, det = {det:.3}): wrong layout or major order?"
        ));
    }
    Ok(UnitQuaternion::from_rotation_matrix(
        &Rotation3::from_matrix(&m),
    ))
}

/// One pose's numbers and where they came from.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseValues {
    /// The file the numbers came from.
    pub file: String,
    /// 1-based line of the first number.
    pub line: usize,
    /// The number in the file's name (`endeffector007.txt` → 7), for pairing with images.
    pub number: Option<u64>,
    pub values: Vec<f64>,
}

/// Numbers of a pose file with the line of each; a first line of words is skipped.
fn numbers(text: &str, file: &str) -> Result<Vec<(usize, f64)>, ImportError> {
    let mut out = vec![];
    let mut seen_numbers = false;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("");
        let toks: Vec<&str> = line
            .split(|c: char| c.is_whitespace() || c == ',' || c == ';')
            .filter(|t| !t.is_empty())
            .collect();
        if toks.is_empty() {
            continue;
        }
        let parsed: Vec<Option<f64>> = toks.iter().map(|t| t.parse::<f64>().ok()).collect();
        if !seen_numbers && parsed.iter().all(Option::is_none) {
            // A header row of column names.
            seen_numbers = true;
            continue;
        }
        seen_numbers = true;
        for (t, p) in toks.iter().zip(parsed) {
            match p {
                Some(x) if x.is_finite() => out.push((i + 1, x)),
                _ => {
                    return Err(ImportError::bad(
                        file,
                        Some(i + 1),
                        None,
                        format!("\"{t}\" is not a finite number (pose files hold numbers only)"),
                    ))
                }
            }
        }
    }
    Ok(out)
}

/// The poses of one file holding `count` numbers per pose.
pub fn parse_pose_file(
    text: &str,
    file: &str,
    count: usize,
) -> Result<Vec<PoseValues>, ImportError> {
    let nums = numbers(text, file)?;
    if nums.is_empty() {
        return Err(ImportError::bad(
            file,
            None,
            None,
            "no numbers in the pose file",
        ));
    }
    if nums.len() % count != 0 {
        return Err(ImportError::bad(
            file,
            None,
            None,
            format!(
                "{} numbers is not a whole number of poses of {count} numbers each (wrong layout?)",
                nums.len()
            ),
        ));
    }
    Ok(nums
        .chunks(count)
        .map(|c| PoseValues {
            file: file.to_string(),
            line: c[0].0,
            number: None,
            values: c.iter().map(|(_, x)| *x).collect(),
        })
        .collect())
}

/// The last run of digits in a file name's stem (`cam0_012.jpg` → 12).
pub fn file_number(p: &Path) -> Option<u64> {
    let stem = p.file_stem()?.to_str()?;
    let end = stem.rfind(|c: char| c.is_ascii_digit())? + 1;
    let start = stem[..end]
        .rfind(|c: char| !c.is_ascii_digit())
        .map_or(0, |i| i + 1);
    stem[start..end].parse().ok()
}

/// The files of `dir` (sorted by name) whose extension is one of `exts` (any case; all
/// regular files when `exts` is empty).
pub fn list_files(dir: &Path, exts: &[&str]) -> Result<Vec<PathBuf>, ImportError> {
    let rd = std::fs::read_dir(dir).map_err(|source| ImportError::Io {
        file: dir.display().to_string(),
        source,
    })?;
    let mut v: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .filter(|p| {
            exts.is_empty()
                || p.extension()
                    .and_then(|x| x.to_str())
                    .is_some_and(|x| exts.iter().any(|e| x.eq_ignore_ascii_case(e)))
        })
        .collect();
    v.sort();
    Ok(v)
}

/// Images paired with their poses.
pub type Pairs = Vec<(PathBuf, PoseValues)>;

/// Pair images with poses: by the number in the file names when every pose has a distinct
/// one and the images do too; else in order (then the counts must match).
/// Returns `(image, pose)` pairs and warnings (images or poses left without a partner).
pub fn pair(images: &[PathBuf], poses: &[PoseValues]) -> Result<(Pairs, Vec<String>), ImportError> {
    let inums: Vec<Option<u64>> = images.iter().map(|p| file_number(p)).collect();
    let distinct = |v: &[Option<u64>]| {
        let mut s: Vec<u64> = v.iter().filter_map(|x| *x).collect();
        let n = s.len();
        s.sort_unstable();
        s.dedup();
        n == v.len() && s.len() == n
    };
    let pnums: Vec<Option<u64>> = poses.iter().map(|p| p.number).collect();
    let mut warnings = vec![];
    if distinct(&inums) && distinct(&pnums) {
        let mut out = vec![];
        for (img, n) in images.iter().zip(&inums) {
            match poses.iter().find(|p| p.number == *n) {
                Some(p) => out.push((img.clone(), p.clone())),
                None => warnings.push(format!(
                    "image {} has no pose file with number {} (skipped)",
                    img.display(),
                    n.unwrap_or(0)
                )),
            }
        }
        for p in poses {
            if !inums.contains(&p.number) {
                warnings.push(format!("pose file {} has no image (skipped)", p.file));
            }
        }
        return Ok((out, warnings));
    }
    if images.len() != poses.len() {
        return Err(ImportError::Usage(format!(
            "{} images but {} poses (paired in order: image k ↔ pose k): a pose or an image is missing",
            images.len(),
            poses.len()
        )));
    }
    Ok((
        images.iter().cloned().zip(poses.iter().cloned()).collect(),
        warnings,
    ))
}

/// The board's spread under one reading: RMS distance (mm) and RMS angle (deg) of the board
/// poses in the base (eye-in-hand) or flange (eye-to-hand) from their mean.
#[derive(Debug, Clone, PartialEq)]
pub struct Spread {
    pub reading: Reading,
    pub mm: f64,
    pub deg: f64,
}

/// Board poses in the camera of the views (`None` where no board was found), from closed-form
/// intrinsics (Zhang, no distortion). `corners` are in board order.
pub fn board_in_camera(
    corners: &[Option<Vec<Option<[f64; 2]>>>],
    target: &TargetHeader,
    width: u32,
    height: u32,
) -> Vec<Option<Isometry3<f64>>> {
    let (cols, s) = (target.cols as usize, target.square_mm);
    let hs: Vec<Option<Matrix3<f64>>> = corners
        .iter()
        .map(|c| {
            let c = c.as_ref()?;
            let (plane, img): (Vec<[f64; 2]>, Vec<[f64; 2]>) = c
                .iter()
                .enumerate()
                .filter_map(|(k, p)| {
                    let p = (*p)?;
                    let b = geom::board_point(k % cols, k / cols, s);
                    Some(([b.x, b.y], p))
                })
                .unzip();
            if plane.len() < 6 {
                return None;
            }
            zhang::homography(&plane, &img)
        })
        .collect();
    let all: Vec<Matrix3<f64>> = hs.iter().flatten().copied().collect();
    let (cx, cy) = (f64::from(width) / 2.0 - 0.5, f64::from(height) / 2.0 - 0.5);
    let k = zhang::zhang_k(&all, cx, cy, f64::from(width))
        .filter(|k| {
            let f = (k[(0, 0)] * k[(1, 1)]).sqrt();
            f.is_finite()
                && f > 0.1 * f64::from(width)
                && f < 20.0 * f64::from(width)
                && (k[(0, 0)] / k[(1, 1)] - 1.0).abs() < 0.2
                && (k[(0, 2)] - cx).abs() < 0.3 * f64::from(width)
                && (k[(1, 2)] - cy).abs() < 0.3 * f64::from(height)
        })
        .or_else(|| zhang::focal_centered(&all, cx, cy));
    let Some(k) = k else {
        return vec![None; corners.len()];
    };

    hs.iter()
        .map(|h| zhang::pose_from_h(&k, h.as_ref()?))
        .collect()
}

/// The spread of the board under `flange` poses (see [`Spread`]); `None` when the hand-eye
/// cannot be solved (fewer than [`MIN_CHECK_VIEWS`] views, no rotation).
pub fn spread(
    flange: &[Isometry3<f64>],
    cam_board: &[Option<Isometry3<f64>>],
    mount: Mount,
) -> Option<(f64, f64)> {
    let (f, b): (Vec<Isometry3<f64>>, Vec<Isometry3<f64>>) = flange
        .iter()
        .zip(cam_board)
        .filter_map(|(f, b)| {
            let m = match mount {
                Mount::Flange => *f,
                Mount::Base => f.inverse(),
            };
            Some((m, (*b)?))
        })
        .unzip();
    if f.len() < MIN_CHECK_VIEWS {
        return None;
    }
    let pairs = handeye::motion_pairs(&f, &b, 2.0);
    let x = handeye::solve(handeye::Method::ParkMartin, &pairs)
        .or_else(|| handeye::solve(handeye::Method::TsaiLenz, &pairs))?;
    let world: Vec<Isometry3<f64>> = f.iter().zip(&b).map(|(f, b)| f * x * b).collect();
    let mean = geom::mean_pose(&world);
    let n = world.len() as f64;
    let (mut se_t, mut se_r) = (0.0, 0.0);
    for w in &world {
        let (t, r) = geom::pose_error(&mean, w);
        se_t += t * t;
        se_r += r * r;
    }
    let (mm, deg) = ((se_t / n).sqrt(), (se_r / n).sqrt());
    (mm.is_finite() && deg.is_finite()).then_some((mm, deg))
}

/// The declared reading's spread and every valid candidate's, best (smallest mm) first.
pub fn check_readings(
    declared: Reading,
    values: &[&[f64]],
    cam_board: &[Option<Isometry3<f64>>],
    mount: Mount,
) -> Vec<Spread> {
    let mut out: Vec<Spread> = declared
        .candidates()
        .into_iter()
        .filter_map(|r| {
            let poses: Result<Vec<_>, _> = values.iter().map(|v| r.pose(v)).collect();
            let (mm, deg) = spread(&poses.ok()?, cam_board, mount)?;
            Some(Spread {
                reading: r,
                mm,
                deg,
            })
        })
        .collect();
    out.sort_by(|a, b| a.mm.total_cmp(&b.mm));
    out
}

/// `Err(message)` when a reading other than `declared` is far more consistent (see
/// [`REFUSE_FACTOR`]); the message names it and shows both spreads. `frame` is where the board
/// should stay put (`base` eye-in-hand, `flange` eye-to-hand).
pub fn verdict(declared: Reading, spreads: &[Spread], frame: &str) -> Result<(), String> {
    let Some(d) = spreads.iter().find(|s| s.reading == declared) else {
        return Ok(());
    };
    let Some(best) = spreads
        .iter()
        .filter(|s| s.reading != declared)
        .min_by(|a, b| {
            (a.mm / REFUSE_MM + a.deg / REFUSE_DEG)
                .total_cmp(&(b.mm / REFUSE_MM + b.deg / REFUSE_DEG))
        })
    else {
        return Ok(());
    };
    let far = |dv: f64, bv: f64, abs: f64| dv > REFUSE_FACTOR * bv && dv > bv + abs;
    let better_t = far(d.mm, best.mm, REFUSE_MM) && best.deg <= d.deg * 1.5 + REFUSE_DEG;
    let better_r = far(d.deg, best.deg, REFUSE_DEG) && best.mm <= d.mm * 1.5 + REFUSE_MM;
    if better_t || better_r {
        return Err(format!(
            "the declared pose reading ({}) does not keep the board still: it moves {:.1} mm / {:.2}° RMS in the {} across the views, against {:.1} mm / {:.2}° under \"{}\". The poses are most likely {}; declare that (or check the images belong to these poses)",
            d.reading.name(),
            d.mm,
            d.deg,
            frame,
            best.mm,
            best.deg,
            best.reading.name(),
            best.reading.name()
        ));
    }
    Ok(())
}

/// The pose record of one view: `id`, the flange pose (mm, `[w,x,y,z]`) and the image path as
/// written in the dataset.
pub fn record(id: u64, flange: &Isometry3<f64>, image: &str, source: &PoseValues) -> Value {
    let t = flange.translation.vector;
    json!({"kind": "pose", "id": id, "t": (id - 1) as f64, "group": "train",
           "flange": {"p": [t.x, t.y, t.z], "quat": wxyz(&flange.rotation)},
           "image": image, "source_line": format!("{}:{}", source.file, source.line)})
}

/// What `robocal import handeye` reads.
#[derive(Debug, Clone)]
pub struct HandeyeOptions {
    /// The image folder (PNG, JPEG, BMP, TIFF, PGM).
    pub images: PathBuf,
    /// One pose file (poses in order, or chunked) or a folder of one file per pose.
    pub poses: PathBuf,
    pub reading: Reading,
    pub target: TargetHeader,
    pub mount: Mount,
    /// The dataset to write (image paths are written relative to it when possible).
    pub out: PathBuf,
    /// Every N-th view (N-1, 2N-1, …, counted from 0) goes to `heldout` instead (0 = none).
    pub heldout_every: usize,
    pub heldout: Option<PathBuf>,
}

/// What the import found.
#[derive(Debug, Clone)]
pub struct HandeyeImport {
    /// `(dataset path, records written)`.
    pub written: Vec<(PathBuf, usize)>,
    pub width: u32,
    pub height: u32,
    /// Views with a detected board (used by the check).
    pub detected: usize,
    /// Images that gave no board: `(image, reason)`.
    pub unusable: Vec<(String, String)>,
    /// Spread of every candidate reading, best first (empty when not checkable).
    pub spreads: Vec<Spread>,
    pub warnings: Vec<String>,
}

fn usage(m: impl Into<String>) -> ImportError {
    ImportError::Usage(m.into())
}

/// Read the poses: a file, or a folder with one file per pose (numbered from the file names).
pub fn read_poses(path: &Path, count: usize) -> Result<Vec<PoseValues>, ImportError> {
    let read = |p: &Path| -> Result<String, ImportError> {
        let b = std::fs::read(p).map_err(|source| ImportError::Io {
            file: p.display().to_string(),
            source,
        })?;
        String::from_utf8(b).map_err(|e| {
            ImportError::bad(
                &p.display().to_string(),
                None,
                None,
                format!(
                    "not UTF-8 text (byte {}): a pose file holds numbers as text",
                    e.utf8_error().valid_up_to()
                ),
            )
        })
    };
    if path.is_dir() {
        let files = list_files(path, &[])?;
        if files.is_empty() {
            return Err(usage(format!(
                "{}: no pose files in the folder",
                path.display()
            )));
        }
        let mut out = vec![];
        for f in files {
            let name = f.display().to_string();
            let mut v = parse_pose_file(&read(&f)?, &name, count)?;
            if v.len() != 1 {
                return Err(ImportError::bad(
                    &name,
                    None,
                    None,
                    format!(
                        "{} poses in a file of a pose folder (one pose of {count} numbers per file expected)",
                        v.len()
                    ),
                ));
            }
            let mut p = v.remove(0);
            p.number = file_number(&f);
            out.push(p);
        }
        Ok(out)
    } else {
        parse_pose_file(&read(path)?, &path.display().to_string(), count)
    }
}

/// The path of `p` as a dataset at `out` names it: relative to the dataset's folder when `p`
/// is inside it, else absolute.
fn dataset_path(p: &Path, out: &Path) -> String {
    let abs = std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    let base = out
        .parent()
        .filter(|b| !b.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    match std::fs::canonicalize(base) {
        Ok(b) => abs
            .strip_prefix(&b)
            .map(|r| r.display().to_string())
            .unwrap_or_else(|_| abs.display().to_string()),
        Err(_) => abs.display().to_string(),
    }
}

/// Run the import: pair, detect, check the declaration, write the dataset(s).
pub fn import_handeye(o: &HandeyeOptions, progress: bool) -> Result<HandeyeImport, ImportError> {
    use rayon::prelude::*;
    let images = list_files(&o.images, robocal_drivers::camera::IMAGE_EXTENSIONS)?;
    if images.is_empty() {
        return Err(usage(format!(
            "{}: no image files ({})",
            o.images.display(),
            robocal_drivers::camera::IMAGE_EXTENSIONS.join(", ")
        )));
    }
    let poses = read_poses(&o.poses, o.reading.layout.count())?;
    let (pairs, mut warnings) = pair(&images, &poses)?;
    // The declared reading must read every pose.
    let mut flange = vec![];
    for (_, p) in &pairs {
        let f = o.reading.pose(&p.values).map_err(|e| {
            ImportError::bad(
                &p.file,
                Some(p.line),
                None,
                format!("under the declared reading ({}): {e}", o.reading.name()),
            )
        })?;
        flange.push(f);
    }
    let detector = crate::solve::camera::data::target_of(&o.target).map_err(usage)?;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let n = pairs.len();
    type Found = Result<(u32, u32, Vec<Option<[f64; 2]>>), String>;
    let found: Vec<Found> = pairs
        .par_iter()
        .map(|(img, _)| {
            let im = robocal_drivers::camera::read_image_file(img).map_err(|e| e.to_string())?;
            let c = detector.detect(&im.data, im.width, im.height);
            let k = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            if progress && (k.is_multiple_of(10) || k == n) {
                eprint!("\rdetecting the board: {k}/{n} images");
                if k == n {
                    eprintln!();
                }
            }
            Ok((im.width, im.height, c?))
        })
        .collect();
    let (width, height) = crate::solve::camera::data::common_size(
        found
            .iter()
            .filter_map(|r| r.as_ref().ok().map(|(w, h, _)| (*w, *h))),
    )
    .ok_or_else(|| {
        let (img, e) = pairs
            .iter()
            .zip(&found)
            .find_map(|((i, _), r)| r.as_ref().err().map(|e| (i, e)))
            .map(|(i, e)| (i.display().to_string(), e.clone()))
            .unwrap_or_default();
        usage(format!("no image could be read (first: {img}: {e})"))
    })?;
    let mut unusable = vec![];
    let mut corners: Vec<Option<Vec<Option<[f64; 2]>>>> = vec![];
    for ((img, _), r) in pairs.iter().zip(&found) {
        let name = img.display().to_string();
        match r {
            Ok((w, h, c)) if (*w, *h) == (width, height) => corners.push(Some(c.clone())),
            Ok((w, h, _)) => {
                unusable.push((
                    name,
                    format!("wrong size {w}×{h} (most images are {width}×{height})"),
                ));
                corners.push(None);
            }
            Err(e) => {
                unusable.push((name, e.clone()));
                corners.push(None);
            }
        }
    }
    let cam_board = board_in_camera(&corners, &o.target, width, height);
    let detected = cam_board.iter().filter(|b| b.is_some()).count();
    let frame = match o.mount {
        Mount::Flange => "base",
        Mount::Base => "flange",
    };
    let values: Vec<&[f64]> = pairs.iter().map(|(_, p)| p.values.as_slice()).collect();
    let spreads = check_readings(o.reading, &values, &cam_board, o.mount);
    if spreads.is_empty() {
        warnings.push(format!(
            "the pose reading could not be checked: {detected} views with a board (need {MIN_CHECK_VIEWS} with rotations between them)"
        ));
    }
    verdict(o.reading, &spreads, frame).map_err(usage)?;
    // Write.
    let header = json!({
        "format": crate::dataset::DATASET_FORMAT,
        "robot": {"model": crate::dataset::NO_ROBOT_MODEL},
        "camera": {"kind": "mono", "width": width, "height": height,
                   "mount": match o.mount { Mount::Flange => "flange", Mount::Base => "base" }},
        "target": o.target,
        "source": {"importer": "handeye", "images": o.images.display().to_string(),
                   "poses": o.poses.display().to_string(), "reading": o.reading.name()},
    });
    let mut train = vec![header.clone()];
    let mut held = vec![header];
    for (k, ((img, p), f)) in pairs.iter().zip(&flange).enumerate() {
        let to_held = o.heldout.is_some()
            && o.heldout_every > 0
            && k % o.heldout_every == o.heldout_every - 1;
        let out = if to_held {
            o.heldout.as_ref().unwrap_or(&o.out)
        } else {
            &o.out
        };
        let mut r = record(k as u64 + 1, f, &dataset_path(img, out), p);
        if to_held {
            r["group"] = json!("validation");
            held.push(r);
        } else {
            train.push(r);
        }
    }
    let mut written = vec![];
    for (path, lines) in [(Some(&o.out), &train), (o.heldout.as_ref(), &held)] {
        let Some(path) = path else { continue };
        let text: String = lines
            .iter()
            .map(|v| serde_json::to_string(v).unwrap_or_default() + "\n")
            .collect();
        crate::fsio::write(path, text).map_err(|source| ImportError::Io {
            file: path.display().to_string(),
            source,
        })?;
        crate::dataset::read_dataset(path)
            .map_err(|e| usage(format!("the written dataset does not load back: {e}")))?;
        written.push((path.clone(), lines.len() - 1));
    }
    Ok(HandeyeImport {
        written,
        width,
        height,
        detected,
        unusable,
        spreads,
        warnings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(layout: Layout, unit: LengthUnit, direction: Direction) -> Reading {
        Reading {
            layout,
            unit,
            direction,
        }
    }

    #[test]
    fn every_layout_reads_the_same_pose() {
        let p = Isometry3::from_parts(
            Translation3::new(412.0, -35.5, 505.25),
            UnitQuaternion::from_euler_angles(0.3, -0.7, 1.9),
        );
        let r = p.rotation.to_rotation_matrix().into_inner();
        let t = p.translation.vector / 1000.0;
        let m4row: Vec<f64> = (0..4)
            .flat_map(|i| (0..4).map(move |j| (i, j)))
            .map(|(i, j)| {
                if i == 3 {
                    if j == 3 {
                        1.0
                    } else {
                        0.0
                    }
                } else if j == 3 {
                    t[i]
                } else {
                    r[(i, j)]
                }
            })
            .collect();
        let m4col: Vec<f64> = (0..16).map(|k| m4row[(k % 4) * 4 + k / 4]).collect();
        let pt = p.translation.vector;
        let mut rot9col: Vec<f64> = (0..9).map(|k| r[(k % 3, k / 3)]).collect();
        rot9col.extend([pt.x, pt.y, pt.z]);
        let q = p.rotation.quaternion();
        let xyzw = vec![pt.x, pt.y, pt.z, q.i, q.j, q.k, q.w];
        let (roll, pitch, yaw) = p.rotation.euler_angles();
        // nalgebra's euler_angles: R = Rz(yaw)·Ry(pitch)·Rx(roll) = extrinsic xyz.
        let euler = vec![
            pt.x,
            pt.y,
            pt.z,
            roll.to_degrees(),
            pitch.to_degrees(),
            yaw.to_degrees(),
        ];
        let inv = p.inverse();
        let it = inv.translation.vector;
        let iq = inv.rotation.quaternion();
        let inv_wxyz = vec![it.x, it.y, it.z, iq.w, iq.i, iq.j, iq.k];
        let xyz: EulerSeq = "xyz".parse().unwrap();
        for (what, r, v) in [
            (
                "matrix4-row m",
                reading(
                    Layout::Matrix4 { col_major: false },
                    LengthUnit::M,
                    Direction::BaseFlange,
                ),
                m4row.clone(),
            ),
            (
                "matrix4-col m",
                reading(
                    Layout::Matrix4 { col_major: true },
                    LengthUnit::M,
                    Direction::BaseFlange,
                ),
                m4col,
            ),
            (
                "rot9-col mm",
                reading(
                    Layout::Rot9 { col_major: true },
                    LengthUnit::Mm,
                    Direction::BaseFlange,
                ),
                rot9col,
            ),
            (
                "quat-xyzw",
                reading(
                    Layout::Quat(QuatOrder::Xyzw),
                    LengthUnit::Mm,
                    Direction::BaseFlange,
                ),
                xyzw,
            ),
            (
                "euler xyz deg",
                reading(
                    Layout::Euler(xyz, AngleUnit::Deg),
                    LengthUnit::Mm,
                    Direction::BaseFlange,
                ),
                euler,
            ),
            (
                "quat-wxyz flange-base",
                reading(
                    Layout::Quat(QuatOrder::Wxyz),
                    LengthUnit::Mm,
                    Direction::FlangeBase,
                ),
                inv_wxyz,
            ),
        ] {
            let got = r.pose(&v).unwrap_or_else(|e| panic!("{what}: {e}"));
            let (dt, dr) = geom::pose_error(&p, &got);
            assert!(dt < 1e-6 && dr < 1e-6, "{what}: {dt} mm {dr}°");
        }
        // The transposed 4×4 has its translation in the last row: refused, naming why.
        let e = reading(
            Layout::Matrix4 { col_major: true },
            LengthUnit::M,
            Direction::BaseFlange,
        )
        .pose(&m4row)
        .unwrap_err();
        assert!(e.contains("last row"), "{e}");
        let e = reading(
            Layout::Rot9 { col_major: false },
            LengthUnit::Mm,
            Direction::BaseFlange,
        )
        .pose(&[1.0, 2.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
        .unwrap_err();
        assert!(e.contains("not a rotation"), "{e}");
    }

    #[test]
    fn pose_files_are_chunked_with_lines_and_bad_tokens_named() {
        let text =
            "# robot poses\nr11 r12 r13\n1 0 0 0 1 0 0 0 1 10 20 30\n\n0,1,0;-1 0 0 0 0 1 1 2 3\n";
        let p = parse_pose_file(text, "poses.txt", 12).unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!((p[0].line, p[1].line), (3, 5));
        assert_eq!(p[1].values[9..], [1.0, 2.0, 3.0]);
        let e = parse_pose_file(text, "poses.txt", 16)
            .unwrap_err()
            .to_string();
        assert!(e.contains("poses.txt") && e.contains("24 numbers"), "{e}");
        let e = parse_pose_file("1 2 3\n4 x 6\n", "p.txt", 3)
            .unwrap_err()
            .to_string();
        assert!(e.contains("p.txt:2") && e.contains("\"x\""), "{e}");
        let e = parse_pose_file("1 2 NaN\n", "p.txt", 3)
            .unwrap_err()
            .to_string();
        assert!(e.contains("NaN"), "{e}");
    }

    #[test]
    fn file_numbers_pair_images_with_pose_files() {
        assert_eq!(file_number(Path::new("a/cam0_012.jpg")), Some(12));
        assert_eq!(file_number(Path::new("endeffector007.txt")), Some(7));
        assert_eq!(file_number(Path::new("img.png")), None);
        let pv = |n: u64| PoseValues {
            file: format!("e{n}.txt"),
            line: 1,
            number: Some(n),
            values: vec![],
        };
        let imgs: Vec<PathBuf> = ["c_2.png", "c_1.png", "c_9.png"]
            .iter()
            .map(PathBuf::from)
            .collect();
        let (pairs, w) = pair(&imgs, &[pv(1), pv(2), pv(3)]).unwrap();
        assert_eq!(pairs.len(), 2);
        assert_eq!(pairs[0].1.number, Some(2));
        assert_eq!(w.len(), 2, "{w:?}");
        let e = pair(
            &imgs[..2],
            &[PoseValues {
                number: None,
                ..pv(1)
            }],
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("2 images but 1 poses"), "{e}");
    }

    /// A synthetic eye-in-hand rig: the spread test finds the right reading, refuses the
    /// transposed one (naming the right one), and accepts the right one.
    #[test]
    fn the_spread_test_names_the_right_reading() {
        let x = Isometry3::from_parts(
            Translation3::new(10.0, -40.0, 60.0),
            UnitQuaternion::from_euler_angles(0.1, 0.2, 1.4),
        );
        let board = Isometry3::from_parts(
            Translation3::new(600.0, 100.0, -20.0),
            UnitQuaternion::from_euler_angles(3.1, 0.05, 0.3),
        );
        let mut flange = vec![];
        let mut cam_board = vec![];
        for i in 0..12 {
            let a = i as f64;
            let f = Isometry3::from_parts(
                Translation3::new(
                    400.0 + 20.0 * a.sin(),
                    50.0 * (0.7 * a).cos(),
                    500.0 + 3.0 * a,
                ),
                UnitQuaternion::from_euler_angles(0.3 * a.sin(), 0.25 * (1.3 * a).cos(), 0.2 * a),
            );
            cam_board.push(Some((f * x).inverse() * board));
            flange.push(f);
        }
        let rot9col: Vec<Vec<f64>> = flange
            .iter()
            .map(|f| {
                let r = f.rotation.to_rotation_matrix().into_inner();
                let t = f.translation.vector;
                let mut v: Vec<f64> = (0..9).map(|k| r[(k % 3, k / 3)]).collect();
                v.extend([t.x, t.y, t.z]);
                v
            })
            .collect();
        let vals: Vec<&[f64]> = rot9col.iter().map(Vec::as_slice).collect();
        let right = reading(
            Layout::Rot9 { col_major: true },
            LengthUnit::Mm,
            Direction::BaseFlange,
        );
        let wrong = reading(
            Layout::Rot9 { col_major: false },
            LengthUnit::Mm,
            Direction::BaseFlange,
        );
        let s = check_readings(wrong, &vals, &cam_board, Mount::Flange);
        assert_eq!(s[0].reading, right, "{s:?}");
        assert!(s[0].mm < 1e-6 && s[0].deg < 1e-6, "{s:?}");
        let e = verdict(wrong, &s, "base").unwrap_err();
        assert!(e.contains("rot9-col") && e.contains("most likely"), "{e}");
        let s = check_readings(right, &vals, &cam_board, Mount::Flange);
        assert!(verdict(right, &s, "base").is_ok());
    }
}
