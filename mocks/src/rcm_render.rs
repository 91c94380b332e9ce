//! The endoscope's image of the RCM cell: what the fixed endoscope camera of
//! [`crate::rcm`] sees, rendered by ray casting from the world's true geometry.
//!
//! Scene (all in the robot base, mm): the instrument shaft (a cylinder of the scenario's radius
//! from the trocar to the tip, black-coated: dark diffuse, strong specular highlight), a metal
//! jaw beyond the tip (thinner cylinder), tissue-like background (the body cavity: a sphere of
//! tissue seen from inside, a procedural albedo of blotches and vessels, bump-mapped wet
//! specular glints) and tissue
//! blobs (spheres) that may hide part of the shaft. The light sits at the endoscope's tip
//! (intensity falling off with the square of the distance), the lens vignettes (cos⁴) and
//! distorts (the scenario's OpenCV `[k1, k2, p1, p2, k3]`: the image is the *distorted* one, as
//! a real endoscope delivers it). Pixels on an edge between surfaces are supersampled; then
//! Gaussian optical blur, signal-dependent grey noise, 8-bit quantisation and saturation.
//!
//! This module shares no code with the estimator's line detector (`robocal::solve::rcm`).
use std::path::Path;

use nalgebra::{Isometry3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::rcm::{RcmCell, RcmView};

/// A tissue blob (sphere) in the base.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RcmBlob {
    /// Centre (mm, base).
    pub center_mm: [f64; 3],
    /// Radius (mm).
    pub radius_mm: f64,
}

/// How the endoscope image is rendered (scenario table `[render]`; every field has a default).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RcmRenderConfig {
    /// σ of the Gaussian optical blur (px).
    pub blur_px: f64,
    /// σ of the grey noise at black (grey levels); shot noise adds `0.02 · grey` to the variance.
    pub noise_grey: f64,
    /// Sub-samples per axis on pixels where two surfaces meet.
    pub supersample: u32,
    /// The body cavity: a sphere of tissue around the work area, seen from inside (mm, base).
    pub cavity_center_mm: [f64; 3],
    /// See `cavity_center_mm`.
    pub cavity_radius_mm: f64,
    /// Jaw beyond the tip: length (mm) and radius as a fraction of the shaft's.
    pub jaw_mm: f64,
    /// See `jaw_mm`.
    pub jaw_radius_frac: f64,
    /// Tissue blobs (spheres) that can hide part of the shaft.
    pub blobs: Vec<RcmBlob>,
    /// Light power: radiance of a white Lambertian surface facing the light at 150 mm (the
    /// exposure maps radiance `L` to grey `255 (1 − exp(−L / 160))`).
    pub light_grey: f64,
}

impl Default for RcmRenderConfig {
    fn default() -> Self {
        RcmRenderConfig {
            blur_px: 1.2,
            noise_grey: 2.0,
            supersample: 4,
            cavity_center_mm: [450.0, 0.0, 150.0],
            cavity_radius_mm: 170.0,
            jaw_mm: 10.0,
            jaw_radius_frac: 0.6,
            blobs: Vec::new(),
            light_grey: 600.0,
        }
    }
}

/// An 8-bit grey image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct GreyImage {
    /// Width (px).
    pub width: u32,
    /// Height (px).
    pub height: u32,
    /// Pixels.
    pub data: Vec<u8>,
}

/// What a ray hits first.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Surface {
    Nothing,
    Tissue,
    Shaft,
    Jaw,
    Blob(usize),
}

/// A hit: surface, point, outward unit normal.
struct Hit {
    what: Surface,
    p: Vector3<f64>,
    n: Vector3<f64>,
}

/// The scene of one view, in the camera frame (camera at the origin).
struct Scene<'a> {
    cfg: &'a RcmRenderConfig,
    /// Instrument axis: tip, unit direction towards the tip.
    tip: Vector3<f64>,
    dir: Vector3<f64>,
    /// Axial range of the shaft (s ≤ 0 behind the tip): from the trocar to the tip.
    s_trocar: f64,
    radius: f64,
    /// Cavity centre and radius; texture axes.
    cavity_c: Vector3<f64>,
    cavity_r: f64,
    plane_e1: Vector3<f64>,
    plane_e2: Vector3<f64>,
    blobs: Vec<(Vector3<f64>, f64)>,
}

/// Smallest `t > eps` with `|w + t d|² = r²` restricted to the part of the infinite cylinder
/// (axis through the origin along `z`, `w` the ray origin relative to a point on the axis)
/// whose axial coordinate lies in `[s0, s1]`; returns `(t, axial s)`.
fn cylinder(
    w: &Vector3<f64>,
    d: &Vector3<f64>,
    z: &Vector3<f64>,
    r: f64,
    s0: f64,
    s1: f64,
) -> Option<(f64, f64)> {
    let dp = d - z * d.dot(z);
    let wp = w - z * w.dot(z);
    let a = dp.norm_squared();
    if a < 1e-15 {
        return None;
    }
    let b = 2.0 * wp.dot(&dp);
    let c = wp.norm_squared() - r * r;
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    for t in [(-b - sq) / (2.0 * a), (-b + sq) / (2.0 * a)] {
        if t > 1e-6 {
            let s = (w + d * t).dot(z);
            if s >= s0 && s <= s1 {
                return Some((t, s));
            }
        }
    }
    None
}

/// Value noise-free smooth texture: a sum of oriented sinusoids (deterministic per seed).
fn blotches(x: f64, y: f64) -> f64 {
    let waves = [
        (0.031, 0.017, 0.4, 0.35),
        (-0.012, 0.044, 1.3, 0.25),
        (0.071, -0.052, 2.1, 0.15),
        (0.009, 0.013, 0.2, 0.45),
        (-0.11, 0.09, 0.7, 0.08),
    ];
    waves
        .iter()
        .map(|&(kx, ky, ph, a)| a * (kx * x + ky * y + ph).sin())
        .sum()
}

/// Darkening by vessels: thin meandering curves.
fn vessels(x: f64, y: f64) -> f64 {
    let mut dark: f64 = 0.0;
    for (k, &(fx, fy, ax, w)) in [
        (0.045, 0.012, 14.0, 1.4),
        (0.021, 0.018, 9.0, 0.9),
        (0.080, 0.025, 6.0, 0.6),
    ]
    .iter()
    .enumerate()
    {
        let (xx, yy) = if k % 2 == 0 { (x, y) } else { (y, -x) };
        let centre = ax * (fx * xx).sin()
            + 0.5 * ax * (fx * 2.3 * xx + 1.0).sin()
            + 0.3 * ax * (fx * 5.1 * xx + 2.0).sin();
        let period = 1.0 / fy;
        let d = ((yy - centre) / period).rem_euclid(1.0) * period;
        let d = d.min(period - d);
        dark = dark.max((-(d * d) / (2.0 * w * w)).exp());
    }
    dark
}

/// Tissue height field (mm) for the bump map.
fn bumps(x: f64, y: f64) -> f64 {
    0.8 * (0.09 * x + 0.3).sin() * (0.07 * y).cos() + 0.4 * (0.21 * x - 0.17 * y).sin()
}

impl Scene<'_> {
    fn cast(&self, d: &Vector3<f64>) -> Hit {
        let mut best = Hit {
            what: Surface::Nothing,
            p: Vector3::zeros(),
            n: Vector3::zeros(),
        };
        let mut t_best = f64::INFINITY;
        let w = -self.tip; // ray origin (camera) relative to the tip
        if let Some((t, s)) = cylinder(&w, d, &self.dir, self.radius, self.s_trocar, 0.0) {
            t_best = t;
            let p = d * t;
            let n = (p - self.tip - self.dir * s).normalize();
            best = Hit {
                what: Surface::Shaft,
                p,
                n,
            };
        }
        let rj = self.radius * self.cfg.jaw_radius_frac;
        if let Some((t, s)) = cylinder(&w, d, &self.dir, rj, 0.0, self.cfg.jaw_mm) {
            if t < t_best {
                t_best = t;
                let p = d * t;
                best = Hit {
                    what: Surface::Jaw,
                    p,
                    n: (p - self.tip - self.dir * s).normalize(),
                };
            }
        }
        // The shaft's end face at the tip (a disc), seen when the tip points at the camera.
        let dn = d.dot(&self.dir);
        if dn.abs() > 1e-12 {
            let t = self.tip.dot(&self.dir) / dn;
            let q = d * t - self.tip;
            if t > 1e-6 && t < t_best && q.norm() <= self.radius && q.norm() > rj {
                t_best = t;
                best = Hit {
                    what: Surface::Shaft,
                    p: d * t,
                    n: self.dir,
                };
            }
        }
        for (k, (c, r)) in self.blobs.iter().enumerate() {
            let b = d.dot(c);
            let disc = b * b - (c.norm_squared() - r * r);
            if disc >= 0.0 {
                let t = b - disc.sqrt();
                if t > 1e-6 && t < t_best {
                    t_best = t;
                    let p = d * t;
                    best = Hit {
                        what: Surface::Blob(k),
                        p,
                        n: (p - c) / *r,
                    };
                }
            }
        }
        // The cavity wall, from inside: the far root of |t d − c|² = R².
        let b = d.dot(&self.cavity_c);
        let disc = b * b - (self.cavity_c.norm_squared() - self.cavity_r * self.cavity_r);
        if disc >= 0.0 {
            let t = b + disc.sqrt();
            if t > 1e-6 && t < t_best {
                let p = d * t;
                best = Hit {
                    what: Surface::Tissue,
                    p,
                    n: (self.cavity_c - p) / self.cavity_r,
                };
            }
        }
        best
    }

    /// Radiance (grey level before noise) of what the unit ray `d` hits.
    fn shade(&self, d: &Vector3<f64>) -> f64 {
        let h = self.cast(d);
        let (albedo, ks, shininess, n) = match h.what {
            Surface::Nothing => return 0.0,
            Surface::Shaft => (0.06, 0.55, 30.0, h.n),
            Surface::Jaw => (0.45, 0.9, 60.0, h.n),
            Surface::Tissue | Surface::Blob(_) => {
                // Texture coordinates: plane axes (tissue) or the base-fixed camera axes (blob).
                let (x, y) = (h.p.dot(&self.plane_e1), h.p.dot(&self.plane_e2));
                let off = match h.what {
                    Surface::Blob(k) => 37.0 * (k as f64 + 1.0),
                    _ => 0.0,
                };
                let (x, y) = (x + off, y - off);
                let mut albedo = (0.62 + 0.18 * blotches(x, y)) * (1.0 - 0.45 * vessels(x, y));
                if off > 0.0 {
                    albedo *= 0.4; // blobs sit close to the light: darker tissue (fat, liver)
                }
                // Bump map: perturb the normal by the height field's gradient.
                let e = 0.05;
                let gx = (bumps(x + e, y) - bumps(x - e, y)) / (2.0 * e);
                let gy = (bumps(x, y + e) - bumps(x, y - e)) / (2.0 * e);
                let (t1, t2) = (self.plane_e1, self.plane_e2);
                let n = (h.n - (t1 - h.n * h.n.dot(&t1)) * gx - (t2 - h.n * h.n.dot(&t2)) * gy)
                    .normalize();
                (albedo, 0.25, 80.0, n)
            }
        };
        // Light at the camera: l = v = −d; Blinn–Phong half vector = v.
        let v = -d;
        let dist = h.p.norm();
        let e = (150.0 / dist).powi(2) * self.cfg.light_grey;
        let c = n.dot(&v).max(0.0);
        e * (albedo * c + ks * c.powf(shininess))
    }
}

/// Undistorted normalised image coordinates of a distorted pixel (fixed-point inversion of
/// the OpenCV model `[k1, k2, p1, p2, k3]`).
fn undistort_px(cell: &RcmCell, u: f64, v: f64) -> (f64, f64) {
    let c = &cell.scenario.camera;
    let [k1, k2, p1, p2, k3] = c.dist;
    let (xd, yd) = ((u - c.cx) / c.fx, (v - c.cy) / c.fy);
    let (mut x, mut y) = (xd, yd);
    for _ in 0..30 {
        let r2 = x * x + y * y;
        let rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let tx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let ty = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        x = (xd - tx) / rad;
        y = (yd - ty) / rad;
    }
    (x, y)
}

/// The endoscope renderer of one cell: the pixel rays and the static background (tissue,
/// blobs: the camera is fixed in the base) are computed once; [`Self::render`] then casts only
/// the instrument.
pub struct RcmRenderer {
    cell: RcmCell,
    cfg: RcmRenderConfig,
    /// Unit rays through the pixel corners `(i − ½, j − ½)`, `(w+1) × (h+1)`, camera frame.
    rays: Vec<Vector3<f64>>,
    /// Background at the pixel corners: surface and distance along the ray.
    bg_corner: Vec<(Surface, f64)>,
    /// Background radiance per pixel (supersampled where the background has an edge).
    bg: Vec<f64>,
}

impl RcmRenderer {
    /// Precomputes the rays and the background of `cell` under `cfg` (the renderer keeps its
    /// own copy of the cell: a simulated camera holds it for the whole session).
    pub fn new(cell: &RcmCell, cfg: &RcmRenderConfig) -> RcmRenderer {
        let sc = &cell.scenario;
        let (w, h) = (sc.camera.width as usize, sc.camera.height as usize);
        let rays: Vec<Vector3<f64>> = (0..=h)
            .flat_map(|j| (0..=w).map(move |i| (i, j)))
            .map(|(i, j)| {
                let (x, y) = undistort_px(cell, i as f64 - 0.5, j as f64 - 0.5);
                Vector3::new(x, y, 1.0).normalize()
            })
            .collect();
        let mut r = RcmRenderer {
            cell: cell.clone(),
            cfg: cfg.clone(),
            rays,
            bg_corner: Vec::new(),
            bg: Vec::new(),
        };
        // No instrument: a tip far behind the camera with a zero-radius shaft.
        let bg_corner: Vec<(Surface, f64)> = {
            let scene = r.scene(None);
            r.rays
                .iter()
                .map(|d| {
                    let hit = scene.cast(d);
                    (hit.what, hit.p.norm())
                })
                .collect()
        };
        r.bg_corner = bg_corner;
        let mut bg = vec![0.0; w * h];
        {
            let scene = r.scene(None);
            for j in 0..h {
                for i in 0..w {
                    let k = j * (w + 1) + i;
                    let c = r.bg_corner[k].0;
                    let uniform = [k + 1, k + w + 1, k + w + 2]
                        .iter()
                        .all(|&o| r.bg_corner[o].0 == c);
                    bg[j * w + i] = r.pixel(&scene, i, j, !uniform);
                }
            }
        }
        r.bg = bg;
        r
    }

    /// The scene in the camera frame, with the instrument at `inst` (or none).
    fn scene(&self, inst: Option<&Isometry3<f64>>) -> Scene<'_> {
        let sc = &self.cell.scenario;
        let cfg = &self.cfg;
        let to_cam = self.cell.camera.inverse();
        let trocar = Vector3::from(sc.trocar_mm);
        let ins = Vector3::from(sc.insertion_dir).normalize();
        let e1 = ins.cross(&Vector3::x());
        let e1 = if e1.norm() < 1e-6 {
            ins.cross(&Vector3::y())
        } else {
            e1
        }
        .normalize();
        let e2 = ins.cross(&e1);
        let rot = to_cam.rotation;
        let (tip, dir, s_trocar, radius) = match inst {
            Some(inst) => {
                let tip_b = inst.translation.vector;
                let dir_b = inst.rotation * Vector3::z();
                (
                    (to_cam * Point3::from(tip_b)).coords,
                    rot * dir_b,
                    (trocar - tip_b).dot(&dir_b),
                    sc.instrument.shaft_radius_mm,
                )
            }
            None => (Vector3::new(0.0, 0.0, -1e9), Vector3::z(), 0.0, 0.0),
        };
        Scene {
            cfg,
            tip,
            dir,
            s_trocar,
            radius,
            cavity_c: (to_cam * Point3::from(Vector3::from(cfg.cavity_center_mm))).coords,
            cavity_r: cfg.cavity_radius_mm,
            plane_e1: rot * e1,
            plane_e2: rot * e2,
            blobs: cfg
                .blobs
                .iter()
                .map(|b| {
                    (
                        (to_cam * Point3::from(Vector3::from(b.center_mm))).coords,
                        b.radius_mm,
                    )
                })
                .collect(),
        }
    }

    /// Ray through the image point `(i + a, j + b)` (`a, b ∈ [−½, ½]`), bilinear in the corner
    /// rays (the distortion varies far less than a pixel's ray over a pixel).
    fn ray(&self, i: usize, j: usize, a: f64, b: f64) -> Vector3<f64> {
        let w1 = self.cell.scenario.camera.width as usize + 1;
        let k = j * w1 + i;
        let (fa, fb) = (a + 0.5, b + 0.5);
        (self.rays[k] * ((1.0 - fa) * (1.0 - fb))
            + self.rays[k + 1] * (fa * (1.0 - fb))
            + self.rays[k + w1] * ((1.0 - fa) * fb)
            + self.rays[k + w1 + 1] * (fa * fb))
            .normalize()
    }

    /// Radiance of pixel `(i, j)`: its centre ray, or the mean of `n × n` sub-samples.
    fn pixel(&self, scene: &Scene, i: usize, j: usize, supersample: bool) -> f64 {
        if !supersample {
            return scene.shade(&self.ray(i, j, 0.0, 0.0));
        }
        let ss = self.cfg.supersample.max(1) as usize;
        let mut acc = 0.0;
        for a in 0..ss {
            for b in 0..ss {
                let da = (a as f64 + 0.5) / ss as f64 - 0.5;
                let db = (b as f64 + 0.5) / ss as f64 - 0.5;
                acc += scene.shade(&self.ray(i, j, da, db));
            }
        }
        acc / (ss * ss) as f64
    }

    /// Renders the endoscope image of the instrument at its true pose `inst` (instrument frame
    /// in the base: origin at the tip, z towards the tip); `seed` drives the noise.
    pub fn render(&self, inst: &Isometry3<f64>, seed: u64) -> GreyImage {
        let sc = &self.cell.scenario;
        let (w, h) = (sc.camera.width as usize, sc.camera.height as usize);
        let scene = self.scene(Some(inst));
        let rj = scene.radius * self.cfg.jaw_radius_frac;
        let w0 = -scene.tip;
        // What each pixel corner sees first: the instrument (1) or the background (0 + id).
        let inst_at = |d: &Vector3<f64>| -> Option<f64> {
            let a = cylinder(&w0, d, &scene.dir, scene.radius, scene.s_trocar, 0.0).map(|x| x.0);
            let b = cylinder(&w0, d, &scene.dir, rj, 0.0, self.cfg.jaw_mm).map(|x| x.0);
            match (a, b) {
                (Some(a), Some(b)) => Some(a.min(b)),
                (a, b) => a.or(b),
            }
        };
        let corner: Vec<(bool, Surface)> = self
            .rays
            .iter()
            .zip(&self.bg_corner)
            .map(|(d, &(bg, dist))| match inst_at(d) {
                Some(t) if t < dist || bg == Surface::Nothing => (true, Surface::Shaft),
                _ => (false, bg),
            })
            .collect();
        let mut img = self.bg.clone();
        for j in 0..h {
            for i in 0..w {
                let k = j * (w + 1) + i;
                let c = [
                    corner[k],
                    corner[k + 1],
                    corner[k + w + 1],
                    corner[k + w + 2],
                ];
                let any_inst = c.iter().any(|x| x.0);
                if !any_inst {
                    continue; // background only: precomputed
                }
                let uniform = c.iter().all(|x| *x == c[0]);
                img[j * w + i] = self.pixel(&scene, i, j, !uniform);
            }
        }
        // Vignetting (cos⁴ of the field angle).
        for j in 0..h {
            for i in 0..w {
                let x = (i as f64 - sc.camera.cx) / sc.camera.fx;
                let y = (j as f64 - sc.camera.cy) / sc.camera.fy;
                img[j * w + i] /= (1.0 + x * x + y * y).powi(2);
            }
        }
        if self.cfg.blur_px > 0.0 {
            img = crate::world::sensors::gaussian_blur(&img, w, h, self.cfg.blur_px);
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let nz = self.cfg.noise_grey;
        let data = img
            .iter()
            .map(|&g| {
                // Exposure with a soft shoulder (highlights saturate).
                let g = 255.0 * (1.0 - (-g / 160.0).exp());
                let sigma = (nz * nz + 0.02 * g.max(0.0)).sqrt();
                let n: f64 = rng.sample::<f64, _>(StandardNormal) * sigma;
                (g + n).round().clamp(0.0, 255.0) as u8
            })
            .collect();
        GreyImage {
            width: w as u32,
            height: h as u32,
            data,
        }
    }
}

/// Writes an RCM dataset whose records carry images instead of `shaft_lines`: `dir/name.jsonl`
/// and `dir/name.images/pose-<id>.pgm` (relative paths in the records, as `robocal run`
/// writes them). `poses` are `(true instrument pose, reported instrument pose)`; poses whose
/// shaft is not in view ([`RcmCell::view`] is `None`) are left out. Returns the dataset path
/// and, per written record, the id and the world's exact view (the truth, for scoring).
pub fn write_image_dataset(
    cell: &RcmCell,
    poses: &[(Isometry3<f64>, Isometry3<f64>)],
    cfg: &RcmRenderConfig,
    dir: &Path,
    name: &str,
    seed: u64,
) -> std::io::Result<(std::path::PathBuf, Vec<(u64, RcmView)>)> {
    let renderer = RcmRenderer::new(cell, cfg);
    let img_dir = format!("{name}.images");
    std::fs::create_dir_all(dir.join(&img_dir))?;
    let mut views = Vec::new();
    let mut with_views = Vec::new();
    for (i, (truth, reported)) in poses.iter().enumerate() {
        let Some(v) = cell.view(truth) else { continue };
        let id = i as u64 + 1;
        let im = renderer.render(truth, seed.wrapping_mul(1000).wrapping_add(id));
        let rel = format!("{img_dir}/pose-{id}.pgm");
        std::fs::write(
            dir.join(&rel),
            robocal_drivers::camera::pgm::encode(im.width, im.height, &im.data),
        )?;
        with_views.push((*reported, v.clone(), rel));
        views.push((id, v));
    }
    let text = cell.dataset_jsonl(
        &with_views
            .iter()
            .map(|(p, v, _)| (*p, v.clone()))
            .collect::<Vec<_>>(),
    );
    // Replace each record's shaft_lines by its image (ids follow the written order).
    let mut out = String::new();
    for (k, line) in text.lines().enumerate() {
        if k == 0 {
            out.push_str(line);
        } else {
            let mut rec: serde_json::Value =
                serde_json::from_str(line).map_err(std::io::Error::other)?;
            let (id, _) = views[k - 1];
            rec["id"] = id.into();
            if let Some(o) = rec.as_object_mut() {
                o.remove("shaft_lines");
            }
            rec["image"] = with_views[k - 1].2.clone().into();
            out.push_str(&rec.to_string());
        }
        out.push('\n');
    }
    let path = dir.join(format!("{name}.jsonl"));
    std::fs::write(&path, out)?;
    Ok((path, views))
}
