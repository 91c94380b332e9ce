//! Detector accuracy against the simulated world's TRUE corners, and the estimator on true
//! corners (is an error the detector's or the estimator's?).
//!
//!     cargo run --release --example camera_detector                 # 640×480, fx 900 (the test cell)
//!     cargo run --release --example camera_detector -- 1280x1024    # fx 1500, the benchmark camera
//!     cargo run --release --example camera_detector -- border       # boards touching the image edge
//!     cargo run --release --example camera_detector -- charuco      # ChArUco: whole, partial, occluded
//!     cargo run --release --features opencv --example camera_detector [-- border]
//!                                      # + OpenCV's chessboard detectors through the Rust bindings
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
use robocal::solve::camera::charuco::{self, CharucoSpec};
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
    assert_eq!(robocal::main_with_args(args), 0);
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
    #[cfg(feature = "opencv")]
    for delta in ours.keys() {
        let imgs: Vec<(&[u8], &[Option<[f64; 2]>], Option<&[bool]>)> = jobs
            .iter()
            .filter(|j| format!("{:>5.1}", j.0) == *delta)
            .map(|j| (j.4.as_slice(), j.2.as_slice(), Some(j.3.as_slice())))
            .collect();
        opencv_rust(delta, cam.width, cam.height, spec, &imgs);
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

/// Statistics of one detector on one set of views: views with a detection, corners found of
/// the true corners inside the image, wrong ids (> 2 px from their id's true corner), error
/// mean / RMS / max (px) of the rest.
#[derive(Default)]
struct DetStats {
    views: usize,
    found_views: usize,
    inside: usize,
    found: usize,
    wrong: usize,
    errs: Vec<f64>,
    secs: f64,
}

impl DetStats {
    fn add(
        &mut self,
        det: Option<&[Option<[f64; 2]>]>,
        truth: &[Option<[f64; 2]>],
        inside: &[bool],
    ) {
        self.views += 1;
        self.inside += inside.iter().filter(|b| **b).count();
        let Some(det) = det else { return };
        self.found_views += 1;
        for ((d, t), ins) in det.iter().zip(truth).zip(inside) {
            if let (Some(d), Some(t)) = (d, t) {
                let e = ((d[0] - t[0]).powi(2) + (d[1] - t[1]).powi(2)).sqrt();
                if e > 2.0 {
                    self.wrong += 1;
                } else if *ins {
                    self.found += 1;
                    self.errs.push(e);
                }
            }
        }
    }
    fn row(&self, set: &str, det: &str) -> String {
        let n = self.errs.len().max(1) as f64;
        format!(
            "{set:<26} {det:<34} {:>3}/{:<3} {:>5}/{:<5} {:>5.1} % {:>4}   {:.4} / {:.4} / {:.4}{}",
            self.found_views,
            self.views,
            self.found,
            self.inside,
            100.0 * self.found as f64 / self.inside.max(1) as f64,
            self.wrong,
            self.errs.iter().sum::<f64>() / n,
            (self.errs.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
            self.errs.iter().cloned().fold(0.0, f64::max),
            if self.secs > 0.0 {
                format!(
                    "   {:.1} ms/image",
                    1e3 * self.secs / self.views.max(1) as f64
                )
            } else {
                String::new()
            }
        )
    }
}

/// A camera `dist` mm from the board point `(x, y)` (board frame), looking at it along the
/// board's +z (the side that reads a ChArUco board's markers), tilted by `tilt` (rad, about
/// the camera's x and y) and rolled by `roll` about its axis.
fn camera_at(
    b: &robocal_mocks::scenario::ChessboardConfig,
    x: f64,
    y: f64,
    dist: f64,
    tilt: [f64; 2],
    roll: f64,
) -> Isometry3<f64> {
    use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};
    let rot = b.placement.isometry().rotation
        * UnitQuaternion::from_scaled_axis(Vector3::new(tilt[0], tilt[1], 0.0))
        * UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, roll));
    let target = b.placement.isometry() * Point3::new(x, y, 0.0);
    let eye = target.coords - rot * Vector3::z() * dist;
    Isometry3::from_parts(Translation3::from(eye), rot)
}

/// ChArUco detector accuracy (`charuco` mode): the ChArUco cell's board seen whole (seed 004
/// shell at 520–600 mm), from close up (the charuco plan's shell at 250–350 mm: the board
/// overfills the view), with the image centre on a board edge (half the board outside) and
/// with a third of the view occluded. calib-targets' detector alone, with our sub-pixel
/// refinement, and OpenCV's `CharucoDetector` (Python peer) on the same images.
fn charuco_study() {
    use rand::Rng;
    let mut sc = Scenario::load(&root().join("mocks/scenarios/ur5e-camera-charuco.toml")).unwrap();
    sc.arms[0].errors = GeometricErrors::none();
    let cam = sc.cameras[0].clone();
    let b = sc.scene.chessboard.clone().unwrap();
    let m = b.charuco.clone().unwrap();
    let spec = CharucoSpec {
        cols: (b.cols - 1) as usize,
        rows: (b.rows - 1) as usize,
        square_mm: b.square_mm,
        marker_mm: m.marker_mm,
        dictionary: m.dictionary.clone(),
    };
    let (w, h) = (cam.width, cam.height);
    let dir = root().join("out/camera-detector/charuco");
    std::fs::create_dir_all(&dir).unwrap();
    let world = WorldHandle::from_scenario(&sc).unwrap();
    // (set, image, truth)
    let mut views: Vec<(&str, Vec<u8>, Vec<Option<[f64; 2]>>)> = vec![];
    let whole = plan(
        &root().join("plans/seed004-ur5e-camera.toml"),
        "[2, 2, 5]",
        4,
        false,
        &dir.join("whole.json"),
    );
    for s in shoot(&world, &sc, &whole) {
        views.push(("whole (shell 520-600 mm)", s.image, s.truth));
    }
    let close = plan(
        &root().join("plans/seed004-ur5e-camera-charuco.toml"),
        "[2, 2, 5]",
        4,
        false,
        &dir.join("close.json"),
    );
    for s in shoot(&world, &sc, &close) {
        views.push(("close (shell 250-350 mm)", s.image, s.truth));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(23);
    let (bw, bh) = (b.cols as f64 * b.square_mm, b.rows as f64 * b.square_mm);
    for k in 0..16 {
        let (x, y) = match k % 4 {
            0 => (0.0, bh / 2.0),
            1 => (bw, bh / 2.0),
            2 => (bw / 2.0, 0.0),
            _ => (bw / 2.0, bh),
        };
        let pose = camera_at(
            &b,
            x,
            y,
            rng.random_range(350.0..500.0),
            [rng.random_range(-0.35..0.35), rng.random_range(-0.35..0.35)],
            rng.random_range(-3.1..3.1),
        );
        let img = robocal_mocks::world::sensors::render(&cam, &pose, Some(&b), &mut rng);
        views.push((
            "half outside (edge-centred)",
            img,
            camera_board::true_corners(&cam, &pose, &b),
        ));
    }
    for k in 0..16 {
        // Half the views: a card over a fifth of the columns; the others: the middle third.
        let (u0, u1) = if k % 2 == 0 {
            (2 * w as usize / 5, 3 * w as usize / 5)
        } else {
            (w as usize / 3, 2 * w as usize / 3)
        };
        let pose = camera_at(
            &b,
            bw / 2.0,
            bh / 2.0,
            rng.random_range(520.0..600.0),
            [rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3)],
            rng.random_range(-3.1..3.1),
        );
        let mut img = robocal_mocks::world::sensors::render(&cam, &pose, Some(&b), &mut rng);
        let mut truth = camera_board::true_corners(&cam, &pose, &b);
        // A grey card over columns u0..u1: its corners are gone.
        for v in 0..h as usize {
            for u in u0..u1 {
                img[v * w as usize + u] = 140;
            }
        }
        for t in truth.iter_mut() {
            if t.is_some_and(|p| p[0] > u0 as f64 - 3.0 && p[0] < u1 as f64 + 2.0) {
                *t = None;
            }
        }
        views.push((
            if k % 2 == 0 {
                "occluded (middle fifth)"
            } else {
                "occluded (middle third)"
            },
            img,
            truth,
        ));
    }
    let inside: Vec<Vec<bool>> = views
        .iter()
        .map(|(_, _, t)| {
            t.iter()
                .map(|t| {
                    t.is_some_and(|p| {
                        p[0] >= 0.0
                            && p[1] >= 0.0
                            && p[0] <= w as f64 - 1.0
                            && p[1] <= h as f64 - 1.0
                    })
                })
                .collect()
        })
        .collect();
    let paths: Vec<PathBuf> = views
        .iter()
        .enumerate()
        .map(|(i, (_, img, _))| {
            let p = dir.join(format!("v{i:03}.pgm"));
            std::fs::write(&p, robocal_drivers::camera::pgm::encode(w, h, img)).unwrap();
            p
        })
        .collect();
    println!(
        "ChArUco {}x{} squares, {} mm squares, {} mm markers, {}; camera {}x{} fx {} k1 {} blur {} px noise {} grey; {} views",
        b.cols, b.rows, b.square_mm, m.marker_mm, m.dictionary, w, h, cam.fx, cam.k1, cam.blur_px, cam.noise_grey, views.len()
    );
    let sets: Vec<&str> = {
        let mut s: Vec<&str> = views.iter().map(|v| v.0).collect();
        s.sort_by_key(|n| views.iter().position(|v| v.0 == *n));
        s.dedup();
        s
    };
    type Stats = std::collections::BTreeMap<(usize, usize), DetStats>;
    let mut st: Stats = Stats::new();
    let set_of = |name: &str| sets.iter().position(|s| *s == name).unwrap();
    for (i, (set, img, truth)) in views.iter().enumerate() {
        let si = set_of(set);
        let t0 = std::time::Instant::now();
        let raw = charuco::detect_raw(img, w, h, &spec).ok();
        let t_raw = t0.elapsed().as_secs_f64();
        let refined = raw.clone().map(|mut c| {
            charuco::refine(img, w, h, &spec, &mut c);
            c
        });
        let t_all = t0.elapsed().as_secs_f64();
        for (d, det, secs) in [(0, &raw, t_raw), (1, &refined, t_all)] {
            let e = st.entry((si, d)).or_default();
            e.add(det.as_deref(), truth, &inside[i]);
            e.secs += secs;
        }
    }
    // OpenCV through the peer script.
    let py = root().join(".venv/peers-cv2/bin/python");
    let mut cv_version = None;
    if py.exists() {
        let job = serde_json::json!({
            "squares": [b.cols, b.rows],
            "square_mm": b.square_mm,
            "marker_mm": m.marker_mm,
            "dictionary": m.dictionary,
            "images": paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        });
        let t0 = std::time::Instant::now();
        let v = run_peer(&py, "charuco_detect_cv2.py", &job);
        let secs = t0.elapsed().as_secs_f64();
        cv_version = v["opencv"].as_str().map(str::to_string);
        for (i, ((set, _, truth), r)) in views
            .iter()
            .zip(v["results"].as_array().unwrap())
            .enumerate()
        {
            let si = set_of(set);
            let det = r["found"].as_bool().unwrap_or(false).then(|| {
                let mut c = vec![None; spec.cols * spec.rows];
                for (id, p) in r["ids"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .zip(r["corners"].as_array().unwrap())
                {
                    let id = id.as_u64().unwrap() as usize;
                    if id < c.len() {
                        c[id] = Some([p[0].as_f64().unwrap(), p[1].as_f64().unwrap()]);
                    }
                }
                c
            });
            let e = st.entry((si, 2)).or_default();
            e.add(det.as_deref(), truth, &inside[i]);
            e.secs += secs / views.len() as f64;
        }
    } else {
        println!("SKIP OpenCV: {} missing (run .ci/peers.sh)", py.display());
    }
    println!(
        "{:<26} {:<34} {:>7} {:>11} {:>7} {:>4}   err mean / RMS / max px",
        "views", "detector", "views", "corners", "rate", "bad"
    );
    let names = [
        "calib-targets 0.16 (raw)",
        "calib-targets + robocal subpix",
        "OpenCV CharucoDetector (Python)",
    ];
    for (si, set) in sets.iter().enumerate() {
        for (d, name) in names.iter().enumerate() {
            if let Some(e) = st.get(&(si, d)) {
                println!("{}", e.row(set, name));
            }
        }
    }
    println!(
        "(corners: found with their id within 2 px of the id's true corner / true corners inside the image; bad = labelled more than 2 px off{})",
        cv_version.map_or(String::new(), |v| format!("; OpenCV {v}, timing includes the Python process"))
    );
}

/// Run a peer script of `scripts/peers/` with a JSON job on stdin; its JSON reply.
fn run_peer(py: &Path, script: &str, job: &serde_json::Value) -> serde_json::Value {
    use std::io::Write as _;
    let mut child = std::process::Command::new(py)
        .arg(root().join("scripts/peers").join(script))
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(job.to_string().as_bytes())
        .unwrap();
    let o = child.wait_with_output().unwrap();
    serde_json::from_slice(&o.stdout).expect("peer JSON")
}

/// OpenCV's chessboard detectors through the Rust bindings (feature `opencv`:
/// `robocal_drivers::camera::opencv::find_chessboard`, i.e. `findChessboardCorners` with
/// adaptive threshold + normalisation, then `cornerSubPix` with a half-window of 0.4 × the
/// corner spacing (≤ 11 px); and `findChessboardCornersSB` with EXHAUSTIVE | ACCURACY) on the
/// same images, each corner matched to its nearest true corner. `near` marks the corners near
/// an image edge (border study), if any.
#[cfg(feature = "opencv")]
fn opencv_rust(
    label: &str,
    w: u32,
    h: u32,
    spec: &BoardSpec,
    imgs: &[(&[u8], &[Option<[f64; 2]>], Option<&[bool]>)],
) {
    use robocal_drivers::camera::opencv::{find_chessboard, Detector};
    for (det, name) in [
        (
            Detector::Classic,
            "OpenCV-Rust findChessboardCorners+SubPix",
        ),
        (Detector::SectorBased, "OpenCV-Rust findChessboardCornersSB"),
    ] {
        let (mut found, mut all, mut near) = (0, vec![], vec![]);
        let t0 = std::time::Instant::now();
        for (img, truth, nmask) in imgs {
            let im = robocal_drivers::Image {
                width: w,
                height: h,
                data: img.to_vec(),
                t: 0.0,
            };
            let Ok(Some(c)) = find_chessboard(&im, spec.cols as u32, spec.rows as u32, det) else {
                continue;
            };
            found += 1;
            for p in c {
                let (e, k) = truth
                    .iter()
                    .enumerate()
                    .filter_map(|(k, t)| {
                        t.map(|t| (((t[0] - p[0]).powi(2) + (t[1] - p[1]).powi(2)).sqrt(), k))
                    })
                    .fold((f64::INFINITY, 0), |a, b| if b.0 < a.0 { b } else { a });
                all.push(e);
                if nmask.is_some_and(|m| m[k]) {
                    near.push(e);
                }
            }
        }
        let secs = t0.elapsed().as_secs_f64();
        let st = |e: &[f64]| {
            let n = e.len().max(1) as f64;
            (
                e.iter().sum::<f64>() / n,
                (e.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
                e.iter().cloned().fold(0.0, f64::max),
            )
        };
        let (a, r, m) = st(&all);
        let mut line = format!(
            "{label}: {name:<42} {found}/{} views, all corners mean {a:.4} RMS {r:.4} max {m:.4} px",
            imgs.len()
        );
        if imgs.iter().any(|i| i.2.is_some()) {
            let (a, r, m) = st(&near);
            line += &format!(", near-edge mean {a:.4} RMS {r:.4} max {m:.4} px");
        }
        line += &format!(", {:.1} ms/image", 1e3 * secs / imgs.len().max(1) as f64);
        println!("{line}");
    }
}

fn main() {
    let size = std::env::args().nth(1).unwrap_or_else(|| "640x480".into());
    if size == "charuco" {
        charuco_study();
        return;
    }
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
    // Every corner's error (for the detector table) and OpenCV through the Rust bindings.
    let errs: Vec<f64> = shots
        .iter()
        .chain(&hshots)
        .zip(&detected)
        .filter_map(|(s, d)| d.as_ref().map(|d| (s, d)))
        .flat_map(|(s, d)| {
            d.iter().zip(&s.truth).filter_map(|(d, t)| {
                t.map(|t| ((d[0] - t[0]).powi(2) + (d[1] - t[1]).powi(2)).sqrt())
            })
        })
        .collect();
    println!(
        "robocal (calib-targets + subpix): {}/{} views, all corners mean {:.4} max {:.4} px",
        detected.iter().filter(|d| d.is_some()).count(),
        detected.len(),
        errs.iter().sum::<f64>() / errs.len().max(1) as f64,
        errs.iter().cloned().fold(0.0, f64::max)
    );
    #[cfg(feature = "opencv")]
    {
        let imgs: Vec<(&[u8], &[Option<[f64; 2]>], Option<&[bool]>)> = shots
            .iter()
            .chain(&hshots)
            .map(|s| (s.image.as_slice(), s.truth.as_slice(), None))
            .collect();
        opencv_rust("shell views", c.width, c.height, &spec, &imgs);
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
