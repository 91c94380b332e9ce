//! The per-view pose corrections' prior on the real eye-in-hand sets (issue 31 §3): X and the
//! target fitted with one flange correction per view under a prior of `alpha` times the pose
//! noise the data imply (isotropic, then the full 6×6 covariance; `solve::camera::viewcorr`),
//! intrinsics held at the board-only fit, every 4th view held out: the internal 5-fold CV on
//! the training views beside the held-out RMS, from `alpha → 0` (the flange poses treated as
//! exact) to the implied noise (`alpha = 1`).
//!
//!     cargo run --profile test --example realcam_prior -- ur3e   # or kuka
use nalgebra::{Isometry3, Matrix6};
use robocal::solve::camera::geom::mean_pose;
use robocal::solve::camera::handeye::{motion_pairs, solve, Method};
use robocal::solve::camera::intrinsics::calibrate_intrinsics;
use robocal::solve::camera::realeval::{self, split_every};
use robocal::solve::camera::{
    board_points, heldout_rms, posenoise, viewcorr, CameraData, DistModel,
};

fn vobs(d: &CameraData) -> Vec<viewcorr::ViewObs> {
    let pts = board_points(&d.board);
    d.views
        .iter()
        .map(|v| viewcorr::ViewObs {
            flange: v.flange,
            pts: v
                .corners
                .iter()
                .enumerate()
                .filter_map(|(k, c)| c.map(|c| (pts[k], c)))
                .collect(),
        })
        .collect()
}

fn main() {
    let which = std::env::args().nth(1).unwrap_or("ur3e".into());
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    let dir = root.join(if which == "kuka" {
        "real-handeye-kuka1"
    } else {
        "real-handeye-ur3e"
    });
    if !dir.exists() {
        println!("SKIPPED: {} is absent", dir.display());
        return;
    }
    let (set, model) = if which == "kuka" {
        (
            realeval::load_kuka1(&root.join("real-handeye-kuka1")).unwrap(),
            DistModel::K1K2,
        )
    } else {
        (
            realeval::load_ur3e(&root.join("real-handeye-ur3e"), 12.5).unwrap(),
            DistModel::K1,
        )
    };
    let (cam, _) = realeval::detect_set(&set);
    let (train, held) = split_every(&cam, 4);
    let fit = calibrate_intrinsics(&train, model).unwrap();
    let k = fit.k;
    let sp = fit.rms_px / 2f64.sqrt();
    let g: Vec<Isometry3<f64>> = train.views.iter().map(|v| v.flange).collect();
    let x0 = solve(Method::ParkMartin, &motion_pairs(&g, &fit.poses, 2.0)).unwrap();
    let b0 = mean_pose(
        &g.iter()
            .zip(&fit.poses)
            .map(|(g, t)| g * x0 * t)
            .collect::<Vec<_>>(),
    );
    let iso = posenoise::fit(&g, &fit.poses, &x0, &b0).unwrap();
    let full = posenoise::fit_full(&g, &fit.poses, &x0, &b0).unwrap();
    println!(
        "board-only rms {:.3}; iso noise {:.4} deg {:.3} mm",
        fit.rms_px, iso.sigma_deg, iso.sigma_mm
    );
    let n = train.views.len();
    for (name, sig) in [("iso", iso.noise_cov), ("full", full.noise_cov)] {
        for alpha in [1e-6, 1e-5, 3e-5, 1e-4, 3e-4, 1e-3, 1e-2] {
            let prior: Matrix6<f64> = sig * alpha;
            let t0 = std::time::Instant::now();
            let (mut se, mut nc) = (0.0, 0usize);
            for f in 0..5 {
                let tr = CameraData {
                    views: train
                        .views
                        .iter()
                        .enumerate()
                        .filter(|(i, _)| i % 5 != f)
                        .map(|(_, v)| v.clone())
                        .collect(),
                    ..train.clone()
                };
                let te = CameraData {
                    views: train
                        .views
                        .iter()
                        .enumerate()
                        .filter(|(i, _)| i % 5 == f)
                        .map(|(_, v)| v.clone())
                        .collect(),
                    ..train.clone()
                };
                let Some(r) = viewcorr::fit_fixed(&k, &vobs(&tr), &x0, &b0, &prior, sp) else {
                    se = f64::NAN;
                    break;
                };
                let h = heldout_rms(&te, &k, &r.x, &r.target, 1.0, [0.0; 2]);
                let c: usize = te
                    .views
                    .iter()
                    .map(|v| v.corners.iter().flatten().count())
                    .sum();
                se += h * h * c as f64;
                nc += c;
            }
            let cv = (se / nc as f64).sqrt();
            let all = viewcorr::fit_fixed(&k, &vobs(&train), &x0, &b0, &prior, sp).unwrap();
            let ho = heldout_rms(&held, &k, &all.x, &all.target, 1.0, [0.0; 2]);
            println!("{name} alpha {alpha:>7}: cv {cv:.3} px, held-out {ho:.3} px, corrected {:.3}, {:.1} s (n {n})", all.corrected_rms_px, t0.elapsed().as_secs_f64());
        }
    }
}
