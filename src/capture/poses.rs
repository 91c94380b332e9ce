//! Pose teaching: the operator guides the arm by hand (UR: `freedrive_mode()` through the
//! script interface; DENSO: read-only while the teach pendant holds the arm) and each pose is
//! recorded where the arm is held still: on Enter with a terminal, else on its own after the
//! arm moved and came to rest. The joints are only read: nothing here moves the arm.

use robocal_drivers::{Clock, JointReadout};

use super::Keys;

/// Options of pose teaching.
#[derive(Debug, Clone)]
pub struct PoseOptions {
    /// Poses to record.
    pub count: usize,
    /// Record on a key (a terminal) instead of on rest.
    pub on_key: bool,
    /// A joint that moves more than this over the window (deg) means not at rest.
    pub still_deg: f64,
    /// Rest window averaged into a pose (s).
    pub hold_s: f64,
    /// The arm must move this far (deg, any joint) from the last recorded pose (or the
    /// start) before the next is taken on rest.
    pub min_move_deg: f64,
    /// Give up after this long (s).
    pub max_seconds: f64,
    /// Joint read period (s).
    pub period_s: f64,
}

impl Default for PoseOptions {
    fn default() -> Self {
        Self {
            count: 4,
            on_key: false,
            still_deg: 0.01,
            hold_s: 0.6,
            min_move_deg: 2.0,
            max_seconds: 600.0,
            period_s: 0.02,
        }
    }
}

/// One taught pose.
#[derive(Debug, Clone, PartialEq)]
pub struct TaughtPose {
    /// `P1`, `P2`, …
    pub name: String,
    /// Mean joint angles over the rest window (deg).
    pub q_deg: Vec<f64>,
    /// Largest joint range over the window (deg).
    pub range_deg: f64,
    /// Joint readings averaged.
    pub samples: usize,
}

fn max_range(w: &[Vec<f64>]) -> f64 {
    let n = w.first().map_or(0, Vec::len);
    (0..n)
        .map(|j| {
            let (lo, hi) = w.iter().fold((f64::MAX, f64::MIN), |(lo, hi), q| {
                (lo.min(q[j]), hi.max(q[j]))
            });
            hi - lo
        })
        .fold(0.0, f64::max)
}

fn mean(w: &[Vec<f64>]) -> Vec<f64> {
    let n = w.first().map_or(0, Vec::len);
    (0..n)
        .map(|j| w.iter().map(|q| q[j]).sum::<f64>() / w.len() as f64)
        .collect()
}

/// Read the arm's joints until `count` poses are recorded.
pub async fn capture_poses(
    arm: &dyn JointReadout,
    clock: &dyn Clock,
    opt: &PoseOptions,
    keys: &Keys,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Vec<TaughtPose>> {
    let need = ((opt.hold_s / opt.period_s).round() as usize).max(5);
    let t_start = clock.now();
    let start: Vec<f64> = arm
        .joints()
        .await?
        .q
        .iter()
        .map(|x| x.to_degrees())
        .collect();
    let mut out: Vec<TaughtPose> = Vec::new();
    let mut window: Vec<Vec<f64>> = Vec::new();
    let mut keys_seen = keys.count();
    let mut last_report = t_start;
    let mut pacer = super::Pacer::new(clock, opt.period_s);
    progress(&format!(
        "guide the arm to pose P1 of {} and hold it still{}",
        opt.count,
        if opt.on_key { "; Enter records" } else { "" }
    ));
    while out.len() < opt.count {
        let q: Vec<f64> = arm
            .joints()
            .await?
            .q
            .iter()
            .map(|x| x.to_degrees())
            .collect();
        anyhow::ensure!(
            q.len() == start.len() && q.iter().all(|x| x.is_finite()),
            "the arm reported {} joint values ({:?}), expected {} finite",
            q.len(),
            q,
            start.len()
        );
        window.push(q.clone());
        if window.len() > need {
            window.remove(0);
        }
        let now = clock.now();
        let last = out.last().map_or(&start, |p| &p.q_deg);
        let moved = q
            .iter()
            .zip(last)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let range = if window.len() >= need {
            max_range(&window)
        } else {
            f64::INFINITY
        };
        let still = range <= opt.still_deg;
        let key = keys.count() > keys_seen;
        keys_seen = keys.count();
        let take = if opt.on_key {
            key && still
        } else {
            still && moved >= opt.min_move_deg
        };
        if key && !still {
            progress("  not recorded: the arm is moving; hold it still and press Enter again");
        }
        if take {
            let p = TaughtPose {
                name: format!("P{}", out.len() + 1),
                q_deg: mean(&window),
                range_deg: range,
                samples: window.len(),
            };
            progress(&format!(
                "  {}: [{}] deg (range {:.4}° over {} readings)",
                p.name,
                p.q_deg
                    .iter()
                    .map(|x| format!("{x:.3}"))
                    .collect::<Vec<_>>()
                    .join(", "),
                p.range_deg,
                p.samples
            ));
            out.push(p);
            window.clear();
            if out.len() < opt.count {
                progress(&format!(
                    "guide the arm to pose P{} of {} and hold it still",
                    out.len() + 1,
                    opt.count
                ));
            }
            continue;
        }
        if now - last_report >= 2.0 {
            last_report = now;
            progress(&format!(
                "  P{}: {}",
                out.len() + 1,
                if still && moved < opt.min_move_deg {
                    format!("at rest {moved:.2}° from the last pose: move it to the next pose")
                } else if still {
                    "at rest".to_string()
                } else {
                    "moving".to_string()
                }
            ));
        }
        anyhow::ensure!(
            now - t_start < opt.max_seconds,
            "{} of {} poses taught within {:.0} s: guide the arm to each pose and hold it still",
            out.len(),
            opt.count,
            opt.max_seconds
        );
        pacer.tick(clock).await;
    }
    Ok(out)
}

/// The taught poses as `name,j1_deg,…,jN_deg`.
pub fn poses_csv(poses: &[TaughtPose]) -> String {
    let n = poses.first().map_or(0, |p| p.q_deg.len());
    let mut s = String::from("name");
    for j in 1..=n {
        s += &format!(",j{j}_deg");
    }
    s.push('\n');
    for p in poses {
        s += &p.name;
        for x in &p.q_deg {
            s += &format!(",{x:.6}");
        }
        s.push('\n');
    }
    s
}

/// Read a `name,j1_deg,…` table back (errors name the file, line and field).
pub fn read_poses_csv(file: &str, text: &str) -> anyhow::Result<Vec<TaughtPose>> {
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, head) = lines
        .next()
        .ok_or_else(|| anyhow::anyhow!("{file}: empty: expected a `name,j1_deg,…` header"))?;
    let cols: Vec<&str> = head.split(',').map(str::trim).collect();
    anyhow::ensure!(
        cols.first() == Some(&"name")
            && cols.len() >= 2
            && cols[1..]
                .iter()
                .enumerate()
                .all(|(i, c)| *c == format!("j{}_deg", i + 1)),
        "{file}:1: header {head:?}: expected `name,j1_deg,j2_deg,…`"
    );
    let mut out = Vec::new();
    for (i, l) in lines {
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        anyhow::ensure!(
            f.len() == cols.len(),
            "{file}:{}: {} fields, the header has {}",
            i + 1,
            f.len(),
            cols.len()
        );
        let q = f[1..]
            .iter()
            .zip(&cols[1..])
            .map(|(v, c)| {
                v.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite() && x.abs() <= 720.0)
                    .ok_or_else(|| {
                        anyhow::anyhow!(
                            "{file}:{}: field {c}: {v:?} is not an angle in degrees",
                            i + 1
                        )
                    })
            })
            .collect::<anyhow::Result<Vec<f64>>>()?;
        out.push(TaughtPose {
            name: f[0].to_string(),
            q_deg: q,
            range_deg: 0.0,
            samples: 0,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_round_trip_and_bad_field() {
        let p = vec![TaughtPose {
            name: "P1".into(),
            q_deg: vec![1.0, -2.5, 90.0],
            range_deg: 0.0,
            samples: 0,
        }];
        let back = read_poses_csv("x.csv", &poses_csv(&p)).unwrap();
        assert_eq!(back[0].q_deg, p[0].q_deg);
        let e = read_poses_csv("x.csv", "name,j1_deg\nP1,abc\n").unwrap_err();
        assert!(e.to_string().contains("x.csv:2: field j1_deg"), "{e}");
    }
}
