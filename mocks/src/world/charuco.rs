//! The printed ChArUco board: which squares carry which ArUco marker and which of a marker's
//! cells are black, from the real dictionary tables (OpenCV's codes, as shipped by
//! `calib-targets-aruco`; checked against `cv2.aruco.generateImageMarker`). The renderer
//! ([`super::sensors::render`]) adds the markers to the chessboard's closed-form box mean with
//! [`Pattern::black_fraction`], so marker edges land exactly where the geometry puts them, as
//! the chessboard's do.
//!
//! Layout (OpenCV ≥ 4.6, not the legacy one): square `(a, b)` (column, row) is dark iff
//! `a + b` is even; markers sit on the other squares, numbered row by row from 0 (marker 0 in
//! square `(1, 0)`), each centred in its square with a one-cell black border; bit `(bx, by)`
//! of a marker (column, row of its inner `bits × bits` grid) is bit `by·bits + bx` of its
//! code, 1 = black. Board coordinates: `x = a·square + …` along the columns, `y` along the
//! rows, as printed (the board frame's −z side reads the markers the right way round).
use calib_targets_aruco::builtins::{builtin_dictionary, BUILTIN_DICTIONARY_NAMES};

use crate::scenario::CharucoConfig;

/// A ChArUco board's marker cells.
#[derive(Debug, Clone)]
pub struct Pattern {
    cols: u32,
    rows: u32,
    square: f64,
    /// Offset of a marker inside its square: `(square − marker) / 2`.
    offset: f64,
    marker: f64,
    /// Cells per marker side: dictionary bits + 2 (border).
    n: usize,
    /// Per square `b·cols + a`: the marker's id and black cells (`n × n`, row-major).
    squares: Vec<Option<(u32, Vec<bool>)>>,
}

impl Pattern {
    /// The markers of a `cols × rows`-square board (errors name the bad value).
    pub fn new(cols: u32, rows: u32, square_mm: f64, cfg: &CharucoConfig) -> Result<Self, String> {
        let dict = builtin_dictionary(&cfg.dictionary).ok_or_else(|| {
            format!(
                "unknown dictionary {:?} (known: {})",
                cfg.dictionary,
                BUILTIN_DICTIONARY_NAMES.join(", ")
            )
        })?;
        if !(cfg.marker_mm.is_finite() && cfg.marker_mm > 0.0 && cfg.marker_mm < square_mm) {
            return Err(format!(
                "marker_mm = {} must be positive and less than square_mm = {square_mm}",
                cfg.marker_mm
            ));
        }
        if cols < 2 || rows < 2 {
            return Err(format!(
                "a ChArUco board needs ≥ 2×2 squares, got {cols}×{rows}"
            ));
        }
        let bits = dict.marker_size();
        let n = bits + 2;
        let mut squares = vec![None; (cols * rows) as usize];
        let mut id = 0u32;
        for b in 0..rows {
            for a in 0..cols {
                if (a + b) % 2 == 0 {
                    continue;
                }
                let code = *dict.codes().get(id as usize).ok_or_else(|| {
                    format!(
                        "the board has {} markers, dictionary {} only {}",
                        (cols * rows) / 2,
                        cfg.dictionary,
                        dict.codes().len()
                    )
                })?;
                let mut black = vec![true; n * n];
                for by in 0..bits {
                    for bx in 0..bits {
                        black[(by + 1) * n + bx + 1] = (code >> (by * bits + bx)) & 1 == 1;
                    }
                }
                squares[(b * cols + a) as usize] = Some((id, black));
                id += 1;
            }
        }
        Ok(Pattern {
            cols,
            rows,
            square: square_mm,
            offset: 0.5 * (square_mm - cfg.marker_mm),
            marker: cfg.marker_mm,
            n,
            squares,
        })
    }

    /// Number of markers on the board.
    pub fn marker_count(&self) -> usize {
        self.squares.iter().flatten().count()
    }

    /// The marker id in square `(a, b)` (column, row), if any.
    pub fn marker_at(&self, a: u32, b: u32) -> Option<u32> {
        if a >= self.cols || b >= self.rows {
            return None;
        }
        self.squares[(b * self.cols + a) as usize]
            .as_ref()
            .map(|(id, _)| *id)
    }

    /// Whether board point `(x, y)` (mm) is on a black marker cell.
    pub fn is_black(&self, x: f64, y: f64) -> bool {
        self.black_fraction(x, y, 1e-9, 1e-9) > 0.5
    }

    /// Mean over the board box `[x ± hx] × [y ± hy]` (mm) of the indicator of the black
    /// marker cells (0 – 1), in closed form: a sum of products of 1-D box overlaps.
    pub fn black_fraction(&self, x: f64, y: f64, hx: f64, hy: f64) -> f64 {
        let (hx, hy) = (hx.max(1e-9), hy.max(1e-9));
        let s = self.square;
        let range = |lo: f64, hi: f64, n: u32| -> Option<(u32, u32)> {
            let (a0, a1) = ((lo / s).floor(), (hi / s).floor());
            if a1 < 0.0 || a0 >= n as f64 {
                return None;
            }
            Some((a0.max(0.0) as u32, a1.min(n as f64 - 1.0) as u32))
        };
        let (Some((a0, a1)), Some((b0, b1))) = (
            range(x - hx, x + hx, self.cols),
            range(y - hy, y + hy, self.rows),
        ) else {
            return 0.0;
        };
        let c = self.marker / self.n as f64;
        let n = self.n;
        // Cells of one marker overlapping [lo, hi] along an axis, with their 1-D overlap.
        let cells = |lo: f64, hi: f64, origin: f64, out: &mut Vec<(usize, f64)>| {
            out.clear();
            let (i0, i1) = (((lo - origin) / c).floor(), ((hi - origin) / c).floor());
            if i1 < 0.0 || i0 >= n as f64 {
                return;
            }
            for i in (i0.max(0.0) as usize)..=(i1.min(n as f64 - 1.0) as usize) {
                let (e0, e1) = (origin + i as f64 * c, origin + (i + 1) as f64 * c);
                let w = hi.min(e1) - lo.max(e0);
                if w > 0.0 {
                    out.push((i, w));
                }
            }
        };
        let (mut xs, mut ys) = (Vec::new(), Vec::new());
        let mut area = 0.0;
        for b in b0..=b1 {
            for a in a0..=a1 {
                let Some((_, black)) = &self.squares[(b * self.cols + a) as usize] else {
                    continue;
                };
                cells(x - hx, x + hx, a as f64 * s + self.offset, &mut xs);
                if xs.is_empty() {
                    continue;
                }
                cells(y - hy, y + hy, b as f64 * s + self.offset, &mut ys);
                for &(j, wy) in &ys {
                    for &(i, wx) in &xs {
                        if black[j * n + i] {
                            area += wx * wy;
                        }
                    }
                }
            }
        }
        area / (4.0 * hx * hy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(dict: &str, marker: f64) -> CharucoConfig {
        CharucoConfig {
            marker_mm: marker,
            dictionary: dict.into(),
        }
    }

    #[test]
    fn layout_and_bits_are_opencvs() {
        let p = Pattern::new(9, 6, 30.0, &cfg("DICT_4X4_50", 22.0)).unwrap();
        assert_eq!(p.marker_count(), 27);
        assert_eq!(p.marker_at(0, 0), None);
        assert_eq!(p.marker_at(1, 0), Some(0));
        assert_eq!(p.marker_at(0, 1), Some(4));
        assert_eq!(p.marker_at(8, 5), Some(26));
        assert_eq!(p.marker_at(7, 5), None);
        // Marker 0 of DICT_4X4_50 as cv2.aruco.generateImageMarker draws it (1 = black):
        // rows 0100 / 1010 / 1100 / 1101.
        let want = [[0, 1, 0, 0], [1, 0, 1, 0], [1, 1, 0, 0], [1, 1, 0, 1]];
        let c = 22.0 / 6.0;
        let (x0, y0) = (30.0 + 4.0, 4.0);
        for (by, row) in want.iter().enumerate() {
            for (bx, &w) in row.iter().enumerate() {
                let (x, y) = (x0 + (bx as f64 + 1.5) * c, y0 + (by as f64 + 1.5) * c);
                assert_eq!(p.is_black(x, y), w == 1, "bit ({bx}, {by})");
            }
        }
        // Border ring black, the square's margin white.
        assert!(p.is_black(x0 + 0.5 * c, y0 + 2.5 * c));
        assert!(!p.is_black(30.0 + 1.0, 1.0));
    }

    #[test]
    fn box_mean_is_the_covered_area() {
        let p = Pattern::new(3, 2, 30.0, &cfg("DICT_4X4_50", 24.0)).unwrap();
        // The whole marker 0 (square (1, 0)): border ring 20 cells + its black bits.
        let bits = 6 * 6 - 16
            + (0..16)
                .filter(|k| (builtin_dictionary("DICT_4X4_50").unwrap().codes()[0] >> k) & 1 == 1)
                .count();
        let f = p.black_fraction(45.0, 15.0, 12.0, 12.0);
        assert!((f - bits as f64 / 36.0).abs() < 1e-12, "{f}");
        // A box half on the margin, half on the border ring.
        let f = p.black_fraction(33.0, 15.0, 1.0, 1.0);
        assert!((f - 0.5).abs() < 1e-12, "{f}");
        assert_eq!(p.black_fraction(15.0, 15.0, 5.0, 5.0), 0.0);
    }

    #[test]
    fn a_scenario_with_a_bad_charuco_block_is_refused() {
        let text = include_str!("../../scenarios/ur5e-camera-charuco.toml");
        let sc = crate::Scenario::from_toml(text).unwrap();
        assert_eq!(
            sc.scene.chessboard.unwrap().charuco.unwrap().dictionary,
            "DICT_4X4_50"
        );
        for (from, to, want) in [
            (
                "\"DICT_4X4_50\"",
                "\"DICT_4X4_49\"",
                "unknown dictionary \"DICT_4X4_49\"",
            ),
            (
                "marker_mm = 22.0",
                "marker_mm = 31.0",
                "less than square_mm",
            ),
        ] {
            let e = crate::Scenario::from_toml(&text.replace(from, to))
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("scene.chessboard.charuco") && e.contains(want),
                "{e}"
            );
        }
    }

    #[test]
    fn bad_boards_are_refused_with_the_reason() {
        let e = Pattern::new(9, 6, 30.0, &cfg("DICT_4X4_9", 22.0)).unwrap_err();
        assert!(
            e.contains("unknown dictionary") && e.contains("DICT_4X4_50"),
            "{e}"
        );
        let e = Pattern::new(9, 6, 30.0, &cfg("DICT_4X4_50", 30.0)).unwrap_err();
        assert!(e.contains("less than square_mm"), "{e}");
        let e = Pattern::new(12, 10, 30.0, &cfg("DICT_4X4_50", 22.0)).unwrap_err();
        assert!(e.contains("60 markers") && e.contains("only 50"), "{e}");
    }
}
