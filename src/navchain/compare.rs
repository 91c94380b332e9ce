//! Seed 003's correction network beside the physical diagnosis, on the same held-out poses
//! (four models): the geometric fit, the network trained on what the geometric fit leaves,
//! the physical diagnosis ([`crate::diagnose::diagnose`]), and the network on top of what the
//! diagnosis leaves, each scored on the training poses and on the held-out poses, with the
//! wall time of each stage.
//!
//! Nothing here reads a truth: the residuals are measured − predicted, as a user scores them.
//! The splits are the ones `examples/real_policy.rs` uses: the file's own (interleaved) and
//! the time-blocked one ([`time_blocked`]).
use std::time::Instant;

use nalgebra::Vector3;

use crate::diagnose::fit::{fit, fit_nominal, residuals, State};
use crate::diagnose::{self, Options};
use crate::model::KinematicModel;
use crate::navchain::correction::pose_inputs;
use crate::navchain::nn::{NetOptions, SeedNet};
use crate::solve::obs::PoseObs;

/// Training and held-out RMS (mm) of one stage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Score {
    pub train_mm: f64,
    pub heldout_mm: f64,
    /// Wall time of the stage (s).
    pub secs: f64,
}

impl Score {
    /// `(held-out − train) / train`: the overfitting gap.
    pub fn gap(&self) -> f64 {
        self.heldout_mm / self.train_mm - 1.0
    }
}

/// The comparison on one split.
#[derive(Debug, Clone)]
pub struct Comparison {
    pub n_train: usize,
    pub n_heldout: usize,
    /// Nominal arm, setup (tracker ← base, marker) fitted.
    pub nominal: Score,
    /// Geometric calibration (what `calibrate kinematics` fits).
    pub geometric: Score,
    /// Geometric + seed 003's network trained on the geometric residual.
    pub network: Score,
    /// The physical diagnosis (None when not asked for).
    pub diagnosis: Option<Score>,
    /// Effects the diagnosis kept (labels; its `nonparametric` correction included).
    pub diagnosis_chain: Vec<String>,
    /// The diagnosis + the network trained on what it leaves.
    pub diagnosis_network: Option<Score>,
}

/// RMS (mm) of the 3-D error of `state` (+ `net`) on `obs`.
pub fn rms_with(state: &State, net: Option<&SeedNet>, obs: &[PoseObs]) -> f64 {
    if obs.is_empty() {
        return f64::NAN;
    }
    let r = residuals(state, obs);
    let ss: f64 = obs
        .iter()
        .enumerate()
        .map(|(k, o)| {
            let mut e = Vector3::new(r[3 * k], r[3 * k + 1], r[3 * k + 2]);
            if let Some(n) = net {
                let c = n.predict(&pose_inputs(&state.model, &o.ctx.q));
                e -= Vector3::new(c[0], c[1], c[2]);
            }
            e.norm_squared()
        })
        .sum();
    (ss / obs.len() as f64).sqrt()
}

/// Seed 003's network trained on the residual `state` leaves on `train` (position error;
/// orientation outputs zero: the marker's orientation is not used).
pub fn train_on_residual(state: &State, train: &[PoseObs], opts: &NetOptions) -> SeedNet {
    let r = residuals(state, train);
    let xs: Vec<[f64; 6]> = train
        .iter()
        .map(|o| pose_inputs(&state.model, &o.ctx.q))
        .collect();
    let ys: Vec<[f64; 6]> = (0..train.len())
        .map(|k| [r[3 * k], r[3 * k + 1], r[3 * k + 2], 0.0, 0.0, 0.0])
        .collect();
    SeedNet::train(&xs, &ys, opts)
}

/// The geometric fit alone (the diagnosis' first stage): nominal setup, then every
/// identifiable geometric parameter. Returns (nominal, geometric).
pub fn geometric_fit(model: &KinematicModel, train: &[PoseObs]) -> anyhow::Result<(State, State)> {
    let mut model = model.clone();
    model.fix_point_redundancies();
    fit_nominal(&mut model, train)?;
    let nominal = State {
        prior: None,
        model,
        effects: vec![],
    };
    let mut geo = nominal.clone();
    fit(&mut geo, train, 50);
    Ok((nominal, geo))
}

fn score(state: &State, net: Option<&SeedNet>, tr: &[PoseObs], he: &[PoseObs], secs: f64) -> Score {
    Score {
        train_mm: rms_with(state, net, tr),
        heldout_mm: rms_with(state, net, he),
        secs,
    }
}

/// Compares on one split. `diag`: run the physical diagnosis with these options (None: the
/// geometric fit and the network only, for sets the diagnosis is too slow on).
pub fn compare(
    model: &KinematicModel,
    train: &[PoseObs],
    held: &[PoseObs],
    diag: Option<&Options>,
    net_opts: &NetOptions,
) -> anyhow::Result<Comparison> {
    anyhow::ensure!(
        train.len() >= 30 && !held.is_empty(),
        "{} training and {} held-out poses: the comparison needs ≥ 30 and ≥ 1",
        train.len(),
        held.len()
    );
    let t0 = Instant::now();
    let (nominal, geometric, d) = match diag {
        Some(o) => {
            let d = diagnose::diagnose(model, train, held, o)?;
            (d.nominal.clone(), d.geometric.clone(), Some(d))
        }
        None => {
            let (n, g) = geometric_fit(model, train)?;
            (n, g, None)
        }
    };
    let diag_secs = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let net = train_on_residual(&geometric, train, net_opts);
    let net_secs = t1.elapsed().as_secs_f64();
    let mut out = Comparison {
        n_train: train.len(),
        n_heldout: held.len(),
        nominal: score(&nominal, None, train, held, 0.0),
        geometric: score(&geometric, None, train, held, 0.0),
        network: score(&geometric, Some(&net), train, held, net_secs),
        diagnosis: None,
        diagnosis_chain: vec![],
        diagnosis_network: None,
    };
    if let Some(d) = d {
        out.diagnosis = Some(score(&d.state, None, train, held, diag_secs));
        out.diagnosis_chain = d.steps.iter().map(|s| s.evidence.label.clone()).collect();
        let t2 = Instant::now();
        let net2 = train_on_residual(&d.state, train, net_opts);
        let s2 = t2.elapsed().as_secs_f64();
        out.diagnosis_network = Some(score(&d.state, Some(&net2), train, held, s2));
    }
    Ok(out)
}

/// The time-blocked split of `examples/real_policy.rs`: the first 75 % of the training poses
/// (by time) train, the held-out poses from then on score.
pub fn time_blocked(train: &[PoseObs], held: &[PoseObs]) -> (Vec<PoseObs>, Vec<PoseObs>) {
    let mut ts: Vec<f64> = train.iter().map(|o| o.ctx.t).collect();
    ts.sort_by(f64::total_cmp);
    let Some(&t_split) = ts.get(ts.len() * 3 / 4) else {
        return (vec![], vec![]);
    };
    (
        train
            .iter()
            .filter(|o| o.ctx.t < t_split)
            .cloned()
            .collect(),
        held.iter()
            .filter(|o| o.ctx.t >= t_split)
            .cloned()
            .collect(),
    )
}

/// The first `max` training poses (acquisition order) and the held-out poses measured no
/// later than the last of them (`real_policy --max-train`).
pub fn first_poses(
    train: &[PoseObs],
    held: &[PoseObs],
    max: usize,
) -> (Vec<PoseObs>, Vec<PoseObs>) {
    let tr: Vec<PoseObs> = train.iter().take(max).cloned().collect();
    let t_end = tr.last().map_or(f64::NEG_INFINITY, |o| o.ctx.t);
    let he = held.iter().filter(|o| o.ctx.t <= t_end).cloned().collect();
    (tr, he)
}

/// The table header of [`row`].
pub const TABLE_HEAD: &str = "| series | split | poses train / held-out | nominal | geometric | \
geometric + network (train) | physical diagnosis (train) | diagnosis + network | network s | diagnosis s | diagnosis chain |\n\
|---|---|---|---|---|---|---|---|---|---|---|";

/// One markdown row of a comparison (held-out RMS, mm; training RMS in parentheses).
pub fn row(series: &str, split: &str, c: &Comparison) -> String {
    let opt = |s: Option<Score>, f: &dyn Fn(Score) -> String| s.map_or("—".to_string(), f);
    format!(
        "| {series} | {split} | {} / {} | {:.4} | {:.4} | {:.4} ({:.4}) | {} | {} | {:.1} | {} | {} |",
        c.n_train,
        c.n_heldout,
        c.nominal.heldout_mm,
        c.geometric.heldout_mm,
        c.network.heldout_mm,
        c.network.train_mm,
        opt(c.diagnosis, &|s| format!("{:.4} ({:.4})", s.heldout_mm, s.train_mm)),
        opt(c.diagnosis_network, &|s| format!("{:.4}", s.heldout_mm)),
        c.network.secs,
        opt(c.diagnosis, &|s| format!("{:.1}", s.secs)),
        if c.diagnosis.is_none() {
            "not run".to_string()
        } else if c.diagnosis_chain.is_empty() {
            "none".to_string()
        } else {
            c.diagnosis_chain.join(", ")
        }
    )
}
