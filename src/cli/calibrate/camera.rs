//! `robocal calibrate camera --data D.jsonl --out DIR [--heldout H.jsonl]`: camera intrinsics
//! and hand-eye (seed 004). Library: [`crate::solve::camera`]. Writes `DIR/calibration.json`
//! (`kind: camera`, the `camera` block) and `DIR/camera_report.json` (every method side by
//! side), prints the table.
use std::path::PathBuf;

use anyhow::Context as _;
use serde_json::json;

use crate::solve::camera::calfile::{calibration_file, failure_report_json, report_json, table};
use crate::solve::camera::data::{load, unusable_lines, Overrides};
use crate::solve::camera::{self, DistModel, Mount, Options};

/// Arguments of `robocal calibrate camera`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Camera dataset: pose records with `flange` and/or `q` and an `image` (or `corners`).
    #[arg(long, value_name = "D.jsonl")]
    pub data: PathBuf,
    /// Output directory (`calibration.json`, `camera_report.json`).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Held-out camera dataset (never fitted): reprojection error of every method.
    #[arg(long, value_name = "H.jsonl")]
    pub heldout: Option<PathBuf>,
    /// Board inner corners COLSxROWS (overrides the header's `target`).
    #[arg(long, value_name = "COLSxROWS", value_parser = crate::cell::parse_board)]
    pub board: Option<(u32, u32)>,
    /// Board square edge (mm; overrides the header's `target.square_mm`).
    #[arg(long, value_name = "MM")]
    pub square: Option<f64>,
    /// Camera mount: `flange` (eye-in-hand) or `base` (eye-to-hand); default from the header.
    #[arg(long, value_parser = ["flange", "base"])]
    pub mount: Option<String>,
    /// Force a distortion model (`none`, `k1`, `k1-k2`, `k1-k2-p1-p2`, `k1-k2-p1-p2-k3`);
    /// default: chosen by validation error.
    #[arg(long)]
    pub distortion: Option<String>,
    /// Bootstrap refits over views (uncertainty).
    #[arg(long, default_value_t = 0)]
    pub bootstrap: usize,
    /// Also run seed 004's incremental Tsai–Lenz (update from 4 poses on, 2σ rejection,
    /// 80-of-130 random subsets × 50 averaged).
    #[arg(long)]
    pub incremental: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

fn parse_dist(s: &str) -> anyhow::Result<DistModel> {
    serde_json::from_value(json!(s)).map_err(|_| {
        anyhow::anyhow!(
            "--distortion {s:?}: expected none, k1, k1-k2, k1-k2-p1-p2 or k1-k2-p1-p2-k3"
        )
    })
}

/// Overrides from the command line.
pub fn overrides(board: Option<(u32, u32)>, square: Option<f64>, mount: Option<&str>) -> Overrides {
    Overrides {
        board,
        square_mm: square,
        mount: mount.map(|m| {
            if m == "base" {
                Mount::Base
            } else {
                Mount::Flange
            }
        }),
    }
}

/// Run `robocal calibrate camera`.
pub fn exec(a: Args) -> anyhow::Result<()> {
    crate::plausible::limits::bootstrap(a.bootstrap)?;
    let ov = overrides(a.board, a.square, a.mount.as_deref());
    let t0 = std::time::Instant::now();
    let train =
        load(&a.data, &ov, !a.quiet).with_context(|| format!("reading {}", a.data.display()))?;
    let held = match &a.heldout {
        Some(h) => {
            Some(load(h, &ov, !a.quiet).with_context(|| format!("reading {}", h.display()))?)
        }
        None => None,
    };
    let t_detect = t0.elapsed().as_secs_f64();
    let opts = Options {
        distortion: a.distortion.as_deref().map(parse_dist).transpose()?,
        bootstrap: a.bootstrap,
        incremental: a.incremental,
        ..Options::default()
    };
    for l in unusable_lines(&train, "training")
        .into_iter()
        .chain(held.iter().flat_map(|h| unusable_lines(h, "held-out")))
    {
        eprintln!("{l}");
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let res = match camera::calibrate(&train.data, held.as_ref().map(|h| &h.data), &opts) {
        Ok(r) => r,
        Err(e) => {
            // The report is written on failure too: it names every image that gave no view.
            let report = failure_report_json(&train, held.as_ref(), &e.to_string());
            let path = a.out.join("camera_report.json");
            crate::fsio::write(&path, serde_json::to_string_pretty(&report)? + "\n")
                .with_context(|| format!("writing {}", path.display()))?;
            let cause = crate::solve::camera::data::likely_cause(&train)
                .map(|c| format!("; {c}"))
                .unwrap_or_default();
            return Err(anyhow::Error::new(e).context(format!(
                "calibrating the camera of {} ({} images without a usable board are listed above and in {}{cause})",
                a.data.display(),
                train.no_board.len(),
                path.display()
            )));
        }
    };
    let t_total = t0.elapsed().as_secs_f64();
    let cal = calibration_file(&train, &res);
    crate::dataset::write_calibration(a.out.join("calibration.json"), &cal)?;
    let report = report_json(&train, held.as_ref(), &res, t_detect, t_total);
    crate::fsio::write(
        a.out.join("camera_report.json"),
        serde_json::to_string_pretty(&report)? + "\n",
    )
    .with_context(|| format!("writing {}", a.out.join("camera_report.json").display()))?;
    print!("{}", table(&train, held.as_ref(), &res));
    println!(
        "detection {t_detect:.2} s, total {t_total:.2} s; wrote {}",
        a.out.display()
    );
    Ok(())
}
