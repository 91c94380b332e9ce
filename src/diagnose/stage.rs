//! The diagnosis of a dataset into a directory: what `robocal diagnose` and a session's
//! diagnose stage run. Fit the geometric model, find the effect the residual points to, add
//! it, and report the held-out error before and after.
//!
//! Writes `DIR/diagnosis.json`, `DIR/calibration.json` (`robocal-calibration/1` with the
//! effects, read by `robocal predict`), `DIR/report.md`, `DIR/heldout_predictions.csv`
//! (`id,x_mm,y_mm,z_mm` of every held-out pose, predicted with the full session context) and
//! one `DIR/effect_<n>_<kind>.svg` partial-residual plot per accepted effect. Camera datasets
//! go to [`super::camera_stage`], laser datasets to [`crate::solve::laser::stage`].
use std::path::PathBuf;

use anyhow::Context;
use serde_json::{json, Map, Value};

use crate::dataset::{CalibrationFile, Loaded, PoseRecord};
use crate::diagnose::effects::EffectModel;
use crate::diagnose::{self, effects, plot, Options};
use crate::model::KinematicModel;
use crate::solve::obs;

/// What to diagnose and how (the options of `robocal diagnose`).
#[derive(Debug, Clone, Default)]
pub struct DiagnoseRequest {
    /// Dataset (`robocal-dataset/1`); `group: validation` records are held out.
    pub data: PathBuf,
    /// Output directory (created).
    pub out: PathBuf,
    /// Start from this calibration's parameters instead of the header's nominal chain.
    pub calibration: Option<PathBuf>,
    /// Held-out poses in a separate dataset of the same session.
    pub heldout: Option<PathBuf>,
    /// Do not add a nonparametric correction even if structured residual remains.
    pub no_nonparametric: bool,
    /// Only the physics-first chain.
    pub physics_first: bool,
    /// Only the kernel-benchmark chain.
    pub kernel_benchmark: bool,
    /// Do not add the transmission error maps after the chain.
    pub no_transmission_map: bool,
    /// Standard deviations of the geometric parameters' prior about nominal (None: the
    /// default, [`crate::diagnose::determined::DEFAULT_GEOMETRIC_TOLERANCE`]).
    pub geometric_prior: Option<crate::diagnose::determined::GeometricTolerance>,
    /// Fit every free geometric parameter without a prior.
    pub no_geometric_prior: bool,
}

/// Run the diagnosis `args` into its directory and return the short console summary. Each
/// file is read once; [`run_loaded`] does the rest.
pub fn run(args: &DiagnoseRequest) -> anyhow::Result<String> {
    let main = crate::dataset::read_dataset(&args.data)?;
    let extra = match &args.heldout {
        Some(p) => Some(crate::dataset::read_dataset(p)?),
        None => None,
    };
    run_loaded(args, &main, extra.as_ref())
}

/// [`run`] on datasets already read: `main` is `args.data`, `extra` is `args.heldout`.
pub fn run_loaded(
    args: &DiagnoseRequest,
    main: &Loaded,
    extra: Option<&Loaded>,
) -> anyhow::Result<String> {
    if main.dataset.header.camera().ok().flatten().is_some() {
        return super::camera_stage::run(&args.data, args.heldout.as_deref(), &args.out);
    }
    super::heap::keep_large_blocks();
    // Bad input is refused at the boundary: strict reader + plausibility.
    let ds = &main.dataset;
    crate::plausible::check_dataset(ds, &args.data)?;
    if let (Some(x), Some(h)) = (extra, &args.heldout) {
        crate::plausible::check_same_robot(
            &ds.header.robot,
            &args.data,
            &x.dataset.header.robot,
            h,
            "held-out file",
        )?;
        crate::plausible::check_dataset(&x.dataset, h)?;
    }
    // Laser (range sensor) datasets have their own effect library (the laser geometry).
    if crate::solve::laser::stage::is_laser_dataset(ds) {
        return crate::solve::laser::stage::diagnose_laser(
            &args.data,
            args.heldout.as_deref(),
            &args.out,
        );
    }
    let mut model = KinematicModel::from_robot_block(&main.dataset.header.robot)
        .with_context(|| format!("{}: robot block", args.data.display()))?;
    if let Some(c) = &args.calibration {
        let cal = crate::plausible::calibration::load_for(c, &ds.header.robot, &args.data)?;
        if cal.kind() != crate::dataset::CalibrationKind::Kinematic {
            anyhow::bail!(
                "{}: field `kind`: {:?} is not a kinematic calibration: diagnose starts only \
                 from a kinematic calibration of this robot",
                c.display(),
                cal.kind()
            );
        }
        model
            .apply_cal_params(&cal.params)
            .with_context(|| format!("{}: params", c.display()))?;
    }
    let dof = model.dof();
    let (train, held, skipped) =
        obs::split_observations(&main.dataset, extra.map(|x| &x.dataset), dof);
    let mut session: Vec<&PoseRecord> = main.dataset.poses().collect();
    if let Some(x) = extra {
        session.extend(x.dataset.poses());
    }
    if let (Some(x), Some(h)) = (extra, &args.heldout) {
        let recs: Vec<&PoseRecord> = x.dataset.poses().collect();
        anyhow::ensure!(
            !obs::session_observations(&recs, &session, dof).0.is_empty(),
            "{}: no usable held-out poses (pose records with `q` and a visible marker `p`): a \
             --heldout file must hold poses to score on",
            h.display()
        );
    }
    if train.len() < 20 {
        anyhow::bail!(
            "{}: only {} usable training poses (need ≥ 20)",
            args.data.display(),
            train.len()
        );
    }
    let base = if args.physics_first {
        Options::physics_first()
    } else if args.kernel_benchmark {
        Options::kernel_benchmark()
    } else {
        Options::default()
    };
    let opt = Options {
        allow_nonparametric: !args.no_nonparametric,
        transmission_map: !args.no_transmission_map,
        geometric_tolerance: (!args.no_geometric_prior).then(|| {
            args.geometric_prior
                .unwrap_or(crate::diagnose::determined::DEFAULT_GEOMETRIC_TOLERANCE)
        }),
        ..base
    };
    let mut d = diagnose::diagnose(&model, &train, &held, &opt)?;
    d.warnings
        .extend(main.warnings.iter().map(ToString::to_string));
    if skipped.iter().any(|s| s.no_reference) {
        d.warnings.push(obs::reference_skip_warning(&skipped));
    }
    let (_, inferred) = obs::contexts_counted(&session, dof);
    if inferred > 0 {
        d.warnings
            .push(obs::q_prev_warning(inferred, "the backlash candidates"));
    }
    for w in &d.warnings {
        eprintln!("warning: {w}");
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("{}", args.out.display()))?;
    let w = |name: &str, text: &str| -> anyhow::Result<()> {
        let p = args.out.join(name);
        crate::fsio::write_atomic_ctx(&p, text.as_bytes())
    };
    crate::schema::write(&args.out.join("diagnosis.json"), &d.to_file())?;
    w("report.md", &d.report_md())?;
    let mut metrics = Map::new();
    let num = |v: Option<f64>| {
        v.filter(|x| x.is_finite())
            .map(|x| json!(x))
            .unwrap_or(Value::Null)
    };
    metrics.insert("train_rms_mm".into(), num(Some(d.train_rms_final)));
    metrics.insert("heldout_rms_mm_before".into(), num(d.heldout_rms_nominal));
    metrics.insert(
        "heldout_rms_mm_geometric".into(),
        num(d.heldout_rms_geometric),
    );
    metrics.insert("heldout_rms_mm_after".into(), num(d.heldout_rms_final));
    let range = effects::JointRange::of(&train);
    let cal = CalibrationFile {
        format: crate::schema::CALIBRATION_FORMAT.into(),
        robot: main.dataset.header.robot.clone(),
        params: d.state.model.to_cal_params(),
        effects: d.cal_effects(),
        effects_joint_range: range.as_ref().map(effects::JointRange::to_cal),
        metrics,
        extra: Map::new(),
    };
    w("calibration.json", &serde_json::to_string_pretty(&cal)?)?;
    use rayon::prelude::*;
    let rows: Vec<crate::schema::points_csv::IdPoint> = held
        .par_iter()
        .map(|o| {
            let p = effects::apply_effects_held(
                &d.state.model,
                &d.state.effects,
                &o.ctx,
                range.as_ref(),
            );
            crate::schema::points_csv::IdPoint {
                id: o.id,
                x_mm: p.x,
                y_mm: p.y,
                z_mm: p.z,
            }
        })
        .collect();
    w(
        "heldout_predictions.csv",
        &crate::schema::points_csv::to_string(&rows),
    )?;
    let idxs: Vec<usize> = (0..d.state.effects.len()).collect();
    let plots = plot::partial_residuals_per_pose(&d.state, &train, &idxs);
    for ((i, e), (pts, xl, yl)) in d.state.effects.iter().enumerate().zip(plots) {
        let name = format!("effect_{}_{}.svg", i + 1, e.block.kind());
        let path = args.out.join(&name);
        if let effects::Block::TransmissionMap(m) = &e.block {
            // A map is read against its joint's angle: the partial residual (blue) and the
            // fitted curve (red) over the training poses' angles.
            let tri: Vec<(f64, f64, f64)> = train
                .iter()
                .zip(&pts)
                .filter_map(|(o, p)| {
                    let (fit, y) = (*p)?;
                    Some((o.ctx.q.get(m.joint - 1)?.to_degrees(), y, fit))
                })
                .collect();
            let xl = format!("q{} (deg)", m.joint);
            plot::write_driver_svg(&path, &e.block.label(), &tri, &xl, &yl)?;
        } else {
            let pts: Vec<(f64, f64)> = pts.into_iter().flatten().collect();
            plot::write_svg(&path, &e.block.label(), &pts, &xl, &yl)?;
        }
    }
    let f = |v: Option<f64>| v.map(|x| format!("{x:.4}")).unwrap_or_else(|| "—".into());
    let mut s = format!(
        "held-out RMS (mm): nominal {} → geometric {} → final {}\n",
        f(d.heldout_rms_nominal),
        f(d.heldout_rms_geometric),
        f(d.heldout_rms_final)
    );
    if let Some(line) = d.near_heldout_line() {
        s.push_str(&format!("  {line}\n"));
    }
    for st in &d.steps {
        s.push_str(&format!(
            "  + {}: train {:.4} → {:.4} mm, held-out {} → {} mm\n",
            st.evidence.label,
            st.train_rms_before,
            st.train_rms_after,
            f(st.heldout_rms_before),
            f(st.heldout_rms_after)
        ));
    }
    if d.steps.is_empty() {
        s.push_str("  no effect added\n");
    }
    if let Some(line) = d.policy_line() {
        s.push_str(&format!("{line}\n"));
    }
    s.push_str(&format!("wrote {}", args.out.display()));
    Ok(s)
}
