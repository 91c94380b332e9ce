//! Camera hand-eye on real eye-in-hand sets (issue 31 §3): `../shared/data/real-handeye-kuka1`
//! (RWHE-Calib `kuka_1`) and `../shared/data/real-handeye-ur3e` (probabilisticAXYB), every 4th
//! view held out, held-out corners predicted from the flange pose against the detected corners;
//! robocal's closed forms, its ML variants and the written estimate beside OpenCV's
//! `calibrateCamera` + `calibrateHandEye` on the same detections (`.venv/peers-cv2`, made by
//! `.ci/peers.sh`); the held-out floor; split-half stability against OpenCV Park; the stated 1σ
//! against the split half and the bootstrap.
//!
//!     cargo run --release --example real_handeye            # every set present
//!     cargo run --release --example real_handeye -- ur3e    # one set
//!
//! `ROBOCAL_SHARED_DATA` overrides `../shared/data`. A set that is absent is reported SKIPPED.
//! `ROBOCAL_RANDOM_HALVES=N` (default 10, 0 to skip): the split half is also measured on `N`
//! seeded random halvings of the views, robocal beside OpenCV Park on the same halves.
//! RWHE-Calib `kuka_2`, the set kept for evaluation (never tuned on, not in `../shared/data`),
//! is read from `ROBOCAL_REAL_KUKA2` (the repository `ihtishamaliktk/RWHE-Calib`'s
//! `Datasets/kuka_2` folder, unpacked anywhere outside the project):
//!
//!     ROBOCAL_REAL_KUKA2=/tmp/kuka_2 cargo run --release --example real_handeye -- kuka2
use std::path::PathBuf;
use std::time::Instant;

use robocal::solve::camera::realeval::{self, RealSet};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn main() {
    let filter = std::env::args().nth(1);
    let data = std::env::var_os("ROBOCAL_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join("../shared/data"));
    let py = root().join(".venv/peers-cv2/bin/python");
    let script = root().join("scripts/peers/camera_handeye_cv2.py");
    let peer = py.exists().then_some((py.as_path(), script.as_path()));
    if peer.is_none() {
        println!(
            "OpenCV peer SKIPPED: no {} (run .ci/peers.sh)",
            py.display()
        );
    }
    type Loader = fn(&std::path::Path) -> Result<RealSet, String>;
    let sets: [(&str, &str, Loader); 3] = [
        ("kuka1", "real-handeye-kuka1", realeval::load_kuka1),
        ("ur3e", "real-handeye-ur3e", |d| {
            realeval::load_ur3e(d, 12.5)
        }),
        ("kuka2", "real-handeye-kuka2", realeval::load_kuka2),
    ];
    let mut summary = vec![];
    for (key, dir, load) in sets {
        if filter.as_deref().is_some_and(|f| !key.contains(f)) {
            continue;
        }
        let dir = match (key, std::env::var_os("ROBOCAL_REAL_KUKA2")) {
            ("kuka2", Some(d)) => PathBuf::from(d),
            _ => data.join(dir),
        };
        if !dir.exists() {
            println!("\n=== {key}: SKIPPED — {} is absent ===", dir.display());
            continue;
        }
        let set = match load(&dir) {
            Ok(s) => s,
            Err(e) => {
                println!("\n=== {key}: cannot load: {e} ===");
                continue;
            }
        };
        let t0 = Instant::now();
        let (cam, failed) = realeval::detect_set(&set);
        let t_det = t0.elapsed().as_secs_f64();
        println!(
            "\n=== {} ({} images, board {}x{} x {} mm): detected {} in {t_det:.1} s ===",
            set.name,
            set.images.len(),
            set.board.cols,
            set.board.rows,
            set.board.square_mm,
            cam.views.len()
        );
        for (img, why) in &failed {
            println!("  not used: {img}: {why}");
        }
        let t1 = Instant::now();
        let r = match realeval::evaluate(&cam, peer, 50) {
            Ok(r) => r,
            Err(e) => {
                println!("  calibration failed: {e}");
                continue;
            }
        };
        let res = &r.result;
        println!(
            "{} train / {} held-out views; board-only RMS {:.3} px; distortion {:?}; rejected views {:?}; {:.1} s",
            r.n_train,
            r.n_held,
            r.board_only_px,
            res.distortion,
            res.rejected_views,
            t1.elapsed().as_secs_f64()
        );
        println!(
            "board scale the robot's motion implies: {:.4} ({:.3} mm squares against the declared {} mm)",
            res.implied_scale,
            res.implied_scale * set.board.square_mm,
            set.board.square_mm
        );
        if let Some((d, m)) = res.pose_noise {
            println!("robot pose noise implied by the data: {d:.4} deg, {m:.3} mm (1σ per axis)");
        }
        println!("internal CV (training views, 5 folds by view):");
        for (name, s) in &res.cv_scores {
            println!("  {name:<28} {s:.3} px");
        }
        println!("{:<30} {:>9} {:>11}", "method", "train px", "held-out px");
        for row in r.robocal.iter().chain(&r.opencv) {
            println!(
                "  {:<28} {:>9.3} {:>11.3}",
                row.method, row.train_px, row.heldout_px
            );
        }
        let best_cv = r
            .opencv
            .iter()
            .min_by(|a, b| a.heldout_px.total_cmp(&b.heldout_px));
        println!(
            "written: {} held-out {:.3} px; held-out floor (X, target fitted to the held-out views) {:.3} px, with the intrinsics free too {:.3} px",
            r.written.method, r.written.heldout_px, r.floor_px, r.floor_free_px
        );
        if let Some(b) = best_cv {
            println!(
                "best OpenCV ({}, OpenCV {}): {:.3} px -> written / best OpenCV = {:.3}; 0.85x = {:.3} px against the floors {:.3} ({:.3}x) / {:.3} ({:.3}x)",
                b.method,
                r.opencv_version,
                b.heldout_px,
                r.written.heldout_px / b.heldout_px,
                0.85 * b.heldout_px,
                r.floor_px,
                r.floor_px / b.heldout_px,
                r.floor_free_px,
                r.floor_free_px / b.heldout_px
            );
        }
        println!(
            "park-martin's X held, camera + target refitted by ML: held-out {:.3} px",
            r.park_refit_px
        );
        let s = &r.split;
        println!(
            "split half: written X ({} / {}) differs {:.2} mm / {:.3} deg; OpenCV Park {}",
            s.methods[0],
            s.methods[1],
            s.dx_mm,
            s.dr_deg,
            s.opencv_park
                .map_or("-".into(), |(t, d)| format!("{t:.2} mm / {d:.3} deg"))
        );
        for (m, t, d) in &s.per_method {
            println!("  split half of {m:<50} {t:6.2} mm / {d:.3} deg");
        }
        let n_random: usize = std::env::var("ROBOCAL_RANDOM_HALVES")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(10);
        let mut random = (f64::NAN, f64::NAN, 0, 0, f64::NAN);
        if n_random > 0 {
            match realeval::random_halves(&cam, peer, n_random, 7) {
                Ok(h) => {
                    let (r, p, le) = h.summary();
                    let each: Vec<String> = h
                        .dx_mm
                        .iter()
                        .map(|d| format!("{:.2}/{:.2}", d.0, d.1))
                        .collect();
                    println!(
                        "  {n_random} random halvings, ΔX robocal / OpenCV Park (mm): {}; mean {r:.2} / {p:.2}; robocal ≤ Park in {le} of {n_random}",
                        each.join(" ")
                    );
                    println!(
                        "  the same halvings, |ΔX| / combined stated σ ≤ 2: {:.0} % of {} coordinates",
                        100.0 * h.within_2sigma(),
                        6 * h.ratios.len()
                    );
                    for ((m, q), d) in h.methods.iter().zip(&h.ratios).zip(&h.dx_mm) {
                        println!(
                            "    {:.2} mm, |ΔX|/σ {:?}: {} / {}",
                            d.0,
                            q.map(|v| (v * 10.0).round() / 10.0),
                            m[0],
                            m[1]
                        );
                    }
                    random = (r, p, le, n_random, 100.0 * h.within_2sigma());
                }
                Err(e) => println!("  random halvings failed: {e}"),
            }
        }
        let ok = s.ratios.iter().filter(|q| **q <= 2.0).count();
        println!(
            "  |ΔX| / combined σ (x y z mm, rx ry rz deg): {:?} -> {ok}/6 ≤ 2",
            s.ratios.map(|q| (q * 100.0).round() / 100.0)
        );
        println!(
            "stated X 1σ {:?} mm, {:?} deg",
            r.sigma_mm.map(|v| (v * 1000.0).round() / 1000.0),
            r.sigma_deg.map(|v| (v * 10000.0).round() / 10000.0)
        );
        print!(
            "{}",
            robocal::solve::camera::calfile::sigma_parts_lines(&r.result)
        );
        if let Some((bt, br)) = r.bootstrap {
            let rat: Vec<f64> = (0..3)
                .map(|a| bt[a] / r.sigma_mm[a])
                .chain((0..3).map(|a| br[a] / r.sigma_deg[a]))
                .map(|q| (q * 100.0).round() / 100.0)
                .collect();
            println!(
                "bootstrap (50 view resamples) X 1σ {:?} mm, {:?} deg; bootstrap / stated {rat:?}",
                bt.map(|v| (v * 1000.0).round() / 1000.0),
                br.map(|v| (v * 10000.0).round() / 10000.0)
            );
        }
        summary.push((
            set.name.clone(),
            r.written.heldout_px,
            best_cv.map_or(f64::NAN, |b| b.heldout_px),
            r.floor_px,
            s.dx_mm,
            s.opencv_park.map_or(f64::NAN, |p| p.0),
            random,
            ok,
        ));
    }
    println!("\n| set | written held-out px | best OpenCV px | ratio | floor px | split-half X mm (robocal / Park) | random halvings: mean ΔX mm (robocal / Park), robocal ≤ Park, |ΔX|/σ ≤ 2 | σ ratios ≤ 2 |");
    println!("|---|---|---|---|---|---|---|---|");
    for (n, w, o, f, dx, dp, (rr, rp, le, nr, w2), ok) in summary {
        println!(
            "| {n} | {w:.3} | {o:.3} | {:.3} | {f:.3} | {dx:.2} / {dp:.2} | {rr:.2} / {rp:.2}, {le} of {nr}, {w2:.0} % | {ok}/6 |",
            w / o
        );
    }
}
