//! The session stage `verify` (seed 001 §3 / §4.4, validation): judge a calibration by what
//! the robot *does* when commanded with it.
//!
//! Targets are the validation plan's (inside the cell, every IK branch the planner found safe
//! and visible). Each target's desired marker pose `W` is a place in the cell (tracker
//! frame): where today's controller believes it sends the marker, the nominal chain (with
//! the fitted tracker → base and marker) at the planned joints. The calibrated model reaches
//! `W` through its own tracker → base (two fits' bases are different gauges of one frame, so
//! a pose "in the base" would not be the same place for both).
//! - **before**: the planned joints are the nominal IK of `T`: the validation run already
//!   commanded them, so its measurements are the "before" (no second run);
//! - **after**: the deployed calibration's inverse kinematics of `T` on the same branch
//!   (`solve::correct`, geometric), commanded by a third run (`run-verify/`), measured with
//!   the tracker.
//!
//! Error = measured marker − desired marker in the tracker frame (each side's own tracker →
//! base), position (RMS, p95, max) and orientation when the marker has one. Seed 001's
//! inverse-solution coincidence error: for each target reached on ≥ 2 branches, the largest
//! distance between the measured positions; its mean over targets, before → after. The
//! verified after-RMS is compared with the predicted held-out after-RMS of the validate
//! stage: more than 20 % worse is flagged.
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use anyhow::{bail, Context as _};
use nalgebra::{Isometry3, Point3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use super::{Cell, Log, SessionFile, SessionKind, Work};
use crate::dataset::{CalibrationFile, Dataset};
use crate::model::KinematicModel;
use crate::plan::file::{PlanFile, PlanFilePose, PlanPose};
use crate::solve::obs::{observations, Split};

/// Largest joint change (deg) from the planned (safety-checked) joints a corrected target may
/// make; larger ones are not commanded (the planner's checks would no longer cover them).
pub const MAX_CORRECTION_DEG: f64 = 5.0;
/// A corrected target whose model miss stays above this (mm) did not converge: with a
/// backlash joint, its direction flips with the correction it causes.
const UNCONVERGED_MM: f64 = 1e-3;
/// Verified after-RMS more than this ratio above the predicted one is flagged.
pub const FLAG_RATIO: f64 = 1.2;

/// Commanded-vs-measured error statistics (mm, deg).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ErrorStats {
    pub poses: usize,
    pub rms_mm: f64,
    pub p95_mm: f64,
    pub max_mm: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rot_rms_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rot_max_deg: Option<f64>,
}

/// What the `verify` stage found (`session.json` `verify`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VerifySummary {
    /// Targets (validation points) and poses commanded after correction.
    pub targets: usize,
    /// Nominal IK (the validation run) and calibrated IK (`run-verify`).
    pub before: ErrorStats,
    pub after: ErrorStats,
    /// Mean over targets reached on ≥ 2 branches of the largest distance between the
    /// measured positions (mm), and how many targets had ≥ 2 branches.
    pub coincidence_mm_before: Option<f64>,
    pub coincidence_mm_after: Option<f64>,
    pub coincidence_targets: usize,
    /// Predicted held-out after-RMS (validate stage) and verified / predicted.
    pub predicted_after_rms_mm: Option<f64>,
    pub verified_vs_predicted: Option<f64>,
    /// Verified worse than predicted by more than 20 %.
    pub flagged: bool,
    /// Poses not commanded (IK failure, correction beyond [`MAX_CORRECTION_DEG`]).
    pub not_commanded: usize,
    /// Effects of the deployed calibration, inverted in the commanded joints (position).
    pub effects_inverted: usize,
    /// Targets reached through a back-off pose (a backlash joint's move too small to fix its
    /// direction; see `session::approach`).
    #[serde(default)]
    pub approach_poses: usize,
    /// The plan and run directory (relative).
    pub plan: String,
    pub run: String,
}

fn stats(pos: &[f64], rot: &[f64]) -> ErrorStats {
    let q = |x: &[f64], p| crate::solve::stats::quantile(x, p);
    ErrorStats {
        poses: pos.len(),
        rms_mm: crate::solve::stats::rms(pos),
        p95_mm: q(pos, 0.95),
        max_mm: pos.iter().cloned().fold(0.0, f64::max),
        rot_rms_deg: (!rot.is_empty()).then(|| crate::solve::stats::rms(rot)),
        rot_max_deg: (!rot.is_empty()).then(|| rot.iter().cloned().fold(0.0, f64::max)),
    }
}

/// One measured pose: its target (point), branch, position and orientation errors.
struct Hit {
    point: u64,
    p: Point3<f64>,
    pos_err: f64,
    /// Measured marker orientation relative to the desired one (marker frame).
    rot_rel: Option<UnitQuaternion<f64>>,
}

/// Errors of every measured pose of `ds` against `desired(id)` (marker pose in the tracker).
fn hits(
    ds: &Dataset,
    dof: usize,
    desired: &dyn Fn(u64) -> Option<(u64, Isometry3<f64>)>,
) -> Vec<Hit> {
    let (obs, _) = observations(ds, dof, Split::All);
    obs.iter()
        .filter_map(|o| {
            let (point, want) = desired(o.id)?;
            Some(Hit {
                point,
                p: o.p,
                pos_err: (o.p.coords - want.translation.vector).norm(),
                rot_rel: o
                    .quat
                    .map(|q: UnitQuaternion<f64>| want.rotation.inverse() * q),
            })
        })
        .collect()
}

/// Mean over targets with ≥ 2 measured branches of the largest pairwise distance.
fn coincidence(h: &[Hit]) -> (Option<f64>, usize) {
    let mut by: BTreeMap<u64, Vec<Point3<f64>>> = BTreeMap::new();
    for x in h {
        by.entry(x.point).or_default().push(x.p);
    }
    let spreads: Vec<f64> = by
        .values()
        .filter(|v| v.len() >= 2)
        .map(|v| {
            let mut m: f64 = 0.0;
            for i in 0..v.len() {
                for j in i + 1..v.len() {
                    m = m.max((v[i] - v[j]).norm());
                }
            }
            m
        })
        .collect();
    let n = spreads.len();
    ((n > 0).then(|| crate::solve::stats::mean(&spreads)), n)
}

fn summarise(h: &[Hit]) -> ErrorStats {
    let pos: Vec<f64> = h.iter().map(|x| x.pos_err).collect();
    stats(&pos, &rotation_errors(h))
}

/// Orientation errors (deg) about the mean relative rotation: the kinematic model locates
/// the marker's origin, not how the marker is turned on the flange, so the constant mounting
/// rotation is removed (a 30° mounting would otherwise read as a 30° error on every pose).
fn rotation_errors(h: &[Hit]) -> Vec<f64> {
    let rel: Vec<UnitQuaternion<f64>> = h.iter().filter_map(|x| x.rot_rel).collect();
    let Some(first) = rel.first() else {
        return Vec::new();
    };
    // Chordal mean: quaternions summed on one hemisphere, normalised.
    let sum = rel.iter().fold(nalgebra::Vector4::zeros(), |acc, q| {
        let v = q.as_ref().coords;
        if v.dot(&first.as_ref().coords) < 0.0 {
            acc - v
        } else {
            acc + v
        }
    });
    if sum.norm() < 1e-12 {
        return Vec::new();
    }
    let mean = UnitQuaternion::from_quaternion(nalgebra::Quaternion::from(sum));
    rel.iter().map(|q| q.angle_to(&mean).to_degrees()).collect()
}

/// The calibrated IK of tool pose `t` (robot base) on `branch`, with the deployed effects
/// inverted when `ctx` (the validation pose's context: time, temperature, the joints the move
/// starts from) is given: the aim point moves by what the full model misses at the current
/// joints, up to 8 times or 1e-4 mm. The approach directions are those of the move to the
/// current joints (`signs`), since the correction itself may decide them. `world` is `t` in
/// the tracker frame. Returns the solution and what the model still misses there (mm): a
/// miss that stays large means no solution agrees with its own approach directions (the
/// backlash flips with the correction it causes).
fn solve_with_effects(
    cal: &KinematicModel,
    effects: &[crate::dataset::CalEffect],
    ctx: Option<&crate::solve::obs::PoseCtx>,
    signs: &dyn Fn(&[f64]) -> Vec<f64>,
    branch: u8,
    t: &Isometry3<f64>,
    world: &Isometry3<f64>,
) -> anyhow::Result<Option<(crate::model::ik::IkSolution, f64)>> {
    let mut aim = *t;
    let mut best = None;
    for _ in 0..8 {
        let Some(sol) = cal.ik_for_tool(&aim).ok().and_then(|v| {
            v.into_iter()
                .find(|x| x.branch == branch && x.within_limits)
        }) else {
            return Ok(best);
        };
        let Some(ctx) = ctx.filter(|_| !effects.is_empty()) else {
            return Ok(Some((sol, 0.0)));
        };
        let mut c = ctx.clone();
        if c.q_cmd.is_some() {
            c.q_cmd = Some(sol.q.clone());
        }
        c.q = sol.q.clone();
        c.approach = signs(&sol.q);
        let pred = crate::diagnose::effects::apply_cal_effects(cal, effects, None, &c)?;
        let miss = world.translation.vector - pred.coords;
        best = Some((sol, miss.norm()));
        if miss.norm() < 1e-4 {
            break;
        }
        aim.translation.vector += cal.base().rotation.inverse() * miss;
    }
    Ok(best)
}

/// Run the `verify` stage (kinematic sessions; a camera session has nothing to command).
pub fn verify_stage(
    dir: &Path,
    s: &mut SessionFile,
    work: &mut Work,
    cell: &mut dyn Cell,
    log: Log,
) -> anyhow::Result<()> {
    if s.setup.kind == SessionKind::Camera {
        return Ok(());
    }
    // Today's controller: the nominal chain with tracker → base and the marker fitted (the
    // identification's "before").
    let nominal = work
        .identification(dir, s)
        .context("verify: the nominal fit (today's controller)")?
        .nominal
        .clone();
    let val = &work.dataset(dir, s, "validation")?.1.dataset;
    let cal_path = dir.join("deploy").join("calibration.json");
    let cal = CalibrationFile::load(&cal_path)
        .with_context(|| format!("verify: {}", cal_path.display()))?;
    let (calibrated, _) = crate::solve::correct::models_of(&cal)
        .with_context(|| format!("verify: {}", cal_path.display()))?;
    let vplan_path = dir.join("plan").join("validation.json");
    let vplan = PlanFile::read(&vplan_path)
        .map_err(|e| anyhow::anyhow!("verify: {}: {e}", vplan_path.display()))?;
    let preset = KinematicModel::from_robot_block(&vplan.robot)?;
    let dof = preset.dof();
    // Desired marker pose in the base of every planned pose: today's belief at the plan's q.
    let target_of = |p: &PlanPose| -> Vec<f64> { p.q_deg.iter().map(|d| d.to_radians()).collect() };
    let before_want: HashMap<u64, (u64, Isometry3<f64>)> = vplan
        .poses
        .iter()
        .map(|p| (p.id, (p.point, nominal.measured_pose(&target_of(p)))))
        .collect();
    let before = hits(val, dof, &|id| before_want.get(&id).copied());
    // The deployed calibration's effects (joint compliance, backlash, …) are inverted by
    // aiming the geometric IK off by what they add, in the validation pose's context.
    let ctxs: HashMap<u64, crate::solve::obs::PoseCtx> = if cal.effects.is_empty() {
        HashMap::new()
    } else {
        let session: Vec<&crate::dataset::PoseRecord> = val.poses().collect();
        let ids: HashMap<usize, u64> = session
            .iter()
            .map(|r| (crate::solve::obs::record_key(r), r.id))
            .collect();
        crate::solve::obs::contexts(&session, dof)
            .into_iter()
            .filter_map(|(k, c)| Some((*ids.get(&k)?, c)))
            .collect()
    };
    // Corrected joints, same branch, within a few degrees of the safety-checked plan.
    let mut poses = Vec::new();
    let mut after_want: HashMap<u64, (u64, Isometry3<f64>)> = HashMap::new();
    let mut not_commanded = 0;
    // Direction-dependent effects (backlash) are inverted for the approach each joint will
    // have in THIS run: the sign of the commanded move from the previous commanded pose (the
    // first from where the validation run left the arm), computed on the corrected joints
    // (see `approach`). A target whose backlash joints would move too little for the servo
    // error to leave their direction certain is reached through a back-off pose.
    let approach = super::approach::Approach::new(&cal.effects, val, dof);
    let limits = calibrated.joint_limits();
    let (mut prev_cmd, mut last_sign) = match ctxs.values().max_by(|a, b| a.t.total_cmp(&b.t)) {
        Some(c) => (Some(c.q.clone()), c.approach.clone()),
        None => (None, vec![0.0; dof]),
    };
    let mut approach_poses = 0;
    for p in &vplan.poses {
        let q_plan = target_of(p);
        // The target is a place in the cell (tracker frame); each model reaches it through
        // its own tracker → base (the bases of two fits are different gauges of one frame).
        let world = nominal.measured_pose(&q_plan);
        let t = calibrated.base().inverse() * world;
        let with_prev = |prev: &[f64]| {
            ctxs.get(&p.id).map(|c| {
                let mut c = c.clone();
                c.q_prev = Some(prev.to_vec());
                c
            })
        };
        let from = prev_cmd.clone().unwrap_or_else(|| q_plan.clone());
        let carried = last_sign.clone();
        let solve = |from: &[f64], carried: &[f64]| {
            let ctx = if prev_cmd.is_some() {
                with_prev(from)
            } else {
                ctxs.get(&p.id).cloned()
            };
            let signs = |q: &[f64]| {
                if prev_cmd.is_some() {
                    approach.signs(from, q, carried)
                } else {
                    carried.to_vec()
                }
            };
            solve_with_effects(
                &calibrated,
                &cal.effects,
                ctx.as_ref(),
                &signs,
                p.branch,
                &t,
                &world,
            )
        };
        let Some((mut sol, miss)) = solve(&from, &carried)? else {
            not_commanded += 1;
            continue;
        };
        let mut sign = approach.signs(&from, &sol.q, &carried);
        let mut via = None;
        if ctxs.contains_key(&p.id)
            && !approach.joints.is_empty()
            && (approach.undetermined(&from, &sol.q) || miss > UNCONVERGED_MM)
        {
            let (back, dir) = approach.backoff(&sol.q, &sign, &limits);
            let Some((s2, _)) = solve(&back, &dir)? else {
                not_commanded += 1;
                continue;
            };
            if approach.undetermined(&back, &s2.q) {
                not_commanded += 1;
                continue;
            }
            sign = approach.signs(&back, &s2.q, &dir);
            sol = s2;
            via = Some(back);
        }
        let jump = sol
            .q
            .iter()
            .chain(via.iter().flatten())
            .zip(q_plan.iter().cycle())
            .map(|(a, b)| (a - b).abs().to_degrees())
            .fold(0.0, f64::max);
        if jump > MAX_CORRECTION_DEG {
            not_commanded += 1;
            continue;
        }
        if let Some(back) = via {
            // Measured like any pose (the acquisition has no pass-through poses) and not scored.
            approach_poses += 1;
            poses.push(PlanPose {
                id: poses.len() as u64,
                label: format!("{}-approach", p.label),
                q_deg: back.iter().map(|x| x.to_degrees()).collect(),
                flange: PlanFilePose::from_iso(&preset.flange_pose(&back)),
                group: "verify-approach".into(),
                ..p.clone()
            });
        }
        prev_cmd = Some(sol.q.clone());
        last_sign = sign;
        let id = poses.len() as u64;
        after_want.insert(id, (p.point, world));
        poses.push(PlanPose {
            id,
            q_deg: sol.q.iter().map(|x| x.to_degrees()).collect(),
            flange: PlanFilePose::from_iso(&preset.flange_pose(&sol.q)),
            group: "verify".into(),
            ..p.clone()
        });
    }
    if poses.is_empty() {
        bail!("verify: no validation target has a corrected IK solution on its planned branch");
    }
    let mut plan = vplan.clone();
    plan.name = format!("{}-verify", vplan.name);
    plan.summary.feasible = poses.len();
    plan.poses = poses;
    let plan_path = dir.join("plan").join("verify.json");
    super::write_atomic(&plan_path, serde_json::to_string_pretty(&plan)?.as_bytes())?;
    PlanFile::read(&plan_path)
        .map_err(|e| anyhow::anyhow!("verify: the written plan does not read back: {e}"))?;
    log(&format!(
        "  {} poses commanded with the calibrated IK ({} not commanded{})",
        after_want.len(),
        not_commanded,
        if approach_poses > 0 {
            format!(
                "; {approach_poses} reached through a back-off pose {:.1}° short on the \
                 backlash joint(s): their direction was undecided (a tiny move, or one the correction reverses)",
                super::approach::BACKOFF_DEG
            )
        } else {
            String::new()
        }
    ));
    let run_dir = dir.join("run-verify");
    let summary = cell.acquire(&plan_path, &run_dir).with_context(|| {
        format!(
            "acquiring the verify poses (continue with `robocal session --resume {}`)",
            dir.display()
        )
    })?;
    if let Some(reason) = &summary.aborted {
        bail!("verify acquisition stopped: {reason}");
    }
    let ds_path = run_dir.join("dataset.jsonl");
    let vds = Dataset::load(&ds_path).with_context(|| format!("{}", ds_path.display()))?;
    let after = hits(&vds, dof, &|id| after_want.get(&id).copied());
    if after.is_empty() {
        bail!("verify: no usable measured pose in {}", ds_path.display());
    }
    let (cb, nb) = coincidence(&before);
    let (ca, na) = coincidence(&after);
    let b = summarise(&before);
    let a = summarise(&after);
    let predicted = s.measured.heldout_rms_mm_after;
    let ratio = predicted.filter(|p| *p > 0.0).map(|p| a.rms_mm / p);
    let flagged = ratio.is_some_and(|r| r > FLAG_RATIO);
    let v = VerifySummary {
        targets: before_want
            .values()
            .map(|(p, _)| *p)
            .collect::<std::collections::BTreeSet<_>>()
            .len(),
        before: b,
        after: a,
        coincidence_mm_before: cb,
        coincidence_mm_after: ca,
        coincidence_targets: nb.min(na),
        predicted_after_rms_mm: predicted,
        verified_vs_predicted: ratio,
        flagged,
        not_commanded,
        effects_inverted: cal.effects.len(),
        approach_poses,
        plan: "plan/verify.json".into(),
        run: "run-verify".into(),
    };
    if flagged {
        s.warnings.push(format!(
            "verify: the calibrated robot verifies at {:.4} mm RMS, {:.0} % worse than the \
             predicted held-out {:.4} mm{}",
            v.after.rms_mm,
            (ratio.unwrap_or(0.0) - 1.0) * 100.0,
            predicted.unwrap_or(f64::NAN),
            if v.effects_inverted > 0 {
                format!(
                    " ({} diagnosed effect(s) inverted in the commanded joints)",
                    v.effects_inverted
                )
            } else {
                String::new()
            }
        ));
    }
    let m = &mut s.measured;
    m.verified_rms_mm_before = Some(v.before.rms_mm);
    m.verified_rms_mm_after = Some(v.after.rms_mm);
    m.verified_max_mm_after = Some(v.after.max_mm);
    m.coincidence_mm_before = v.coincidence_mm_before;
    m.coincidence_mm_after = v.coincidence_mm_after;
    m.verified_vs_predicted = v.verified_vs_predicted;
    log(&format!("  {}", line(&v)));
    s.verify = Some(v);
    Ok(())
}

/// One line of the closing note: verified before → after, coincidence, predicted.
pub fn line(v: &VerifySummary) -> String {
    let f = |x: Option<f64>| x.map_or("–".into(), |x| format!("{x:.4}"));
    format!(
        "verified (commanded vs measured) RMS {:.4} → {:.4} mm, p95 {:.4} → {:.4}, max {:.4} → {:.4}; coincidence {} → {} mm ({} targets); predicted held-out after {} mm{}",
        v.before.rms_mm,
        v.after.rms_mm,
        v.before.p95_mm,
        v.after.p95_mm,
        v.before.max_mm,
        v.after.max_mm,
        f(v.coincidence_mm_before),
        f(v.coincidence_mm_after),
        v.coincidence_targets,
        f(v.predicted_after_rms_mm),
        if v.flagged {
            " — FLAGGED: verifies > 20 % worse than predicted"
        } else {
            ""
        }
    )
}

/// The verify table of a fleet / the closing note (seed 001 §3): per robot, predicted
/// held-out after, verified before → after, coincidence before → after (mm).
pub fn fleet_table(sessions: &[SessionFile]) -> String {
    use std::fmt::Write as _;
    let f = |x: Option<f64>| x.map_or("—".into(), |x| format!("{x:.4}"));
    let mut t = String::from(
        "\n| robot | predicted held-out after (mm) | verified before → after (mm) | coincidence before → after (mm) | flag |\n|---|---|---|---|---|\n",
    );
    for s in sessions {
        let Some(v) = &s.verify else { continue };
        let _ = writeln!(
            t,
            "| {} | {} | {:.4} → {:.4} | {} → {} | {} |",
            s.cell.robot_serial.as_deref().unwrap_or("?"),
            f(v.predicted_after_rms_mm),
            v.before.rms_mm,
            v.after.rms_mm,
            f(v.coincidence_mm_before),
            f(v.coincidence_mm_after),
            if v.flagged {
                "verifies > 20 % worse"
            } else {
                ""
            }
        );
    }
    t
}

/// The report's section on the verify stage: commanded-vs-measured before / after (table and a
/// log-scale bar chart, so a 50× improvement stays readable), the coincidence error and how
/// the verified error compares with the prediction.
pub fn html(v: &VerifySummary) -> String {
    use std::fmt::Write as _;
    let f = |x: Option<f64>| x.map_or("—".into(), |x| format!("{x:.4}"));
    let mut h = String::from(
        "<h2>Verification: the calibrated robot commanded to held-out targets</h2>\
         <p>Each held-out target was reached with the nominal inverse kinematics (before) and \
         with the calibration's (after), and the tracker measured where the tool went.</p>\
         <table id=\"verify\"><tr><th></th><th>poses</th><th>RMS (mm)</th><th>p95 (mm)</th>\
         <th>max (mm)</th><th>orientation RMS (°)</th><th>orientation max (°)</th></tr>",
    );
    for (name, e) in [
        ("before (nominal IK)", &v.before),
        ("after (calibrated IK)", &v.after),
    ] {
        let _ = write!(
            h,
            "<tr><th>{name}</th><td>{}</td><td>{:.4}</td><td>{:.4}</td><td>{:.4}</td><td>{}</td><td>{}</td></tr>",
            e.poses,
            e.rms_mm,
            e.p95_mm,
            e.max_mm,
            f(e.rot_rms_deg),
            f(e.rot_max_deg)
        );
    }
    h.push_str("</table>");
    let _ = write!(
        h,
        "<p>Same target on different inverse-kinematics branches, spread of the measured \
         positions: {} → {} mm ({} targets). Targets not commanded: {}.</p>",
        f(v.coincidence_mm_before),
        f(v.coincidence_mm_after),
        v.coincidence_targets,
        v.not_commanded
    );
    if let (Some(p), Some(r)) = (v.predicted_after_rms_mm, v.verified_vs_predicted) {
        let cls = if v.flagged { "flag" } else { "ok" };
        let _ = write!(
            h,
            "<p class=\"{cls}\" id=\"verify-vs-predicted\">Verified RMS {:.4} mm against {p:.4} mm \
             predicted on the held-out poses: {r:.2}×{}</p>",
            v.after.rms_mm,
            if v.flagged {
                format!(
                    " — the calibration verifies worse than it predicts by more than {:.0} %: \
                     an effect acts when the robot is commanded that the held-out scoring at the \
                     measured joint angles does not see",
                    (FLAG_RATIO - 1.0) * 100.0
                )
            } else {
                " (within the expected range)".to_string()
            }
        );
    }
    h.push_str(&bars_svg(v));
    h
}

/// Before / after RMS, p95 and max as paired horizontal bars on a log axis (mm).
fn bars_svg(v: &VerifySummary) -> String {
    use std::fmt::Write as _;
    let rows = [
        ("RMS", v.before.rms_mm, v.after.rms_mm),
        ("p95", v.before.p95_mm, v.after.p95_mm),
        ("max", v.before.max_mm, v.after.max_mm),
    ];
    let vals: Vec<f64> = rows
        .iter()
        .flat_map(|r| [r.1, r.2])
        .filter(|x| x.is_finite() && *x > 0.0)
        .collect();
    if vals.is_empty() {
        return String::new();
    }
    let lo = vals.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = vals.iter().cloned().fold(0.0, f64::max);
    let (d0, d1) = (
        lo.log10().floor(),
        hi.log10().ceil().max(lo.log10().floor() + 1.0),
    );
    let (x0, w) = (60.0, 560.0);
    let x = |v: f64| x0 + (v.max(10f64.powf(d0)).log10() - d0) / (d1 - d0) * w;
    let height = 40.0 + rows.len() as f64 * 44.0;
    let mut s = format!(
        "<figure id=\"plot-verify\"><svg xmlns=\"http://www.w3.org/2000/svg\" width=\"700\" \
         height=\"{height:.0}\" font-family=\"sans-serif\" font-size=\"12\">"
    );
    let mut d = d0;
    while d <= d1 + 1e-9 {
        let xv = x(10f64.powf(d));
        let _ = write!(
            s,
            "<line x1=\"{xv:.1}\" y1=\"10\" x2=\"{xv:.1}\" y2=\"{:.0}\" stroke=\"#ddd\"/>\
             <text x=\"{xv:.1}\" y=\"{:.0}\" text-anchor=\"middle\">{:.*}</text>",
            height - 22.0,
            height - 8.0,
            (-d).max(0.0) as usize,
            10f64.powf(d)
        );
        d += 1.0;
    }
    for (i, (name, b, a)) in rows.iter().enumerate() {
        let y = 14.0 + i as f64 * 44.0;
        let _ = write!(
            s,
            "<text x=\"4\" y=\"{:.0}\">{name}</text>\
             <rect x=\"{x0}\" y=\"{y:.0}\" width=\"{:.1}\" height=\"16\" fill=\"#9aa4b1\"/>\
             <text x=\"{:.1}\" y=\"{:.0}\">{b:.4} before</text>\
             <rect x=\"{x0}\" y=\"{:.0}\" width=\"{:.1}\" height=\"16\" fill=\"#1a7f37\"/>\
             <text x=\"{:.1}\" y=\"{:.0}\">{a:.4} after</text>",
            y + 22.0,
            (x(*b) - x0).max(1.0),
            x(*b) + 4.0,
            y + 12.0,
            y + 18.0,
            (x(*a) - x0).max(1.0),
            x(*a) + 4.0,
            y + 30.0,
        );
    }
    let _ = write!(
        s,
        "</svg><figcaption>Commanded-vs-measured position error (mm, log scale), before and \
         after.</figcaption></figure>"
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coincidence_is_the_mean_largest_branch_spread() {
        let h = |point, x: f64| Hit {
            point,
            p: Point3::new(x, 0.0, 0.0),
            pos_err: x.abs(),
            rot_rel: None,
        };
        let v = vec![
            h(1, 0.0),
            h(1, 0.3),
            h(1, 0.1),
            h(2, 1.0),
            h(2, 2.0),
            h(3, 5.0),
        ];
        let (c, n) = coincidence(&v);
        assert_eq!(n, 2);
        assert!((c.unwrap() - 0.65).abs() < 1e-12);
        let s = summarise(&v);
        assert_eq!(s.poses, 6);
        assert!((s.max_mm - 5.0).abs() < 1e-12);
        assert!(s.rot_rms_deg.is_none());
        assert_eq!(coincidence(&v[5..]).1, 0);
    }

    #[test]
    fn a_constant_mounting_rotation_is_not_an_orientation_error() {
        let mount = UnitQuaternion::from_euler_angles(0.0, 0.0, 30f64.to_radians());
        let h: Vec<Hit> = [0.0, 0.1, -0.1]
            .iter()
            .map(|d: &f64| Hit {
                point: 1,
                p: Point3::origin(),
                pos_err: 0.0,
                rot_rel: Some(mount * UnitQuaternion::from_euler_angles(d.to_radians(), 0.0, 0.0)),
            })
            .collect();
        let s = summarise(&h);
        let rms = s.rot_rms_deg.unwrap();
        // errors 0, 0.1, 0.1 deg about the mean: RMS sqrt(2/3)·0.1
        assert!((rms - (2.0f64 / 3.0).sqrt() * 0.1).abs() < 1e-6, "{rms}");
    }
}
