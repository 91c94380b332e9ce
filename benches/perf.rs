//! The performance suite of issue 32: `cargo bench --bench perf [-- quick|camera]`.
//!
//! Prints, on this machine, each figure of the issue that the kinematic side owns and the
//! peer on the same input in the same run, with the ratio:
//! - **bootstrap** 10,000 × 200 on the public 500-pose case (`tests/data/kin-geometric`):
//!   the whole `robocal calibrate kinematics --bootstrap 10000 --subset 200` process (wall), and
//!   in-process the fast path vs exact LM refits of the same subsets (time ratio and the
//!   largest difference of mean and σ, in σ);
//! - **identification vs poses**: whole `robocal calibrate kinematics` processes on 1,000 /
//!   10,000 / 100,000 poses (wall, peak RSS, time per pose), on data generated here from the
//!   identified 500-pose model with 0.035 mm noise (every 10th pose held out);
//! - **camera**: `robocal calibrate camera` on the 60 rendered 1280×1024 views of
//!   `examples/camera_world` (world `ur5e-clean`, rendered by that example), whole process,
//!   and OpenCV's detection + `calibrateCamera` + `calibrateHandEye` on the same image files
//!   (`scripts/peers/camera_pipeline_cv2.py`, `.venv/peers-cv2`), with the ratio;
//! - **peer**: pybotics + SciPy `least_squares` on the same 500-pose kinematic problem
//!   (`examples/ident_pybotics.rs`, needs `.venv/peers-pybotics` from `.ci/peers.sh`).
//!
//! - **diagnose** (the default policy, whole process) on real UR10 + laser-tracker poses: the
//!   first 2,000 training poses of `../shared/data/real-ur10-ipa-grid` (Series A) with the
//!   held-out poses of the same span, then the whole series (8,934 + 2,977), plus any dataset
//!   named in `$ROBOCAL_BENCH_DIAGNOSE` (`:`-separated files whose `validation` records are
//!   held out, e.g. IPA Series C imported with `robocal import ipa`). There is no peer that
//!   diagnoses; the row prints the held-out RMS beside SciPy's geometric reference on Series A.
//!   Real data is read from outside the project and never copied; absent, the row says SKIPPED.
//!
//! `quick` stops the pose ladder at 10,000; `camera` runs the camera row only; `diagnose` the
//! diagnose row only. Nothing in CI runs this or depends on a timing.
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use robocal::dataset::Dataset;
use robocal::model::KinematicModel;
use robocal::solve::bootstrap::{bootstrap, BootstrapMethod, BootstrapOptions, SubsetSize};
use robocal::solve::kinematics::{identify, IdentOptions};
use serde_json::Value;

#[path = "../examples/ident_pybotics.rs"]
mod ident_pybotics;

const BIN: &str = env!("CARGO_BIN_EXE_robocal");

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Wall time (s) and peak resident memory (MB) of one `robocal` process.
fn run_robocal(args: &[&str]) -> (f64, f64) {
    let (wall, _, rss) = run_robocal_cpu(args);
    (wall, rss)
}

/// Wall time (s), CPU time (user + system, s) and peak resident memory (MB) of one `robocal`
/// process.
// The child is reaped by `libc::wait4` (for its rusage), which clippy cannot see.
#[allow(clippy::zombie_processes)]
fn run_robocal_cpu(args: &[&str]) -> (f64, f64, f64) {
    let t0 = Instant::now();
    let child = Command::new(BIN)
        .args(args)
        .stdout(std::process::Stdio::null())
        // Warnings about the data (e.g. a missing `q_prev`) would break the printed table;
        // a failed run shows as a missing output file in the row that reads it.
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("spawn robocal");
    let mut status = 0;
    // SAFETY: a zeroed rusage is a valid value; wait4 fills it for our own child.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = child.id() as libc::pid_t;
    // SAFETY: pid is our child, not yet waited for; the pointers are valid for the call.
    let rc = unsafe { libc::wait4(pid, &mut status, 0, &mut ru) };
    let wall = t0.elapsed().as_secs_f64();
    assert_eq!(rc, pid, "wait4");
    assert!(
        libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0,
        "robocal {args:?} failed ({status})"
    );
    let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    (
        wall,
        secs(ru.ru_utime) + secs(ru.ru_stime),
        ru.ru_maxrss as f64 / 1024.0,
    )
}

/// Writes `n` poses near the 500 public ones (joints jittered ±2°), measured through `truth`
/// with 0.035 mm noise per axis; every 10th pose in group `validation`.
fn write_poses(path: &Path, template: &Path, truth: &KinematicModel, n: usize) {
    let text = std::fs::read_to_string(template).expect("template");
    let mut lines = text.lines();
    let header = lines.next().expect("header");
    let poses: Vec<Value> = lines
        .map(|l| serde_json::from_str::<Value>(l).expect("record"))
        .filter(|v| v["kind"] == "pose" && v["marker"]["visible"] == true)
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(32);
    let noise = Normal::new(0.0, 0.035).expect("normal");
    let jitter = Normal::new(0.0, 1.0).expect("normal");
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).expect("create"));
    writeln!(out, "{header}").expect("write");
    for i in 0..n {
        let mut v = poses[i % poses.len()].clone();
        let q_deg: Vec<f64> = v["q"]
            .as_array()
            .expect("q")
            .iter()
            .map(|x| x.as_f64().expect("q") + jitter.sample(&mut rng))
            .collect();
        let q: Vec<f64> = q_deg.iter().map(|d| d.to_radians()).collect();
        let p = truth.measured_point(&q);
        v["id"] = i.into();
        v["t"] = (i as f64 * 9.0).into();
        v["point"] = i.into();
        v["group"] = if i % 10 == 9 { "validation" } else { "train" }.into();
        v["q"] = serde_json::json!(q_deg);
        v["q_cmd"] = serde_json::json!(q_deg);
        v["marker"]["p"] = serde_json::json!((0..3)
            .map(|a| p[a] + noise.sample(&mut rng))
            .collect::<Vec<_>>());
        if let Some(m) = v["marker"].as_object_mut() {
            m.remove("quat");
        }
        writeln!(out, "{v}").expect("write");
    }
}

fn main() {
    let quick = std::env::args().any(|a| a == "quick");
    if std::env::args().any(|a| a == "camera") {
        let tmp = tempfile::tempdir().expect("tempdir");
        camera_row(tmp.path());
        return;
    }
    if std::env::args().any(|a| a == "diagnose") {
        let tmp = tempfile::tempdir().expect("tempdir");
        diagnose_row(tmp.path());
        return;
    }
    let data = root().join("tests/data/kin-geometric");
    let train = data.join("train.jsonl");
    let held = data.join("heldout.jsonl");
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("cal");
    let s = |p: &Path| p.to_str().expect("utf-8 path").to_string();
    println!(
        "machine: {} cores (rayon {} threads), robocal {}",
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        rayon::current_num_threads(),
        BIN
    );

    // --- bootstrap, whole process
    let (w0, _) = run_robocal(&[
        "calibrate",
        "kinematics",
        "--data",
        &s(&train),
        "--heldout",
        &s(&held),
        "--out",
        &s(&out),
    ]);
    let (w, rss) = run_robocal(&[
        "calibrate",
        "kinematics",
        "--data",
        &s(&train),
        "--heldout",
        &s(&held),
        "--bootstrap",
        "10000",
        "--subset",
        "200",
        "--out",
        &s(&out),
    ]);
    println!(
        "bootstrap 10000 x 200 of 500, whole process: {w:.2} s wall ({:.2} s without --bootstrap), \
         peak {rss:.0} MB",
        w0
    );

    // --- bootstrap, in process: fast path vs exact refits of the same subsets
    let res = identify(
        &Dataset::load(&train).expect("train"),
        &IdentOptions {
            heldout: Some(Dataset::load(&held).expect("heldout")),
            ..Default::default()
        },
    )
    .expect("identify");
    let opts = |k, method| BootstrapOptions {
        k,
        subset: SubsetSize::Count(200),
        seed: 1,
        method,
        ..Default::default()
    };
    let k = if quick { 1000 } else { 10_000 };
    let fast = bootstrap(&res, &[], &opts(k, BootstrapMethod::Fast)).expect("fast");
    let exact = bootstrap(&res, &[], &opts(k, BootstrapMethod::Exact)).expect("exact");
    let (mut dm, mut ds) = (0.0f64, 0.0f64);
    for (f, e) in fast.summaries.iter().zip(&exact.summaries) {
        dm = dm.max((f.mean - e.mean).abs() / e.std);
        ds = ds.max((f.std / e.std - 1.0).abs());
    }
    println!(
        "bootstrap {k} x 200, in process: fast {:.3} s ({} LM fallbacks, {:.2} FK passes per \
         subset, audit {:.1e} σ) vs exact LM refits {:.3} s: {:.1}x; means within {dm:.1e} σ, \
         σ within {:.1} %",
        fast.elapsed_s,
        fast.n_fallback,
        fast.n_chord_passes as f64 / k as f64,
        fast.audit_max_sigma.unwrap_or(f64::NAN),
        exact.elapsed_s,
        exact.elapsed_s / fast.elapsed_s,
        100.0 * ds
    );

    // --- identification vs number of poses, whole process
    let ladder: &[usize] = if quick {
        &[1_000, 10_000]
    } else {
        &[1_000, 10_000, 100_000]
    };
    println!("identification (calibrate kinematics, 10 % held out):");
    println!(
        "{:>9} {:>9} {:>9} {:>12}",
        "poses", "wall s", "peak MB", "µs / pose"
    );
    for &n in ladder {
        let f = tmp.path().join(format!("poses-{n}.jsonl"));
        write_poses(&f, &train, &res.model, n);
        let (w, rss) = run_robocal(&[
            "calibrate",
            "kinematics",
            "--data",
            &s(&f),
            "--out",
            &s(&out),
        ]);
        println!("{n:>9} {w:>9.2} {rss:>9.0} {:>12.1}", 1e6 * w / n as f64);
    }

    camera_row(tmp.path());
    diagnose_row(tmp.path());

    // --- peer: pybotics + SciPy least_squares on the same 500-pose problem
    println!("peer (examples/ident_pybotics.rs):");
    ident_pybotics::main();
}

/// `calibrate camera` (detection + intrinsics + hand-eye, whole process) on the 60 rendered
/// 1280×1024 views of `examples/camera_world` (world `ur5e-clean`), and OpenCV's pipeline on
/// the same image files (`scripts/peers/camera_pipeline_cv2.py`: findChessboardCorners +
/// cornerSubPix, calibrateCamera, calibrateHandEye), whole process, with the ratio.
fn camera_row(tmp: &Path) {
    let data = root().join("out/camera-world/ur5e-clean/train.jsonl");
    if !data.is_file() {
        println!(
            "camera 60 x 1280x1024: SKIPPED ({} absent: `cargo run --release --example \
             camera_world -- ur5e-clean` renders it)",
            data.display()
        );
        return;
    }
    let out = tmp.join("cam");
    let d = data.to_str().expect("utf-8 path");
    let o = out.to_str().expect("utf-8 path");
    let (w, cpu, rss) = run_robocal_cpu(&["calibrate", "camera", "--data", d, "--out", o]);
    // The split the command itself measured (detection = image decode + board detection).
    let split = std::fs::read_to_string(out.join("camera_report.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<Value>(&t).ok())
        .map(|v| {
            format!(
                "; in process: detection {:.2} s, then calibration {:.2} s (wall)",
                v["timing_s"]["detection"].as_f64().unwrap_or(f64::NAN),
                v["timing_s"]["total"].as_f64().unwrap_or(f64::NAN)
                    - v["timing_s"]["detection"].as_f64().unwrap_or(f64::NAN)
            )
        })
        .unwrap_or_default();
    println!(
        "camera 60 x 1280x1024 (calibrate camera, whole process): {w:.2} s wall, {cpu:.2} s CPU \
         on {} cores, peak {rss:.0} MB{split}",
        std::thread::available_parallelism().map_or(0, |n| n.get())
    );
    let py = root().join(".venv/peers-cv2/bin/python");
    if !py.is_file() {
        println!("  peer OpenCV: SKIPPED (.venv/peers-cv2 absent: `bash .ci/peers.sh`)");
        return;
    }
    let t0 = Instant::now();
    let res = Command::new(&py)
        .arg(root().join("scripts/peers/camera_pipeline_cv2.py"))
        .arg(&data)
        .output()
        .expect("run python");
    let pw = t0.elapsed().as_secs_f64();
    let txt = String::from_utf8_lossy(&res.stdout);
    match serde_json::from_str::<Value>(txt.trim()) {
        Ok(v) if res.status.success() => println!(
            "  peer OpenCV {} (same images, whole process): {pw:.2} s wall ({} / {} views \
             detected; detection {:.2} s, calibrateCamera {:.2} s, calibrateHandEye {:.3} s); \
             OpenCV / robocal = {:.1}x",
            v["opencv"].as_str().unwrap_or("?"),
            v["found"],
            v["views"],
            v["detect_s"].as_f64().unwrap_or(f64::NAN),
            v["calibrate_s"].as_f64().unwrap_or(f64::NAN),
            v["handeye_s"].as_f64().unwrap_or(f64::NAN),
            pw / w
        ),
        _ => println!(
            "  peer OpenCV failed: {} {}",
            txt.trim(),
            String::from_utf8_lossy(&res.stderr).trim()
        ),
    }
}

/// `robocal diagnose` (default policy, whole process) on real UR10 poses: Series A's first
/// 2,000 training poses (and its held-out poses of the same span), all of Series A, and the
/// datasets named in `$ROBOCAL_BENCH_DIAGNOSE`.
fn diagnose_row(tmp: &Path) {
    let series = root().join("../shared/data/real-ur10-ipa-grid");
    let mut cases: Vec<(String, PathBuf, Option<PathBuf>)> = Vec::new();
    if series.join("train.jsonl").is_file() {
        let (train, held) = (series.join("train.jsonl"), series.join("heldout.jsonl"));
        let (t2k, h2k) = (tmp.join("a2k-train.jsonl"), tmp.join("a2k-held.jsonl"));
        write_first_span(&train, &held, 2_000, &t2k, &h2k);
        cases.push(("Series A, first 2,000".into(), t2k, Some(h2k)));
        cases.push(("Series A, all".into(), train, Some(held)));
    } else {
        println!(
            "diagnose on real UR10 poses: SKIPPED ({} absent; real data is never copied into \
             the project)",
            series.display()
        );
    }
    if let Ok(extra) = std::env::var("ROBOCAL_BENCH_DIAGNOSE") {
        for f in extra.split(':').filter(|f| !f.is_empty()) {
            let name = Path::new(f)
                .file_name()
                .map_or(f.to_string(), |n| n.to_string_lossy().into_owned());
            cases.push((name, PathBuf::from(f), None));
        }
    }
    if cases.is_empty() {
        return;
    }
    println!("diagnose (default policy, whole process; held-out RMS mm geometric -> final):");
    println!(
        "{:<24} {:>7} {:>7} {:>8} {:>8} {:>8} {:>17}",
        "data", "train", "held", "wall s", "CPU s", "peak MB", "held-out mm"
    );
    for (name, train, held) in cases {
        let out = tmp.join("diag");
        let _ = std::fs::remove_dir_all(&out);
        let mut args = vec![
            "diagnose".to_string(),
            "--data".into(),
            train.to_string_lossy().into_owned(),
            "--out".into(),
            out.to_string_lossy().into_owned(),
        ];
        if let Some(h) = &held {
            args.push("--heldout".into());
            args.push(h.to_string_lossy().into_owned());
        }
        let argv: Vec<&str> = args.iter().map(String::as_str).collect();
        let (w, cpu, rss) = run_robocal_cpu(&argv);
        let d = std::fs::read_to_string(out.join("diagnosis.json"))
            .ok()
            .and_then(|t| serde_json::from_str::<Value>(&t).ok());
        let Some(d) = d else {
            println!("{name:<24} diagnose failed (no diagnosis.json)");
            continue;
        };
        let f = |k: &str| d["heldout_rms"][k].as_f64().unwrap_or(f64::NAN);
        println!(
            "{name:<24} {:>7} {:>7} {w:>8.2} {cpu:>8.2} {rss:>8.0} {:>8.4} -> {:.4}",
            d["n_train"],
            d["n_heldout"],
            f("base_model_mm"),
            f("final_mm")
        );
    }
    println!("  reference (the data's README): SciPy geometric least squares on all of Series A, held-out 0.438 mm");
}

/// The header and first `n` training records of `train`, and the held-out records of `held`
/// acquired within their span (by id).
fn write_first_span(train: &Path, held: &Path, n: usize, t_out: &Path, h_out: &Path) {
    let t = std::fs::read_to_string(train).expect("read train");
    let mut lines = t.lines();
    let header = lines.next().expect("header");
    let recs: Vec<&str> = lines.take(n).collect();
    let id = |l: &str| {
        serde_json::from_str::<Value>(l)
            .ok()
            .and_then(|v| v["id"].as_u64())
    };
    let last = recs.iter().rev().find_map(|l| id(l)).expect("ids");
    std::fs::write(t_out, format!("{header}\n{}\n", recs.join("\n"))).expect("write");
    let h = std::fs::read_to_string(held).expect("read held-out");
    let mut hl = h.lines();
    let hh = hl.next().expect("header");
    let hr: Vec<&str> = hl.filter(|l| id(l).is_some_and(|i| i <= last)).collect();
    std::fs::write(h_out, format!("{hh}\n{}\n", hr.join("\n"))).expect("write");
}
