//! Settling detector: a window of joint and marker samples must agree within tolerances.
use std::collections::VecDeque;

use nalgebra::Point3;

use super::SettleOptions;

/// One poll of the arm (and the marker, when visible).
#[derive(Debug, Clone, PartialEq)]
pub struct SettleSample {
    /// Measured joints (rad).
    pub q: Vec<f64>,
    /// Reported joint speeds (rad/s), when the controller gives them.
    pub qd: Option<Vec<f64>>,
    /// Marker position in the tracker frame (mm), when visible.
    pub marker: Option<Point3<f64>>,
}

/// Feeds polls in; says when the last `window` polls agree.
#[derive(Debug, Clone)]
pub struct Settler {
    opts: SettleOptions,
    window: VecDeque<SettleSample>,
    noise_3d_mm: Option<f64>,
}

impl Settler {
    /// A detector with the given tolerances. `noise_3d_mm` is the tracker's per-frame
    /// scatter (RMS 3-D distance from the mean, e.g. the `spread_mm` of the previous
    /// pose); `None` estimates it from the window itself (less strict against drift).
    pub fn new(opts: SettleOptions, noise_3d_mm: Option<f64>) -> Settler {
        Settler {
            opts,
            window: VecDeque::new(),
            noise_3d_mm: noise_3d_mm.filter(|x| x.is_finite() && *x >= 0.0),
        }
    }

    /// Adds a poll; returns whether the arm (and marker) are now settled.
    pub fn push(&mut self, s: SettleSample) -> bool {
        self.window.push_back(s);
        let n = self.opts.window.max(1);
        while self.window.len() > n {
            self.window.pop_front();
        }
        self.window.len() == n && self.is_settled()
    }

    fn is_settled(&self) -> bool {
        let o = &self.opts;
        let first = &self.window[0];
        let dof = first.q.len();
        for s in &self.window {
            if s.q.len() != dof {
                return false;
            }
            if let Some(qd) = &s.qd {
                if qd
                    .iter()
                    .any(|v| v.abs() > o.qd_tol_rad_s || !v.is_finite())
                {
                    return false;
                }
            }
        }
        for j in 0..dof {
            let (lo, hi) = self
                .window
                .iter()
                .map(|s| s.q[j])
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
                    (l.min(x), h.max(x))
                });
            let band = hi - lo;
            if band.is_nan() || band > o.q_tol_rad {
                return false;
            }
        }
        // The marker must be seen in every poll of the window and must not drift: the mean
        // position of the last half of the window may differ from that of the first half
        // by `pos_tol_mm` plus 3 σ of the difference of two means under the observed noise
        // (so tracker noise alone never prevents settling, while drift does).
        let markers: Vec<Point3<f64>> = self.window.iter().filter_map(|s| s.marker).collect();
        if markers.len() == self.window.len() && markers.len() >= 2 {
            let h = markers.len() / 2;
            let (a, b) = (&markers[..h], &markers[markers.len() - h..]);
            let mean = |v: &[Point3<f64>]| {
                v.iter().map(|p| p.coords).sum::<nalgebra::Vector3<f64>>() / v.len() as f64
            };
            let (ma, mb) = (mean(a), mean(b));
            let ss: f64 = a
                .iter()
                .map(|p| (p.coords - ma).norm_squared())
                .sum::<f64>()
                + b.iter()
                    .map(|p| (p.coords - mb).norm_squared())
                    .sum::<f64>();
            let dof = (2 * h).saturating_sub(2).max(1) as f64;
            let sigma3d = self.noise_3d_mm.unwrap_or_else(|| (ss / dof).sqrt());
            let allowed = o.pos_tol_mm + 3.0 * sigma3d * (2.0 / h as f64).sqrt();
            let d = (mb - ma).norm();
            if d.is_nan() || d > allowed {
                return false;
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts() -> SettleOptions {
        SettleOptions {
            window: 3,
            q_tol_rad: 1e-4,
            qd_tol_rad_s: 1e-3,
            pos_tol_mm: 0.05,
            ..SettleOptions::default()
        }
    }

    fn s(q: f64, qd: f64, m: Option<f64>) -> SettleSample {
        SettleSample {
            q: vec![q, 0.0],
            qd: Some(vec![qd, 0.0]),
            marker: m.map(|x| Point3::new(x, 0.0, 0.0)),
        }
    }

    #[test]
    fn settles_only_after_a_quiet_window() {
        let mut st = Settler::new(opts(), None);
        assert!(!st.push(s(0.0, 0.0, Some(0.0))));
        assert!(!st.push(s(0.0, 0.0, Some(0.0))));
        assert!(st.push(s(0.0, 0.0, Some(0.01))));
        // A joint still creeping.
        let mut st = Settler::new(opts(), None);
        for i in 0..10 {
            assert!(!st.push(s(i as f64 * 1e-3, 0.0, None)));
        }
        // Joint speed above tolerance.
        let mut st = Settler::new(opts(), None);
        for _ in 0..10 {
            assert!(!st.push(s(0.0, 0.01, None)));
        }
        // Marker still drifting although the joints are quiet.
        let mut st = Settler::new(opts6(), Some(0.0));
        for i in 0..20 {
            assert!(!st.push(s(0.0, 0.0, Some(0.1 * i as f64))));
        }
        // ... and then it stops.
        for _ in 0..5 {
            assert!(!st.push(s(0.0, 0.0, Some(3.0))));
        }
        assert!(st.push(s(0.0, 0.0, Some(3.0))));
    }

    fn opts6() -> SettleOptions {
        SettleOptions {
            window: 6,
            ..opts()
        }
    }

    #[test]
    fn tracker_noise_alone_does_not_prevent_settling() {
        // 0.1 mm noise (twice the 0.05 mm tolerance), no drift: settles within a few
        // windows for most noise draws.
        use rand::{Rng, SeedableRng};
        use rand_distr::StandardNormal;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let mut settled_after = Vec::new();
        for _ in 0..200 {
            let mut st = Settler::new(opts6(), Some(0.1 * 3f64.sqrt()));
            let mut n = 0;
            loop {
                n += 1;
                let x: f64 = 0.1 * rng.sample::<f64, _>(StandardNormal);
                if st.push(s(0.0, 0.0, Some(x))) || n > 60 {
                    break;
                }
            }
            settled_after.push(n);
        }
        settled_after.sort();
        assert!(
            settled_after[100] <= 8,
            "median {} polls",
            settled_after[100]
        );
        assert!(
            settled_after[190] <= 20,
            "95th percentile {} polls",
            settled_after[190]
        );
        // The same noise on top of a 0.5 mm/poll drift never settles.
        let mut st = Settler::new(opts6(), Some(0.1 * 3f64.sqrt()));
        for i in 0..200 {
            let x: f64 = 0.5 * i as f64 + 0.1 * rng.sample::<f64, _>(StandardNormal);
            assert!(!st.push(s(0.0, 0.0, Some(x))));
        }
    }
}
