//! Pivot capture: stream the probe while the operator pivots it about its tip in a divot; live
//! progress (frames, angular spread, tilt directions covered, a hint where to tilt more); stop
//! on enough spread or on a key; refuse too little spread and a divot that moved.

use nalgebra::{UnitQuaternion, Vector3};
use robocal_drivers::{Clock, MarkerTracker};
use serde_json::{json, Map};

use super::{choose_tool, next_frame, Keys, ToolFrame};
use crate::dataset::{
    Dataset, Header, MarkerObs, PivotRecord, Record, RobotBlock, DATASET_FORMAT, NO_ROBOT_MODEL,
};

/// Options of a pivot capture.
#[derive(Debug, Clone)]
pub struct PivotOptions {
    /// Tool to capture (required when the tracker has several).
    pub tool: Option<String>,
    /// Largest angle between two captured orientations needed (deg).
    pub min_spread_deg: f64,
    /// Tilt directions (of 8 sectors) that must be covered.
    pub min_sectors: usize,
    /// Frames needed.
    pub min_frames: usize,
    /// Give up after this long (s).
    pub max_seconds: f64,
    /// Frame period (s).
    pub period_s: f64,
    /// Largest movement of the pivot point between quarters of the capture (mm).
    pub max_drift_mm: f64,
}

impl Default for PivotOptions {
    fn default() -> Self {
        Self {
            tool: None,
            min_spread_deg: 40.0,
            min_sectors: 6,
            min_frames: 600,
            max_seconds: 120.0,
            period_s: 1.0 / 60.0,
            max_drift_mm: 0.5,
        }
    }
}

/// What a pivot capture gathered.
#[derive(Debug, Clone)]
pub struct PivotCapture {
    /// The tool captured.
    pub tool: String,
    /// Visible frames.
    pub frames: Vec<ToolFrame>,
    /// Frames the tool was missing / out of volume.
    pub missing: usize,
    /// Largest angle between two captured orientations (deg).
    pub spread_deg: f64,
    /// Tilt directions covered (of 8).
    pub sectors: usize,
    /// Movement of the pivot point between quarters of the capture (mm).
    pub drift_mm: f64,
    /// Why it stopped.
    pub stopped: &'static str,
}

const SECTOR_NAMES: [&str; 8] = ["+x", "+x+y", "+y", "−x+y", "−x", "−x−y", "−y", "+x−y"];

/// Coverage of the marker's tilt directions: the marker origin's displacement from its mean,
/// seen along the tracker's line of sight (tracker x, y), in 8 sectors; a sector counts when
/// some frame reaches 40 % of the largest displacement in it.
pub fn coverage(frames: &[ToolFrame]) -> [bool; 8] {
    let mut out = [false; 8];
    if frames.len() < 2 {
        return out;
    }
    let n = frames.len() as f64;
    let mean: Vector3<f64> = frames
        .iter()
        .map(|f| f.pose.translation.vector)
        .sum::<Vector3<f64>>()
        / n;
    let d: Vec<(f64, f64)> = frames
        .iter()
        .map(|f| {
            let v = f.pose.translation.vector - mean;
            (v.x, v.y)
        })
        .collect();
    let max = d.iter().map(|(x, y)| x.hypot(*y)).fold(0.0, f64::max);
    if max <= 1.0 {
        return out;
    }
    for (x, y) in d {
        if x.hypot(y) >= 0.4 * max {
            let a = y.atan2(x).rem_euclid(std::f64::consts::TAU);
            let k = ((a / (std::f64::consts::TAU / 8.0)) + 0.5) as usize % 8;
            out[k] = true;
        }
    }
    out
}

/// The hint for the first uncovered sector (opposite a covered one first).
pub fn hint(cov: &[bool; 8]) -> Option<String> {
    let k = (0..8)
        .find(|&k| !cov[k] && cov[(k + 4) % 8])
        .or_else(|| (0..8).find(|&k| !cov[k]))?;
    Some(format!(
        "tilt more towards {} (tracker frame)",
        SECTOR_NAMES[k]
    ))
}

/// How far the pivot point slid during the capture: the pivot model with a pivot point moving
/// at constant velocity, `R_i·tip + p_i = c + v·(t_i − t̄)`, solved by linear least squares;
/// returns (|v|·duration mm, |v| / its standard error). A divot held still gives a velocity
/// within its noise.
pub fn drift(frames: &[ToolFrame]) -> (f64, f64) {
    let n = frames.len();
    if n < 10 {
        return (0.0, 0.0);
    }
    let tm = frames.iter().map(|f| f.t).sum::<f64>() / n as f64;
    let mut a = nalgebra::DMatrix::<f64>::zeros(3 * n, 9);
    let mut b = nalgebra::DVector::<f64>::zeros(3 * n);
    for (i, f) in frames.iter().enumerate() {
        let r = f.pose.rotation.to_rotation_matrix();
        let dt = f.t - tm;
        for k in 0..3 {
            for j in 0..3 {
                a[(3 * i + k, j)] = r[(k, j)];
            }
            a[(3 * i + k, 3 + k)] = -1.0;
            a[(3 * i + k, 6 + k)] = -dt;
            b[3 * i + k] = -f.pose.translation.vector[k];
        }
    }
    let ata = a.transpose() * &a;
    let Some(inv) = ata.clone().try_inverse() else {
        return (0.0, 0.0);
    };
    let x = &inv * (a.transpose() * &b);
    let res = &a * &x - &b;
    let dof = (3 * n).saturating_sub(9).max(1) as f64;
    let s2 = res.norm_squared() / dof;
    let v = Vector3::new(x[6], x[7], x[8]);
    let speed = v.norm();
    if speed == 0.0 {
        return (0.0, 0.0);
    }
    let u = v / speed;
    let cv = inv.fixed_view::<3, 3>(6, 6).into_owned() * s2;
    let se = (u.transpose() * cv * u)[(0, 0)].max(0.0).sqrt();
    let span = frames[n - 1].t - frames[0].t;
    (
        speed * span,
        if se > 0.0 { speed / se } else { f64::INFINITY },
    )
}

fn angle(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
    a.angle_to(b).to_degrees()
}

/// Stream `tracker` until enough spread (or a key, or `max_seconds`), then check the capture.
/// `Err` when too little spread, two tools without `--tool`, or a divot that moved; the
/// frames gathered are in the error text's counts only.
pub async fn capture_pivot(
    tracker: &dyn MarkerTracker,
    clock: &dyn Clock,
    opt: &PivotOptions,
    keys: &Keys,
    progress: &mut dyn FnMut(&str),
) -> anyhow::Result<PivotCapture> {
    let keys0 = keys.count();
    let t_start = clock.now();
    let mut tool: Option<String> = None;
    let mut frames: Vec<ToolFrame> = Vec::new();
    let mut missing = 0usize;
    let mut spread: f64 = 0.0;
    let mut last_report = t_start;
    let mut pacer = super::Pacer::new(clock, opt.period_s);
    let stopped;
    loop {
        let name = match &tool {
            Some(t) => t.clone(),
            None => {
                let f = tracker.frame().await?;
                let names: Vec<String> = f.tools.iter().map(|t| t.tool.clone()).collect();
                let t = choose_tool(&names, opt.tool.as_deref())?;
                progress(&format!(
                    "pivot capture of tool {t:?}: pivot the probe about its tip in the divot, \
                     tilting it all round (Enter stops)"
                ));
                tool = Some(t.clone());
                t
            }
        };
        let (_, obs) = next_frame(tracker, &name).await?;
        match obs {
            Some(f) => {
                for g in &frames {
                    spread = spread.max(angle(&g.pose.rotation, &f.pose.rotation));
                }
                frames.push(f);
            }
            None => missing += 1,
        }
        let now = clock.now();
        let cov = coverage(&frames);
        let sectors = cov.iter().filter(|c| **c).count();
        let enough = frames.len() >= opt.min_frames
            && spread >= opt.min_spread_deg
            && sectors >= opt.min_sectors;
        if now - last_report >= 1.0 || enough {
            last_report = now;
            progress(&format!(
                "  {:5} frames ({missing} not seen), spread {spread:5.1}° of {:.0}°, tilt \
                 directions {sectors}/8{}",
                frames.len(),
                opt.min_spread_deg,
                if enough {
                    String::new()
                } else {
                    hint(&cov).map(|h| format!(": {h}")).unwrap_or_default()
                }
            ));
        }
        if enough {
            stopped = "enough spread";
            break;
        }
        if keys.count() > keys0 {
            stopped = "key";
            break;
        }
        if now - t_start >= opt.max_seconds {
            stopped = "time limit";
            break;
        }
        pacer.tick(clock).await;
    }
    let tool = tool.unwrap_or_default();
    let cov = coverage(&frames);
    let sectors = cov.iter().filter(|c| **c).count();
    anyhow::ensure!(
        spread >= opt.min_spread_deg && sectors >= opt.min_sectors.min(8) && frames.len() >= 20,
        "too little spread to calibrate the probe: {} frames of tool {tool:?} covering {spread:.1}° \
         (needed {:.0}°) and {sectors} of 8 tilt directions (needed {}) when stopped by {stopped}: \
         pivot wider and all round{}",
        frames.len(),
        opt.min_spread_deg,
        opt.min_sectors,
        hint(&cov).map(|h| format!(" ({h})")).unwrap_or_default()
    );
    let (d, z) = drift(&frames);
    anyhow::ensure!(
        d <= opt.max_drift_mm || z < 4.0,
        "the divot moved: the pivot point slid {d:.2} mm over {:.1} s ({:.0} standard errors; \
         allowed {:.2} mm): clamp the divot (or the phantom holding it) and pivot again",
        frames.last().map_or(0.0, |l| l.t - frames[0].t),
        z,
        opt.max_drift_mm
    );
    Ok(PivotCapture {
        tool,
        frames,
        missing,
        spread_deg: spread,
        sectors,
        drift_mm: d,
        stopped,
    })
}

/// The capture as a `robocal-dataset/1` of `pivot` records (what `calibrate pivot` reads).
pub fn pivot_dataset(c: &PivotCapture, tracker: &str) -> Dataset {
    let t0 = c.frames.first().map_or(0.0, |f| f.t);
    let records = c
        .frames
        .iter()
        .map(|f| {
            let q = f.pose.rotation.into_inner();
            Record::Pivot(PivotRecord {
                t: f.t - t0,
                tool: Some(c.tool.clone()),
                marker: MarkerObs {
                    p: Some(f.pose.translation.vector.into()),
                    quat: Some([q.w, q.i, q.j, q.k]),
                    rms: Some(f.rms_mm),
                    visible: true,
                    frames: None,
                    extra: Map::new(),
                },
                extra: Map::new(),
            })
        })
        .collect();
    let mut hx = Map::new();
    hx.insert(
        "source".into(),
        json!({"capture": "pivot", "spread_deg": c.spread_deg, "tilt_sectors": c.sectors,
               "divot_drift_mm": c.drift_mm, "frames_not_seen": c.missing}),
    );
    Dataset {
        header: Header {
            format: DATASET_FORMAT.into(),
            created: None,
            robot: RobotBlock {
                model: NO_ROBOT_MODEL.into(),
                serial: None,
                chain: None,
                flange: None,
                extra: Map::new(),
            },
            tool: None,
            tracker: Some(json!({"device": tracker})),
            range_sensor: None,
            plan: None,
            notes: None,
            extra: hx,
        },
        records,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Point3, Translation3};

    fn frames(cone_deg: f64, n: usize) -> Vec<ToolFrame> {
        let tip = Vector3::new(0.0, 0.0, -150.0);
        let pivot = Point3::new(0.0, 0.0, -1200.0);
        (0..n)
            .map(|i| {
                let a = i as f64 * 0.37;
                let tilt = cone_deg.to_radians() * (0.75 + 0.25 * (i as f64 * 0.05).sin());
                let axis = Vector3::new(a.cos(), a.sin(), 0.0);
                let r = UnitQuaternion::from_scaled_axis(axis * tilt);
                ToolFrame {
                    t: i as f64 / 60.0,
                    pose: Isometry3::from_parts(Translation3::from(pivot.coords - r * tip), r),
                    rms_mm: 0.1,
                }
            })
            .collect()
    }

    #[test]
    fn coverage_and_hint() {
        let f = frames(30.0, 400);
        assert_eq!(coverage(&f).iter().filter(|c| **c).count(), 8);
        assert_eq!(hint(&coverage(&f)), None);
        // Tilting in one plane only (the shaft swung along x): sectors are taken about the
        // centre of the frames, so only the two along that line are covered, and the hint
        // names a direction across it.
        let one: Vec<ToolFrame> = f
            .into_iter()
            .filter(|g| {
                let v = g.pose.translation.vector;
                v.y.atan2(v.x).sin().abs() < 0.2
            })
            .collect();
        let c = coverage(&one);
        assert!(c.iter().filter(|c| **c).count() <= 3, "{c:?}");
        let h = hint(&c).unwrap();
        assert!(h.contains('y'), "{h}");
    }

    #[test]
    fn drift_sees_a_sliding_divot() {
        let f = frames(30.0, 400);
        assert!(drift(&f).0 < 1e-6);
        let slid: Vec<ToolFrame> = f
            .iter()
            .map(|g| ToolFrame {
                pose: Isometry3::from_parts(
                    Translation3::from(
                        g.pose.translation.vector + Vector3::new(0.3 * g.t, 0.0, 0.0),
                    ),
                    g.pose.rotation,
                ),
                ..*g
            })
            .collect();
        let (d, _) = drift(&slid);
        // 0.3 mm/s over 6.65 s.
        assert!((d - 2.0).abs() < 0.01, "{d}");
    }
}
