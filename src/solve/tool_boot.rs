//! Uncertainty of the tool identifications: [`tool_with_arm`] with a bootstrap
//! over poses (std of every tool / base parameter), and the guide tool's frame with its
//! spread from the pin tips' pivot intervals (Monte Carlo). mm / rad inside.
use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::obs::PoseObs;
use super::tool::{guide_tool_frame, tool_with_arm, GuideFrame, ToolFit};
use super::{stats, SolveError};
use crate::model::{KinematicModel, ParamGroup};

/// [`tool_with_arm`] plus the bootstrap std of each base / tool parameter (internal units).
#[derive(Debug, Clone)]
pub struct ToolBoot {
    pub fit: ToolFit,
    /// The arm with the fitted base and tool.
    pub model: KinematicModel,
    /// `(name, std)` of every base / tool parameter (mm or rad).
    pub std: Vec<(String, f64)>,
    /// Replicates that converged.
    pub replicates: usize,
}

fn base_tool(model: &KinematicModel) -> Vec<(String, f64)> {
    model
        .params()
        .iter()
        .filter(|p| matches!(p.group, ParamGroup::Base | ParamGroup::Tool))
        .map(|p| (p.name.clone(), p.value))
        .collect()
}

/// Tool identification with the arm fixed, with `reps` bootstrap replicates over poses.
pub fn tool_with_arm_boot(
    arm: &KinematicModel,
    obs: &[PoseObs],
    reps: usize,
    seed: u64,
) -> Result<ToolBoot, SolveError> {
    let fit = tool_with_arm(arm, obs)?;
    let mut model = arm.clone();
    model.set_base(&fit.base);
    model.set_tool(&fit.tool);
    let centre = base_tool(&model);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut samples: Vec<Vec<f64>> = vec![Vec::new(); centre.len()];
    let mut ok = 0;
    for _ in 0..reps {
        let s: Vec<PoseObs> = (0..obs.len())
            .map(|_| obs[rng.random_range(0..obs.len())].clone())
            .collect();
        let Ok(f) = tool_with_arm(arm, &s) else {
            continue;
        };
        let mut m = arm.clone();
        m.set_base(&f.base);
        m.set_tool(&f.tool);
        for (k, (_, v)) in base_tool(&m).into_iter().enumerate() {
            samples[k].push(v - centre[k].1);
        }
        ok += 1;
    }
    let std = centre
        .iter()
        .zip(&samples)
        .map(|((n, _), s)| {
            (
                n.clone(),
                if s.len() > 1 {
                    stats::std_dev(s)
                } else {
                    f64::NAN
                },
            )
        })
        .collect();
    Ok(ToolBoot {
        fit,
        model,
        std,
        replicates: ok,
    })
}

/// The guide tool frame and its spread: the pin tips `q1`, `q2` (marker frame) with per-axis
/// standard deviations `s1`, `s2` (e.g. a 95 % pivot interval / 3.92).
#[derive(Debug, Clone)]
pub struct GuideSpread {
    pub frame: GuideFrame,
    /// Std of the axis direction (rad, angle to the central axis) and of the origin (mm,
    /// distance to the central origin), over Monte Carlo draws.
    pub axis_std_deg: f64,
    pub origin_std_mm: f64,
    pub protrusion_std_mm: f64,
}

/// [`guide_tool_frame`] with Monte Carlo spread (`draws` samples of the tips).
pub fn guide_with_spread(
    q1: &Point3<f64>,
    q2: &Point3<f64>,
    s1: &Vector3<f64>,
    s2: &Vector3<f64>,
    l1: f64,
    draws: usize,
    seed: u64,
) -> Result<GuideSpread, SolveError> {
    let frame = guide_tool_frame(q1, q2, l1)?;
    if !s1
        .iter()
        .chain(s2.iter())
        .all(|s| s.is_finite() && *s >= 0.0)
    {
        return Err(SolveError::Invalid(
            "guide tool: tip standard deviations must be finite and ≥ 0".into(),
        ));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n01 = Normal::new(0.0, 1.0).map_err(|e| SolveError::Invalid(e.to_string()))?;
    let (mut ang, mut org, mut pro) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..draws {
        let a = q1 + s1.component_mul(&Vector3::from_fn(|_, _| n01.sample(&mut rng)));
        let b = q2 + s2.component_mul(&Vector3::from_fn(|_, _| n01.sample(&mut rng)));
        if let Ok(g) = guide_tool_frame(&a, &b, l1) {
            ang.push(g.axis.angle(&frame.axis).to_degrees());
            org.push((g.origin - frame.origin).norm());
            pro.push(g.protrusion - frame.protrusion);
        }
    }
    // RMS about the central value (the angle and the distance are ≥ 0).
    Ok(GuideSpread {
        frame,
        axis_std_deg: stats::rms(&ang),
        origin_std_mm: stats::rms(&org),
        protrusion_std_mm: stats::std_dev(&pro),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn guide_spread_grows_with_tip_noise_and_vanishes_without() {
        let q1 = Point3::new(0.0, 0.0, 100.0);
        let q2 = Point3::new(0.0, 0.0, 150.0);
        let z = Vector3::zeros();
        let g0 = guide_with_spread(&q1, &q2, &z, &z, 40.0, 200, 1).unwrap();
        assert!(g0.axis_std_deg < 1e-9 && g0.origin_std_mm < 1e-9);
        let s = Vector3::new(0.1, 0.1, 0.1);
        let g = guide_with_spread(&q1, &q2, &s, &s, 40.0, 2000, 1).unwrap();
        // Axis: two tips 50 mm apart, 0.1 mm lateral per axis each → ≈ √2·√2·0.1/50 rad RMS.
        let expect = (2.0f64 * 2.0).sqrt() * 0.1 / 50.0;
        assert!(
            (g.axis_std_deg.to_radians() / expect - 1.0).abs() < 0.15,
            "{g:?}"
        );
        assert!(g.origin_std_mm > 0.05 && g.origin_std_mm < 0.3, "{g:?}");
        assert!(
            guide_with_spread(&q1, &q2, &Vector3::new(f64::NAN, 0.0, 0.0), &s, 40.0, 10, 1)
                .is_err()
        );
    }
}
