//! How the `verify` stage approaches each target, for the direction-dependent effects of the
//! deployed calibration (backlash / lost motion).
//!
//! A joint with backlash sits half its lost motion behind the direction it last moved in, so
//! the calibrated model must know that direction for every commanded target. The direction is
//! the sign of the *commanded* move (corrected joints minus the previous corrected joints, not
//! the planned ones: when two targets share a joint angle, e.g. two IK branches of one point,
//! the correction alone decides the direction). When a backlash joint moves so little that
//! the servo error could reverse its direction, the target is approached the way real cells
//! do it: first a back-off pose a fixed step short of the target on every backlash joint, then
//! the target, so each backlash joint arrives from a known side.
use crate::dataset::{CalEffect, Dataset};

/// Step (deg) by which an approach pose stands short of its target on each backlash joint:
/// far above any servo error and lost motion, small enough to stay inside the checked cell.
pub const BACKOFF_DEG: f64 = 0.2;
/// Smallest move, in multiples of the joint's measured servo error (RMS of `q − q_cmd`), whose
/// direction the servo error cannot reverse.
pub const SERVO_SIGMAS: f64 = 6.0;
/// Smallest determinate move (deg) when no servo error is measured (records without `q_cmd`).
pub const DEFAULT_MIN_MOVE_DEG: f64 = 0.005;

/// The backlash joints of a calibration and the smallest move whose direction is certain.
#[derive(Debug, Clone, PartialEq)]
pub struct Approach {
    /// 0-based joints with a direction-dependent effect.
    pub joints: Vec<usize>,
    /// Per joint of the arm: the smallest determinate move (rad).
    pub min_move: Vec<f64>,
}

impl Approach {
    /// The backlash joints of `effects` and, per joint, the determinate move from the servo
    /// error the records of `ds` show (`q` measured against `q_cmd` commanded).
    pub fn new(effects: &[CalEffect], ds: &Dataset, dof: usize) -> Self {
        let mut joints: Vec<usize> = effects
            .iter()
            .filter(|e| e.kind == "backlash")
            .filter_map(|e| e.joint?.checked_sub(1))
            .filter(|&j| j < dof)
            .collect();
        joints.sort_unstable();
        joints.dedup();
        let mut sum = vec![0.0; dof];
        let mut n = 0usize;
        for r in ds.poses() {
            let (Some(q), Some(c)) = (&r.q, &r.q_cmd) else {
                continue;
            };
            if q.len() != dof || c.len() != dof || q.iter().chain(c).any(|x| !x.is_finite()) {
                continue;
            }
            for (s, (a, b)) in sum.iter_mut().zip(q.iter().zip(c)) {
                *s += (a - b).powi(2);
            }
            n += 1;
        }
        let min_move = sum
            .iter()
            .map(|s| {
                let deg = if n >= 3 {
                    (SERVO_SIGMAS * (s / n as f64).sqrt()).max(1e-4)
                } else {
                    DEFAULT_MIN_MOVE_DEG
                };
                deg.to_radians()
            })
            .collect();
        Self { joints, min_move }
    }

    /// Approach direction of every joint moving from `prev` to `q`: the sign of the move, or
    /// `carried` (the direction the joint last moved in) where the move is below the
    /// determinate size.
    pub fn signs(&self, prev: &[f64], q: &[f64], carried: &[f64]) -> Vec<f64> {
        carried
            .iter()
            .enumerate()
            .map(|(j, &c)| match (q.get(j), prev.get(j)) {
                (Some(a), Some(b)) if (a - b).abs() >= self.min_move[j] => (a - b).signum(),
                _ => c,
            })
            .collect()
    }

    /// Whether some backlash joint moves too little from `prev` to `q` for its direction to
    /// be certain.
    pub fn undetermined(&self, prev: &[f64], q: &[f64]) -> bool {
        self.joints.iter().any(|&j| match (q.get(j), prev.get(j)) {
            (Some(a), Some(b)) => (a - b).abs() < self.min_move[j],
            _ => true,
        })
    }

    /// The back-off pose of target `q`: each backlash joint [`BACKOFF_DEG`] short of its
    /// target against its approach direction in `signs` (reversed where that would leave the
    /// joint's `limits`), other joints at the target. Returns the pose and the directions the
    /// target will then be reached from.
    pub fn backoff(&self, q: &[f64], signs: &[f64], limits: &[(f64, f64)]) -> (Vec<f64>, Vec<f64>) {
        let step = BACKOFF_DEG.to_radians();
        let mut pose = q.to_vec();
        let mut dir = signs.to_vec();
        for &j in &self.joints {
            let s = if dir[j] == 0.0 { 1.0 } else { dir[j] };
            let inside = |x: f64| limits.get(j).is_none_or(|(lo, hi)| x >= *lo && x <= *hi);
            let s = if inside(q[j] - s * step) { s } else { -s };
            pose[j] = q[j] - s * step;
            dir[j] = s;
        }
        (pose, dir)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn approach() -> Approach {
        Approach {
            joints: vec![0],
            min_move: vec![0.01f64.to_radians(); 2],
        }
    }

    #[test]
    fn the_direction_is_the_commanded_moves_and_carried_when_too_small() {
        let a = approach();
        let r = |d: f64| d.to_radians();
        // Joint 1 moves −0.02° (determinate), joint 2 0.001° (carried +1).
        let s = a.signs(&[r(10.0), r(5.0)], &[r(9.98), r(5.001)], &[1.0, 1.0]);
        assert_eq!(s, vec![-1.0, 1.0]);
        assert!(!a.undetermined(&[r(10.0), r(5.0)], &[r(9.98), r(5.001)]));
        // Joint 1 (backlash) moving 0.005° is undetermined; joint 2 (no backlash) is not asked.
        assert!(a.undetermined(&[r(10.0), r(5.0)], &[r(10.005), r(9.0)]));
    }

    #[test]
    fn a_backoff_stands_short_of_the_target_inside_the_limits() {
        let a = approach();
        let lim = [(-(170f64.to_radians()), 170f64.to_radians()); 2];
        let q = [20f64.to_radians(), 1.0];
        let (p, d) = a.backoff(&q, &[-1.0, 1.0], &lim);
        assert!((p[0] - (20.0 + BACKOFF_DEG).to_radians()).abs() < 1e-12);
        assert_eq!(p[1], 1.0);
        assert_eq!(d, vec![-1.0, 1.0]);
        // At the upper limit the back-off reverses: the target is reached moving down.
        let q = [170f64.to_radians(), 1.0];
        let (p, d) = a.backoff(&q, &[-1.0, 1.0], &lim);
        assert!(p[0] < q[0]);
        assert_eq!(d[0], 1.0);
        assert!(!a.undetermined(&p, &q));
    }
}
