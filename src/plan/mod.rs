//! Pose planning and plan-only mode (`robocal plan`): before the robot moves, a field
//! engineer learns whether a plan is reachable, safe, visible to the sensors, quick, and able
//! to identify the kinematic parameters.
//!
//! Pipeline: a strict TOML [`spec::PlanSpec`] → [`gen::generate`] candidate tool poses (seed
//! 001 cylindrical annulus, seed 004 spherical shell, seed 000 calibration planes and
//! validation sets) → IK on every branch + [`constraints`] (each rejection says why) →
//! [`timing`] (trapezoidal time model, nearest neighbour + 2-opt + Or-opt order) →
//! [`observe`] (O1 / condition number of the identification Jacobian, greedy D-optimal
//! `--select`) → [`file::PlanFile`] (`PLAN.json`) and [`export`] (CSV, URScript, PacScript).
//!
//! **Units:** inside the library mm and radians; spec and plan files mm and degrees.
//! Nothing here opens a device.
use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector, Isometry3, Point3, Translation3, UnitQuaternion};
use robocal_drivers::safety::{check_move, SafetyLimits};
use thiserror::Error;

use crate::dataset::RobotBlock;
use crate::model::KinematicModel;

pub mod constraints;
pub mod export;
pub mod file;
pub mod gen;
pub mod observe;
pub mod recheck;
pub mod spec;
pub mod timing;

pub use constraints::RejectReason;
pub use file::{PlanFile, PlanFilePose, PlanPose, PlanSummary, PLAN_FORMAT};
pub use gen::{BranchPolicy, Candidate};
pub use observe::Observability;
pub use spec::PlanSpec;
pub use timing::TimeModel;

/// What can go wrong planning.
#[derive(Debug, Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum PlanError {
    /// The TOML spec does not parse or has invalid values.
    #[error("plan spec: {message}")]
    Spec { message: String },
    /// A plan file that does not parse or does not validate.
    #[error("plan file: {message}")]
    PlanFile { message: String },
    /// File I/O.
    #[error("{path}: {message}")]
    Io { path: String, message: String },
    /// The robot model.
    #[error("robot model: {message}")]
    Model { message: String },
    /// Export failure.
    #[error("export: {message}")]
    Export { message: String },
}

/// `xyz` (mm) + URDF rpy (deg) → isometry (mm, rad).
pub fn frame_iso(f: &spec::FrameSpec) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(f.xyz[0], f.xyz[1], f.xyz[2]),
        UnitQuaternion::from_euler_angles(
            f.rpy[0].to_radians(),
            f.rpy[1].to_radians(),
            f.rpy[2].to_radians(),
        ),
    )
}

/// One feasible pose.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedPose {
    /// Index into the candidate list.
    pub candidate: usize,
    pub point: usize,
    pub branch: u8,
    pub branch_label: String,
    /// Joints (rad).
    pub q: Vec<f64>,
    /// Flange pose in the robot base.
    pub flange: Isometry3<f64>,
}

/// One rejection (a whole target when `branch` is `None`).
#[derive(Debug, Clone, PartialEq)]
pub struct Rejection {
    pub candidate: usize,
    pub point: usize,
    pub branch: Option<u8>,
    pub reason: RejectReason,
}

/// Feasible poses (generated order) and rejections of a candidate set.
#[derive(Debug, Clone, PartialEq)]
pub struct Feasibility {
    pub candidates: Vec<Candidate>,
    pub poses: Vec<PlannedPose>,
    pub rejections: Vec<Rejection>,
    /// Target × branch combinations examined (unreachable / pose-level rejected count once).
    pub examined: usize,
}

impl Feasibility {
    /// Feasible poses per branch label.
    pub fn per_branch(&self) -> BTreeMap<String, usize> {
        let mut m = BTreeMap::new();
        for p in &self.poses {
            *m.entry(format!("{} {}", p.branch, p.branch_label))
                .or_insert(0) += 1;
        }
        m
    }
    /// Rejections per reason key.
    pub fn reject_counts(&self) -> BTreeMap<String, usize> {
        let mut m = BTreeMap::new();
        for r in &self.rejections {
            *m.entry(r.reason.key().to_string()).or_insert(0) += 1;
        }
        m
    }
}

/// Pose-level checks of one candidate (tracker, laser).
pub fn pose_checks(spec: &PlanSpec, c: &Candidate) -> Option<RejectReason> {
    if let Some(t) = &spec.tracker {
        if let Some(r) = constraints::tracker_check(t, &frame_iso(&t.pose), &c.tool_in_base) {
            return Some(r);
        }
    }
    if let (Some(l), Some(hp)) = (&spec.laser, &c.hit_plane) {
        if let Some(r) = constraints::laser_check(l, &c.tool_in_base, hp) {
            return Some(r);
        }
    }
    None
}

/// One IK solution as the planner uses it.
#[derive(Debug, Clone, PartialEq)]
pub struct IkBranch {
    /// Joints (rad), wrapped into the limits where possible.
    pub q: Vec<f64>,
    pub branch: u8,
    pub label: String,
}

/// Seeds of the numeric fallback: joint 2/3/5 sign patterns around a bent-elbow posture.
fn numeric_seeds(dof: usize) -> Vec<Vec<f64>> {
    (0..8u8)
        .map(|b| {
            let sg = |bit: u8| if b & bit == 0 { 1.0 } else { -1.0 };
            (0..dof)
                .map(|i| match i {
                    0 => 0.0,
                    1 => 0.5 * sg(4),
                    2 => 1.2 * sg(2),
                    4 => 0.8 * sg(1),
                    _ => 0.0,
                })
                .collect()
        })
        .collect()
}

/// Every IK branch of a flange pose: the model's closed form, or — for geometries without
/// one (e.g. an arbitrary URDF) — damped least squares from eight seeds, distinct solutions
/// kept (`numeric-k` labels). `None` when unreachable.
pub fn solve_ik(model: &KinematicModel, flange: &Isometry3<f64>) -> Option<Vec<IkBranch>> {
    match model.ik(flange) {
        Ok(sols) => Some(
            sols.into_iter()
                .map(|s| IkBranch {
                    q: s.q,
                    branch: s.branch,
                    label: s.label.to_string(),
                })
                .collect(),
        ),
        Err(crate::model::IkError::NoClosedForm { .. }) => {
            let limits = model.joint_limits();
            let mut out: Vec<IkBranch> = Vec::new();
            for (k, seed) in numeric_seeds(model.dof()).iter().enumerate() {
                let Ok(mut q) = model.ik_from_seed(flange, seed) else {
                    continue;
                };
                crate::model::ik::wrap_into_limits(&mut q, &limits);
                let dup = out
                    .iter()
                    .any(|o| o.q.iter().zip(&q).all(|(a, b)| (a - b).abs() < 1e-3));
                if !dup {
                    out.push(IkBranch {
                        q,
                        branch: k as u8,
                        label: format!("numeric-{k}"),
                    });
                }
            }
            (!out.is_empty()).then_some(out)
        }
        Err(_) => None,
    }
}

/// One try of a candidate at tool pose `tp`: feasible branches, rejections, examined count.
fn attempt(
    model: &KinematicModel,
    spec: &PlanSpec,
    tool: &Isometry3<f64>,
    tool_inv: &Isometry3<f64>,
    ci: usize,
    c: &Candidate,
    tp: &Isometry3<f64>,
) -> (Vec<PlannedPose>, Vec<Rejection>, usize) {
    let reject_target = |reason| Rejection {
        candidate: ci,
        point: c.point,
        branch: None,
        reason,
    };
    let mut cc = c.clone();
    cc.tool_in_base = *tp;
    if let Some(r) = pose_checks(spec, &cc) {
        return (Vec::new(), vec![reject_target(r)], 1);
    }
    let flange = tp * tool_inv;
    let Some(sols) = solve_ik(model, &flange) else {
        return (
            Vec::new(),
            vec![reject_target(RejectReason::Unreachable)],
            1,
        );
    };
    let mut ok = Vec::new();
    let mut rej = Vec::new();
    let n = sols.len();
    for s in sols {
        match constraints::arm_check(&spec.constraints, model, &s.q, tool) {
            Some(reason) => rej.push(Rejection {
                candidate: ci,
                point: c.point,
                branch: Some(s.branch),
                reason,
            }),
            None => ok.push(PlannedPose {
                candidate: ci,
                point: c.point,
                branch: s.branch,
                branch_label: s.label,
                flange: model.flange_pose(&s.q),
                q: s.q,
            }),
        }
    }
    (ok, rej, n)
}

/// IK every candidate on every branch and apply the constraints.
pub fn feasibility(
    model: &KinematicModel,
    spec: &PlanSpec,
    candidates: Vec<Candidate>,
) -> Feasibility {
    let tool = frame_iso(&spec.tool);
    let tool_inv = tool.inverse();
    let tm = TimeModel::from_spec(&spec.timing, model.dof());
    let mut poses = Vec::new();
    let mut rejections = Vec::new();
    let mut examined = 0;
    for (ci, c) in candidates.iter().enumerate() {
        let first = attempt(model, spec, &tool, &tool_inv, ci, c, &c.tool_in_base);
        let (ok, rej, ex) = if first.0.is_empty() && c.free_roll {
            (1..12)
                .map(|k| {
                    let roll =
                        UnitQuaternion::from_euler_angles(0.0, 0.0, (30.0 * k as f64).to_radians());
                    attempt(
                        model,
                        spec,
                        &tool,
                        &tool_inv,
                        ci,
                        c,
                        &(c.tool_in_base * roll),
                    )
                })
                .find(|a| !a.0.is_empty())
                .unwrap_or(first)
        } else {
            first
        };
        examined += ex;
        rejections.extend(rej);
        let reject_target = |reason| Rejection {
            candidate: ci,
            point: c.point,
            branch: None,
            reason,
        };
        match c.branches {
            BranchPolicy::All => poses.extend(ok),
            BranchPolicy::AllAtLeast(k) => {
                if ok.len() >= k {
                    poses.extend(ok);
                } else if !ok.is_empty() {
                    rejections.push(reject_target(RejectReason::TooFewBranches {
                        got: ok.len(),
                    }));
                }
            }
            BranchPolicy::Best => {
                if let Some(best) = ok.into_iter().min_by(|a, b| {
                    tm.move_time(&tm.home, &a.q)
                        .total_cmp(&tm.move_time(&tm.home, &b.q))
                }) {
                    poses.push(best);
                }
            }
        }
    }
    Feasibility {
        candidates,
        poses,
        rejections,
        examined,
    }
}

/// The model used for the identification Jacobian: tool set, redundancies and the spec's
/// `fixed` parameters fixed.
pub fn identification_model(
    model: &KinematicModel,
    spec: &PlanSpec,
) -> Result<KinematicModel, PlanError> {
    let mut m = model.clone();
    m.set_tool(&frame_iso(&spec.tool));
    if spec.observability.fix_point_redundancies {
        m.fix_point_redundancies();
    }
    for name in &spec.observability.fixed {
        m.set_free(name, false).map_err(|e| PlanError::Spec {
            message: format!("observability.fixed: {e}"),
        })?;
    }
    Ok(m)
}

/// O1 of every greedy prefix of `order` (scaled Jacobian `j`, 3 rows per pose), via the
/// information matrix. Entry k is O1 of the first k+1 poses (0 while singular).
pub fn prefix_o1(j: &DMatrix<f64>, order: &[usize]) -> Vec<f64> {
    let l = j.ncols();
    let mut info = DMatrix::<f64>::zeros(l, l);
    let mut out = Vec::with_capacity(order.len());
    for (k, &i) in order.iter().enumerate() {
        let b = j.rows(3 * i, 3);
        info += b.transpose() * b;
        let o1 = match info.clone().cholesky() {
            Some(c) if 3 * (k + 1) >= l => {
                let logdet: f64 = c.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum();
                (logdet / (2.0 * l as f64)).exp() / ((k + 1) as f64).sqrt()
            }
            _ => 0.0,
        };
        out.push(o1);
    }
    out
}

/// Options of [`build_plan`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PlanOptions {
    /// Keep only this many poses chosen for observability (greedy D-optimal).
    pub select: Option<usize>,
}

/// Everything [`build_plan`] computes.
#[derive(Debug, Clone)]
pub struct PlanOutcome {
    pub file: PlanFile,
    pub feasibility: Feasibility,
    /// Indices into `feasibility.poses`, in the written (optimised) order.
    pub order: Vec<usize>,
}

/// Generate, check, select, order and summarise a plan.
pub fn build_plan(
    spec: &PlanSpec,
    robot: RobotBlock,
    model: &KinematicModel,
    opts: &PlanOptions,
) -> Result<PlanOutcome, PlanError> {
    spec.validate()?;
    let candidates = gen::generate(spec);
    let targets = candidates.len();
    let feas = feasibility(model, spec, candidates);
    let mut warnings = Vec::new();

    // Observability of the full feasible set.
    let idm = identification_model(model, spec)?;
    let qs_all: Vec<&[f64]> = feas.poses.iter().map(|p| p.q.as_slice()).collect();
    let names = observe::free_names(&idm);
    let mut j = observe::stacked_jacobian(&idm, &qs_all);
    let scales = if j.nrows() > 0 {
        observe::column_scales(&j)
    } else {
        DVector::from_element(j.ncols(), 1.0)
    };
    observe::scale_columns(&mut j, &scales);
    let rel_tol = spec.observability.rel_tol;
    let obs_all = observe::analyse(&j, qs_all.len(), &names, rel_tol);

    // Optional selection.
    let mut keep: Vec<usize> = (0..feas.poses.len()).collect();
    let mut select = None;
    if let Some(n) = opts.select {
        let chosen = observe::select_d_optimal(&j, n);
        let prefix = prefix_o1(&j, &chosen);
        let reach = prefix
            .iter()
            .position(|&o| o >= obs_all.o1 && obs_all.o1 > 0.0)
            .map(|k| k + 1);
        let qs_sel: Vec<&[f64]> = chosen.iter().map(|&i| feas.poses[i].q.as_slice()).collect();
        let obs_sel = observe::observability(&idm, &qs_sel, &scales, rel_tol);
        select = Some(file::SelectSummary {
            requested: n,
            all: obs_all.clone(),
            selected: obs_sel,
            poses_to_reach_full_o1: reach,
        });
        keep = chosen;
        keep.sort_unstable();
    }
    let obs_written = match &select {
        Some(s) => s.selected.clone(),
        None => obs_all.clone(),
    };
    for group in &obs_written.unidentifiable {
        warnings.push(format!(
            "UNIDENTIFIABLE with this plan: {} (a null direction of the identification Jacobian)",
            group.join(" + ")
        ));
    }
    if obs_written.condition.is_finite() && obs_written.condition > 1e4 {
        warnings.push(format!(
            "poorly conditioned identification Jacobian (cond {:.2e} > 1e4)",
            obs_written.condition
        ));
    }
    if feas.poses.is_empty() {
        warnings.push("no feasible pose: check the spec against the robot's workspace".into());
    }

    // Order.
    let tm = TimeModel::from_spec(&spec.timing, model.dof());
    let qs_keep: Vec<Vec<f64>> = keep.iter().map(|&i| feas.poses[i].q.clone()).collect();
    let gen_order: Vec<usize> = (0..qs_keep.len()).collect();
    let t_gen = tm.session_time(&qs_keep, &gen_order);
    let opt_order = timing::optimise_order(&tm, &qs_keep);
    let t_opt = tm.session_time(&qs_keep, &opt_order);
    let order: Vec<usize> = opt_order.iter().map(|&k| keep[k]).collect();

    // Safety path check of the final order (table / envelope along joint-interpolated moves).
    let path_violations = path_check(
        model,
        spec,
        &tm,
        &order
            .iter()
            .map(|&i| feas.poses[i].q.clone())
            .collect::<Vec<_>>(),
    );
    if path_violations > 0 {
        warnings.push(format!(
            "{path_violations} moves of the ordered plan pass outside the envelope / below the table clearance"
        ));
    }

    let mut rejects = feas.reject_counts();
    rejects.retain(|_, v| *v > 0);
    let per_branch = {
        let mut m = BTreeMap::new();
        for &i in &keep {
            let p = &feas.poses[i];
            *m.entry(format!("{} {}", p.branch, p.branch_label))
                .or_insert(0) += 1;
        }
        m
    };
    let summary = PlanSummary {
        name: spec.name.clone(),
        targets,
        examined: feas.examined,
        feasible: feas.poses.len(),
        per_branch,
        rejects,
        path_violations,
        timing: file::TimingSummary {
            generated_s: t_gen,
            generated_poses_per_hour: timing::poses_per_hour(qs_keep.len(), t_gen),
            optimised_s: t_opt,
            optimised_poses_per_hour: timing::poses_per_hour(qs_keep.len(), t_opt),
        },
        observability: obs_written,
        select,
        warnings,
    };
    let poses = order
        .iter()
        .enumerate()
        .map(|(id, &i)| {
            let p = &feas.poses[i];
            let c = &feas.candidates[p.candidate];
            PlanPose {
                id: id as u64,
                point: p.point as u64,
                branch: p.branch,
                label: c.label.clone(),
                branch_label: p.branch_label.clone(),
                q_deg: p.q.iter().map(|x| x.to_degrees()).collect(),
                flange: PlanFilePose::from_iso(&p.flange),
                group: c.group.clone(),
                plane: c.plane.clone(),
                move_kind: c.move_kind.clone(),
                block: c.block.map(|b| b as u64),
                target: c.target.clone(),
            }
        })
        .collect();
    let file = PlanFile {
        format: PLAN_FORMAT.into(),
        name: spec.name.clone(),
        robot,
        tool: PlanFilePose::from_iso(&frame_iso(&spec.tool)),
        spec: serde_json::to_value(spec).map_err(|e| PlanError::Spec {
            message: e.to_string(),
        })?,
        poses,
        rejected: feas
            .rejections
            .iter()
            .map(|r| file::RejectedPose {
                point: r.point as u64,
                label: feas.candidates[r.candidate].label.clone(),
                branch: r.branch,
                reason: r.reason.key().to_string(),
                detail: r.reason.to_string(),
            })
            .collect(),
        summary,
    };
    Ok(PlanOutcome {
        file,
        feasibility: feas,
        order,
    })
}

/// Count the moves (home → first, then consecutive) that the safety wrappers' path check
/// refuses (only when a table or envelope is configured).
pub fn path_check(
    model: &KinematicModel,
    spec: &PlanSpec,
    tm: &TimeModel,
    qs: &[Vec<f64>],
) -> usize {
    let c = &spec.constraints;
    let table = constraints::table_plane(c);
    if table.is_none() && c.envelope.is_none() {
        return 0;
    }
    let limits = model.joint_limits();
    let sl = SafetyLimits {
        joint_lower: limits.iter().map(|l| l.0).collect(),
        joint_upper: limits.iter().map(|l| l.1).collect(),
        max_vel: tm.vmax.iter().cloned().fold(f64::INFINITY, f64::min),
        max_acc: tm.amax.iter().cloned().fold(f64::INFINITY, f64::min),
        envelope: c.envelope.clone(),
        table,
        path_step: 2f64.to_radians(),
    };
    let tool = frame_iso(&spec.tool);
    let geom = |q: &[f64]| -> Vec<Point3<f64>> {
        let pts = constraints::arm_points(model, q, &tool);
        let n = pts.len();
        // Flange and tool point: the parts that swing widest.
        pts[n.saturating_sub(2)..].to_vec()
    };
    let mut bad = 0;
    let mut prev: Option<&[f64]> = None;
    for q in qs {
        // The home pose may itself violate (e.g. zeros); start from the first pose then.
        if prev.is_some() && check_move(&sl, Some(&geom), prev, q).is_err() {
            bad += 1;
        }
        prev = Some(q);
    }
    bad
}
