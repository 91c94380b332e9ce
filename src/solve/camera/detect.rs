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
use calib_targets::core::DetectorConfig;
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
    #[error("the detected grid has {found} corners, more than the board's {expected}, and no single whole board in it (check the declared board size)")]
    Extra { found: usize, expected: usize },
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
    // Coarse to fine first: the ChESS response on a 3-level pyramid, refined at full
    // resolution in small windows about the coarse seeds (≈ 13× less work than the full-image
    // response on 1280×1024 views, the same corners to the bit where it finds the board). A
    // view where it gives no whole board (it can miss a corner on a hard real image) is
    // detected again on the full image, as before, and that result (or error) stands.
    board_in(&img, data, &coarse_to_fine(), board)
        .or_else(|_| board_in(&img, data, &detect::default_chess_config(), board))
}

/// The project's ChESS configuration with the library's 3-level pyramid.
fn coarse_to_fine() -> DetectorConfig {
    let mut cfg = detect::default_chess_config();
    cfg.multiscale = DetectorConfig::chess_multiscale().multiscale;
    cfg
}

/// [`detect_chessboard`] with the ChESS detector configured by `cfg`.
fn board_in(
    img: &GrayImage,
    data: &[u8],
    cfg: &DetectorConfig,
    board: &BoardSpec,
) -> Result<Vec<[f64; 2]>, DetectError> {
    let (width, height) = (img.width(), img.height());
    let det = detect::detect_chessboard_best(img, cfg, &ChessboardParams::sweep_default())
        .map_err(|_| DetectError::NotFound)?;
    let expected = board.cols * board.rows;
    let mut corners = det.corners;
    if corners.len() > expected {
        // The detector's grid reaches past the board (a corner found on the board's margin or
        // on the background): keep the one whole board-sized window in it, if there is one.
        let cells: Vec<(i32, i32)> = corners.iter().map(|c| (c.grid.u, c.grid.v)).collect();
        match whole_board_window(&cells, board) {
            Some((u0, v0, w, h)) => corners
                .retain(|c| (u0..u0 + w).contains(&c.grid.u) && (v0..v0 + h).contains(&c.grid.v)),
            None => {
                return Err(DetectError::Extra {
                    found: corners.len(),
                    expected,
                })
            }
        }
    }
    let (mut gw, mut gh) = (0i32, 0i32);
    let (mut mu, mut mv) = (i32::MAX, i32::MAX);
    for c in &corners {
        mu = mu.min(c.grid.u);
        mv = mv.min(c.grid.v);
    }
    for c in &corners {
        gw = gw.max(c.grid.u - mu + 1);
        gh = gh.max(c.grid.v - mv + 1);
    }
    if corners.len() != expected
        || !((gw as usize == board.cols && gh as usize == board.rows)
            || (gw as usize == board.rows && gh as usize == board.cols))
    {
        return Err(DetectError::Partial {
            found: corners.len(),
            expected,
        });
    }
    let grid: Vec<((usize, usize), [f64; 2])> = corners
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
        let mut radius = super::subpix::grid_radius(&out, board.cols, board.rows);
        if markers_in_squares(data, width, height, &out, board) >= MARKER_SQUARES_SHARE {
            // Printed markers inside the light squares (a ChArUco board declared as a
            // chessboard): keep the window inside the squares' clean rim.
            for r in &mut radius {
                *r *= MARKER_WINDOW / WINDOW;
            }
        }
        super::subpix::refine(data, width, height, &mut out, &radius);
    }
    Ok(out)
}

/// The one window of the board's size (`cols × rows`, either way round) whose every cell is in
/// `cells` (grid coordinates): `(u0, v0, width, height)`. `None` when there is none or more
/// than one (which corners are the board's would be a guess).
fn whole_board_window(cells: &[(i32, i32)], board: &BoardSpec) -> Option<(i32, i32, i32, i32)> {
    if cells.is_empty() {
        return None;
    }
    let set: std::collections::HashSet<(i32, i32)> = cells.iter().copied().collect();
    let (u_min, u_max) = cells
        .iter()
        .fold((i32::MAX, i32::MIN), |a, c| (a.0.min(c.0), a.1.max(c.0)));
    let (v_min, v_max) = cells
        .iter()
        .fold((i32::MAX, i32::MIN), |a, c| (a.0.min(c.1), a.1.max(c.1)));
    let (c, r) = (board.cols as i32, board.rows as i32);
    let mut sizes = vec![(c, r)];
    if c != r {
        sizes.push((r, c));
    }
    let mut found = vec![];
    for (w, h) in sizes {
        for u0 in u_min..=u_max - w + 1 {
            for v0 in v_min..=v_max - h + 1 {
                if (u0..u0 + w).all(|u| (v0..v0 + h).all(|v| set.contains(&(u, v)))) {
                    found.push((u0, v0, w, h));
                }
            }
        }
    }
    (found.len() == 1).then(|| found[0])
}

/// Sub-pixel window radius as a fraction of the corner spacing on a plain chessboard
/// ([`super::subpix::grid_radius`]).
pub const WINDOW: f64 = 0.4;
/// The window's fraction of the corner spacing when the light squares carry markers: a
/// ChArUco marker of up to 0.8 × the square leaves a clean rim of (1 − 0.8) / 2 × the square
/// along each edge, which a disc of 0.12 × the spacing about the corner never leaves
/// (√2 · 0.12 < 0.2).
pub const MARKER_WINDOW: f64 = 0.12;
/// Share of the light squares with dark printing in their centre from which a board declared
/// as a chessboard is taken to carry markers.
pub const MARKER_SQUARES_SHARE: f64 = 0.5;

/// The share of the board's interior light squares whose central half is more than 15 % dark
/// (markers printed inside the squares: a ChArUco board), from the labelled `corners` (board
/// order). A plain chessboard gives ≈ 0, a ChArUco board ≈ 1.
pub fn markers_in_squares(
    data: &[u8],
    width: u32,
    height: u32,
    corners: &[[f64; 2]],
    board: &BoardSpec,
) -> f64 {
    let (c, r) = (board.cols, board.rows);
    if corners.len() != c * r || c < 2 || r < 2 || data.len() != width as usize * height as usize {
        return 0.0;
    }
    let grey = |p: [f64; 2]| -> Option<f64> {
        let (i, j) = (p[0].round() as i64, p[1].round() as i64);
        (i >= 0 && j >= 0 && (i as u32) < width && (j as u32) < height)
            .then(|| f64::from(data[j as usize * width as usize + i as usize]))
    };
    // Square (i, j) spans corners (i, j)…(i+1, j+1); point (a, b) ∈ [0, 1]² bilinear.
    let at = |i: usize, j: usize, a: f64, b: f64| -> [f64; 2] {
        let p = |ii: usize, jj: usize| corners[jj * c + ii];
        let (p00, p10, p01, p11) = (p(i, j), p(i + 1, j), p(i, j + 1), p(i + 1, j + 1));
        [0, 1].map(|d| {
            (1.0 - a) * (1.0 - b) * p00[d]
                + a * (1.0 - b) * p10[d]
                + (1.0 - a) * b * p01[d]
                + a * b * p11[d]
        })
    };
    // Rim level (near the four corners, inside the square) and centre samples of each square.
    let mut squares: Vec<(usize, f64, Vec<f64>)> = vec![];
    for j in 0..r - 1 {
        for i in 0..c - 1 {
            let rim: Vec<f64> = [(0.1, 0.1), (0.9, 0.1), (0.1, 0.9), (0.9, 0.9)]
                .iter()
                .filter_map(|&(a, b)| grey(at(i, j, a, b)))
                .collect();
            let centre: Vec<f64> = (0..6)
                .flat_map(|y| (0..6).map(move |x| (0.25 + 0.1 * x as f64, 0.25 + 0.1 * y as f64)))
                .filter_map(|(a, b)| grey(at(i, j, a, b)))
                .collect();
            if rim.len() == 4 && centre.len() == 36 {
                squares.push(((i + j) % 2, rim.iter().sum::<f64>() / 4.0, centre));
            }
        }
    }
    let level = |parity: usize| {
        let v: Vec<f64> = squares
            .iter()
            .filter(|s| s.0 == parity)
            .map(|s| s.1)
            .collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let (l0, l1) = (level(0), level(1));
    let (light, lo, hi) = if l0 > l1 { (0, l1, l0) } else { (1, l0, l1) };
    if hi - lo < 20.0 {
        return 0.0;
    }
    let mid = 0.5 * (lo + hi);
    let light_squares: Vec<&(usize, f64, Vec<f64>)> =
        squares.iter().filter(|s| s.0 == light).collect();
    if light_squares.is_empty() {
        return 0.0;
    }
    let marked = light_squares
        .iter()
        .filter(|s| s.2.iter().filter(|&&g| g < mid).count() as f64 > 0.15 * s.2.len() as f64)
        .count();
    marked as f64 / light_squares.len() as f64
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

#[cfg(test)]
mod marker_tests {
    use super::*;

    /// A detector grid one corner larger than the board (OpenCV's `left12.jpg`: 55 corners
    /// for a 9×6 board) keeps the one whole board in it; a grid a whole column larger holds
    /// two boards and is refused.
    #[test]
    fn whole_board_window_drops_an_extra_corner_only_when_unambiguous() {
        let board = BoardSpec {
            cols: 9,
            rows: 6,
            square_mm: 1.0,
        };
        let full = |w: i32, h: i32| -> Vec<(i32, i32)> {
            (0..w).flat_map(|u| (0..h).map(move |v| (u, v))).collect()
        };
        let mut cells = full(9, 6);
        cells.push((9, 2));
        assert_eq!(whole_board_window(&cells, &board), Some((0, 0, 9, 6)));
        // Turned a quarter: 6 wide, 9 high, one extra above.
        let mut cells: Vec<(i32, i32)> = full(6, 9)
            .into_iter()
            .map(|(u, v)| (u + 3, v + 1))
            .collect();
        cells.push((4, 0));
        assert_eq!(whole_board_window(&cells, &board), Some((3, 1, 6, 9)));
        assert_eq!(whole_board_window(&full(10, 6), &board), None);
        assert_eq!(whole_board_window(&full(8, 6), &board), None);
    }

    /// An axis-aligned board of `cols × rows` inner corners, squares of `s` px from `(x0, y0)`,
    /// supersampled 4×4 per pixel; `marker` (largest fraction of the square) prints a
    /// black-bordered marker with a white centre in every light square.
    fn render(
        cols: usize,
        rows: usize,
        s: f64,
        x0: f64,
        y0: f64,
        marker: Option<f64>,
    ) -> (Vec<u8>, u32, u32) {
        let (w, h) = (
            (x0 * 2.0 + s * (cols + 1) as f64) as u32,
            (y0 * 2.0 + s * (rows + 1) as f64) as u32,
        );
        let value = |x: f64, y: f64| -> f64 {
            let (bx, by) = ((x - x0) / s, (y - y0) / s);
            if bx < 0.0 || by < 0.0 || bx >= (cols + 1) as f64 || by >= (rows + 1) as f64 {
                return 200.0;
            }
            let (a, b) = (bx.floor() as usize, by.floor() as usize);
            if (a + b) % 2 == 0 {
                return 30.0;
            }
            if let Some(m) = marker {
                // Markers differ from square to square (as ChArUco's do), so their edges do not
                // cancel about a corner.
                let m = m - 0.1 * ((a * 2 + b) % 3) as f64;
                let (fx, fy) = (bx.fract() - 0.5, by.fract() - 0.5);
                let half = m / 2.0;
                if fx.abs() < half && fy.abs() < half {
                    // Black border one sixth of the marker, a white cell in the middle.
                    let inner = half * 4.0 / 6.0;
                    let cell = fx.abs() < inner / 2.0 && fy.abs() < inner / 2.0;
                    return if cell { 220.0 } else { 30.0 };
                }
            }
            220.0
        };
        let mut data = vec![0u8; (w * h) as usize];
        for j in 0..h {
            for i in 0..w {
                let mut acc = 0.0;
                for sy in 0..4 {
                    for sx in 0..4 {
                        acc += value(
                            i as f64 - 0.5 + (sx as f64 + 0.5) / 4.0,
                            j as f64 - 0.5 + (sy as f64 + 0.5) / 4.0,
                        );
                    }
                }
                data[(j * w + i) as usize] = (acc / 16.0).round() as u8;
            }
        }
        (data, w, h)
    }

    /// The coarse-to-fine detector [`detect_chessboard`] tries first gives the full-image
    /// detector's corners (to 1e-9 px, before and after the sub-pixel refinement), and a board
    /// it cannot find whole is refused with the full-image detector's own error.
    #[test]
    fn coarse_to_fine_detection_gives_the_full_image_corners() {
        let board = BoardSpec {
            cols: 9,
            rows: 6,
            square_mm: 20.0,
        };
        let (data, w, h) = render(board.cols, board.rows, 41.0, 300.3, 211.8, None);
        let img = GrayImage::from_raw(w, h, data.clone()).expect("image");
        let fast = board_in(&img, &data, &coarse_to_fine(), &board).expect("coarse to fine");
        let full = board_in(&img, &data, &detect::default_chess_config(), &board).expect("full");
        assert_eq!(fast.len(), board.cols * board.rows);
        for (a, b) in fast.iter().zip(&full) {
            assert!(
                (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9,
                "{a:?} vs {b:?}"
            );
        }
        assert_eq!(detect_chessboard(&data, w, h, &board).expect("found"), fast);
        // A 10×6 declaration of the 9×6 board: neither detector finds it whole.
        let wrong = BoardSpec { cols: 10, ..board };
        let e = detect_chessboard(&data, w, h, &wrong).unwrap_err();
        let full_err = board_in(&img, &data, &detect::default_chess_config(), &wrong).unwrap_err();
        assert_eq!(e, full_err);
    }

    #[test]
    fn markers_inside_squares_are_seen_and_the_window_stays_in_the_clean_rim() {
        let board = BoardSpec {
            cols: 7,
            rows: 6,
            square_mm: 20.0,
        };
        let (s, x0, y0) = (32.0, 24.3, 19.7);
        let truth: Vec<[f64; 2]> = (0..board.rows)
            .flat_map(|j| (0..board.cols).map(move |i| (i, j)))
            .map(|(i, j)| [x0 + s * (i + 1) as f64, y0 + s * (j + 1) as f64])
            .collect();
        for (marker, want_markers) in [(None, false), (Some(0.8), true)] {
            let (data, w, h) = render(board.cols, board.rows, s, x0, y0, marker);
            let got = detect_chessboard(&data, w, h, &board).expect("board found");
            let share = markers_in_squares(&data, w, h, &got, &board);
            assert_eq!(
                share >= MARKER_SQUARES_SHARE,
                want_markers,
                "{marker:?}: share {share}"
            );
            // Board order may be the mirror image of `truth`: compare as sets.
            let worst = truth
                .iter()
                .map(|t| {
                    got.iter()
                        .map(|g| ((g[0] - t[0]).powi(2) + (g[1] - t[1]).powi(2)).sqrt())
                        .fold(f64::INFINITY, f64::min)
                })
                .fold(0.0f64, f64::max);
            assert!(worst < 0.1, "{marker:?}: worst corner error {worst:.3} px");
        }
    }
}
