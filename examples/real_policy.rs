//! The diagnosis policy on real robots (issue 31 §4): every real series and split, scored on
//! held-out poses, against the targets (held-out ≤ 0.26 mm or ≥ 40 % below that split's
//! geometric fit, train/held-out gap < 15 %), with the wall time of each diagnosis.
//!
//! ```text
//! cargo run --release --example real_policy -- [--policy default|physics-first|kernel-benchmark]
//!     [--max-train N] [--max-gap F] [--max-extrapolation F] [--pf-max N] [--no-time-blocked]
//!     [--geometric-prior MM,DEG|none] [--why] [SERIES ...]
//! ```
//!
//! `--geometric-prior MM,DEG|none`: the prior standard deviations of the geometric parameters
//! about nominal (default 5 mm, 0.5°; `none`: no prior, every free parameter fitted freely).
//! `--pf-max N`: at most `N` physical effects in the physics-first chain (default 6).
//! `--cv-stop K` / `--cv-stop-fold K` / `--no-cv-stop`: the physics-first chain also stops
//! when the next effect lowers the time-blocked CV error of the training poses by no more
//! than `K` standard errors (per pose / per fold; `robocal::diagnose::inner_cv`), or only
//! at its cap. After it, `--cv-stop-all-params` (each fold refits the geometric parameters
//! too, not only the effect coefficients) and `--cv-stop-forward` (each fold predicted from
//! the folds before it only).
//! `--why`: after each split, what the final model leaves: the held-out error's distribution
//! (median, p95, max, share of the squared error on the worst 5 % of poses) and the library
//! candidates scored against the final physical model's training residual (the strongest
//! first, with whether they pass the selection's tests).
//!
//! A `SERIES` is a directory holding `train.jsonl` + `heldout.jsonl` (the layout of
//! `../shared/data/real-ur10-ipa-grid`) or one dataset file whose `group: validation` records
//! are held out (what `robocal import ipa` writes). Without a series the example reads
//! `$ROBOCAL_REAL_DATA` or `../shared/data/real-ur10-ipa-grid` and says SKIPPED when absent.
//! Real data is never copied into the repository.
//!
//! Under every split's row, the geometric fit's own train / held-out gap on that split: what the
//! split itself costs before any effect.
//!
//! Splits printed for every series: `interleaved` (the file's own split), `time-blocked`
//! (the first 75 % of the training poses train, the held-out poses after them score), and,
//! with several series, `cross-series` (the first series' final model carried to every
//! other series with only the setup re-registered, [`robocal::diagnose::transfer`]; two
//! more cross-series rows, not counted, carry its physical effects alone and its geometric
//! fit alone; each is printed again with the joint zero offsets re-fitted as well; two last
//! rows hold its effects, then its transmission maps alone, with every geometric parameter
//! re-fitted on the series: what its effects add to the series' own geometric calibration).
use std::path::{Path, PathBuf};
use std::time::Instant;

use robocal::diagnose::effects::EffectModel;
use robocal::diagnose::fit::{residuals, residuals_held, rms3, State};
use robocal::diagnose::transfer::{refit_geometry, refit_setup, refit_setup_and_joint_offsets};
use robocal::diagnose::{self, Options, OVERFIT_GAP};
use robocal::model::KinematicModel;
use robocal::solve::obs::PoseObs;

/// Held-out target (mm) and the alternative relative target (fraction below geometric).
const TARGET_MM: f64 = 0.26;
const TARGET_GAIN: f64 = 0.40;

fn load(series: &Path) -> anyhow::Result<(KinematicModel, Vec<PoseObs>, Vec<PoseObs>)> {
    robocal::diagnose::pooled::load_series(series)
}

fn rms(st: &State, obs: &[PoseObs]) -> f64 {
    rms3(&residuals(st, obs))
}

/// Held-out RMS as the diagnosis scores it: the unbounded effects held at the edge of the training
/// poses' joint ranges ([`robocal::diagnose::effects::apply_effects_held`]).
fn rms_held(st: &State, obs: &[PoseObs], train: &[PoseObs]) -> f64 {
    let range = robocal::diagnose::effects::JointRange::of(train);
    rms3(&residuals_held(st, obs, range.as_ref()))
}

/// The §4 targets: held-out `fin` ≤ 0.26 mm or ≥ 40 % below the geometric fit's `geo`, and
/// less than 15 % above the reference training RMS `train`.
fn meets(geo: f64, fin: f64, train: f64) -> bool {
    (fin <= TARGET_MM || 1.0 - fin / geo >= TARGET_GAIN) && fin / train - 1.0 < OVERFIT_GAP
}

/// One row of the table: held-out of the geometric fit and of the final model, the gap,
/// and whether the split meets the targets.
fn row(name: &str, split: &str, geo: f64, fin: f64, train: f64, secs: f64, what: &str) -> bool {
    let gain = 1.0 - fin / geo;
    let gap = fin / train - 1.0;
    let ok = meets(geo, fin, train);
    println!(
        "| {name} | {split} | {geo:.4} | {fin:.4} | {:.1} % | {train:.4} | {:.1} % | {} | {secs:.1} | {what} |",
        100.0 * gain,
        100.0 * gap,
        if ok { "yes" } else { "NO" }
    );
    ok
}

fn chain(d: &diagnose::Diagnosis) -> String {
    let v: Vec<String> = d.steps.iter().map(|s| s.evidence.label.clone()).collect();
    if v.is_empty() {
        "none".into()
    } else {
        v.join(", ")
    }
}

/// What the final model of `d` leaves (`--why`): the held-out error's distribution and the
/// library candidates scored against the final physical model's training residual.
fn explain(d: &diagnose::Diagnosis, train: &[PoseObs], held: &[PoseObs], opt: &Options) {
    let range = robocal::diagnose::effects::JointRange::of(train);
    let mut e: Vec<f64> = residuals_held(&d.state, held, range.as_ref())
        .as_slice()
        .chunks(3)
        .map(|c| c.iter().map(|v| v * v).sum::<f64>().sqrt())
        .collect();
    e.sort_by(f64::total_cmp);
    if let Some(&max) = e.last() {
        let total: f64 = e.iter().map(|v| v * v).sum();
        let worst = e.len().div_ceil(20);
        let top: f64 = e[e.len() - worst..].iter().map(|v| v * v).sum();
        println!(
            "    held-out 3-D error: median {:.4}, p95 {:.4}, max {:.4} mm; the worst {worst} poses carry {:.1} % of the squared error; without them RMS {:.4} mm",
            e[e.len() / 2],
            e[(e.len() * 95 / 100).min(e.len() - 1)],
            max,
            100.0 * top / total.max(1e-300),
            ((total - top) / (e.len() - worst).max(1) as f64).sqrt()
        );
    }
    // The three worst held-out poses: the final and geometric models' errors there and the
    // nearest training pose in joint space (does the chain add the error, or the data lack it?).
    let err = |st: &State, o: &PoseObs| rms(st, std::slice::from_ref(o));
    let mut worst: Vec<&PoseObs> = held.iter().collect();
    worst.sort_by(|a, b| err(&d.state, b).total_cmp(&err(&d.state, a)));
    for o in worst.iter().take(3) {
        let near = train
            .iter()
            .map(|t| {
                t.ctx
                    .q
                    .iter()
                    .zip(&o.ctx.q)
                    .map(|(a, b)| (a - b).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .fold(f64::INFINITY, f64::min);
        let q: Vec<String> = o
            .ctx
            .q
            .iter()
            .map(|v| format!("{:.1}", v.to_degrees()))
            .collect();
        println!(
            "    held-out pose {}: final {:.3} mm, geometric {:.3} mm, q [{}]°, nearest training pose {:.1}° away",
            o.ctx.id,
            err(&d.state, o),
            err(&d.geometric, o),
            q.join(", "),
            near.to_degrees()
        );
    }
    if let Some(p) = d.policy_line() {
        println!("    {p}");
    }
    if let Some((b, a)) = d.nonparametric {
        println!("    correction: CV RMS {b:.4} -> {a:.4} mm");
    } else {
        println!("    no correction (none of the kernel grid passed the gap and gain rules; ROBOCAL_LOG=robocal::diagnose=debug lists the grid)");
    }
    // The physical part of the final model and what the library still finds in its residual.
    let mut phys = d.state.clone();
    phys.effects
        .retain(|e| !matches!(e.block, diagnose::effects::Block::Nonparametric(_)));
    let (mut cands, _) = diagnose::candidates_with(&phys.model, train, opt);
    for g in cands.iter_mut() {
        g.retain(|b| !phys.effects.iter().any(|e| e.block.label() == b.label()));
    }
    cands.retain(|g| !g.is_empty());
    let m_tests: usize = cands.iter().map(Vec::len).sum::<usize>().max(1);
    let scores = diagnose::score_round(&phys, train, &cands, opt);
    for s in scores.iter().take(8) {
        let signif = s.p_value < opt.alpha / m_tests as f64 && s.delta_bic > opt.min_delta_bic;
        println!(
            "    left in the residual: {} ΔBIC {:.1}, CV gain {:+.2} %, independence {:.2}{}",
            s.label,
            s.delta_bic,
            100.0 * s.cv_gain,
            s.independence,
            if signif && s.cv_gain > opt.min_cv_gain && s.independence >= opt.min_independence {
                " (passes the tests)"
            } else {
                ""
            }
        );
    }
}

fn main() -> anyhow::Result<()> {
    if let Ok(f) = tracing_subscriber::EnvFilter::try_from_env("ROBOCAL_LOG") {
        let _ = tracing_subscriber::fmt()
            .with_env_filter(f)
            .with_writer(std::io::stderr)
            .try_init();
    }
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut opt = Options::default();
    let mut policy = "default".to_string();
    let mut max_train = usize::MAX;
    let mut time_blocked = true;
    let mut max_gap = None;
    let mut max_extrapolation = None;
    let mut pf_max = None;
    let mut why = false;
    let mut cv_stop = None;
    let mut series: Vec<PathBuf> = Vec::new();
    let mut i = 0;
    while i < args.len() {
        match args[i].as_str() {
            "--policy" => {
                policy = args
                    .get(i + 1)
                    .cloned()
                    .ok_or_else(|| anyhow::anyhow!("--policy needs a name"))?;
                opt = match policy.as_str() {
                    "default" => Options::default(),
                    "physics-first" => Options::physics_first(),
                    "kernel-benchmark" => Options::kernel_benchmark(),
                    p => anyhow::bail!(
                        "unknown policy {p:?} (default, physics-first, kernel-benchmark)"
                    ),
                };
                i += 1;
            }
            "--max-train" => {
                max_train = args
                    .get(i + 1)
                    .and_then(|v| v.parse().ok())
                    .ok_or_else(|| anyhow::anyhow!("--max-train needs a number"))?;
                i += 1;
            }
            "--max-gap" => {
                max_gap = Some(
                    args.get(i + 1)
                        .and_then(|v| v.parse::<f64>().ok())
                        .ok_or_else(|| anyhow::anyhow!("--max-gap needs a number"))?,
                );
                i += 1;
            }
            "--max-extrapolation" => {
                max_extrapolation = Some(
                    args.get(i + 1)
                        .and_then(|v| v.parse::<f64>().ok())
                        .ok_or_else(|| anyhow::anyhow!("--max-extrapolation needs a number"))?,
                );
                i += 1;
            }
            "--pf-max" => {
                pf_max = Some(
                    args.get(i + 1)
                        .and_then(|v| v.parse::<usize>().ok())
                        .ok_or_else(|| anyhow::anyhow!("--pf-max needs a number"))?,
                );
                i += 1;
            }
            "--cv-stop" | "--cv-stop-fold" => {
                let k_se = args
                    .get(i + 1)
                    .and_then(|v| v.parse::<f64>().ok())
                    .ok_or_else(|| anyhow::anyhow!("{} needs a number", args[i]))?;
                cv_stop = Some(Some(diagnose::inner_cv::CvStop {
                    k_se,
                    by_fold: args[i] == "--cv-stop-fold",
                    effects_only: true,
                    forward: false,
                }));
                i += 1;
            }
            "--no-cv-stop" => cv_stop = Some(None),
            "--cv-stop-all-params" | "--cv-stop-forward" => {
                let Some(Some(c)) = cv_stop.as_mut() else {
                    anyhow::bail!("{} after --cv-stop K or --cv-stop-fold K", args[i]);
                };
                if args[i] == "--cv-stop-forward" {
                    c.forward = true;
                } else {
                    c.effects_only = false;
                }
            }
            "--why" => why = true,
            "--no-time-blocked" => time_blocked = false,
            "--geometric-prior" => {
                i += 1;
                let v = args.get(i).map(String::as_str).unwrap_or("");
                opt.geometric_tolerance = if v == "none" {
                    None
                } else {
                    let (mm, deg) = v
                        .split_once(',')
                        .and_then(|(a, b)| Some((a.parse().ok()?, b.parse().ok()?)))
                        .ok_or_else(|| anyhow::anyhow!("--geometric-prior needs MM,DEG or none"))?;
                    Some(robocal::diagnose::determined::GeometricTolerance { mm, deg })
                };
            }
            a if a.starts_with("--") => {
                anyhow::bail!("unknown argument {a:?} (see the file's header)")
            }
            a => series.push(PathBuf::from(a)),
        }
        i += 1;
    }
    if let Some(g) = max_gap {
        opt.correction_max_gap = g;
    }
    if let Some(x) = max_extrapolation {
        opt.max_extrapolation = x;
    }
    if let Some(n) = pf_max {
        opt.physics_first_max_effects = n;
        if policy == "physics-first" {
            opt.max_effects = n;
        }
    }
    if let Some(c) = cv_stop {
        opt.physics_first_stop = c;
    }
    if series.is_empty() {
        let p = std::env::var_os("ROBOCAL_REAL_DATA")
            .map(PathBuf::from)
            .unwrap_or_else(|| {
                Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/real-ur10-ipa-grid")
            });
        if !p.join("train.jsonl").is_file() {
            println!(
                "SKIPPED: real data absent ({}): nothing measured",
                p.display()
            );
            return Ok(());
        }
        series.push(p);
    }
    println!("policy: {policy}; RMS = held-out 3-D marker error (mm); targets: held-out ≤ {TARGET_MM} mm or ≥ {:.0} % below geometric, gap < {:.0} %", 100.0 * TARGET_GAIN, 100.0 * OVERFIT_GAP);
    println!("| series | split | geometric | final | below geometric | train | gap | target met | s | chain |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let (mut n_ok, mut n) = (0, 0);
    // The same targets with the gap taken against the training poses nearest the held-out
    // ones ([`robocal::diagnose::region`]) instead of all training poses.
    let mut n_ok_near = 0;
    // The first series' final model, its physical part alone and its geometric fit.
    let mut first: Option<[(State, &str); 3]> = None;
    for s in &series {
        let name = s
            .file_stem()
            .map(|x| x.to_string_lossy().into_owned())
            .unwrap_or_default();
        let (model, mut train, mut held) = load(s)?;
        if train.len() > max_train {
            train.truncate(max_train);
            let t_end = train.last().map(|o| o.ctx.t).unwrap_or(0.0);
            held.retain(|o| o.ctx.t <= t_end);
        }
        let mut splits = vec![("interleaved", train.clone(), held.clone())];
        if time_blocked {
            let mut ts: Vec<f64> = train.iter().map(|o| o.ctx.t).collect();
            ts.sort_by(f64::total_cmp);
            let t_split = ts[ts.len() * 3 / 4];
            let early = train
                .iter()
                .filter(|o| o.ctx.t < t_split)
                .cloned()
                .collect();
            let late = held
                .iter()
                .filter(|o| o.ctx.t >= t_split)
                .cloned()
                .collect();
            splits.push(("time-blocked", early, late));
        }
        for (split, tr, he) in splits {
            let t0 = Instant::now();
            let d = diagnose::diagnose(&model, &tr, &he, &opt)?;
            let secs = t0.elapsed().as_secs_f64();
            let geo = rms(&d.geometric, &he);
            let fin = rms_held(&d.state, &he, &tr);
            if let Some(o) = &d.outside {
                println!("    {}", o.warning());
            }
            let label = format!("{split} {}/{}", tr.len(), he.len());
            n += 1;
            let ok = row(
                &name,
                &label,
                geo,
                fin,
                rms(&d.state, &tr),
                secs,
                &chain(&d),
            );
            n_ok += ok as usize;
            n_ok_near += d.near_heldout.map_or(ok, |nh| meets(geo, fin, nh.final_mm)) as usize;
            let geo_train = rms(&d.geometric, &tr);
            println!(
                "    the geometric fit on the same split: train {geo_train:.4}, held-out {geo:.4} mm, gap {:.1} % (what the split itself costs, before any effect)",
                100.0 * (geo / geo_train - 1.0)
            );
            if let Some(line) = d.near_heldout_line() {
                println!("    {line}");
            }
            for w in d
                .warnings
                .iter()
                .filter(|w| w.starts_with("where the held-out"))
            {
                println!("    {w}");
            }
            if let Some(s) = d
                .policy_choice
                .as_ref()
                .and_then(|c| c.physics_first_stopped.as_ref())
            {
                println!("    physics first {s}");
            }
            if why {
                explain(&d, &tr, &he, &opt);
            }
            if split == "interleaved" {
                match &first {
                    None => {
                        let mut phys = d.state.clone();
                        phys.effects.retain(|e| {
                            !matches!(e.block, diagnose::effects::Block::Nonparametric(_))
                        });
                        first = Some([
                            (d.state.clone(), "first series' model, setup re-registered"),
                            (phys, "its physical effects only (no correction)"),
                            (d.geometric.clone(), "its geometric fit only"),
                        ]);
                    }
                    Some(models) => {
                        // Cross-series: the first series' model, setup re-registered here
                        // (the target counts the whole model; the other two rows say which
                        // part carries over).
                        for (k, (st, what)) in models.iter().enumerate() {
                            let carried = refit_setup(st, &train)?;
                            let t = rms(&carried, &train);
                            let h = rms(&carried, &held);
                            let ok = row(&name, "cross-series", geo, h, t, 0.0, what);
                            if k == 0 {
                                n += 1;
                                n_ok += ok as usize;
                                n_ok_near += ok as usize;
                            }
                            let carried = refit_setup_and_joint_offsets(st, &train)?;
                            let (t, h) = (rms(&carried, &train), rms(&carried, &held));
                            let what = format!("{what}; joint zero offsets re-fitted too");
                            row(&name, "cross-series", geo, h, t, 0.0, &what);
                        }
                        // What the effects carry on top of this series' own geometry: the
                        // first series' effects held, every geometric parameter re-fitted here
                        // (all of them; then the transmission maps alone, the ripples out).
                        let mut maps = models[0].0.clone();
                        maps.effects.retain(|e| {
                            matches!(e.block, diagnose::effects::Block::TransmissionMap(_))
                        });
                        for (st, what) in [
                            (
                                &models[0].0,
                                "its effects held, this series' geometry re-fitted",
                            ),
                            (
                                &maps,
                                "its transmission maps held, this series' geometry re-fitted",
                            ),
                        ] {
                            let carried = refit_geometry(st, &train)?;
                            let (t, h) = (rms(&carried, &train), rms(&carried, &held));
                            row(&name, "cross-series", geo, h, t, 0.0, what);
                        }
                    }
                }
            }
        }
    }
    println!("\n{n_ok} / {n} splits meet the targets");
    println!(
        "{n_ok_near} / {n} with the gap taken against the training poses nearest the held-out ones (the line \"Where the held-out poses are\" under each row)"
    );
    Ok(())
}
