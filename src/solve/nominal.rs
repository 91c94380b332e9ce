//! The nominal fit: the nominal chain with only the tracker → robot-base
//! transform (6) and the flange → marker offset (3) fitted — the "before" of every
//! calibration.
//!
//! Closed-form start with no user guess: the unknowns `(R, b, t)` of
//! `p_i = R·(f_i + F_i·t) + b` (f_i, F_i the nominal flange position and rotation) are
//! found by alternating a Kabsch registration of the offset flange points onto the
//! markers (fixed t) and the linear least-squares tool offset `t = mean F_iᵀ(Rᵀ(p_i − b) − f_i)`
//! (fixed R, b). Each half-step cannot increase the cost, and at t = 0 the first Kabsch
//! is already within the tool length of the answer. Levenberg–Marquardt on the 9
//! parameters then polishes to the least-squares optimum.
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use super::lm::{self, LmOptions, Termination};
use super::obs::{observations, PoseObs, Skipped, Split};
use super::{kinematics, rigid, stats, SolveError};
use crate::dataset::Dataset;
use crate::model::{KinematicModel, ParamGroup};

/// Options of [`fit_nominal`].
#[derive(Debug, Clone, Default)]
pub struct NominalOptions<'a> {
    /// Score on all usable pose records of this dataset instead of the `validation`
    /// records of the training file.
    pub heldout: Option<&'a Dataset>,
}

/// Result of the nominal fit.
#[derive(Debug, Clone)]
pub struct NominalFit {
    /// The nominal chain with base and tool set (internal units).
    pub model: KinematicModel,
    pub termination: Termination,
    pub iterations: usize,
    pub n_train: usize,
    pub train_errors: Vec<f64>,
    pub train_rms_mm: f64,
    /// RMS / max 3-D error on held-out poses (validation records or `heldout`).
    pub heldout_rms_mm_before: Option<f64>,
    pub heldout_max_mm_before: Option<f64>,
    pub n_heldout: usize,
    pub skipped: Vec<Skipped>,
}

/// Closed-form base (tracker ← robot base) and tool position for a nominal chain.
pub fn closed_form_base_tool(
    model: &KinematicModel,
    obs: &[PoseObs],
) -> Result<(Isometry3<f64>, Vector3<f64>), SolveError> {
    if obs.len() < 4 {
        return Err(SolveError::TooFewData {
            what: "nominal fit".into(),
            need: 4,
            got: obs.len(),
        });
    }
    let flanges: Vec<Isometry3<f64>> = obs.iter().map(|o| model.flange_pose(&o.q)).collect();
    let meas: Vec<Point3<f64>> = obs.iter().map(|o| o.p).collect();
    let mut t = Vector3::zeros();
    let mut base = Isometry3::identity();
    let mut last = f64::INFINITY;
    for _ in 0..500 {
        let pts: Vec<Point3<f64>> = flanges.iter().map(|f| f * Point3::from(t)).collect();
        base = rigid::register_points(&pts, &meas)?;
        let inv = base.inverse();
        let mut acc = Vector3::zeros();
        for (f, p) in flanges.iter().zip(&meas) {
            let local = inv * p;
            acc += f.rotation.inverse() * (local.coords - f.translation.vector);
        }
        t = acc / obs.len() as f64;
        let cost: f64 = flanges
            .iter()
            .zip(&meas)
            .map(|(f, p)| (base * (f * Point3::from(t)) - p).norm_squared())
            .sum();
        if (last - cost).abs() <= 1e-12 * cost.max(1e-12) {
            break;
        }
        last = cost;
    }
    Ok((base, t))
}

/// Nominal fit on observations: `chain` gives the nominal joints (its base/tool values are
/// ignored); returns the chain with base (6) and tool position (3) fitted. With
/// `orientation`, the tool rotation is also set in closed form from the marker quaternions.
pub fn fit_nominal_obs(
    chain: &KinematicModel,
    obs: &[PoseObs],
    orientation: bool,
) -> Result<NominalFit, SolveError> {
    let (base, t) = closed_form_base_tool(chain, obs)?;
    let mut m = chain.clone();
    m.set_base(&base);
    m.set_tool(&Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::identity(),
    ));
    let names: Vec<(String, ParamGroup)> = m
        .params()
        .iter()
        .map(|p| (p.name.clone(), p.group))
        .collect();
    for (n, g) in &names {
        let free = match g {
            ParamGroup::Base => true,
            ParamGroup::Tool => !(n.ends_with("rx") || n.ends_with("ry") || n.ends_with("rz")),
            _ => false,
        };
        m.set_free(n, free)?;
    }
    let empty = [];
    let prob = kinematics::KinProblem::new(m, obs, &empty);
    let rep = lm::minimize(&prob, prob.x0(), &LmOptions::default());
    if rep.termination == Termination::NonFinite {
        return Err(SolveError::Solver(rep.termination.describe().into()));
    }
    let mut model = prob.model_at(&rep.x);
    if orientation && obs.iter().all(|o| o.quat.is_some()) {
        let b_inv = model.base().inverse();
        let tools: Vec<Isometry3<f64>> = obs
            .iter()
            .filter_map(|o| {
                o.quat.map(|q| {
                    let meas = Isometry3::from_parts(Translation3::from(o.p.coords), q);
                    model.flange_pose(&o.q).inverse() * b_inv * meas
                })
            })
            .collect();
        let mut tool = model.tool();
        tool.rotation = rigid::mean_isometry(&tools).rotation;
        model.set_tool(&tool);
    }
    // Restore the chain's free flags for joints (the caller decides what to identify).
    for (i, p) in chain.params().iter().enumerate() {
        if let ParamGroup::Joint(_) = p.group {
            model.set_free(&p.name, chain.params()[i].free)?;
        }
    }
    let train_errors = kinematics::model_errors(&model, obs);
    Ok(NominalFit {
        train_rms_mm: stats::rms(&train_errors),
        train_errors,
        model,
        termination: rep.termination,
        iterations: rep.iterations,
        n_train: obs.len(),
        heldout_rms_mm_before: None,
        heldout_max_mm_before: None,
        n_heldout: 0,
        skipped: Vec::new(),
    })
}

/// `robocal calibrate nominal` as a library call: fit on the non-`validation` pose records,
/// score on the `validation` records (or all records of `opts.heldout`).
pub fn fit_nominal(ds: &Dataset, opts: &NominalOptions) -> Result<NominalFit, SolveError> {
    let chain = KinematicModel::from_robot_block(&ds.header.robot)?;
    let dof = chain.dof();
    let (train, mut skipped) = observations(ds, dof, Split::Train);
    if let Some(h) = opts.heldout {
        super::obs::check_same_frame(ds, h).map_err(SolveError::Invalid)?;
    }
    let (held, s2) = match opts.heldout {
        Some(h) => observations(h, dof, Split::All),
        None => observations(ds, dof, Split::Validation),
    };
    skipped.extend(s2);
    if opts.heldout.is_some() && held.is_empty() {
        return Err(SolveError::Invalid(format!(
            "no usable held-out poses in the --heldout file ({} pose records skipped: {}): a held-out \
             file must hold poses with `q` and a visible marker `p`",
            skipped.len(),
            skipped.first().map_or("no pose records".into(), |s| s.reason.clone())
        )));
    }
    // Count rule: 6 base + 3 tool parameters need twice as many equations (3 per pose).
    let need = super::kinematics::poses_needed(9, 3);
    if train.len() < need {
        return Err(SolveError::Invalid(format!(
            "{} usable training poses give {} equations for the 9 parameters of the nominal fit \
             (tracker → base 6, marker 3): at least {need} poses are needed (twice as many \
             equations as parameters); measure {} more poses",
            train.len(),
            3 * train.len(),
            need - train.len()
        )));
    }
    let mut fit = fit_nominal_obs(&chain, &train, false)?;
    if !held.is_empty() {
        let e = kinematics::model_errors(&fit.model, &held);
        fit.heldout_rms_mm_before = Some(stats::rms(&e));
        fit.heldout_max_mm_before = Some(e.iter().cloned().fold(0.0, f64::max));
    }
    fit.n_heldout = held.len();
    fit.skipped = skipped;
    Ok(fit)
}
