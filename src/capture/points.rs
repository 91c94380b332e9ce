//! Point capture: the operator touches each named fiducial with the calibrated probe; each
//! point is the mean tip position over a still window (motion rejected, its spread reported).
//! The result is the `name,x_mm,y_mm,z_mm` table `register` reads (tracker frame).

use nalgebra::{Point3, Vector3};
use robocal_drivers::{Clock, MarkerTracker};

use super::{mean_spread, next_frame};

/// Options of a point capture.
#[derive(Debug, Clone)]
pub struct PointOptions {
    /// The probe tool.
    pub tool: String,
    /// Probe tip in its marker frame (mm), from `calibrate pivot`.
    pub tip_mm: Vector3<f64>,
    /// Length of the still window averaged into a point (s).
    pub hold_s: f64,
    /// Largest RMS 3-D spread of the tip over the window (mm) for it to count as still.
    pub still_mm: f64,
    /// The tip must leave a recorded point by this much (mm) before the next is taken.
    pub lift_mm: f64,
    /// Give up after this long per point (s).
    pub max_seconds_per_point: f64,
    /// Frame period (s).
    pub period_s: f64,
}

impl Default for PointOptions {
    fn default() -> Self {
        Self {
            tool: "probe".into(),
            tip_mm: Vector3::zeros(),
            hold_s: 3.0,
            still_mm: 0.6,
            lift_mm: 5.0,
            max_seconds_per_point: 60.0,
            period_s: 1.0 / 60.0,
        }
    }
}

/// One captured point.
#[derive(Debug, Clone, PartialEq)]
pub struct CapturedPoint {
    /// Fiducial name.
    pub name: String,
    /// Mean tip position in the tracker frame (mm).
    pub xyz: Point3<f64>,
    /// RMS 3-D spread of the tip over the window (mm).
    pub spread_mm: f64,
    /// Frames averaged.
    pub frames: usize,
    /// Windows rejected as moving before this one.
    pub rejected: usize,
}

/// Whether the tip samples of a window are still: RMS spread ≤ `still_mm` and the means of its
/// two halves within `still_mm / 2` (a slow slide passes the first test, not the second).
pub fn is_still(w: &[Point3<f64>], still_mm: f64) -> (bool, f64) {
    let (_, rms) = mean_spread(w);
    let h = w.len() / 2;
    if h < 3 {
        return (false, rms);
    }
    let (a, _) = mean_spread(&w[..h]);
    let (b, _) = mean_spread(&w[h..]);
    (rms <= still_mm && (a - b).norm() <= still_mm / 2.0, rms)
}

/// Capture `names` in order. A point is the first still window of `hold_s` after the tip left
/// the previous point by `lift_mm`.
pub async fn capture_points(
    tracker: &dyn MarkerTracker,
    clock: &dyn Clock,
    names: &[String],
    opt: &PointOptions,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<Vec<CapturedPoint>> {
    let need = ((opt.hold_s / opt.period_s).round() as usize).max(6);
    let mut out: Vec<CapturedPoint> = Vec::new();
    for name in names {
        progress(&format!(
            "touch {name} with the probe tip and hold still ({:.1} s)",
            opt.hold_s
        ));
        let t_start = clock.now();
        let mut window: Vec<Point3<f64>> = Vec::new();
        let mut left = out.is_empty();
        let mut rejected = 0usize;
        let mut was_still_candidate = false;
        let mut last_report = t_start;
        let mut pacer = super::Pacer::new(clock, opt.period_s);
        loop {
            let (names_seen, obs) = next_frame(tracker, &opt.tool).await?;
            anyhow::ensure!(
                names_seen.contains(&opt.tool),
                "the tracker has no tool {:?} (tools: {}): check --tool",
                opt.tool,
                names_seen.join(", ")
            );
            match obs {
                None => window.clear(),
                Some(f) => {
                    let tip = f.pose * Point3::from(opt.tip_mm);
                    if !left {
                        let prev = out.last().map(|p| p.xyz).unwrap_or(tip);
                        left = (tip - prev).norm() > opt.lift_mm;
                    } else {
                        window.push(tip);
                        if window.len() > need {
                            window.remove(0);
                        }
                    }
                }
            }
            let now = clock.now();
            if window.len() >= need {
                let (still, rms) = is_still(&window, opt.still_mm);
                if still {
                    let (m, _) = mean_spread(&window);
                    progress(&format!(
                        "  {name}: [{:.2}, {:.2}, {:.2}] mm, spread {rms:.3} mm RMS over {} frames{}",
                        m.x,
                        m.y,
                        m.z,
                        window.len(),
                        if rejected > 0 {
                            format!(" ({rejected} moving windows rejected)")
                        } else {
                            String::new()
                        }
                    ));
                    out.push(CapturedPoint {
                        name: name.clone(),
                        xyz: m,
                        spread_mm: rms,
                        frames: window.len(),
                        rejected,
                    });
                    break;
                }
                // A window that was nearly still and then moved counts as a rejection.
                if rms <= 2.0 * opt.still_mm {
                    was_still_candidate = true;
                } else if was_still_candidate {
                    rejected += 1;
                    was_still_candidate = false;
                }
            }
            if now - last_report >= 2.0 {
                last_report = now;
                progress(&format!(
                    "  waiting for {name}: {}",
                    if !left {
                        "lift the tip off the last point".to_string()
                    } else if window.is_empty() {
                        "probe not seen".to_string()
                    } else {
                        format!("tip moving ({:.2} mm RMS)", mean_spread(&window).1)
                    }
                ));
            }
            anyhow::ensure!(
                now - t_start < opt.max_seconds_per_point,
                "no still window for {name} within {:.0} s ({} point{} captured: {}): touch the \
                 fiducial and hold the probe still for {:.1} s",
                opt.max_seconds_per_point,
                out.len(),
                if out.len() == 1 { "" } else { "s" },
                out.iter()
                    .map(|p| p.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
                opt.hold_s
            );
            pacer.tick(clock).await;
        }
    }
    Ok(out)
}

/// As the named points `register` reads (tracker frame, mm).
pub fn named_points(points: &[CapturedPoint]) -> Vec<crate::register::points::NamedPoint> {
    points
        .iter()
        .map(|p| crate::register::points::NamedPoint {
            name: p.name.clone(),
            p: p.xyz,
            line: 0,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn still_and_sliding_windows() {
        let still: Vec<Point3<f64>> = (0..60)
            .map(|i| Point3::new(0.2 * ((i * 7) % 5) as f64 - 0.4, 0.0, 0.0))
            .collect();
        assert!(is_still(&still, 0.6).0);
        let slide: Vec<Point3<f64>> = (0..60)
            .map(|i| Point3::new(i as f64 * 0.03, 0.0, 0.0))
            .collect();
        // RMS 0.52 mm passes the first test, the halves 0.9 mm apart fail the second.
        assert!(!is_still(&slide, 0.6).0);
    }
}
