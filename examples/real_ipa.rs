//! Real robot data (issue 18): the public IPA robot-accuracy dataset — a UR10 measured by a
//! Leica laser tracker with a T-Mac probe (Landgraf et al., CASE 2021; MIT licence). Real
//! data is not in this repository: the example reads `$ROBOCAL_REAL_DATA` or
//! `../shared/data/real-ur10-ipa-grid` (`train.jsonl`, `heldout.jsonl` = Series A in the
//! dataset format) and says so plainly when it is absent.
//!
//! ```text
//! cargo run --release --example real_ipa -- [--max-train N] [--series B.jsonl ...]
//!     [--plots DIR] [--no-ablation]
//! ```
//!
//! `--plots DIR` (default `out/real_ipa`) receives one SVG per library effect: the residual
//! of the training poses against the effect's driver (joint angle, harmonic phase, gravity
//! torque, bending moment, temperature, ...), with the effect fitted alone on top of the
//! geometric model (blue: partial residual, red: the fitted effect), and one per effect of
//! the diagnoses (`A_default_*`, `A_physics_first_*`).
//!
//! Prints, for Series A:
//! 1. the diagnosis on the given split (every 4th pose held out): one row per stage
//!    (nominal, geometric, each effect added) with train RMS, held-out RMS, 95th percentile
//!    and max, and the train/held-out gap (overfitting flag above 15 %);
//! 2. the same on a time-blocked split (train on the first 75 % of the session, score on
//!    held-out poses of the last 25 %): extrapolation in time, the honest figure;
//! 3. for every `--series` file (another series converted with `robocal import ipa`): each
//!    stage's model carried over with only the setup (tracker ← base, marker offset)
//!    re-registered on that series' training poses, scored on its held-out poses.
//!
//! and the wall time of each diagnosis.
use std::path::{Path, PathBuf};
use std::time::Instant;

use robocal::diagnose::effects::{Block, Effect, EffectModel};
use robocal::diagnose::fit::{fit, residuals, State};
use robocal::diagnose::transfer::refit_setup;
use robocal::diagnose::{self, plot, Options};
use robocal::model::KinematicModel;
use robocal::solve::obs::PoseObs;

fn data_dir() -> Option<PathBuf> {
    let p = std::env::var_os("ROBOCAL_REAL_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/real-ur10-ipa-grid")
        });
    (p.join("train.jsonl").is_file() && p.join("heldout.jsonl").is_file()).then_some(p)
}

/// RMS, 95th percentile and max of the 3-D error (mm).
fn stats(state: &State, obs: &[PoseObs]) -> (f64, f64, f64) {
    let r = residuals(state, obs);
    let mut e: Vec<f64> = (0..obs.len())
        .map(|k| (r[3 * k].powi(2) + r[3 * k + 1].powi(2) + r[3 * k + 2].powi(2)).sqrt())
        .collect();
    if e.is_empty() {
        return (f64::NAN, f64::NAN, f64::NAN);
    }
    let rms = (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
    e.sort_by(f64::total_cmp);
    let p95 = e[((e.len() as f64 * 0.95).ceil() as usize).clamp(1, e.len()) - 1];
    (rms, p95, *e.last().unwrap())
}

/// The stages of a diagnosis: (label, state).
fn stages(d: &diagnose::Diagnosis) -> Vec<(String, State)> {
    let mut v = vec![
        ("nominal".to_string(), d.nominal.clone()),
        ("geometric".to_string(), d.geometric.clone()),
    ];
    for s in &d.steps {
        v.push((
            format!("+ {}", s.effect.block.label()),
            s.state_after.clone(),
        ));
    }
    v
}

fn table(d: &diagnose::Diagnosis, train: &[PoseObs], held: &[PoseObs]) {
    println!(
        "  {:<34} {:>9} {:>9} {:>9} {:>9} {:>7}",
        "stage", "train", "held-out", "held p95", "held max", "gap"
    );
    for (label, st) in stages(d) {
        let (tr, _, _) = stats(&st, train);
        let (h, p95, mx) = stats(&st, held);
        let gap = 100.0 * (h / tr - 1.0);
        let flag = if gap > 100.0 * diagnose::OVERFIT_GAP {
            "  OVERFIT"
        } else {
            ""
        };
        println!("  {label:<34} {tr:>9.4} {h:>9.4} {p95:>9.4} {mx:>9.4} {gap:>6.1}%{flag}");
    }
    for w in &d.warnings {
        println!("  warning: {w}");
    }
}

/// Every candidate of the effect library added alone to the geometric model (refitted
/// jointly with the geometry): what each physical effect buys on held-out poses.
fn ablation(d: &diagnose::Diagnosis, train: &[PoseObs], held: &[PoseObs], plots: &Path) {
    let (groups, untestable) = diagnose::candidates(&d.geometric.model, train);
    // Of a group of many variants (joint coupling: every driver joint; ripple: every harmonic),
    // the one the first round scored best.
    let round0: Vec<String> = d
        .rounds
        .first()
        .map(|r| r.iter().map(|s| s.label.clone()).collect())
        .unwrap_or_default();
    let (g_tr, _, _) = stats(&d.geometric, train);
    let (g_h, g_p95, g_mx) = stats(&d.geometric, held);
    println!(
        "\n  each effect alone on top of the geometric model (geometric: train {g_tr:.4}, held-out {g_h:.4} / p95 {g_p95:.4} / max {g_mx:.4} mm)"
    );
    println!(
        "  {:<34} {:>9} {:>9} {:>9} {:>9} {:>8}",
        "effect", "train", "held-out", "held p95", "held max", "Δheld"
    );
    let mut rows = Vec::new();
    for g in groups {
        // One representative per group: the linear drift of a warm-up grid, the middle of
        // a change-point grid; the best-scored harmonic of a ripple group.
        let picks: Vec<Block> = match g.first() {
            Some(Block::BaseShift(_)) => vec![g[g.len() / 2].clone()],
            Some(Block::JointDrift(_)) | Some(Block::LengthDrift(_)) => {
                vec![g[0].clone()]
            }
            Some(Block::Coupling(_)) | Some(Block::Ripple(_)) => g
                .iter()
                .find(|b| round0.contains(&b.label()))
                .or(g.first())
                .cloned()
                .into_iter()
                .collect(),
            _ => g,
        };
        for b in picks {
            let mut st = d.geometric.clone();
            st.effects.push(Effect::zero(b.clone()));
            fit(&mut st, train, 30);
            let (tr, _, _) = stats(&st, train);
            let (h, p95, mx) = stats(&st, held);
            let k = st.effects.len() - 1;
            let (pts, xl, yl) = plot::driver_residual(&st, train, k);
            let file = plots.join(format!("A_alone_{}.svg", file_name(&b.label())));
            match plot::write_driver_svg(&file, &b.label(), &pts, &xl, &yl) {
                Ok(()) => println!("  plot: {}", file.display()),
                Err(e) => println!("  plot {} failed: {e}", file.display()),
            }
            rows.push((b.label(), tr, h, p95, mx));
        }
    }
    rows.sort_by(|a, b| a.2.total_cmp(&b.2));
    for (label, tr, h, p95, mx) in rows {
        println!(
            "  {label:<34} {tr:>9.4} {h:>9.4} {p95:>9.4} {mx:>9.4} {:>7.1}%",
            100.0 * (h / g_h - 1.0)
        );
    }
    for (what, why) in untestable {
        println!("  not testable: {what}: {why}");
    }
}

/// A label as a file name.
fn file_name(label: &str) -> String {
    label
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect::<String>()
        .split('_')
        .filter(|s| !s.is_empty())
        .collect::<Vec<_>>()
        .join("_")
}

/// The residual-vs-driver plot of every effect of a diagnosis (training poses).
fn diagnosis_plots(d: &diagnose::Diagnosis, train: &[PoseObs], plots: &Path, prefix: &str) {
    for (i, e) in d.state.effects.iter().enumerate() {
        if matches!(e.block, Block::Nonparametric(_)) {
            continue;
        }
        let (pts, xl, yl) = plot::driver_residual(&d.state, train, i);
        let file = plots.join(format!(
            "{prefix}_{}_{}.svg",
            i + 1,
            file_name(&e.block.label())
        ));
        match plot::write_driver_svg(&file, &e.block.label(), &pts, &xl, &yl) {
            Ok(()) => println!("  plot: {}", file.display()),
            Err(err) => println!("  plot {} failed: {err}", file.display()),
        }
    }
}

struct Split {
    train: Vec<PoseObs>,
    held: Vec<PoseObs>,
}

fn load(train: &Path, held: Option<&Path>) -> anyhow::Result<(KinematicModel, Split)> {
    let main = robocal::dataset::read_dataset(train)?.dataset;
    let extra = held
        .map(|h| robocal::dataset::read_dataset(h).map(|l| l.dataset))
        .transpose()?;
    let model = KinematicModel::from_robot_block(&main.header.robot)?;
    let (train, held, _) =
        robocal::solve::obs::split_observations(&main, extra.as_ref(), model.dof());
    Ok((model, Split { train, held }))
}

fn run(
    name: &str,
    model: &KinematicModel,
    train: &[PoseObs],
    held: &[PoseObs],
) -> anyhow::Result<diagnose::Diagnosis> {
    run_with(name, model, train, held, &Options::default())
}

fn run_with(
    name: &str,
    model: &KinematicModel,
    train: &[PoseObs],
    held: &[PoseObs],
    opt: &Options,
) -> anyhow::Result<diagnose::Diagnosis> {
    let t0 = Instant::now();
    let d = diagnose::diagnose(model, train, held, opt)?;
    println!(
        "\n## {name}: {} train / {} held-out poses, diagnosis {:.1} s",
        train.len(),
        held.len(),
        t0.elapsed().as_secs_f64()
    );
    table(&d, train, held);
    Ok(d)
}

/// Physics first: the same selection (F test, ΔBIC, time-blocked CV gain, independence,
/// all on training data) without the rule that a physical effect must explain half of what
/// the kernel benchmark explains; up to 6 effects, then the correction.
fn physics_first() -> Options {
    Options::physics_first()
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut max_train = usize::MAX;
    let mut series = Vec::new();
    let mut plots = PathBuf::from("out/real_ipa");
    let mut do_ablation = true;
    let mut i = 0;
    while i < args.len() {
        match args[i].as_str() {
            "--max-train" => {
                max_train = args
                    .get(i + 1)
                    .and_then(|v| v.parse().ok())
                    .ok_or_else(|| anyhow::anyhow!("--max-train needs a number"))?;
                i += 1;
            }
            "--series" => {
                series.push(PathBuf::from(
                    args.get(i + 1)
                        .ok_or_else(|| anyhow::anyhow!("--series needs a path"))?,
                ));
                i += 1;
            }
            "--plots" => {
                plots = PathBuf::from(
                    args.get(i + 1)
                        .ok_or_else(|| anyhow::anyhow!("--plots needs a directory"))?,
                );
                i += 1;
            }
            "--no-ablation" => do_ablation = false,
            a => anyhow::bail!("unknown argument {a:?} (see the file's header)"),
        }
        i += 1;
    }
    let Some(dir) = data_dir() else {
        println!(
            "real data absent: set ROBOCAL_REAL_DATA to a directory holding train.jsonl and \
             heldout.jsonl (e.g. ../shared/data/real-ur10-ipa-grid); nothing measured"
        );
        return Ok(());
    };
    println!(
        "# Real UR10 (IPA Series A, Leica T-Mac) from {}",
        dir.display()
    );
    let (model, mut a) = load(&dir.join("train.jsonl"), Some(&dir.join("heldout.jsonl")))?;
    if a.train.len() > max_train {
        // Keep the first `max_train` poses of the session (a contiguous block in time).
        a.train.truncate(max_train);
        let t_end = a.train.last().map(|o| o.ctx.t).unwrap_or(0.0);
        a.held.retain(|o| o.ctx.t <= t_end);
    }
    let d = run(
        "Series A, every 4th pose held out",
        &model,
        &a.train,
        &a.held,
    )?;
    std::fs::create_dir_all(&plots)?;
    diagnosis_plots(&d, &a.train, &plots, "A_default");
    if do_ablation {
        ablation(&d, &a.train, &a.held, &plots);
    }
    let dp = run_with(
        "Series A, physics first (kernel-benchmark rule off, up to 6 effects)",
        &model,
        &a.train,
        &a.held,
        &physics_first(),
    )?;
    diagnosis_plots(&dp, &a.train, &plots, "A_physics_first");

    // Time-blocked: the first 75 % of the session trains, held-out poses of the rest score.
    let mut ts: Vec<f64> = a.train.iter().map(|o| o.ctx.t).collect();
    ts.sort_by(f64::total_cmp);
    let t_split = ts[ts.len() * 3 / 4];
    let early: Vec<PoseObs> = a
        .train
        .iter()
        .filter(|o| o.ctx.t < t_split)
        .cloned()
        .collect();
    let late: Vec<PoseObs> = a
        .held
        .iter()
        .filter(|o| o.ctx.t >= t_split)
        .cloned()
        .collect();
    run(
        "Series A, time-blocked (train first 75 %, score held-out of the last 25 %)",
        &model,
        &early,
        &late,
    )?;
    run_with(
        "Series A, time-blocked, physics first",
        &model,
        &early,
        &late,
        &physics_first(),
    )?;

    for p in &series {
        let (_, s) = load(p, None)?;
        println!(
            "\n## carried over to {} ({} train poses re-register the setup, {} held-out score)",
            p.display(),
            s.train.len(),
            s.held.len()
        );
        println!(
            "  {:<34} {:>9} {:>9} {:>9} {:>9}",
            "stage (fitted on Series A)", "setup", "held-out", "held p95", "held max"
        );
        let physics_first = stages(&dp)
            .into_iter()
            .skip(2)
            .map(|(l, st)| (format!("{l} [physics first]"), st));
        for (label, st) in stages(&d).into_iter().chain(physics_first) {
            let st2 = refit_setup(&st, &s.train)?;
            let (tr, _, _) = stats(&st2, &s.train);
            let (h, p95, mx) = stats(&st2, &s.held);
            println!("  {label:<34} {tr:>9.4} {h:>9.4} {p95:>9.4} {mx:>9.4}");
        }
        // Reference: the series' own geometric identification.
        let own = diagnose::diagnose(
            &model,
            &s.train,
            &s.held,
            &Options {
                max_effects: 0,
                allow_nonparametric: false,
                ..Options::default()
            },
        )?;
        let (h, p95, mx) = stats(&own.geometric, &s.held);
        println!(
            "  {:<34} {:>9.4} {h:>9.4} {p95:>9.4} {mx:>9.4}",
            "(own geometric fit, reference)",
            stats(&own.geometric, &s.train).0
        );
    }
    Ok(())
}
