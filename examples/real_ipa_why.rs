//! Why the time-blocked and cross-series splits of the real UR10 set (issue 18) do not
//! improve the way the interleaved split does: measured, not guessed. Reads the IPA Series A
//! set from `$ROBOCAL_REAL_DATA` (or `../shared/data/real-ur10-ipa-grid`) and says so
//! plainly when it is absent; `--series FILE` adds another series converted with
//! `robocal import ipa` (scored against Series A).
//!
//! ```text
//! cargo run --release --example real_ipa_why -- [--series B.jsonl ...] [--periodogram-only]
//!     [--dump poses.csv]
//! ```
//!
//! Prints:
//! 1. the session's sub-sessions (pauses > 1 h) with their temperature, and the mean
//!    residual of the geometric model (fitted on every training pose) per sub-session: a
//!    tracker/setup move at a pause shows as a mean offset;
//! 2. the time-blocked split decomposed: the late held-out poses scored by (a) the
//!    geometric model of the early poses, (b) the same with only the setup (tracker ← base,
//!    marker) re-registered on the late training poses, (c) the geometric model of every
//!    training pose, (d) the interleaved diagnosis (with its correction);
//! 3. coverage: the distance of each held-out pose to its nearest training pose in the
//!    correction's input space (wrist centre + marker in frame 1, 100 mm units), for the
//!    interleaved split, the time-blocked split and every `--series`;
//! 4. the kernel correction's cross-validated gain on the geometric residual with
//!    time-blocked folds vs interleaved folds (what the correction learns from neighbours in
//!    time), and the correlation of the residual with `temp_c`.
use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use robocal::diagnose::fit::{residuals, rms3, State};
use robocal::diagnose::transfer::refit_setup;
use robocal::diagnose::{self, nonparam, Options};
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

fn load(
    train: &Path,
    held: Option<&Path>,
) -> anyhow::Result<(KinematicModel, Vec<PoseObs>, Vec<PoseObs>)> {
    let main = robocal::dataset::read_dataset(train)?.dataset;
    let extra = held
        .map(|h| robocal::dataset::read_dataset(h).map(|l| l.dataset))
        .transpose()?;
    let model = KinematicModel::from_robot_block(&main.header.robot)?;
    let (train, held, _) =
        robocal::solve::obs::split_observations(&main, extra.as_ref(), model.dof());
    Ok((model, train, held))
}

fn geometric(model: &KinematicModel, train: &[PoseObs]) -> anyhow::Result<State> {
    let d = diagnose::diagnose(
        model,
        train,
        &[],
        &Options {
            max_effects: 0,
            allow_nonparametric: false,
            ..Options::default()
        },
    )?;
    Ok(d.geometric)
}

fn rms(st: &State, obs: &[PoseObs]) -> f64 {
    rms3(&residuals(st, obs))
}

/// Correction inputs (arm frame, 100 mm units) of every pose.
fn features(model: &KinematicModel, obs: &[PoseObs]) -> Vec<Vec<f64>> {
    obs.iter()
        .map(|o| nonparam::arm_frame(model, &o.q).0)
        .collect()
}

/// Distance of every query to its nearest reference (Euclidean, brute force).
fn nn_dist(reference: &[Vec<f64>], query: &[Vec<f64>]) -> Vec<f64> {
    query
        .iter()
        .map(|a| {
            reference
                .iter()
                .map(|b| a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>())
                .fold(f64::INFINITY, f64::min)
                .sqrt()
        })
        .collect()
}

fn quantiles(mut v: Vec<f64>) -> (f64, f64, f64) {
    v.sort_by(f64::total_cmp);
    let q = |p: f64| v[((v.len() as f64 - 1.0) * p).round() as usize];
    (q(0.5), q(0.9), q(1.0))
}

fn coverage_row(label: &str, reference: &[Vec<f64>], query: &[Vec<f64>]) {
    let d = nn_dist(reference, query);
    let far = |x: f64| 100.0 * d.iter().filter(|v| **v > x).count() as f64 / d.len() as f64;
    let (med, p90, mx) = quantiles(d.clone());
    println!(
        "  {label:<46} {:>6} {:>8.1} {:>8.1} {:>8.1} {:>7.1}% {:>7.1}%",
        query.len(),
        100.0 * med,
        100.0 * p90,
        100.0 * mx,
        far(0.5),
        far(1.0)
    );
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut series = Vec::new();
    let mut dump: Option<PathBuf> = None;
    let mut periodogram_only = false;
    let mut i = 0;
    while i < args.len() {
        match args[i].as_str() {
            "--series" => {
                series.push(PathBuf::from(
                    args.get(i + 1)
                        .ok_or_else(|| anyhow::anyhow!("--series needs a path"))?,
                ));
                i += 1;
            }
            "--periodogram-only" => periodogram_only = true,
            "--dump" => {
                dump = Some(PathBuf::from(
                    args.get(i + 1)
                        .ok_or_else(|| anyhow::anyhow!("--dump needs a path"))?,
                ));
                i += 1;
            }
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
        "# Why the splits differ (IPA Series A from {})",
        dir.display()
    );
    let (model, train, held) = load(&dir.join("train.jsonl"), Some(&dir.join("heldout.jsonl")))?;
    let sorted = train.windows(2).all(|w| w[0].t <= w[1].t);
    println!(
        "training poses in time order: {sorted} (the diagnosis' CV folds are contiguous blocks of this order)"
    );

    // 1. Sub-sessions and the geometric residual per sub-session.
    let geo = geometric(&model, &train)?;
    let mut all: Vec<&PoseObs> = train.iter().chain(&held).collect();
    all.sort_by(|a, b| a.t.total_cmp(&b.t));
    let mut cuts = vec![f64::NEG_INFINITY];
    for w in all.windows(2) {
        if w[1].t - w[0].t > 3600.0 {
            cuts.push(0.5 * (w[0].t + w[1].t));
        }
    }
    cuts.push(f64::INFINITY);
    println!(
        "\n## 1. Sub-sessions (pauses > 1 h); geometric model fitted on all {} training poses (train {:.4} / held-out {:.4} mm)",
        train.len(),
        rms(&geo, &train),
        rms(&geo, &held)
    );
    println!(
        "  {:>3} {:>8} {:>8} {:>6} {:>6} {:>13} {:>26} {:>9} {:>9}",
        "seg",
        "start h",
        "end h",
        "train",
        "held",
        "temp °C",
        "mean residual x,y,z (mm)",
        "RMS",
        "RMS−mean"
    );
    let r_all = residuals(&geo, &train);
    for s in 0..cuts.len() - 1 {
        let idx: Vec<usize> = (0..train.len())
            .filter(|&k| train[k].t > cuts[s] && train[k].t <= cuts[s + 1])
            .collect();
        if idx.is_empty() {
            continue;
        }
        let nh = held
            .iter()
            .filter(|o| o.t > cuts[s] && o.t <= cuts[s + 1])
            .count();
        let v: Vec<Vector3<f64>> = idx
            .iter()
            .map(|&k| Vector3::new(r_all[3 * k], r_all[3 * k + 1], r_all[3 * k + 2]))
            .collect();
        let mean = v.iter().sum::<Vector3<f64>>() / v.len() as f64;
        let ms = (v.iter().map(|x| x.norm_squared()).sum::<f64>() / v.len() as f64).sqrt();
        let ms0 =
            (v.iter().map(|x| (x - mean).norm_squared()).sum::<f64>() / v.len() as f64).sqrt();
        let temps: Vec<f64> = idx.iter().filter_map(|&k| train[k].temp_c).collect();
        let (tlo, thi) = (
            temps.iter().copied().fold(f64::INFINITY, f64::min),
            temps.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        );
        println!(
            "  {s:>3} {:>8.1} {:>8.1} {:>6} {:>6} {:>6.2}–{:<6.2} {:>8.3} {:>8.3} {:>8.3} {:>9.4} {:>9.4}",
            train[idx[0]].t / 3600.0,
            train[*idx.last().unwrap()].t / 3600.0,
            idx.len(),
            nh,
            tlo,
            thi,
            mean.x,
            mean.y,
            mean.z,
            ms,
            ms0
        );
    }
    // Residual vs temperature (geometric, training poses): correlation per axis.
    let temps: Vec<f64> = train.iter().map(|o| o.temp_c.unwrap_or(f64::NAN)).collect();
    if temps.iter().all(|t| t.is_finite()) {
        let n = temps.len() as f64;
        let tm = temps.iter().sum::<f64>() / n;
        let sd_t = (temps.iter().map(|t| (t - tm).powi(2)).sum::<f64>() / n).sqrt();
        let corr: Vec<f64> = (0..3)
            .map(|a| {
                let x: Vec<f64> = (0..train.len()).map(|k| r_all[3 * k + a]).collect();
                let xm = x.iter().sum::<f64>() / n;
                let sx = (x.iter().map(|v| (v - xm).powi(2)).sum::<f64>() / n).sqrt();
                x.iter()
                    .zip(&temps)
                    .map(|(v, t)| (v - xm) * (t - tm))
                    .sum::<f64>()
                    / n
                    / (sx * sd_t)
            })
            .collect();
        println!(
            "  temp_c over the training poses: sd {sd_t:.3} °C; correlation of the geometric residual with temp_c: x {:+.3}, y {:+.3}, z {:+.3}",
            corr[0], corr[1], corr[2]
        );
    }

    if periodogram_only {
        return periodogram(&model, &geo, &train);
    }
    // 2. Time-blocked split decomposed.
    let mut ts: Vec<f64> = train.iter().map(|o| o.t).collect();
    ts.sort_by(f64::total_cmp);
    let t_split = ts[ts.len() * 3 / 4];
    let early: Vec<PoseObs> = train.iter().filter(|o| o.t < t_split).cloned().collect();
    let late_train: Vec<PoseObs> = train.iter().filter(|o| o.t >= t_split).cloned().collect();
    let late: Vec<PoseObs> = held.iter().filter(|o| o.t >= t_split).cloned().collect();
    let early_held: Vec<PoseObs> = held.iter().filter(|o| o.t < t_split).cloned().collect();
    println!(
        "\n## 2. Time-blocked split: {} early training poses, {} late held-out poses (t ≥ {:.1} h)",
        early.len(),
        late.len(),
        t_split / 3600.0
    );
    let geo_early = geometric(&model, &early)?;
    if let Some(path) = &dump {
        // Every pose with the residual of the early geometric model in the arm frame (for
        // exploring correction bases offline); `--dump` stops here.
        use std::io::Write;
        let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
        writeln!(
            f,
            "id,t,split,q1,q2,q3,q4,q5,q6,x1,x2,x3,x4,x5,x6,r1,r2,r3,temp"
        )?;
        let mut rows: Vec<(&PoseObs, &str)> = train.iter().map(|o| (o, "train")).collect();
        rows.extend(held.iter().map(|o| (o, "held")));
        let r = residuals(
            &geo_early,
            &rows.iter().map(|(o, _)| (*o).clone()).collect::<Vec<_>>(),
        );
        for (k, (o, sp)) in rows.iter().enumerate() {
            let (x, rot) = nonparam::arm_frame(&geo_early.model, &o.q);
            let ra = rot.transpose() * Vector3::new(r[3 * k], r[3 * k + 1], r[3 * k + 2]);
            let q: Vec<String> = o.q.iter().map(|v| format!("{v:.9}")).collect();
            let xs: Vec<String> = x.iter().map(|v| format!("{v:.9}")).collect();
            writeln!(
                f,
                "{},{},{sp},{},{},{:.6},{:.6},{:.6},{}",
                o.id,
                o.t,
                q.join(","),
                xs.join(","),
                ra.x,
                ra.y,
                ra.z,
                o.temp_c.unwrap_or(f64::NAN)
            )?;
        }
        println!(
            "  dumped {} poses to {} (t_split {t_split} s)",
            rows.len(),
            path.display()
        );
        return Ok(());
    }
    let reg = refit_setup(&geo_early, &late_train)?;
    println!(
        "  {:<70} {:>9}",
        "model scoring the late held-out poses", "RMS mm"
    );
    println!(
        "  {:<70} {:>9.4}",
        "(a) geometric fitted on the early poses",
        rms(&geo_early, &late)
    );
    println!(
        "  {:<70} {:>9.4}",
        "(b) = (a) with only the setup re-registered on the late training poses",
        rms(&reg, &late)
    );
    println!(
        "  {:<70} {:>9.4}",
        "(c) geometric fitted on every training pose (early and late)",
        rms(&geo, &late)
    );
    let geo_late = geometric(&model, &late_train)?;
    println!(
        "  {:<70} {:>9.4}",
        "(c') geometric fitted on the late training poses only",
        rms(&geo_late, &late)
    );
    println!(
        "  {:<70} {:>9.4}",
        "    (for scale: (a) on the early held-out poses)",
        rms(&geo_early, &early_held)
    );
    let d = diagnose::diagnose(&model, &train, &held, &Options::default())?;
    println!(
        "  {:<70} {:>9.4}",
        "(d) interleaved default diagnosis (effects + correction), all training",
        rms(&d.state, &late)
    );
    let d_early = diagnose::diagnose(&model, &early, &late, &Options::default())?;
    println!(
        "  {:<70} {:>9.4}",
        "(e) time-blocked default diagnosis (early training only)",
        rms(&d_early.state, &late)
    );
    println!(
        "  {:<70} {:>9.4}",
        "(f) = (e) with only the setup re-registered on the late training poses",
        rms(&refit_setup(&d_early.state, &late_train)?, &late)
    );
    println!(
        "  chain of (e): {}",
        d_early
            .steps
            .iter()
            .map(|s| s.evidence.label.clone())
            .collect::<Vec<_>>()
            .join(", ")
    );

    // 3. Coverage in the correction's input space.
    let f_train = features(&model, &train);
    let f_held = features(&model, &held);
    let f_early = features(&model, &early);
    let f_late = features(&model, &late);
    let f_early_held = features(&model, &early_held);
    println!("\n## 3. Coverage: distance of a held-out pose to the nearest training pose in the correction's inputs (wrist centre + marker in frame 1), mm");
    println!(
        "  {:<46} {:>6} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "held-out vs training", "poses", "median", "p90", "max", ">50 mm", ">100 mm"
    );
    coverage_row("interleaved: A held-out vs A train", &f_train, &f_held);
    coverage_row(
        "time-blocked: late held-out vs early train",
        &f_early,
        &f_late,
    );
    coverage_row(
        "time-blocked: early held-out vs early train",
        &f_early,
        &f_early_held,
    );
    for p in &series {
        let (_, s_tr, s_he) = load(p, None)?;
        let all_s: Vec<PoseObs> = s_tr.into_iter().chain(s_he).collect();
        coverage_row(
            &format!("{} vs A train", p.file_name().unwrap().to_string_lossy()),
            &f_train,
            &features(&model, &all_s),
        );
        let temps: Vec<f64> = all_s.iter().filter_map(|o| o.temp_c).collect();
        if !temps.is_empty() {
            println!(
                "    its temp_c {:.2}–{:.2} °C (Series A training: {:.2}–{:.2} °C)",
                temps.iter().copied().fold(f64::INFINITY, f64::min),
                temps.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                train
                    .iter()
                    .filter_map(|o| o.temp_c)
                    .fold(f64::INFINITY, f64::min),
                train
                    .iter()
                    .filter_map(|o| o.temp_c)
                    .fold(f64::NEG_INFINITY, f64::max),
            );
        }
    }

    // 4. What the correction learns: time-blocked vs interleaved folds on the geometric
    // residual of the full training set.
    let rv: Vec<Vector3<f64>> = (0..train.len())
        .map(|k| Vector3::new(r_all[3 * k], r_all[3 * k + 1], r_all[3 * k + 2]))
        .collect();
    let qs: Vec<Vec<f64>> = train.iter().map(|o| o.q.clone()).collect();
    let (xs, ys) = nonparam::arm_frame_data(&geo.model, &qs, &rv);
    let k = 5;
    let n = xs.len();
    let blocked: Vec<usize> = (0..n).map(|i| (i * k / n).min(k - 1)).collect();
    let interleaved: Vec<usize> = (0..n).map(|i| i % k).collect();
    println!("\n## 4. Kernel correction on the geometric residual (all training poses), 5 folds");
    for (label, fo) in [
        ("time-blocked folds (what the diagnosis uses)", &blocked),
        ("interleaved folds (every 5th pose)", &interleaved),
    ] {
        match nonparam::cross_validate(&xs, &ys, fo, k) {
            Some(cv) => println!(
                "  {label:<46} CV RMS per axis {:.4} → {:.4} mm ({:+.1} %), ℓ = {}, λ = {}",
                cv.cv_rms_before,
                cv.cv_rms_after,
                100.0 * (cv.cv_rms_after / cv.cv_rms_before - 1.0),
                cv.length_scale,
                cv.lambda
            ),
            None => println!("  {label}: too few poses"),
        }
    }
    periodogram(&model, &geo, &train)
}

fn periodogram(model: &KinematicModel, geo: &State, train: &[PoseObs]) -> anyhow::Result<()> {
    // 5. Periodogram of each joint's angle error: the geometric residual scored against
    // `δθ_j = a sin kq_j + b cos kq_j` for every integer k up to 260 cycles per output turn
    // (harmonic-drive wave-generator lines sit at k = N and 2N: N = 100 or 101 for the 100:1
    // strain-wave gears of UR arms, depending on which spline is fixed).
    let kmax: u32 = std::env::var("WHY_KMAX")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(260);
    println!(
        "\n## 5. Periodogram of the joint-angle error on the geometric residual (all training poses): ΔBIC of a sin/cos of k·q_j, k = 1..{kmax}"
    );
    let opt = Options::default();
    for j in 1..=model.dof() {
        let groups: Vec<Vec<robocal::diagnose::effects::Block>> = (1..=kmax)
            .map(|harmonic| vec![robocal::diagnose::effects::Ripple { joint: j, harmonic }.into()])
            .collect();
        let scores = diagnose::score_round(geo, train, &groups, &opt);
        let k_of = |s: &diagnose::Score| match s.block {
            robocal::diagnose::effects::Block::Ripple(ref r) => r.harmonic,
            _ => 0,
        };
        let top: Vec<String> = scores
            .iter()
            .take(8)
            .map(|s| {
                format!(
                    "k={} ΔBIC {:.0} CV {:+.1}%",
                    k_of(s),
                    s.delta_bic,
                    100.0 * s.cv_gain
                )
            })
            .collect();
        let at = |k: u32| {
            scores
                .iter()
                .find(|s| k_of(s) == k)
                .map(|s| format!("{:.0}", s.delta_bic))
                .unwrap_or_else(|| "—".into())
        };
        println!("  j{j}: top {}", top.join("; "));
        println!(
            "      at the wave-generator lines: k=100 {}, 101 {}, 200 {}, 202 {} (the diagnosis accepts ΔBIC > 10 with p < 0.01 / tests)",
            at(100),
            at(101),
            at(200),
            at(202),
        );
    }
    Ok(())
}
