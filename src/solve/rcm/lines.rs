//! The instrument shaft's two silhouette lines in an endoscope image: what
//! `shaft_lines` holds, found from the pixels.
//!
//! 1. Edge points: Sobel gradient, non-maximum suppression along the gradient, sub-pixel
//!    position by a parabola through the gradient magnitude across the edge; each point is then
//!    undistorted with the header's OpenCV `[k1, k2, p1, p2, k3]` (lines are straight only in
//!    the undistorted image), its normal carried along.
//! 2. Straight edges: a Hough transform voted by each point's own gradient direction gives
//!    candidates; each is refitted by weighted total least squares on the points within a
//!    shrinking band (3 → 1.5 → 1 px, normal within 8°), split into runs (gaps > 8 px) and
//!    runs shorter than 20 px dropped, so crossing texture and curved edges fall away.
//! 3. The shaft: the longest straight edge and the edges nearly parallel to it (within 12°)
//!    with a comparable length that overlap it along its direction form one family (the two
//!    silhouettes, the edges of the specular highlight and of the jaw inside them); its two
//!    outermost members are the silhouettes.
//!
//! Each line carries its quality: points, RMS distance of its points (px), covered length (px)
//! and the 1-σ of its end points, `2·rms/√n` (px). A view is refused, with the reason, when no
//! such pair exists, a line is not straight (RMS above the limit), too short, or the two lines
//! are too close or cross within the view. Units: pixels of the undistorted image.
use crate::dataset::endoscope::EndoscopeCamera;
use crate::solve::camera::geom::{project, unproject, Intrinsics};

/// Detector settings.
#[derive(Debug, Clone, Copy)]
pub struct LineOptions {
    /// Smallest gradient magnitude of an edge point (grey levels per pixel).
    pub min_gradient: f64,
    /// Smallest covered length of a silhouette (px).
    pub min_length_px: f64,
    /// Largest RMS distance of a silhouette's points from its line (px).
    pub max_rms_px: f64,
    /// Smallest distance between the two silhouettes (px).
    pub min_separation_px: f64,
    /// The shaft comes into the view from outside it: both silhouettes must end within this
    /// distance of the image border (px, in the image as taken).
    pub border_px: f64,
}

impl Default for LineOptions {
    fn default() -> Self {
        LineOptions {
            min_gradient: 4.0,
            min_length_px: 60.0,
            max_rms_px: 0.8,
            min_separation_px: 10.0,
            border_px: 30.0,
        }
    }
}

/// One fitted straight edge.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FittedLine {
    /// Segment `[u1, v1, u2, v2]` (undistorted px): the line between its extreme points.
    pub seg: [f64; 4],
    /// Edge points on it.
    pub n_points: usize,
    /// RMS distance of the points from the line (px).
    pub rms_px: f64,
    /// Length covered by runs of points (px).
    pub length_px: f64,
    /// Longest run of points without a gap over 8 px (px).
    pub run_px: f64,
    /// 1-σ of the end points across the line (px): `2·rms/√n`.
    pub sigma_px: f64,
    /// Mean gradient magnitude of its points (grey levels per px).
    pub contrast: f64,
    /// Which side is brighter: `+1` where `a u + b v + c > 0`, else `−1` (majority of points).
    pub polarity: f64,
    /// Unit normal `(a, b)` and offset `c` of `a u + b v + c = 0`.
    #[serde(skip)]
    pub abc: [f64; 3],
}

/// The shaft's two silhouette lines and the detection's quality.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ShaftLines {
    /// The two silhouettes.
    pub lines: [FittedLine; 2],
    /// Straight-edge candidates found in the image.
    pub candidates: usize,
    /// Edge points in the image.
    pub edge_points: usize,
}

impl ShaftLines {
    /// As a record's `shaft_lines`.
    pub fn segs(&self) -> [[f64; 4]; 2] {
        [self.lines[0].seg, self.lines[1].seg]
    }
    /// The detection's quality figure: the larger end-point 1-σ of the two lines (px).
    pub fn sigma_px(&self) -> f64 {
        self.lines[0].sigma_px.max(self.lines[1].sigma_px)
    }
}

#[derive(Debug, Clone, Copy)]
struct Edge {
    x: f64,
    y: f64,
    /// Unit normal (dark → bright).
    nx: f64,
    ny: f64,
    mag: f64,
}

fn intrinsics(cam: &EndoscopeCamera) -> Intrinsics {
    Intrinsics {
        fx: cam.fx,
        fy: cam.fy,
        cx: cam.cx,
        cy: cam.cy,
        dist: cam.dist,
    }
}

/// Undistorted pixel of a distorted one.
fn undistort(k: &Intrinsics, u: f64, v: f64) -> (f64, f64) {
    if k.dist.iter().all(|d| *d == 0.0) {
        return (u, v);
    }
    let r = unproject(k, u, v);
    (k.fx * r.x + k.cx, k.fy * r.y + k.cy)
}

/// Sub-pixel edge points (undistorted) of an 8-bit image.
fn edge_points(img: &[u8], w: usize, h: usize, k: &Intrinsics, min_grad: f64) -> Vec<Edge> {
    let g = |x: usize, y: usize| img[y * w + x] as f64;
    let mut gx = vec![0.0f64; w * h];
    let mut gy = vec![0.0f64; w * h];
    let mut mag = vec![0.0f64; w * h];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let sx = (g(x + 1, y - 1) + 2.0 * g(x + 1, y) + g(x + 1, y + 1))
                - (g(x - 1, y - 1) + 2.0 * g(x - 1, y) + g(x - 1, y + 1));
            let sy = (g(x - 1, y + 1) + 2.0 * g(x, y + 1) + g(x + 1, y + 1))
                - (g(x - 1, y - 1) + 2.0 * g(x, y - 1) + g(x + 1, y - 1));
            let i = y * w + x;
            gx[i] = sx / 8.0;
            gy[i] = sy / 8.0;
            mag[i] = (gx[i] * gx[i] + gy[i] * gy[i]).sqrt();
        }
    }
    let bilinear = |x: f64, y: f64| -> f64 {
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (i, j) = (x0 as usize, y0 as usize);
        if x0 < 0.0 || y0 < 0.0 || i + 1 >= w || j + 1 >= h {
            return 0.0;
        }
        let m = |a: usize, b: usize| mag[b * w + a];
        m(i, j) * (1.0 - fx) * (1.0 - fy)
            + m(i + 1, j) * fx * (1.0 - fy)
            + m(i, j + 1) * (1.0 - fx) * fy
            + m(i + 1, j + 1) * fx * fy
    };
    let mut out = Vec::new();
    for y in 2..h - 2 {
        for x in 2..w - 2 {
            let i = y * w + x;
            let m0 = mag[i];
            if m0 < min_grad {
                continue;
            }
            let (nx, ny) = (gx[i] / m0, gy[i] / m0);
            let (xf, yf) = (x as f64, y as f64);
            let mp = bilinear(xf + nx, yf + ny);
            let mm = bilinear(xf - nx, yf - ny);
            if !(m0 > mp && m0 >= mm) {
                continue;
            }
            let den = mm - 2.0 * m0 + mp;
            let d = if den < 0.0 {
                (0.5 * (mm - mp) / den).clamp(-0.5, 0.5)
            } else {
                0.0
            };
            let (ex, ey) = (xf + d * nx, yf + d * ny);
            let (ux, uy) = undistort(k, ex, ey);
            // Carry the normal through the distortion: undistort a short tangent.
            let (tx, ty) = (-ny, nx);
            let (ax, ay) = undistort(k, ex + 0.7 * tx, ey + 0.7 * ty);
            let (bx, by) = undistort(k, ex - 0.7 * tx, ey - 0.7 * ty);
            let (tx, ty) = (ax - bx, ay - by);
            let tn = (tx * tx + ty * ty).sqrt();
            if !(tn > 0.0 && ux.is_finite() && uy.is_finite()) {
                continue;
            }
            out.push(Edge {
                x: ux,
                y: uy,
                nx: ty / tn,
                ny: -tx / tn,
                mag: m0,
            });
        }
    }
    out
}

/// Angle bins (1°) and offset bins (px) of the Hough accumulator.
const N_THETA: usize = 180;
const RHO_BIN: f64 = 2.0;

struct Hough {
    acc: Vec<f64>,
    n_rho: usize,
    rho_max: f64,
}

impl Hough {
    fn new(rho_max: f64) -> Hough {
        let n_rho = (2.0 * rho_max / RHO_BIN).ceil() as usize + 1;
        Hough {
            acc: vec![0.0; N_THETA * n_rho],
            n_rho,
            rho_max,
        }
    }
    /// Votes of one point (its own gradient direction ± 2°) with weight `s`.
    fn vote(&mut self, e: &Edge, s: f64) {
        let th = e.ny.atan2(e.nx).rem_euclid(std::f64::consts::PI);
        let t0 = (th.to_degrees().round() as i64).rem_euclid(N_THETA as i64);
        for dt in -2i64..=2 {
            let t = (t0 + dt).rem_euclid(N_THETA as i64) as usize;
            let a = (t as f64).to_radians();
            let rho = e.x * a.cos() + e.y * a.sin();
            let r = ((rho + self.rho_max) / RHO_BIN).round();
            if r >= 0.0 && (r as usize) < self.n_rho {
                self.acc[t * self.n_rho + r as usize] += s;
            }
        }
    }
    /// The strongest cell: `(votes, theta rad, rho px)`.
    fn peak(&self) -> (f64, f64, f64) {
        let (mut best, mut bi) = (0.0, 0);
        for (i, &v) in self.acc.iter().enumerate() {
            if v > best {
                best = v;
                bi = i;
            }
        }
        let (t, r) = (bi / self.n_rho, bi % self.n_rho);
        (
            best,
            (t as f64).to_radians(),
            r as f64 * RHO_BIN - self.rho_max,
        )
    }
}

/// Unsigned angle (rad, in `[0, π/2]`) between two line normals.
fn normal_angle(ax: f64, ay: f64, bx: f64, by: f64) -> f64 {
    (ax * bx + ay * by).abs().min(1.0).acos()
}

/// Weighted total least squares line `(a, b, c)` (unit normal) through the points `idx`.
fn tls(pts: &[Edge], idx: &[usize]) -> Option<[f64; 3]> {
    let wsum: f64 = idx.iter().map(|&i| pts[i].mag).sum();
    if idx.len() < 2 || wsum <= 0.0 {
        return None;
    }
    let mx = idx.iter().map(|&i| pts[i].mag * pts[i].x).sum::<f64>() / wsum;
    let my = idx.iter().map(|&i| pts[i].mag * pts[i].y).sum::<f64>() / wsum;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for &i in idx {
        let (dx, dy, wt) = (pts[i].x - mx, pts[i].y - my, pts[i].mag);
        sxx += wt * dx * dx;
        sxy += wt * dx * dy;
        syy += wt * dy * dy;
    }
    // Normal = eigenvector of the smaller eigenvalue of the scatter matrix.
    let tr = sxx + syy;
    let det = sxx * syy - sxy * sxy;
    let l_min = 0.5 * tr - (0.25 * tr * tr - det).max(0.0).sqrt();
    let (a, b) = if sxy.abs() > 1e-12 {
        (sxy, l_min - sxx)
    } else if sxx < syy {
        (1.0, 0.0)
    } else {
        (0.0, 1.0)
    };
    let n = (a * a + b * b).sqrt();
    let (a, b) = (a / n, b / n);
    Some([a, b, -(a * mx + b * my)])
}

/// Fits a straight edge from a Hough peak; `None` when too little of it is straight.
fn fit_line(pts: &[Edge], theta: f64, rho: f64, min_run: f64) -> Option<(FittedLine, Vec<usize>)> {
    let mut abc = [theta.cos(), theta.sin(), -rho];
    let mut idx: Vec<usize> = Vec::new();
    for gate in [3.0, 1.5, 1.0, 1.0] {
        idx = (0..pts.len())
            .filter(|&i| {
                let e = &pts[i];
                (abc[0] * e.x + abc[1] * e.y + abc[2]).abs() < gate
                    && normal_angle(abc[0], abc[1], e.nx, e.ny) < 8f64.to_radians()
            })
            .collect();
        // Keep runs along the line at least `min_run` long (gaps up to 8 px).
        let (tx, ty) = (-abc[1], abc[0]);
        idx.sort_by(|&i, &j| {
            (tx * pts[i].x + ty * pts[i].y).total_cmp(&(tx * pts[j].x + ty * pts[j].y))
        });
        let t = |i: usize| tx * pts[i].x + ty * pts[i].y;
        let mut kept = Vec::new();
        let mut start = 0;
        for k in 1..=idx.len() {
            if k == idx.len() || t(idx[k]) - t(idx[k - 1]) > 8.0 {
                if k > start && t(idx[k - 1]) - t(idx[start]) >= min_run {
                    kept.extend_from_slice(&idx[start..k]);
                }
                start = k;
            }
        }
        idx = kept;
        abc = tls(pts, &idx)?;
    }
    if idx.len() < 10 {
        return None;
    }
    let d = |i: usize| abc[0] * pts[i].x + abc[1] * pts[i].y + abc[2];
    let rms = (idx.iter().map(|&i| d(i) * d(i)).sum::<f64>() / idx.len() as f64).sqrt();
    let (tx, ty) = (-abc[1], abc[0]);
    let t = |i: usize| tx * pts[i].x + ty * pts[i].y;
    let mut ts: Vec<f64> = idx.iter().map(|&i| t(i)).collect();
    ts.sort_by(f64::total_cmp);
    let length: f64 = ts
        .windows(2)
        .map(|p| p[1] - p[0])
        .filter(|g| *g <= 8.0)
        .sum();
    let (mut run, mut cur) = (0.0f64, 0.0f64);
    for p in ts.windows(2) {
        let g = p[1] - p[0];
        cur = if g <= 8.0 { cur + g } else { 0.0 };
        run = run.max(cur);
    }
    // End points: the extreme points projected onto the line.
    let foot = |s: f64| {
        let (px, py) = (-abc[0] * abc[2], -abc[1] * abc[2]);
        [px + s * tx, py + s * ty]
    };
    let (p1, p2) = (foot(ts[0]), foot(ts[ts.len() - 1]));
    let n = idx.len();
    let contrast = idx.iter().map(|&i| pts[i].mag).sum::<f64>() / n as f64;
    let pol: f64 = idx
        .iter()
        .map(|&i| pts[i].mag * (pts[i].nx * abc[0] + pts[i].ny * abc[1]).signum())
        .sum();
    Some((
        FittedLine {
            seg: [p1[0], p1[1], p2[0], p2[1]],
            n_points: n,
            rms_px: rms,
            length_px: length,
            run_px: run,
            sigma_px: 2.0 * rms / (n as f64).sqrt(),
            contrast,
            polarity: if pol >= 0.0 { 1.0 } else { -1.0 },
            abc,
        },
        idx,
    ))
}

/// Signed distance of a point from a line.
fn dist(abc: &[f64; 3], x: f64, y: f64) -> f64 {
    abc[0] * x + abc[1] * y + abc[2]
}

/// Every straight edge of an 8-bit grey image (`w × h`, row-major) taken by `cam` (its
/// distortion removed from the edge points), longest first, and the number of edge points.
/// `Err` when the image does not fit the camera or holds (almost) no edges.
pub fn straight_edges(
    img: &[u8],
    w: u32,
    h: u32,
    cam: &EndoscopeCamera,
    opts: &LineOptions,
) -> Result<(Vec<FittedLine>, usize), String> {
    let (wu, hu) = (w as usize, h as usize);
    if img.len() != wu * hu || wu < 16 || hu < 16 {
        return Err(format!(
            "image of {w}×{h} px with {} samples (at least 16×16, one sample per pixel)",
            img.len()
        ));
    }
    if (w, h) != (cam.width, cam.height) {
        return Err(format!(
            "image is {w}×{h} px but the header's camera is {}×{} px (another camera, or a resized image?)",
            cam.width, cam.height
        ));
    }
    let k = intrinsics(cam);
    let pts = edge_points(img, wu, hu, &k, opts.min_gradient);
    if pts.len() < 20 {
        return Err(format!(
            "only {} edge points above {} grey/px: image blank, dark or out of focus",
            pts.len(),
            opts.min_gradient
        ));
    }
    let rho_max = 2.0 * ((wu * wu + hu * hu) as f64).sqrt();
    let mut hough = Hough::new(rho_max);
    for e in &pts {
        hough.vote(e, 1.0);
    }
    let mut used = vec![false; pts.len()];
    let mut lines: Vec<FittedLine> = Vec::new();
    for _ in 0..60 {
        let (votes, theta, rho) = hough.peak();
        if votes < 0.25 * opts.min_length_px {
            break;
        }
        if let Some((line, idx)) = fit_line(&pts, theta, rho, 20.0) {
            for &i in &idx {
                if !used[i] {
                    used[i] = true;
                    hough.vote(&pts[i], -1.0);
                }
            }
            let dup = lines.iter().any(|l| {
                normal_angle(l.abc[0], l.abc[1], line.abc[0], line.abc[1]) < 0.5f64.to_radians()
                    && dist(&l.abc, line.seg[0], line.seg[1]).abs() < 1.0
            });
            if !dup {
                lines.push(line);
            }
        }
        // Clear the peak's neighbourhood so the next one is another line.
        let t0 = theta.to_degrees().round() as i64;
        let r0 = ((rho + rho_max) / RHO_BIN).round() as i64;
        for dt in -1..=1i64 {
            let t = (t0 + dt).rem_euclid(N_THETA as i64) as usize;
            for dr in -2..=2i64 {
                let r = r0 + dr;
                if r >= 0 && (r as usize) < hough.n_rho {
                    hough.acc[t * hough.n_rho + r as usize] = 0.0;
                }
            }
        }
    }
    lines.sort_by(|a, b| b.length_px.total_cmp(&a.length_px));
    Ok((lines, pts.len()))
}

/// Finds the shaft's two silhouette lines in an 8-bit grey image (`w × h`, row-major) taken by
/// `cam` (its distortion is removed from the edge points). `Err` says why the view is refused.
///
/// Among the straight edges at least `min_length_px` long and straight within `max_rms_px`,
/// the strongest pair that comes into the view from its border (the shaft is held from
/// outside the view), is nearly parallel (within 12°), overlapping along its length, at
/// least `min_separation_px` apart without crossing and bounding a band darker (or brighter)
/// than both sides (support: the smaller of the two lines' longest run × contrast) is the
/// shaft's (its silhouettes, or the edges of its specular highlight); the silhouettes are the
/// outermost edges through that pair's vanishing point next to it ([`outermost`]).
pub fn detect(
    img: &[u8],
    w: u32,
    h: u32,
    cam: &EndoscopeCamera,
    opts: &LineOptions,
) -> Result<ShaftLines, String> {
    let (lines, n_pts) = straight_edges(img, w, h, cam, opts)?;
    let n_cand = lines.len();
    let long: Vec<&FittedLine> = lines
        .iter()
        .filter(|l| l.length_px >= opts.min_length_px && l.rms_px <= opts.max_rms_px)
        .collect();
    // Distance of an (undistorted) end point from the border of the image as taken.
    let k = intrinsics(cam);
    let at_border = |u: f64, v: f64| {
        let p = nalgebra::Vector3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
        project(&k, &p).is_some_and(|[x, y]| {
            x.min(y).min(w as f64 - 1.0 - x).min(h as f64 - 1.0 - y) <= opts.border_px
        })
    };
    let enters = |l: &FittedLine| at_border(l.seg[0], l.seg[1]) || at_border(l.seg[2], l.seg[3]);
    if long.is_empty() {
        return Err(format!(
            "no straight edge of {} px or more (found {n_cand} shorter or curved ones): shaft not in view, hidden, or too blurred",
            opts.min_length_px
        ));
    }
    let mut best: Option<(f64, usize, usize)> = None;
    let mut why = format!(
        "no two long straight edges come into the view from its border (within {} px): the shaft is not in view, or hidden where it enters",
        opts.border_px
    );
    for i in 0..long.len() {
        for j in i + 1..long.len() {
            if !(enters(long[i]) && enters(long[j])) {
                continue;
            }
            match pair(long[i], long[j], opts) {
                Ok(score) => {
                    if best.is_none_or(|b| score > b.0) {
                        best = Some((score, i, j));
                    }
                }
                Err(e) => why = e,
            }
        }
    }
    let Some((_, i, j)) = best else {
        return Err(why);
    };
    // Every edge of a cylinder along its axis (silhouettes, highlight edges) meets the others in
    // the axis' vanishing point: grow the pair to the outermost such edges next to it.
    let (lo, hi) = outermost(&long, i, j, &enters);
    Ok(ShaftLines {
        lines: [long[lo].clone(), long[hi].clone()],
        candidates: n_cand,
        edge_points: n_pts,
    })
}

/// The outermost edges of the family of `long[i]`, `long[j]`: edges coming in from the image
/// border (`enters`), at least half as sharp (contrast) and long (run) as the weaker of the
/// two, through their common (vanishing) point within 5 px, overlapping them, added while each lies within three times
/// the family's current width outside it. Returns indices into `long`.
fn outermost(
    long: &[&FittedLine],
    i: usize,
    j: usize,
    enters: &dyn Fn(&FittedLine) -> bool,
) -> (usize, usize) {
    let (a, b) = (long[i], long[j]);
    // Homogeneous intersection of the two lines (w ≈ 0: parallel, a point at infinity).
    let v = [
        a.abc[1] * b.abc[2] - a.abc[2] * b.abc[1],
        a.abc[2] * b.abc[0] - a.abc[0] * b.abc[2],
        a.abc[0] * b.abc[1] - a.abc[1] * b.abc[0],
    ];
    let through_v = |l: &FittedLine| {
        let m = [
            0.5 * (l.seg[0] + l.seg[2]),
            0.5 * (l.seg[1] + l.seg[3]),
            1.0,
        ];
        // Line through m and v.
        let h = [
            m[1] * v[2] - m[2] * v[1],
            m[2] * v[0] - m[0] * v[2],
            m[0] * v[1] - m[1] * v[0],
        ];
        let n = (h[0] * h[0] + h[1] * h[1]).sqrt();
        if n < 1e-12 {
            return false;
        }
        let d = |x: f64, y: f64| ((h[0] * x + h[1] * y + h[2]) / n).abs();
        d(l.seg[0], l.seg[1]).max(d(l.seg[2], l.seg[3])) < 5.0
    };
    // Offsets across a, at the middle of a.
    let (tx, ty) = (-a.abc[1], a.abc[0]);
    let mid = 0.5 * ((tx * a.seg[0] + ty * a.seg[1]) + (tx * a.seg[2] + ty * a.seg[3]));
    let foot = [-a.abc[0] * a.abc[2], -a.abc[1] * a.abc[2]];
    let q = [foot[0] + mid * tx, foot[1] + mid * ty];
    let off = |l: &FittedLine| {
        let c = a.abc[0] * l.abc[0] + a.abc[1] * l.abc[1];
        -dist(&l.abc, q[0], q[1]) / c
    };
    let span = |l: &FittedLine| {
        let s0 = tx * l.seg[0] + ty * l.seg[1];
        let s1 = tx * l.seg[2] + ty * l.seg[3];
        (s0.min(s1), s0.max(s1))
    };
    let (a0, a1) = span(a);
    let family: Vec<(usize, f64)> = (0..long.len())
        .filter(|&k| {
            let l = long[k];
            let (l0, l1) = span(l);
            k == i
                || k == j
                || (enters(l)
                    && l.contrast >= 0.5 * a.contrast.min(b.contrast)
                    && l.run_px >= 0.5 * a.run_px.min(b.run_px)
                    && normal_angle(l.abc[0], l.abc[1], a.abc[0], a.abc[1]) < 12f64.to_radians()
                    && l1.min(a1) - l0.max(a0) > 0.3 * (l1 - l0).min(a1 - a0)
                    && through_v(l))
        })
        .map(|k| (k, off(long[k])))
        .collect();
    let (mut lo, mut hi) = if off(a) <= off(b) { (i, j) } else { (j, i) };
    loop {
        let (olo, ohi) = (off(long[lo]), off(long[hi]));
        let w = ohi - olo;
        let mut changed = false;
        for &(k, o) in &family {
            if o < off(long[lo]) && o >= olo - 3.0 * w {
                lo = k;
                changed = true;
            }
            if o > off(long[hi]) && o <= ohi + 3.0 * w {
                hi = k;
                changed = true;
            }
        }
        if !changed {
            return (lo, hi);
        }
    }
}

/// Whether two straight edges can be the shaft's silhouettes, and the pair's support.
fn pair(a: &FittedLine, b: &FittedLine, opts: &LineOptions) -> Result<f64, String> {
    if normal_angle(a.abc[0], a.abc[1], b.abc[0], b.abc[1]) > 12f64.to_radians() {
        return Err("no two long straight edges are nearly parallel".into());
    }
    // Positions along a's direction; b's span must overlap a's.
    let (tx, ty) = (-a.abc[1], a.abc[0]);
    let span = |l: &FittedLine| {
        let s0 = tx * l.seg[0] + ty * l.seg[1];
        let s1 = tx * l.seg[2] + ty * l.seg[3];
        (s0.min(s1), s0.max(s1))
    };
    let ((a0, a1), (b0, b1)) = (span(a), span(b));
    if b1.min(a1) - b0.max(a0) < 0.3 * (a1 - a0).min(b1 - b0) {
        return Err("the nearly parallel straight edges do not overlap along their length".into());
    }
    // Signed distance of b from a (along a's normal) at both ends of the union of the spans.
    let foot = [-a.abc[0] * a.abc[2], -a.abc[1] * a.abc[2]];
    let off = |s: f64| {
        let q = [foot[0] + s * tx, foot[1] + s * ty];
        let c = a.abc[0] * b.abc[0] + a.abc[1] * b.abc[1];
        -dist(&b.abc, q[0], q[1]) / c
    };
    let (o0, o1) = (off(a0.min(b0)), off(a1.max(b1)));
    if o0.signum() != o1.signum() {
        return Err("the two outermost parallel edges cross within the view: not a shaft".into());
    }
    let sep = o0.abs().min(o1.abs());
    if sep < opts.min_separation_px {
        return Err(format!(
            "the nearly parallel straight edges are {sep:.1} px apart (at least {} px): not a shaft",
            opts.min_separation_px
        ));
    }
    // Band: the bright side of each line, relative to the other line.
    let b_side = o0.signum(); // b lies on a's side with this sign
    let a_bright_towards_b = a.polarity == b_side;
    let mid_a = [0.5 * (a.seg[0] + a.seg[2]), 0.5 * (a.seg[1] + a.seg[3])];
    let a_side_of_b = dist(&b.abc, mid_a[0], mid_a[1]).signum();
    let b_bright_towards_a = b.polarity == a_side_of_b;
    if a_bright_towards_b != b_bright_towards_a {
        return Err("the nearly parallel straight edges bound no dark or bright band (one step, not a shaft)".into());
    }
    Ok((a.run_px * a.contrast).min(b.run_px * b.contrast))
}
