//! Why robocal's two split halves disagree more than OpenCV's (issue 31 §3): on every real set,
//! each alternate half of all views calibrated by robocal and by OpenCV, and Park–Martin's X
//! from each ingredient swapped in turn (robocal's intrinsics / every distortion model /
//! OpenCV's K), so that the split-half difference can be traced to the intrinsics, the pairs,
//! or the selection.
//!
//!     cargo run --release --example realcam_split [kuka1|ur3e|kuka2]
//!
//! Sets as in `examples/real_handeye.rs` (`ROBOCAL_SHARED_DATA`, `ROBOCAL_REAL_KUKA2`).
use std::path::PathBuf;

use nalgebra::Isometry3;
use robocal::solve::camera::geom::pose_error;
use robocal::solve::camera::handeye::{motion_pairs, solve, Method};
use robocal::solve::camera::intrinsics::calibrate_intrinsics;
use robocal::solve::camera::realeval::{self, RealSet};
use robocal::solve::camera::{calibrate, CameraData, DistModel, Options};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn park(data: &CameraData, poses: &[Isometry3<f64>]) -> Option<Isometry3<f64>> {
    let g: Vec<_> = data.views.iter().map(|v| v.flange).collect();
    solve(Method::ParkMartin, &motion_pairs(&g, poses, 2.0))
}

fn main() {
    let filter = std::env::args().nth(1);
    let data = std::env::var_os("ROBOCAL_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join("../shared/data"));
    let py = root().join(".venv/peers-cv2/bin/python");
    let script = root().join("scripts/peers/camera_handeye_cv2.py");
    type Loader = fn(&std::path::Path) -> Result<RealSet, String>;
    let sets: [(&str, PathBuf, Loader); 3] = [
        (
            "kuka1",
            data.join("real-handeye-kuka1"),
            realeval::load_kuka1,
        ),
        ("ur3e", data.join("real-handeye-ur3e"), |d| {
            realeval::load_ur3e(d, 12.5)
        }),
        (
            "kuka2",
            std::env::var_os("ROBOCAL_REAL_KUKA2")
                .map(PathBuf::from)
                .unwrap_or_else(|| data.join("real-handeye-kuka2")),
            realeval::load_kuka2,
        ),
    ];
    for (key, dir, load) in sets {
        if filter.as_deref().is_some_and(|f| !key.contains(f)) || !dir.exists() {
            continue;
        }
        let set = load(&dir).unwrap();
        let (cam, _) = realeval::detect_set(&set);
        let (a, b) = realeval::halves(&cam);
        println!(
            "\n=== {key}: {} + {} views ===",
            a.views.len(),
            b.views.len()
        );
        let mut rows: Vec<(String, [Option<Isometry3<f64>>; 2])> = vec![];
        let mut push = |name: String, h: usize, x: Option<Isometry3<f64>>| {
            if let Some(r) = rows.iter_mut().find(|r| r.0 == name) {
                r.1[h] = x;
            } else {
                let mut v = [None, None];
                v[h] = x;
                rows.push((name, v));
            }
        };
        for (h, half) in [&a, &b].into_iter().enumerate() {
            let r = calibrate(half, None, &Options::default()).unwrap();
            println!(
                "half {h}: robocal model {:?} k {:.1} {:.1} {:.1} {:.1} dist {:?}; written {}; rejected {:?}",
                r.distortion,
                r.intrinsics_only.fx,
                r.intrinsics_only.fy,
                r.intrinsics_only.cx,
                r.intrinsics_only.cy,
                r.intrinsics_only.dist,
                r.ml.method,
                r.rejected_views
            );
            push("robocal written".into(), h, Some(r.ml.x));
            for e in r.closed_form.iter().chain(&r.candidates) {
                push(format!("robocal {}", e.method), h, Some(e.x));
            }
            println!(
                "  cv {:?}",
                r.cv_scores
                    .iter()
                    .map(|(n, s)| format!("{n}: {s:.3}"))
                    .collect::<Vec<_>>()
            );
            for m in DistModel::ALL {
                if let Ok(f) = calibrate_intrinsics(half, m) {
                    println!(
                        "  {m:?}: fx {:.1} fy {:.1} rms {:.3}",
                        f.k.fx, f.k.fy, f.rms_px
                    );
                    push(format!("park on {m:?} intrinsics"), h, park(half, &f.poses));
                }
            }
            if py.exists() {
                let p = realeval::opencv_peer(&py, &script, half).unwrap();
                println!(
                    "  opencv: fx {:.1} fy {:.1} cx {:.1} cy {:.1} dist {:?} rms {:.3}",
                    p.k.fx, p.k.fy, p.k.cx, p.k.cy, p.k.dist, p.rms_px
                );
                for (name, x, _) in &p.methods {
                    push(format!("opencv {name}"), h, Some(*x));
                }
            }
        }
        for (name, [xa, xb]) in &rows {
            if let (Some(xa), Some(xb)) = (xa, xb) {
                let (dt, dr) = pose_error(xa, xb);
                let t = xa.translation.vector;
                println!(
                    "  {name:<36} ΔX {dt:7.2} mm {dr:6.3} deg   (half 0 t = {:.1} {:.1} {:.1})",
                    t.x, t.y, t.z
                );
            }
        }
    }
}
