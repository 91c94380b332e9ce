//! Synchronised trapezoidal joint motion.

/// A synchronised point-to-point joint move: every joint follows the same normalised
/// trapezoidal (or triangular) velocity profile so that all arrive together; the joint with the
/// largest travel moves at the caps.
#[derive(Debug, Clone, PartialEq)]
pub struct Move {
    /// Start joint angles (rad).
    pub from: Vec<f64>,
    /// Target joint angles (rad).
    pub to: Vec<f64>,
    /// Start time (s).
    pub t0: f64,
    /// Acceleration phase length (s).
    pub t_acc: f64,
    /// Profile length (s), excluding settling.
    pub t_total: f64,
    /// Settling time after the profile (s).
    pub settle_s: f64,
}

impl Move {
    /// Plan a move from `from` to `to` starting at `t0` under speed `v` (rad/s) and acceleration
    /// `a` (rad/s²) caps.
    pub fn plan(from: Vec<f64>, to: Vec<f64>, t0: f64, v: f64, a: f64, settle_s: f64) -> Self {
        let d = from
            .iter()
            .zip(&to)
            .map(|(x, y)| (y - x).abs())
            .fold(0.0, f64::max);
        let (t_acc, t_total) = if d <= 0.0 || v <= 0.0 || a <= 0.0 {
            (0.0, 0.0)
        } else if d <= v * v / a {
            let ta = (d / a).sqrt();
            (ta, 2.0 * ta)
        } else {
            (v / a, d / v + v / a)
        };
        Self {
            from,
            to,
            t0,
            t_acc,
            t_total,
            settle_s,
        }
    }

    /// A move that has already ended, holding `q`.
    pub fn hold(q: Vec<f64>, t0: f64) -> Self {
        Self::plan(q.clone(), q, t0, 1.0, 1.0, 0.0)
    }

    /// Normalised progress s ∈ [0, 1] at time `t`.
    pub fn progress(&self, t: f64) -> f64 {
        let tau = t - self.t0;
        if tau <= 0.0 {
            return 0.0;
        }
        if tau >= self.t_total || self.t_total <= 0.0 {
            return 1.0;
        }
        let (ta, tt) = (self.t_acc, self.t_total);
        let tc = tt - 2.0 * ta; // cruise length
        let vpk = 1.0 / (ta + tc); // peak normalised speed (area = 1)
        let acc = if ta > 0.0 { vpk / ta } else { 0.0 };
        if tau < ta {
            0.5 * acc * tau * tau
        } else if tau < ta + tc {
            0.5 * acc * ta * ta + vpk * (tau - ta)
        } else {
            let r = tt - tau;
            1.0 - 0.5 * acc * r * r
        }
    }

    /// Normalised speed ds/dt at time `t` (1/s).
    pub fn speed(&self, t: f64) -> f64 {
        let tau = t - self.t0;
        if tau <= 0.0 || tau >= self.t_total || self.t_total <= 0.0 {
            return 0.0;
        }
        let (ta, tt) = (self.t_acc, self.t_total);
        let tc = tt - 2.0 * ta;
        let vpk = 1.0 / (ta + tc);
        if tau < ta {
            vpk * tau / ta
        } else if tau < ta + tc {
            vpk
        } else {
            vpk * (tt - tau) / ta
        }
    }

    /// Joint angles at time `t`.
    pub fn q_at(&self, t: f64) -> Vec<f64> {
        let s = self.progress(t);
        self.from
            .iter()
            .zip(&self.to)
            .map(|(a, b)| a + (b - a) * s)
            .collect()
    }

    /// Joint velocities at time `t`.
    pub fn qd_at(&self, t: f64) -> Vec<f64> {
        let v = self.speed(t);
        self.from
            .iter()
            .zip(&self.to)
            .map(|(a, b)| (b - a) * v)
            .collect()
    }

    /// Time the arm is settled at the target.
    pub fn end(&self) -> f64 {
        self.t0 + self.t_total + self.settle_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trapezoid_respects_caps_and_arrives_together() {
        let m = Move::plan(vec![0.0, 0.0], vec![2.0, -1.0], 10.0, 1.0, 2.0, 0.25);
        // d = 2 > v²/a = 0.5: t_acc = 0.5, total = 2 + 0.5 = 2.5.
        assert!((m.t_acc - 0.5).abs() < 1e-12);
        assert!((m.t_total - 2.5).abs() < 1e-12);
        assert!((m.end() - 12.75).abs() < 1e-12);
        let mut t = 10.0;
        let mut prev = m.q_at(t);
        while t < 12.6 {
            t += 0.001;
            let q = m.q_at(t);
            let v0 = (q[0] - prev[0]) / 0.001;
            assert!(v0 <= 1.0 + 1e-6, "speed cap {v0}");
            prev = q;
        }
        assert_eq!(m.q_at(12.5), vec![2.0, -1.0]);
        assert!((m.q_at(11.25)[0] - 1.0).abs() < 1e-12, "symmetric midpoint");
        let tri = Move::plan(vec![0.0], vec![0.1], 0.0, 1.0, 2.0, 0.0);
        assert!((tri.t_total - 2.0 * (0.05f64).sqrt()).abs() < 1e-12);
    }
}
