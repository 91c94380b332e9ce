//! The laser session (seed 000): the hand-eye of a laser range sensor on the flange from three
//! orthogonal calibration planes, validated on five-direction targets.
//!
//! Stages (in this order; `session.json` records each, `--resume` continues):
//! 1. plan: the calibration planes (`[planes]`, 60 poses a plane) and the *selection* targets:
//!    the first half (along v) of the spec's five-direction plate, aimed with the nominal
//!    beam mounting (`plan/train.json`, `plan/selection.json`);
//! 2. acquire-train: both (`run-train/`, `run-selection/`);
//! 3. calibrate: the seed's methods side by side (closed form per plane, data selection per
//!    plane scored on the selection targets, orthogonal-planes LM, direct ML), the spots
//!    through the *identified* arm when the session has the arm's kinematic calibration of the
//!    same visit (`calibrate/calibration.json`, `calibrate/laser_report.json`);
//! 4. acquire-validation: the held-out targets (second half of the plate), planned only now
//!    and aimed with the CALIBRATED beam (`plan/validation.json`, `run-validation/`);
//! 5. diagnose: range scale, incidence, non-linearity (`diagnose/`);
//! 6. validate: every method and the diagnosed beam on the held-out targets, the nominal
//!    mounting as "before" (`validate/laser_report.json`), `deploy/calibration.json`;
//! 7. verify: not applicable (nothing is commanded with the beam); 8. report.
//!
//! Never reads the simulator's truth: the figures are the five-direction spreads (the spots of
//! one target seen from five directions agree only when the beam is right) and the planes' RMS.
use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{bail, Context as _};
use nalgebra::{Point3, Rotation3, Unit, Vector3};
use serde::{Deserialize, Serialize};

use super::{acquire_set, load_ds, stage_done, write_atomic, Cell, Log, SessionFile, Stage};
use crate::dataset::{Dataset, RobotBlock};
use crate::model::KinematicModel;
use crate::plan::{self, spec::FrameSpec, PlanOptions, PlanSpec};
use crate::solve::laser::{self, Beam, LaserObs};

/// The default plan spec of a laser session.
pub const SPEC: &str = include_str!("../../plans/seed000-session.toml");
/// The default acceptance spec of a laser session.
pub const ACCEPT: &str = include_str!("../../accept/laser.toml");
/// The copy of the arm's kinematic calibration in the session directory.
pub const ARM_CALIBRATION: &str = "arm-calibration.json";
/// The arm's kinematic calibration refined jointly with the beam (calibrate stage).
pub const ARM_REFINED: &str = "calibrate/arm-refined.json";

/// Seed 000's figures (mean ± sd of the five-direction spread, mm): one plane, orthogonal planes.
pub const SEED_SINGLE_PLANE_MM: (f64, f64) = (1.37, 0.24);
pub const SEED_ORTHOGONAL_MM: (f64, f64) = (0.37, 0.05);

/// One method on the held-out targets, with the seed's figure for it when the seed gives one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MethodSpread {
    pub method: String,
    /// Calibration points it used.
    pub points: usize,
    /// Five-direction spread over the held-out targets: mean and sd (mm).
    pub spread_mean_mm: f64,
    pub spread_sd_mm: f64,
    /// The seed's mean ± sd for this kind of method (mm), if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed_mm: Option<[f64; 2]>,
}

/// `session.json` `laser`: what the laser session found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaserSummary {
    /// Where the flange poses come from (identified arm / controller's nominal kinematics).
    pub flange_poses: String,
    /// The nominal mounting (the plan's tool) and the deployed beam: point (mm), direction.
    pub nominal_r_mm: [f64; 3],
    pub nominal_v: [f64; 3],
    pub beam_r_mm: [f64; 3],
    pub beam_v: [f64; 3],
    /// 1.96 σ of the beam point (mm), from the direct fit's covariance.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beam_r_ci95_mm: Option<[f64; 3]>,
    /// Targets that scored the data selection / held-out targets reported.
    pub selection_targets: usize,
    pub validation_targets: usize,
    /// Point-to-plane RMS of the calibration data (mm): plain beam, with the laser effects.
    pub plane_rms_mm: f64,
    pub plane_rms_mm_diagnosed: Option<f64>,
    /// Effects the diagnosis added (kind).
    pub effects: Vec<String>,
    /// Every method on the held-out targets (the deployed, diagnosed beam last).
    pub methods: Vec<MethodSpread>,
}

/// A laser session's plan spec: one file with the calibration planes (`[planes]`) and the
/// five-direction plate (`[validation.five_direction]`, at least two target rows: the first
/// half scores the data selection, the second half is held out), sharing the tool (the
/// nominal beam mounting), laser window, constraints and timing. Returns the planes' spec and
/// the plate's spec, each a valid single-generator plan spec.
pub fn parse_spec(text: &str) -> anyhow::Result<(PlanSpec, PlanSpec)> {
    let both: PlanSpec = toml::from_str(text).map_err(|e| {
        anyhow::anyhow!(crate::schema::kind::with_toml_hint(
            format_args!("not a valid plan spec: {e}"),
            text,
            crate::schema::kind::TomlKind::PlanSpec,
        ))
    })?;
    if both.planes.as_ref().is_none_or(|p| p.planes.is_empty()) {
        bail!("a laser session needs calibration planes: add [planes] with [[planes.planes]] (see plans/seed000-session.toml)");
    }
    let Some(f) = both
        .validation
        .as_ref()
        .and_then(|v| v.five_direction.as_ref())
    else {
        bail!("a laser session needs the five-direction validation plate: add [validation.five_direction] (see plans/seed000-session.toml)");
    };
    if f.targets[1] < 2 || f.targets[0] < 1 {
        bail!(
            "[validation.five_direction] targets = {:?}: need at least 2 rows along v (the \
             first half scores the data selection, the second half is held out)",
            f.targets
        );
    }
    let mut planes = both.clone();
    planes.validation = None;
    planes.validate().context("[planes]")?;
    let mut targets = both;
    targets.planes = None;
    if let Some(v) = targets.validation.as_mut() {
        v.coincidence = None;
    }
    targets.validate().context("[validation.five_direction]")?;
    Ok((planes, targets))
}

/// The beam of a tool frame: origin, +z.
pub fn beam_of_frame(f: &FrameSpec) -> Beam {
    let iso = plan::frame_iso(f);
    Beam {
        r: iso.translation.vector,
        v: Unit::new_normalize(iso.rotation * Vector3::z()),
    }
}

/// The tool frame whose origin is the beam point and whose +z is the beam.
pub fn frame_of_beam(b: &Beam) -> FrameSpec {
    let rot = Rotation3::rotation_between(&Vector3::z(), &b.v.into_inner())
        .unwrap_or_else(Rotation3::identity);
    let (r, p, y) = rot.euler_angles();
    FrameSpec {
        xyz: [b.r.x, b.r.y, b.r.z],
        rpy: [r.to_degrees(), p.to_degrees(), y.to_degrees()],
    }
}

/// The spec of one half of the five-direction plate (`half` 0: selection, 1: held out),
/// aimed with `tool`.
fn targets_spec(spec: &PlanSpec, half: usize, tool: FrameSpec) -> anyhow::Result<PlanSpec> {
    let mut t = spec.clone();
    t.tool = tool;
    let (group, tag) = if half == 0 {
        ("selection", "sel")
    } else {
        ("validation", "val")
    };
    t.group = group.into();
    t.name = format!("{}-{group}", spec.name);
    t.seed = spec.seed.wrapping_add(1 + half as u64);
    let f = t
        .validation
        .as_mut()
        .and_then(|v| v.five_direction.as_mut())
        .context("no five-direction plate")?;
    let n = Vector3::from(f.plane.normal)
        .try_normalize(1e-9)
        .context("five-direction plate: zero normal")?;
    let u = Vector3::from(f.plane.u_axis);
    let ev = n
        .cross(&u)
        .try_normalize(1e-9)
        .context("five-direction plate: u_axis parallel to the normal")?;
    let sv = f.plane.size_mm[1];
    let shift = ev * (sv / 4.0) * if half == 0 { -1.0 } else { 1.0 };
    for k in 0..3 {
        f.plane.center_mm[k] += shift[k];
    }
    f.plane.size_mm[1] = sv / 2.0;
    f.plane.name = format!("{}-{tag}", f.plane.name);
    f.targets[1] = if half == 0 {
        f.targets[1] / 2
    } else {
        f.targets[1] - f.targets[1] / 2
    };
    Ok(t)
}

/// The session's plan specs (planes, plate), fitted to the cell: home, speed caps, settling.
fn session_spec(dir: &Path, s: &SessionFile) -> anyhow::Result<(PlanSpec, PlanSpec)> {
    let p = dir.join(&s.setup.spec_file);
    let text =
        crate::fsio::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
    let (mut planes, mut plate) = parse_spec(&text).with_context(|| format!("{}", p.display()))?;
    fit_timing(&mut planes, s);
    fit_timing(&mut plate, s);
    Ok((planes, plate))
}

/// A tracker-less session's plan timing fitted to the cell: home, speed caps, the arm's
/// settling and the settle detector's window (laser and RCM sessions).
pub(super) fn fit_timing(spec: &mut PlanSpec, s: &SessionFile) {
    let settle = crate::acquire::SettleOptions::default();
    if let Some(h) = &s.cell.home_deg {
        spec.timing.home_deg = Some(h.clone());
    }
    spec.timing.speed_deg_s = vec![s.setup.speed_deg_s];
    spec.timing.accel_deg_s2 = vec![s.setup.accel_deg_s2];
    spec.timing.settle_s = s.cell.settle_s.unwrap_or(0.3) + settle.poll_s * settle.window as f64;
}

fn robot(s: &SessionFile) -> RobotBlock {
    RobotBlock {
        model: s.cell.robot_model.clone(),
        serial: s.cell.robot_serial.clone(),
        chain: None,
        flange: None,
        extra: Default::default(),
    }
}

/// Plans `spec` and writes `plan/{name}.json` and `.txt`; returns the pose count.
pub(super) fn plan_set(
    dir: &Path,
    s: &mut SessionFile,
    spec: &PlanSpec,
    name: &str,
    log: Log,
) -> anyhow::Result<usize> {
    let rb = robot(s);
    let model = KinematicModel::from_robot_block(&rb).context("the cell's robot")?;
    let out = plan::build_plan(spec, rb, &model, &PlanOptions::default())?;
    let f = &out.file;
    if f.poses.is_empty() {
        bail!("the {name} plan has no feasible pose in this cell: check the spec against the cell file");
    }
    let pdir = dir.join("plan");
    write_atomic(
        &pdir.join(format!("{name}.json")),
        serde_json::to_string_pretty(f)?.as_bytes(),
    )?;
    write_atomic(
        &pdir.join(format!("{name}.txt")),
        plan::export::summary_text(&f.summary).as_bytes(),
    )?;
    for (k, v) in &f.summary.rejects {
        *s.plan_rejects.entry(format!("{name}: {k}")).or_insert(0) += v;
    }
    s.predicted_duration_s += f.summary.timing.optimised_s;
    s.poses_planned += f.poses.len();
    // The planes' poses are not a kinematic identification: its Jacobian warnings do not apply.
    s.warnings.extend(
        f.summary
            .warnings
            .iter()
            .filter(|w| !w.contains("identification Jacobian"))
            .map(|w| format!("{name} plan: {w}")),
    );
    log(&format!(
        "  {name}: {} poses, {:.0} s predicted",
        f.poses.len(),
        f.summary.timing.optimised_s
    ));
    Ok(f.poses.len())
}

/// The arm the spots go through: the session's copy of the kinematic calibration, if any.
fn arm(
    dir: &Path,
    s: &SessionFile,
    ds: &Dataset,
    ds_path: &Path,
) -> anyhow::Result<Option<laser::IdentifiedArm>> {
    match &s.setup.arm_calibration {
        Some(f) => {
            // Once the calibrate stage has refined the arm with the laser's data, every
            // later stage reads the spots through the refined arm.
            let refined = dir.join(ARM_REFINED);
            let p = if refined.is_file() {
                refined
            } else {
                dir.join(f)
            };
            Ok(Some(laser::identified_arm(&p, ds, ds_path)?))
        }
        None => Ok(None),
    }
}

/// Observations of a session dataset (through the identified arm when there is one).
fn obs_of(dir: &Path, s: &SessionFile, role: &str) -> anyhow::Result<Vec<LaserObs>> {
    let (p, ds) = load_ds(dir, s, role)?;
    let arm = arm(dir, s, &ds, &p)?;
    laser::observations_through(&ds, arm.as_ref())
        .with_context(|| format!("reading laser poses of {}", p.display()))
}

/// The calibration planes' and the two target sets' observations.
struct Data {
    train: Vec<LaserObs>,
    selection: Vec<LaserObs>,
}

fn data(dir: &Path, s: &SessionFile) -> anyhow::Result<Data> {
    let train: Vec<LaserObs> = obs_of(dir, s, "train")?
        .into_iter()
        .filter(|o| o.plane.is_some())
        .collect();
    let selection: Vec<LaserObs> = obs_of(dir, s, "selection")?
        .into_iter()
        .filter(|o| o.target.is_some())
        .collect();
    Ok(Data { train, selection })
}

/// Runs (or continues) a laser session.
pub fn run(
    dir: &Path,
    mut s: SessionFile,
    cell: &mut dyn Cell,
    log: Log,
) -> anyhow::Result<SessionFile> {
    if !s.done(Stage::Plan) {
        log("plan: calibration planes + selection targets (nominal beam mounting)");
        let (train, plate) = session_spec(dir, &s)?;
        s.poses_planned = 0;
        s.predicted_duration_s = 0.0;
        s.plan_rejects.clear();
        plan_set(dir, &mut s, &train, "train", &mut *log)?;
        let sel = targets_spec(&plate, 0, plate.tool.clone())?;
        plan_set(dir, &mut s, &sel, "selection", &mut *log)?;
        s.warnings.push(
            "the held-out targets are planned after the calibration, aimed with the calibrated beam"
                .into(),
        );
        stage_done(dir, &mut s, Stage::Plan)?;
    }
    if s.setup.plan_only {
        return Ok(s);
    }
    if !s.done(Stage::AcquireTrain) {
        for set in ["train", "selection"] {
            if !s.datasets.iter().any(|d| d.role == set) {
                acquire_set(dir, &mut s, cell, set, &mut *log)?;
                s.save(&dir.join("session.json"))?;
            }
        }
        stage_done(dir, &mut s, Stage::AcquireTrain)?;
    }
    if !s.done(Stage::Calibrate) {
        log(
            "calibrate: the seed's laser methods side by side, selection scored on its own targets",
        );
        calibrate_stage(dir, &mut s, &mut *log)?;
        stage_done(dir, &mut s, Stage::Calibrate)?;
    }
    if !s.done(Stage::AcquireValidation) {
        if !dir.join("plan").join("validation.json").is_file() {
            log("plan: held-out targets aimed with the calibrated beam");
            let cal = crate::dataset::CalibrationFile::load(
                dir.join("calibrate").join("calibration.json"),
            )
            .context("reading calibrate/calibration.json")?;
            let beam = laser::beam_from_calibration(&cal)?;
            let (_, plate) = session_spec(dir, &s)?;
            let val = targets_spec(&plate, 1, frame_of_beam(&beam))?;
            plan_set(dir, &mut s, &val, "validation", &mut *log)?;
            s.save(&dir.join("session.json"))?;
        }
        acquire_set(dir, &mut s, cell, "validation", &mut *log)?;
        stage_done(dir, &mut s, Stage::AcquireValidation)?;
    }
    if !s.done(Stage::Diagnose) {
        log("diagnose: laser range scale, incidence, non-linearity");
        diagnose_stage(dir, &mut s, &mut *log)?;
        stage_done(dir, &mut s, Stage::Diagnose)?;
    }
    if !s.done(Stage::Validate) {
        log("validate: five-direction spread on the held-out targets, every method");
        validate_stage(dir, &mut s, &mut *log)?;
        stage_done(dir, &mut s, Stage::Validate)?;
    }
    // Nothing is commanded with the beam: the held-out targets are the verification.
    super::close_without_verify(dir, &mut s)?;
    Ok(s)
}

fn flange_note(dir: &Path, s: &SessionFile) -> String {
    match &s.setup.arm_calibration {
        Some(f) if dir.join(ARM_REFINED).is_file() => format!(
            "joints through the identified arm ({f}) with its joint parameters refined jointly \
             with the beam ({ARM_REFINED}, deployed as deploy/arm-calibration.json)"
        ),
        Some(f) => format!("joints through the identified arm and its joint effects ({f})"),
        None => "the controller's flange (nominal kinematics: the arm's errors stay in the spots)"
            .into(),
    }
}

fn calibrate_stage(dir: &Path, s: &mut SessionFile, log: Log) -> anyhow::Result<()> {
    let d = data(dir, s)?;
    if s.setup.arm_calibration.is_none() {
        s.warnings.push(
            "no kinematic calibration of the arm (--arm-calibration): the laser spots keep the \
             arm's nominal kinematic errors"
                .into(),
        );
    }
    if s.setup.arm_calibration.is_some() {
        let (p, ds) = load_ds(dir, s, "train")?;
        if let Some(a) = arm(dir, s, &ds, &p)? {
            log(&format!(
                "  flange poses through the identified arm: geometry + {}",
                if a.applied.is_empty() {
                    "no joint effect".to_string()
                } else {
                    a.applied.join(", ")
                }
            ));
            if !a.left_out.is_empty() {
                s.warnings.push(format!(
                    "arm calibration effects left out of the flange poses (they do not act on \
                     the joints): {}",
                    a.left_out.join(", ")
                ));
            }
        }
    }
    // A resumed stage starts again from the arm as calibrated.
    let refined = dir.join(ARM_REFINED);
    if refined.is_file() {
        std::fs::remove_file(&refined)
            .with_context(|| format!("removing the stale {}", refined.display()))?;
    }
    let mut cmp = laser::compare_split(&d.train, &d.selection, &d.selection, None, None)
        .context("laser hand-eye calibration")?;
    if s.setup.arm_calibration.is_some() && refine_arm(dir, s, &cmp, &mut *log)? {
        let d = data(dir, s)?;
        cmp = laser::compare_split(&d.train, &d.selection, &d.selection, None, None)
            .context("laser hand-eye calibration through the refined arm")?;
    }
    let (_, train_ds) = load_ds(dir, s, "train")?;
    let mut cal = laser::calibration_file(train_ds.header.robot.clone(), &cmp)?;
    cal.extra
        .insert("flange_poses".into(), flange_note(dir, s).into());
    cal.extra.insert("datasets".into(), s.dataset_hashes());
    let out = dir.join("calibrate");
    std::fs::create_dir_all(&out)?;
    cal.save(out.join("calibration.json"))
        .context("writing calibrate/calibration.json")?;
    crate::schema::write(&out.join("laser_report.json"), &cmp.to_report_file())?;
    for line in laser::table(&cmp).lines() {
        log(&format!("  {line}"));
    }
    s.measured.laser_plane_rms_mm = Some(cmp.final_plane_rms_mm);
    Ok(())
}

/// Refines the arm's joint parameters jointly with the beam, the planes and the selection
/// targets ([`laser::arm_refine`]; prior: the session's arm calibration) and writes
/// [`ARM_REFINED`]. `Ok(false)` (with a warning) when the refinement does not converge or does
/// not lower the selection targets' spread: the stage then keeps the arm as calibrated.
fn refine_arm(
    dir: &Path,
    s: &mut SessionFile,
    cmp: &laser::Comparison,
    log: Log,
) -> anyhow::Result<bool> {
    let Some(f) = s.setup.arm_calibration.clone() else {
        return Ok(false);
    };
    let Some(beam) = cmp.final_beam else {
        return Ok(false);
    };
    let cal_path = dir.join(&f);
    let cal = crate::dataset::CalibrationFile::load(&cal_path)
        .with_context(|| format!("reading {}", cal_path.display()))?;
    let (tp, tds) = load_ds(dir, s, "train")?;
    let arm = laser::identified_arm(&cal_path, &tds, &tp)?;
    let train: Vec<_> = laser::arm_refine::arm_observations(&tds, &arm)?
        .into_iter()
        .filter(|o| o.obs.plane.is_some())
        .collect();
    let (_, sds) = load_ds(dir, s, "selection")?;
    let selection: Vec<_> = laser::arm_refine::arm_observations(&sds, &arm)?
        .into_iter()
        .filter(|o| o.obs.target.is_some())
        .collect();
    let r = match laser::arm_refine::refine(
        &arm,
        &cal,
        &train,
        &selection,
        &cmp.outliers,
        (&beam, &cmp.final_planes),
        &Default::default(),
    ) {
        Ok(r) => r,
        Err(e) => {
            s.warnings
                .push(format!("arm refinement with the laser data failed ({e}): the spots go through the arm as calibrated"));
            return Ok(false);
        }
    };
    let id = &r.identifiability;
    log(&format!(
        "  arm refinement: {} joint parameters; directions pinned better than the kinematic \
         calibration: planes {} / with selection targets {} (largest σ-scaled singular values \
         {:.2} / {:.2}); plane RMS {:.4} -> {:.4} mm, selection spread {:.4} -> {:.4} mm",
        id.arm_params.len(),
        id.planes_pinned,
        id.with_targets_pinned,
        id.planes_sv.first().copied().unwrap_or(0.0),
        id.with_targets_sv.first().copied().unwrap_or(0.0),
        r.plane_rms_before_mm,
        r.plane_rms_after_mm,
        r.selection_spread_before_mm,
        r.selection_spread_after_mm
    ));
    // The planes are the calibration's own evidence: a refinement that buys the targets'
    // agreement with the planes' fit is a model the data do not support.
    if r.plane_rms_after_mm > 1.5 * r.plane_rms_before_mm + 0.01 {
        s.warnings.push(format!(
            "arm refinement with the laser data raised the planes' RMS ({:.4} -> {:.4} mm): the \
             spots go through the arm as calibrated",
            r.plane_rms_before_mm, r.plane_rms_after_mm
        ));
        return Ok(false);
    }
    if r.selection_spread_after_mm >= r.selection_spread_before_mm {
        s.warnings.push(format!(
            "arm refinement with the laser data did not lower the selection spread ({:.4} -> \
             {:.4} mm): the spots go through the arm as calibrated",
            r.selection_spread_before_mm, r.selection_spread_after_mm
        ));
        return Ok(false);
    }
    let out = laser::arm_refine::refined_calibration(&cal, &r);
    let p = dir.join(ARM_REFINED);
    if let Some(parent) = p.parent() {
        std::fs::create_dir_all(parent)?;
    }
    out.save(&p)
        .with_context(|| format!("writing {}", p.display()))?;
    Ok(true)
}

/// The comparison the calibrate stage made (deterministic: recomputed from the same data).
fn comparison(d: &Data, validation: &[LaserObs]) -> anyhow::Result<laser::Comparison> {
    laser::compare_split(&d.train, &d.selection, validation, None, None)
        .context("laser hand-eye calibration")
}

fn diagnose_stage(dir: &Path, s: &mut SessionFile, log: Log) -> anyhow::Result<()> {
    let d = data(dir, s)?;
    let cmp = comparison(&d, &d.selection)?;
    let beam = cmp.final_beam.context("no beam")?;
    // The selection targets (never the held-out ones) score the effects' spread.
    let diag = laser::effects::diagnose(&d.train, &d.selection, &beam, &cmp.final_planes)
        .context("laser effect diagnosis")?;
    let final_beam = diag.beam.unwrap_or(beam);
    let (_, train_ds) = load_ds(dir, s, "train")?;
    let mut cal = crate::dataset::CalibrationFile::new(
        train_ds.header.robot.clone(),
        laser::beam_params(&final_beam, cmp.final_std),
    );
    cal.set_kind("laser");
    cal.effects = diag.cal_effects();
    cal.metrics
        .insert("plane_rms_mm_before".into(), diag.rms_before_mm.into());
    cal.metrics
        .insert("plane_rms_mm_after".into(), diag.rms_after_mm.into());
    cal.extra
        .insert("flange_poses".into(), flange_note(dir, s).into());
    cal.extra.insert("datasets".into(), s.dataset_hashes());
    let out = dir.join("diagnose");
    std::fs::create_dir_all(&out)?;
    cal.save(out.join("calibration.json"))
        .context("writing diagnose/calibration.json")?;
    // Every artifact records the datasets it came from.
    let mut v = serde_json::to_value(diag.to_file(d.train.len(), d.selection.len()))?;
    if let Some(o) = v.as_object_mut() {
        o.insert("datasets".into(), s.dataset_hashes());
    }
    write_atomic(
        &out.join("diagnosis.json"),
        serde_json::to_string_pretty(&v)?.as_bytes(),
    )?;
    log(&format!(
        "  point-to-plane RMS {:.4} -> {:.4} mm; effects: {}",
        diag.rms_before_mm,
        diag.rms_after_mm,
        if diag.findings.is_empty() {
            "none significant".to_string()
        } else {
            diag.findings
                .iter()
                .map(|f| format!("{} ({:.1} {})", f.kind, f.sensor_value, f.sensor_unit))
                .collect::<Vec<_>>()
                .join(", ")
        }
    ));
    s.effects = diag
        .findings
        .iter()
        .map(|f| super::EffectFound {
            kind: f.kind.to_string(),
            words: format!(
                "the laser's {} ({:.2} {}) cut the calibration planes' RMS to {:.4} mm",
                f.kind.replace('_', " "),
                f.sensor_value,
                f.sensor_unit,
                f.rms_after_mm
            ),
            heldout_rms_mm_before: None,
            heldout_rms_mm_after: None,
            heldout_rms_px_before: None,
            heldout_rms_px_after: None,
            plot: None,
        })
        .collect();
    Ok(())
}

/// Mean and sd over targets of the five-direction spread of `spot`.
pub fn target_spreads(
    targets: &BTreeMap<String, Vec<LaserObs>>,
    spot: &dyn Fn(&LaserObs) -> Point3<f64>,
) -> Option<(f64, f64)> {
    let v: Vec<f64> = targets
        .values()
        .filter(|o| o.len() >= 2)
        .map(|o| laser::validate::spread(&o.iter().map(spot).collect::<Vec<_>>()))
        .collect();
    (!v.is_empty()).then(|| {
        (
            crate::solve::stats::mean(&v),
            crate::solve::stats::std_dev(&v),
        )
    })
}

fn validate_stage(dir: &Path, s: &mut SessionFile, log: Log) -> anyhow::Result<()> {
    let d = data(dir, s)?;
    let val: Vec<LaserObs> = obs_of(dir, s, "validation")?
        .into_iter()
        .filter(|o| o.target.is_some())
        .collect();
    if val.is_empty() {
        bail!("no held-out target pose with a laser reading in the validation run");
    }
    let cmp = comparison(&d, &val)?;
    let out = dir.join("validate");
    std::fs::create_dir_all(&out)?;
    crate::schema::write(&out.join("laser_report.json"), &cmp.to_report_file())?;
    let targets = laser::by_target(&val);
    // Before: the nominal mounting (what the plan aimed with).
    let (spec, _) = session_spec(dir, s)?;
    let nominal = beam_of_frame(&spec.tool);
    let before = target_spreads(&targets, &|o| nominal.spot(&o.flange, o.d));
    // After: the deployed beam with its range effects.
    let dcal = crate::dataset::CalibrationFile::load(dir.join("diagnose").join("calibration.json"))
        .context("reading diagnose/calibration.json")?;
    let beam = laser::beam_from_calibration(&dcal)?;
    let effects = dcal.effects.clone();
    let after = target_spreads(&targets, &|o| {
        beam.spot(
            &o.flange,
            laser::effects::corrected_range(o.d, &effects, None),
        )
    });
    let mut methods: Vec<MethodSpread> = cmp
        .rows
        .iter()
        .filter(|r| r.spread_mean_mm.is_finite())
        .map(|r| MethodSpread {
            method: r.method.clone(),
            points: r.n_used,
            spread_mean_mm: r.spread_mean_mm,
            spread_sd_mm: r.spread_std_mm,
            seed_mm: if r.method.starts_with("closed-form") {
                Some([SEED_SINGLE_PLANE_MM.0, SEED_SINGLE_PLANE_MM.1])
            } else if r.method.starts_with("orthogonal") {
                Some([SEED_ORTHOGONAL_MM.0, SEED_ORTHOGONAL_MM.1])
            } else {
                None
            },
        })
        .collect();
    if let Some((m, sd)) = after {
        methods.push(MethodSpread {
            method: "deployed (direct ML + laser effects)".into(),
            points: d.train.len(),
            spread_mean_mm: m,
            spread_sd_mm: sd,
            seed_mm: None,
        });
    }
    log(&format!(
        "  held-out spread {} → {} mm ({} targets)",
        before.map_or("—".into(), |x| format!("{:.3}", x.0)),
        after.map_or("—".into(), |x| format!("{:.3} ± {:.3}", x.0, x.1)),
        targets.len()
    ));
    let me = &mut s.measured;
    me.heldout_poses = val.len();
    me.laser_spread_mm_before = before.map(|x| x.0);
    me.laser_spread_mm_after = after.map(|x| x.0);
    me.laser_spread_sd_mm_after = after.map(|x| x.1);
    me.laser_plane_rms_mm = Some(
        dcal.metrics
            .get("plane_rms_mm_after")
            .and_then(|v| v.as_f64())
            .unwrap_or(cmp.final_plane_rms_mm),
    );
    // Deploy the diagnosed calibration.
    let ddir = dir.join("deploy");
    std::fs::create_dir_all(&ddir)?;
    let src = dir.join("diagnose").join("calibration.json");
    let bytes = crate::fsio::read(&src).with_context(|| format!("{}", src.display()))?;
    write_atomic(&ddir.join("calibration.json"), &bytes)?;
    s.deploy = vec!["deploy/calibration.json".into()];
    // The beam holds with the arm it was fitted through: deploy the refined arm beside it.
    let refined = dir.join(ARM_REFINED);
    if refined.is_file() {
        let bytes =
            crate::fsio::read(&refined).with_context(|| format!("{}", refined.display()))?;
        write_atomic(&ddir.join("arm-calibration.json"), &bytes)?;
        s.deploy.push("deploy/arm-calibration.json".into());
    }
    let ci = dcal
        .params
        .iter()
        .take(3)
        .map(|p| p.std.map(|x| 1.96 * x))
        .collect::<Option<Vec<f64>>>();
    s.laser = Some(LaserSummary {
        flange_poses: flange_note(dir, s),
        nominal_r_mm: nominal.r.into(),
        nominal_v: nominal.v.into_inner().into(),
        beam_r_mm: beam.r.into(),
        beam_v: beam.v.into_inner().into(),
        beam_r_ci95_mm: ci.map(|c| [c[0], c[1], c[2]]),
        selection_targets: laser::by_target(&d.selection).len(),
        validation_targets: targets.len(),
        plane_rms_mm: cmp.final_plane_rms_mm,
        plane_rms_mm_diagnosed: s.measured.laser_plane_rms_mm,
        effects: dcal.effects.iter().map(|e| e.kind.clone()).collect(),
        methods,
    });
    Ok(())
}

/// What the CLI prints of a laser session: the held-out spread before → after, the beam, every
/// method beside the seed's figure.
pub fn lines(l: &LaserSummary, m: &super::Measured) -> Vec<String> {
    let f = |v: Option<f64>| v.map_or("—".into(), |x| format!("{x:.3}"));
    let mut out = vec![
        format!(
            "laser: held-out five-direction spread {} mm (nominal mounting) → {} ± {} mm \
             (calibrated), {} held-out targets ({} poses), {} selection targets; plane RMS {} mm",
            f(m.laser_spread_mm_before),
            f(m.laser_spread_mm_after),
            f(m.laser_spread_sd_mm_after),
            l.validation_targets,
            m.heldout_poses,
            l.selection_targets,
            f(m.laser_plane_rms_mm)
        ),
        format!(
            "beam: r = [{:.3}, {:.3}, {:.3}] mm, v = [{:.5}, {:.5}, {:.5}]; flange poses: {}",
            l.beam_r_mm[0],
            l.beam_r_mm[1],
            l.beam_r_mm[2],
            l.beam_v[0],
            l.beam_v[1],
            l.beam_v[2],
            l.flange_poses
        ),
    ];
    for x in &l.methods {
        out.push(format!(
            "  {:<38} {:>4} pts  spread {:>7.3} ± {:.3} mm{}",
            x.method,
            x.points,
            x.spread_mean_mm,
            x.spread_sd_mm,
            x.seed_mm.map_or(String::new(), |s| format!(
                "   (seed {:.2} ± {:.2} mm)",
                s[0], s[1]
            ))
        ));
    }
    out
}

/// The laser section of the session report: the beam, every method's held-out spread beside
/// the seed's figure.
pub fn html(l: &LaserSummary, m: &super::Measured) -> String {
    let esc = |t: &str| {
        t.replace('&', "&amp;")
            .replace('<', "&lt;")
            .replace('>', "&gt;")
    };
    let f = |v: Option<f64>| v.map_or("—".into(), |x| format!("{x:.3}"));
    let mut h = format!(
        "<h2>Laser beam (seed 000)</h2><p id=\"laser\">Held-out five-direction spread {} mm with \
         the nominal mounting → {} ± {} mm calibrated, on {} held-out targets ({} poses; {} other \
         targets scored the data selection). Beam r = [{:.3}, {:.3}, {:.3}] mm, v = [{:.5}, \
         {:.5}, {:.5}]. Flange poses: {}.</p>",
        f(m.laser_spread_mm_before),
        f(m.laser_spread_mm_after),
        f(m.laser_spread_sd_mm_after),
        l.validation_targets,
        m.heldout_poses,
        l.selection_targets,
        l.beam_r_mm[0],
        l.beam_r_mm[1],
        l.beam_r_mm[2],
        l.beam_v[0],
        l.beam_v[1],
        l.beam_v[2],
        esc(&l.flange_poses)
    );
    h.push_str("<table id=\"laser-methods\"><tr><th>method</th><th>points</th><th>held-out spread (mm)</th><th>seed 000 (mm)</th></tr>");
    for x in &l.methods {
        h.push_str(&format!(
            "<tr><td>{}</td><td>{}</td><td>{:.3} ± {:.3}</td><td>{}</td></tr>",
            esc(&x.method),
            x.points,
            x.spread_mean_mm,
            x.spread_sd_mm,
            x.seed_mm
                .map_or("—".into(), |s| format!("{:.2} ± {:.2}", s[0], s[1]))
        ));
    }
    h.push_str("</table>\n");
    h
}
