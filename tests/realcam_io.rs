//! Real camera data in, through the real commands (issue 31 §1–§2): PNG / JPEG / BMP / TIFF
//! images in the default build, `robocal import handeye` with its AX = XB spread check, every
//! unusable image named (console and `camera_report.json`, also when the calibration fails), and
//! `robocal import ndi`. Synthetic fixtures always run; the real sets under
//! `../shared/data/real-*` are used when present and SKIPPED loudly otherwise.
use std::path::{Path, PathBuf};

use nalgebra::Isometry3;

use crate::common::{cli, root, s};

fn real(name: &str) -> Option<PathBuf> {
    let p = root().join("../shared/data").join(name);
    if p.is_dir() {
        Some(p)
    } else {
        crate::common::skipped(format_args!(
            "{} is not present (real data is never copied into the project)",
            p.display()
        ));
        None
    }
}

/// A simulated eye-in-hand session (PGM images + flange poses), shared by the tests here.
fn simulated(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(root().join("mocks/scenarios/ur5e-camera.toml")).unwrap();
    let sc = dir.join("scenario.toml");
    std::fs::write(&sc, text).unwrap();
    let plan = crate::camera_calib::plan_from(
        "plans/seed004-ur5e-camera.toml",
        dir,
        "plan",
        "[2, 2, 4]",
        7,
        false,
    );
    crate::camera_calib::run(dir, &plan, &sc, "sim")
}

/// The flange poses and image paths of a dataset written by `robocal run`.
fn views_of(ds: &Path) -> Vec<(Isometry3<f64>, PathBuf)> {
    let d = robocal::dataset::read_dataset(ds).unwrap().dataset;
    let base = ds.parent().unwrap();
    d.poses()
        .filter_map(|r| {
            let f = r.flange.as_ref()?;
            let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                f.quat[0], f.quat[1], f.quat[2], f.quat[3],
            ));
            let p = Isometry3::from_parts(nalgebra::Translation3::new(f.p[0], f.p[1], f.p[2]), q);
            Some((p, base.join(r.image.as_ref()?)))
        })
        .collect()
}

fn encode(img: &robocal_drivers::traits::Image, path: &Path) {
    let g = image::GrayImage::from_raw(img.width, img.height, img.data.clone()).unwrap();
    let ext = path.extension().unwrap().to_str().unwrap();
    if ext == "tif" {
        // 16-bit grey TIFF.
        let g16 = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(
            img.width,
            img.height,
            |x, y| image::Luma([u16::from(g.get_pixel(x, y).0[0]) * 257]),
        );
        image::DynamicImage::ImageLuma16(g16).save(path).unwrap();
    } else if ext == "jpg" {
        image::DynamicImage::ImageLuma8(g)
            .to_rgb8()
            .save(path)
            .unwrap();
    } else {
        image::DynamicImage::ImageLuma8(g).save(path).unwrap();
    }
}

/// `robocal import handeye` on a folder of PNG / JPEG / BMP / 16-bit TIFF images with the
/// poses written column-major (rot9-col, metres, one file per pose): the right declaration is
/// accepted and calibrates; the row-major declaration is refused naming rot9-col; bad images
/// are named with their reason in the console report and in `camera_report.json`.
#[test]
fn import_handeye_checks_the_declaration_and_every_image_format_calibrates() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = simulated(tmp.path());
    let views = views_of(&ds);
    assert!(views.len() >= 12, "{} views", views.len());
    let imgs = tmp.path().join("imgs");
    let poses = tmp.path().join("poses");
    std::fs::create_dir_all(&imgs).unwrap();
    std::fs::create_dir_all(&poses).unwrap();
    let exts = ["png", "jpg", "bmp", "tif"];
    for (k, (f, img)) in views.iter().enumerate() {
        let im = robocal_drivers::camera::read_image_file(img).unwrap();
        encode(
            &im,
            &imgs.join(format!("view_{:03}.{}", k + 1, exts[k % 4])),
        );
        let r = f.rotation.to_rotation_matrix().into_inner();
        let t = f.translation.vector / 1000.0;
        let mut line: Vec<String> = (0..9)
            .map(|i| format!("{:.12}", r[(i % 3, i / 3)]))
            .collect();
        line.extend([t.x, t.y, t.z].iter().map(|v| format!("{v:.9}")));
        std::fs::write(
            poses.join(format!("pose{:03}.txt", k + 1)),
            line.join(" ") + "\n",
        )
        .unwrap();
    }
    let target = std::fs::read_to_string(&ds).unwrap();
    let header: serde_json::Value = serde_json::from_str(target.lines().next().unwrap()).unwrap();
    let t = &header["target"];
    let board = format!("{}x{}", t["cols"], t["rows"]);
    let square = t["square_mm"].to_string();
    let out = tmp.path().join("imported.jsonl");
    let args = |layout: &str| {
        vec![
            "import".to_string(),
            "handeye".into(),
            "--images".into(),
            s(&imgs).into(),
            "--poses".into(),
            s(&poses).into(),
            "--layout".into(),
            layout.into(),
            "--unit".into(),
            "m".into(),
            "--board".into(),
            board.clone(),
            "--square".into(),
            square.clone(),
            "--out".into(),
            s(&out).into(),
            "--quiet".into(),
        ]
    };
    let run = |a: Vec<String>| {
        let mut v = vec!["robocal".to_string()];
        v.extend(a);
        robocal::main_with_args(v)
    };
    // The wrong major order is refused (no dataset written).
    assert_eq!(run(args("rot9-row")), 1);
    assert!(!out.exists(), "a refused import writes nothing");
    let r = robocal::import::handeye::HandeyeOptions {
        images: imgs.clone(),
        poses: poses.clone(),
        reading: robocal::import::handeye::Reading {
            layout: robocal::import::handeye::Layout::Rot9 { col_major: false },
            unit: robocal::import::generic::LengthUnit::M,
            direction: robocal::import::handeye::Direction::BaseFlange,
        },
        target: serde_json::from_value(t.clone()).unwrap(),
        mount: robocal::solve::camera::Mount::Flange,
        out: out.clone(),
        heldout_every: 0,
        heldout: None,
    };
    let e = robocal::import::handeye::import_handeye(&r, false)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("rot9-col") && e.contains("most likely"),
        "the refusal names the right reading: {e}"
    );
    // The right one is accepted, writes a flange-only dataset that calibrates.
    assert_eq!(run(args("rot9-col")), 0);
    let d = robocal::dataset::read_dataset(&out).unwrap().dataset;
    assert_eq!(d.header.robot.model, "none");
    assert_eq!(d.poses().count(), views.len());
    let cal = tmp.path().join("cal");
    assert_eq!(
        cli(&[
            "calibrate",
            "camera",
            "--data",
            s(&out),
            "--out",
            s(&cal),
            "--quiet"
        ]),
        0
    );
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(cal.join("camera_report.json")).unwrap())
            .unwrap();
    assert_eq!(
        rep["views"].as_u64().unwrap() as usize,
        views.len(),
        "every format gives a view: {}",
        rep["views_without_board"]
    );
    // Broken images: each named with its reason, and the report is written on failure too.
    let broken = tmp.path().join("broken");
    std::fs::create_dir_all(broken.join("dir.png")).unwrap();
    let png = std::fs::read(imgs.join("view_001.png")).unwrap();
    std::fs::write(broken.join("cut.png"), &png[..png.len() / 3]).unwrap();
    std::fs::write(broken.join("text.jpg"), b"not an image at all").unwrap();
    let small = image::GrayImage::from_pixel(64, 48, image::Luma([128]));
    small.save(broken.join("small.png")).unwrap();
    std::fs::copy(imgs.join("view_001.png"), broken.join("ok1.png")).unwrap();
    let mut lines = vec![target.lines().next().unwrap().to_string()];
    let names = [
        "dir.png",
        "cut.png",
        "text.jpg",
        "small.png",
        "missing.png",
        "ok1.png",
    ];
    let f0 = views[0].0;
    for (k, n) in names.iter().enumerate() {
        let tr = f0.translation.vector;
        let q = f0.rotation.quaternion();
        lines.push(
            serde_json::json!({"kind": "pose", "id": k + 1, "t": k as f64,
                "flange": {"p": [tr.x, tr.y, tr.z], "quat": [q.w, q.i, q.j, q.k]},
                "image": format!("broken/{n}")})
            .to_string(),
        );
    }
    let bad = tmp.path().join("bad.jsonl");
    std::fs::write(&bad, lines.join("\n") + "\n").unwrap();
    let bcal = tmp.path().join("bcal");
    assert_eq!(
        cli(&[
            "calibrate",
            "camera",
            "--data",
            s(&bad),
            "--out",
            s(&bcal),
            "--quiet"
        ]),
        1,
        "one usable view cannot calibrate"
    );
    let rep: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(bcal.join("camera_report.json")).unwrap())
            .unwrap();
    assert!(
        rep["failed"].as_str().unwrap().contains("too few views"),
        "{rep}"
    );
    let why = rep["views_without_board"].to_string();
    for (n, reason) in [
        ("dir.png", "directory"),
        ("cut.png", "truncated"),
        ("text.jpg", "not an image"),
        ("small.png", "wrong size"),
        ("missing.png", "No such file"),
    ] {
        assert!(
            why.contains(n) && why.contains(reason),
            "{n}: {reason} in {why}"
        );
    }
}

/// The real KUKA set (30 PNG 1928×1208, row-major 4×4 in metres): the declared reading is
/// accepted with the board still in the base; inverted poses are refused.
#[test]
fn real_kuka1_imports_and_wrong_direction_is_refused() {
    let Some(dir) = real("real-handeye-kuka1") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("kuka1.jsonl");
    let opts = |direction| crate::common::kuka1_import_options(&dir, &out, None, direction);
    use robocal::import::handeye::Direction;
    let r = robocal::import::handeye::import_handeye(&opts(Direction::BaseFlange), false).unwrap();
    let d = r
        .spreads
        .iter()
        .find(|s| {
            s.reading.direction == Direction::BaseFlange
                && s.reading.unit == robocal::import::generic::LengthUnit::M
                && s.reading.layout
                    == robocal::import::handeye::Layout::Matrix4 { col_major: false }
        })
        .unwrap();
    eprintln!(
        "kuka_1: board found in {} of 30 images; spreads: {}",
        r.detected,
        r.spreads
            .iter()
            .map(|s| format!("{}: {:.2} mm / {:.3}°", s.reading.name(), s.mm, s.deg))
            .collect::<Vec<_>>()
            .join("; ")
    );
    assert_eq!(r.detected, 30, "{:?}", r.unusable);
    // Closed-form intrinsics without distortion: the declared reading leaves 12.5 mm / 1.7°
    // (OpenCV with distortion: 1.7 mm / 0.05°), every other reading ≥ 214 mm.
    assert!(d.mm < 20.0 && d.deg < 3.0, "{d:?}");
    assert!(
        r.spreads
            .iter()
            .filter(|s| s.reading != d.reading)
            .all(|s| s.mm > 10.0 * d.mm),
        "{:?}",
        r.spreads
    );
    let e = robocal::import::handeye::import_handeye(&opts(Direction::FlangeBase), false)
        .unwrap_err()
        .to_string();
    assert!(e.contains("direction base-flange"), "{e}");
}

/// The real UR3e set (88 JPEG, column-major rotation then mm, one file per pose): column-major
/// is accepted (README: 2.2 mm spread), row-major refused (README: 188 mm / 33°).
#[test]
fn real_ur3e_column_major_accepted_row_major_refused() {
    let Some(dir) = real("real-handeye-ur3e") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ur3e.jsonl");
    let opts = |col_major| robocal::import::handeye::HandeyeOptions {
        images: dir.join("images"),
        poses: dir.join("endeffectors"),
        reading: robocal::import::handeye::Reading {
            layout: robocal::import::handeye::Layout::Rot9 { col_major },
            unit: robocal::import::generic::LengthUnit::Mm,
            direction: robocal::import::handeye::Direction::BaseFlange,
        },
        target: robocal::dataset::TargetHeader {
            kind: "chessboard".into(),
            cols: 6,
            rows: 5,
            square_mm: 12.5,
            marker_mm: None,
            dictionary: None,
        },
        mount: robocal::solve::camera::Mount::Flange,
        out: out.clone(),
        heldout_every: 4,
        heldout: Some(tmp.path().join("ur3e-heldout.jsonl")),
    };
    let r = robocal::import::handeye::import_handeye(&opts(true), false).unwrap();
    eprintln!(
        "ur3e: board found in {} of 88 images; spreads: {}",
        r.detected,
        r.spreads
            .iter()
            .take(4)
            .map(|s| format!("{}: {:.2} mm / {:.3}°", s.reading.name(), s.mm, s.deg))
            .collect::<Vec<_>>()
            .join("; ")
    );
    assert_eq!(r.written.iter().map(|w| w.1).sum::<usize>(), 88);
    assert_eq!(r.written[1].1, 22, "every 4th view held out");
    let best = &r.spreads[0];
    assert_eq!(
        best.reading.layout,
        robocal::import::handeye::Layout::Rot9 { col_major: true }
    );
    let e = robocal::import::handeye::import_handeye(&opts(false), false)
        .unwrap_err()
        .to_string();
    eprintln!("ur3e row-major: {e}");
    assert!(e.contains("rot9-col"), "{e}");
}

/// `robocal import ndi` on an NDI Track export of our own (a probe pivoting about its tip, one
/// frame `Missing`, repeated marker columns) → `robocal calibrate pivot` finds the tip.
#[test]
fn ndi_track_export_imports_and_pivot_calibrates() {
    let tmp = tempfile::tempdir().unwrap();
    let tip = nalgebra::Vector3::new(10.0, 150.0, -5.0);
    let pivot = nalgebra::Vector3::new(50.0, -20.0, -1500.0);
    let mut csv = String::from(
        "Tools,Probe,Frame,Face,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error,Markers,State,Tx,Ty,Tz,State,Tx,Ty,Tz\n",
    );
    for k in 0..40 {
        let a = k as f64 * 0.37;
        let r =
            nalgebra::UnitQuaternion::from_euler_angles(0.5 * a.sin(), 0.4 * (1.7 * a).cos(), a);
        let p = pivot - r * tip;
        let q = r.quaternion();
        if k == 7 {
            let m = "-3.697314E28";
            csv += &format!("1,Probe,{},1,Missing,{m},{m},{m},{m},{m},{m},{m},{m},2,Missing,{m},{m},{m},Missing,{m},{m},{m}\n", 1000 + 3 * k);
            continue;
        }
        csv += &format!(
            "1,Probe,{},1,OK,{:.7},{:.7},{:.7},{:.7},{:.3},{:.3},{:.3},0.12,2,OK,{:.3},{:.3},{:.3},Missing,-3.697314E28,-3.697314E28,-3.697314E28\n",
            1000 + 3 * k, q.w, q.i, q.j, q.k, p.x, p.y, p.z, p.x + 1.0, p.y, p.z
        );
    }
    let input = tmp.path().join("track.csv");
    std::fs::write(&input, csv).unwrap();
    let out = tmp.path().join("pivot.jsonl");
    assert_eq!(
        cli(&["import", "ndi", "--input", s(&input), "--out", s(&out)]),
        0
    );
    let d = robocal::dataset::read_dataset(&out).unwrap().dataset;
    assert_eq!(d.records.len(), 39, "the Missing frame is not imported");
    let dir = tmp.path().join("cal");
    assert_eq!(
        cli(&["calibrate", "pivot", "--data", s(&out), "--out", s(&dir)]),
        0
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("pivot.json")).unwrap()).unwrap();
    let t = &v["results"][0]["tip_in_marker_mm"];
    let got = nalgebra::Vector3::new(
        t[0].as_f64().unwrap(),
        t[1].as_f64().unwrap(),
        t[2].as_f64().unwrap(),
    );
    assert!((got - tip).norm() < 0.01, "tip {got:?}");
    // A malformed export is refused naming the line and the column.
    std::fs::write(&input, "Tools,Probe,Frame,Face,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error\n1,Probe,5,1,OK,1,0,0,0,1,2,x,0.1\n").unwrap();
    assert_eq!(
        cli(&["import", "ndi", "--input", s(&input), "--out", s(&out)]),
        1
    );
}
