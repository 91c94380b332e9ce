//! Sensor physics: tracker volume, laser ray casting, chessboard (and ChArUco) rendering.

use crate::scenario::{CameraConfig, ChessboardConfig, SceneConfig, VolumeKind};
use nalgebra::{Isometry3, Point3, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;

/// Frustum parameters of a measurement volume along the tracker's −z axis:
/// (near depth mm, far depth mm, tan of half-angle in x, in y).
pub fn volume_frustum(v: VolumeKind) -> Option<(f64, f64, f64, f64)> {
    match v {
        VolumeKind::PolarisPyramid => Some((950.0, 2400.0, 0.33, 0.28)),
        VolumeKind::PolarisExtended => Some((950.0, 3000.0, 0.33, 0.28)),
        VolumeKind::Optotrak => Some((1000.0, 6000.0, 0.55, 0.45)),
        VolumeKind::Unbounded => None,
    }
}

/// Whether a point in the tracker frame (mm) lies inside the volume.
pub fn in_volume(v: VolumeKind, p: &Point3<f64>) -> bool {
    match volume_frustum(v) {
        None => true,
        Some((near, far, tx, ty)) => {
            let depth = -p.z;
            depth >= near && depth <= far && p.x.abs() <= depth * tx && p.y.abs() <= depth * ty
        }
    }
}

/// Distance from `c` to the segment `a`–`b`.
pub fn segment_distance(a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>) -> f64 {
    let ab = b - a;
    let l2 = ab.norm_squared();
    let s = if l2 > 0.0 {
        ((c - a).dot(&ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a + ab * s - c).norm()
}

/// A ray hit: distance along the ray (mm), unit surface normal (facing the ray), surface label.
#[derive(Debug, Clone, PartialEq)]
pub struct Hit {
    /// Distance from the ray origin (mm).
    pub distance_mm: f64,
    /// Unit normal of the surface at the hit, facing the incoming ray.
    pub normal: Vector3<f64>,
    /// What was hit (`P1`, `plate`, `block`, …).
    pub surface: String,
}

/// Cast a ray (base frame, `dir` unit) into the scene; nearest hit.
pub fn cast_ray(scene: &SceneConfig, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
    let mut best: Option<Hit> = None;
    let mut consider = |d: f64, n: Vector3<f64>, name: &str| {
        if d > 1e-9 && best.as_ref().is_none_or(|b| d < b.distance_mm) {
            let n = if n.dot(dir) > 0.0 { -n } else { n };
            best = Some(Hit {
                distance_mm: d,
                normal: n,
                surface: name.to_string(),
            });
        }
    };
    for p in &scene.planes {
        let n = Vector3::from(p.normal).normalize();
        let denom = dir.dot(&n);
        if denom.abs() > 1e-12 {
            let d = (Point3::from(p.through_mm) - origin).dot(&n) / denom;
            consider(d, n, &p.name);
        }
    }
    if let Some(pl) = &scene.plate {
        let t = pl.placement.isometry();
        let (o, u) = (t.inverse() * origin, t.inverse_transform_vector(dir));
        if u.z.abs() > 1e-12 {
            let d = -o.z / u.z;
            let h = o + u * d;
            if h.x.abs() <= pl.size_mm[0] / 2.0 && h.y.abs() <= pl.size_mm[1] / 2.0 {
                consider(d, t.rotation * Vector3::z(), "plate");
            }
        }
    }
    if let Some(b) = &scene.block {
        let t = b.placement.isometry();
        let (o, u) = (t.inverse() * origin, t.inverse_transform_vector(dir));
        let half = Vector3::from(b.size_mm) / 2.0;
        // Slab method: entry face.
        let (mut tmin, mut tmax, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0usize);
        let mut ok = true;
        for k in 0..3 {
            if u[k].abs() < 1e-12 {
                if o[k].abs() > half[k] {
                    ok = false;
                }
                continue;
            }
            let (t1, t2) = ((-half[k] - o[k]) / u[k], (half[k] - o[k]) / u[k]);
            let (lo, hi) = (t1.min(t2), t1.max(t2));
            if lo > tmin {
                tmin = lo;
                axis = k;
            }
            tmax = tmax.min(hi);
        }
        if ok && tmin <= tmax && tmin > 0.0 {
            let mut n = Vector3::zeros();
            n[axis] = 1.0;
            consider(tmin, t.rotation * n, "block");
        }
    }
    best
}

/// Pixel to a unit-depth ray in the camera frame (undistorting the radial model iteratively).
pub fn pixel_ray(cam: &CameraConfig, u: f64, v: f64) -> Vector3<f64> {
    let (xd, yd) = ((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy);
    let (mut x, mut y) = (xd, yd);
    for _ in 0..8 {
        let r2 = x * x + y * y;
        let f = 1.0 + cam.k1 * r2 + cam.k2 * r2 * r2;
        x = xd / f;
        y = yd / f;
    }
    Vector3::new(x, y, 1.0)
}

/// Project a point in the camera frame to pixels (pinhole + radial distortion).
pub fn project(cam: &CameraConfig, p: &Point3<f64>) -> Option<(f64, f64)> {
    if p.z <= 1e-9 {
        return None;
    }
    let (x, y) = (p.x / p.z, p.y / p.z);
    let r2 = x * x + y * y;
    let f = 1.0 + cam.k1 * r2 + cam.k2 * r2 * r2;
    Some((cam.fx * x * f + cam.cx, cam.fy * y * f + cam.cy))
}

/// Grey levels of the board: dark squares, bright squares and the white margin, and the
/// background around the board.
const DARK: f64 = 30.0;
const BRIGHT: f64 = 225.0;
const BACKGROUND: f64 = 90.0;

/// Mean over `[x - h, x + h]` of the indicator of `[lo, hi]`.
fn box_indicator(x: f64, h: f64, lo: f64, hi: f64) -> f64 {
    ((x + h).min(hi) - (x - h).max(lo)).max(0.0) / (2.0 * h)
}

/// ∫₀ᵗ P(s) ds for the square wave P = +1 on even squares, −1 on odd ones (a triangle wave),
/// with P restricted to `[0, len]`.
fn square_wave_integral(t: f64, sq: f64, len: f64) -> f64 {
    let t = t.clamp(0.0, len);
    let k = (t / sq).floor();
    let f = t - k * sq;
    if (k as i64) % 2 == 0 {
        f
    } else {
        sq - f
    }
}

/// Mean grey of the board (and its surroundings) over the board-frame box
/// `[x ± hx] × [y ± hy]` (mm), in closed form: the pattern is
/// `BACKGROUND + (BRIGHT − BACKGROUND)·1_margin − ½(BRIGHT − DARK)·1_squares·(1 + Px·Py)`
/// and every term is a product of a function of x and one of y, so its box mean is the product
/// of 1-D means. No sampling, so edges and corners land exactly where the geometry puts them.
fn board_grey_box(b: &ChessboardConfig, x: f64, y: f64, hx: f64, hy: f64) -> f64 {
    let (w, h) = (b.cols as f64 * b.square_mm, b.rows as f64 * b.square_mm);
    let m = b.square_mm;
    let (hx, hy) = (hx.max(1e-9), hy.max(1e-9));
    let margin = box_indicator(x, hx, -m, w + m) * box_indicator(y, hy, -m, h + m);
    let inside = box_indicator(x, hx, 0.0, w) * box_indicator(y, hy, 0.0, h);
    let px = (square_wave_integral(x + hx, b.square_mm, w)
        - square_wave_integral(x - hx, b.square_mm, w))
        / (2.0 * hx);
    let py = (square_wave_integral(y + hy, b.square_mm, h)
        - square_wave_integral(y - hy, b.square_mm, h))
        / (2.0 * hy);
    let half = 0.5 * (BRIGHT - DARK);
    BACKGROUND + (BRIGHT - BACKGROUND) * margin - half * (inside + px * py)
}

/// Render an 8-bit image of the chessboard seen from `cam_in_base`, then Gaussian blur
/// `blur_px` and grey noise `noise_grey`. Each pixel is the exact mean of the pattern over the
/// pixel's footprint on the board (the footprint taken as the board-aligned box spanned by the
/// pixel's projection), so corner positions carry no sampling bias.
pub fn render<R: Rng>(
    cam: &CameraConfig,
    cam_in_base: &Isometry3<f64>,
    board: Option<&ChessboardConfig>,
    rng: &mut R,
) -> Vec<u8> {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut img = vec![BACKGROUND; w * h];
    if let Some(b) = board {
        // ChArUco markers (validated with the scenario; an invalid block renders none).
        let markers = b
            .charuco
            .as_ref()
            .and_then(|m| super::charuco::Pattern::new(b.cols, b.rows, b.square_mm, m).ok());
        let board_from_cam = b.placement.isometry().inverse() * cam_in_base;
        let o = board_from_cam * Point3::origin();
        // Board-plane point hit by the ray through image point (u, v).
        let hit = |u: f64, v: f64| -> Option<(f64, f64)> {
            let ray = board_from_cam * pixel_ray(cam, u, v);
            super::camera_board::hit_board(b, &o, &ray)
        };
        // Hits at the pixel corners (u ± ½, v ± ½): (w+1)·(h+1) rays.
        let corners: Vec<Option<(f64, f64)>> = (0..=h)
            .flat_map(|j| (0..=w).map(move |i| (i, j)))
            .map(|(i, j)| hit(i as f64 - 0.5, j as f64 - 0.5))
            .collect();
        let at = |i: usize, j: usize| corners[j * (w + 1) + i];
        for v in 0..h {
            for u in 0..w {
                let (Some(c00), Some(c10), Some(c01), Some(c11)) =
                    (at(u, v), at(u + 1, v), at(u, v + 1), at(u + 1, v + 1))
                else {
                    continue;
                };
                let xs = [c00.0, c10.0, c01.0, c11.0];
                let ys = [c00.1, c10.1, c01.1, c11.1];
                let (x, y) = (xs.iter().sum::<f64>() / 4.0, ys.iter().sum::<f64>() / 4.0);
                // Half-extents of the footprint parallelogram along the board axes.
                let hx = 0.25
                    * ((c10.0 - c00.0 + c11.0 - c01.0).abs()
                        + (c01.0 - c00.0 + c11.0 - c10.0).abs());
                let hy = 0.25
                    * ((c10.1 - c00.1 + c11.1 - c01.1).abs()
                        + (c01.1 - c00.1 + c11.1 - c10.1).abs());
                img[v * w + u] = board_grey_box(b, x, y, hx, hy)
                    + markers
                        .as_ref()
                        .map_or(0.0, |m| (DARK - BRIGHT) * m.black_fraction(x, y, hx, hy));
            }
        }
    }
    if cam.blur_px > 0.0 {
        img = gaussian_blur(&img, w, h, cam.blur_px);
    }
    img.iter()
        .map(|&g| {
            let n: f64 = if cam.noise_grey > 0.0 {
                rng.sample::<f64, _>(StandardNormal) * cam.noise_grey
            } else {
                0.0
            };
            (g + n).round().clamp(0.0, 255.0) as u8
        })
        .collect()
}

pub(crate) fn gaussian_blur(img: &[f64], w: usize, h: usize, sigma: f64) -> Vec<f64> {
    let r = (3.0 * sigma).ceil() as i64;
    let k: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let ks: f64 = k.iter().sum();
    let pass = |src: &[f64], horiz: bool| -> Vec<f64> {
        let mut out = vec![0.0; w * h];
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                let mut acc = 0.0;
                for (t, kv) in k.iter().enumerate() {
                    let o = t as i64 - r;
                    let (xx, yy) = if horiz {
                        ((x + o).clamp(0, w as i64 - 1), y)
                    } else {
                        (x, (y + o).clamp(0, h as i64 - 1))
                    };
                    acc += kv * src[(yy as usize) * w + xx as usize];
                }
                out[(y as usize) * w + x as usize] = acc / ks;
            }
        }
        out
    };
    let tmp = pass(img, true);
    pass(&tmp, false)
}
