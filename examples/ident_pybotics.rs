//! Peer benchmark: the same kinematic calibration of `tests/data/kin-geometric` fitted by
//! robocal and by pybotics (public code: its MDH robot model and accuracy optimisation,
//! minimised with SciPy `least_squares`, `scripts/peers/pybotics_fit.py`), in one run.
//! Prints both fit times, the time ratio and both held-out RMS errors against the
//! simulator's noise-free `truth.csv`.
//!
//! pybotics' MDH links have no Hayati β, so the tilt between the parallel axes 2 and 3
//! (our `beta3`) cannot be represented; pybotics gets the same start (our closed-form
//! nominal base/tool), the same redundancy choice where the parameterisations coincide
//! (joint 1 and `theta6`, `d6` fixed; `d2` fixed for the parallel pair) and therefore 26
//! free parameters against our 27.
//!
//! `cargo run --release --example ident_pybotics` (needs `.venv/peers-pybotics`, made by
//! `.ci/peers.sh`; prints SKIP without it).
use std::collections::HashMap;
use std::path::Path;
use std::process::Command;
use std::time::Instant;

use nalgebra::{Isometry3, Matrix4, Point3};
use robocal::dataset::Dataset;
use robocal::model::KinematicModel;
use robocal::solve::kinematics::{identify, IdentOptions};
use robocal::solve::nominal::fit_nominal;
use robocal::solve::obs::{observations, Split};
use serde_json::{json, Value};

fn mat(m: &Matrix4<f64>) -> Value {
    json!((0..4)
        .map(|r| (0..4).map(|c| m[(r, c)]).collect::<Vec<_>>())
        .collect::<Vec<_>>())
}

fn iso(i: &Isometry3<f64>) -> Matrix4<f64> {
    i.to_homogeneous()
}

fn val(m: &KinematicModel, name: &str) -> f64 {
    m.param_index(name)
        .map(|i| m.params()[i].value)
        .unwrap_or(0.0)
}

pub fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let py = root.join(".venv/peers-pybotics/bin/python");
    if !py.exists() {
        println!("SKIP: {} missing (run .ci/peers.sh)", py.display());
        return;
    }
    let dir = root.join("tests/data/kin-geometric");
    let train = Dataset::load(dir.join("train.jsonl")).expect("train");
    let held = Dataset::load(dir.join("heldout.jsonl")).expect("heldout");
    let truth: HashMap<u64, Point3<f64>> = std::fs::read_to_string(dir.join("truth.csv"))
        .expect("truth")
        .lines()
        .skip(1)
        .filter_map(|l| {
            let v: Vec<f64> = l.split(',').filter_map(|s| s.parse().ok()).collect();
            (v.len() == 4).then(|| (v[0] as u64, Point3::new(v[1], v[2], v[3])))
        })
        .collect();
    let (tobs, _) = observations(&train, 6, Split::Train);
    let (hobs, _) = observations(&held, 6, Split::All);

    // robocal: the whole identification (closed-form start, identifiability, LM, covariance).
    let opts = IdentOptions {
        heldout: Some(held.clone()),
        ..Default::default()
    };
    let mut times = Vec::new();
    let mut res = None;
    for _ in 0..5 {
        let t = Instant::now();
        res = Some(identify(&train, &opts).expect("identify"));
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    let ours_s = times[2];
    let res = res.expect("result");
    let rms = |pred: &[Point3<f64>]| -> f64 {
        let s: f64 = hobs
            .iter()
            .zip(pred)
            .map(|(o, p)| (p - truth[&o.id]).norm_squared())
            .sum();
        (s / hobs.len() as f64).sqrt()
    };
    let ours_pred: Vec<Point3<f64>> = hobs
        .iter()
        .map(|o| res.model.measured_point(&o.q))
        .collect();
    let ours_rms = rms(&ours_pred);

    // pybotics job: nominal MDH table, start world/tool from our closed-form nominal fit.
    let nom = fit_nominal(&train, &Default::default())
        .expect("nominal")
        .model;
    let n = nom.dof();
    let mdh: Vec<[f64; 4]> = (1..=n)
        .map(|i| {
            [
                val(&nom, &format!("alpha{i}")),
                val(&nom, &format!("a{i}")),
                val(&nom, &format!("phi{i}")),
                val(&nom, &format!("d{i}")),
            ]
        })
        .collect();
    let beta_max = (1..=n)
        .map(|i| val(&nom, &format!("beta{i}")).abs())
        .fold(0.0, f64::max);
    let q0 = vec![0.0; n];
    let world = iso(&(nom.base() * nom.joint_frame(&q0, 0)));
    let tool = iso(&(nom.flange_transform() * nom.tool()));
    let mut chain_mask = Vec::new();
    for i in 1..=n {
        for k in ["alpha", "a", "theta", "d"] {
            let free = match (i, k) {
                (1, _) => false,
                (2, "d") => false,
                (i, "theta" | "d") if i == n => false,
                _ => true,
            };
            chain_mask.push(free);
        }
    }
    let job = json!({
        "mdh": mdh,
        "world": mat(&world),
        "tool": mat(&tool),
        "chain_mask": chain_mask,
        "world_mask": vec![true; 6],
        "tool_mask": [true, true, true, false, false, false],
        "train_q": tobs.iter().map(|o| o.q.clone()).collect::<Vec<_>>(),
        "train_p": tobs.iter().map(|o| [o.p.x, o.p.y, o.p.z]).collect::<Vec<_>>(),
        "heldout_q": hobs.iter().map(|o| o.q.clone()).collect::<Vec<_>>(),
        "check_p": tobs.iter().map(|o| { let p = nom.measured_point(&o.q); [p.x, p.y, p.z] }).collect::<Vec<_>>(),
    });
    let tmp = tempfile::tempdir().expect("tempdir");
    let job_path = tmp.path().join("job.json");
    let out_path = tmp.path().join("out.json");
    std::fs::write(&job_path, job.to_string()).expect("write job");
    if let Ok(keep) = std::env::var("ROBOCAL_PYBOTICS_JOB") {
        std::fs::write(&keep, job.to_string()).expect("write job copy");
    }
    if std::env::var("ROBOCAL_PYBOTICS_JOB_ONLY").is_ok() {
        return;
    }
    let t = Instant::now();
    let status = Command::new(&py)
        .arg(root.join("scripts/peers/pybotics_fit.py"))
        .arg(&job_path)
        .arg(&out_path)
        .status()
        .expect("run python");
    let py_wall = t.elapsed().as_secs_f64();
    assert!(status.success(), "pybotics script failed");
    let out: Value =
        serde_json::from_str(&std::fs::read_to_string(&out_path).expect("out")).expect("json");
    let py_fit = out["fit_seconds"].as_f64().unwrap_or(f64::NAN);
    let py_pred: Vec<Point3<f64>> = out["heldout_pred"]
        .as_array()
        .expect("pred")
        .iter()
        .map(|p| {
            let v: Vec<f64> = p
                .as_array()
                .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
                .unwrap_or_default();
            Point3::new(v[0], v[1], v[2])
        })
        .collect();
    let py_rms = rms(&py_pred);
    let before: Vec<Point3<f64>> = hobs.iter().map(|o| nom.measured_point(&o.q)).collect();
    println!(
        "kin-geometric: {} train poses, {} held-out poses",
        tobs.len(),
        hobs.len()
    );
    println!(
        "convention check (pybotics FK of the start model vs robocal): max {:.2e} mm (nominal max |beta| {:.1e} rad)",
        out["convention_check_max_mm"].as_f64().unwrap_or(f64::NAN),
        beta_max
    );
    println!(
        "held-out RMS vs truth.csv, before (nominal): {:.4} mm",
        rms(&before)
    );
    println!(
        "robocal : {:>8.1} ms (median of 5, whole identify), {} params, held-out RMS {:.4} mm",
        ours_s * 1e3,
        res.x.len(),
        ours_rms
    );
    println!(
        "pybotics: {:>8.1} ms (least_squares only; process wall {:.1} s), {} params, {} evaluations, held-out RMS {:.4} mm ({})",
        py_fit * 1e3,
        py_wall,
        out["n_params"],
        out["nfev"],
        py_rms,
        out["message"].as_str().unwrap_or("")
    );
    println!("time ratio pybotics / robocal: {:.0}×", py_fit / ours_s);
}
