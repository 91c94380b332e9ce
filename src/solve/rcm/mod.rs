//! Hand-eye calibration of an endoscope camera under a remote-centre-of-motion constraint
//! (seed 002, see docs/seeds.md).
//!
//! A laparoscopic instrument pivots about the trocar (the RCM), so its pose barely changes and
//! `AX = XB` is ill-conditioned. Instead the camera sees the instrument's cylindrical shaft:
//! 1. [`plucker::axis_from_boundaries`]: the two image boundary lines → the shaft axis as a
//!    Plücker line in the camera frame (radius known);
//! 2. [`seed::refine`]: all axes must pass through the RCM → joint refinement with the seed's
//!    loss over common-perpendicular points;
//! 3. [`seed::hand_eye`]: the RCM point in the camera and the robot's instrument directions
//!    give the hand-eye rotation and translation (the camera in the robot base);
//! 4. beyond the seed, [`ml::refine`]: maximum likelihood on the segment end points (predicted
//!    silhouettes of the cylinder vs the observed end points), with its covariance and a
//!    bootstrap over poses.
//!
//! [`axxb`] holds the classical baselines. Units: mm, radians inside.
use std::path::Path;

use nalgebra::{Isometry3, Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::dataset::endoscope::{self, EndoscopeCamera, InstrumentBlock};
use crate::dataset::{Dataset, Record};

pub mod axxb;
pub mod dual;
pub mod lines;
pub mod ml;
pub mod plucker;
pub mod report;
pub mod seed;

use plucker::{Line, Pinhole};

/// Errors of the RCM calibration.
#[derive(Debug, thiserror::Error)]
pub enum RcmError {
    /// The dataset lacks or misstates a field (message names file, line, field).
    #[error("{0}")]
    Data(String),
    /// A pair of boundary lines does not describe a cylinder.
    #[error("shaft boundary lines: {0}")]
    BadLines(String),
    /// Too few poses.
    #[error("need at least 3 poses with shaft lines and an instrument pose, got {got}")]
    TooFew {
        /// Usable poses.
        got: usize,
    },
    /// The poses cannot determine the hand-eye transform.
    #[error("degenerate data: {0}")]
    Degenerate(String),
    /// The solver failed.
    #[error("solver: {0}")]
    Solver(String),
}

/// One usable pose.
#[derive(Debug, Clone)]
pub struct RcmObs {
    /// Record id.
    pub id: u64,
    /// Line of the record in its file (1-based).
    pub line: usize,
    /// Instrument frame in the base (origin on the shaft axis, z towards the tip).
    pub flange: Isometry3<f64>,
    /// The two silhouette segments (undistorted pixels).
    pub segs: [[f64; 4]; 2],
}

impl RcmObs {
    /// The instrument axis in the base.
    pub fn axis(&self) -> Line {
        Line::through(
            &self.flange.translation.vector,
            &(self.flange.rotation * Vector3::z()),
        )
    }
}

/// What an RCM calibration needs from a dataset.
#[derive(Debug, Clone)]
pub struct RcmData {
    /// The header's camera block.
    pub camera: EndoscopeCamera,
    /// Pinhole of the undistorted image.
    pub k: Pinhole,
    /// Shaft radius (mm).
    pub radius: f64,
    /// Usable poses.
    pub obs: Vec<RcmObs>,
    /// Poses whose `shaft_lines` were detected in their image: id and the detection (quality).
    pub detected: Vec<(u64, lines::ShaftLines)>,
    /// Views whose image was refused by the line detector: what and why.
    pub refused: Vec<String>,
}

impl RcmData {
    /// From in-memory parts (simulation, tests).
    pub fn new(camera: EndoscopeCamera, radius: f64, obs: Vec<RcmObs>) -> RcmData {
        let k = Pinhole {
            fx: camera.fx,
            fy: camera.fy,
            cx: camera.cx,
            cy: camera.cy,
        };
        RcmData {
            camera,
            k,
            radius,
            obs,
            detected: Vec::new(),
            refused: Vec::new(),
        }
    }
    /// Reads the `camera`, `instrument` and per-pose `flange` + `shaft_lines` of a dataset;
    /// `file` names it in errors. A pose without `shaft_lines` but with an `image` (path
    /// relative to the dataset) gets them from [`lines::detect`]; a view the detector refuses
    /// is skipped and listed in `refused` with the reason. Poses with neither are skipped (the
    /// shaft was not seen); a pose with `shaft_lines` or an image but no `flange` is an error,
    /// and so is an image that cannot be read.
    pub fn from_dataset(ds: &Dataset, file: &Path) -> Result<RcmData, RcmError> {
        let f = file.display();
        let camera: EndoscopeCamera = endoscope::block(&ds.header.extra, "camera")
            .map_err(|e| RcmError::Data(format!("{f}:1: header {e}")))?
            .ok_or_else(|| {
                RcmError::Data(format!(
                    "{f}:1: header field \"camera\": missing (an RCM dataset needs {{\"kind\": \"endoscope\", \"width\", \"height\", \"fx\", \"fy\", \"cx\", \"cy\", \"dist\"}})"
                ))
            })?;
        if camera.kind != "endoscope" {
            return Err(RcmError::Data(format!(
                "{f}:1: header field \"camera.kind\": expected \"endoscope\", got \"{}\"",
                camera.kind
            )));
        }
        for (name, v) in [("fx", camera.fx), ("fy", camera.fy)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(RcmError::Data(format!(
                    "{f}:1: header field \"camera.{name}\": must be a positive focal length in pixels, got {v}"
                )));
            }
        }
        let inst: InstrumentBlock = endoscope::block(&ds.header.extra, "instrument")
            .map_err(|e| RcmError::Data(format!("{f}:1: header {e}")))?
            .ok_or_else(|| {
                RcmError::Data(format!(
                    "{f}:1: header field \"instrument\": missing (needs {{\"shaft_radius_mm\": r}})"
                ))
            })?;
        if !(inst.shaft_radius_mm.is_finite() && inst.shaft_radius_mm > 0.0) {
            return Err(RcmError::Data(format!(
                "{f}:1: header field \"instrument.shaft_radius_mm\": must be > 0, got {}",
                inst.shaft_radius_mm
            )));
        }
        // Plausibility: a radius in metres fits just as well at another scale.
        if !(MIN_SHAFT_RADIUS_MM..=MAX_SHAFT_RADIUS_MM).contains(&inst.shaft_radius_mm) {
            return Err(RcmError::Data(format!(
                "{f}:1: header field \"instrument.shaft_radius_mm\": {} mm is not an instrument \
                 shaft radius ({MIN_SHAFT_RADIUS_MM} to {MAX_SHAFT_RADIUS_MM} mm): likely metres \
                 (give millimetres) or the diameter of another part",
                inst.shaft_radius_mm
            )));
        }
        // Pixel coordinates far outside any image (1e308) are corrupt values, not silhouettes.
        let px_max = MAX_PIXEL_FACTOR * (camera.width.max(camera.height) as f64).max(1.0);
        let mut obs = Vec::new();
        let (mut detected, mut refused) = (Vec::new(), Vec::new());
        for (idx, rec) in ds.records.iter().enumerate() {
            let Record::Pose(p) = rec else { continue };
            let line = idx + 2;
            let segs = endoscope::shaft_lines(&p.extra)
                .map_err(|e| RcmError::Data(format!("{f}:{line}: {e}")))?;
            let mut found = None;
            let segs = match (segs, &p.image) {
                (Some(s), _) => s,
                (None, Some(img)) => {
                    let path = file.parent().unwrap_or(Path::new(".")).join(img);
                    let im = robocal_drivers::camera::read_image_file(&path)
                        .map_err(|e| RcmError::Data(format!("{f}:{line}: field \"image\": {e}")))?;
                    match lines::detect(
                        &im.data,
                        im.width,
                        im.height,
                        &camera,
                        &lines::LineOptions::default(),
                    ) {
                        Ok(d) => {
                            let s = d.segs();
                            found = Some(d);
                            s
                        }
                        Err(why) => {
                            refused.push(format!(
                                "pose {} ({f}:{line}, image {}): {why}",
                                p.id,
                                path.display()
                            ));
                            continue;
                        }
                    }
                }
                (None, None) => continue,
            };
            if let Some(x) = segs.iter().flatten().find(|x| x.abs() > px_max) {
                return Err(RcmError::Data(format!(
                    "{f}:{line}: field \"shaft_lines\": pixel coordinate {x:e} is far outside \
                     the {}×{} image: a corrupt value",
                    camera.width, camera.height
                )));
            }
            let fl = p.flange.as_ref().ok_or_else(|| {
                RcmError::Data(format!(
                    "{f}:{line}: field \"flange\": missing (pose {} has shaft_lines but no instrument pose)",
                    p.id
                ))
            })?;
            let flange = crate::solve::laser::file_pose(&fl.p, &fl.quat).ok_or_else(|| {
                RcmError::Data(format!(
                    "{f}:{line}: field \"flange\": not finite or quaternion not unit"
                ))
            })?;
            if let Some(d) = found {
                detected.push((p.id, d));
            }
            obs.push(RcmObs {
                id: p.id,
                line,
                flange,
                segs,
            });
        }
        // Flange positions in metres: the instrument frames would span millimetres at most.
        if obs.len() >= 3 {
            let c = obs
                .iter()
                .map(|o| o.flange.translation.vector)
                .sum::<Vector3<f64>>()
                / obs.len() as f64;
            let spread = obs
                .iter()
                .map(|o| (o.flange.translation.vector - c).norm())
                .fold(0.0, f64::max);
            let far = obs
                .iter()
                .map(|o| o.flange.translation.vector.norm())
                .fold(0.0, f64::max);
            if spread < 1.0 && far < 5.0 {
                return Err(RcmError::Data(format!(
                    "{f}: field \"flange.p\": the instrument positions lie within {spread:.4} mm \
                     of each other and {far:.4} mm of the robot base: likely metres (robocal \
                     reads millimetres)"
                )));
            }
        }
        let mut data = RcmData::new(camera, inst.shaft_radius_mm, obs);
        data.detected = detected;
        data.refused = refused;
        Ok(data)
    }
}

/// Plausible instrument shaft radius (mm): a 0.2 mm radius is thinner than any endoscopic
/// instrument, 50 mm thicker.
pub const MIN_SHAFT_RADIUS_MM: f64 = 0.2;
pub const MAX_SHAFT_RADIUS_MM: f64 = 50.0;
/// Largest plausible |pixel coordinate| of a silhouette, in image sizes.
pub const MAX_PIXEL_FACTOR: f64 = 100.0;

/// Tolerance (mm) on the RMS distance of the robot's instrument axes from their common point.
pub const AXES_MEET_TOL_MM: f64 = 2.0;
/// Smallest allowed ratio of the third to the first singular value of the axis directions.
pub const COPLANAR_TOL: f64 = 1e-3;

/// The checks every RCM calibration runs first: enough poses, robot axes meeting in one point,
/// not all in one plane. Returns the RCM in the base and the axes' RMS distance from it.
pub fn check(data: &RcmData) -> Result<(Vector3<f64>, f64), RcmError> {
    if data.obs.len() < 3 {
        return Err(RcmError::TooFew {
            got: data.obs.len(),
        });
    }
    let axes: Vec<Line> = data.obs.iter().map(RcmObs::axis).collect();
    let mut m = Matrix3::zeros();
    for a in &axes {
        m += a.d * a.d.transpose();
    }
    let mut ev: Vec<f64> = m
        .symmetric_eigenvalues()
        .iter()
        .map(|x| x.max(0.0).sqrt())
        .collect();
    ev.sort_by(f64::total_cmp);
    if ev[1] < 1e-6 * ev[2] {
        return Err(RcmError::Degenerate(
            "all instrument axes are parallel: the instrument never pivoted about the trocar"
                .into(),
        ));
    }
    let (p, rms) = seed::rcm_base(&axes).ok_or_else(|| {
        RcmError::Degenerate("the instrument axes have no nearest common point".into())
    })?;
    if rms > AXES_MEET_TOL_MM {
        return Err(RcmError::Degenerate(format!(
            "the instrument axes do not meet in one point: RMS distance {rms:.2} mm from their nearest common point (tolerance {AXES_MEET_TOL_MM} mm); is the robot pivoting about a trocar, and is the flange z axis the shaft axis?"
        )));
    }
    if ev[0] < COPLANAR_TOL * ev[2] {
        return Err(RcmError::Degenerate(format!(
            "all instrument axes lie in one plane (pivoting about a single axis, σ₃/σ₁ = {:.1e}): the hand-eye rotation about that plane's normal and the RCM depth are then weakly determined; add poses pivoting in a second direction",
            ev[0] / ev[2]
        )));
    }
    Ok((p, rms))
}

/// Result of the seed's two-step pipeline.
#[derive(Debug, Clone)]
pub struct SeedOut {
    /// Camera in base.
    pub hand_eye: Isometry3<f64>,
    /// RCM in the camera (common perpendiculars of the refined axes).
    pub rcm_cam: Vector3<f64>,
    /// RMS half-length of the common perpendiculars before / after the refinement (mm).
    pub meet_rms_mm: (f64, f64),
    /// Refined, oriented camera-frame axes.
    pub lines: Vec<Line>,
}

/// The camera-frame axis of every pose (seed step 1); errors name the pose.
pub fn camera_axes(data: &RcmData) -> Result<Vec<Line>, RcmError> {
    data.obs
        .iter()
        .map(|o| {
            plucker::axis_from_boundaries(&data.k, &o.segs, data.radius)
                .map_err(|e| RcmError::BadLines(format!("pose {} (line {}): {e}", o.id, o.line)))
        })
        .collect()
}

/// The seed's pipeline: Plücker axes → RCM-constrained refinement → hand-eye.
pub fn seed_two_step(data: &RcmData) -> Result<SeedOut, RcmError> {
    let (rcm_base, _) = check(data)?;
    let measured = camera_axes(data)?;
    let (_, before) = seed::rcm_from_pairs(&measured)
        .ok_or_else(|| RcmError::Degenerate("all shaft axes in the images are parallel".into()))?;
    let (refined, _) = seed::refine(&measured)?;
    let (rcm_cam, after) = seed::rcm_from_pairs(&refined)
        .ok_or_else(|| RcmError::Degenerate("all refined axes are parallel".into()))?;
    // The visible shaft lies beyond the trocar: orient each axis towards it.
    let seen: Vec<Vector3<f64>> = data
        .obs
        .iter()
        .zip(&refined)
        .map(|(o, l)| {
            let s = &o.segs;
            let ray = data.k.ray(
                (s[0][0] + s[0][2] + s[1][0] + s[1][2]) / 4.0,
                (s[0][1] + s[0][3] + s[1][1] + s[1][3]) / 4.0,
            );
            let ray_line = Line::through(&Vector3::zeros(), &ray);
            plucker::common_perpendicular(l, &ray_line)
                .map(|(p, _)| p)
                .unwrap_or_else(|| l.foot())
        })
        .collect();
    let lines = seed::orient(&refined, &rcm_cam, &seen);
    let base: Vec<Line> = data.obs.iter().map(RcmObs::axis).collect();
    let hand_eye = seed::hand_eye(&lines, &base, &rcm_cam, &rcm_base);
    Ok(SeedOut {
        hand_eye,
        rcm_cam,
        meet_rms_mm: (before, after),
        lines,
    })
}

/// Options of [`calibrate`].
#[derive(Debug, Clone, Copy)]
pub struct RcmOptions {
    /// Bootstrap resamples (0: none).
    pub bootstrap: usize,
    /// Seed of the bootstrap.
    pub seed: u64,
}

impl Default for RcmOptions {
    fn default() -> Self {
        RcmOptions {
            bootstrap: 100,
            seed: 2,
        }
    }
}

/// Spread of a pose estimate.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct PoseStd {
    /// 1-σ of the translation (mm).
    pub xyz_mm: [f64; 3],
    /// 1-σ of a small rotation about the base axes (deg).
    pub rot_deg: [f64; 3],
}

/// Result of [`calibrate`].
#[derive(Debug, Clone)]
pub struct RcmCalibration {
    /// The seed's two-step result (start of the ML).
    pub seed: SeedOut,
    /// The ML refinement (the result).
    pub ml: ml::MlFit,
    /// Uncertainty from the LM covariance.
    pub std: PoseStd,
    /// Uncertainty from the bootstrap over poses (when asked).
    pub bootstrap: Option<PoseStd>,
    /// RCM in the base (robot axes) and the axes' RMS distance from it (mm).
    pub rcm_base: (Vector3<f64>, f64),
    /// RCM in the camera (final hand-eye applied to the base RCM).
    pub rcm_cam: Vector3<f64>,
    /// Poses used.
    pub n_poses: usize,
}

/// Largest RMS end-point distance (px) accepted for the final fit.
pub const MAX_RMS_PX: f64 = 15.0;

/// Seed two-step, then the ML refinement, covariance and bootstrap.
pub fn calibrate(data: &RcmData, opts: &RcmOptions) -> Result<RcmCalibration, RcmError> {
    let seed_out = seed_two_step(data)?;
    let axes: Vec<Line> = data.obs.iter().map(RcmObs::axis).collect();
    let segs: Vec<[[f64; 4]; 2]> = data.obs.iter().map(|o| o.segs).collect();
    let fit = ml::refine(data.k, data.radius, &axes, &segs, &seed_out.hand_eye)?;
    if fit.rms_px > MAX_RMS_PX {
        return Err(RcmError::Degenerate(format!(
            "the predicted shaft silhouettes miss the observed ones by {:.1} px RMS (limit {MAX_RMS_PX} px): check shaft_radius_mm, the intrinsics, that shaft_lines are undistorted, and that flange z is the shaft axis",
            fit.rms_px
        )));
    }
    let sd = |i: usize| fit.cov[(i, i)].max(0.0).sqrt();
    let std = PoseStd {
        rot_deg: [sd(0).to_degrees(), sd(1).to_degrees(), sd(2).to_degrees()],
        xyz_mm: [sd(3), sd(4), sd(5)],
    };
    let bootstrap = (opts.bootstrap >= 2).then(|| {
        let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
        let n = axes.len();
        let mut dts = Vec::new();
        let mut drs = Vec::new();
        for _ in 0..opts.bootstrap {
            let idx: Vec<usize> = (0..n).map(|_| rng.random_range(0..n)).collect();
            let a: Vec<Line> = idx.iter().map(|&i| axes[i]).collect();
            let s: Vec<[[f64; 4]; 2]> = idx.iter().map(|&i| segs[i]).collect();
            if let Ok(f) = ml::refine(data.k, data.radius, &a, &s, &fit.pose) {
                dts.push(f.pose.translation.vector - fit.pose.translation.vector);
                drs.push((f.pose.rotation * fit.pose.rotation.inverse()).scaled_axis());
            }
        }
        let sdv = |v: &[Vector3<f64>], k: usize| {
            let xs: Vec<f64> = v.iter().map(|x| x[k]).collect();
            crate::solve::stats::std_dev(&xs)
        };
        PoseStd {
            xyz_mm: [sdv(&dts, 0), sdv(&dts, 1), sdv(&dts, 2)],
            rot_deg: [
                sdv(&drs, 0).to_degrees(),
                sdv(&drs, 1).to_degrees(),
                sdv(&drs, 2).to_degrees(),
            ],
        }
    });
    let (rcm_b, rms) = check(data)?;
    let rcm_cam = fit.pose.inverse() * nalgebra::Point3::from(rcm_b);
    Ok(RcmCalibration {
        seed: seed_out,
        ml: fit,
        std,
        bootstrap,
        rcm_base: (rcm_b, rms),
        rcm_cam: rcm_cam.coords,
        n_poses: data.obs.len(),
    })
}

/// Translation (mm) and rotation (deg) error between two poses.
pub fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    (
        (a.translation.vector - b.translation.vector).norm(),
        a.rotation.angle_to(&b.rotation).to_degrees(),
    )
}
