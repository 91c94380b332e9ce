//! Detector accuracy against the simulated world's TRUE corners, and the estimator on true
//! corners (is an error the detector's or the estimator's?).
//!
//!     cargo run --release --example camera_detector                 # 640×480, fx 900 (the test cell)
//!     cargo run --release --example camera_detector -- 1280x1024    # fx 1500, the benchmark camera
//!     cargo run --release --example camera_detector -- border       # boards touching the image edge
//!
//! For every view of the seed 004 shell plan on the clean UR5e camera cell: detected corners
//! (`robocal::solve::camera::detect`) minus the world's true projection of each corner
//! (`robocal_mocks::world::camera_board::true_corners`): mean (bias) and RMS, and the part of the
//! error that is a scale about the board's image centre (a radial shrink shows up as focal-length
//! bias). Then `camera::calibrate` on (a) the detected corners and (b) the true corners plus
//! 0.05 px Gaussian noise, hand-eye and intrinsics against truth.
#![allow(clippy::type_complexity)]
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

/// Views where the board's outermost inner corner lies `delta` px from an image edge (the
/// board whole, its margin cut): for each distance, 8 views (2 per image side) at random tilt
/// (≤ 20°) and roll, camera 560 mm from the board. Each detector's error on the corners within
/// 3 squares of that edge and on the whole board, against the world's true corners; OpenCV's
/// `findChessboardCorners` + `cornerSubPix` (11×11) and `findChessboardCornersSB` through the
/// peer script on the same images.
fn border_study(sc: &Scenario, spec: &BoardSpec) {
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    use rand::Rng;
    let cam = &sc.cameras[0];
    let board = sc.scene.chessboard.as_ref().unwrap();
    let bo = board.placement.isometry();
    let centre = bo
        * nalgebra::Point3::new(
            board.cols as f64 * board.square_mm / 2.0,
            board.rows as f64 * board.square_mm / 2.0,
            0.0,
        );
    let (w, h) = (cam.width as f64, cam.height as f64);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let dir = root().join("out/camera-detector/border");
    std::fs::create_dir_all(&dir).unwrap();
    let mut jobs = vec![];
    for &delta in &[1.5, 3.0, 5.0, 8.0, 12.0, 20.0] {
        for k in 0..8 {
            let side = k % 4;
            let tilt = UnitQuaternion::from_scaled_axis(Vector3::new(
                rng.random_range(-0.35..0.35),
                rng.random_range(-0.35..0.35),
                rng.random_range(-0.3..0.3),
            ));
            // Camera looking down (x right, y down in the image, z into the board).
            let down =
                UnitQuaternion::from_scaled_axis(Vector3::new(std::f64::consts::PI, 0.0, 0.0));
            let rot = tilt * down;
            let axis = rot * Vector3::z();
            let (ex, ey) = (rot * Vector3::x(), rot * Vector3::y());
            // Image direction towards the chosen side.
            let toward = match side {
                0 => -ex,
                1 => ex,
                2 => -ey,
                _ => ey,
            };
            let margin = |s: f64| -> f64 {
                let eye = centre.coords - axis * 560.0 - toward * s;
                let pose = Isometry3::from_parts(Translation3::from(eye), rot);
                let tc = camera_board::true_corners(cam, &pose, board);
                tc.iter()
                    .map(|t| match t {
                        Some([u, v]) => match side {
                            0 => u + 0.5,
                            1 => w - 0.5 - u,
                            2 => v + 0.5,
                            _ => h - 0.5 - v,
                        },
                        None => f64::NEG_INFINITY,
                    })
                    .fold(f64::INFINITY, f64::min)
            };
            // Bisection on the shift so that the nearest corner is `delta` from the edge.
            let (mut lo, mut hi) = (0.0, 400.0);
            if margin(lo) < delta {
                continue;
            }
            for _ in 0..60 {
                let m = 0.5 * (lo + hi);
                if margin(m) > delta {
                    lo = m;
                } else {
                    hi = m;
                }
            }
            let eye = centre.coords - axis * 560.0 - toward * lo;
            let pose = Isometry3::from_parts(Translation3::from(eye), rot);
            let truth = camera_board::true_corners(cam, &pose, board);
            let img = robocal_mocks::world::sensors::render(cam, &pose, Some(board), &mut rng);
            let path = dir.join(format!("d{delta}-{k}.pgm"));
            std::fs::write(
                &path,
                robocal_drivers::camera::pgm::encode(cam.width, cam.height, &img),
            )
            .unwrap();
            // Corners within 3 squares of that side (board order): by the true margin.
            let near: Vec<bool> = truth
                .iter()
                .map(|t| {
                    let [u, v] = t.unwrap();
                    let m = match side {
                        0 => u + 0.5,
                        1 => w - 0.5 - u,
                        2 => v + 0.5,
                        _ => h - 0.5 - v,
                    };
                    m < delta + 3.0 * cam.fx * board.square_mm / 560.0 * 0.5
                })
                .collect();
            jobs.push((delta, path, truth, near, img));
        }
    }
    // Ours.
    println!(
        "border study: {} views, {}x{}, camera 560 mm from the board",
        jobs.len(),
        cam.width,
        cam.height
    );
    let stats = |errs: &[f64]| -> (f64, f64) {
        let n = errs.len().max(1) as f64;
        (
            (errs.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
            errs.iter().cloned().fold(0.0, f64::max),
        )
    };
    let mut ours = std::collections::BTreeMap::<String, (usize, usize, Vec<f64>, Vec<f64>)>::new();
    for (delta, _, truth, near, img) in &jobs {
        let e = ours.entry(format!("{delta:>5.1}")).or_default();
        e.1 += 1;
        if let Ok(d) = detect::detect_chessboard(img, cam.width, cam.height, spec) {
            e.0 += 1;
            for ((d, t), n) in d.iter().zip(truth).zip(near) {
                let t = t.unwrap();
                let err = ((d[0] - t[0]).powi(2) + (d[1] - t[1]).powi(2)).sqrt();
                if *n {
                    e.2.push(err);
                }
                e.3.push(err);
            }
        }
    }
    println!("edge px  detector                         found   near-edge RMS / max px   all RMS / max px");
    for (k, (f, n, near, all)) in &ours {
        let (a, b) = stats(near);
        let (c, d) = stats(all);
        println!("{k}    robocal (calib-targets + subpix)  {f:>2}/{n:<2}   {a:>8.4} / {b:<8.4}        {c:.4} / {d:.4}");
    }
    // OpenCV.
    let py = root().join(".venv/peers-cv2/bin/python");
    if !py.exists() {
        println!("SKIP OpenCV: {} missing (run .ci/peers.sh)", py.display());
        return;
    }
    let job = serde_json::json!({
        "pattern": [spec.cols, spec.rows],
        "images": jobs.iter().map(|j| j.1.display().to_string()).collect::<Vec<_>>(),
    });
    let mut child = std::process::Command::new(&py)
        .arg(root().join("scripts/peers/chessboard_detect_cv2.py"))
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    use std::io::Write as _;
    child
        .stdin
        .take()
        .unwrap()
        .write_all(job.to_string().as_bytes())
        .unwrap();
    let o = child.wait_with_output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("peer JSON");
    for method in ["classic", "sb"] {
        let mut by =
            std::collections::BTreeMap::<String, (usize, usize, Vec<f64>, Vec<f64>)>::new();
        for (j, r) in jobs.iter().zip(v["results"].as_array().unwrap()) {
            let e = by.entry(format!("{:>5.1}", j.0)).or_default();
            e.1 += 1;
            let m = &r[method];
            if !m["found"].as_bool().unwrap_or(false) {
                continue;
            }
            e.0 += 1;
            // OpenCV orders corners its own way: match each to its nearest true corner.
            for c in m["corners"].as_array().unwrap() {
                let (u, w) = (c[0].as_f64().unwrap(), c[1].as_f64().unwrap());
                let (best, k) =
                    j.2.iter()
                        .enumerate()
                        .map(|(k, t)| {
                            let t = t.unwrap();
                            (((t[0] - u).powi(2) + (t[1] - w).powi(2)).sqrt(), k)
                        })
                        .fold((f64::INFINITY, 0), |a, b| if b.0 < a.0 { b } else { a });
                if j.3[k] {
                    e.2.push(best);
                }
                e.3.push(best);
            }
        }
        let name = if method == "classic" {
            "OpenCV findChessboardCorners+SubPix"
        } else {
            "OpenCV findChessboardCornersSB    "
        };
        for (k, (f, n, near, all)) in &by {
            let (a, b) = stats(near);
            let (c, d) = stats(all);
            println!("{k}    {name} {f:>2}/{n:<2}   {a:>8.4} / {b:<8.4}        {c:.4} / {d:.4}");
        }
    }
    println!(
        "(OpenCV {}; its corners matched to the nearest true corner)",
        v["opencv"].as_str().unwrap_or("?")
    );
}

fn main() {
    let size = std::env::args().nth(1).unwrap_or_else(|| "640x480".into());
    if size == "border" {
        let mut sc = Scenario::load(&root().join("mocks/scenarios/ur5e-camera.toml")).unwrap();
        sc.arms[0].errors = GeometricErrors::none();
        let b = sc.scene.chessboard.clone().unwrap();
        let spec = BoardSpec {
            cols: (b.cols - 1) as usize,
            rows: (b.rows - 1) as usize,
            square_mm: b.square_mm,
        };
        border_study(&sc, &spec);
        return;
    }
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
