//! Accuracy metrics of seed 001 §3 and ISO 9283, computed on held-out poses.
//!
//! All metrics compare measured marker points with a model's predictions for the same
//! joint readings, so "before" (nominal, base/tool fitted) and "after" (identified) are
//! scored on identical data:
//! - **relative distance error** (%): distance of every point from a reference point
//!   (the first), measured vs model, `|L_meas − L_model| / L_model · 100` (eq. 13). It
//!   needs no tracker–robot registration.
//! - **inverse-solution coincidence error** (mm): poses sharing a `point` but reached by
//!   different IK `branch`es. If the controller had aimed them all at the same target with
//!   this model, each branch would land at `target + e_b` with `e_b = measured − predicted`;
//!   the error is the largest distance of the `e_b` from their mean. With the nominal model
//!   and nominal IK commands this equals the raw spread of the measured points.
//! - absolute position RMS and max (mm).
//! - ISO 9283 position accuracy AP (distance of the barycentre of repeated visits from the
//!   model's prediction) and repeatability RP (`l̄ + 3·S_l`), where a `(point, branch)` was
//!   visited at least twice.
use std::collections::BTreeMap;

use nalgebra::{Point3, Vector3};

use super::obs::PoseObs;
use super::stats;

/// Relative distance error statistics (%).
#[derive(Debug, Clone, PartialEq)]
pub struct RelativeDistance {
    pub mean_pct: f64,
    pub max_pct: f64,
    pub std_pct: f64,
    pub n: usize,
}

/// Relative distance error of `pred` vs `meas` with the first point as reference; pairs
/// closer than `min_dist_mm` are skipped. `None` with fewer than two usable points.
pub fn relative_distance(
    pred: &[Point3<f64>],
    meas: &[Point3<f64>],
    min_dist_mm: f64,
) -> Option<RelativeDistance> {
    if pred.len() != meas.len() || pred.len() < 2 {
        return None;
    }
    let (p0, m0) = (pred[0], meas[0]);
    let v: Vec<f64> = pred
        .iter()
        .zip(meas)
        .skip(1)
        .filter_map(|(p, m)| {
            let lm = (p - p0).norm();
            let lmeas = (m - m0).norm();
            (lm > min_dist_mm).then(|| (lmeas - lm).abs() / lm * 100.0)
        })
        .collect();
    if v.is_empty() {
        return None;
    }
    Some(RelativeDistance {
        mean_pct: stats::mean(&v),
        max_pct: v.iter().cloned().fold(0.0, f64::max),
        std_pct: stats::std_dev(&v),
        n: v.len(),
    })
}

/// Inverse-solution coincidence error over all multi-branch points (mm).
#[derive(Debug, Clone, PartialEq)]
pub struct Coincidence {
    /// Per point: (`point`, number of branches, error mm).
    pub per_point: Vec<(u64, usize, f64)>,
    pub mean_mm: f64,
    pub std_mm: f64,
    pub max_mm: f64,
}

/// See the module docs. `None` when no `point` was reached by two or more branches.
pub fn coincidence(obs: &[PoseObs], pred: &[Point3<f64>]) -> Option<Coincidence> {
    let mut groups: BTreeMap<u64, Vec<(u64, Vector3<f64>)>> = BTreeMap::new();
    for (o, p) in obs.iter().zip(pred) {
        if let (Some(pt), Some(br)) = (o.point, o.branch) {
            groups.entry(pt).or_default().push((br, o.p - p));
        }
    }
    let mut per_point = Vec::new();
    for (pt, g) in groups {
        // One residual per distinct branch (average repeated visits of a branch).
        let mut by_branch: BTreeMap<u64, (Vector3<f64>, usize)> = BTreeMap::new();
        for (b, e) in g {
            let s = by_branch.entry(b).or_insert((Vector3::zeros(), 0));
            s.0 += e;
            s.1 += 1;
        }
        if by_branch.len() < 2 {
            continue;
        }
        let es: Vec<Vector3<f64>> = by_branch.values().map(|(s, n)| s / *n as f64).collect();
        let mean = es.iter().fold(Vector3::zeros(), |s, e| s + e) / es.len() as f64;
        let err = es.iter().map(|e| (e - mean).norm()).fold(0.0, f64::max);
        per_point.push((pt, es.len(), err));
    }
    if per_point.is_empty() {
        return None;
    }
    let v: Vec<f64> = per_point.iter().map(|x| x.2).collect();
    Some(Coincidence {
        mean_mm: stats::mean(&v),
        std_mm: stats::std_dev(&v),
        max_mm: v.iter().cloned().fold(0.0, f64::max),
        per_point,
    })
}

/// ISO 9283 position accuracy / repeatability (mm), averaged over repeated targets.
#[derive(Debug, Clone, PartialEq)]
pub struct Iso9283 {
    /// Number of `(point, branch)` targets visited ≥ 2 times.
    pub targets: usize,
    pub ap_mean_mm: f64,
    pub ap_max_mm: f64,
    pub rp_mean_mm: f64,
    pub rp_max_mm: f64,
}

/// (measured, predicted) points of repeated visits of one target.
type Visits = Vec<(Point3<f64>, Point3<f64>)>;

/// See the module docs. `None` when no target was visited twice.
pub fn iso9283(obs: &[PoseObs], pred: &[Point3<f64>]) -> Option<Iso9283> {
    let mut groups: BTreeMap<(u64, u64), Visits> = BTreeMap::new();
    for (o, p) in obs.iter().zip(pred) {
        if let (Some(pt), Some(br)) = (o.point, o.branch) {
            groups.entry((pt, br)).or_default().push((o.p, *p));
        }
    }
    let mut ap = Vec::new();
    let mut rp = Vec::new();
    for g in groups.values().filter(|g| g.len() >= 2) {
        let n = g.len() as f64;
        let bary = g.iter().fold(Vector3::zeros(), |s, (m, _)| s + m.coords) / n;
        let cmd = g.iter().fold(Vector3::zeros(), |s, (_, p)| s + p.coords) / n;
        ap.push((bary - cmd).norm());
        let l: Vec<f64> = g.iter().map(|(m, _)| (m.coords - bary).norm()).collect();
        rp.push(stats::mean(&l) + 3.0 * stats::std_dev(&l));
    }
    if ap.is_empty() {
        return None;
    }
    Some(Iso9283 {
        targets: ap.len(),
        ap_mean_mm: stats::mean(&ap),
        ap_max_mm: ap.iter().cloned().fold(0.0, f64::max),
        rp_mean_mm: stats::mean(&rp),
        rp_max_mm: rp.iter().cloned().fold(0.0, f64::max),
    })
}

/// All metrics of one model on one set of poses.
#[derive(Debug, Clone, PartialEq)]
pub struct Scores {
    pub n: usize,
    pub rms_mm: f64,
    pub max_mm: f64,
    pub relative: Option<RelativeDistance>,
    pub coincidence: Option<Coincidence>,
    pub iso: Option<Iso9283>,
}

/// Score predictions `pred` of the observations `obs`.
pub fn score(obs: &[PoseObs], pred: &[Point3<f64>]) -> Scores {
    let e: Vec<f64> = obs
        .iter()
        .zip(pred)
        .map(|(o, p)| (o.p - p).norm())
        .collect();
    let meas: Vec<Point3<f64>> = obs.iter().map(|o| o.p).collect();
    Scores {
        n: obs.len(),
        rms_mm: stats::rms(&e),
        max_mm: e.iter().cloned().fold(0.0, f64::max),
        relative: relative_distance(pred, &meas, 1.0),
        coincidence: coincidence(obs, pred),
        iso: iso9283(obs, pred),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs(id: u64, point: u64, branch: u64, p: [f64; 3]) -> PoseObs {
        let mut o = PoseObs::at(id, 0.0, vec![0.0; 6], Point3::new(p[0], p[1], p[2]));
        o.point = Some(point);
        o.branch = Some(branch);
        o
    }

    #[test]
    fn relative_distance_of_scaled_points() {
        let pred = vec![
            Point3::origin(),
            Point3::new(100.0, 0.0, 0.0),
            Point3::new(0.0, 200.0, 0.0),
        ];
        let meas: Vec<_> = pred
            .iter()
            .map(|p| Point3::from(p.coords * 1.002))
            .collect();
        let r = relative_distance(&pred, &meas, 1.0).unwrap();
        assert!((r.mean_pct - 0.2).abs() < 1e-9, "{r:?}");
        assert_eq!(r.n, 2);
        // translation-invariant
        let shifted: Vec<_> = meas
            .iter()
            .map(|p| p + Vector3::new(5.0, -3.0, 1.0))
            .collect();
        let r2 = relative_distance(&pred, &shifted, 1.0).unwrap();
        assert!((r2.mean_pct - r.mean_pct).abs() < 1e-9);
        assert!(relative_distance(&pred[..1], &meas[..1], 1.0).is_none());
    }

    #[test]
    fn coincidence_is_max_distance_from_mean_of_branches() {
        // point 0: 3 branches land at x = 0, 1, 2 (predicted all at origin) → mean 1, max 1
        // point 1: single branch → ignored
        let o = vec![
            obs(0, 0, 0, [0.0, 0.0, 0.0]),
            obs(1, 0, 1, [1.0, 0.0, 0.0]),
            obs(2, 0, 2, [2.0, 0.0, 0.0]),
            obs(3, 1, 0, [9.0, 9.0, 9.0]),
        ];
        let pred = vec![Point3::origin(); 4];
        let c = coincidence(&o, &pred).unwrap();
        assert_eq!(c.per_point, vec![(0, 3, 1.0)]);
        // a perfect model (pred = meas) gives 0
        let pred2: Vec<_> = o.iter().map(|x| x.p).collect();
        assert!(coincidence(&o, &pred2).unwrap().mean_mm < 1e-12);
        assert!(coincidence(&o[3..], &pred[3..]).is_none());
    }

    #[test]
    fn iso9283_accuracy_and_repeatability() {
        let o = vec![
            obs(0, 0, 0, [1.0, 0.0, 0.0]),
            obs(1, 0, 0, [1.2, 0.0, 0.0]),
            obs(2, 0, 0, [0.8, 0.0, 0.0]),
        ];
        let pred = vec![Point3::origin(); 3];
        let r = iso9283(&o, &pred).unwrap();
        assert_eq!(r.targets, 1);
        assert!((r.ap_mean_mm - 1.0).abs() < 1e-12);
        // l = [0, 0.2, 0.2]: mean 0.1333, std 0.11547 → RP = 0.4797
        assert!((r.rp_mean_mm - (0.4 / 3.0 + 3.0 * 0.115_470_053_837_925_15)).abs() < 1e-9);
        let s = score(&o, &pred);
        assert!((s.max_mm - 1.2).abs() < 1e-12);
        assert!(s.iso.is_some() && s.coincidence.is_none());
    }
}
