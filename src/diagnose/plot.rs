//! SVG plots: partial residual of each accepted effect against its regressor.
//!
//! For an effect acting on joint `j` the x axis is the effect's angle correction `δθ_j`
//! (millidegrees) and the y axis the partial residual (final residual plus the effect's own
//! contribution) expressed as an angle of joint `j` (projection onto `∂p/∂θ_j`). For other
//! effects x is the size of the effect's displacement (mm) and y the partial residual along
//! it. In both cases a correct effect puts the points on the line y = x.
use nalgebra::Vector3;
use plotters::prelude::*;
use std::path::Path;

use super::effects::{apply_effects_np, np_correction, Block, Effect, EffectModel};
use super::error::PlotError;
use super::fit::State;
use crate::solve::obs::PoseObs;

/// One scatter plot: its (x, y) pairs and the x and y axis labels.
pub type Scatter = (Vec<(f64, f64)>, String, String);

/// A [`Scatter`] with one entry per pose (`None` where the pose gives no point).
pub type PoseScatter = (Vec<Option<(f64, f64)>>, String, String);

/// (x, y) pairs of the partial-residual plot of `state.effects[idx]`, and axis labels.
pub fn partial_residual(state: &State, obs: &[PoseObs], idx: usize) -> Scatter {
    partial_residuals(state, obs, &[idx])
        .pop()
        .expect("one plot per index")
}

/// [`partial_residual`] of each effect `idxs[i]`, one pass over the poses: each pose's
/// prediction with every effect, its kernel corrections and its parameter Jacobian are
/// computed once for all the plots (the same values as one plot at a time).
pub fn partial_residuals(state: &State, obs: &[PoseObs], idxs: &[usize]) -> Vec<Scatter> {
    partial_residuals_per_pose(state, obs, idxs)
        .into_iter()
        .map(|(pts, xl, yl)| (pts.into_iter().flatten().collect(), xl, yl))
        .collect()
}

/// [`partial_residuals`] with one entry per pose of `obs` (`None` where the projection on
/// the joint's column is degenerate), so that a caller can pair each point with its pose.
pub fn partial_residuals_per_pose(
    state: &State,
    obs: &[PoseObs],
    idxs: &[usize],
) -> Vec<PoseScatter> {
    // Per plot: the other effects, and the joint it projects on. Effects that act on a
    // joint angle project on that joint; link deflection moves the point directly (its
    // joint is where it bends, not an angle).
    let plots: Vec<(usize, Vec<Effect>, Option<usize>)> = idxs
        .iter()
        .map(|&idx| {
            let e = &state.effects[idx];
            let others: Vec<Effect> = state
                .effects
                .iter()
                .enumerate()
                .filter(|(i, _)| *i != idx)
                .map(|(_, e)| e.clone())
                .collect();
            let joint = e
                .block
                .joint()
                .filter(|_| !matches!(e.block, Block::LinkDeflection(_)));
            (idx, others, joint)
        })
        .collect();
    // Every pose on its own (in parallel, collected in pose order): the kernel sums of the
    // correction once per pose, not twice per plot.
    use rayon::prelude::*;
    let per_pose: Vec<Vec<Option<(f64, f64)>>> = obs
        .par_iter()
        .map(|o| {
            let np: Vec<Option<Vector3<f64>>> = state
                .effects
                .iter()
                .map(|e| np_correction(&state.model, e, &o.ctx))
                .collect();
            let full = apply_effects_np(
                &state.model,
                &state.effects,
                &o.ctx,
                np.iter().flatten().copied(),
            );
            let mut jm = None;
            plots
                .iter()
                .map(|(idx, others, joint)| {
                    let np_others = np
                        .iter()
                        .enumerate()
                        .filter(|(i, _)| i != idx)
                        .filter_map(|(_, c)| *c);
                    let without = apply_effects_np(&state.model, others, &o.ctx, np_others);
                    let g: Vector3<f64> = full - without;
                    let r = o.p - full;
                    let pr = r + g;
                    match joint {
                        Some(j) => {
                            let jm = jm.get_or_insert_with(|| {
                                state.model.point_param_jacobian(&o.ctx.q).1
                            });
                            let ip = state.model.param_index(&format!("phi{j}"))?;
                            let c = jm.column(ip).into_owned();
                            let n2 = c.norm_squared();
                            if n2 < 1e-9 {
                                return None;
                            }
                            let x = g.dot(&c) / n2;
                            let y = pr.dot(&c) / n2;
                            Some((x.to_degrees() * 1e3, y.to_degrees() * 1e3))
                        }
                        None => {
                            let n = g.norm();
                            if n < 1e-12 {
                                return Some((0.0, 0.0));
                            }
                            Some((n, pr.dot(&(g / n))))
                        }
                    }
                })
                .collect()
        })
        .collect();
    plots
        .iter()
        .enumerate()
        .map(|(k, (idx, _, joint))| {
            let pts: Vec<Option<(f64, f64)>> = per_pose.iter().map(|p| p[k]).collect();
            let e = &state.effects[*idx];
            let (xl, yl) = match joint {
                Some(j) => (
                    format!("{} correction of joint {j} (mdeg)", e.block.kind()),
                    format!("partial residual as joint-{j} angle (mdeg)"),
                ),
                None => (
                    format!("{} displacement (mm)", e.block.kind()),
                    "partial residual along it (mm)".to_string(),
                ),
            };
            (pts, xl, yl)
        })
        .collect()
}

/// The plotting library's error `e` on the plot `path`.
fn err(path: &Path, e: impl std::fmt::Display) -> PlotError {
    PlotError {
        path: path.to_path_buf(),
        why: e.to_string(),
    }
}

/// Write one SVG scatter with the y = x line.
pub fn write_svg(
    path: &Path,
    title: &str,
    pts: &[(f64, f64)],
    xl: &str,
    yl: &str,
) -> Result<(), PlotError> {
    let lo = pts
        .iter()
        .flat_map(|(x, y)| [*x, *y])
        .filter(|v| v.is_finite())
        .fold(f64::INFINITY, f64::min);
    let hi = pts
        .iter()
        .flat_map(|(x, y)| [*x, *y])
        .filter(|v| v.is_finite())
        .fold(f64::NEG_INFINITY, f64::max);
    let (lo, hi) = if lo.is_finite() && hi > lo {
        let m = 0.05 * (hi - lo);
        (lo - m, hi + m)
    } else {
        (-1.0, 1.0)
    };
    let root = SVGBackend::new(path, (720, 540)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(lo..hi, lo..hi)
        .map_err(|e| err(path, e))?;
    chart
        .configure_mesh()
        .x_desc(xl)
        .y_desc(yl)
        .draw()
        .map_err(|e| err(path, e))?;
    chart
        .draw_series(
            pts.iter()
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .map(|(x, y)| Circle::new((*x, *y), 2, BLUE.filled())),
        )
        .map_err(|e| err(path, e))?;
    chart
        .draw_series(LineSeries::new(vec![(lo, lo), (hi, hi)], RED))
        .map_err(|e| err(path, e))?;
    root.present().map_err(|e| err(path, e))?;
    Ok(())
}

/// The driver of an effect at one pose (the quantity its regressor is a function of) and
/// its axis label: joint angle, harmonic phase, temperature, gravity torque, bending moment.
pub fn driver_value(state: &State, e: &Effect, o: &PoseObs) -> (f64, String) {
    e.block.plot_driver(&state.model, o)
}

/// Residual against the driver of `state.effects[idx]`: per pose (driver, partial residual,
/// the effect's own fitted contribution), the y values in the units of
/// [`partial_residual`] (joint-angle mdeg for joint-angle effects, mm along the effect's
/// displacement otherwise), and the axis labels.
pub fn driver_residual(
    state: &State,
    obs: &[PoseObs],
    idx: usize,
) -> (Vec<(f64, f64, f64)>, String, String) {
    let (_, _, yl) = partial_residual(state, &obs[..obs.len().min(1)], idx);
    let e = &state.effects[idx];
    let mut xl = String::new();
    // `partial_residual` skips poses where the projection is degenerate: recompute the
    // per-pose pairs so that drivers and residuals stay aligned.
    let mut out = Vec::with_capacity(obs.len());
    for o in obs {
        let (x, l) = driver_value(state, e, o);
        xl = l;
        let one = std::slice::from_ref(o);
        let (p, _, _) = partial_residual(state, one, idx);
        if let Some((fit, y)) = p.first() {
            out.push((x, *y, *fit));
        }
    }
    (out, xl, yl)
}

/// Write one SVG: partial residual (blue) and the fitted effect (red) against the driver.
pub fn write_driver_svg(
    path: &Path,
    title: &str,
    pts: &[(f64, f64, f64)],
    xl: &str,
    yl: &str,
) -> Result<(), PlotError> {
    let fin = |v: &f64| v.is_finite();
    let range = |it: &mut dyn Iterator<Item = f64>| {
        let (lo, hi) = it
            .filter(fin)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(v), b.max(v))
            });
        if lo.is_finite() && hi > lo {
            let m = 0.05 * (hi - lo);
            (lo - m, hi + m)
        } else {
            (-1.0, 1.0)
        }
    };
    let (x0, x1) = range(&mut pts.iter().map(|p| p.0));
    let (y0, y1) = range(&mut pts.iter().flat_map(|p| [p.1, p.2]));
    let root = SVGBackend::new(path, (720, 540)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| err(path, e))?;
    chart
        .configure_mesh()
        .x_desc(xl)
        .y_desc(yl)
        .draw()
        .map_err(|e| err(path, e))?;
    chart
        .draw_series(
            pts.iter()
                .filter(|p| p.0.is_finite() && p.1.is_finite())
                .map(|p| Circle::new((p.0, p.1), 2, BLUE.mix(0.5).filled())),
        )
        .map_err(|e| err(path, e))?;
    chart
        .draw_series(
            pts.iter()
                .filter(|p| p.0.is_finite() && p.2.is_finite())
                .map(|p| Circle::new((p.0, p.2), 1, RED.filled())),
        )
        .map_err(|e| err(path, e))?;
    root.present().map_err(|e| err(path, e))?;
    Ok(())
}
