//! Sub-pixel refinement of chessboard corners on the image (the gradient-orthogonality
//! estimator of Förstner / OpenCV's `cornerSubPix`): at the true corner `q`, every image
//! gradient `g_i` at pixel `p_i` near it is orthogonal to `q − p_i` (on an edge the gradient is
//! normal to the edge through `q`; in flat areas it vanishes). `q` minimises
//! `Σ w_i (g_iᵀ (q − p_i))²`, a 2×2 linear system, re-solved with the Gaussian window
//! `w_i = exp(−|p_i − q|² / r²)` re-centred on the estimate until it moves less than 1e-4 px.
//!
//! Differences from `cornerSubPix`: gradients are taken on the pixel grid itself (Scharr
//! derivative, no bilinear re-sampling of the window, so no interpolation smoothing that moves
//! with the sub-pixel phase), and the window radius follows the local square size (0.4 ×
//! the distance to the nearest grid neighbour, 3–40 px: within it only the corner's own two
//! edges) instead of a fixed 11 px, so that large
//! squares use long stretches of edge and small ones never reach the next corner.
//!
//! Pixel convention: the centre of pixel `(i, j)` is at `(i, j)` (OpenCV's), as everywhere in
//! [`super`].

/// Refine `corners` (pixels) in the 8-bit image `data` (`width × height`, row-major).
/// `radius[k]` is the window radius of corner `k` (px). A corner whose refinement does not
/// converge, leaves the image or moves farther than half its radius keeps its position and is
/// reported in the returned list of indices.
pub fn refine(
    data: &[u8],
    width: u32,
    height: u32,
    corners: &mut [[f64; 2]],
    radius: &[f64],
) -> Vec<usize> {
    let (w, h) = (width as i64, height as i64);
    let px = |x: i64, y: i64| data[(y * w + x) as usize] as f64;
    // Scharr gradient at an interior pixel (weights 3, 10, 3; /32).
    let grad = |x: i64, y: i64| -> [f64; 2] {
        let gx = 3.0 * (px(x + 1, y - 1) - px(x - 1, y - 1))
            + 10.0 * (px(x + 1, y) - px(x - 1, y))
            + 3.0 * (px(x + 1, y + 1) - px(x - 1, y + 1));
        let gy = 3.0 * (px(x - 1, y + 1) - px(x - 1, y - 1))
            + 10.0 * (px(x, y + 1) - px(x, y - 1))
            + 3.0 * (px(x + 1, y + 1) - px(x + 1, y - 1));
        [gx / 32.0, gy / 32.0]
    };
    let mut failed = vec![];
    for (k, c) in corners.iter_mut().enumerate() {
        let r = radius.get(k).copied().unwrap_or(5.0).clamp(2.0, 40.0);
        let ri = r.ceil() as i64;
        let start = *c;
        let mut q = *c;
        let mut ok = false;
        for _ in 0..50 {
            let (cx, cy) = (q[0].round() as i64, q[1].round() as i64);
            let (mut a, mut b, mut d, mut e0, mut e1) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for y in (cy - ri).max(1)..=(cy + ri).min(h - 2) {
                for x in (cx - ri).max(1)..=(cx + ri).min(w - 2) {
                    let (dx, dy) = (x as f64 - q[0], y as f64 - q[1]);
                    let d2 = dx * dx + dy * dy;
                    if d2 > r * r {
                        continue;
                    }
                    let wt = (-d2 / (r * r)).exp();
                    let [gx, gy] = grad(x, y);
                    let (gxx, gxy, gyy) = (wt * gx * gx, wt * gx * gy, wt * gy * gy);
                    a += gxx;
                    b += gxy;
                    d += gyy;
                    e0 += gxx * x as f64 + gxy * y as f64;
                    e1 += gxy * x as f64 + gyy * y as f64;
                }
            }
            let det = a * d - b * b;
            if !(det.is_finite() && det > 1e-9 * (a + d).powi(2).max(1e-300)) {
                break;
            }
            let n = [(d * e0 - b * e1) / det, (a * e1 - b * e0) / det];
            let step = ((n[0] - q[0]).powi(2) + (n[1] - q[1]).powi(2)).sqrt();
            q = n;
            if !(q[0].is_finite() && q[1].is_finite()) {
                break;
            }
            if step < 1e-4 {
                ok = true;
                break;
            }
        }
        let moved = ((q[0] - start[0]).powi(2) + (q[1] - start[1]).powi(2)).sqrt();
        let inside = q[0] >= 0.0 && q[1] >= 0.0 && q[0] <= (w - 1) as f64 && q[1] <= (h - 1) as f64;
        if ok && inside && moved <= 0.5 * r {
            *c = q;
        } else {
            failed.push(k);
        }
    }
    failed
}

/// Window radius of every corner of a `cols × rows` grid in board order: 0.4 × the distance
/// to its nearest grid neighbour, within 3–40 px.
pub fn grid_radius(corners: &[[f64; 2]], cols: usize, rows: usize) -> Vec<f64> {
    let dist = |a: [f64; 2], b: [f64; 2]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
    (0..cols * rows)
        .map(|k| {
            let (i, j) = (k % cols, k / cols);
            let mut m = f64::INFINITY;
            let mut nb = |ii: usize, jj: usize| {
                m = m.min(dist(corners[k], corners[jj * cols + ii]));
            };
            if i > 0 {
                nb(i - 1, j);
            }
            if i + 1 < cols {
                nb(i + 1, j);
            }
            if j > 0 {
                nb(i, j - 1);
            }
            if j + 1 < rows {
                nb(i, j + 1);
            }
            if m.is_finite() {
                (m / 2.5).clamp(3.0, 40.0)
            } else {
                5.0
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A blurred corner of two edges through `(u0, v0)` at angles `a1`, `a2` (rad), rendered by
    /// 8×8 supersampling of each pixel's area (pixel centre at integer coordinates), then
    /// box-blurred once; dark/bright 30/225.
    fn corner_image(w: u32, h: u32, u0: f64, v0: f64, a1: f64, a2: f64) -> Vec<u8> {
        let (n1, n2) = ((-a1.sin(), a1.cos()), (-a2.sin(), a2.cos()));
        let mut f = vec![0.0f64; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let mut s = 0.0;
                for sy in 0..8 {
                    for sx in 0..8 {
                        let (px, py) = (
                            x as f64 - 0.5 + (sx as f64 + 0.5) / 8.0 - u0,
                            y as f64 - 0.5 + (sy as f64 + 0.5) / 8.0 - v0,
                        );
                        let s1 = n1.0 * px + n1.1 * py >= 0.0;
                        let s2 = n2.0 * px + n2.1 * py >= 0.0;
                        s += if s1 == s2 { 225.0 } else { 30.0 };
                    }
                }
                f[(y * w + x) as usize] = s / 64.0;
            }
        }
        let g = f.clone();
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let mut s = 0.0;
                for dy in -1i64..=1 {
                    for dx in -1i64..=1 {
                        s += g[((y as i64 + dy) as u32 * w + (x as i64 + dx) as u32) as usize];
                    }
                }
                f[(y * w + x) as usize] = s / 9.0;
            }
        }
        f.iter().map(|v| v.round() as u8).collect()
    }

    #[test]
    fn refines_a_skewed_corner_to_its_true_position() {
        for (u0, v0, a1, a2) in [
            (20.3, 19.71, 0.2, 1.9),
            (21.77, 20.12, -0.4, 0.9),
            (19.5, 20.5, 0.0, std::f64::consts::FRAC_PI_2),
        ] {
            let img = corner_image(41, 41, u0, v0, a1, a2);
            let mut c = [[u0.round() + 0.4, v0.round() - 0.4]];
            let failed = refine(&img, 41, 41, &mut c, &[8.0]);
            assert!(failed.is_empty());
            let e = ((c[0][0] - u0).powi(2) + (c[0][1] - v0).powi(2)).sqrt();
            assert!(e < 0.02, "({u0}, {v0}) -> {:?}: {e} px", c[0]);
        }
    }

    #[test]
    fn a_flat_patch_is_reported_not_moved() {
        let img = vec![128u8; 30 * 30];
        let mut c = [[15.2, 14.8]];
        assert_eq!(refine(&img, 30, 30, &mut c, &[5.0]), vec![0]);
        assert_eq!(c[0], [15.2, 14.8]);
    }

    #[test]
    fn radius_is_0_4_of_the_nearest_neighbour() {
        let c: Vec<[f64; 2]> = (0..6)
            .map(|k| [(k % 3) as f64 * 30.0, (k / 3) as f64 * 45.0])
            .collect();
        let r = grid_radius(&c, 3, 2);
        assert!(r.iter().all(|r| (r - 12.0).abs() < 1e-12), "{r:?}");
    }
}
