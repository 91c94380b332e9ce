//! The simulated navigation chain of seed 003: a CT head phantom with fiducials
//! and a surface, an optical stereo tracker whose depth error grows with z², a robot whose
//! calibrated positioning still errs, and a tool tip. The world holds the truth (phantom
//! pose in the tracker, tracker pose in the robot base, marker on the flange) and computes
//! every measurement with its own code; estimators only ever see the measurements.
#![allow(clippy::too_many_arguments)]
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Noise levels of the simulated chain (1σ).
#[derive(Debug, Clone, Copy)]
pub struct NavNoise {
    /// Stereo baseline of the tracker (mm).
    pub baseline_mm: f64,
    /// Focal length of the tracker's cameras (px).
    pub focal_px: f64,
    /// Disparity noise (px): depth σ = z²/(b·f)·σ_d.
    pub disparity_sigma_px: f64,
    /// Image noise (px): lateral σ = z/f·σ_px.
    pub pixel_sigma_px: f64,
    /// CT fiducial localisation per axis (mm).
    pub ct_sigma_mm: f64,
    /// Calibrated robot's tip positioning error per axis (mm).
    pub robot_sigma_mm: f64,
    /// Tool tip offset error per axis (mm).
    pub tool_sigma_mm: f64,
    /// Marker orientation noise per axis (deg).
    pub marker_rot_sigma_deg: f64,
}

impl Default for NavNoise {
    fn default() -> Self {
        NavNoise {
            baseline_mm: 500.0,
            focal_px: 1500.0,
            disparity_sigma_px: 0.08,
            pixel_sigma_px: 0.06,
            ct_sigma_mm: 0.25,
            robot_sigma_mm: 0.15,
            tool_sigma_mm: 0.05,
            marker_rot_sigma_deg: 0.03,
        }
    }
}

/// One simulated operating room.
pub struct NavWorld {
    /// True `T_tracker_ct` (phantom pose in the tracker).
    pub t_tracker_ct: Isometry3<f64>,
    /// True `T_base_tracker`.
    pub t_base_tracker: Isometry3<f64>,
    /// True `T_flange_marker`.
    pub t_flange_marker: Isometry3<f64>,
    /// True fiducial centres (CT frame, mm).
    pub fiducials: Vec<(String, Point3<f64>)>,
    /// Noise levels.
    pub noise: NavNoise,
    rng: ChaCha8Rng,
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

fn gauss3(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    Vector3::new(gauss(rng), gauss(rng), gauss(rng))
}

fn random_rotation(rng: &mut ChaCha8Rng) -> UnitQuaternion<f64> {
    let q = nalgebra::Quaternion::new(gauss(rng), gauss(rng), gauss(rng), gauss(rng));
    UnitQuaternion::from_quaternion(q)
}

/// Radius (mm) of the head phantom in direction (polar θ from +z, azimuth φ from +x): an
/// ellipsoid with a nose, brow ridge and an occipital bump, so no symmetry lets a surface
/// registration slide.
pub fn phantom_radius(theta: f64, phi: f64) -> f64 {
    let d = Vector3::new(
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    );
    let (a, b, c) = (85.0, 70.0, 100.0);
    let base = 1.0 / ((d.x / a).powi(2) + (d.y / b).powi(2) + (d.z / c).powi(2)).sqrt();
    let bump = |dir: Vector3<f64>, width: f64, h: f64| {
        let cosang = d.dot(&dir.normalize());
        h * (-(1.0 - cosang) / width).exp()
    };
    base + bump(Vector3::new(1.0, 0.0, 0.1), 0.01, 18.0) // nose
        + bump(Vector3::new(0.8, 0.0, 0.6), 0.05, 6.0) // brow
        + bump(Vector3::new(-0.7, 0.4, 0.3), 0.08, 8.0) // occipital, off-centre
        + 2.0 * (3.0 * phi).sin() * theta.sin()
}

/// Surface point of the phantom (CT frame) at (θ, φ).
pub fn phantom_point(theta: f64, phi: f64) -> Point3<f64> {
    let r = phantom_radius(theta, phi);
    Point3::new(
        r * theta.sin() * phi.cos(),
        r * theta.sin() * phi.sin(),
        r * theta.cos(),
    )
}

/// The phantom surface as a triangle mesh (CT frame): latitude-longitude grid with poles.
pub fn phantom_mesh(n_lat: usize, n_lon: usize) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    let mut v = vec![[0.0, 0.0, phantom_radius(0.0, 0.0)]];
    for i in 1..n_lat {
        let th = std::f64::consts::PI * i as f64 / n_lat as f64;
        for j in 0..n_lon {
            let ph = 2.0 * std::f64::consts::PI * j as f64 / n_lon as f64;
            let p = phantom_point(th, ph);
            v.push([p.x, p.y, p.z]);
        }
    }
    v.push([0.0, 0.0, -phantom_radius(std::f64::consts::PI, 0.0)]);
    let south = v.len() - 1;
    let idx = |i: usize, j: usize| 1 + (i - 1) * n_lon + (j % n_lon);
    let mut t = Vec::new();
    for j in 0..n_lon {
        t.push([0, idx(1, j), idx(1, j + 1)]);
        t.push([south, idx(n_lat - 1, j + 1), idx(n_lat - 1, j)]);
    }
    for i in 1..n_lat - 1 {
        for j in 0..n_lon {
            t.push([idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)]);
            t.push([idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)]);
        }
    }
    (v, t)
}

impl NavWorld {
    /// A random room: the phantom 1.4–1.9 m in front of the tracker in any orientation,
    /// the tracker ~1.9 m from the robot base looking back at it.
    pub fn new(seed: u64, noise: NavNoise) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let ph_pos = Vector3::new(
            rng.random_range(-150.0..150.0),
            rng.random_range(-150.0..150.0),
            rng.random_range(-1900.0..-1400.0),
        );
        let t_tracker_ct =
            Isometry3::from_parts(Translation3::from(ph_pos), random_rotation(&mut rng));
        // Tracker: at x ≈ 1.9 m, z ≈ 0.9 m, looking along −x (its −z axis toward the robot).
        let look = UnitQuaternion::from_euler_angles(0.0, -std::f64::consts::FRAC_PI_2, 0.0);
        let jitter = UnitQuaternion::from_scaled_axis(gauss3(&mut rng) * 0.05);
        let t_base_tracker = Isometry3::from_parts(
            Translation3::new(
                1900.0 + rng.random_range(-100.0..100.0),
                rng.random_range(-200.0..200.0),
                900.0 + rng.random_range(-100.0..100.0),
            ),
            jitter * look,
        );
        let t_flange_marker =
            Isometry3::new(Vector3::new(30.0, -20.0, 90.0), Vector3::new(0.2, 0.1, 0.3));
        let fiducials = [
            (0.35, 0.3),
            (0.6, 1.6),
            (0.9, -1.2),
            (1.3, 0.4),
            (1.2, 2.6),
            (0.2, -2.5),
            (1.6, -0.5),
        ]
        .iter()
        .enumerate()
        .map(|(i, (th, ph))| (format!("F{}", i + 1), phantom_point(*th, *ph)))
        .collect();
        NavWorld {
            t_tracker_ct,
            t_base_tracker,
            t_flange_marker,
            fiducials,
            noise,
            rng,
        }
    }

    /// Stereo reconstruction noise of a point at `p` (tracker frame): depth σ = z²/(b f)·σ_d
    /// along the line of sight, z/f·σ_px across it.
    fn stereo_noise(&mut self, p: &Point3<f64>) -> Vector3<f64> {
        let z = p.coords.norm();
        let los = p.coords / z;
        let e1 = los
            .cross(&Vector3::x())
            .try_normalize(1e-9)
            .unwrap_or_else(|| los.cross(&Vector3::y()).normalize());
        let e2 = los.cross(&e1);
        let n = self.noise;
        let sd = z * z / (n.baseline_mm * n.focal_px) * n.disparity_sigma_px;
        let sl = z / n.focal_px * n.pixel_sigma_px;
        los * (sd * gauss(&mut self.rng))
            + e1 * (sl * gauss(&mut self.rng))
            + e2 * (sl * gauss(&mut self.rng))
    }

    /// Fiducials as localised in the CT image.
    pub fn ct_fiducials(&mut self) -> Vec<(String, Point3<f64>)> {
        let s = self.noise.ct_sigma_mm;
        let f = self.fiducials.clone();
        f.into_iter()
            .map(|(n, p)| (n, p + gauss3(&mut self.rng) * s))
            .collect()
    }

    /// Fiducials touched with the tracked probe (tracker frame).
    pub fn tracker_fiducials(&mut self) -> Vec<(String, Point3<f64>)> {
        let f = self.fiducials.clone();
        f.into_iter()
            .map(|(n, p)| {
                let q = self.t_tracker_ct * p;
                let e = self.stereo_noise(&q);
                (n, q + e)
            })
            .collect()
    }

    /// `n` surface points digitised with the probe on the accessible part of the head
    /// (top and face: θ ≤ 100°, |φ| ≤ 120°), tracker frame.
    pub fn surface_points(&mut self, n: usize) -> Vec<Point3<f64>> {
        (0..n)
            .map(|_| {
                let th = self.rng.random_range(0.05..100f64.to_radians());
                let ph = self
                    .rng
                    .random_range(-120f64.to_radians()..120f64.to_radians());
                let q = self.t_tracker_ct * phantom_point(th, ph);
                let e = self.stereo_noise(&q);
                q + e
            })
            .collect()
    }

    /// `n` robot-world poses: reported flange pose `A_i` (the calibrated robot's, which errs
    /// by its positioning error) and the measured marker pose `B_i` in the tracker.
    pub fn robot_world_poses(&mut self, n: usize) -> Vec<(Isometry3<f64>, Isometry3<f64>)> {
        let nominal = UnitQuaternion::from_euler_angles(0.0, std::f64::consts::FRAC_PI_2, 0.0);
        (0..n)
            .map(|_| {
                let pos = Vector3::new(
                    self.rng.random_range(350.0..750.0),
                    self.rng.random_range(-300.0..300.0),
                    self.rng.random_range(250.0..650.0),
                );
                let tilt = UnitQuaternion::from_scaled_axis(gauss3(&mut self.rng) * 0.35);
                let a_true = Isometry3::from_parts(Translation3::from(pos), tilt * nominal);
                let mut a_rep = a_true;
                a_rep.translation.vector += gauss3(&mut self.rng) * self.noise.robot_sigma_mm;
                let b_true = self.t_base_tracker.inverse() * a_true * self.t_flange_marker;
                let p = Point3::from(b_true.translation.vector);
                let e = self.stereo_noise(&p);
                let drot = gauss3(&mut self.rng) * self.noise.marker_rot_sigma_deg.to_radians();
                let b = Isometry3::from_parts(
                    Translation3::from(p.coords + e),
                    UnitQuaternion::from_scaled_axis(drot) * b_true.rotation,
                );
                (a_rep, b)
            })
            .collect()
    }

    /// The true position of a CT point in the robot base.
    pub fn true_in_base(&self, x_ct: &Point3<f64>) -> Point3<f64> {
        self.t_base_tracker * (self.t_tracker_ct * x_ct)
    }

    /// Where the tool tip really ends when the robot is commanded to `p` (base frame).
    pub fn reach(&mut self, p: &Point3<f64>) -> Point3<f64> {
        p + gauss3(&mut self.rng) * self.noise.robot_sigma_mm
            + gauss3(&mut self.rng) * self.noise.tool_sigma_mm
    }

    /// A random target inside the head (CT frame).
    pub fn random_target(&mut self) -> Point3<f64> {
        let th = self.rng.random_range(0.2..2.9);
        let ph = self.rng.random_range(-3.1..3.1);
        let s = self.rng.random_range(0.1..0.7);
        Point3::from(phantom_point(th, ph).coords * s)
    }

    /// A start guess of `T_tracker_ct` off the truth by `angle_deg` about a random axis
    /// through the phantom centre and `shift_mm` in a random direction.
    pub fn perturbed_start(&mut self, angle_deg: f64, shift_mm: f64) -> Isometry3<f64> {
        let axis = gauss3(&mut self.rng).normalize();
        let dir = gauss3(&mut self.rng).normalize();
        let c = self.t_tracker_ct.translation.vector;
        let r = UnitQuaternion::from_scaled_axis(axis * angle_deg.to_radians());
        let about_c = Isometry3::from_parts(Translation3::from(c), r)
            * Isometry3::from_parts(Translation3::from(-c), UnitQuaternion::identity());
        let mut t = about_c * self.t_tracker_ct;
        t.translation.vector += dir * shift_mm;
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mesh_is_closed_and_fiducials_lie_on_the_surface() {
        let (v, t) = phantom_mesh(30, 60);
        assert_eq!(t.len(), 2 * 60 * 29);
        // Every edge shared by exactly two triangles (closed surface).
        let mut edges = std::collections::HashMap::new();
        for tri in &t {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        assert!(edges.values().all(|&c| c == 2));
        assert!(v.iter().all(|p| p.iter().all(|x| x.is_finite())));
        let w = NavWorld::new(1, NavNoise::default());
        assert_eq!(w.fiducials.len(), 7);
    }
}
