//! The OpenCV camera layer (feature `opencv`): image files, image sequences and video files
//! through `VideoCapture`, chessboard detection on drawn boards with known corners, and the
//! errors for what cannot be opened. Live streams are tested against the world's camera
//! simulator in `mocks/tests/camera_opencv.rs`.
#![cfg(feature = "opencv")]

use robocal_drivers::camera::opencv::{
    find_chessboard, image_to_mat, read_image, write_image, CaptureConfig, Detector, Mode,
    VideoCaptureSource,
};
use robocal_drivers::camera::{Error, FolderSource};
use robocal_drivers::error::ErrorKind;
use robocal_drivers::traits::{Image, ImageSource};

fn tmp(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("robocal-ocv-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn gradient(w: u32, h: u32, k: u8) -> Image {
    let data = (0..w * h)
        .map(|i| {
            ((i % w) as u8)
                .wrapping_mul(3)
                .wrapping_add(k.wrapping_mul(40))
        })
        .collect();
    Image {
        width: w,
        height: h,
        data,
        t: 0.0,
    }
}

/// A chessboard of `sq`-pixel squares whose inner corner (i, j) is at pixel
/// (x0 + (i+1)·sq, y0 + (j+1)·sq) in OpenCV's convention (pixel centres at integers), each pixel
/// the exact area average of the squares it covers.
fn board(w: u32, h: u32, x0: f64, y0: f64, sq: f64, cols: u32, rows: u32) -> Image {
    // Overlaps of [a, b) with the cells of size sq: (cell index, length).
    let cells = |a: f64, b: f64| -> Vec<(i64, f64)> {
        let mut out = Vec::new();
        let mut k = (a / sq).floor() as i64;
        while (k as f64) * sq < b {
            let lo = a.max(k as f64 * sq);
            let hi = b.min((k + 1) as f64 * sq);
            if hi > lo {
                out.push((k, hi - lo));
            }
            k += 1;
        }
        out
    };
    let grey = |i: i64, j: i64| -> f64 {
        let inside = i >= 0 && j >= 0 && i <= cols as i64 && j <= rows as i64;
        if inside && (i + j) % 2 == 0 {
            20.0
        } else {
            230.0
        }
    };
    let mut data = vec![0u8; (w * h) as usize];
    for v in 0..h {
        let ys = cells(v as f64 - 0.5 - y0, v as f64 + 0.5 - y0);
        for u in 0..w {
            let xs = cells(u as f64 - 0.5 - x0, u as f64 + 0.5 - x0);
            let mut acc = 0.0f64;
            for &(i, lx) in &xs {
                for &(j, ly) in &ys {
                    acc += lx * ly * grey(i, j);
                }
            }
            data[(v * w + u) as usize] = acc.round() as u8;
        }
    }
    Image {
        width: w,
        height: h,
        data,
        t: 0.0,
    }
}

/// A camera's optics: Gaussian blur (OpenCV's), which keeps corners where they are.
fn blur(img: &Image, sigma: f64) -> Image {
    let m = image_to_mat(img).unwrap();
    let mut out = opencv::core::Mat::default();
    opencv::imgproc::gaussian_blur_def(&m, &mut out, opencv::core::Size::new(0, 0), sigma).unwrap();
    robocal_drivers::camera::opencv::mat_to_image(&out, 0.0).unwrap()
}

#[test]
fn png_and_pgm_round_trip_losslessly_and_folders_serve_them() {
    let d = tmp("files");
    let img = gradient(37, 21, 1);
    write_image(&d.join("a.png"), &img).unwrap();
    write_image(&d.join("b.pgm"), &gradient(5, 4, 2)).unwrap();
    write_image(&d.join("c.bmp"), &gradient(6, 3, 3)).unwrap();
    let back = read_image(&d.join("a.png")).unwrap();
    assert_eq!((back.width, back.height), (37, 21));
    assert_eq!(back.data, img.data, "PNG is lossless");
    // Our own PGM reader reads what OpenCV wrote.
    let bytes = std::fs::read(d.join("b.pgm")).unwrap();
    let (w, h, data) = robocal_drivers::camera::pgm::decode(&bytes).unwrap();
    assert_eq!((w, h, data), (5, 4, gradient(5, 4, 2).data));
    std::fs::write(d.join("d.jpg"), b"not a jpeg").unwrap();
    let src = FolderSource::open(&d, false).unwrap();
    assert_eq!(src.len(), 4, "png, pgm, bmp and jpg are listed");
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        assert_eq!(src.grab().await.unwrap().data, img.data);
        assert_eq!(src.grab().await.unwrap().width, 5);
        assert_eq!(src.grab().await.unwrap().data, gradient(6, 3, 3).data);
        let e = src.grab().await.unwrap_err();
        assert_eq!(e.kind(), ErrorKind::Protocol, "{e}");
        assert!(e.to_string().contains("d.jpg"), "{e}");
    });
    assert!(matches!(
        read_image(&d.join("missing.png")),
        Err(Error::Io { .. })
    ));
    std::fs::remove_dir_all(&d).unwrap();
}

#[tokio::test]
async fn image_sequence_reads_in_order_then_reports_exhausted() {
    let d = tmp("seq");
    for k in 0..5u8 {
        write_image(&d.join(format!("img_{k:03}.png")), &gradient(64, 48, k)).unwrap();
    }
    let cfg = CaptureConfig::new(d.join("img_%03d.png").display().to_string());
    assert_eq!(cfg.effective_mode(), Mode::Sequential);
    let src = VideoCaptureSource::open(cfg).unwrap();
    for k in 0..5u8 {
        let img = src.grab().await.unwrap();
        assert_eq!((img.width, img.height), (64, 48));
        assert_eq!(img.data, gradient(64, 48, k).data, "frame {k}");
    }
    let e = src.grab().await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Other);
    assert!(e.to_string().contains("no more images"), "{e}");
    std::fs::remove_dir_all(&d).unwrap();
}

#[tokio::test]
async fn video_file_written_by_opencv_reads_back_frame_by_frame() {
    use opencv::prelude::*;
    let d = tmp("video");
    let path = d.join("clip.avi");
    let fourcc = opencv::videoio::VideoWriter::fourcc('M', 'J', 'P', 'G').unwrap();
    let mut wr = opencv::videoio::VideoWriter::new(
        path.as_os_str(),
        fourcc,
        10.0,
        opencv::core::Size::new(64, 48),
        false,
    )
    .unwrap();
    assert!(wr.is_opened().unwrap(), "MJPG/AVI writer (FFmpeg backend)");
    let flat = |g: u8| Image {
        width: 64,
        height: 48,
        data: vec![g; 64 * 48],
        t: 0.0,
    };
    for g in [40u8, 120, 200] {
        wr.write(&image_to_mat(&flat(g)).unwrap()).unwrap();
    }
    wr.release().unwrap();
    let src = VideoCaptureSource::open(CaptureConfig::new(path.display().to_string())).unwrap();
    for g in [40u8, 120, 200] {
        let img = src.grab().await.unwrap();
        assert_eq!((img.width, img.height), (64, 48));
        let mean = img.data.iter().map(|&p| p as f64).sum::<f64>() / img.data.len() as f64;
        assert!((mean - g as f64).abs() < 3.0, "frame grey {mean} vs {g}");
    }
    assert!(src.grab().await.is_err(), "three frames only");
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn chessboard_corners_are_found_where_they_were_drawn() {
    let (cols, rows, sq) = (8u32, 5u32, 32.0);
    for (x0, y0) in [(60.0, 50.0), (61.3, 47.6), (75.75, 52.25)] {
        let img = blur(&board(400, 300, x0, y0, sq, cols, rows), 1.0);
        for det in [Detector::Classic, Detector::SectorBased] {
            let c = find_chessboard(&img, cols, rows, det)
                .unwrap()
                .unwrap_or_else(|| panic!("{det:?} found no board at ({x0}, {y0})"));
            assert_eq!(c.len(), (cols * rows) as usize);
            let mut worst = 0.0f64;
            for p in &c {
                // nearest drawn corner (the detector may start at either end)
                let best = (0..rows)
                    .flat_map(|j| (0..cols).map(move |i| (i, j)))
                    .map(|(i, j)| {
                        let (u, v) = (x0 + (i + 1) as f64 * sq, y0 + (j + 1) as f64 * sq);
                        ((p[0] - u).powi(2) + (p[1] - v).powi(2)).sqrt()
                    })
                    .fold(f64::INFINITY, f64::min);
                worst = worst.max(best);
            }
            println!("board at ({x0}, {y0}) {det:?}: worst corner error {worst:.4} px");
            assert!(worst < 0.1, "{det:?}: {worst} px");
        }
    }
    let blank = Image {
        width: 200,
        height: 100,
        data: vec![128; 20_000],
        t: 0.0,
    };
    assert_eq!(
        find_chessboard(&blank, 8, 5, Detector::Classic).unwrap(),
        None
    );
    assert!(matches!(
        find_chessboard(&blank, 1, 5, Detector::Classic),
        Err(Error::Invalid(_))
    ));
    let short = Image {
        width: 10,
        height: 10,
        data: vec![0; 99],
        t: 0.0,
    };
    assert!(matches!(
        find_chessboard(&short, 3, 3, Detector::Classic),
        Err(Error::Invalid(_))
    ));
}

#[test]
fn unopenable_targets_are_typed_errors_not_panics() {
    let e = VideoCaptureSource::open(CaptureConfig::new("/nonexistent/clip.avi")).unwrap_err();
    assert!(matches!(e, Error::Open { .. }), "{e}");
    // A camera index that does not exist on a CI machine.
    let e = VideoCaptureSource::open(CaptureConfig::new("/dev/video97")).unwrap_err();
    assert!(matches!(e, Error::Open { .. }), "{e}");
    // A stream nobody serves: refused quickly, within the open timeout.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut cfg = CaptureConfig::new(format!("http://127.0.0.1:{port}/video.mjpg"));
    cfg.timeout_s = 2.0;
    assert_eq!(cfg.effective_mode(), Mode::Live);
    let t0 = std::time::Instant::now();
    let e = VideoCaptureSource::open(cfg).unwrap_err();
    assert!(matches!(e, Error::Open { .. }), "{e}");
    assert!(t0.elapsed().as_secs_f64() < 10.0);
    let mut bad = CaptureConfig::new("x.avi");
    bad.timeout_s = f64::NAN;
    assert!(matches!(
        VideoCaptureSource::open(bad),
        Err(Error::Invalid(_))
    ));
}
