//! RCM-constrained pose generator: instrument poses pivoting about a trocar point
//! (two pivot angles and an insertion depth), each checked to be reachable by the robot
//! holding the instrument (closed-form IK within the joint limits) when a model is given.
//!
//! The instrument frame (what a dataset's `flange` holds for an RCM cell) has its origin at
//! the tip on the shaft axis and z along the shaft towards the tip; the robot's flange sits
//! `shaft_length_mm` behind the tip on the same axis.
use nalgebra::{Isometry3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::model::KinematicModel;

/// What to generate.
#[derive(Debug, Clone, PartialEq)]
pub struct RcmPlanSpec {
    /// The trocar (RCM) in the base (mm).
    pub trocar_mm: [f64; 3],
    /// Nominal insertion direction (into the body).
    pub insertion_dir: [f64; 3],
    /// Direction the instrument's x axis should face (e.g. towards the camera).
    pub x_hint: [f64; 3],
    /// Pivot range: each of the two pivot angles uniform in `±pivot_deg`.
    pub pivot_deg: f64,
    /// Insertion depth range of the tip beyond the trocar (mm).
    pub insertion_mm: [f64; 2],
    /// Roll about the shaft uniform in `±roll_deg`.
    pub roll_deg: f64,
    /// Number of poses.
    pub count: usize,
    /// Random seed.
    pub seed: u64,
    /// Tip-to-flange distance along the shaft (mm), for the reachability check.
    pub shaft_length_mm: f64,
}

/// One generated pose.
#[derive(Debug, Clone, PartialEq)]
pub struct RcmPose {
    /// Instrument frame in the base.
    pub instrument: Isometry3<f64>,
    /// The two pivot angles (deg).
    pub pivot_deg: [f64; 2],
    /// Tip depth beyond the trocar (mm).
    pub insertion_mm: f64,
    /// Joint angles (rad) of a reachable branch, when a model was given.
    pub q: Option<Vec<f64>>,
}

/// Errors of the generator.
#[derive(Debug, thiserror::Error)]
pub enum RcmPlanError {
    /// A bad spec value.
    #[error("RCM plan: {0}")]
    Spec(String),
    /// Too few reachable poses.
    #[error("RCM plan: only {got} of {want} poses are reachable by the robot within its joint limits after {tries} tries; move the trocar or narrow the pivot range")]
    Unreachable {
        /// Reachable.
        got: usize,
        /// Asked.
        want: usize,
        /// Tries.
        tries: usize,
    },
}

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

/// The instrument pose for pivot angles `(a, b)` (rad, about the nominal frame's x and y),
/// depth `depth` and roll `roll` (rad).
pub fn rcm_pose(spec: &RcmPlanSpec, a: f64, b: f64, depth: f64, roll: f64) -> Isometry3<f64> {
    let z0 = v3(spec.insertion_dir).normalize();
    let hint = v3(spec.x_hint);
    let x0 = (hint - z0 * hint.dot(&z0)).normalize();
    let y0 = z0.cross(&x0);
    let piv = Rotation3::from_axis_angle(&Unit::new_normalize(x0), a)
        * Rotation3::from_axis_angle(&Unit::new_normalize(y0), b);
    let z = piv * z0;
    let x = (hint - z * hint.dot(&z)).normalize();
    let x = Rotation3::from_axis_angle(&Unit::new_normalize(z), roll) * x;
    let r = Rotation3::from_basis_unchecked(&[x, z.cross(&x), z]);
    Isometry3::from_parts(
        Translation3::from(v3(spec.trocar_mm) + z * depth),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// The `[rcm]` table of a plan spec (`plans/seed002-rcm.toml`): strict TOML, mm / degrees.
/// The spec's `[tool]` is the instrument's tip frame in the flange (`xyz = [0, 0, L]`: the
/// tip `L` mm ahead of the flange on the shaft axis).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RcmSpecTable {
    /// Number of poses.
    pub points: usize,
    /// The trocar (RCM) in the base (mm).
    pub trocar_mm: [f64; 3],
    /// Nominal insertion direction (into the body) in the base.
    pub insertion_dir: [f64; 3],
    /// Direction the instrument's x axis should face (e.g. towards the endoscope).
    pub x_hint: [f64; 3],
    /// Each of the two pivot angles uniform in `±pivot_deg`.
    pub pivot_deg: f64,
    /// Tip depth beyond the trocar `[min, max]` (mm).
    pub insertion_mm: [f64; 2],
    /// Roll about the shaft uniform in `±roll_deg`.
    #[serde(default)]
    pub roll_deg: f64,
}

impl RcmSpecTable {
    /// As the generator's spec (`shaft_length_mm`: tip-to-flange distance, for reachability).
    pub fn to_spec(&self, seed: u64, shaft_length_mm: f64) -> RcmPlanSpec {
        RcmPlanSpec {
            trocar_mm: self.trocar_mm,
            insertion_dir: self.insertion_dir,
            x_hint: self.x_hint,
            pivot_deg: self.pivot_deg,
            insertion_mm: self.insertion_mm,
            roll_deg: self.roll_deg,
            count: self.points,
            seed,
            shaft_length_mm,
        }
    }
}

impl RcmPlanSpec {
    /// Checks the ranges; the error says which value and why.
    pub fn check(&self) -> Result<(), RcmPlanError> {
        let z0 = v3(self.insertion_dir);
        if z0.norm().is_nan() || z0.norm() <= 1e-9 {
            return Err(RcmPlanError::Spec(
                "insertion_dir must be a non-zero vector".into(),
            ));
        }
        let h = v3(self.x_hint);
        if h.cross(&z0).norm() < 1e-6 * h.norm() * z0.norm() || h.norm() < 1e-9 {
            return Err(RcmPlanError::Spec(
                "x_hint must not be parallel to insertion_dir".into(),
            ));
        }
        if !(self.pivot_deg >= 0.0 && self.pivot_deg < 80.0) {
            return Err(RcmPlanError::Spec(format!(
                "pivot_deg must be in [0, 80), got {}",
                self.pivot_deg
            )));
        }
        let [d0, d1] = self.insertion_mm;
        if !(d0 > 0.0 && d1 >= d0) {
            return Err(RcmPlanError::Spec(format!(
                "insertion_mm must be [min, max] with 0 < min ≤ max, got [{d0}, {d1}]"
            )));
        }
        Ok(())
    }
}

/// `spec.count` poses drawn from the ranges without a reachability check (the planner checks
/// each against the robot); the spec must pass [`RcmPlanSpec::check`].
pub fn draw(spec: &RcmPlanSpec) -> Vec<RcmPose> {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    (0..spec.count)
        .map(|_| {
            let (inst, a, b, depth, _) = draw_one(spec, &mut rng);
            RcmPose {
                instrument: inst,
                pivot_deg: [a.to_degrees(), b.to_degrees()],
                insertion_mm: depth,
                q: None,
            }
        })
        .collect()
}

fn draw_one(spec: &RcmPlanSpec, rng: &mut ChaCha8Rng) -> (Isometry3<f64>, f64, f64, f64, f64) {
    let p = spec.pivot_deg.to_radians();
    let [d0, d1] = spec.insertion_mm;
    let u = |rng: &mut ChaCha8Rng, a: f64| {
        if a > 0.0 {
            rng.random_range(-a..=a)
        } else {
            0.0
        }
    };
    let a = u(rng, p);
    let b = u(rng, p);
    let depth = if d1 > d0 {
        rng.random_range(d0..=d1)
    } else {
        d0
    };
    let roll = u(rng, spec.roll_deg.to_radians());
    (rcm_pose(spec, a, b, depth, roll), a, b, depth, roll)
}

/// Generate `spec.count` poses; with `model`, only poses whose flange is reachable within the
/// joint limits are kept.
pub fn generate(
    spec: &RcmPlanSpec,
    model: Option<&KinematicModel>,
) -> Result<Vec<RcmPose>, RcmPlanError> {
    spec.check()?;
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let mut out = Vec::new();
    let tries = 50 * spec.count.max(1);
    let tool = Isometry3::translation(0.0, 0.0, spec.shaft_length_mm);
    for _ in 0..tries {
        if out.len() == spec.count {
            break;
        }
        let (inst, a, b, depth, _) = draw_one(spec, &mut rng);
        let q = match model {
            None => None,
            Some(m) => {
                let flange = inst * tool.inverse();
                match crate::model::ik::solve(m, &flange) {
                    Ok(sols) => match sols.into_iter().find(|s| s.within_limits) {
                        Some(s) => Some(s.q),
                        None => continue,
                    },
                    Err(_) => continue,
                }
            }
        };
        out.push(RcmPose {
            instrument: inst,
            pivot_deg: [a.to_degrees(), b.to_degrees()],
            insertion_mm: depth,
            q,
        });
    }
    if out.len() < spec.count {
        return Err(RcmPlanError::Unreachable {
            got: out.len(),
            want: spec.count,
            tries,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> RcmPlanSpec {
        RcmPlanSpec {
            trocar_mm: [450.0, 0.0, 250.0],
            insertion_dir: [0.0, 0.0, -1.0],
            x_hint: [0.0, 1.0, 0.0],
            pivot_deg: 25.0,
            insertion_mm: [50.0, 150.0],
            roll_deg: 10.0,
            count: 20,
            seed: 1,
            shaft_length_mm: 350.0,
        }
    }

    #[test]
    fn poses_pivot_about_the_trocar_within_the_ranges() {
        let s = spec();
        let m = KinematicModel::preset("ur5e").unwrap();
        let poses = generate(&s, Some(&m)).unwrap();
        assert_eq!(poses.len(), 20);
        let c = v3(s.trocar_mm);
        for p in &poses {
            let z = p.instrument.rotation * Vector3::z();
            let t = p.instrument.translation.vector;
            // The axis passes through the trocar.
            assert!((t - c).cross(&z).norm() < 1e-9);
            let depth = (t - c).dot(&z);
            assert!((50.0..=150.0).contains(&depth));
            let tilt = z.angle(&Vector3::new(0.0, 0.0, -1.0)).to_degrees();
            assert!(tilt <= 25.0 * 2f64.sqrt() + 1e-9);
            assert!(p.q.is_some());
        }
        assert!(generate(
            &RcmPlanSpec {
                x_hint: [0.0, 0.0, 1.0],
                ..s.clone()
            },
            None
        )
        .is_err());
        let far = RcmPlanSpec {
            trocar_mm: [3000.0, 0.0, 0.0],
            count: 2,
            ..s
        };
        assert!(matches!(
            generate(&far, Some(&m)),
            Err(RcmPlanError::Unreachable { .. })
        ));
    }
}
