//! Proof against code nobody here wrote: OpenCV (`opencv-python-headless<5`, venv
//! `.venv/peers-cv2`, installed by `.ci/peers.sh`) opens the simulated camera with
//! `cv2.VideoCapture("http://…/video.mjpg")` (FFmpeg `mpjpeg` demuxer), reads frames of the
//! right shape, and finds the chessboard corners where the world's true camera pose projects
//! the true board corners.
//!
//! Figures are printed: `cargo test -p robocal-mocks --test camera_peer -- --nocapture`.

use nalgebra::Point3;
use robocal_mocks::camera::{self, SimCameraConfig};
use robocal_mocks::world::sensors::project;
use robocal_mocks::{Scenario, WorldHandle};
use std::path::PathBuf;
use std::time::Duration;

mod peer;

async fn run_peer(
    py: &PathBuf,
    url: &str,
    frames: usize,
    cols: u32,
    rows: u32,
) -> Vec<serde_json::Value> {
    let args = vec![
        url.to_string(),
        frames.to_string(),
        cols.to_string(),
        rows.to_string(),
    ];
    peer::run_json_lines(py, "camera_cv2.py", args, Duration::from_secs(120)).await
}

fn points(v: &serde_json::Value) -> Vec<(f64, f64)> {
    v.as_array()
        .expect("corner list")
        .iter()
        .map(|p| (p[0].as_f64().unwrap(), p[1].as_f64().unwrap()))
        .collect()
}

/// Nearest-neighbour match of `found` to `truth`: per-corner (found - truth) offsets (px);
/// panics unless the match is one-to-one.
fn match_errors(found: &[(f64, f64)], truth: &[(f64, f64)]) -> Vec<(f64, f64)> {
    assert_eq!(found.len(), truth.len());
    let mut used = vec![false; truth.len()];
    found
        .iter()
        .map(|&(u, v)| {
            let (k, d) = truth
                .iter()
                .enumerate()
                .map(|(k, &(tu, tv))| (k, (u - tu).hypot(v - tv)))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            assert!(!used[k], "two corners matched truth corner {k} ({d} px)");
            used[k] = true;
            (u - truth[k].0, v - truth[k].1)
        })
        .collect()
}

/// (rms px, max px, mean offset u, mean offset v) of matched offsets.
fn stats(e: &[(f64, f64)]) -> (f64, f64, f64, f64) {
    let n = e.len() as f64;
    let rms = (e.iter().map(|d| d.0 * d.0 + d.1 * d.1).sum::<f64>() / n).sqrt();
    let max = e.iter().map(|d| d.0.hypot(d.1)).fold(0.0, f64::max);
    let mu = e.iter().map(|d| d.0).sum::<f64>() / n;
    let mv = e.iter().map(|d| d.1).sum::<f64>() / n;
    (rms, max, mu, mv)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn opencv_videocapture_reads_the_stream_and_finds_the_true_corners() {
    let Some(py) = peer::python("cv2", "camera peer test") else {
        return;
    };
    // The scenario as it is (blur 0.7 px, noise 2 grey), then without noise to separate the
    // error of the image from the error of the corner finder on a clean render.
    for noise in [true, false] {
        check(&py, noise).await;
    }
}

async fn check(py: &PathBuf, noise: bool) {
    let mut s =
        Scenario::load(&peer::workspace().join("mocks/scenarios/ur5e-camera.toml")).unwrap();
    if !noise {
        s.cameras[0].noise_grey = 0.0;
    }
    let w = WorldHandle::from_scenario(&s).unwrap();
    let sim = camera::serve(
        w.clone(),
        "cam",
        SimCameraConfig::default(),
        "127.0.0.1:0".parse().unwrap(),
    )
    .await
    .unwrap();
    let board = s
        .scene
        .chessboard
        .clone()
        .expect("scenario has a chessboard");
    let out = run_peer(py, &sim.url(), 3, board.cols, board.rows).await;
    println!("{}", serde_json::to_string(&out).unwrap());

    let frames: Vec<&serde_json::Value> = out.iter().filter(|v| v.get("frame").is_some()).collect();
    assert_eq!(frames.len(), 3, "{out:?}");
    let render_mean = {
        let img = w.render_camera_of(0);
        img.data.iter().map(|&g| f64::from(g)).sum::<f64>() / img.data.len() as f64
    };
    for f in &frames {
        let shape: Vec<u64> = f["shape"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_u64().unwrap())
            .collect();
        assert!(
            shape == [480, 640, 3] || shape == [480, 640],
            "shape {shape:?}"
        );
        let m = f["mean_grey"].as_f64().unwrap();
        assert!(
            (m - render_mean).abs() < 1.0,
            "mean grey {m} vs render {render_mean}"
        );
    }
    // Counted after the part's last byte is written: awaited, not read once (see camera_sim).
    let t0 = std::time::Instant::now();
    while sim.frames_sent() < 3 && t0.elapsed().as_secs_f64() < 5.0 {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert!(
        sim.frames_sent() >= 3,
        "{} parts counted",
        sim.frames_sent()
    );

    let res = out.last().unwrap();
    assert_eq!(res["found"], true, "OpenCV found no chessboard: {res}");
    let found_raw = points(&res["corners"]);
    let found_sub = points(&res["corners_subpix"]);
    let (nc, nr) = (board.cols as usize - 1, board.rows as usize - 1);
    assert_eq!(found_raw.len(), nc * nr);

    // The truth: the world's own camera pose and the board placement of the scenario.
    let cam_cfg = &s.cameras[0];
    let cam_in_base = w.camera_in_base(0).unwrap();
    let board_in_base = board.placement.isometry();
    let mut truth = Vec::new();
    for j in 0..nr {
        for i in 0..nc {
            let p = board_in_base
                * Point3::new(
                    (i + 1) as f64 * board.square_mm,
                    (j + 1) as f64 * board.square_mm,
                    0.0,
                );
            truth.push(project(cam_cfg, &(cam_in_base.inverse() * p)).expect("in front"));
        }
    }
    // The match must be the grid itself, in one of the four orderings OpenCV may report for a
    // non-square pattern (rows of `nc` corners, starting from any of the four outer corners).
    let errs = |found: &[(f64, f64)]| {
        let e = match_errors(found, &truth);
        let near = |a: &(f64, f64), b: &(f64, f64)| (a.0 - b.0).hypot(a.1 - b.1) < 3.0;
        let orderings = [(false, false), (true, false), (false, true), (true, true)];
        let ok = orderings.iter().any(|&(flip_i, flip_j)| {
            (0..nr).all(|j| {
                (0..nc).all(|i| {
                    let ti = if flip_i { nc - 1 - i } else { i };
                    let tj = if flip_j { nr - 1 - j } else { j };
                    near(&found[j * nc + i], &truth[tj * nc + ti])
                })
            })
        });
        assert!(
            ok,
            "OpenCV's corner order is not a grid ordering of the truth"
        );
        e
    };
    let bias = |found: &[(f64, f64)]| {
        let n = found.len() as f64;
        let (mut du, mut dv) = (0.0, 0.0);
        for (f, t) in found.iter().zip(&truth) {
            // Only meaningful as a size: the sign depends on the ordering.
            du += (f.0 - t.0).abs() / n;
            dv += (f.1 - t.1).abs() / n;
        }
        (du, dv)
    };
    let _ = bias;
    let (raw_rms, raw_max, raw_mu, raw_mv) = stats(&errs(&found_raw));
    let (sub_rms, sub_max, sub_mu, sub_mv) = stats(&errs(&found_sub));
    println!(
        "noise={noise}: OpenCV {} ({}) vs truth: findChessboardCorners rms {raw_rms:.3} px, \
         max {raw_max:.3} px, mean offset ({raw_mu:+.3}, {raw_mv:+.3}); after cornerSubPix: \
         rms {sub_rms:.3} px, max {sub_max:.3} px, mean offset ({sub_mu:+.3}, {sub_mv:+.3})",
        res["opencv"], res["backend"]
    );
    assert!(
        sub_max <= 0.15,
        "sub-pixel corners off by up to {sub_max} px"
    );
    assert!(
        raw_max <= 0.5,
        "findChessboardCorners corners off by up to {raw_max} px"
    );
}
