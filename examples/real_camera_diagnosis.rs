//! The camera diagnosis on real eye-in-hand sets (issue 31 §3): each set imported as a user
//! would (`robocal import handeye`, every 4th view held out), then `robocal diagnose`'s camera
//! diagnosis: the held-out reprojection before / after, the effects it accepts (`flange_map`:
//! the arm's reported positions off by a linear map), and how stable the diagnosed hand-eye is
//! — `N` seeded random halvings of all the views, each half diagnosed on its own as a user
//! would (its every 4th view held out), |ΔX| beside the two halves' stated 1σ.
//!
//!     cargo run --release --example real_camera_diagnosis            # every set present
//!     cargo run --release --example real_camera_diagnosis -- ur3e    # one set
//!
//! Sets: `../shared/data/real-handeye-kuka1` (RWHE-Calib `kuka_1`), `../shared/data/
//! real-handeye-ur3e` (probabilisticAXYB, 12.5 mm squares) and, from `ROBOCAL_REAL_KUKA2`, the
//! evaluation set `kuka_2`. `ROBOCAL_SHARED_DATA` overrides `../shared/data`;
//! `ROBOCAL_RANDOM_HALVES=N` (default 10, 0 to skip). An absent set is reported SKIPPED.
use std::path::{Path, PathBuf};
use std::time::Instant;

use robocal::import::handeye::{Direction, HandeyeOptions, Layout, Reading};
use robocal::solve::camera::data::{load, Loaded, Overrides};
use robocal::solve::camera::CameraData;

fn import(
    images: PathBuf,
    poses: PathBuf,
    layout: Layout,
    unit: robocal::import::generic::LengthUnit,
    board: (u32, u32, f64),
    tmp: &Path,
    name: &str,
) -> Result<(Loaded, Loaded), String> {
    let out = tmp.join(format!("{name}.jsonl"));
    let held = tmp.join(format!("{name}-h.jsonl"));
    let o = HandeyeOptions {
        images,
        poses,
        reading: Reading {
            layout,
            unit,
            direction: Direction::BaseFlange,
        },
        target: robocal::dataset::TargetHeader {
            kind: "chessboard".into(),
            cols: board.0,
            rows: board.1,
            square_mm: board.2,
            marker_mm: None,
            dictionary: None,
        },
        mount: robocal::solve::camera::Mount::Flange,
        out: out.clone(),
        heldout_every: 4,
        heldout: Some(held.clone()),
    };
    robocal::import::handeye::import_handeye(&o, false).map_err(|e| e.to_string())?;
    let ov = Overrides::default();
    Ok((
        load(&out, &ov, false).map_err(|e| e.to_string())?,
        load(&held, &ov, false).map_err(|e| e.to_string())?,
    ))
}

/// Key, folder, pose file (in the folder), layout, unit, board (cols, rows, square mm).
type SetSpec = (
    &'static str,
    Option<PathBuf>,
    PathBuf,
    Layout,
    robocal::import::generic::LengthUnit,
    (u32, u32, f64),
);

fn main() {
    let filter = std::env::args().nth(1);
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let data = std::env::var_os("ROBOCAL_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("../shared/data"));
    let n_halves: usize = std::env::var("ROBOCAL_RANDOM_HALVES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10);
    let kuka2 = std::env::var_os("ROBOCAL_REAL_KUKA2").map(PathBuf::from);
    use robocal::import::generic::LengthUnit;
    let sets: Vec<SetSpec> = vec![
        (
            "kuka1",
            Some(data.join("real-handeye-kuka1")),
            PathBuf::from("RobotPosesVec.txt"),
            Layout::Matrix4 { col_major: false },
            LengthUnit::M,
            (28, 17, 20.0),
        ),
        (
            "ur3e",
            Some(data.join("real-handeye-ur3e")),
            PathBuf::from("endeffectors"),
            Layout::Rot9 { col_major: true },
            LengthUnit::Mm,
            (6, 5, 12.5),
        ),
        (
            "kuka2",
            kuka2,
            PathBuf::from("RobotPosesVec.txt"),
            Layout::Matrix4 { col_major: false },
            LengthUnit::M,
            (24, 17, 15.0),
        ),
    ];
    let tmp = tempfile::tempdir().expect("temporary folder");
    let mut summary = vec![];
    for (key, dir, poses, layout, unit, board) in sets {
        if filter.as_deref().is_some_and(|f| !key.contains(f)) {
            continue;
        }
        let Some(dir) = dir.filter(|d| d.exists()) else {
            println!("\n=== {key}: SKIPPED (absent; kuka2 needs ROBOCAL_REAL_KUKA2) ===");
            continue;
        };
        let images = if key == "ur3e" {
            dir.join("images")
        } else {
            dir.clone()
        };
        let (train, held) = match import(
            images,
            dir.join(&poses),
            layout,
            unit,
            board,
            tmp.path(),
            key,
        ) {
            Ok(v) => v,
            Err(e) => {
                println!("\n=== {key}: cannot import: {e} ===");
                continue;
            }
        };
        let t0 = Instant::now();
        let d = match robocal::diagnose::camera::diagnose(
            &train.data,
            Some(&held.data),
            &train.dataset,
            Some(&held.dataset),
        ) {
            Ok(d) => d,
            Err(e) => {
                println!("\n=== {key}: diagnosis failed: {e} ===");
                continue;
            }
        };
        let before = d.baseline.heldout_rms_px.unwrap_or(f64::NAN);
        let after = d.last().heldout_rms_px.unwrap_or(f64::NAN);
        println!(
            "\n=== {key}: {} training / {} held-out views; diagnosis {:.1} s ===",
            train.data.views.len(),
            held.data.views.len(),
            t0.elapsed().as_secs_f64()
        );
        println!(
            "held-out {before:.3} px (calibration, {}) -> {after:.3} px (diagnosed); train {:.3} -> {:.3} px",
            d.baseline.method,
            d.baseline.train_rms_px,
            d.last().train_rms_px
        );
        for e in &d.effects {
            println!(
                "  effect {} (F {:.0}): {}",
                e.kind,
                e.evidence.f.unwrap_or(f64::NAN),
                e.summary
            );
        }
        for f in d.findings() {
            println!("  {f}");
        }
        let u = &d.uncertainty;
        println!(
            "diagnosed X {:?} mm, 1σ {:?} mm {:?} deg",
            d.last()
                .x
                .translation
                .vector
                .as_slice()
                .iter()
                .map(|v| (v * 100.0).round() / 100.0)
                .collect::<Vec<_>>(),
            u.x_mm.map(|v| (v * 1000.0).round() / 1000.0),
            u.x_deg.map(|v| (v * 1000.0).round() / 1000.0)
        );
        // Random halvings of all the views, each half diagnosed on its own.
        let all = CameraData {
            views: train
                .data
                .views
                .iter()
                .chain(&held.data.views)
                .cloned()
                .collect(),
            ..train.data.clone()
        };
        let mut ds = train.dataset.clone();
        ds.records.extend(held.dataset.records.iter().cloned());
        let (mut dx, mut within, mut n_coord, mut with_map) = (vec![], 0usize, 0usize, 0usize);
        use rand::seq::SliceRandom;
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for _ in 0..n_halves {
            let mut idx: Vec<usize> = (0..all.views.len()).collect();
            idx.shuffle(&mut rng);
            let (ia, ib) = idx.split_at(idx.len() / 2);
            let half = |ix: &[usize]| {
                let mut ix = ix.to_vec();
                ix.sort_unstable();
                CameraData {
                    views: ix.iter().map(|&i| all.views[i].clone()).collect(),
                    ..all.clone()
                }
            };
            let (a, b) = (half(ia), half(ib));
            let run = |h: &CameraData| {
                let (t, v) = robocal::solve::camera::realeval::split_every(h, 4);
                robocal::diagnose::camera::diagnose(&t, Some(&v), &ds, Some(&ds))
            };
            let (Ok(da), Ok(db)) = (run(&a), run(&b)) else {
                println!("  a halving failed");
                continue;
            };
            with_map += da.flange_map.is_some() as usize + db.flange_map.is_some() as usize;
            let (xa, xb) = (da.last().x, db.last().x);
            let t = xb.translation.vector - xa.translation.vector;
            let r = (xa.inverse() * xb).rotation.scaled_axis();
            let (ua, ub) = (&da.uncertainty, &db.uncertainty);
            let ratios: Vec<f64> = (0..3)
                .map(|i| t[i].abs() / ua.x_mm[i].hypot(ub.x_mm[i]))
                .chain((0..3).map(|i| r[i].to_degrees().abs() / ua.x_deg[i].hypot(ub.x_deg[i])))
                .collect();
            within += ratios.iter().filter(|q| **q <= 2.0).count();
            n_coord += 6;
            dx.push(t.norm());
            println!(
                "  halving: ΔX {:.2} mm, |ΔX|/σ {:?}; effects {:?} / {:?}",
                t.norm(),
                ratios
                    .iter()
                    .map(|q| (q * 10.0).round() / 10.0)
                    .collect::<Vec<_>>(),
                da.effects
                    .iter()
                    .map(|e| e.kind.as_str())
                    .collect::<Vec<_>>(),
                db.effects
                    .iter()
                    .map(|e| e.kind.as_str())
                    .collect::<Vec<_>>()
            );
        }
        let mean = dx.iter().sum::<f64>() / dx.len().max(1) as f64;
        let share = 100.0 * within as f64 / n_coord.max(1) as f64;
        println!(
            "{} random halvings: mean ΔX {mean:.2} mm; |ΔX| / combined σ ≤ 2 for {share:.0} % of {n_coord} coordinates; flange_map accepted on {with_map} of {} halves",
            dx.len(),
            2 * dx.len()
        );
        summary.push((key, before, after, mean, share));
    }
    println!("\n| set | held-out px: calibration → diagnosed | random halvings of the diagnosis: mean ΔX mm, within 2σ |");
    println!("|---|---|---|");
    for (k, b, a, m, s) in summary {
        println!(
            "| {k} | {b:.3} → {a:.3} ({:+.1} %) | {m:.2}, {s:.0} % |",
            100.0 * (a / b - 1.0)
        );
    }
}
