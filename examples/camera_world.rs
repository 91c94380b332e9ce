//! Camera calibration + eye-in-hand hand-eye on simulated worlds (seed 004), against truth and
//! against OpenCV (`cv2.calibrateCamera` + `cv2.calibrateHandEye`, all five methods, venv
//! `.venv/peers-cv2`) on the same corners; detector accuracy of both detectors against the
//! world's true corners; timing of detection + calibration.
//!
//!     cargo run --release --example camera_world            # every world
//!     cargo run --release --example camera_world -- clean   # worlds whose name contains "clean"
//!
//! Each world: the seed 004 shell plan (60 training viewpoints, `robocal plan`) and a separate
//! jittered held-out shell plan (20 viewpoints), the arm driven through the world, one
//! 1280×1024 image per pose rendered by the world, a `robocal-dataset/1` file with the
//! `camera` / `target` header blocks written to `out/camera-world/<world>/` (so
//! `robocal calibrate camera --data out/camera-world/<world>/train.jsonl --heldout
//! .../heldout.jsonl --out DIR` runs on the same files). The undeclared-effect worlds: board
//! printed 0.4 % large (declared square as designed), board bowed 0.4 mm, arm joint offsets
//! 0.05° each; the diagnosis (`robocal::diagnose::camera`) names and compensates them.
#![allow(clippy::type_complexity)]
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde_json::json;

use robocal::plan::PlanFile;
use robocal::solve::camera::data::{load, Overrides};
use robocal::solve::camera::geom::{self, Intrinsics};
use robocal::solve::camera::{self, CameraData, Options};
use robocal_drivers::traits::MoveSpeed;
use robocal_mocks::scenario::GeometricErrors;
use robocal_mocks::world::camera_board;
use robocal_mocks::{Scenario, WorldHandle};

struct Case {
    name: &'static str,
    scenario: &'static str,
    spec: &'static str,
    robot: &'static str,
    /// Change the world (hidden from the estimator).
    modify: fn(&mut Scenario),
}

fn clean(s: &mut Scenario) {
    s.arms[0].errors = GeometricErrors::none();
    let c = &mut s.cameras[0];
    (c.width, c.height, c.fx, c.fy, c.cx, c.cy, c.k1, c.k2) =
        (1280, 1024, 1500.0, 1500.0, 640.0, 512.0, -0.08, 0.02);
}
fn scale(s: &mut Scenario) {
    clean(s);
    s.scene.chessboard.as_mut().unwrap().square_mm *= 1.004;
}
fn bend(s: &mut Scenario) {
    clean(s);
    s.scene.chessboard.as_mut().unwrap().bend_mm = 0.4;
}
fn offsets(s: &mut Scenario) {
    clean(s);
    s.arms[0].errors = GeometricErrors {
        origin_mm: [0.0, 0.0],
        origin_deg: [0.0, 0.0],
        offset_deg: [0.045, 0.055],
        seed: Some(17),
    };
}
fn vs060(s: &mut Scenario) {
    s.arms[0].errors = GeometricErrors::none();
}

const CASES: &[Case] = &[
    Case {
        name: "ur5e-clean",
        scenario: "mocks/scenarios/ur5e-camera.toml",
        spec: "plans/seed004-ur5e-camera.toml",
        robot: "ur5e",
        modify: clean,
    },
    Case {
        name: "ur5e-board-scale",
        scenario: "mocks/scenarios/ur5e-camera.toml",
        spec: "plans/seed004-ur5e-camera.toml",
        robot: "ur5e",
        modify: scale,
    },
    Case {
        name: "ur5e-board-bend",
        scenario: "mocks/scenarios/ur5e-camera.toml",
        spec: "plans/seed004-ur5e-camera.toml",
        robot: "ur5e",
        modify: bend,
    },
    Case {
        name: "ur5e-joint-offsets",
        scenario: "mocks/scenarios/ur5e-camera.toml",
        spec: "plans/seed004-ur5e-camera.toml",
        robot: "ur5e",
        modify: offsets,
    },
    Case {
        name: "vs060-clean",
        scenario: "mocks/scenarios/vs060-camera.toml",
        spec: "plans/seed004-vs060-camera.toml",
        robot: "denso-vs060",
        modify: vs060,
    },
];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Plan the shell spec with `strata`, `seed`, `jitter`, `group` replaced.
fn plan(
    spec: &Path,
    robot: &str,
    strata: &str,
    seed: u64,
    jitter: bool,
    group: &str,
    out: &Path,
) -> PlanFile {
    let text = std::fs::read_to_string(spec).unwrap();
    let t: String = text
        .lines()
        .map(|l| match l.split('=').next().unwrap_or("").trim() {
            "strata" => format!("strata = {strata}"),
            "seed" => format!("seed = {seed}"),
            "jitter" => format!("jitter = {jitter}"),
            "group" => format!("group = \"{group}\""),
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
        robot,
        "--out",
        out.to_str().unwrap(),
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    assert_eq!(
        robocal::main_with_args(args),
        0,
        "planning {}",
        sp.display()
    );
    PlanFile::read(out).unwrap()
}

struct Acquired {
    path: PathBuf,
    /// True corners per view (board order) and true camera pose.
    truth: Vec<(Vec<Option<[f64; 2]>>, Isometry3<f64>)>,
    images: Vec<PathBuf>,
}

fn quat_of(p: &Isometry3<f64>) -> [f64; 4] {
    let q = p.rotation;
    [q.w, q.i, q.j, q.k]
}

/// Drive the world through the plan, render, write the dataset (declared board = `declared`).
fn acquire(
    world: &WorldHandle,
    sc: &Scenario,
    plan: &PlanFile,
    dir: &Path,
    stem: &str,
    robot: &str,
    declared_square: f64,
) -> Acquired {
    let img_dir = dir.join(format!("{stem}.images"));
    std::fs::create_dir_all(&img_dir).unwrap();
    let cam = &sc.cameras[0];
    let board = sc.scene.chessboard.as_ref().unwrap();
    let mut lines = vec![json!({
        "format": "robocal-dataset/1",
        "robot": {"model": robot},
        "camera": {"kind": "mono", "width": cam.width, "height": cam.height, "name": cam.name, "mount": "flange"},
        "target": {"kind": "chessboard", "cols": board.cols - 1, "rows": board.rows - 1, "square_mm": declared_square},
        "plan": {"name": plan.name},
    })
    .to_string()];
    let mut truth = vec![];
    let mut images = vec![];
    for p in &plan.poses {
        let q: Vec<f64> = p.q_deg.iter().map(|d| d.to_radians()).collect();
        let dur = world.arm_start_move(0, &q, MoveSpeed::default()).unwrap();
        world.advance(dur + 0.05);
        let js = world.arm_joint_state(0);
        let f = world.arm_controller_flange(0);
        let img = world.render_camera_of(0);
        let cam_pose = world.camera_in_base(0).unwrap();
        let name = format!("pose-{}.pgm", p.id);
        let path = img_dir.join(&name);
        std::fs::write(
            &path,
            robocal_drivers::camera::pgm::encode(img.width, img.height, &img.data),
        )
        .unwrap();
        images.push(path);
        truth.push((camera_board::true_corners(cam, &cam_pose, board), cam_pose));
        let t = f.translation.vector;
        lines.push(
            json!({"kind": "pose", "id": p.id, "t": world.now(), "group": plan.poses.first().map(|_| stem),
                   "q": js.q.iter().map(|r| r.to_degrees()).collect::<Vec<_>>(),
                   "flange": {"p": [t.x, t.y, t.z], "quat": quat_of(&f)},
                   "image": format!("{stem}.images/{name}")})
            .to_string(),
        );
    }
    let path = dir.join(format!("{stem}.jsonl"));
    std::fs::write(&path, lines.join("\n") + "\n").unwrap();
    Acquired {
        path,
        truth,
        images,
    }
}

fn k_true(sc: &Scenario) -> Intrinsics {
    let c = &sc.cameras[0];
    Intrinsics {
        fx: c.fx,
        fy: c.fy,
        cx: c.cx,
        cy: c.cy,
        dist: [c.k1, c.k2, 0.0, 0.0, 0.0],
    }
}

/// RMS (px) of predicted corners against TRUE corners of the held-out views, under the full
/// model of an estimate (board scale and bend; the flange poses of `data`, which the caller
/// corrects for identified joint offsets).
fn truth_rms(
    data: &CameraData,
    acq: &Acquired,
    k: &Intrinsics,
    x: &Isometry3<f64>,
    target: &Isometry3<f64>,
    scale: f64,
    bend: [f64; 2],
) -> f64 {
    // The held-out views with the world's true corners in place of the detected ones: the
    // residuals of the prediction are then prediction minus truth.
    let views = data
        .views
        .iter()
        .enumerate()
        .map(|(v, view)| camera::View {
            corners: acq.truth[v].0.clone(),
            ..view.clone()
        })
        .collect();
    let d = CameraData {
        views,
        ..data.clone()
    };
    camera::heldout_rms(&d, k, x, target, scale, bend)
}

fn he_err(x: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64) {
    geom::pose_error(x, truth)
}

fn main() {
    let filter: Option<String> = std::env::args().nth(1);
    let out = root().join("out/camera-world");
    let py = root().join(".venv/peers-cv2/bin/python");
    let mut summary = vec![];
    for case in CASES
        .iter()
        .filter(|c| filter.as_ref().is_none_or(|f| c.name.contains(f.as_str())))
    {
        let dir = out.join(case.name);
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut sc = Scenario::load(&root().join(case.scenario)).unwrap();
        let declared = sc.scene.chessboard.as_ref().unwrap().square_mm;
        (case.modify)(&mut sc);
        let spec = root().join(case.spec);
        let train_plan = plan(
            &spec,
            case.robot,
            "[2, 3, 10]",
            4,
            false,
            "train",
            &dir.join("train-plan.json"),
        );
        let held_plan = plan(
            &spec,
            case.robot,
            "[1, 2, 10]",
            5,
            true,
            "validation",
            &dir.join("heldout-plan.json"),
        );
        let world = WorldHandle::from_scenario(&sc).unwrap();
        let t0 = Instant::now();
        let tr = acquire(
            &world,
            &sc,
            &train_plan,
            &dir,
            "train",
            case.robot,
            declared,
        );
        let he = acquire(
            &world, &sc, &held_plan, &dir, "heldout", case.robot, declared,
        );
        let t_render = t0.elapsed().as_secs_f64();
        // Detection + calibration (timed).
        let t1 = Instant::now();
        let train = load(&tr.path, &Overrides::default(), false).unwrap();
        let t_detect = t1.elapsed().as_secs_f64();
        let held = load(&he.path, &Overrides::default(), false).unwrap();
        let t2 = Instant::now();
        let res = camera::calibrate(
            &train.data,
            Some(&held.data),
            &Options {
                incremental: true,
                ..Options::default()
            },
        )
        .unwrap();
        let t_cal = t2.elapsed().as_secs_f64();
        // The hand-eye truth, up to the last joint's zero offset: it turns the flange about its
        // own axis, so every camera method (ours and OpenCV's) absorbs it into the hand-eye —
        // no camera data separates the two. The reference is the mount as the nominal arm sees
        // it: E·X with E = FK(q)⁻¹ FK(q + δ₆) (the world's own kinematics; E = I when δ₆ = 0).
        let x_mount = sc.cameras[0].placement.isometry();
        let phys = world.truth().arms[0].physics.clone();
        let d6 = phys.offsets_rad.last().copied().unwrap_or(0.0);
        let q0 = vec![0.3; phys.offsets_rad.len()];
        let mut q6 = q0.clone();
        if let Some(l) = q6.last_mut() {
            *l += d6;
        }
        let x_true = phys.nominal_flange(&q0).inverse() * phys.nominal_flange(&q6) * x_mount;
        let kt = k_true(&sc);
        println!(
            "\n=== {} ({} train views, {} held-out; render {t_render:.1} s) ===",
            case.name,
            train.data.views.len(),
            held.data.views.len()
        );
        println!("timing: detection of {} images {}x{} {t_detect:.2} s + calibration {t_cal:.2} s = {:.2} s",
            tr.images.len(), train.data.width, train.data.height, t_detect + t_cal);
        println!(
            "no board in {} train views; rejected by residual: {:?}; distortion {:?}",
            train.no_board.len(),
            res.rejected_views,
            res.distortion
        );
        // Detector accuracy (ours) against truth.
        let mut det_err = vec![];
        for (v, view) in train.data.views.iter().enumerate() {
            let idx = train_plan
                .poses
                .iter()
                .position(|p| p.id == view.id)
                .unwrap();
            let _ = v;
            for (c, d) in view.corners.iter().enumerate() {
                if let (Some(d), Some(t)) = (d, tr.truth[idx].0[c]) {
                    det_err.push(((d[0] - t[0]).powi(2) + (d[1] - t[1]).powi(2)).sqrt());
                }
            }
        }
        let det_rms =
            (det_err.iter().map(|e| e * e).sum::<f64>() / det_err.len().max(1) as f64).sqrt();
        let det_max = det_err.iter().cloned().fold(0.0, f64::max);
        println!("detector calib-targets: {} corners, error vs truth RMS {det_rms:.4} px, max {det_max:.4} px", det_err.len());
        // Held-out truth for our methods.
        let held_views_acq = &he;
        let mut rows: Vec<(String, f64, f64, f64, f64, f64)> = vec![];
        let ktruth_err = |k: &Intrinsics| {
            (k.fx - kt.fx)
                .abs()
                .max((k.fy - kt.fy).abs())
                .max((k.cx - kt.cx).abs())
                .max((k.cy - kt.cy).abs())
        };
        let mut ests: Vec<&camera::Estimate> = res.closed_form.iter().collect();
        if let Some(i) = &res.incremental {
            ests.push(&i.estimate);
        }
        ests.push(&res.ml);
        // The same calibration on the world's true corners (the detector's error removed): what
        // the solver alone achieves, and so how much of the hand-eye error the detector makes.
        let true_views: Vec<camera::View> = train
            .data
            .views
            .iter()
            .map(|v| {
                let idx = train_plan.poses.iter().position(|p| p.id == v.id).unwrap();
                camera::View {
                    corners: tr.truth[idx].0.clone(),
                    ..v.clone()
                }
            })
            .collect();
        let on_truth = camera::calibrate(
            &CameraData {
                views: true_views,
                ..train.data.clone()
            },
            Some(&held.data),
            &Options::default(),
        )
        .ok()
        .map(|r| camera::Estimate {
            method: "ml on the true corners".into(),
            ..r.ml
        });
        ests.extend(on_truth.as_ref());
        for e in ests {
            let (dt, dr) = he_err(&e.x, &x_true);
            rows.push((
                format!("robocal {}", e.method),
                dt,
                dr,
                e.heldout_rms_px.unwrap_or(f64::NAN),
                truth_rms(
                    &held.data,
                    held_views_acq,
                    &e.intrinsics,
                    &e.x,
                    &e.target,
                    1.0,
                    [0.0; 2],
                ),
                ktruth_err(&e.intrinsics),
            ));
        }
        // Diagnosis (board scale / bend / joint offsets).
        if let Ok(d) = robocal::diagnose::camera::diagnose(
            &train.data,
            Some(&held.data),
            &train.dataset,
            Some(&held.dataset),
        ) {
            for eff in &d.effects {
                println!(
                    "diagnosis: {} {} (held-out {:.4} -> {:.4} px, X change {:.4} mm {:.5} deg)",
                    eff.kind,
                    eff.summary,
                    eff.heldout_rms_before_px.unwrap_or(f64::NAN),
                    eff.heldout_rms_after_px.unwrap_or(f64::NAN),
                    eff.hand_eye_change_mm,
                    eff.hand_eye_change_deg
                );
            }
            if let Some(f) = &d.final_estimate {
                let (dt, dr) = he_err(&f.x, &x_true);
                // Held-out flange poses through the identified joint offsets, if any.
                let mut hd = held.data.clone();
                if let Some(arm) = &d.arm {
                    for v in hd.views.iter_mut() {
                        let rec = held.dataset.poses().find(|r| r.id == v.id).unwrap();
                        let q: Vec<f64> = rec
                            .q
                            .as_ref()
                            .unwrap()
                            .iter()
                            .map(|d| d.to_radians())
                            .collect();
                        v.flange = arm.model.flange_pose(&q);
                    }
                }
                rows.push((
                    "robocal ml+diagnosis".to_string(),
                    dt,
                    dr,
                    f.heldout_rms_px.unwrap_or(f64::NAN),
                    truth_rms(
                        &hd,
                        held_views_acq,
                        &f.intrinsics,
                        &f.x,
                        &f.target,
                        d.scale,
                        d.bend_mm,
                    ),
                    ktruth_err(&f.intrinsics),
                ));
            }
        }
        // Peer: OpenCV on the same corners.
        if py.exists() {
            let flange: Vec<Vec<f64>> = train
                .data
                .views
                .iter()
                .map(|v| {
                    let r = v.flange.rotation.to_rotation_matrix();
                    let t = v.flange.translation.vector;
                    let m = r.matrix();
                    vec![
                        m[(0, 0)],
                        m[(0, 1)],
                        m[(0, 2)],
                        m[(1, 0)],
                        m[(1, 1)],
                        m[(1, 2)],
                        m[(2, 0)],
                        m[(2, 1)],
                        m[(2, 2)],
                        t.x,
                        t.y,
                        t.z,
                    ]
                })
                .collect();
            let corners: Vec<Option<Vec<[f64; 2]>>> = train
                .data
                .views
                .iter()
                .map(|v| v.corners.iter().copied().collect::<Option<Vec<_>>>())
                .collect();
            let detect_images: Vec<String> =
                tr.images.iter().map(|p| p.display().to_string()).collect();
            let job = json!({"pattern": [train.data.board.cols, train.data.board.rows], "square_mm": train.data.board.square_mm,
                "size": [train.data.width, train.data.height], "corners": corners, "flange": flange,
                "detect_images": detect_images, "flags": "default"});
            let mut child = std::process::Command::new(&py)
                .arg(root().join("scripts/peers/camera_handeye_cv2.py"))
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
            let kk = &v["K"];
            let d = &v["dist"];
            let f = |x: &serde_json::Value| x.as_f64().unwrap();
            let kcv = Intrinsics {
                fx: f(&kk[0][0]),
                fy: f(&kk[1][1]),
                cx: f(&kk[0][2]),
                cy: f(&kk[1][2]),
                dist: [f(&d[0]), f(&d[1]), f(&d[2]), f(&d[3]), f(&d[4])],
            };
            let used: Vec<usize> = v["used"]
                .as_array()
                .unwrap()
                .iter()
                .map(|u| u.as_u64().unwrap() as usize)
                .collect();
            let tcams: Vec<Isometry3<f64>> = (0..used.len())
                .map(|i| {
                    let r = &v["rvecs"][i];
                    let t = &v["tvecs"][i];
                    Isometry3::from_parts(
                        Translation3::new(f(&t[0]), f(&t[1]), f(&t[2])),
                        UnitQuaternion::from_scaled_axis(Vector3::new(
                            f(&r[0]),
                            f(&r[1]),
                            f(&r[2]),
                        )),
                    )
                })
                .collect();
            for (name, m) in v["hand_eye"].as_object().unwrap() {
                let r = &m["R"];
                let mat = Matrix3::from_fn(|i, j| f(&r[i][j]));
                let x = Isometry3::from_parts(
                    Translation3::new(f(&m["t"][0]), f(&m["t"][1]), f(&m["t"][2])),
                    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(mat)),
                );
                let all: Vec<Isometry3<f64>> = used
                    .iter()
                    .zip(&tcams)
                    .map(|(&k, t)| train.data.views[k].flange * x * t)
                    .collect();
                let target = geom::mean_pose(&all);
                let (dt, dr) = he_err(&x, &x_true);
                let hr = camera::heldout_rms(&held.data, &kcv, &x, &target, 1.0, [0.0; 2]);
                rows.push((
                    format!("opencv {name}"),
                    dt,
                    dr,
                    hr,
                    truth_rms(&held.data, held_views_acq, &kcv, &x, &target, 1.0, [0.0; 2]),
                    ktruth_err(&kcv),
                ));
            }
            // OpenCV detector accuracy: each detected corner against its nearest true corner.
            let mut errs = vec![];
            let mut found = 0;
            for (i, dv) in v["detect"].as_array().unwrap().iter().enumerate() {
                if !dv["found"].as_bool().unwrap_or(false) {
                    continue;
                }
                found += 1;
                for c in dv["corners"].as_array().unwrap() {
                    let (u, w) = (f(&c[0]), f(&c[1]));
                    let best = tr.truth[i]
                        .0
                        .iter()
                        .flatten()
                        .map(|t| ((t[0] - u).powi(2) + (t[1] - w).powi(2)).sqrt())
                        .fold(f64::INFINITY, f64::min);
                    errs.push(best);
                }
            }
            let r = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len().max(1) as f64).sqrt();
            let mx = errs.iter().cloned().fold(0.0, f64::max);
            println!("detector OpenCV {} findChessboardCorners+cornerSubPix: found {found}/{} images, {} corners, error vs truth RMS {r:.4} px, max {mx:.4} px",
                v["opencv"].as_str().unwrap_or("?"), tr.images.len(), errs.len());
        } else {
            println!(
                "SKIP OpenCV peer: {} missing (run .ci/peers.sh)",
                py.display()
            );
        }
        println!(
            "{:<34} {:>10} {:>10} {:>12} {:>14} {:>10}",
            "method", "X err mm", "X err deg", "held-out px", "held-out px*", "K err px"
        );
        for r in &rows {
            println!(
                "{:<34} {:>10.4} {:>10.5} {:>12.4} {:>14.4} {:>10.3}",
                r.0, r.1, r.2, r.3, r.4, r.5
            );
        }
        println!("(held-out px: predicted vs detected corners of the held-out views; px*: vs the world's TRUE corners)");
        if d6 != 0.0 {
            println!(
                "(X err against the mount turned by the last joint's true zero offset {:.4}°, which no camera separates from the hand-eye; against the mount itself every method is off by that rotation)",
                d6.to_degrees()
            );
        }
        summary.push((case.name, rows));
    }
    let _ = summary;
}
