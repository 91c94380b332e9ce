//! Where the held-out poses lie: the training error near them.
//!
//! The train / held-out gap compares the held-out RMS with the RMS over *all* training poses.
//! When the held-out poses come from a part of the workspace where the model is less accurate
//! (a time-blocked split that ends in another region, a validation set drawn elsewhere), the
//! gap is large although nothing was learned by heart; when they come from an easy part, the
//! gap is small although the effects may have learned the training poses. Series A of the
//! real UR10 shows the first: its time-blocked held-out poses are 17 % worse than the training
//! RMS, but only 6 % worse than the training poses nearest them. Series B shows the second
//! (14 % plain, 42 % against the nearest training poses).
//!
//! [`Neighbours::rms`] weighs the training residual by where the held-out poses are: for every
//! held-out pose, the mean squared 3-D error of the [`NEIGHBOURS`] training poses nearest it in
//! joint space, averaged over the held-out poses. The held-out RMS against it is the gap the
//! fit itself makes; the geometric fit's own figure says how much of that the effects do not
//! cause (the robot or the setup changed, or an error varies faster than the poses sample it),
//! and the distance from a held-out pose to its nearest training pose, against the training
//! poses' own spacing, says whether the model extrapolates there ([`NearHeldout::sentence`]).
use rayon::prelude::*;

use crate::solve::obs::PoseObs;

/// Training poses averaged around every held-out pose.
pub const NEIGHBOURS: usize = 5;

/// Held-out poses whose nearest training pose is more than this many times the training
/// poses' own spacing away (medians) lie away from the training poses.
pub const SPACING_RATIO: f64 = 1.5;

/// The training RMS where the held-out poses are, for the geometric fit and the final model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NearHeldout {
    /// Training poses averaged around every held-out pose.
    pub neighbours: usize,
    /// The geometric fit's training RMS near the held-out poses (mm).
    pub geometric_mm: f64,
    /// The final model's training RMS near the held-out poses (mm).
    pub final_mm: f64,
    /// Median over the held-out poses of the distance to the nearest training pose in joint
    /// space (deg, Euclidean over the joints).
    pub heldout_spacing_deg: f64,
    /// Median over the training poses of the distance to the nearest other training pose
    /// (deg): how densely the training poses cover their own region.
    pub train_spacing_deg: f64,
}

/// The `k` training poses nearest every held-out pose in joint space (Euclidean over the
/// recorded joint angles), found once and used for every model.
#[derive(Debug, Clone)]
pub struct Neighbours {
    idx: Vec<Vec<usize>>,
    n_train: usize,
    /// Median distance from a held-out pose to its nearest training pose (rad).
    pub heldout_spacing: f64,
    /// Median distance from a training pose to its nearest other training pose (rad; at
    /// most [`SPACING_SAMPLE`] training poses, evenly spread over the list, are asked).
    pub train_spacing: f64,
}

/// Training poses whose nearest neighbour is sought for [`Neighbours::train_spacing`].
pub const SPACING_SAMPLE: usize = 2000;

fn dist2(a: &PoseObs, b: &PoseObs) -> f64 {
    a.ctx
        .q
        .iter()
        .zip(&b.ctx.q)
        .map(|(x, y)| (x - y).powi(2))
        .sum()
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.len() / 2;
    *v.select_nth_unstable_by(m, f64::total_cmp).1
}

impl Neighbours {
    /// None without held-out poses or with fewer than `k` training poses.
    pub fn new(train: &[PoseObs], held: &[PoseObs], k: usize) -> Option<Neighbours> {
        if held.is_empty() || k == 0 || train.len() < k {
            return None;
        }
        let (idx, nearest): (Vec<Vec<usize>>, Vec<f64>) = held
            .par_iter()
            .map(|h| {
                let mut d: Vec<(f64, usize)> = train
                    .iter()
                    .enumerate()
                    .map(|(i, t)| (dist2(t, h), i))
                    .collect();
                if k < d.len() {
                    d.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0));
                }
                let nearest = d[..k].iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
                (d[..k].iter().map(|&(_, i)| i).collect(), nearest.sqrt())
            })
            .unzip();
        let step = train.len().div_ceil(SPACING_SAMPLE).max(1);
        let own: Vec<f64> = (0..train.len())
            .step_by(step)
            .collect::<Vec<_>>()
            .par_iter()
            .map(|&i| {
                train
                    .iter()
                    .enumerate()
                    .filter(|&(j, _)| j != i)
                    .map(|(_, t)| dist2(t, &train[i]))
                    .fold(f64::INFINITY, f64::min)
                    .sqrt()
            })
            .collect();
        Some(Neighbours {
            idx,
            n_train: train.len(),
            heldout_spacing: median(nearest),
            train_spacing: median(own),
        })
    }

    /// The RMS over the held-out poses of the root-mean-square 3-D error of each one's
    /// neighbours (`train_err2`: squared error per training pose, the order of the training
    /// poses). None when `train_err2` does not match or a value is not finite.
    pub fn rms(&self, train_err2: &[f64]) -> Option<f64> {
        if train_err2.len() != self.n_train {
            return None;
        }
        let sum: f64 = self
            .idx
            .iter()
            .map(|n| n.iter().map(|&i| train_err2[i]).sum::<f64>() / n.len() as f64)
            .sum();
        let v = (sum / self.idx.len() as f64).sqrt();
        v.is_finite().then_some(v)
    }
}

/// Squared 3-D error per pose of a stacked residual (x, y, z per pose).
pub fn per_pose_err2(r: &nalgebra::DVector<f64>) -> Vec<f64> {
    r.as_slice()
        .chunks(3)
        .map(|c| c.iter().map(|v| v * v).sum())
        .collect()
}

impl NearHeldout {
    /// The sentence on the gap that follows an overfitting warning: whether the held-out
    /// poses lie where the model is weaker, whether the robot or the setup changed between
    /// them (the geometric fit sees it as well), or whether the effects learned the training
    /// poses. `held_*`: the held-out RMS of the geometric fit and the final model.
    pub fn sentence(&self, held_geometric: f64, held_final: f64, limit: f64) -> String {
        let gap = held_final / self.final_mm - 1.0;
        let gap_geo = held_geometric / self.geometric_mm - 1.0;
        let near = format!(
            "the {} training poses nearest each held-out pose (in joint space) have RMS {:.4} mm with every effect and {:.4} mm with the geometric fit alone",
            self.neighbours, self.final_mm, self.geometric_mm
        );
        let apart = self.heldout_spacing_deg > SPACING_RATIO * self.train_spacing_deg;
        if gap < limit {
            format!(
                "where the held-out poses are: {near}; the held-out RMS {held_final:.4} mm is {:+.0} % from them, within the {:.0} % limit: the final model predicts the held-out poses about as well as the training poses beside them, which lie where it is less accurate than on average",
                100.0 * gap,
                100.0 * limit
            )
        } else if apart {
            format!(
                "where the held-out poses are: {near}; the held-out poses are {:.0} % worse than them with every effect and {:.0} % with the geometric fit alone, and they lie away from the training poses (a held-out pose's nearest training pose is {:.1}° away, median, against {:.1}° between neighbouring training poses): the model extrapolates there; trust the held-out figure, and add training poses where the held-out ones are",
                100.0 * gap,
                100.0 * gap_geo,
                self.heldout_spacing_deg,
                self.train_spacing_deg
            )
        } else if gap_geo >= limit {
            format!(
                "where the held-out poses are: {near}; the held-out poses are {:.0} % worse than them with every effect and {:.0} % with the geometric fit alone: the training poses do not show what differs at the held-out ones (the robot or the setup changed between them, or an error varies over the workspace faster than the poses sample it; the geometric fit sees it too), so part of the gap is not the effects; trust the held-out figure",
                100.0 * gap,
                100.0 * gap_geo
            )
        } else {
            format!(
                "where the held-out poses are: {near}; the held-out poses are {:.0} % worse than them with every effect but only {:.0} % with the geometric fit alone: the effects fit the training poses better than they predict the held-out poses beside them; trust the held-out figure",
                100.0 * gap,
                100.0 * gap_geo
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    fn pose(id: u64, q0: f64) -> PoseObs {
        PoseObs::at(id, id as f64, vec![q0, 0.0, 0.0], Point3::origin())
    }

    #[test]
    fn the_training_error_is_taken_where_the_heldout_poses_are() {
        // Training error 0.1 mm on q0 < 0 and 0.3 mm on q0 > 0; held-out poses all at q0 > 0.
        let train: Vec<PoseObs> = (0..200)
            .map(|i| pose(i, -1.0 + 2.0 * i as f64 / 199.0))
            .collect();
        let err2: Vec<f64> = train
            .iter()
            .map(|o| if o.ctx.q[0] < 0.0 { 0.01 } else { 0.09 })
            .collect();
        let held: Vec<PoseObs> = (0..20)
            .map(|i| pose(1000 + i, 0.2 + 0.03 * i as f64))
            .collect();
        let nb = Neighbours::new(&train, &held, NEIGHBOURS).unwrap();
        let near = nb.rms(&err2).unwrap();
        assert!((near - 0.3).abs() < 1e-12, "{near}");
        // Training poses 2/199 rad apart; the held-out ones between them, or on one.
        assert!(
            (nb.train_spacing - 2.0 / 199.0).abs() < 1e-12,
            "{}",
            nb.train_spacing
        );
        assert!(
            nb.heldout_spacing <= 1.0 / 199.0 + 1e-12,
            "{}",
            nb.heldout_spacing
        );
        let all = (err2.iter().sum::<f64>() / err2.len() as f64).sqrt();
        assert!(all < 0.25, "{all}");
        // Held-out on the other side: 0.1.
        let held: Vec<PoseObs> = (0..20)
            .map(|i| pose(1000 + i, -0.8 + 0.03 * i as f64))
            .collect();
        let near = Neighbours::new(&train, &held, NEIGHBOURS)
            .and_then(|n| n.rms(&err2))
            .unwrap();
        assert!((near - 0.1).abs() < 1e-12, "{near}");
        // Too few training poses, or none held out: no figure.
        assert!(Neighbours::new(&train[..3], &held, NEIGHBOURS).is_none());
        assert!(Neighbours::new(&train, &[], NEIGHBOURS).is_none());
    }

    #[test]
    fn the_sentence_tells_the_region_the_drift_and_the_learned_poses_apart() {
        let mut n = NearHeldout {
            neighbours: 5,
            geometric_mm: 0.40,
            final_mm: 0.20,
            heldout_spacing_deg: 3.0,
            train_spacing_deg: 2.0,
        };
        // Held-out 0.21 against 0.20 near: the region.
        let s = n.sentence(0.41, 0.21, 0.15);
        assert!(
            s.contains("as well as the training poses beside them"),
            "{s}"
        );
        // Held-out 0.30 against 0.20, geometric 0.50 against 0.40 (25 %): a change.
        let s = n.sentence(0.50, 0.30, 0.15);
        assert!(s.contains("changed between them"), "{s}");
        assert!(s.contains("50 % worse") && s.contains("25 %"), "{s}");
        // Held-out 0.30 against 0.20, geometric 0.42 (5 %): the effects learned the poses.
        let s = n.sentence(0.42, 0.30, 0.15);
        assert!(s.contains("better than they predict"), "{s}");
        // The same figures with the held-out poses 3× the training spacing away: extrapolation.
        n.heldout_spacing_deg = 6.0;
        let s = n.sentence(0.50, 0.30, 0.15);
        assert!(s.contains("extrapolates"), "{s}");
        let s = n.sentence(0.41, 0.21, 0.15);
        assert!(
            s.contains("as well as the training poses beside them"),
            "{s}"
        );
    }
}
