//! Operator-guided acquisition (`robocal capture`): the operator pivots a tracked
//! probe in a divot ([`pivot`]), touches fiducials with the calibrated probe ([`points`]), or
//! hand-guides the arm and records poses ([`poses`]). Nothing here commands the arm to move:
//! the tracker and the joint encoders are only read (a UR is put in freedrive by the caller).
//!
//! Every loop takes a progress sink (one line at a time: live progress, coverage hints) and a
//! [`Keys`] flag the CLI sets when the operator presses Enter; without a terminal the loops stop
//! on their own criteria.

pub mod cell;
pub mod pivot;
pub mod points;
pub mod poses;
pub mod settle;
pub mod teach;

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use nalgebra::{Isometry3, Point3};
use robocal_drivers::{MarkerTracker, ToolStatus};

/// Key presses counted by the CLI (Enter = stop / record here).
#[derive(Debug, Clone, Default)]
pub struct Keys(Arc<AtomicUsize>);

impl Keys {
    /// No key pressed yet.
    pub fn new() -> Self {
        Self::default()
    }
    /// Count one key press.
    pub fn press(&self) {
        self.0.fetch_add(1, Ordering::SeqCst);
    }
    /// Key presses so far.
    pub fn count(&self) -> usize {
        self.0.load(Ordering::SeqCst)
    }
}

/// Paces a loop at a fixed period on `clock` (deadlines, so the time a frame takes does not
/// lower the rate; a late loop does not try to catch up).
#[derive(Debug, Clone, Copy)]
pub struct Pacer {
    next: f64,
    period: f64,
}

impl Pacer {
    /// A pacer whose first tick is one period from now.
    pub fn new(clock: &dyn robocal_drivers::Clock, period: f64) -> Self {
        Self {
            next: clock.now() + period,
            period,
        }
    }
    /// Sleep until the next deadline.
    pub async fn tick(&mut self, clock: &dyn robocal_drivers::Clock) {
        let now = clock.now();
        if self.next > now {
            clock.sleep(self.next - now).await;
            self.next += self.period;
        } else {
            self.next = now + self.period;
        }
    }
}

/// One tracked pose of the captured tool.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolFrame {
    /// Time (s, the tracker's clock).
    pub t: f64,
    /// Marker in the tracker frame (mm).
    pub pose: Isometry3<f64>,
    /// The tracker's marker fit RMS (mm).
    pub rms_mm: f64,
}

/// Which tool of the tracker to capture: the one named, or the only one. Two or more tools
/// and no name: refused, naming them (records of two tools solved as one belong to neither).
pub fn choose_tool(names: &[String], tool: Option<&str>) -> anyhow::Result<String> {
    match tool {
        Some(t) => {
            anyhow::ensure!(
                names.iter().any(|n| n == t),
                "tool {t:?} is not among the tracker's tools ({}): check --tool and the device \
                 file's `tools`",
                names.join(", ")
            );
            Ok(t.to_string())
        }
        None => match names {
            [one] => Ok(one.clone()),
            [] => anyhow::bail!("the tracker reports no tools: check the device file's `tools`"),
            many => anyhow::bail!(
                "the tracker reports {} tools ({}): a capture is of one tool; choose it with \
                 --tool NAME",
                many.len(),
                many.join(", ")
            ),
        },
    }
}

/// The next frame of `tool`: `Ok(Some)` when visible, `Ok(None)` when missing / out of volume.
pub async fn next_frame(
    tracker: &dyn MarkerTracker,
    tool: &str,
) -> anyhow::Result<(Vec<String>, Option<ToolFrame>)> {
    let f = tracker.frame().await?;
    let names = f.tools.iter().map(|t| t.tool.clone()).collect();
    let obs = f
        .tools
        .iter()
        .find(|t| t.tool == tool)
        .and_then(|t| match t.status {
            ToolStatus::Visible { pose, rms_mm } => Some(ToolFrame {
                t: f.t,
                pose: pose.0,
                rms_mm,
            }),
            _ => None,
        });
    Ok((names, obs))
}

/// Mean and RMS 3-D deviation of points.
pub fn mean_spread(p: &[Point3<f64>]) -> (Point3<f64>, f64) {
    if p.is_empty() {
        return (Point3::origin(), 0.0);
    }
    let n = p.len() as f64;
    let m = Point3::from(p.iter().map(|x| x.coords).sum::<nalgebra::Vector3<f64>>() / n);
    let rms = (p.iter().map(|x| (x - m).norm_squared()).sum::<f64>() / n).sqrt();
    (m, rms)
}
