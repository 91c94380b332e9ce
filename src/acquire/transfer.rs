//! Safe transfers: how the arm gets from wherever it is to the next planned pose.
//!
//! The straight joint move is used when the safety check passes along it (the normal case,
//! consecutive planned poses). When it does not — after a (re)start the arm is wherever it
//! was left, after a recovery it is somewhere on a path — the move goes through one or two
//! **safe postures** (the plan's own poses that pass the safety check, so known to be inside
//! the envelope and above the table) such that every leg passes the check. The check is
//! [`robocal_drivers::safety::check_move`], the pure function the arm's safety wrappers run
//! on every move, with the same limits and arm geometry: a transfer the planner accepts is
//! one the wrappers accept.
//!
//! A pose is given up for good only when the pose itself is unsafe
//! ([`NoTransfer::UnsafeTarget`]); when no path is found ([`NoTransfer::NoPath`]) the pose is
//! skipped for a *transient* reason (it depends on where the arm was).
use robocal_drivers::safety::{check_move, Violation};

use super::TransferSafety;

/// Why no transfer was planned.
#[derive(Debug, Clone, PartialEq)]
pub enum NoTransfer {
    /// The target itself breaks a limit (joint limit, envelope, table).
    UnsafeTarget(Violation),
    /// The arm is now at a posture that breaks a limit: no move out of it passes the wrappers.
    UnsafeStart(Violation),
    /// Neither the straight move nor one through one or two safe postures passes the check.
    NoPath,
}

/// Joint-space distance used to rank transfers (rad, largest joint change: the time of a
/// move with a per-joint speed cap).
fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// Most pair checks tried for a two-posture transfer.
const MAX_PAIR_CHECKS: usize = 4000;

impl TransferSafety {
    fn ok(&self, from: Option<&[f64]>, to: &[f64]) -> Result<(), Violation> {
        check_move(&self.limits, self.geometry.as_deref(), from, to)
    }

    /// The postures of `candidates` that are safe to stand at (a move may end there).
    pub fn safe_postures(&self, candidates: &[Vec<f64>]) -> Vec<Vec<f64>> {
        candidates
            .iter()
            .filter(|q| self.ok(None, q).is_ok())
            .cloned()
            .collect()
    }

    /// The legs of a safe transfer `from → to` (rad): `[to]` when the straight move passes,
    /// else one or two of `postures` (which must be [`safe_postures`](Self::safe_postures))
    /// followed by `to`, shortest first. Every consecutive pair of `from`, legs… passes the
    /// safety check.
    pub fn plan(
        &self,
        postures: &[Vec<f64>],
        from: &[f64],
        to: &[f64],
    ) -> Result<Vec<Vec<f64>>, NoTransfer> {
        self.ok(None, to).map_err(NoTransfer::UnsafeTarget)?;
        if self.ok(Some(from), to).is_ok() {
            return Ok(vec![to.to_vec()]);
        }
        self.ok(None, from).map_err(NoTransfer::UnsafeStart)?;
        // One posture: rank by total distance, check both legs lazily.
        let n = postures.len();
        let mut order: Vec<usize> = (0..n).collect();
        let total = |i: usize| dist(from, &postures[i]) + dist(&postures[i], to);
        order.sort_by(|&a, &b| total(a).total_cmp(&total(b)));
        let mut reach_from = vec![None::<bool>; n];
        let mut reach_to = vec![None::<bool>; n];
        for &i in &order {
            let w = &postures[i];
            let a = self.ok(Some(from), w).is_ok();
            reach_from[i] = Some(a);
            if !a {
                continue;
            }
            let b = self.ok(Some(w), to).is_ok();
            reach_to[i] = Some(b);
            if b {
                return Ok(vec![w.clone(), to.to_vec()]);
            }
        }
        // Two postures: a reachable from `from`, b reaching `to`, a → b safe.
        let firsts: Vec<usize> = (0..n).filter(|&i| reach_from[i] == Some(true)).collect();
        if firsts.is_empty() {
            return Err(NoTransfer::NoPath);
        }
        let lasts: Vec<usize> = (0..n)
            .filter(|&i| match reach_to[i] {
                Some(b) => b,
                None => self.ok(Some(&postures[i]), to).is_ok(),
            })
            .collect();
        let mut pairs: Vec<(f64, usize, usize)> = Vec::with_capacity(firsts.len() * lasts.len());
        for &a in &firsts {
            for &b in &lasts {
                if a != b {
                    let c = dist(from, &postures[a])
                        + dist(&postures[a], &postures[b])
                        + dist(&postures[b], to);
                    pairs.push((c, a, b));
                }
            }
        }
        pairs.sort_by(|x, y| x.0.total_cmp(&y.0));
        for &(_, a, b) in pairs.iter().take(MAX_PAIR_CHECKS) {
            if self.ok(Some(&postures[a]), &postures[b]).is_ok() {
                return Ok(vec![postures[a].clone(), postures[b].clone(), to.to_vec()]);
            }
        }
        Err(NoTransfer::NoPath)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use robocal_drivers::safety::{ArmGeometry, Envelope, SafetyLimits};
    use std::sync::Arc;

    /// A 2-joint "arm" whose check point is (q1, q2) in mm ×100, in a box with a forbidden
    /// square |q1|, |q2| < 1 in the middle (with `wall`: the strip |q1| < 1, q2 < 2.5): the
    /// straight move across it is refused, a detour is not.
    fn safety_with(wall: bool) -> TransferSafety {
        let limits = SafetyLimits {
            joint_lower: vec![-10.0, -10.0],
            joint_upper: vec![10.0, 10.0],
            max_vel: 1.0,
            max_acc: 1.0,
            envelope: Some(Envelope::Box {
                min: [-500.0, -500.0, -1.0],
                max: [500.0, 500.0, 1.0],
            }),
            table: None,
            path_step: 0.01,
        };
        // Points outside the envelope (z = 5) when inside the square |x|,|y| < 1.
        let geom: Arc<dyn ArmGeometry> = Arc::new(move |q: &[f64]| {
            let top = if wall { 2.5 } else { 1.0 };
            let bottom = if wall { f64::NEG_INFINITY } else { -1.0 };
            let z = if q[0].abs() < 1.0 && q[1] < top && q[1] > bottom {
                5.0
            } else {
                0.0
            };
            vec![Point3::new(q[0] * 100.0, q[1] * 100.0, z)]
        });
        TransferSafety {
            limits: Arc::new(limits),
            geometry: Some(geom),
        }
    }

    fn safety() -> TransferSafety {
        safety_with(false)
    }

    fn check_legs(s: &TransferSafety, from: &[f64], legs: &[Vec<f64>]) {
        let mut at = from.to_vec();
        for l in legs {
            check_move(&s.limits, s.geometry.as_deref(), Some(&at), l).unwrap();
            at = l.clone();
        }
    }

    #[test]
    fn straight_move_when_safe_detour_when_not() {
        let s = safety();
        let postures = s.safe_postures(&[
            vec![0.0, 0.0], // unsafe: dropped
            vec![-2.0, 2.0],
            vec![2.0, 2.0],
            vec![2.0, -2.0],
        ]);
        assert_eq!(postures.len(), 3);
        // Straight.
        let legs = s.plan(&postures, &[-2.0, -2.0], &[-2.0, 2.0]).unwrap();
        assert_eq!(legs, vec![vec![-2.0, 2.0]]);
        // Across the forbidden square: via one posture.
        let legs = s.plan(&postures, &[-2.0, -2.0], &[2.0, 2.0]).unwrap();
        assert_eq!(legs.len(), 2);
        check_legs(&s, &[-2.0, -2.0], &legs);
        // A wall: over it takes two postures.
        let s = safety_with(true);
        let over = s.safe_postures(&[vec![-3.0, 3.0], vec![3.0, 3.0]]);
        assert!(s.plan(&over[..1], &[-3.0, 0.0], &[3.0, 0.0]).is_err());
        let legs = s.plan(&over, &[-3.0, 0.0], &[3.0, 0.0]).unwrap();
        assert_eq!(legs.len(), 3, "{legs:?}");
        check_legs(&s, &[-3.0, 0.0], &legs);
    }

    #[test]
    fn unsafe_target_start_and_no_path_are_told_apart() {
        let s = safety();
        let p = s.safe_postures(&[vec![2.0, 2.0]]);
        assert!(matches!(
            s.plan(&p, &[-2.0, -2.0], &[0.5, 0.5]),
            Err(NoTransfer::UnsafeTarget(_))
        ));
        assert!(matches!(
            s.plan(&p, &[-2.0, -2.0], &[20.0, 0.0]),
            Err(NoTransfer::UnsafeTarget(_))
        ));
        assert!(matches!(
            s.plan(&p, &[0.0, 0.0], &[2.0, -2.0]),
            Err(NoTransfer::UnsafeStart(_))
        ));
        assert_eq!(
            s.plan(&[], &[-2.0, -2.0], &[2.0, 2.0]),
            Err(NoTransfer::NoPath)
        );
    }
}
