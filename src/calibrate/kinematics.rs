//! The kinematic calibration of `robocal calibrate kinematics` as a library call: full
//! identification (MDH + Hayati arm, tracker → base, flange → marker) with automatic
//! identifiability, held-out scores before / after, seed 001's metrics and an optional subset
//! bootstrap. Writes `calibration.json` (and `bootstrap.csv` with a bootstrap) and returns what
//! it found; the CLI prints it.
use std::io::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;
use serde_json::json;

use crate::dataset::CalibrationFile;
use crate::model::Unit;
use crate::solve::bootstrap::{bootstrap, BootstrapOptions, BootstrapResult, SubsetSize};
use crate::solve::calfile;
use crate::solve::kinematics::{identify, IdentOptions, IdentResult};
use crate::solve::metrics::{self, Scores};

/// What to calibrate and how.
#[derive(Debug, Clone)]
pub struct KinematicsOptions {
    /// Dataset (`robocal-dataset/1`); pose records not in group `validation` are fitted.
    pub data: PathBuf,
    /// Output directory (created if missing).
    pub out: PathBuf,
    /// Held-out poses (default: the `validation` records of `data`, else 5-fold CV).
    pub heldout: Option<PathBuf>,
    /// Number of random-subset refits.
    pub bootstrap: Option<usize>,
    /// Subset size: a count (200) or a fraction (0.75 or 75%).
    pub subset: String,
    /// Random seed of the bootstrap.
    pub seed: u64,
    /// Huber threshold (mm) on the per-pose error.
    pub huber_mm: Option<f64>,
    /// Also fit the marker orientation.
    pub orientation: bool,
    /// Parameters fixed in addition to the automatic choice.
    pub fix: Vec<String>,
}

/// Seed 001's metrics of the nominal and the identified model on the held-out poses.
#[derive(Debug, Clone)]
pub struct HeldoutMetrics {
    /// Nominal model (base and tool fitted).
    pub before: Scores,
    /// Identified model.
    pub after: Scores,
}

/// The subset bootstrap and what it wrote.
#[derive(Debug, Clone)]
pub struct BootstrapReport {
    /// The distributions.
    pub result: BootstrapResult,
    /// Held-out RMS (mm) of the model with the subset means (the full-data fit is kept).
    pub heldout_rms_mm_mean_model: Option<f64>,
    /// `bootstrap.csv`.
    pub csv: PathBuf,
}

/// What the calibration found and wrote.
#[derive(Debug, Clone)]
pub struct KinematicsCalibration {
    /// The identification.
    pub ident: IdentResult,
    /// Seed 001's metrics, when there are held-out poses.
    pub metrics: Option<HeldoutMetrics>,
    /// The bootstrap, when asked for.
    pub bootstrap: Option<BootstrapReport>,
    /// `calibration.json`.
    pub calibration: PathBuf,
}

/// A value in internal units as the files and the summary show it (mm or degrees).
pub fn show(v: f64, unit: Unit) -> (f64, &'static str) {
    match unit {
        Unit::Mm => (v, "mm"),
        Unit::Rad => (v.to_degrees(), "deg"),
    }
}

/// Runs the calibration (see the module docs).
pub fn calibrate(o: &KinematicsOptions) -> anyhow::Result<KinematicsCalibration> {
    crate::plausible::limits::bootstrap(o.bootstrap.unwrap_or(0))?;
    // Strict reader + plausibility; a held-out file must be for the same robot (a held-out
    // error of another robot's model would judge nothing).
    let (ds, held) = crate::plausible::load_with_heldout(&o.data, o.heldout.as_deref())?;
    if let Some(c) = o.huber_mm {
        anyhow::ensure!(
            c.is_finite() && c > 0.0,
            "--huber must be a positive number of mm"
        );
    }
    let opts = IdentOptions {
        heldout: held,
        huber_mm: o.huber_mm,
        orientation: o.orientation,
        fix: o.fix.clone(),
        ..Default::default()
    };
    let res = identify(&ds, &opts).context("kinematic identification")?;
    std::fs::create_dir_all(&o.out).with_context(|| format!("creating {}", o.out.display()))?;
    let mut file = calfile::ident_file(&ds.header.robot, &res);
    let metrics = heldout_metrics(&res);
    if let Some(m) = &metrics {
        let (b, a) = (&m.before, &m.after);
        let mut put = |k: &str, v: f64| {
            file.metrics.insert(k.into(), json!(v));
        };
        if let (Some(b), Some(a)) = (&b.relative, &a.relative) {
            put("relative_distance_pct_before", b.mean_pct);
            put("relative_distance_pct_after", a.mean_pct);
        }
        if let (Some(b), Some(a)) = (&b.coincidence, &a.coincidence) {
            put("coincidence_mm_before", b.mean_mm);
            put("coincidence_mm_after", a.mean_mm);
        }
        if let (Some(b), Some(a)) = (&b.iso, &a.iso) {
            put("iso9283_ap_mm_before", b.ap_mean_mm);
            put("iso9283_ap_mm_after", a.ap_mean_mm);
            put("iso9283_rp_mm", a.rp_mean_mm);
        }
    }
    let bootstrap = match o.bootstrap {
        Some(k) => Some(run_bootstrap(o, k, &res, &opts, &mut file)?),
        None => None,
    };
    let calibration = o.out.join("calibration.json");
    file.save(&calibration)
        .with_context(|| format!("writing {}", calibration.display()))?;
    Ok(KinematicsCalibration {
        ident: res,
        metrics,
        bootstrap,
        calibration,
    })
}

/// Seed 001's metrics on the held-out poses (none without held-out poses).
fn heldout_metrics(res: &IdentResult) -> Option<HeldoutMetrics> {
    if res.heldout_obs.is_empty() {
        return None;
    }
    let points = |m: &crate::model::KinematicModel| -> Vec<_> {
        res.heldout_obs
            .iter()
            .map(|o| m.measured_point(&o.q))
            .collect()
    };
    Some(HeldoutMetrics {
        before: metrics::score(&res.heldout_obs, &points(&res.nominal)),
        after: metrics::score(&res.heldout_obs, &points(&res.model)),
    })
}

/// The subset bootstrap: `bootstrap.csv` (written atomically) and the per-parameter
/// distributions added to `file`.
fn run_bootstrap(
    o: &KinematicsOptions,
    k: usize,
    res: &IdentResult,
    opts: &IdentOptions,
    file: &mut CalibrationFile,
) -> anyhow::Result<BootstrapReport> {
    let bo = BootstrapOptions {
        k,
        subset: SubsetSize::parse(&o.subset)?,
        seed: o.seed,
        ..Default::default()
    };
    let b = bootstrap(res, &opts.effects, &bo).context("bootstrap")?;
    let heldout_mean = (!res.heldout_obs.is_empty()).then(|| {
        let e = crate::solve::kinematics::model_errors(&b.mean_model, &res.heldout_obs);
        crate::solve::stats::rms(&e)
    });
    let path = o.out.join("bootstrap.csv");
    // Built in memory, then written atomically (a kill never leaves half a file).
    let mut w: Vec<u8> = Vec::new();
    writeln!(
        w,
        "name,unit,full,mean,std,q025,q975,skewness,excess_kurtosis,normal_p"
    )?;
    let units: std::collections::HashMap<&str, Unit> = res
        .params
        .iter()
        .map(|p| (p.name.as_str(), p.unit))
        .collect();
    for (i, name) in b.names.iter().enumerate() {
        let s = &b.summaries[i];
        let u = units.get(name.as_str()).copied().unwrap_or(Unit::Mm);
        let c = |v: f64| show(v, u).0;
        writeln!(
            w,
            "{name},{},{},{},{},{},{},{:.4},{:.4},{:.4}",
            show(0.0, u).1,
            c(b.full[i]),
            c(s.mean),
            c(s.std),
            c(s.q025),
            c(s.q975),
            s.skewness,
            s.excess_kurtosis,
            s.normal_p
        )?;
        if let Some(p) = file.params.iter_mut().find(|p| &p.name == name) {
            p.extra.insert(
                "bootstrap".into(),
                json!({"mean": c(s.mean), "std": c(s.std), "ci95": [c(s.q025), c(s.q975)], "normal_p": s.normal_p}),
            );
        }
    }
    crate::fsio::write_atomic_ctx(&path, &w)?;
    file.extra.insert(
        "bootstrap".into(),
        json!({"k": b.n_requested, "converged": b.samples.len(), "subset": b.subset_size,
               "seed": o.seed, "seconds": b.elapsed_s,
               "max_mean_shift_sigma": b.max_mean_shift_sigma,
               "non_normal": b.non_normal, "heldout_rms_mm_mean_model": heldout_mean,
               "covariance": crate::navchain::BootstrapCovariance::from_samples(&b.names, &b.samples),
               "final": "full-data fit (the subset mean is reported per parameter)"}),
    );
    Ok(BootstrapReport {
        result: b,
        heldout_rms_mm_mean_model: heldout_mean,
        csv: path,
    })
}
