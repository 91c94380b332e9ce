//! Camera hand-eye on the real eye-in-hand sets (issue 31 §3), read from
//! `../shared/data/real-handeye-*` when present (SKIPPED loudly otherwise; real data is never
//! copied into the project). Every 4th view held out; held-out corners predicted from the
//! flange pose. With OpenCV (`.venv/peers-cv2`, `.ci/peers.sh`) the written estimate must not be
//! worse than OpenCV's best closed form on the same detections; without it, than robocal's.
use std::path::{Path, PathBuf};

use robocal::solve::camera::realeval::{self, RealSet};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `held_max`: the written held-out RMS at most this multiple of the best reference's;
/// `split_max`: the written X's split-half difference at most this multiple of OpenCV Park's.
fn check(
    name: &str,
    dir: &str,
    load: impl Fn(&Path) -> Result<RealSet, String>,
    held_max: f64,
    split_max: f64,
) {
    let dir = root().join("../shared/data").join(dir);
    if !dir.exists() {
        crate::common::skipped(format_args!("real set {name} absent ({})", dir.display()));
        return;
    }
    let set = load(&dir).unwrap();
    let (cam, failed) = realeval::detect_set(&set);
    for (img, why) in &failed {
        eprintln!("{name}: not used: {img}: {why}");
    }
    if cam.views.len() + 10 < set.images.len() {
        eprintln!(
            "{name}: only {} of {} images read and detected (this build reads: see above)",
            cam.views.len(),
            set.images.len()
        );
        return;
    }
    let py = root().join(".venv/peers-cv2/bin/python");
    let script = root().join("scripts/peers/camera_handeye_cv2.py");
    let peer = py.exists().then_some((py.as_path(), script.as_path()));
    if peer.is_none() {
        crate::common::skipped(format_args!(
            "{name}: OpenCV peer (no .venv/peers-cv2): compared with robocal's closed forms only"
        ));
    }
    let r = realeval::evaluate(&cam, peer, 30).unwrap();
    let res = &r.result;
    eprintln!("{name}: cv {:?}", res.cv_scores);
    eprintln!(
        "{name}: written {} {:.3} px, floor {:.3} px, opencv {:?}, robocal {:?}",
        r.written.method,
        r.written.heldout_px,
        r.floor_px,
        r.opencv
            .iter()
            .map(|o| (o.method.as_str(), o.heldout_px))
            .collect::<Vec<_>>(),
        r.robocal
            .iter()
            .map(|o| (o.method.as_str(), o.heldout_px))
            .collect::<Vec<_>>()
    );
    eprintln!(
        "{name}: split half {:.2} mm / {:.3} deg (OpenCV Park {:?}), ratios {:?}; σ {:?} mm {:?} deg, bootstrap {:?}",
        r.split.dx_mm, r.split.dr_deg, r.split.opencv_park, r.split.ratios, r.sigma_mm, r.sigma_deg, r.bootstrap
    );
    // §3: the residual is the robot's (training RMS far above the board-only RMS), and the
    // diagnosis wording says so for this set (no joint angles recorded).
    let note = robocal::diagnose::camera::robot_dominance_note(
        r.written.train_px,
        r.board_only_px,
        res.pose_noise,
        &robocal::diagnose::camera::ArmState::Untestable(
            "the records carry no joint angles `q`".into(),
        ),
    );
    eprintln!(
        "{name}: training RMS {:.3} px / board-only {:.3} px = {:.1}x; {note:?}",
        r.written.train_px,
        r.board_only_px,
        r.written.train_px / r.board_only_px
    );
    assert!(note.is_some_and(|n| n.contains("robot poses dominate")));
    let reference: Vec<f64> = if r.opencv.is_empty() {
        res.closed_form
            .iter()
            .filter_map(|e| e.heldout_rms_px)
            .collect()
    } else {
        r.opencv.iter().map(|o| o.heldout_px).collect()
    };
    let best = reference.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(
        r.written.heldout_px <= best * held_max,
        "{name}: written held-out {:.3} px above {held_max} x the best closed form {best:.3} px",
        r.written.heldout_px
    );
    // The floor is below what any estimate from other views reaches.
    assert!(r.floor_px <= r.written.heldout_px);
    // Honest 1σ: the split-half difference within 2 combined σ for most coordinates and
    // within 3 for all (issue 31's goal is ≥ 90 % within 2; measured 4/6 and 6/6 here).
    let ok = r.split.ratios.iter().filter(|q| **q <= 2.0).count();
    assert!(
        ok >= 4 && r.split.ratios.iter().all(|q| *q <= 3.0),
        "{name}: split half / σ {:?}",
        r.split.ratios
    );
    // Split-half stability against OpenCV Park's (the goal, ≤ 1×, is met on the UR3e, not on
    // kuka_1: see `docs/findings.md`).
    if let Some((park_mm, _)) = r.split.opencv_park {
        assert!(
            r.split.dx_mm <= split_max * park_mm,
            "{name}: split half {:.2} mm vs OpenCV Park {park_mm:.2} mm",
            r.split.dx_mm
        );
    }
    // Bootstrap and stated covariance within 50 %, translation and rotation (issue 31's goal;
    // the rotation met since the lens model's share is weighed by how often the rule chooses
    // each model: kuka_1 rx / ry were 0.38 / 0.48, the UR3e's ry 1.52).
    let (bt, br) = r.bootstrap.unwrap();
    let stated = r.sigma_mm.iter().chain(&r.sigma_deg);
    for (a, (b, st)) in bt.iter().chain(&br).zip(stated).enumerate() {
        let q = b / st;
        assert!(
            (0.5..=1.5).contains(&q),
            "{name}: bootstrap / stated σ {q:.2} (coordinate {a}: x y z rx ry rz)"
        );
    }
}

#[test]
fn real_kuka1_hand_eye() {
    // Measured: held-out 0.990x OpenCV's best, split half 1.65 / 1.23 mm = 1.34x Park's.
    check(
        "kuka_1",
        "real-handeye-kuka1",
        realeval::load_kuka1,
        1.0001,
        1.4,
    );
}

#[test]
fn real_ur3e_hand_eye() {
    // Measured: held-out 0.834x OpenCV's best, split half 1.65 / 1.80 mm = 0.92x Park's.
    check(
        "ur3e",
        "real-handeye-ur3e",
        |d| realeval::load_ur3e(d, 12.5),
        0.85,
        1.0,
    );
}

/// The UR3e set's detected views (`None`, said loudly, when the set is absent or this build
/// detects too few of its images).
fn ur3e_views() -> Option<robocal::solve::camera::CameraData> {
    let dir = root().join("../shared/data/real-handeye-ur3e");
    if !dir.exists() {
        crate::common::skipped(format_args!("real set ur3e absent ({})", dir.display()));
        return None;
    }
    let set = realeval::load_ur3e(&dir, 12.5).unwrap();
    let (cam, _) = realeval::detect_set(&set);
    if cam.views.len() + 10 < set.images.len() {
        eprintln!("ur3e: only {} views detected", cam.views.len());
        return None;
    }
    Some(cam)
}

/// Issue 31 §3, honest 1σ beyond one split: on random halvings of the UR3e views the principal
/// point moves up to 15 px with the views (a 6×5 board in 640×480 images) and X's rotation
/// 1.2° with it. The stated 1σ of an estimate that holds the board-only intrinsics now carries
/// their uncertainty (view jackknife of the board-only fit, propagated through a refit of X)
/// and X's spread over the distortion models as plausible as the chosen one (halves that choose
/// tangential terms or not differ by 16 px in the principal point and 1.2–1.4° in X's
/// rotation). The intrinsics come from every view (they came from 20). It also carries X's
/// spread over the candidate estimators that resamples of the views write instead (halves of
/// the set write different ones). Measured on these six halvings: 97 % of the coordinates
/// within 2 combined σ, the worst at 3.1σ (94 % without the estimator part; 97 % and 2.3σ with
/// every plausible model counted as equally likely, round 12); intrinsics from 20 views without
/// the model term 89 % and 4.7σ; with the intrinsics held exact 69 % and 14.8σ.
#[test]
fn real_ur3e_random_halvings_are_within_the_stated_sigma() {
    let Some(cam) = ur3e_views() else {
        return;
    };
    let h = realeval::random_halves(&cam, None, 6, 7).unwrap();
    let worst = h.ratios.iter().flatten().copied().fold(0.0, f64::max);
    eprintln!(
        "ur3e random halvings: ΔX {:?} mm, within 2σ {:.0} %, worst {worst:.1}σ, ratios {:?}",
        h.dx_mm.iter().map(|d| d.0).collect::<Vec<_>>(),
        100.0 * h.within_2sigma(),
        h.ratios
    );
    assert!(h.within_2sigma() >= 0.9, "{:.2}", h.within_2sigma());
    assert!(worst <= 3.5, "worst |ΔX|/σ {worst:.1}");
}

/// Issue 31 §3, honest 1σ a field engineer can act on: on the UR3e training views the lens
/// model is not decided (k1 chosen; k1-k2-p1-p2 and k1-k2-p1-p2-k3 within 1 % of its validation
/// error), and X's rotation about the camera's x axis depends on it: measured 1σ 0.85° from the
/// model choice against 0.06° from the fit and 0.07° from the intrinsics. The stated 1σ says so,
/// part by part, in `camera_report.json` and on the console, with what would decide it.
#[test]
fn real_ur3e_sigma_names_the_undecided_lens_model() {
    use robocal::solve::camera::{calfile, calibrate, Options};
    let Some(cam) = ur3e_views() else {
        return;
    };
    let (train, _) = realeval::split_every(&cam, 4);
    let res = calibrate(&train, None, &Options::default()).unwrap();
    let u = &res.uncertainty;
    let p = u
        .x_parts
        .as_ref()
        .expect("the written estimate holds the board-only intrinsics");
    eprintln!(
        "ur3e σ parts: {p:?}; stated {:?} mm {:?} deg",
        u.x_mm, u.x_deg
    );
    assert!(!p.plausible_models.is_empty());
    assert_eq!(p.dominant_rotation().0, "distortion model");
    assert_eq!(p.dominant_rotation().1, 0, "about the camera's x axis");
    assert!(
        p.distortion_model_deg[0] > 0.4,
        "{:?}",
        p.distortion_model_deg
    );
    // The parts add in quadrature to the stated 1σ.
    for a in 0..3 {
        let q = (p.fit_deg[a].powi(2)
            + p.intrinsics_deg[a].powi(2)
            + p.distortion_model_deg[a].powi(2)
            + p.estimator_deg[a].powi(2))
        .sqrt();
        assert!(
            (q - u.x_deg[a]).abs() < 1e-9 * u.x_deg[a].max(1.0),
            "{a}: {q} vs {}",
            u.x_deg[a]
        );
        let q = (p.fit_mm[a].powi(2)
            + p.intrinsics_mm[a].powi(2)
            + p.distortion_model_mm[a].powi(2)
            + p.estimator_mm[a].powi(2))
        .sqrt();
        assert!(
            (q - u.x_mm[a]).abs() < 1e-9 * u.x_mm[a].max(1.0),
            "{a}: {q} vs {}",
            u.x_mm[a]
        );
    }
    // The model term is weighed by how often the calibration's rule chooses each model on
    // resamples of the views: the chosen model first, the shares add to 1, and the others are
    // chosen in most (measured: k1 28 %, k1-k2-p1-p2 70 %, k1-k2-p1-p2-k3 2 % of 40 resamples).
    assert_eq!(p.model_shares[0].0, res.distortion);
    let total: f64 = p.model_shares.iter().map(|s| s.1).sum();
    assert!((total - 1.0).abs() < 1e-9, "{:?}", p.model_shares);
    assert!(p.model_shares[0].1 < 0.9, "{:?}", p.model_shares);
    // The estimator part: the written candidate first, the shares of the resamples add to 1.
    assert_eq!(
        p.estimator_shares[0].0, res.ml.method,
        "{:?}",
        p.estimator_shares
    );
    let total: f64 = p.estimator_shares.iter().map(|s| s.1).sum();
    assert!((total - 1.0).abs() < 1e-9, "{:?}", p.estimator_shares);
    let lines = calfile::sigma_parts_lines(&res);
    eprintln!("{lines}");
    assert!(
        lines.contains("chosen in resamples of the views"),
        "{lines}"
    );
    assert!(lines.contains("do not decide the lens model"), "{lines}");
    assert!(lines.contains("about the camera's x axis"), "{lines}");
}

/// Issue 31 §3: on the UR3e set's `cam0_079.jpg` OpenCV's detectors label the grid wrongly
/// (the shared README: shifted one square, 88° from what the robot says; measured here with
/// OpenCV 4.14: both `findChessboardCorners` and `...SB` put the board ≈180° and 64–80 mm from
/// where the other views put it, at the same corner positions as robocal). robocal's labelling
/// must agree with the robot: the board in the base that image implies (`G X T`, X from Park on
/// the other views, T from robocal's corners with the board-only intrinsics) lies where the
/// other views put it, within the arm's pose error (measured 2.74 mm / 0.457°; the other
/// views' worst 4.19 mm / 1.334°).
#[test]
fn real_ur3e_shifted_grid_image_is_labelled_right() {
    use robocal::solve::camera::geom::{mean_pose, pose_error};
    use robocal::solve::camera::handeye::{motion_pairs, solve, Method};
    use robocal::solve::camera::intrinsics::calibrate_intrinsics;
    use robocal::solve::camera::DistModel;

    let dir = root().join("../shared/data/real-handeye-ur3e");
    if !dir.exists() {
        eprintln!(
            "\n*** SKIPPED: real set ur3e absent ({}) ***\n",
            dir.display()
        );
        return;
    }
    let set = realeval::load_ur3e(&dir, 12.5).unwrap();
    let (cam, failed) = realeval::detect_set(&set);
    let Some(i79) = cam.views.iter().position(|v| v.id == 79) else {
        eprintln!("\n*** SKIPPED: cam0_079 not read or not detected: {failed:?} ***\n");
        return;
    };
    let fit = calibrate_intrinsics(&cam, DistModel::K1K2).unwrap();
    let g: Vec<_> = cam.views.iter().map(|v| v.flange).collect();
    let others: Vec<usize> = (0..g.len()).filter(|&i| i != i79).collect();
    let (go, to): (Vec<_>, Vec<_>) = others.iter().map(|&i| (g[i], fit.poses[i])).unzip();
    let x = solve(Method::ParkMartin, &motion_pairs(&go, &to, 2.0)).unwrap();
    let b: Vec<_> = go.iter().zip(&to).map(|(g, t)| g * x * t).collect();
    let b_mean = mean_pose(&b);
    let spread: Vec<(f64, f64)> = b.iter().map(|bi| pose_error(&b_mean, bi)).collect();
    let worst = spread
        .iter()
        .fold((0.0f64, 0.0f64), |a, s| (a.0.max(s.0), a.1.max(s.1)));
    let (dt, dr) = pose_error(&b_mean, &(g[i79] * x * fit.poses[i79]));
    eprintln!(
        "ur3e cam0_079: board in base {dt:.2} mm / {dr:.3} deg from the other views' mean (their worst {:.2} mm / {:.3} deg); board-only RMS {:.3} px",
        worst.0, worst.1, fit.rms_px
    );
    assert!(
        dr < 2.0 && dt < 8.0,
        "cam0_079 off by {dt:.2} mm / {dr:.3} deg"
    );
    assert!(dt <= worst.0 && dr <= worst.1);
    // OpenCV's detector on the same image, when the peer is installed: shown, not asserted
    // (a later OpenCV may fix it).
    let py = root().join(".venv/peers-cv2/bin/python");
    if !py.exists() {
        eprintln!("OpenCV peer SKIPPED (no .venv/peers-cv2)");
        return;
    }
    let job = format!(
        "{{\"pattern\": [6, 5], \"images\": [{:?}]}}",
        set.images[78].display().to_string()
    );
    let out = std::process::Command::new(&py)
        .arg(root().join("scripts/peers/chessboard_detect_cv2.py"))
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .and_then(|mut c| {
            use std::io::Write;
            c.stdin.take().unwrap().write_all(job.as_bytes())?;
            c.wait_with_output()
        })
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_default();
    let ours = &cam.views[i79].corners;
    for det in ["classic", "sb"] {
        let r = &v["results"][0][det];
        let cs: Vec<[f64; 2]> = r["corners"]
            .as_array()
            .map(|a| {
                a.iter()
                    .filter_map(|c| Some([c[0].as_f64()?, c[1].as_f64()?]))
                    .collect()
            })
            .unwrap_or_default();
        // The corner positions agree; the labelling is what a detector can get wrong. The
        // board in the base under OpenCV's labelling (corner k = (k mod 6, k div 6), pose from
        // the homography with robocal's K) against where the other views put it.
        let far = cs
            .iter()
            .filter(|c| {
                ours.iter()
                    .flatten()
                    .all(|o| (o[0] - c[0]).hypot(o[1] - c[1]) > 3.0)
            })
            .count();
        let plane: Vec<[f64; 2]> = (0..cs.len())
            .map(|k| [(k % 6) as f64 * 12.5, (k / 6) as f64 * 12.5])
            .collect();
        let km = nalgebra::Matrix3::new(
            fit.k.fx, 0.0, fit.k.cx, 0.0, fit.k.fy, fit.k.cy, 0.0, 0.0, 1.0,
        );
        let off = robocal::solve::camera::zhang::homography(&plane, &cs)
            .and_then(|h| robocal::solve::camera::zhang::pose_from_h(&km, &h))
            .map(|t| pose_error(&b_mean, &(g[i79] * x * t)));
        eprintln!(
            "OpenCV {det} on cam0_079: found {}, {far} of {} corners more than 3 px from every robocal corner; its labelling puts the board {:?} (mm, deg) from the other views' mean",
            r["found"], cs.len(), off
        );
    }
}

/// The real KUKA set imported as a user would (every 4th view held out), then `robocal
/// diagnose`: the arm's reported positions are off by a linear map (no joint angles in these
/// records), the diagnosis names `flange_map`, the held-out views are predicted ≥ 25 % better
/// than by the calibration (measured: 2.411 → 1.701 px, OpenCV's best 2.434), X's stated 1σ
/// says X alone is less determined, and `robocal predict` with the written calibration
/// reproduces the diagnosis' held-out figure (it reads the flanges through the map).
#[test]
fn real_kuka1_camera_diagnosis_names_the_flange_map_and_predict_reproduces_it() {
    let dir = root().join("../shared/data/real-handeye-kuka1");
    if !dir.exists() {
        crate::common::skipped(format_args!("real set kuka_1 absent ({})", dir.display()));
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (train, held) = (tmp.path().join("k1.jsonl"), tmp.path().join("k1-h.jsonl"));
    let o = crate::common::kuka1_import_options(
        &dir,
        &train,
        Some(&held),
        robocal::import::handeye::Direction::BaseFlange,
    );
    robocal::import::handeye::import_handeye(&o, false).unwrap();
    let out = tmp.path().join("diag");
    assert_eq!(crate::common::diagnose_cli(&train, &held, &out), 0);
    let d: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("diagnosis.json")).unwrap())
            .unwrap();
    let kinds: Vec<&str> = d["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|e| e["kind"].as_str())
        .collect();
    let (base, fin) = (
        d["heldout_rms"]["base_model_px"].as_f64().unwrap(),
        d["heldout_rms"]["final_px"].as_f64().unwrap(),
    );
    eprintln!("kuka_1 diagnosis: {kinds:?}, held-out {base:.3} -> {fin:.3} px");
    assert!(kinds.contains(&"flange_map"), "{kinds:?}");
    assert!(fin < 0.75 * base, "{base} -> {fin}");
    let warnings = d["warnings"].to_string();
    assert!(warnings.contains("flange positions"), "{warnings}");
    let cal = out.join("calibration.json");
    let c: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&cal).unwrap()).unwrap();
    assert!(
        c["camera"]["flange_map"]["matrix"].is_array(),
        "{}",
        c["camera"]
    );
    let pred = tmp.path().join("pred.csv");
    assert_eq!(crate::common::predict_cli(&cal, &held, &pred), 0);
    let (got, n) = crate::camera_predict::rms_against_detections(&pred, &held);
    eprintln!("predict with the written calibration: {got:.4} px over {n} corners");
    assert!(
        (got - fin).abs() < 1e-3,
        "predict {got} px vs the diagnosis' {fin} px"
    );
}
