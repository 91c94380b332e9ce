//! The camera's calibration board as a physical object: its (possibly bowed) surface, where a
//! camera ray meets it, and the TRUE pixel of each inner corner (tests and benchmarks compare
//! detectors and calibrations against these; nothing reaches a wire).
use nalgebra::{Isometry3, Point3, Vector3};

use crate::scenario::{CameraConfig, ChessboardConfig};

/// Height (mm) of the board surface above its plane at board point `(x, y)`.
pub fn sag(b: &ChessboardConfig, x: f64, _y: f64) -> f64 {
    if b.bend_mm == 0.0 {
        return 0.0;
    }
    let w = b.cols as f64 * b.square_mm;
    let u = 2.0 * x / w - 1.0;
    b.bend_mm * (1.0 - u * u)
}

/// Board-plane coordinates `(x, y)` where the ray `o + s·d` (board frame, `s > 0`) meets the
/// board's surface (fixed-point on the sag; exact for a flat board).
pub fn hit_board(b: &ChessboardConfig, o: &Point3<f64>, d: &Vector3<f64>) -> Option<(f64, f64)> {
    if d.z.abs() <= 1e-12 {
        return None;
    }
    let mut z = 0.0;
    let mut out = None;
    for _ in 0..if b.bend_mm == 0.0 { 1 } else { 6 } {
        let s = (z - o.z) / d.z;
        if s <= 0.0 {
            return None;
        }
        let (x, y) = (o.x + d.x * s, o.y + d.y * s);
        out = Some((x, y));
        z = sag(b, x, y);
    }
    out
}

/// The board point (mm, board frame) of inner corner `(i, j)`, on the true surface.
pub fn corner_point(b: &ChessboardConfig, i: u32, j: u32) -> Point3<f64> {
    let (x, y) = ((i + 1) as f64 * b.square_mm, (j + 1) as f64 * b.square_mm);
    Point3::new(x, y, sag(b, x, y))
}

/// TRUE pixels of the inner corners, row by row (`j·(cols−1) + i`), seen by camera `cam` at
/// `cam_in_base`; `None` behind the camera.
pub fn true_corners(
    cam: &CameraConfig,
    cam_in_base: &Isometry3<f64>,
    b: &ChessboardConfig,
) -> Vec<Option<[f64; 2]>> {
    let cam_from_board = cam_in_base.inverse() * b.placement.isometry();
    let mut out = vec![];
    for j in 0..b.rows.saturating_sub(1) {
        for i in 0..b.cols.saturating_sub(1) {
            let p = cam_from_board * corner_point(b, i, j);
            out.push(super::sensors::project(cam, &p).map(|(u, v)| [u, v]));
        }
    }
    out
}
