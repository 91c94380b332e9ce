//! Validation of a laser calibration (seed 000 §2.3) and the side-by-side comparison of the
//! four estimators.

use super::fit::{
    closed_form_single_plane, fit_direct, fit_orthogonal_planes, select_data, DirectOptions,
    MultiPlaneFit, SelectionTrace,
};
use super::{by_plane, by_target, Beam, LaserError, LaserObs, Plane};
use crate::solve::rigid::register_points;
use nalgebra::{Point3, Unit, Vector3};
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};

/// 5-direction spread of one target: the RMS distance of its predicted spots from their
/// centroid, `sqrt(Σ|p_i − p̄|² / n)` (mm) (the convention of the independent reference fit
/// quoted with the shared laser-planes case).
pub fn spread(points: &[Point3<f64>]) -> f64 {
    if points.len() < 2 {
        return 0.0;
    }
    let c = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / points.len() as f64;
    let ss: f64 = points.iter().map(|p| (p.coords - c).norm_squared()).sum();
    (ss / points.len() as f64).sqrt()
}

/// Per-target spread (sorted by target label) for `beam` over the validation observations.
pub fn five_direction_spread(
    beam: &Beam,
    targets: &BTreeMap<String, Vec<LaserObs>>,
) -> Vec<(String, f64)> {
    targets
        .iter()
        .map(|(name, obs)| {
            let pts: Vec<Point3<f64>> = obs.iter().map(|o| beam.spot(&o.flange, o.d)).collect();
            (name.clone(), spread(&pts))
        })
        .collect()
}

fn mean_spread(beam: &Beam, targets: &BTreeMap<String, Vec<LaserObs>>) -> f64 {
    let s = five_direction_spread(beam, targets);
    if s.is_empty() {
        return f64::NAN;
    }
    s.iter().map(|x| x.1).sum::<f64>() / s.len() as f64
}

/// FRE (RMS residual after rigid registration of `laser` to `reference`) and the mean
/// leave-one-out TRE (register without point i, error at point i), in mm.
pub fn fre_tre(laser: &[Point3<f64>], reference: &[Point3<f64>]) -> Option<(f64, f64)> {
    if laser.len() != reference.len() || laser.len() < 4 {
        return None;
    }
    let t = register_points(laser, reference).ok()?;
    let fre = (laser
        .iter()
        .zip(reference)
        .map(|(a, b)| (t * a - b).norm_squared())
        .sum::<f64>()
        / laser.len() as f64)
        .sqrt();
    let mut tre = 0.0;
    for i in 0..laser.len() {
        let a: Vec<Point3<f64>> = laser
            .iter()
            .enumerate()
            .filter(|(k, _)| *k != i)
            .map(|x| *x.1)
            .collect();
        let b: Vec<Point3<f64>> = reference
            .iter()
            .enumerate()
            .filter(|(k, _)| *k != i)
            .map(|x| *x.1)
            .collect();
        let ti = register_points(&a, &b).ok()?;
        tre += (ti * laser[i] - reference[i]).norm();
    }
    Some((fre, tre / laser.len() as f64))
}

/// One row of the side-by-side table.
#[derive(Debug, Clone, Serialize)]
pub struct MethodRow {
    /// Method label (e.g. `closed-form P1`, `selected P2`, `orthogonal-planes LM`, `direct ML`).
    pub method: String,
    /// Beam origin in the flange frame (mm).
    pub r_mm: [f64; 3],
    /// Beam direction in the flange frame.
    pub v: [f64; 3],
    /// Mean 5-direction spread over the validation targets (mm).
    pub spread_mean_mm: f64,
    /// Standard deviation of the per-target spreads (mm).
    pub spread_std_mm: f64,
    /// FRE after rigid registration of per-target laser points to the reference points (mm).
    pub fre_mm: Option<f64>,
    /// Mean leave-one-out TRE (mm).
    pub tre_mm: Option<f64>,
    /// RMS distance of the predicted validation spots to the true points (mm), when truth is given.
    pub spot_rms_vs_truth_mm: Option<f64>,
    /// Points used by the estimator.
    pub n_used: usize,
    /// Notes (selection iteration, termination, …).
    pub note: String,
}

/// The side-by-side comparison and the final (direct ML) result.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    /// Every method, in the order of the seed's table then ours.
    pub rows: Vec<MethodRow>,
    /// Data-selection traces per plane (iteration, points, score).
    pub selection: BTreeMap<String, Vec<(usize, usize, f64)>>,
    /// The iteration kept per plane.
    pub selection_best: BTreeMap<String, usize>,
    /// Per-target spreads of the final result.
    pub final_spreads: Vec<(String, f64)>,
    /// Outliers flagged by the robust final fit (ids).
    pub outliers: Vec<u64>,
    /// Point-to-plane RMS of the final fit (mm).
    pub final_plane_rms_mm: f64,
    /// Termination of the final fit.
    pub final_termination: String,
    /// Std of the final parameters (r in mm, v unitless), when computable.
    pub final_std: Option<[f64; 6]>,
    #[serde(skip)]
    /// Final beam.
    pub final_beam: Option<Beam>,
    #[serde(skip)]
    /// Final planes (sorted by label).
    pub final_planes: Vec<(String, Plane)>,
}

impl Comparison {
    /// `laser_report.json` content ([`crate::schema::LaserReportFile`]).
    pub fn to_report_file(&self) -> crate::schema::LaserReportFile {
        use crate::schema::{fin, LaserMethodRow, SelectionStep, TargetSpread};
        crate::schema::LaserReportFile {
            format: crate::schema::LASER_REPORT_FORMAT.into(),
            rows: self
                .rows
                .iter()
                .map(|r| LaserMethodRow {
                    method: r.method.clone(),
                    r_mm: r.r_mm,
                    v: r.v,
                    spread_mean_mm: fin(r.spread_mean_mm),
                    spread_std_mm: fin(r.spread_std_mm),
                    fre_mm: r.fre_mm.and_then(fin),
                    tre_mm: r.tre_mm.and_then(fin),
                    spot_rms_vs_truth_mm: r.spot_rms_vs_truth_mm.and_then(fin),
                    n_used: r.n_used,
                    note: r.note.clone(),
                })
                .collect(),
            selection: self
                .selection
                .iter()
                .map(|(k, v)| {
                    (
                        k.clone(),
                        v.iter()
                            .map(|(i, n, s)| SelectionStep {
                                iteration: *i,
                                points: *n,
                                score: fin(*s),
                            })
                            .collect(),
                    )
                })
                .collect(),
            selection_best: self.selection_best.clone(),
            final_spreads: self
                .final_spreads
                .iter()
                .map(|(t, s)| TargetSpread {
                    target: t.clone(),
                    spread_mm: fin(*s),
                })
                .collect(),
            outliers: self.outliers.clone(),
            final_plane_rms_mm: fin(self.final_plane_rms_mm),
            final_termination: self.final_termination.clone(),
            final_std: self.final_std.filter(|s| s.iter().all(|x| x.is_finite())),
        }
    }
}

fn row(
    method: &str,
    beam: &Beam,
    targets: &BTreeMap<String, Vec<LaserObs>>,
    truth: Option<&HashMap<u64, Point3<f64>>>,
    n_used: usize,
    note: String,
) -> MethodRow {
    let spreads: Vec<f64> = five_direction_spread(beam, targets)
        .into_iter()
        .map(|x| x.1)
        .collect();
    let (m, s) = if spreads.is_empty() {
        (f64::NAN, f64::NAN)
    } else {
        let m = spreads.iter().sum::<f64>() / spreads.len() as f64;
        let s = if spreads.len() > 1 {
            (spreads.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (spreads.len() - 1) as f64)
                .sqrt()
        } else {
            0.0
        };
        (m, s)
    };
    let mut fre = None;
    let mut tre = None;
    let mut rms = None;
    if let Some(truth) = truth {
        // Spot RMS over every validation observation with a true point.
        let mut d2 = 0.0;
        let mut n = 0usize;
        let mut laser_pts = Vec::new();
        let mut ref_pts = Vec::new();
        for obs in targets.values() {
            let mut acc = Vector3::zeros();
            let mut k = 0usize;
            let mut reference = None;
            for o in obs {
                let p = beam.spot(&o.flange, o.d);
                if let Some(t) = truth.get(&o.id) {
                    d2 += (p - t).norm_squared();
                    n += 1;
                    reference = Some(*t);
                }
                acc += p.coords;
                k += 1;
            }
            if let (Some(r), true) = (reference, k > 0) {
                laser_pts.push(Point3::from(acc / k as f64));
                ref_pts.push(r);
            }
        }
        if n > 0 {
            rms = Some((d2 / n as f64).sqrt());
        }
        if let Some((f, t)) = fre_tre(&laser_pts, &ref_pts) {
            fre = Some(f);
            tre = Some(t);
        }
    }
    MethodRow {
        method: method.into(),
        r_mm: [beam.r.x, beam.r.y, beam.r.z],
        v: [beam.v.x, beam.v.y, beam.v.z],
        spread_mean_mm: m,
        spread_std_mm: s,
        fre_mm: fre,
        tre_mm: tre,
        spot_rms_vs_truth_mm: rms,
        n_used,
        note,
    }
}

fn trace_rows(t: &SelectionTrace) -> Vec<(usize, usize, f64)> {
    t.steps
        .iter()
        .map(|s| (s.iteration, s.n_points, s.score))
        .collect()
}

/// Run the four estimators on `train` (plane-labelled observations) and score them on the
/// validation observations (`target`-labelled; from `validation` when given separately).
/// `truth` maps validation ids to true points (mm, base frame) when known.
pub fn compare(
    train: &[LaserObs],
    validation: &[LaserObs],
    truth: Option<&HashMap<u64, Point3<f64>>>,
    huber_mm: Option<f64>,
) -> Result<Comparison, LaserError> {
    compare_split(train, validation, validation, truth, huber_mm)
}

/// [`compare`] with the single-plane data selection (seed 000 §1.4 / §2.2) scored on the
/// `selection_obs` targets and every method reported on `validation` targets: with separate target sets the
/// reported spreads are not the ones the selection was tuned on.
pub fn compare_split(
    train: &[LaserObs],
    selection_obs: &[LaserObs],
    validation: &[LaserObs],
    truth: Option<&HashMap<u64, Point3<f64>>>,
    huber_mm: Option<f64>,
) -> Result<Comparison, LaserError> {
    let planes = by_plane(train);
    if planes.is_empty() {
        return Err(LaserError::TooFewData {
            what: "plane-labelled calibration poses (`plane` field)".into(),
            need: 1,
            got: 0,
        });
    }
    let targets = by_target(validation);
    let sel_targets = by_target(selection_obs);
    let mut rows = Vec::new();
    let mut singles: Vec<(String, Beam, Plane)> = Vec::new();
    for (label, obs) in &planes {
        match closed_form_single_plane(obs) {
            Ok((b, p)) => {
                rows.push(row(
                    &format!("closed-form {label}"),
                    &b,
                    &targets,
                    truth,
                    obs.len(),
                    "seed §1.3".into(),
                ));
                singles.push((label.clone(), b, p));
            }
            Err(e) => rows.push(MethodRow {
                method: format!("closed-form {label}"),
                r_mm: [f64::NAN; 3],
                v: [f64::NAN; 3],
                spread_mean_mm: f64::NAN,
                spread_std_mm: f64::NAN,
                fre_mm: None,
                tre_mm: None,
                spot_rms_vs_truth_mm: None,
                n_used: obs.len(),
                note: format!("failed: {e}"),
            }),
        }
    }
    if singles.is_empty() {
        return Err(LaserError::Degenerate(
            "no single plane could be solved in closed form".into(),
        ));
    }
    // Data selection per plane, scored by the 5-direction spread (or, with no validation
    // targets, by the point-to-plane RMS of all of that plane's data).
    let mut selection = BTreeMap::new();
    let mut selection_best = BTreeMap::new();
    let mut selected: Vec<(String, Beam, Plane)> = Vec::new();
    for (label, obs) in &planes {
        let all = obs.clone();
        let score = |b: &Beam| -> f64 {
            if sel_targets.is_empty() {
                let pts: Vec<Point3<f64>> = all.iter().map(|o| b.spot(&o.flange, o.d)).collect();
                super::fit::pca_plane(&pts)
                    .map(|pl| {
                        (pts.iter().map(|p| pl.distance(p).powi(2)).sum::<f64>() / pts.len() as f64)
                            .sqrt()
                    })
                    .unwrap_or(f64::INFINITY)
            } else {
                mean_spread(b, &sel_targets)
            }
        };
        let max_drop = obs.len().saturating_sub(20).min(40);
        if let Ok((b, p, trace)) = select_data(obs, &score, max_drop) {
            let kept = trace.steps.get(trace.best_iteration).map(|s| s.n_points);
            rows.push(row(
                &format!("selected {label}"),
                &b,
                &targets,
                truth,
                kept.unwrap_or(obs.len()),
                format!("best at iteration {}", trace.best_iteration),
            ));
            selection.insert(label.clone(), trace_rows(&trace));
            selection_best.insert(label.clone(), trace.best_iteration);
            selected.push((label.clone(), b, p));
        }
    }
    // Start of the multi-plane fits: mean of the (selected, else closed-form) single-plane results.
    let base: &Vec<(String, Beam, Plane)> = if selected.len() == singles.len() {
        &selected
    } else {
        &singles
    };
    let k = base.len() as f64;
    let r0 = base.iter().fold(Vector3::zeros(), |a, x| a + x.1.r) / k;
    let v0 = Unit::new_normalize(
        base.iter()
            .fold(Vector3::zeros(), |a, x| a + x.1.v.into_inner())
            / k,
    );
    let start = Beam { r: r0, v: v0 };
    let labels: Vec<String> = base.iter().map(|x| x.0.clone()).collect();
    let data: Vec<Vec<LaserObs>> = labels.iter().map(|l| planes[l].clone()).collect();
    let start_planes: Vec<Plane> = base.iter().map(|x| x.2).collect();
    let n_all: usize = data.iter().map(|d| d.len()).sum();
    let ortho = fit_orthogonal_planes(&data, &start, &start_planes)?;
    rows.push(row(
        if labels.len() >= 3 {
            "orthogonal-planes LM"
        } else {
            "multi-plane LM"
        },
        &ortho.beam,
        &targets,
        truth,
        n_all,
        format!("seed eq. 16-18; {}", ortho.report.termination.describe()),
    ));
    let direct: MultiPlaneFit = fit_direct(
        &data,
        &ortho.beam,
        &ortho.planes,
        DirectOptions {
            huber_mm,
            ..Default::default()
        },
    )?;
    rows.push(row(
        "direct ML",
        &direct.beam,
        &targets,
        truth,
        n_all,
        format!(
            "point-to-plane, {}{}",
            if huber_mm.is_some() { "Huber, " } else { "" },
            direct.report.termination.describe()
        ),
    ));
    Ok(Comparison {
        rows,
        selection,
        selection_best,
        final_spreads: five_direction_spread(&direct.beam, &targets),
        outliers: direct.outliers.clone(),
        final_plane_rms_mm: direct.rms_mm,
        final_termination: direct.report.termination.describe().into(),
        final_std: direct.std,
        final_beam: Some(direct.beam),
        final_planes: labels.into_iter().zip(direct.planes).collect(),
    })
}

/// A plain-text table of the comparison.
pub fn table(c: &Comparison) -> String {
    let f = |x: Option<f64>| x.map_or("-".to_string(), |v| format!("{v:.3}"));
    let mut s = format!(
        "{:<22} {:>6} {:>15} {:>9} {:>9} {:>13}  {}\n",
        "method", "points", "spread mm", "FRE mm", "TRE mm", "RMS vs truth", "note"
    );
    for r in &c.rows {
        s.push_str(&format!(
            "{:<22} {:>6} {:>7.3} ± {:<5.3} {:>9} {:>9} {:>13}  {}\n",
            r.method,
            r.n_used,
            r.spread_mean_mm,
            r.spread_std_mm,
            f(r.fre_mm),
            f(r.tre_mm),
            f(r.spot_rms_vs_truth_mm),
            r.note
        ));
    }
    s
}

/// Angle (deg) between the PCA normals of every pair of faces of a scanned object (seed 000
/// §2.3.3: faces of a machined block; the nominal angle is 90°). Faces with fewer than 3
/// points are skipped. Sorted by face labels.
pub fn face_angles(faces: &BTreeMap<String, Vec<Point3<f64>>>) -> Vec<(String, String, f64)> {
    let normals: Vec<(&String, Vector3<f64>)> = faces
        .iter()
        .filter_map(|(k, pts)| super::fit::pca_plane(pts).map(|p| (k, p.n.into_inner())))
        .collect();
    let mut out = Vec::new();
    for i in 0..normals.len() {
        for j in (i + 1)..normals.len() {
            let c = normals[i].1.dot(&normals[j].1).abs().min(1.0);
            // Angle between the planes, folded into [0°, 90°].
            out.push((
                normals[i].0.clone(),
                normals[j].0.clone(),
                c.acos().to_degrees(),
            ));
        }
    }
    out
}

/// Point-to-surface statistics of a scan against a plane: (RMS, max |d|, mean d) in mm.
pub fn plane_stats(points: &[Point3<f64>], plane: &Plane) -> (f64, f64, f64) {
    if points.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    let d: Vec<f64> = points.iter().map(|p| plane.distance(p)).collect();
    let n = d.len() as f64;
    let rms = (d.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
    let max = d.iter().fold(0.0f64, |a, x| a.max(x.abs()));
    (rms, max, d.iter().sum::<f64>() / n)
}

/// ASCII PLY of a point cloud (mm, robot base frame); `label` per point goes in a comment.
pub fn ply(points: &[Point3<f64>], comment: &str) -> String {
    let mut s = String::from("ply\nformat ascii 1.0\n");
    for line in comment.lines() {
        s.push_str(&format!("comment {line}\n"));
    }
    s.push_str(&format!(
        "element vertex {}\nproperty double x\nproperty double y\nproperty double z\nend_header\n",
        points.len()
    ));
    for p in points {
        s.push_str(&format!("{:.6} {:.6} {:.6}\n", p.x, p.y, p.z));
    }
    s
}

/// Refuses true points (`--truth`, mm in the robot base) that are in metres: every point
/// within 10 mm of the base origin while the flanges of the same poses are hundreds of mm
/// away, or several distinct points spreading over less than 1 % of what those flanges
/// spread over (the spots are a sensor's range from the flange).
pub fn check_truth_units(
    truth: &HashMap<u64, Point3<f64>>,
    obs: &[LaserObs],
    file: &std::path::Path,
) -> Result<(), LaserError> {
    let flanges: Vec<Point3<f64>> = obs
        .iter()
        .filter(|o| truth.contains_key(&o.id))
        .map(|o| Point3::from(o.flange.translation.vector))
        .collect();
    let pts: Vec<Point3<f64>> = obs
        .iter()
        .filter_map(|o| truth.get(&o.id))
        .copied()
        .collect();
    if pts.is_empty() {
        return Ok(());
    }
    let far = |v: &[Point3<f64>]| {
        let mut n: Vec<f64> = v.iter().map(|p| p.coords.norm()).collect();
        n.sort_by(f64::total_cmp);
        n[n.len() / 2]
    };
    let (st, sf) = (
        crate::plausible::dataset::spread(&pts),
        crate::plausible::dataset::spread(&flanges),
    );
    let metres = (pts.iter().all(|p| p.coords.norm() < 10.0) && far(&flanges) > 100.0)
        || (st > 1e-9 && sf > 20.0 && st < 0.01 * sf);
    if metres {
        return Err(LaserError::Calibration(format!(
            "{}: the true points look like metres: they lie {:.4} from the base origin \
             (median) and spread over {st:.4} while the flanges of the same poses are {:.0} mm \
             away and spread over {sf:.1} mm; files use mm",
            file.display(),
            far(&pts),
            far(&flanges)
        )));
    }
    Ok(())
}
