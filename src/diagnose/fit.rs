//! Joint least-squares fit of the free geometric parameters and the effect coefficients
//! (damped Gauss–Newton on the column-scaled stacked Jacobian), plus the initial
//! registration of the tracker–base transform.
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3,
};

use super::data::Obs;
use super::effects::{eval_pose, Effect};
use super::stats::{lstsq, normal_inverse};
use crate::model::{KinematicModel, ParamGroup};

/// A model and its effects: what is fitted and what predicts.
#[derive(Debug, Clone)]
pub struct State {
    pub model: KinematicModel,
    pub effects: Vec<Effect>,
}

/// Stacked residual (3 rows per observation, `y − pred`, mm) and Jacobian of the
/// prediction w.r.t. [free model params, effect coefs].
pub fn stack(state: &State, obs: &[Obs]) -> (DVector<f64>, DMatrix<f64>) {
    let free = state.model.free_indices();
    let ne: usize = state.effects.iter().map(|e| e.block.n_coefs()).sum();
    let p = free.len() + ne;
    let mut r = DVector::zeros(3 * obs.len());
    let mut j = DMatrix::zeros(3 * obs.len(), p);
    for (k, o) in obs.iter().enumerate() {
        let ev = eval_pose(&state.model, &state.effects, &o.ctx);
        let d = o.y - ev.pred;
        for a in 0..3 {
            r[3 * k + a] = d[a];
            for (c, &fi) in free.iter().enumerate() {
                j[(3 * k + a, c)] = ev.jac_model[(a, fi)];
            }
            for c in 0..ne {
                j[(3 * k + a, free.len() + c)] = ev.jac_effects[(a, c)];
            }
        }
    }
    (r, j)
}

/// Residuals only.
pub fn residuals(state: &State, obs: &[Obs]) -> DVector<f64> {
    let mut r = DVector::zeros(3 * obs.len());
    for (k, o) in obs.iter().enumerate() {
        let p = super::effects::apply_effects(&state.model, &state.effects, &o.ctx);
        let d = o.y - p;
        for a in 0..3 {
            r[3 * k + a] = d[a];
        }
    }
    r
}

/// RMS of the 3-D point error (mm): sqrt(mean |e|²).
pub fn rms3(r: &DVector<f64>) -> f64 {
    if r.is_empty() {
        return f64::NAN;
    }
    (r.norm_squared() / (r.len() / 3) as f64).sqrt()
}

fn apply_step(state: &mut State, dx: &DVector<f64>) {
    let free = state.model.free_indices();
    let mut v = state.model.param_values();
    for (c, &fi) in free.iter().enumerate() {
        v[fi] += dx[c];
    }
    state.model.set_param_values(&v);
    let mut off = free.len();
    for e in &mut state.effects {
        for c in e.coefs.iter_mut() {
            *c += dx[off];
            off += 1;
        }
    }
}

/// Outcome of a fit.
#[derive(Debug, Clone)]
pub struct FitReport {
    pub rss: f64,
    pub n_rows: usize,
    pub n_params: usize,
    pub rank: usize,
    pub iterations: usize,
}

/// Damped Gauss–Newton: minimise the residual over free model params and effect coefs.
/// Effect standard deviations are set from the final Jacobian.
pub fn fit(state: &mut State, obs: &[Obs], max_iter: usize) -> FitReport {
    let (mut r, mut j) = stack(state, obs);
    let mut rss = r.norm_squared();
    let mut iterations = 0;
    let mut rank = j.ncols();
    for it in 0..max_iter {
        iterations = it + 1;
        let (dx, rk) = lstsq(&j, &r);
        rank = rk;
        let mut step = 1.0;
        let mut improved = false;
        for _ in 0..8 {
            let mut trial = state.clone();
            apply_step(&mut trial, &(&dx * step));
            let rt = residuals(&trial, obs);
            let rss_t = rt.norm_squared();
            if rss_t.is_finite() && rss_t <= rss {
                let rel = (rss - rss_t) / rss.max(1e-300);
                *state = trial;
                rss = rss_t;
                improved = rel > 1e-10;
                break;
            }
            step *= 0.5;
        }
        if !improved {
            break;
        }
        let s = stack(state, obs);
        r = s.0;
        j = s.1;
    }
    // Parameter uncertainty for the effects.
    let n = r.len();
    let p = j.ncols();
    let sigma2 = rss / (n.saturating_sub(rank).max(1)) as f64;
    let cov = normal_inverse(&j);
    let mut off = state.model.free_count();
    for e in &mut state.effects {
        e.std = (0..e.coefs.len())
            .map(|c| (cov[(off + c, off + c)] * sigma2).max(0.0).sqrt())
            .collect();
        off += e.coefs.len();
    }
    FitReport {
        rss,
        n_rows: n,
        n_params: p,
        rank,
        iterations,
    }
}

/// Best rigid transform `T` with `T·a_k ≈ b_k` (Kabsch / Horn).
pub fn kabsch(a: &[Point3<f64>], b: &[Point3<f64>]) -> Option<Isometry3<f64>> {
    if a.len() < 3 || a.len() != b.len() {
        return None;
    }
    let n = a.len() as f64;
    let ca = a.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / n;
    let cb = b.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / n;
    let mut h = Matrix3::zeros();
    for (p, q) in a.iter().zip(b) {
        h += (p.coords - ca) * (q.coords - cb).transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (vt.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = vt.transpose() * d * u.transpose();
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let t = cb - rot * ca;
    Some(Isometry3::from_parts(Translation3::from(t), rot))
}

/// Nominal fit: register the base (tracker ← robot base) from flange positions, then fit
/// base (6) and tool position (3) with all joint parameters at nominal. Leaves the model's
/// free flags as they were on entry.
pub fn fit_nominal(model: &mut KinematicModel, obs: &[Obs]) -> anyhow::Result<FitReport> {
    if obs.len() < 4 {
        anyhow::bail!("need at least 4 measured poses, got {}", obs.len());
    }
    let flange: Vec<Point3<f64>> = obs
        .iter()
        .map(|o| Point3::from(model.flange_pose(&o.ctx.q).translation.vector))
        .collect();
    let ys: Vec<Point3<f64>> = obs.iter().map(|o| o.y).collect();
    let b = kabsch(&flange, &ys)
        .ok_or_else(|| anyhow::anyhow!("cannot register the tracker to the robot base"))?;
    model.set_base(&b);
    model.set_tool(&Isometry3::identity());
    let saved: Vec<bool> = model.params().iter().map(|p| p.free).collect();
    let names: Vec<(String, bool)> = model
        .params()
        .iter()
        .map(|p| {
            let f = match p.group {
                ParamGroup::Base => true,
                ParamGroup::Tool => matches!(p.name.as_str(), "tool_x" | "tool_y" | "tool_z"),
                _ => false,
            };
            (p.name.clone(), f)
        })
        .collect();
    for (n, f) in &names {
        model.set_free(n, *f)?;
    }
    let mut st = State {
        model: model.clone(),
        effects: vec![],
    };
    let rep = fit(&mut st, obs, 30);
    *model = st.model;
    for (p, f) in names.iter().zip(saved) {
        model.set_free(&p.0, f)?;
    }
    Ok(rep)
}
