//! Chessboard detection in the default build: the pure-Rust `calib-targets` detector (ChESS
//! corners, grid labelling) plus what a calibration needs on top of it:
//!
//! * Board labels. The detector labels its grid from the image (origin at the visual top-left),
//!   which turns with the camera; a calibration needs the board's own corner indices. Among
//!   the grid → board maps that fit the board's size, the one that (1) keeps the board's
//!   handedness as seen from its printed side and (2) puts a dark square at square `(0, 0)`
//!   (the colour of every square sampled through the view's homography) is taken. A board
//!   with `cols + rows` even (inner corners) is symmetric under a half turn: then the labels
//!   stay ambiguous and detection refuses it.
//! * Only whole boards: a plain chessboard seen in part cannot be indexed (the visible part
//!   could be anywhere on the board), so a view with missing corners is rejected — the views
//!   where the board touches the image border included.
use calib_targets::chessboard::ChessboardParams;
use calib_targets::detect;
use calib_targets::image::GrayImage;
use nalgebra::{Matrix3, Vector3};

use super::zhang::homography;

/// The board to detect: inner corners `cols × rows`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoardSpec {
    pub cols: usize,
    pub rows: usize,
    pub square_mm: f64,
}

/// Why a view yields no corners.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DetectError {
    #[error("image is {got} bytes, expected {w}×{h}")]
    Size { got: usize, w: u32, h: u32 },
    #[error("no chessboard found")]
    NotFound,
    #[error("board seen in part ({found} of {expected} corners): a chessboard must be whole to be indexed")]
    Partial { found: usize, expected: usize },
    #[error("the board's orientation is ambiguous (inner corners {cols}×{rows}: cols + rows must be odd)")]
    Symmetric { cols: usize, rows: usize },
    #[error("no grid labelling is consistent with the board's handedness and square colours")]
    Orientation,
}

/// Detected corners in board order (row by row: index `j·cols + i`), pixels.
pub fn detect_chessboard(
    data: &[u8],
    width: u32,
    height: u32,
    board: &BoardSpec,
) -> Result<Vec<[f64; 2]>, DetectError> {
    if data.len() != (width as usize) * (height as usize) {
        return Err(DetectError::Size {
            got: data.len(),
            w: width,
            h: height,
        });
    }
    let img = GrayImage::from_raw(width, height, data.to_vec()).ok_or(DetectError::Size {
        got: data.len(),
        w: width,
        h: height,
    })?;
    let cfg = detect::default_chess_config();
    let det = detect::detect_chessboard_best(&img, &cfg, &ChessboardParams::sweep_default())
        .map_err(|_| DetectError::NotFound)?;
    let expected = board.cols * board.rows;
    let (mut gw, mut gh) = (0i32, 0i32);
    let (mut mu, mut mv) = (i32::MAX, i32::MAX);
    for c in &det.corners {
        mu = mu.min(c.grid.u);
        mv = mv.min(c.grid.v);
    }
    for c in &det.corners {
        gw = gw.max(c.grid.u - mu + 1);
        gh = gh.max(c.grid.v - mv + 1);
    }
    if det.corners.len() != expected
        || !((gw as usize == board.cols && gh as usize == board.rows)
            || (gw as usize == board.rows && gh as usize == board.cols))
    {
        return Err(DetectError::Partial {
            found: det.corners.len(),
            expected,
        });
    }
    let grid: Vec<((usize, usize), [f64; 2])> = det
        .corners
        .iter()
        .map(|c| {
            (
                ((c.grid.u - mu) as usize, (c.grid.v - mv) as usize),
                [c.position.x as f64, c.position.y as f64],
            )
        })
        .collect();
    let mut out = label(
        &grid,
        (gw as usize, gh as usize),
        data,
        width,
        height,
        board,
    )?;
    if refine_enabled() {
        let radius = super::subpix::grid_radius(&out, board.cols, board.rows);
        super::subpix::refine(data, width, height, &mut out, &radius);
    }
    Ok(out)
}

/// Whether [`detect_chessboard`] refines the detector's corners on the image
/// ([`super::subpix`]); on unless `ROBOCAL_SUBPIX=off` (benchmarks compare both).
fn refine_enabled() -> bool {
    std::env::var("ROBOCAL_SUBPIX").map_or(true, |v| v != "off")
}

/// Assign board indices to a whole labelled grid (see the module docs).
pub fn label(
    grid: &[((usize, usize), [f64; 2])],
    (gw, gh): (usize, usize),
    data: &[u8],
    width: u32,
    height: u32,
    board: &BoardSpec,
) -> Result<Vec<[f64; 2]>, DetectError> {
    let (c, r) = (board.cols, board.rows);
    if (c + r) % 2 == 0 {
        return Err(DetectError::Symmetric { cols: c, rows: r });
    }
    type Map = Box<dyn Fn(usize, usize) -> (usize, usize)>;
    let mut cands: Vec<Map> = vec![];
    if gw == c && gh == r {
        cands.push(Box::new(|u: usize, v: usize| (u, v)));
        cands.push(Box::new(move |u: usize, v: usize| (c - 1 - u, v)));
        cands.push(Box::new(move |u: usize, v: usize| (u, r - 1 - v)));
        cands.push(Box::new(move |u: usize, v: usize| (c - 1 - u, r - 1 - v)));
    }
    if gw == r && gh == c {
        cands.push(Box::new(|u: usize, v: usize| (v, u)));
        cands.push(Box::new(move |u: usize, v: usize| (c - 1 - v, u)));
        cands.push(Box::new(move |u: usize, v: usize| (v, r - 1 - u)));
        cands.push(Box::new(move |u: usize, v: usize| (c - 1 - v, r - 1 - u)));
    }
    let s = board.square_mm;
    let grey = |x: f64, y: f64| -> Option<f64> {
        let (i, j) = (x.round() as i64, y.round() as i64);
        (i >= 0 && j >= 0 && (i as u32) < width && (j as u32) < height)
            .then(|| data[j as usize * width as usize + i as usize] as f64)
    };
    let mut best: Option<(f64, Vec<[f64; 2]>)> = None;
    for m in &cands {
        let mut out = vec![[f64::NAN; 2]; c * r];
        for ((u, v), p) in grid {
            let (i, j) = m(*u, *v);
            out[j * c + i] = *p;
        }
        let plane: Vec<[f64; 2]> = (0..r)
            .flat_map(|j| (0..c).map(move |i| [(i + 1) as f64 * s, (j + 1) as f64 * s]))
            .collect();
        let Some(h) = homography(&plane, &out) else {
            continue;
        };
        let at = |h: &Matrix3<f64>, x: f64, y: f64| {
            let q = h * Vector3::new(x, y, 1.0);
            (q.x / q.z, q.y / q.z)
        };
        // Handedness: board +i × +j must be negative in image (u right, v down) coordinates.
        let (o, ei, ej) = (at(&h, s, s), at(&h, 2.0 * s, s), at(&h, s, 2.0 * s));
        let cross = (ei.0 - o.0) * (ej.1 - o.1) - (ei.1 - o.1) * (ej.0 - o.0);
        if cross >= 0.0 {
            continue;
        }
        // Square colours: square (a, b) is dark iff a + b is even.
        let mut samples = vec![];
        for b in 0..=r {
            for a in 0..=c {
                let (x, y) = at(&h, (a as f64 + 0.5) * s, (b as f64 + 0.5) * s);
                if let Some(g) = grey(x, y) {
                    samples.push((if (a + b) % 2 == 0 { -1.0 } else { 1.0 }, g));
                }
            }
        }
        let n = samples.len();
        let mean = samples.iter().map(|(_, g)| g).sum::<f64>() / n.max(1) as f64;
        let score: f64 = samples.iter().map(|(sg, g)| sg * (g - mean)).sum();
        if n == 0 || score <= 0.0 {
            continue;
        }
        if best.as_ref().is_none_or(|(bs, _)| score > *bs) {
            best = Some((score, out));
        }
    }
    best.map(|(_, o)| o).ok_or(DetectError::Orientation)
}
