//! ChArUco detection in the default build: `calib-targets`' ChArUco detector (ChESS corners,
//! grid, ArUco decoding in the grid's cells, alignment to the board by the decoded ids), then
//! the sub-pixel refinement of [`super::subpix`] with a window that stays clear of the
//! markers.
//!
//! Every corner carries its board id (OpenCV's ChArUco corner id = our board order
//! `j·cols + i`, inner corner `(i, j)` at `((i+1)·S, (j+1)·S, 0)`), so a view of part of the
//! board — cut by the image border or occluded — still yields labelled corners: that is what
//! ChArUco is for. Corners not seen are `None`.
//!
//! Board frame (OpenCV's for ChArUco): origin at the printed board's top-left outer corner
//! (square `(0, 0)` dark, marker 0 in square `(1, 0)`), x along the columns, y along the rows
//! as printed; z therefore points into the board, away from a camera that reads the markers.
use calib_targets::aruco::builtins::{builtin_dictionary, BUILTIN_DICTIONARY_NAMES};
use calib_targets::charuco::{CharucoBoardSpec, CharucoDetector, CharucoParams};
use calib_targets::core::GrayImageView;

use super::detect::BoardSpec;

/// A ChArUco board: inner corners `cols × rows` (squares `(cols+1) × (rows+1)`), square and
/// marker edges (mm), OpenCV dictionary name.
#[derive(Debug, Clone, PartialEq)]
pub struct CharucoSpec {
    pub cols: usize,
    pub rows: usize,
    pub square_mm: f64,
    pub marker_mm: f64,
    pub dictionary: String,
}

/// Why a ChArUco board is refused or not found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CharucoError {
    #[error("image is {got} bytes, expected {w}×{h}")]
    Size { got: usize, w: u32, h: u32 },
    #[error("unknown ArUco dictionary {0:?} (known: {known})", known = BUILTIN_DICTIONARY_NAMES.join(", "))]
    Dictionary(String),
    #[error("ChArUco board: {0}")]
    Board(String),
    #[error("no ChArUco board found: {0}")]
    NotFound(String),
    #[error("ChArUco board seen with {0} corners (need at least 4)")]
    TooFew(usize),
}

impl CharucoSpec {
    /// The board geometry the solver uses (same corner layout as a chessboard).
    pub fn board(&self) -> BoardSpec {
        BoardSpec {
            cols: self.cols,
            rows: self.rows,
            square_mm: self.square_mm,
        }
    }

    /// Check the board against the dictionary (known name, enough markers, marker inside its
    /// square); the error says which value is wrong.
    pub fn validate(&self) -> Result<(), CharucoError> {
        self.params().map(|_| ())
    }

    fn params(&self) -> Result<CharucoParams, CharucoError> {
        let dict = builtin_dictionary(&self.dictionary)
            .ok_or_else(|| CharucoError::Dictionary(self.dictionary.clone()))?;
        if self.cols < 1 || self.rows < 1 {
            return Err(CharucoError::Board(format!(
                "{}×{} inner corners: need at least 1×1",
                self.cols, self.rows
            )));
        }
        if !(self.square_mm.is_finite() && self.square_mm > 0.0) {
            return Err(CharucoError::Board(format!(
                "square_mm = {} must be positive",
                self.square_mm
            )));
        }
        if !(self.marker_mm.is_finite() && self.marker_mm > 0.0 && self.marker_mm < self.square_mm)
        {
            return Err(CharucoError::Board(format!(
                "marker_mm = {} must be positive and smaller than square_mm = {}",
                self.marker_mm, self.square_mm
            )));
        }
        let squares = (self.cols + 1) * (self.rows + 1);
        let markers = squares / 2;
        if markers > dict.codes().len() {
            return Err(CharucoError::Board(format!(
                "{}×{} squares carry {markers} markers, dictionary {} has only {}",
                self.cols + 1,
                self.rows + 1,
                self.dictionary,
                dict.codes().len()
            )));
        }
        let spec = CharucoBoardSpec::new(
            (self.rows + 1) as u32,
            (self.cols + 1) as u32,
            self.square_mm as f32,
            (self.marker_mm / self.square_mm) as f32,
            dict,
        );
        Ok(CharucoParams::for_board(spec))
    }
}

/// Labelled corners in board order (`None` = not seen), pixels, sub-pixel refined.
pub fn detect_charuco(
    data: &[u8],
    width: u32,
    height: u32,
    spec: &CharucoSpec,
) -> Result<Vec<Option<[f64; 2]>>, CharucoError> {
    let mut out = detect_raw(data, width, height, spec)?;
    if refine_enabled() {
        refine(data, width, height, spec, &mut out);
    }
    Ok(out)
}

/// The detector's own corners (no refinement).
pub fn detect_raw(
    data: &[u8],
    width: u32,
    height: u32,
    spec: &CharucoSpec,
) -> Result<Vec<Option<[f64; 2]>>, CharucoError> {
    if data.len() != (width as usize) * (height as usize) {
        return Err(CharucoError::Size {
            got: data.len(),
            w: width,
            h: height,
        });
    }
    let det =
        CharucoDetector::new(spec.params()?).map_err(|e| CharucoError::Board(e.to_string()))?;
    // (calib-targets' three-config sweep, `detect_charuco_best` + `sweep_for_board`, found
    // no more boards or corners on the benchmark views and cost 40 % more time: not used.)
    let view = GrayImageView {
        width: width as usize,
        height: height as usize,
        data,
    };
    let found = det
        .detect(&view)
        .map_err(|e| CharucoError::NotFound(e.to_string()))?;
    let n = spec.cols * spec.rows;
    let mut out = vec![None; n];
    let mut count = 0;
    for c in &found.corners {
        let k = c.id as usize;
        let p = [c.position.x as f64, c.position.y as f64];
        if k < n && p.iter().all(|v| v.is_finite()) && out[k].is_none() {
            out[k] = Some(p);
            count += 1;
        }
    }
    if count < 4 {
        return Err(CharucoError::TooFew(count));
    }
    Ok(out)
}

/// Whether the corners are refined on the image; on unless `ROBOCAL_SUBPIX=off`.
fn refine_enabled() -> bool {
    std::env::var("ROBOCAL_SUBPIX").map_or(true, |v| v != "off")
}

/// Window radius of each seen corner: the chessboard's (0.4 × the nearest seen neighbour's
/// distance) but inside the white margin round the markers: the nearest marker corner is
/// `√2·(S − M)/2` from a chessboard corner, so the window stays within 0.9 of that (in pixels
/// at the local scale, less 1.5 px for the blur) and sees only the corner's own two edges.
pub fn window_radius(corners: &[Option<[f64; 2]>], spec: &CharucoSpec) -> Vec<f64> {
    let (c, r) = (spec.cols, spec.rows);
    let dist = |a: [f64; 2], b: [f64; 2]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
    let mut near: Vec<Option<f64>> = vec![None; c * r];
    for k in 0..c * r {
        let Some(p) = corners[k] else { continue };
        let (i, j) = (k % c, k / c);
        let mut m = f64::INFINITY;
        let nbs = [
            (i > 0).then(|| k - 1),
            (i + 1 < c).then(|| k + 1),
            (j > 0).then(|| k - c),
            (j + 1 < r).then(|| k + c),
        ];
        for q in nbs.into_iter().flatten() {
            if let Some(pq) = corners[q] {
                m = m.min(dist(p, pq));
            }
        }
        near[k] = m.is_finite().then_some(m);
    }
    // Corners without a seen neighbour take the view's median spacing.
    let mut seen: Vec<f64> = near.iter().flatten().copied().collect();
    seen.sort_by(f64::total_cmp);
    let median = seen.get(seen.len() / 2).copied().unwrap_or(20.0);
    let margin =
        std::f64::consts::SQRT_2 * 0.5 * (spec.square_mm - spec.marker_mm) / spec.square_mm;
    near.iter()
        .map(|d| {
            let d = d.unwrap_or(median);
            (d / 2.5).min(0.9 * margin * d - 1.5).clamp(2.0, 40.0)
        })
        .collect()
}

/// Farthest a refined corner may move from the detector's position (px): the detector is
/// within 0.31 px on every corner of the whole, close and half-outside views of
/// `examples/camera_detector.rs charuco` (mean 0.08–0.11 px), so a
/// corner that moves farther has something else in its window (an occluder's edge, the image
/// border) and is dropped.
pub const MAX_REFINE_MOVE_PX: f64 = 0.5;

/// Sub-pixel refinement of the seen corners in place (see [`window_radius`]); corners whose
/// refinement fails or moves them more than [`MAX_REFINE_MOVE_PX`] are dropped (`None`).
pub fn refine(
    data: &[u8],
    width: u32,
    height: u32,
    spec: &CharucoSpec,
    corners: &mut [Option<[f64; 2]>],
) {
    let radius = window_radius(corners, spec);
    let idx: Vec<usize> = (0..corners.len())
        .filter(|&k| corners[k].is_some())
        .collect();
    let mut pts: Vec<[f64; 2]> = idx.iter().filter_map(|&k| corners[k]).collect();
    let rad: Vec<f64> = idx.iter().map(|&k| radius[k]).collect();
    let failed = super::subpix::refine(data, width, height, &mut pts, &rad);
    for (n, (k, p)) in idx.iter().zip(pts).enumerate() {
        let Some(q) = corners[*k] else { continue };
        let moved = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt();
        corners[*k] = (!failed.contains(&n) && moved <= MAX_REFINE_MOVE_PX).then_some(p);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(dict: &str, marker: f64) -> CharucoSpec {
        CharucoSpec {
            cols: 8,
            rows: 5,
            square_mm: 30.0,
            marker_mm: marker,
            dictionary: dict.into(),
        }
    }

    #[test]
    fn bad_boards_are_refused_with_the_reason() {
        assert!(spec("DICT_4X4_50", 22.0).validate().is_ok());
        let e = spec("DICT_4X4_51", 22.0)
            .validate()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("unknown ArUco dictionary \"DICT_4X4_51\"") && e.contains("DICT_5X5_100"),
            "{e}"
        );
        let e = spec("DICT_4X4_50", 31.0)
            .validate()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("marker_mm = 31 must be positive and smaller than square_mm = 30"),
            "{e}"
        );
        let big = CharucoSpec {
            cols: 11,
            rows: 9,
            ..spec("DICT_4X4_50", 22.0)
        };
        let e = big.validate().unwrap_err().to_string();
        assert!(e.contains("60 markers") && e.contains("only 50"), "{e}");
    }

    #[test]
    fn the_window_stays_inside_the_white_margin() {
        // 48 px squares, 22 mm markers in 30 mm squares: margin corner at 9.05 px.
        let s = spec("DICT_4X4_50", 22.0);
        let c: Vec<Option<[f64; 2]>> = (0..40)
            .map(|k| Some([(k % 8) as f64 * 48.0, (k / 8) as f64 * 48.0]))
            .collect();
        let r = window_radius(&c, &s);
        let want = 0.9 * std::f64::consts::SQRT_2 * 4.0 / 30.0 * 48.0 - 1.5;
        assert!(r.iter().all(|r| (r - want).abs() < 1e-9), "{r:?}");
        // Small markers: the chessboard's 0.4 × spacing.
        let r = window_radius(&c, &spec("DICT_4X4_50", 5.0));
        assert!(r.iter().all(|r| (r - 48.0 / 2.5).abs() < 1e-9), "{r:?}");
    }
}
