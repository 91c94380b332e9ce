//! Detector accuracy against the simulated world's TRUE corners, and the estimator on true
//! corners (is an error the detector's or the estimator's?).
//!
//!     cargo run --release --example camera_detector                 # 640×480, fx 900 (the test cell)
//!     cargo run --release --example camera_detector -- 1280x1024    # fx 1500, the benchmark camera
//!
//! For every view of the seed 004 shell plan on the clean UR5e camera cell: detected corners
//! (`robocal::solve::camera::detect`) minus the world's true projection of each corner
//! (`robocal_mocks::world::camera_board::true_corners`): mean (bias) and RMS, and the part of the
//! error that is a scale about the board's image centre (a radial shrink shows up as focal-length
//! bias). Then `camera::calibrate` on (a) the detected corners and (b) the true corners plus
//! 0.05 px Gaussian noise, hand-eye and intrinsics against truth.
use std::path::{Path, PathBuf};

use nalgebra::Isometry3;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use robocal::plan::PlanFile;
use robocal::solve::camera::detect::{self, BoardSpec};
use robocal::solve::camera::geom::{self};
use robocal::solve::camera::{self, CameraData, Mount, Options, View};
use robocal_drivers::traits::MoveSpeed;
use robocal_mocks::scenario::GeometricErrors;
use robocal_mocks::world::camera_board;
use robocal_mocks::{Scenario, WorldHandle};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn plan(spec: &Path, strata: &str, seed: u64, jitter: bool, out: &Path) -> PlanFile {
    let text = std::fs::read_to_string(spec).unwrap();
    let t: String = text
        .lines()
        .map(|l| match l.split('=').next().unwrap_or("").trim() {
            "strata" => format!("strata = {strata}"),
            "seed" => format!("seed = {seed}"),
            "jitter" => format!("jitter = {jitter}"),
            _ => l.to_string(),
        })
        .collect::<Vec<_>>()
        .join("\n");
    let sp = out.with_extension("toml");
    std::fs::write(&sp, t).unwrap();
    let args: Vec<String> = [
        "robocal",
        "plan",
        "--spec",
        sp.to_str().unwrap(),
        "--robot",
        "ur5e",
        "--out",
        out.to_str().unwrap(),
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    assert_eq!(robocal::cli::run(args), 0);
    PlanFile::read(out).unwrap()
}

struct Shot {
    id: u64,
    flange: Isometry3<f64>,
    image: Vec<u8>,
    truth: Vec<Option<[f64; 2]>>,
}

fn shoot(world: &WorldHandle, sc: &Scenario, plan: &PlanFile) -> Vec<Shot> {
    let cam = &sc.cameras[0];
    let board = sc.scene.chessboard.as_ref().unwrap();
    plan.poses
        .iter()
        .map(|p| {
            let q: Vec<f64> = p.q_deg.iter().map(|d| d.to_radians()).collect();
            let dur = world.arm_start_move(0, &q, MoveSpeed::default()).unwrap();
            world.advance(dur + 0.05);
            let flange = world.arm_controller_flange(0);
            let img = world.render_camera_of(0);
            let pose = world.camera_in_base(0).unwrap();
            Shot {
                id: p.id,
                flange,
                image: img.data,
                truth: camera_board::true_corners(cam, &pose, board),
            }
        })
        .collect()
}

fn main() {
    let size = std::env::args().nth(1).unwrap_or_else(|| "640x480".into());
    let mut sc = Scenario::load(&root().join("mocks/scenarios/ur5e-camera.toml")).unwrap();
    sc.arms[0].errors = GeometricErrors::none();
    if size == "1280x1024" {
        let c = &mut sc.cameras[0];
        (c.width, c.height, c.fx, c.fy, c.cx, c.cy, c.k1, c.k2) =
            (1280, 1024, 1500.0, 1500.0, 640.0, 512.0, -0.08, 0.02);
    }
    let c = sc.cameras[0].clone();
    let b = sc.scene.chessboard.clone().unwrap();
    let spec = BoardSpec {
        cols: (b.cols - 1) as usize,
        rows: (b.rows - 1) as usize,
        square_mm: b.square_mm,
    };
    let dir = root().join("out/camera-detector");
    std::fs::create_dir_all(&dir).unwrap();
    let spec_path = root().join("plans/seed004-ur5e-camera.toml");
    let train = plan(&spec_path, "[2, 2, 5]", 4, false, &dir.join("train.json"));
    let held = plan(&spec_path, "[1, 1, 6]", 5, true, &dir.join("held.json"));
    let world = WorldHandle::from_scenario(&sc).unwrap();
    let shots = shoot(&world, &sc, &train);
    let hshots = shoot(&world, &sc, &held);
    println!(
        "camera {}x{} fx {} k1 {} blur {} px noise {} grey; board {}x{} inner, {} mm",
        c.width,
        c.height,
        c.fx,
        c.k1,
        c.blur_px,
        c.noise_grey,
        spec.cols,
        spec.rows,
        spec.square_mm
    );
    let mut all = vec![];
    let t0 = std::time::Instant::now();
    let detected: Vec<Option<Vec<[f64; 2]>>> = shots
        .iter()
        .chain(&hshots)
        .map(|s| detect::detect_chessboard(&s.image, c.width, c.height, &spec).ok())
        .collect();
    let t_det = t0.elapsed().as_secs_f64();
    println!(
        "detection of {} images: {t_det:.2} s",
        shots.len() + hshots.len()
    );
    println!("view   n   bias_u   bias_v    rms   scale-1(ppm)");
    for (s, d) in shots.iter().chain(&hshots).zip(&detected) {
        let Some(d) = d else {
            println!("{:>4}  no board", s.id);
            continue;
        };
        let pairs: Vec<([f64; 2], [f64; 2])> = d
            .iter()
            .zip(&s.truth)
            .filter_map(|(d, t)| t.map(|t| (*d, t)))
            .collect();
        let n = pairs.len() as f64;
        let (mu, mv) = pairs.iter().fold((0.0, 0.0), |a, (d, t)| {
            (a.0 + (d[0] - t[0]) / n, a.1 + (d[1] - t[1]) / n)
        });
        let rms = (pairs
            .iter()
            .map(|(d, t)| (d[0] - t[0]).powi(2) + (d[1] - t[1]).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        // Scale about the centroid of the true corners: e - mean ≈ s (t - c).
        let (cu, cv) = pairs
            .iter()
            .fold((0.0, 0.0), |a, (_, t)| (a.0 + t[0] / n, a.1 + t[1] / n));
        let (mut num, mut den) = (0.0, 0.0);
        for (d, t) in &pairs {
            let (ru, rv) = (t[0] - cu, t[1] - cv);
            num += (d[0] - t[0] - mu) * ru + (d[1] - t[1] - mv) * rv;
            den += ru * ru + rv * rv;
        }
        let sc_ppm = num / den * 1e6;
        println!(
            "{:>4} {:>3} {mu:>8.4} {mv:>8.4} {rms:>6.4} {sc_ppm:>10.0}",
            s.id,
            pairs.len()
        );
        all.push((mu, mv, rms, sc_ppm));
    }
    let n = all.len() as f64;
    let m = |f: fn(&(f64, f64, f64, f64)) -> f64| all.iter().map(f).sum::<f64>() / n;
    println!(
        "mean over {} views: bias u {:.4} v {:.4} px, RMS {:.4} px, scale {:.0} ppm",
        all.len(),
        m(|a| a.0),
        m(|a| a.1),
        (all.iter().map(|a| a.2 * a.2).sum::<f64>() / n).sqrt(),
        m(|a| a.3)
    );
    // Estimator on detected vs true corners.
    let mk =
        |sh: &[Shot], corners: &dyn Fn(usize, &Shot) -> Option<Vec<Option<[f64; 2]>>>| CameraData {
            width: c.width,
            height: c.height,
            board: spec,
            mount: Mount::Flange,
            views: sh
                .iter()
                .enumerate()
                .filter_map(|(i, s)| {
                    corners(i, s).map(|cs| View {
                        id: s.id,
                        flange: s.flange,
                        corners: cs,
                    })
                })
                .collect(),
        };
    let nt = shots.len();
    let det_train = mk(&shots, &|i, _| {
        detected[i]
            .as_ref()
            .map(|d| d.iter().map(|p| Some(*p)).collect())
    });
    let det_held = mk(&hshots, &|i, _| {
        detected[nt + i]
            .as_ref()
            .map(|d| d.iter().map(|p| Some(*p)).collect())
    });
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let sigma: f64 = std::env::var("NOISE_PX")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0.05);
    let noise = Normal::new(0.0, sigma.max(1e-300)).unwrap();
    let mut noisy = |s: &Shot| -> Option<Vec<Option<[f64; 2]>>> {
        Some(
            s.truth
                .iter()
                .map(|t| t.map(|t| [t[0] + noise.sample(&mut rng), t[1] + noise.sample(&mut rng)]))
                .collect(),
        )
    };
    let true_train = {
        let cs: Vec<_> = shots.iter().map(&mut noisy).collect();
        mk(&shots, &|i, _| cs[i].clone())
    };
    let true_held = {
        let cs: Vec<_> = hshots.iter().map(&mut noisy).collect();
        mk(&hshots, &|i, _| cs[i].clone())
    };
    let x_true = c.placement.isometry();
    for (name, tr, he) in [
        ("detected corners", &det_train, &det_held),
        ("true corners + NOISE_PX noise", &true_train, &true_held),
    ] {
        let t1 = std::time::Instant::now();
        let res = camera::calibrate(tr, Some(he), &Options::default()).unwrap();
        let (dt, dr) = geom::pose_error(&res.ml.x, &x_true);
        let k = &res.ml.intrinsics;
        println!(
            "{name}: {} views, {:.2} s; ML hand-eye {dt:.4} mm {dr:.5} deg; fx {:.3} fy {:.3} cx {:.3} cy {:.3} k1 {:.5} k2 {:.5} (true {} {} {} {} {} {}); intrinsics-only fx {:.3}; held-out {:.4} px; dist {:?}",
            tr.views.len(),
            t1.elapsed().as_secs_f64(),
            k.fx, k.fy, k.cx, k.cy, k.dist[0], k.dist[1], c.fx, c.fy, c.cx, c.cy, c.k1, c.k2,
            res.intrinsics_only.fx,
            res.ml.heldout_rms_px.unwrap_or(f64::NAN),
            res.distortion
        );
        for e in &res.closed_form {
            let (dt, dr) = geom::pose_error(&e.x, &x_true);
            println!("   {:<12} {dt:.4} mm {dr:.5} deg", e.method);
        }
    }
}
