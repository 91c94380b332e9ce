//! What each deployed artifact delivers on its own. The verdict is earned by
//! the diagnosed model (geometry + effects) through `robocal predict` / `correct`; a URDF holds
//! the geometry only. Each artifact is scored on the same held-out poses and judged against
//! the same acceptance spec, so the report can say which one to deploy and warn when one alone
//! would fail the spec.
use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::{accept, SessionFile};
use crate::solve::metrics;

/// One deployed artifact and the held-out accuracy it delivers on its own.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArtifactAccuracy {
    /// Path relative to the session directory (`deploy/robot.urdf`).
    pub artifact: String,
    /// What it holds, in words.
    pub contains: String,
    /// How it is used.
    pub how: String,
    /// Held-out RMS / max error (mm) and mean relative distance error (%) of its predictions.
    pub heldout_rms_mm: f64,
    pub heldout_max_mm: f64,
    pub relative_distance_pct: Option<f64>,
    /// Whether the session's acceptance spec passes with this artifact alone.
    pub passes: bool,
    /// The criteria it fails alone (`held-out RMS = 0.735 mm (limit ≤ 0.5 mm)`).
    #[serde(default)]
    pub fails: Vec<String>,
}

/// An artifact and its predictions of the held-out marker positions.
pub struct Candidate<'a> {
    pub artifact: &'a str,
    pub contains: String,
    pub how: &'a str,
    pub predicted: &'a [Point3<f64>],
}

/// Scores each candidate on the measured held-out points `meas` against `s.accept`.
pub fn score(s: &SessionFile, meas: &[Point3<f64>], cands: &[Candidate]) -> Vec<ArtifactAccuracy> {
    cands
        .iter()
        .map(|c| {
            let e: Vec<f64> = c
                .predicted
                .iter()
                .zip(meas)
                .map(|(p, m)| (p - m).norm())
                .collect();
            let rms = crate::solve::stats::rms(&e);
            let max = e.iter().cloned().fold(0.0, f64::max);
            let rel = metrics::relative_distance(c.predicted, meas, 50.0).map(|r| r.mean_pct);
            let mut m = s.measured.clone();
            m.heldout_rms_mm_after = Some(rms);
            m.heldout_max_mm_after = Some(max);
            m.relative_distance_pct_after = rel;
            let v = accept::judge_kind(&s.accept, &m, vec![], s.setup.kind);
            // Judged on what the held-out poses can say of the artifact alone: a criterion
            // this scoring cannot evaluate (the verify stage's, measured later) is not a failure.
            let fails: Vec<String> = v
                .criteria
                .iter()
                .filter(|c| c.ok == Some(false))
                .map(|c| format!("{} = {} (limit {})", c.name, c.value, c.limit))
                .collect();
            ArtifactAccuracy {
                artifact: c.artifact.into(),
                contains: c.contains.clone(),
                how: c.how.into(),
                heldout_rms_mm: rms,
                heldout_max_mm: max,
                relative_distance_pct: rel,
                passes: v.verdict != accept::VerdictKind::Fail && fails.is_empty(),
                fails,
            }
        })
        .collect()
}

/// One line per artifact, for the terminal: what it delivers, and a warning when it alone
/// fails the spec.
pub fn lines(s: &SessionFile) -> Vec<String> {
    s.deploy_accuracy
        .iter()
        .map(|a| {
            let rel = a
                .relative_distance_pct
                .map_or(String::new(), |r| format!(", relative distance {r:.3} %"));
            let verdict = if a.passes {
                "meets the spec".to_string()
            } else {
                format!("WARNING: alone it FAILS the spec ({})", a.fails.join("; "))
            };
            format!(
                "deploy {} ({}; {}): held-out RMS {:.4} mm, max {:.4} mm{rel} — {verdict}",
                a.artifact, a.contains, a.how, a.heldout_rms_mm, a.heldout_max_mm
            )
        })
        .collect()
}
