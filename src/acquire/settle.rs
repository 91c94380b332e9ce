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
}

impl Settler {
    /// A detector with the given tolerances.
    pub fn new(opts: SettleOptions) -> Settler {
        Settler {
            opts,
            window: VecDeque::new(),
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
        // The marker must be stable where it is seen in every poll of the window; an
        // invisible marker cannot settle and is dealt with by the sampler (retry / skip).
        let markers: Vec<Point3<f64>> = self.window.iter().filter_map(|s| s.marker).collect();
        if markers.len() == self.window.len() {
            for a in &markers {
                for b in &markers {
                    let d = (a - b).norm();
                    if d.is_nan() || d > o.pos_tol_mm {
                        return false;
                    }
                }
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
        let mut st = Settler::new(opts());
        assert!(!st.push(s(0.0, 0.0, Some(0.0))));
        assert!(!st.push(s(0.0, 0.0, Some(0.0))));
        assert!(st.push(s(0.0, 0.0, Some(0.01))));
        // A joint still creeping.
        let mut st = Settler::new(opts());
        for i in 0..10 {
            assert!(!st.push(s(i as f64 * 1e-3, 0.0, None)));
        }
        // Joint speed above tolerance.
        let mut st = Settler::new(opts());
        for _ in 0..10 {
            assert!(!st.push(s(0.0, 0.01, None)));
        }
        // Marker still oscillating although the joints are quiet.
        let mut st = Settler::new(opts());
        for i in 0..10 {
            let x = if i % 2 == 0 { 0.0 } else { 0.2 };
            assert!(!st.push(s(0.0, 0.0, Some(x))));
        }
        // ... and then it calms down.
        for _ in 0..2 {
            assert!(!st.push(s(0.0, 0.0, Some(0.1))));
        }
        assert!(st.push(s(0.0, 0.0, Some(0.1))));
    }
}
