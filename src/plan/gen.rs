//! Pose generators: each turns a spec into candidate *tool* poses in the robot base
//! (mm, rad); the planner then solves IK for every branch and applies the constraints.
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::spec::{AnnulusSpec, FiveDirectionSpec, PlanSpec, PlaneTarget, PlanesSpec, ShellSpec};

/// How many IK branches of a candidate are kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BranchPolicy {
    /// Every feasible branch (seed 001).
    All,
    /// Every feasible branch, and the point only if at least this many are feasible.
    AllAtLeast(usize),
    /// The feasible branch closest to the previous pose / home (one per point).
    Best,
}

/// A plane the laser beam must hit (robot base, mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HitPlane {
    pub point: Point3<f64>,
    pub normal: Vector3<f64>,
}

/// One planned target before IK.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// Target number (several branches share it).
    pub point: usize,
    /// Desired tool (sensor) pose in the robot base.
    pub tool_in_base: Isometry3<f64>,
    pub group: String,
    pub label: String,
    pub plane: Option<String>,
    pub move_kind: Option<String>,
    pub block: Option<usize>,
    pub target: Option<String>,
    /// For laser plans: the plane the beam must hit.
    pub hit_plane: Option<HitPlane>,
    pub branches: BranchPolicy,
    /// The roll about the tool z axis is free (a laser beam does not care): the planner
    /// tries other rolls when this one is infeasible.
    pub free_roll: bool,
}

impl Candidate {
    fn new(point: usize, tool_in_base: Isometry3<f64>, group: &str, label: String) -> Self {
        Candidate {
            point,
            tool_in_base,
            group: group.to_string(),
            label,
            plane: None,
            move_kind: None,
            block: None,
            target: None,
            hit_plane: None,
            branches: BranchPolicy::All,
            free_roll: false,
        }
    }
}

/// All candidates of a spec (deterministic in `spec.seed`).
pub fn generate(spec: &PlanSpec) -> Vec<Candidate> {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let mut out = Vec::new();
    if let Some(a) = &spec.annulus {
        annulus(a, &spec.group, "A", &mut rng, &mut out);
    }
    if let Some(s) = &spec.shell {
        shell(s, &spec.group, &mut rng, &mut out);
    }
    if let Some(p) = &spec.planes {
        planes(p, &spec.group, &mut rng, &mut out);
    }
    if let Some(r) = &spec.rcm {
        // Seed 002: the tool is the instrument's tip frame; one branch per pose.
        let rs = r.to_spec(spec.seed, spec.tool.xyz[2]);
        for (k, p) in super::rcm::draw(&rs).into_iter().enumerate() {
            let mut c = Candidate::new(
                k,
                p.instrument,
                &spec.group,
                format!(
                    "R{k} pivot {:.1}/{:.1} deg depth {:.0} mm",
                    p.pivot_deg[0], p.pivot_deg[1], p.insertion_mm
                ),
            );
            c.branches = BranchPolicy::Best;
            out.push(c);
        }
    }
    if let Some(v) = &spec.validation {
        if let Some(f) = &v.five_direction {
            five_direction(f, &spec.group, &mut out);
        }
        if let Some(c) = &v.coincidence {
            annulus(c, &spec.group, "C", &mut rng, &mut out);
        }
    }
    out
}

fn uniform(rng: &mut ChaCha8Rng, r: [f64; 2]) -> f64 {
    if r[1] > r[0] {
        rng.random_range(r[0]..=r[1])
    } else {
        r[0]
    }
}

/// Fixed-axis X-Y-Z attitude: `R = Rz(z)·Ry(y)·Rx(x)` (rad).
pub fn attitude(x: f64, y: f64, z: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(x, y, z)
}

/// Seed 001 §4.2: uniform in the annulus area and height, uniform attitude angles.
fn annulus(
    a: &AnnulusSpec,
    group: &str,
    tag: &str,
    rng: &mut ChaCha8Rng,
    out: &mut Vec<Candidate>,
) {
    let first = out.iter().map(|c| c.point + 1).max().unwrap_or(0);
    let d2r = |r: [f64; 2]| [r[0].to_radians(), r[1].to_radians()];
    for i in 0..a.points {
        let phi = uniform(rng, d2r(a.angle_deg));
        let r2 = uniform(rng, [a.radius_mm[0].powi(2), a.radius_mm[1].powi(2)]);
        let r = r2.sqrt();
        let z = uniform(rng, a.height_mm);
        let ax = uniform(rng, d2r(a.attitude_x_deg));
        let ay = uniform(rng, d2r(a.attitude_y_deg));
        let az = uniform(rng, d2r(a.attitude_z_deg));
        let iso = Isometry3::from_parts(
            Translation3::new(r * phi.cos(), r * phi.sin(), z),
            attitude(ax, ay, az),
        );
        let mut c = Candidate::new(first + i, iso, group, format!("{tag}{:03}", i + 1));
        c.branches = if a.min_branches > 1 {
            BranchPolicy::AllAtLeast(a.min_branches)
        } else {
            BranchPolicy::All
        };
        out.push(c);
    }
}

/// Orthonormal frame with z = `z` and x as close as possible to `x_hint`.
fn frame_zx(z: Vector3<f64>, x_hint: Vector3<f64>) -> Rotation3<f64> {
    let z = z.normalize();
    let mut x = x_hint - z * z.dot(&x_hint);
    if x.norm() < 1e-9 {
        let alt = if z.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        x = alt - z * z.dot(&alt);
    }
    let x = x.normalize();
    let y = z.cross(&x);
    Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]))
}

/// Camera pose of seed 004 for spherical coordinates `(r, θ, α)` about `center` with the
/// pole `pole` and azimuth zero `x0`: optical axis (z) at the centre, x normal to the plane
/// through camera, centre and pole.
pub fn shell_viewpoint(
    center: &Point3<f64>,
    pole: &Vector3<f64>,
    x0: &Vector3<f64>,
    r: f64,
    theta: f64,
    alpha: f64,
) -> Isometry3<f64> {
    let w = frame_zx(*pole, *x0);
    let (ex, ey, ez) = (w * Vector3::x(), w * Vector3::y(), w * Vector3::z());
    let dir =
        ex * (theta.sin() * alpha.cos()) + ey * (theta.sin() * alpha.sin()) + ez * theta.cos();
    let cam = center + dir * r;
    let zc = -dir;
    // pole × dir / sinθ, written so that θ = 0 keeps the azimuth's direction.
    let xc = -ex * alpha.sin() + ey * alpha.cos();
    let yc = zc.cross(&xc);
    let rot = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[xc, yc, zc]));
    Isometry3::from_parts(
        Translation3::from(cam.coords),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

/// Seed 004: stratified (r, θ, α) samples.
fn shell(s: &ShellSpec, group: &str, rng: &mut ChaCha8Rng, out: &mut Vec<Candidate>) {
    let center = Point3::from(s.center_mm);
    let pole = Vector3::from(s.pole);
    let x0 = Vector3::from(s.azimuth_zero);
    let [nr, nt, na] = s.strata;
    let mut point = out.iter().map(|c| c.point + 1).max().unwrap_or(0);
    let cell = |rng: &mut ChaCha8Rng, lo: f64, hi: f64, k: usize, n: usize| {
        let w = (hi - lo) / n as f64;
        let f = if s.jitter {
            rng.random_range(0.0..1.0)
        } else {
            0.5
        };
        lo + w * (k as f64 + f)
    };
    for ir in 0..nr {
        for it in 0..nt {
            for ia in 0..na {
                let r = cell(rng, s.radius_mm[0], s.radius_mm[1], ir, nr);
                let th = cell(rng, s.polar_deg[0], s.polar_deg[1], it, nt).to_radians();
                let al = cell(rng, s.azimuth_deg[0], s.azimuth_deg[1], ia, na).to_radians();
                let iso = shell_viewpoint(&center, &pole, &x0, r, th, al);
                let mut c = Candidate::new(point, iso, group, format!("S-r{ir}-t{it}-a{ia}"));
                if s.best_branch_only {
                    c.branches = BranchPolicy::Best;
                }
                out.push(c);
                point += 1;
            }
        }
    }
}

/// Plane frame: origin at the rectangle centre, z = normal, x = u.
fn plane_frame(p: &PlaneTarget) -> (Point3<f64>, Rotation3<f64>) {
    (
        Point3::from(p.center_mm),
        frame_zx(Vector3::from(p.normal), Vector3::from(p.u_axis)),
    )
}

/// Laser pose whose beam (tool z) hits `hit` from `range` mm away along `beam`.
fn laser_pose(
    hit: &Point3<f64>,
    beam: &Vector3<f64>,
    x_hint: &Vector3<f64>,
    range: f64,
) -> Isometry3<f64> {
    let rot = frame_zx(*beam, *x_hint);
    let origin = hit - beam.normalize() * range;
    Isometry3::from_parts(
        Translation3::from(origin.coords),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

/// Beam direction tilted from the anti-normal by `tilt` towards in-plane azimuth `az`.
fn tilted_beam(frame: &Rotation3<f64>, tilt: f64, az: f64) -> Vector3<f64> {
    let (ex, ey, ez) = (
        frame * Vector3::x(),
        frame * Vector3::y(),
        frame * Vector3::z(),
    );
    (-ez * tilt.cos() + (ex * az.cos() + ey * az.sin()) * tilt.sin()).normalize()
}

/// Seed 000 §2.2: per plane `nu × nv` blocks; per block three translation-only moves (one
/// per translation group, fixed orientation per group) and one rotation+translation move.
fn planes(p: &PlanesSpec, group: &str, rng: &mut ChaCha8Rng, out: &mut Vec<Candidate>) {
    let mut point = out.iter().map(|c| c.point + 1).max().unwrap_or(0);
    let [nu, nv] = p.blocks;
    for pl in &p.planes {
        let (o, frame) = plane_frame(pl);
        let (ex, ey, ez) = (
            frame * Vector3::x(),
            frame * Vector3::y(),
            frame * Vector3::z(),
        );
        let (bu, bv) = (pl.size_mm[0] / nu as f64, pl.size_mm[1] / nv as f64);
        let roll = p.roll_deg.to_radians();
        let x_hint = ex * roll.cos() + ey * roll.sin();
        for iv in 0..nv {
            for iu in 0..nu {
                let block = iv * nu + iu;
                let u0 = -pl.size_mm[0] / 2.0 + bu * iu as f64;
                let v0 = -pl.size_mm[1] / 2.0 + bv * iv as f64;
                let hit_in_block = |rng: &mut ChaCha8Rng| {
                    let u = u0 + bu * rng.random_range(0.1..0.9);
                    let v = v0 + bv * rng.random_range(0.1..0.9);
                    o + ex * u + ey * v
                };
                for k in 0..4 {
                    let hit = hit_in_block(rng);
                    let standoff = uniform(rng, p.standoff_mm);
                    let (beam, hint, kind, label) = if k < 3 {
                        // Translation group k: the same orientation in every block.
                        let tilt = p.translate_tilt_deg[k].to_radians();
                        let az = (120.0 * k as f64).to_radians();
                        (
                            tilted_beam(&frame, tilt, az),
                            x_hint,
                            "translate",
                            format!("T{}", k + 1),
                        )
                    } else {
                        let tilt = rng
                            .random_range(0.0..=p.rotate_max_deg.max(0.0))
                            .to_radians();
                        let az = rng.random_range(0.0..std::f64::consts::TAU);
                        let rr = roll + rng.random_range(-0.5..0.5);
                        (
                            tilted_beam(&frame, tilt, az),
                            ex * rr.cos() + ey * rr.sin(),
                            "rotate",
                            "R".into(),
                        )
                    };
                    let range = standoff / beam.dot(&-ez);
                    let iso = laser_pose(&hit, &beam, &hint, range);
                    let mut c = Candidate::new(
                        point,
                        iso,
                        group,
                        format!("{}-b{:02}-{label}", pl.name, block + 1),
                    );
                    c.plane = Some(pl.name.clone());
                    c.move_kind = Some(kind.into());
                    c.block = Some(block + 1);
                    c.hit_plane = Some(HitPlane {
                        point: o,
                        normal: ez,
                    });
                    c.branches = BranchPolicy::Best;
                    c.free_roll = kind == "rotate";
                    out.push(c);
                    point += 1;
                }
            }
        }
    }
}

/// Seed 000 §2.3.1: five directions per target (normal + four at `tilt` spaced 90°).
fn five_direction(f: &FiveDirectionSpec, group: &str, out: &mut Vec<Candidate>) {
    let mut point = out.iter().map(|c| c.point + 1).max().unwrap_or(0);
    let (o, frame) = plane_frame(&f.plane);
    let (ex, ey, ez) = (
        frame * Vector3::x(),
        frame * Vector3::y(),
        frame * Vector3::z(),
    );
    let [nu, nv] = f.targets;
    let (bu, bv) = (
        f.plane.size_mm[0] / nu as f64,
        f.plane.size_mm[1] / nv as f64,
    );
    let tilt = f.tilt_deg.to_radians();
    for iv in 0..nv {
        for iu in 0..nu {
            let t = iv * nu + iu + 1;
            let u = -f.plane.size_mm[0] / 2.0 + bu * (iu as f64 + 0.5);
            let v = -f.plane.size_mm[1] / 2.0 + bv * (iv as f64 + 0.5);
            let hit = o + ex * u + ey * v;
            let name = format!("{}-t{t:02}", f.plane.name);
            for d in 0..5 {
                let beam = if d == 0 {
                    -ez
                } else {
                    tilted_beam(
                        &frame,
                        tilt,
                        (f.azimuth0_deg + 90.0 * (d - 1) as f64).to_radians(),
                    )
                };
                let iso = laser_pose(&hit, &beam, &ex, f.standoff_mm);
                let mut c = Candidate::new(point, iso, group, format!("{name}-d{d}"));
                c.target = Some(name.clone());
                c.hit_plane = Some(HitPlane {
                    point: o,
                    normal: ez,
                });
                c.branches = BranchPolicy::Best;
                c.free_roll = true;
                out.push(c);
                point += 1;
            }
        }
    }
}
