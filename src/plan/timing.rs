//! Session time model and pose ordering.
//!
//! A joint move is synchronous point-to-point: each joint follows a trapezoidal (or, for
//! short moves, triangular) velocity profile under its speed and acceleration caps and the
//! move lasts as long as its slowest joint. Every pose adds a settling time and a
//! measurement time. Angles rad, times s.
use super::spec::TimingSpec;

/// Per-joint caps (rad/s, rad/s²) plus fixed per-pose times (s).
#[derive(Debug, Clone, PartialEq)]
pub struct TimeModel {
    pub vmax: Vec<f64>,
    pub amax: Vec<f64>,
    pub settle_s: f64,
    pub sample_s: f64,
    pub home: Vec<f64>,
}

/// Duration of a rest-to-rest trapezoidal move of `d` (rad) under caps `v`, `a`.
pub fn trapezoid_time(d: f64, v: f64, a: f64) -> f64 {
    let d = d.abs();
    if d == 0.0 {
        return 0.0;
    }
    if d >= v * v / a {
        d / v + v / a
    } else {
        2.0 * (d / a).sqrt()
    }
}

impl TimeModel {
    /// From the spec's `[timing]` table for a `dof`-axis arm.
    pub fn from_spec(t: &TimingSpec, dof: usize) -> TimeModel {
        let pick = |v: &[f64], i: usize| v.get(i).or(v.last()).copied().unwrap_or(1.0).to_radians();
        TimeModel {
            vmax: (0..dof).map(|i| pick(&t.speed_deg_s, i)).collect(),
            amax: (0..dof).map(|i| pick(&t.accel_deg_s2, i)).collect(),
            settle_s: t.settle_s,
            sample_s: t.sample_s,
            home: match &t.home_deg {
                Some(h) if h.len() == dof => h.iter().map(|x| x.to_radians()).collect(),
                _ => vec![0.0; dof],
            },
        }
    }

    /// Duration of the move `a → b` (s).
    pub fn move_time(&self, a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .enumerate()
            .map(|(i, (x, y))| trapezoid_time(y - x, self.vmax[i], self.amax[i]))
            .fold(0.0, f64::max)
    }

    /// Session length (s): home → poses in `order` → each settle + sample (no return).
    pub fn session_time(&self, qs: &[Vec<f64>], order: &[usize]) -> f64 {
        let mut t = 0.0;
        let mut prev: &[f64] = &self.home;
        for &i in order {
            t += self.move_time(prev, &qs[i]) + self.settle_s + self.sample_s;
            prev = &qs[i];
        }
        t
    }
}

/// Poses per hour of a session of `n` poses lasting `secs`.
pub fn poses_per_hour(n: usize, secs: f64) -> f64 {
    if secs > 0.0 {
        n as f64 * 3600.0 / secs
    } else {
        0.0
    }
}

/// An order that shortens the session: nearest neighbour from home, then 2-opt on the open
/// path (the move-time metric is symmetric), then Or-opt moves of single poses.
pub fn optimise_order(tm: &TimeModel, qs: &[Vec<f64>]) -> Vec<usize> {
    let n = qs.len();
    if n <= 1 {
        return (0..n).collect();
    }
    // Distance matrix with node n = home.
    let node = |i: usize| -> &[f64] {
        if i == n {
            &tm.home
        } else {
            &qs[i]
        }
    };
    let mut dm = vec![0.0; (n + 1) * (n + 1)];
    for i in 0..=n {
        for j in (i + 1)..=n {
            let d = tm.move_time(node(i), node(j));
            dm[i * (n + 1) + j] = d;
            dm[j * (n + 1) + i] = d;
        }
    }
    let d = |i: usize, j: usize| dm[i * (n + 1) + j];
    // Nearest neighbour.
    let mut used = vec![false; n];
    let mut tour = Vec::with_capacity(n + 1);
    tour.push(n);
    let mut cur = n;
    for _ in 0..n {
        let mut best = usize::MAX;
        let mut bd = f64::INFINITY;
        for (j, &u) in used.iter().enumerate() {
            if !u && d(cur, j) < bd {
                bd = d(cur, j);
                best = j;
            }
        }
        used[best] = true;
        tour.push(best);
        cur = best;
    }
    // 2-opt on the open path tour[0] = home fixed, end free.
    let m = tour.len();
    let mut improved = true;
    let mut rounds = 0;
    while improved && rounds < 50 {
        improved = false;
        rounds += 1;
        for i in 0..m - 2 {
            for k in (i + 2)..m {
                // Reverse tour[i+1..=k].
                let a = tour[i];
                let b = tour[i + 1];
                let c = tour[k];
                let before = d(a, b) + if k + 1 < m { d(c, tour[k + 1]) } else { 0.0 };
                let after = d(a, c) + if k + 1 < m { d(b, tour[k + 1]) } else { 0.0 };
                if after < before - 1e-9 {
                    tour[i + 1..=k].reverse();
                    improved = true;
                }
            }
        }
        // Or-opt: move one pose to a better place.
        for i in 1..m {
            let x = tour[i];
            let prev = tour[i - 1];
            let next = tour.get(i + 1).copied();
            let remove_gain =
                d(prev, x) + next.map_or(0.0, |nx| d(x, nx)) - next.map_or(0.0, |nx| d(prev, nx));
            let mut best: Option<(usize, f64)> = None;
            for j in 0..m {
                if j == i || j + 1 == i {
                    continue;
                }
                let a = tour[j];
                let b = tour.get(j + 1).copied();
                let add = d(a, x) + b.map_or(0.0, |bb| d(x, bb)) - b.map_or(0.0, |bb| d(a, bb));
                if add < remove_gain - 1e-9 && best.is_none_or(|(_, c)| add < c) {
                    best = Some((j, add));
                }
            }
            if let Some((j, _)) = best {
                tour.remove(i);
                let pos = if j < i { j + 1 } else { j };
                tour.insert(pos, x);
                improved = true;
            }
        }
    }
    tour.into_iter().skip(1).collect()
}
