//! One diagnosis of one robot measured in several sessions (series): the geometry and the
//! physical effects are shared, each series keeps its own setup registration (tracker ←
//! base, 6; marker position on the flange, 3) and its own joint zero offsets (`phi*`, the
//! arm may be re-homed between sessions). Fitted jointly on the one LM solver
//! ([`crate::solve::lm`]); the physical effects are chosen greedily from the library's
//! joint-level families, each accepted only when it lowers the pooled residual by the BIC
//! rule AND lowers every series' own residual (an effect of the robot shows in every
//! session; one that helps a single series is that session's, not the robot's).
//!
//! [`leave_one_series_out`] is the cross-series test as a user would run it: fit on the
//! other series, re-register a new series' setup and joint offsets on a small subset of its
//! poses (its first ones in acquisition order, or a few spread over it: [`Registration`]),
//! predict every other pose of it.
use nalgebra::{DMatrix, DVector};

use super::effects::{Block, Effect, EffectModel};
use super::error::FitError;
use super::fit::{fit_nominal, params_of, residuals, rms3, stack, with_params, State};
use super::stats::lstsq;
use super::transfer::refit_setup_and_joint_offsets;
use crate::model::{KinematicModel, Param, ParamGroup};
use crate::solve::lm::{minimize, LmOptions, LsqProblem};
use crate::solve::obs::PoseObs;

/// Effect kinds a pooled model may share: properties of the arm, not of one session
/// (tracker scale, base drift, warm-up, latency and the kernel correction are left out).
pub const SHARED_KINDS: &[&str] = &[
    "backlash",
    "joint_compliance",
    "joint_coupling",
    "link_deflection",
    "joint_eccentricity",
    "transmission_ratio",
    "transmission_ripple",
    "wave_generator",
];

/// Whether a model parameter belongs to one series (setup registration and joint zero
/// offsets) rather than to the arm.
pub fn is_local(p: &Param) -> bool {
    match p.group {
        ParamGroup::Base => true,
        ParamGroup::Tool => matches!(p.name.as_str(), "tool_x" | "tool_y" | "tool_z"),
        ParamGroup::Joint(_) => p.name.starts_with("phi"),
        _ => false,
    }
}

/// A pooled fit: one state per series, all with the same shared parameters and effects.
#[derive(Debug, Clone)]
pub struct PooledFit {
    pub states: Vec<State>,
    /// Residual sum of squares over every series (mm²) and the number of poses.
    pub rss: f64,
    pub n_poses: usize,
    /// Effect kinds whose coefficients are per series (empty: every effect shared).
    pub local_kinds: Vec<String>,
}

impl PooledFit {
    /// RMS of the 3-D point error of series `s` on `obs`.
    pub fn rms(&self, s: usize, obs: &[PoseObs]) -> f64 {
        rms3(&residuals(&self.states[s], obs))
    }
    /// The shared part with series `s`'s setup and offsets (the start of a new series).
    pub fn shared(&self) -> &State {
        &self.states[0]
    }
}

/// What a column of [`stack`] (free model parameters, then effect coefficients) is in a
/// pooled fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    /// One value for every series, at this pooled index.
    Shared(usize),
    /// One value per series, at this index of the series' block.
    Local(usize),
    /// Held at the state's value (not fitted).
    Fixed,
}

/// How an effect's coefficients are treated in a pooled fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum EffectRole {
    Shared,
    Local,
    Fixed,
}

/// Where each column of the series' [`stack`] sits in the pooled vector.
struct Layout {
    roles: Vec<Role>,
    n_shared: usize,
    n_local: usize,
}

impl Layout {
    /// Model parameters by [`is_local`]; effects of `local_kinds` local, the others shared.
    fn of(st: &State, local_kinds: &[String]) -> Layout {
        Layout::with(st, |b| {
            if local_kinds.iter().any(|k| k == b.kind()) {
                EffectRole::Local
            } else {
                EffectRole::Shared
            }
        })
    }
    fn with(st: &State, effect_role: impl Fn(&Block) -> EffectRole) -> Layout {
        let (mut n_shared, mut n_local) = (0, 0);
        let mut roles = Vec::new();
        let mut push = |local: bool, fixed: bool| {
            roles.push(if fixed {
                Role::Fixed
            } else if local {
                n_local += 1;
                Role::Local(n_local - 1)
            } else {
                n_shared += 1;
                Role::Shared(n_shared - 1)
            })
        };
        for i in st.model.free_indices() {
            push(is_local(&st.model.params()[i]), false);
        }
        for e in &st.effects {
            let r = effect_role(&e.block);
            for _ in &e.coefs {
                push(r == EffectRole::Local, r == EffectRole::Fixed);
            }
        }
        Layout {
            roles,
            n_shared,
            n_local,
        }
    }
    fn n_params(&self, n_series: usize) -> usize {
        self.n_shared + n_series * self.n_local
    }
    /// Pooled column of stack column `c` of series `s` (`None`: fixed).
    fn col(&self, s: usize, c: usize) -> Option<usize> {
        match self.roles[c] {
            Role::Shared(k) => Some(k),
            Role::Local(k) => Some(self.n_shared + s * self.n_local + k),
            Role::Fixed => None,
        }
    }
    fn pack(&self, states: &[State]) -> DVector<f64> {
        let mut x = DVector::zeros(self.n_params(states.len()));
        for (s, st) in states.iter().enumerate() {
            let v = params_of(st);
            for (c, role) in self.roles.iter().enumerate() {
                if let Some(k) = self.col(s, c) {
                    if s == 0 || matches!(role, Role::Local(_)) {
                        x[k] = v[c];
                    }
                }
            }
        }
        x
    }
    fn unpack(&self, states: &[State], x: &DVector<f64>) -> Vec<State> {
        states
            .iter()
            .enumerate()
            .map(|(s, st)| {
                let mut v = params_of(st);
                for c in 0..self.roles.len() {
                    if let Some(k) = self.col(s, c) {
                        v[c] = x[k];
                    }
                }
                with_params(st, &v)
            })
            .collect()
    }
}

struct PooledProblem<'a> {
    layout: Layout,
    states: &'a [State],
    series: &'a [&'a [PoseObs]],
}

impl PooledProblem<'_> {
    fn rows(&self) -> usize {
        3 * self.series.iter().map(|o| o.len()).sum::<usize>()
    }
}

impl LsqProblem for PooledProblem<'_> {
    fn n_params(&self) -> usize {
        self.layout.n_params(self.states.len())
    }
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        let sts = self.layout.unpack(self.states, x);
        let mut r = DVector::zeros(self.rows());
        let mut row = 0;
        for (st, obs) in sts.iter().zip(self.series) {
            let rs = residuals(st, obs);
            r.rows_mut(row, rs.len()).copy_from(&(-rs));
            row += 3 * obs.len();
        }
        r
    }
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let sts = self.layout.unpack(self.states, x);
        let l = &self.layout;
        let mut r = DVector::zeros(self.rows());
        let mut j = DMatrix::zeros(self.rows(), self.n_params());
        let mut row = 0;
        for (s, (st, obs)) in sts.iter().zip(self.series).enumerate() {
            let (rs, js) = stack(st, obs);
            let n = rs.len();
            r.rows_mut(row, n).copy_from(&(-rs));
            for c in 0..l.roles.len() {
                if let Some(k) = l.col(s, c) {
                    j.view_mut((row, k), (n, 1)).copy_from(&js.column(c));
                }
            }
            row += n;
        }
        (r, j)
    }
}

/// Each series' start: the nominal model with its own tracker registration and marker
/// position ([`fit_nominal`]), no effects.
pub fn start_states(model: &KinematicModel, series: &[&[PoseObs]]) -> Result<Vec<State>, FitError> {
    let mut model = model.clone();
    model.fix_point_redundancies();
    series
        .iter()
        .map(|obs| {
            let mut m = model.clone();
            fit_nominal(&mut m, obs)?;
            Ok(State {
                prior: None,
                model: m,
                effects: vec![],
            })
        })
        .collect()
}

/// Fit the shared geometry and effect coefficients and every series' own setup and joint
/// offsets jointly, from `states` (same free flags and effect blocks in every series; the
/// shared values are taken from `states[0]`).
pub fn fit_pooled(
    states: &[State],
    series: &[&[PoseObs]],
    max_iter: usize,
) -> Result<PooledFit, FitError> {
    fit_pooled_local(states, series, max_iter, &[])
}

/// [`fit_pooled`] with the coefficients of the effects of `local_kinds` per series (each
/// series its own, the rest shared).
pub fn fit_pooled_local(
    states: &[State],
    series: &[&[PoseObs]],
    max_iter: usize,
    local_kinds: &[String],
) -> Result<PooledFit, FitError> {
    if states.is_empty() || states.len() != series.len() {
        return Err(FitError::NotFinite(
            "a pooled fit needs one start state per series",
        ));
    }
    let n_poses: usize = series.iter().map(|o| o.len()).sum();
    let prob = PooledProblem {
        layout: Layout::of(&states[0], local_kinds),
        states,
        series,
    };
    if n_poses * 3 < prob.n_params() {
        return Err(FitError::TooFewPoses {
            what: "a pooled fit needs",
            need: prob.n_params().div_ceil(3),
            got: n_poses,
        });
    }
    let x0 = prob.layout.pack(states);
    // The solver's defaults, the diagnosis's cost tolerance.
    let lm = LmOptions {
        max_iter,
        ftol: 1e-10,
        ..LmOptions::default()
    };
    let rep = minimize(&prob, x0.clone(), &lm);
    if !rep.cost.is_finite() {
        return Err(FitError::NotFinite("the pooled fit diverged"));
    }
    let x = if rep.cost <= rep.initial_cost {
        rep.x
    } else {
        x0
    };
    let states = prob.layout.unpack(states, &x);
    let rss = states
        .iter()
        .zip(series)
        .map(|(st, o)| residuals(st, o).norm_squared())
        .sum();
    Ok(PooledFit {
        states,
        rss,
        n_poses,
        local_kinds: local_kinds.to_vec(),
    })
}

/// One accepted effect of the pooled selection.
#[derive(Debug, Clone)]
pub struct PooledStep {
    pub label: String,
    /// Pooled training RMS after the refit (mm).
    pub rms: f64,
    /// ΔBIC of the linearised gain and each series' share of the residual reduction (mm²).
    pub delta_bic: f64,
    pub series_gain: Vec<f64>,
}

/// Selection settings.
#[derive(Debug, Clone)]
pub struct PooledOptions {
    pub max_effects: usize,
    pub min_delta_bic: f64,
    /// Every series must lower its own RSS by at least this share of its pro-rata part of
    /// the pooled reduction (0 = any reduction).
    pub min_series_share: f64,
    pub max_iter: usize,
    /// Effect kinds fitted per series (re-fitted with the setup on a new series).
    pub local_kinds: Vec<String>,
}

impl Default for PooledOptions {
    fn default() -> Self {
        PooledOptions {
            max_effects: 6,
            min_delta_bic: 10.0,
            min_series_share: 0.25,
            max_iter: 30,
            local_kinds: vec![],
        }
    }
}

/// The library's candidates for a pooled model: the joint-level families of
/// [`SHARED_KINDS`] that every series can identify.
pub fn shared_candidates(
    model: &KinematicModel,
    series: &[&[PoseObs]],
    opt: &super::Options,
) -> Vec<Block> {
    let all: Vec<PoseObs> = series.iter().flat_map(|o| o.iter().cloned()).collect();
    let (groups, _) = super::candidates_with(model, &all, opt);
    groups
        .into_iter()
        .flatten()
        .filter(|b| SHARED_KINDS.contains(&b.kind()))
        .filter(|b| {
            series
                .iter()
                .all(|o| b.check_identifiable(model, o).is_ok())
        })
        .collect()
}

/// Greedy forward selection of shared effects on top of `fit` (usually the pooled
/// geometric fit), then the pooled refit after each accepted effect.
pub fn select_pooled(
    fit: &PooledFit,
    series: &[&[PoseObs]],
    cands: &[Block],
    opt: &PooledOptions,
) -> Result<(PooledFit, Vec<PooledStep>), FitError> {
    let mut cur = fit.clone();
    let mut steps = Vec::new();
    let mut left: Vec<Block> = cands.to_vec();
    let n_rows = 3 * cur.n_poses;
    while steps.len() < opt.max_effects && !left.is_empty() {
        let prob = PooledProblem {
            layout: Layout::of(&cur.states[0], &cur.local_kinds),
            states: &cur.states,
            series,
        };
        let (mr, j) = prob.residuals_jacobian(&prob.layout.pack(&cur.states));
        let r = -mr;
        let q = j.qr().q();
        let r = &r - &q * (q.transpose() * &r);
        let rss = r.norm_squared();
        // Series row ranges.
        let mut bounds = Vec::new();
        let mut row = 0;
        for o in series {
            bounds.push((row, 3 * o.len()));
            row += 3 * o.len();
        }
        let mut best: Option<(usize, f64, Vec<f64>, usize)> = None;
        for chunk_start in (0..left.len()).step_by(64) {
            let chunk = &left[chunk_start..(chunk_start + 64).min(left.len())];
            let mut cols: Vec<DMatrix<f64>> = chunk
                .iter()
                .map(|b| DMatrix::zeros(n_rows, b.n_params()))
                .collect();
            for (s, (st, obs)) in cur.states.iter().zip(series).enumerate() {
                let cs = super::candidate_columns(st, obs, chunk);
                for (g, c) in cols.iter_mut().zip(cs) {
                    let (r0, n) = bounds[s];
                    g.rows_mut(r0, n).copy_from(&c);
                }
            }
            for (k, g) in cols.into_iter().enumerate() {
                // A per-series effect: one set of columns per series (block diagonal).
                let g = if cur.local_kinds.iter().any(|x| x == chunk[k].kind()) {
                    let m = g.ncols();
                    let mut d = DMatrix::zeros(n_rows, m * bounds.len());
                    for (s, &(r0, n)) in bounds.iter().enumerate() {
                        d.view_mut((r0, s * m), (n, m))
                            .copy_from(&g.view((r0, 0), (n, m)));
                    }
                    d
                } else {
                    g
                };
                let g = &g - &q * (q.transpose() * &g);
                let (d, rank) = lstsq(&g, &r);
                if rank == 0 {
                    continue;
                }
                let fitted = &g * d;
                let gain = rss - (&r - &fitted).norm_squared();
                if !gain.is_finite() || gain <= 0.0 {
                    continue;
                }
                let series_gain: Vec<f64> = bounds
                    .iter()
                    .map(|&(r0, n)| {
                        let rs = r.rows(r0, n);
                        rs.norm_squared() - (rs - fitted.rows(r0, n)).norm_squared()
                    })
                    .collect();
                let consistent = bounds.iter().zip(&series_gain).all(|(&(_, n), &sg)| {
                    sg > opt.min_series_share * gain * n as f64 / n_rows as f64
                });
                if consistent && best.as_ref().is_none_or(|b| gain > b.1) {
                    best = Some((chunk_start + k, gain, series_gain, g.ncols()));
                }
            }
        }
        let Some((k, gain, series_gain, n_coefs)) = best else {
            break;
        };
        let b = left.remove(k);
        let nf = n_rows as f64;
        let delta_bic = nf * (rss / (rss - gain).max(1e-300)).ln() - n_coefs as f64 * nf.ln();
        if delta_bic < opt.min_delta_bic {
            break;
        }
        let label = b.label();
        let mut states = cur.states.clone();
        for st in &mut states {
            st.effects.push(Effect::zero(b.clone()));
        }
        let next = fit_pooled_local(&states, series, opt.max_iter, &cur.local_kinds)?;
        let rms = (next.rss / next.n_poses as f64).sqrt();
        cur = next;
        steps.push(PooledStep {
            label,
            rms,
            delta_bic,
            series_gain,
        });
    }
    Ok((cur, steps))
}

/// How a new series is registered to a pooled fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Registration {
    /// Poses of the new series used to register it.
    pub n: usize,
    /// `false`: its first `n` poses in acquisition order; `true`: `n` poses spread evenly
    /// over its acquisition order (every k-th).
    pub spread: bool,
    /// Re-fit the joint zero offsets too (else the setup only: tracker ← base, marker).
    pub offsets: bool,
}

/// A new series predicted from a pooled fit: its setup (and, with `offsets`, its joint zero
/// offsets) re-fitted on `register`, everything else as pooled (the first training series'
/// values as the start); the coefficients of per-series effects ([`PooledFit::local_kinds`])
/// are re-fitted on `register` too (from zero).
pub fn register_new_series(
    fit: &PooledFit,
    register: &[PoseObs],
    offsets: bool,
) -> Result<State, FitError> {
    let is_local_effect = |b: &Block| fit.local_kinds.iter().any(|k| k == b.kind());
    let mut st = fit.shared().clone();
    let local_effects = st.effects.iter().any(|e| is_local_effect(&e.block));
    for e in st.effects.iter_mut().filter(|e| is_local_effect(&e.block)) {
        e.coefs.iter_mut().for_each(|c| *c = 0.0);
    }
    let st = if offsets {
        refit_setup_and_joint_offsets(&st, register)?
    } else {
        super::transfer::refit_setup(&st, register)?
    };
    if !local_effects {
        return Ok(st);
    }
    // The series' own effect coefficients with its setup (and offsets): every shared
    // parameter and effect held.
    let mut st = st;
    let saved = st.model.free_flags();
    let keep: Vec<(String, bool)> = st
        .model
        .params()
        .iter()
        .map(|p| {
            let mine = is_local(p) && (offsets || !p.name.starts_with("phi"));
            (p.name.clone(), p.free && mine)
        })
        .collect();
    for (n, f) in &keep {
        st.model.set_free(n, *f)?;
    }
    let layout = Layout::with(&st, |b| {
        if is_local_effect(b) {
            EffectRole::Local
        } else {
            EffectRole::Fixed
        }
    });
    let states = [st];
    let obs = [register];
    let prob = PooledProblem {
        layout,
        states: &states,
        series: &obs,
    };
    if 3 * register.len() < prob.n_params() {
        return Err(FitError::TooFewPoses {
            what: "re-registering a series with its own effects needs",
            need: prob.n_params().div_ceil(3),
            got: register.len(),
        });
    }
    let x0 = prob.layout.pack(&states);
    let lm = LmOptions {
        max_iter: 50,
        ftol: 1e-12,
        ..LmOptions::default()
    };
    let rep = minimize(&prob, x0.clone(), &lm);
    let x = if rep.cost.is_finite() && rep.cost <= rep.initial_cost {
        rep.x
    } else {
        x0
    };
    let mut st = prob.layout.unpack(&states, &x).remove(0);
    st.model.set_free_flags(&saved)?;
    Ok(st)
}

/// The split of a new series into its registration subset and everything else (held
/// out), see [`Registration`].
pub fn registration_split(obs: &[PoseObs], reg: &Registration) -> (Vec<PoseObs>, Vec<PoseObs>) {
    let mut all: Vec<PoseObs> = obs.to_vec();
    all.sort_by(|a, b| a.ctx.t.total_cmp(&b.ctx.t).then(a.ctx.id.cmp(&b.ctx.id)));
    if !reg.spread || reg.n == 0 || reg.n >= all.len() {
        let rest = all.split_off(reg.n.min(all.len()));
        return (all, rest);
    }
    // Every k-th pose, k = len / n (the first pose included).
    let (mut r, mut rest) = (Vec::new(), Vec::new());
    let step = all.len() as f64 / reg.n as f64;
    let mut next = 0.0;
    for (i, o) in all.into_iter().enumerate() {
        if r.len() < reg.n && i as f64 >= next {
            r.push(o);
            next += step;
        } else {
            rest.push(o);
        }
    }
    (r, rest)
}

/// One real series as the examples read it: a directory holding `train.jsonl` +
/// `heldout.jsonl`, or one dataset file whose `group: validation` records are held out.
/// Returns the nominal model and the training and held-out poses.
pub fn load_series(
    series: &std::path::Path,
) -> anyhow::Result<(KinematicModel, Vec<PoseObs>, Vec<PoseObs>)> {
    let (main, extra) = if series.is_dir() {
        (
            series.join("train.jsonl"),
            Some(series.join("heldout.jsonl")),
        )
    } else {
        (series.to_path_buf(), None)
    };
    let main = crate::dataset::read_dataset(&main)?.dataset;
    let extra = extra
        .map(|h| crate::dataset::read_dataset(&h).map(|l| l.dataset))
        .transpose()?;
    let model = KinematicModel::from_robot_block(&main.header.robot)?;
    let (train, held, _) =
        crate::solve::obs::split_observations(&main, extra.as_ref(), model.dof());
    Ok((model, train, held))
}

/// Amplitude (degrees) and phase (degrees, `a sin kq + b cos kq = A sin(kq + φ)`) of a
/// sin/cos effect's coefficients, with their standard deviations from the coefficients'.
pub fn amplitude_phase(e: &Effect) -> Option<(f64, f64, f64, f64)> {
    let [a, b] = e.coefs[..] else {
        return None;
    };
    let amp = a.hypot(b);
    let s = e
        .std
        .first()
        .copied()
        .unwrap_or(f64::NAN)
        .max(e.std.get(1).copied().unwrap_or(f64::NAN));
    Some((
        amp.to_degrees(),
        b.atan2(a).to_degrees(),
        s.to_degrees(),
        (s / amp.max(1e-300)).min(std::f64::consts::PI).to_degrees(),
    ))
}

/// Leave-one-series-out figures (mm).
#[derive(Debug, Clone)]
pub struct LooReport {
    pub n_register: usize,
    pub n_heldout: usize,
    /// Pooled geometric model: training RMS over the training series, held-out RMS.
    pub geo_train: f64,
    pub geo_heldout: f64,
    /// Pooled geometric + shared physical effects.
    pub phys_train: f64,
    pub phys_heldout: f64,
    /// Diagnostic, not a prediction: the pooled physical model with the setup (and joint
    /// offsets) registered on every pose of the new series, held-out RMS on the same held-out
    /// poses. What the shared physics can reach when the registration is not the limit.
    pub phys_all_registered: f64,
    pub steps: Vec<PooledStep>,
    pub geometric: PooledFit,
    pub physical: PooledFit,
}

/// Fit the pooled geometric and physical models on `train` (one slice per series), then
/// predict `target` after re-registering its setup (and joint offsets) on a subset of its
/// poses ([`Registration`]).
pub fn leave_one_series_out(
    model: &KinematicModel,
    train: &[&[PoseObs]],
    target: &[PoseObs],
    reg: &Registration,
    diag: &super::Options,
    opt: &PooledOptions,
) -> Result<LooReport, FitError> {
    let (subset, held) = registration_split(target, reg);
    if held.is_empty() {
        return Err(FitError::TooFewPoses {
            what: "a held-out series needs poses beyond its registration subset:",
            need: reg.n + 1,
            got: target.len(),
        });
    }
    let starts = start_states(model, train)?;
    let geometric = fit_pooled_local(&starts, train, 50, &opt.local_kinds)?;
    let cands = shared_candidates(&geometric.shared().model, train, diag);
    let (physical, steps) = select_pooled(&geometric, train, &cands, opt)?;
    let train_rms = |f: &PooledFit| (f.rss / f.n_poses as f64).sqrt();
    let g = register_new_series(&geometric, &subset, reg.offsets)?;
    let p = register_new_series(&physical, &subset, reg.offsets)?;
    let all = register_new_series(&physical, target, reg.offsets)?;
    Ok(LooReport {
        n_register: subset.len(),
        n_heldout: held.len(),
        geo_train: train_rms(&geometric),
        geo_heldout: rms3(&residuals(&g, &held)),
        phys_train: train_rms(&physical),
        phys_heldout: rms3(&residuals(&p, &held)),
        phys_all_registered: rms3(&residuals(&all, &held)),
        steps,
        geometric,
        physical,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::effects::Ripple;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

    /// The test arm: the UR10e preset with `a3` 0.4 mm long.
    fn test_arm() -> (KinematicModel, KinematicModel) {
        let nominal = KinematicModel::preset("ur10e").expect("ur10e preset");
        let mut arm = nominal.clone();
        arm.set_param("a3", arm.param("a3").unwrap() + 0.4).unwrap();
        (nominal, arm)
    }

    /// Joint 2's ×7 ripple with coefficients `c` (rad).
    fn ripple7(c: [f64; 2]) -> Effect {
        Effect {
            coefs: c.to_vec(),
            ..Effect::zero(Block::from(Ripple {
                joint: 2,
                harmonic: 7,
            }))
        }
    }

    /// Session `k` of `arm` with `effects`: its tracker placed elsewhere, marker moved,
    /// joint 3 re-homed; `n` poses, noiseless.
    fn session(arm: &KinematicModel, effects: Vec<Effect>, k: usize, n: usize) -> Vec<PoseObs> {
        let mut m = arm.clone();
        m.set_base(&Isometry3::from_parts(
            Translation3::new(1500.0 + 200.0 * k as f64, -300.0, 100.0 * k as f64),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), (25.0 * k as f64).to_radians()),
        ));
        m.set_param("tool_x", m.param("tool_x").unwrap() + 5.0 * k as f64)
            .unwrap();
        let phi3 = m.param("phi3").unwrap();
        m.set_param("phi3", phi3 + (0.02 * k as f64).to_radians())
            .unwrap();
        let st = State {
            model: m,
            effects,
            prior: None,
        };
        let seed = 0.37 * k as f64;
        (0..n)
            .map(|i| {
                let f = i as f64 + seed;
                let q = crate::diagnose::test_joints(f, 0.9, 1.3);
                let mut o = PoseObs::at(i as u64, f, q, nalgebra::Point3::origin());
                o.ctx.approach = vec![1.0; 6];
                o.p = crate::diagnose::effects::apply_effects(&st.model, &st.effects, &o.ctx);
                o
            })
            .collect()
    }

    /// Ripple candidates: joints 1–3, harmonics 5–9.
    fn ripple_cands() -> Vec<Block> {
        (5..=9)
            .flat_map(|h| {
                (1..=3).map(move |j| {
                    Block::from(Ripple {
                        joint: j,
                        harmonic: h,
                    })
                })
            })
            .collect()
    }

    /// Three sessions of one simulated arm (its link length and a ripple of joint 2 shared,
    /// each session's tracker placed elsewhere, marker moved, joint 3 re-homed): the pooled
    /// fit finds the shared ripple in every series, and a fourth session registered on 30
    /// of its poses is predicted to noise, where the geometric pooled model is not.
    #[test]
    fn pooled_ripple_carries_to_a_new_session() {
        let (nominal, arm) = test_arm();
        let ripple = ripple7([2e-4, -1e-4]);
        let s: Vec<Vec<PoseObs>> = (0..4)
            .map(|k| session(&arm, vec![ripple.clone()], k, 120))
            .collect();
        let train: Vec<&[PoseObs]> = s[..3].iter().map(|v| v.as_slice()).collect();
        let cands = ripple_cands();
        let starts = start_states(&nominal, &train).unwrap();
        let geo = fit_pooled(&starts, &train, 50).unwrap();
        let (phys, steps) = select_pooled(
            &geo,
            &train,
            &cands,
            &PooledOptions {
                max_effects: 3,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(
            steps.first().map(|s| s.label.as_str()),
            Some("transmission_ripple(j2, ×7)")
        );
        assert!(steps[0].series_gain.iter().all(|&g| g > 0.0));
        assert!(phys.rss.sqrt() < 1e-3, "pooled rss {}", phys.rss);
        let first = Registration {
            n: 30,
            spread: false,
            offsets: true,
        };
        let (reg, held) = registration_split(&s[3], &first);
        assert_eq!((reg.len(), held.len()), (30, 90));
        assert_eq!(reg.last().map(|o| o.ctx.id), Some(29));
        let spread = registration_split(
            &s[3],
            &Registration {
                spread: true,
                ..first
            },
        );
        assert_eq!((spread.0.len(), spread.1.len()), (30, 90));
        assert_eq!(spread.0[1].ctx.id, 4, "every 4th pose");
        let g = register_new_series(&geo, &reg, true).unwrap();
        let p = register_new_series(&phys, &reg, true).unwrap();
        let (eg, ep) = (rms3(&residuals(&g, &held)), rms3(&residuals(&p, &held)));
        assert!(eg > 0.02, "geometric pooled on the new session: {eg} mm");
        assert!(ep < 1e-3, "physical pooled on the new session: {ep} mm");
        // The shared link length was found, not absorbed per series.
        let a3 = phys.shared().model.param("a3").unwrap();
        assert!((a3 - arm.param("a3").unwrap()).abs() < 1e-3, "a3 {a3}");
        // Too few poses to register is an error, not a panic.
        assert!(register_new_series(&phys, &reg[..4], true).is_err());
        // Setup only: joint 3's re-homing of this session is then left in the error.
        let so = register_new_series(&phys, &reg, false).unwrap();
        let eso = rms3(&residuals(&so, &held));
        assert!(eso > 10.0 * ep, "setup only: {eso} mm");
        assert!(fit_pooled(&starts[..1], &train, 5).is_err());
    }

    /// The ripple's phase differs per session (same amplitude): shared, it cannot predict a
    /// new session; per series (`local_kinds`), re-fitted with the setup on 40 poses of the
    /// new session, it does.
    #[test]
    fn a_per_session_ripple_is_refitted_on_the_new_session() {
        let (nominal, arm) = test_arm();
        let amp = 3e-4;
        let s: Vec<Vec<PoseObs>> = (0..4)
            .map(|k| {
                let ph = 1.3 * k as f64;
                session(
                    &arm,
                    vec![ripple7([amp * ph.cos(), amp * ph.sin()])],
                    k,
                    120,
                )
            })
            .collect();
        let train: Vec<&[PoseObs]> = s[..3].iter().map(|v| v.as_slice()).collect();
        let reg = Registration {
            n: 40,
            spread: true,
            offsets: true,
        };
        let run = |local: Vec<String>| {
            let opt = PooledOptions {
                max_effects: 2,
                local_kinds: local,
                ..Default::default()
            };
            let starts = start_states(&nominal, &train).unwrap();
            let geo = fit_pooled_local(&starts, &train, 50, &opt.local_kinds).unwrap();
            let (phys, steps) = select_pooled(&geo, &train, &ripple_cands(), &opt).unwrap();
            let (sub, held) = registration_split(&s[3], &reg);
            let st = register_new_series(&phys, &sub, true).unwrap();
            (steps, phys, rms3(&residuals(&st, &held)))
        };
        let (steps, phys, local) = run(vec!["transmission_ripple".into()]);
        assert_eq!(
            steps.first().map(|s| s.label.as_str()),
            Some("transmission_ripple(j2, ×7)")
        );
        assert!(phys.rss.sqrt() < 1e-3, "pooled rss {}", phys.rss);
        // Each series kept its own phase.
        let c0 = &phys.states[0].effects[0].coefs;
        let c1 = &phys.states[1].effects[0].coefs;
        assert!((c0[0] - amp).abs() < 1e-6 && (c1[0] - amp * 1.3f64.cos()).abs() < 1e-6);
        assert!(
            local < 1e-3,
            "per-session ripple on the new session: {local} mm"
        );
        let (_, _, shared) = run(vec![]);
        assert!(
            shared > 0.05,
            "a shared ripple on the new session: {shared} mm"
        );
        // Too few registration poses for the setup and the series' own coefficients.
        let (sub, _) = registration_split(&s[3], &Registration { n: 4, ..reg });
        assert!(register_new_series(&phys, &sub, true).is_err());
    }
}
