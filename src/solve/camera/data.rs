//! Camera datasets → [`CameraData`]: the header's `camera` / `target` blocks (or overrides),
//! each pose record's flange pose (its `flange`, else FK of `q` through the header's robot),
//! and the board's corners: detected from the record's `image` with the pure-Rust detector
//! ([`super::detect`] for a chessboard, [`super::charuco`] for a ChArUco board: partial views
//! included), else the record's `corners` taken in board order.
#![allow(clippy::type_complexity)]
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::charuco::{detect_charuco, CharucoError, CharucoSpec};
use super::detect::{detect_chessboard, BoardSpec};
use super::{CameraData, Mount, View};
use crate::dataset::{CameraHeader, Dataset, TargetHeader};
use crate::model::KinematicModel;

/// Errors reading a camera dataset.
#[derive(Debug, thiserror::Error)]
pub enum CameraDataError {
    #[error("{file}: {msg}")]
    Header { file: String, msg: String },
    #[error("{file}: pose {id}: {msg}")]
    Record { file: String, id: u64, msg: String },
    #[error(transparent)]
    Dataset(#[from] crate::dataset::DatasetError),
}

/// Overrides of the header's board / mount.
#[derive(Debug, Clone, Default)]
pub struct Overrides {
    /// Inner corners.
    pub board: Option<(u32, u32)>,
    pub square_mm: Option<f64>,
    pub mount: Option<Mount>,
}

/// A camera dataset and how its views were obtained.
#[derive(Debug, Clone)]
pub struct Loaded {
    pub data: CameraData,
    pub camera: CameraHeader,
    pub target: TargetHeader,
    /// Views without a usable board: `(id, reason)`.
    pub no_board: Vec<(u64, String)>,
    /// What detection noticed in usable views (markers inside a chessboard's squares…).
    pub notes: Vec<(u64, String)>,
    pub dataset: Dataset,
}

/// Read `path` (see the module docs). `progress` shows a bar while detecting.
pub fn load(path: &Path, ov: &Overrides, progress: bool) -> Result<Loaded, CameraDataError> {
    load_dataset(Dataset::load(path)?, path, ov, progress)
}

/// As [`load`], on the dataset `ds` already read from `path` (its images are found beside it).
pub fn load_dataset(
    ds: Dataset,
    path: &Path,
    ov: &Overrides,
    progress: bool,
) -> Result<Loaded, CameraDataError> {
    let file = path.display().to_string();
    let herr = |msg: String| CameraDataError::Header {
        file: file.clone(),
        msg,
    };
    let cam = ds.header.camera().map_err(&herr)?;
    let target = ds.header.target().map_err(&herr)?;
    let mut target = match (target, ov.board, ov.square_mm) {
        (Some(t), _, _) => t,
        (None, Some((c, r)), Some(s)) => TargetHeader {
            kind: "chessboard".into(),
            cols: c,
            rows: r,
            square_mm: s,
            marker_mm: None,
            dictionary: None,
        },
        (None, _, _) => return Err(herr(
            "no \"target\" block in the header: give the board with --board COLSxROWS --square MM"
                .into(),
        )),
    };
    if let Some((c, r)) = ov.board {
        target.cols = c;
        target.rows = r;
    }
    if let Some(s) = ov.square_mm {
        target.square_mm = s;
    }
    let detector = target_of(&target).map_err(&herr)?;
    let board = detector.board();
    let model = KinematicModel::from_robot_block(&ds.header.robot).ok();
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let recs: Vec<_> = ds.poses().cloned().collect();
    let mut flanges = vec![];
    for r in &recs {
        let f = crate::solve::laser::record_flange(r, model.as_ref()).map_err(|e| {
            CameraDataError::Record {
                file: file.clone(),
                id: r.id,
                msg: e.to_string(),
            }
        })?;
        flanges.push(f);
    }
    let bar = progress.then(|| {
        let b = indicatif::ProgressBar::new(recs.len() as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template(
                "detecting {bar:30} {pos}/{len} images {elapsed}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    });
    let mut size: Option<(u32, u32)> = cam.as_ref().map(|c| (c.width, c.height));
    let noted: Vec<(Result<Corners, String>, Option<String>)> = recs
        .par_iter()
        .map(|r| {
            let mut note = None;
            let out = corners_of(r, &base, &detector, size, &mut note);
            if let Some(b) = &bar {
                b.inc(1);
            }
            (out, note)
        })
        .collect();
    let notes: Vec<(u64, String)> = recs
        .iter()
        .zip(&noted)
        .filter_map(|(r, (_, n))| Some((r.id, n.clone()?)))
        .collect();
    let detected: Vec<Result<Corners, String>> = noted.into_iter().map(|(d, _)| d).collect();
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    if size.is_none() {
        size = common_size(detected.iter().filter_map(|d| d.as_ref().ok()?.1));
    }
    let mut views = vec![];
    let mut no_board = vec![];
    for ((r, f), d) in recs.iter().zip(&flanges).zip(detected) {
        match d {
            Ok((c, sz)) => {
                if let (Some(s), Some(want)) = (sz, size) {
                    if s != want {
                        let whose = if cam.is_some() {
                            "the header's camera is"
                        } else {
                            "most images are"
                        };
                        no_board.push((
                            r.id,
                            format!(
                                "image {}: wrong size {}×{} ({whose} {}×{}): another camera or a resized copy",
                                r.image.as_deref().unwrap_or("?"),
                                s.0,
                                s.1,
                                want.0,
                                want.1
                            ),
                        ));
                        continue;
                    }
                }
                views.push(View {
                    id: r.id,
                    flange: *f,
                    corners: c,
                });
            }
            Err(e) => no_board.push((r.id, e)),
        }
    }
    let (w, h) =
        size.ok_or_else(|| herr("no \"camera\" block and no image to take the size from".into()))?;
    let camera = cam.unwrap_or(CameraHeader {
        kind: "mono".into(),
        width: w,
        height: h,
        name: None,
        mount: None,
    });
    let mount = match (ov.mount, camera.mount.as_deref()) {
        (Some(m), _) => m,
        (None, None | Some("flange")) => Mount::Flange,
        (None, Some("base")) => Mount::Base,
        (None, Some(other)) => {
            return Err(herr(format!(
                "field \"camera.mount\": {other:?} (expected \"flange\" or \"base\")"
            )))
        }
    };
    Ok(Loaded {
        data: CameraData {
            width: w,
            height: h,
            board,
            mount,
            views,
        },
        camera,
        target,
        no_board,
        notes,
        dataset: ds,
    })
}

type Corners = (Vec<Option<[f64; 2]>>, Option<(u32, u32)>);

/// The most common image size (the first seen on a tie), `None` without images.
pub fn common_size(sizes: impl Iterator<Item = (u32, u32)>) -> Option<(u32, u32)> {
    let mut counts: Vec<((u32, u32), usize)> = vec![];
    for s in sizes {
        match counts.iter_mut().find(|(k, _)| *k == s) {
            Some((_, n)) => *n += 1,
            None => counts.push((s, 1)),
        }
    }
    let best = counts.iter().map(|(_, n)| *n).max()?;
    counts.into_iter().find(|(_, n)| *n == best).map(|(k, _)| k)
}

/// The likely cause when images give no view (the cause, not the symptom), from the reasons of
/// [`Loaded::no_board`]: the images that could not be read, that have another size, or that
/// were read but show no board of the declared layout (a wrong `--board` / `target` block:
/// inner corners, not squares, or rows and columns swapped; the board out of view). `None`
/// when every image gave a view.
pub fn likely_cause(l: &Loaded) -> Option<String> {
    let first = |f: &dyn Fn(&str) -> bool| {
        l.no_board
            .iter()
            .find(|(_, w)| f(w))
            .map(|(id, w)| format!("pose {id}: {w}"))
    };
    let size = |w: &str| w.contains("wrong size");
    let detect = |w: &str| w.starts_with("image ") && !size(w);
    let unread = |w: &str| {
        !w.starts_with("image ") && !w.starts_with("field ") && !w.starts_with("no image")
    };
    let total = l.no_board.len() + l.data.views.len();
    let count = |f: &dyn Fn(&str) -> bool| l.no_board.iter().filter(|(_, w)| f(w)).count();
    let b = l.data.board;
    let mut out = vec![];
    let n = count(&detect);
    if n > 0 {
        out.push(format!(
            "{n} of {total} images were read but show no {}×{} {} board of {} mm squares: \
             likely a wrong --board / target block (it counts inner corners, not squares; rows \
             and columns swapped?) or the board out of view or focus (first: {})",
            b.cols,
            b.rows,
            l.target.kind,
            b.square_mm,
            first(&detect).unwrap_or_default()
        ));
    }
    let n = count(&unread);
    if n > 0 {
        out.push(format!(
            "{n} of {total} images could not be read (missing, a directory, not an image or \
             truncated; first: {})",
            first(&unread).unwrap_or_default()
        ));
    }
    let n = count(&size);
    if n > 0 {
        out.push(format!(
            "{n} of {total} images have another size (another camera or a resized copy)"
        ));
    }
    (!out.is_empty()).then(|| out.join("; "))
}

/// The console lines naming every image (or record) that gives no view, and why.
pub fn unusable_lines(l: &Loaded, label: &str) -> Vec<String> {
    let mut v: Vec<String> = l
        .no_board
        .iter()
        .map(|(id, why)| format!("{label} pose {id}: not used: {why}"))
        .collect();
    if let Some((id, n)) = l.notes.first() {
        v.push(format!(
            "{label} pose {id} (and {} more views): {n}",
            l.notes.len() - 1
        ));
    }
    v
}

/// What is detected in each image: the header's `target` block, checked.
#[derive(Debug, Clone, PartialEq)]
pub enum Target {
    Chessboard(BoardSpec),
    Charuco(CharucoSpec),
}

impl Target {
    /// The corner layout the solver uses.
    pub fn board(&self) -> BoardSpec {
        match self {
            Target::Chessboard(b) => *b,
            Target::Charuco(c) => c.board(),
        }
    }

    /// Corners in board order (`None` = not seen) in an 8-bit image.
    pub fn detect(
        &self,
        data: &[u8],
        width: u32,
        height: u32,
    ) -> Result<Vec<Option<[f64; 2]>>, String> {
        match self {
            Target::Chessboard(b) => detect_chessboard(data, width, height, b)
                .map(|c| c.into_iter().map(Some).collect())
                .map_err(|e| e.to_string()),
            Target::Charuco(c) => detect_charuco(data, width, height, c).map_err(|e| e.to_string()),
        }
    }
}

/// Check a header `target` block strictly (the error names the field and the cause).
pub fn target_of(t: &TargetHeader) -> Result<Target, String> {
    if !(t.square_mm.is_finite() && t.square_mm > 0.0) || t.cols < 2 || t.rows < 2 {
        return Err(format!(
            "field \"target\": a board needs ≥ 2×2 inner corners and a positive square_mm, got {}×{} and {}",
            t.cols, t.rows, t.square_mm
        ));
    }
    let board = BoardSpec {
        cols: t.cols as usize,
        rows: t.rows as usize,
        square_mm: t.square_mm,
    };
    match t.kind.as_str() {
        "chessboard" => {
            for (field, set) in [
                ("marker_mm", t.marker_mm.is_some()),
                ("dictionary", t.dictionary.is_some()),
            ] {
                if set {
                    return Err(format!(
                        "field \"target.{field}\": only a \"charuco\" target has markers (kind is \"chessboard\")"
                    ));
                }
            }
            Ok(Target::Chessboard(board))
        }
        "charuco" => {
            let marker_mm = t.marker_mm.ok_or_else(|| {
                "field \"target.marker_mm\": missing (a \"charuco\" target needs its marker edge in mm)"
                    .to_string()
            })?;
            let dictionary = t.dictionary.clone().ok_or_else(|| {
                "field \"target.dictionary\": missing (a \"charuco\" target needs its ArUco dictionary, e.g. \"DICT_4X4_50\")"
                    .to_string()
            })?;
            let spec = CharucoSpec {
                cols: board.cols,
                rows: board.rows,
                square_mm: board.square_mm,
                marker_mm,
                dictionary,
            };
            spec.validate().map_err(|e| {
                let field = match e {
                    CharucoError::Dictionary(_) => "target.dictionary",
                    _ => "target",
                };
                format!("field \"{field}\": {e}")
            })?;
            Ok(Target::Charuco(spec))
        }
        other => Err(format!(
            "field \"target.kind\": {other:?} (expected \"chessboard\" or \"charuco\")"
        )),
    }
}

/// `expect`: the header's image size (an image of another size is refused before detection).
fn corners_of(
    r: &crate::dataset::PoseRecord,
    base: &Path,
    target: &Target,
    expect: Option<(u32, u32)>,
    note: &mut Option<String>,
) -> Result<Corners, String> {
    let board = target.board();
    let n = board.cols * board.rows;
    if let Some(img) = &r.image {
        let p: PathBuf = base.join(img);
        let im = robocal_drivers::camera::read_image_file(&p).map_err(|e| e.to_string())?;
        if let Some((w, h)) = expect.filter(|s| *s != (im.width, im.height)) {
            return Err(format!(
                "image {img}: wrong size {}×{} (the header's camera is {w}×{h}): another camera or a resized copy",
                im.width, im.height
            ));
        }
        let c = target
            .detect(&im.data, im.width, im.height)
            .map_err(|e| format!("image {img}: {e}"))?;
        if let Target::Chessboard(b) = target {
            let pts: Vec<[f64; 2]> = c.iter().flatten().copied().collect();
            let share = super::detect::markers_in_squares(&im.data, im.width, im.height, &pts, b);
            if share >= super::detect::MARKER_SQUARES_SHARE {
                *note = Some(format!(
                    "image {img}: markers printed inside {:.0} % of the light squares: this looks like a ChArUco board declared as a chessboard (declare target kind \"charuco\" with marker_mm and dictionary; the corners were refined in the squares' clean rim only)",
                    100.0 * share
                ));
            }
        }
        return Ok((c, Some((im.width, im.height))));
    }
    match &r.corners {
        Some(c) if c.len() == n => Ok((
            c.iter()
                .map(|p| p.iter().all(|v| v.is_finite()).then_some(*p))
                .collect(),
            None,
        )),
        Some(c) => Err(format!(
            "field \"corners\": {} points, the board has {n} inner corners",
            c.len()
        )),
        None => Err("no image and no corners".into()),
    }
}
