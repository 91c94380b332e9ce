//! Trials of the RCM endoscope calibration from rendered images (an evaluation harness beside
//! the examples: it reads the world's exact silhouettes to score, so it is no part of the
//! library), shared by `examples/rcm_images.rs` (prints the figures) and `tests/rcm_images.rs`
//! (asserts them).
//!
//! Each trial plans RCM poses (seed 002's pivoting about the trocar, reachable by the UR5e),
//! lets the simulated robot report them with its repeatability noise, renders every view
//! (`robocal_mocks::rcm_render`) and runs the line detector ([`robocal::solve::rcm::lines`]) on
//! the pixels. The world's exact silhouettes (`RcmCell::view`) score the detector, and the same
//! poses are calibrated three times: with the detected lines, with the exact lines and with the
//! exact lines plus 0.5 px end-point noise (what the simulator wrote before images). Truth is
//! read here, in an evaluation harness, only to score; the estimators see what a dataset holds.
use nalgebra::Isometry3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use robocal_mocks::rcm::{RcmCell, RcmScenario, RcmView};
use robocal_mocks::rcm_render::RcmRenderer;

use robocal::dataset::endoscope::EndoscopeCamera;
use robocal::model::KinematicModel;
use robocal::plan::rcm::{generate, RcmPlanSpec};
use robocal::solve::rcm::{self, lines, RcmData, RcmObs};

/// What to run.
#[derive(Debug, Clone)]
pub struct TrialOptions {
    /// Trials (each its own plan seed and noise).
    pub trials: usize,
    /// Planned poses per trial.
    pub poses: usize,
    /// Pivot range (± deg) and insertion depths (mm) of the plan.
    pub pivot_deg: f64,
    /// See `pivot_deg`.
    pub insertion_mm: [f64; 2],
    /// The robot's repeatability: σ of the reported instrument position (mm) and orientation
    /// (deg) per axis.
    pub robot_mm: f64,
    /// See `robot_mm`.
    pub robot_deg: f64,
    /// First seed.
    pub seed: u64,
}

impl Default for TrialOptions {
    fn default() -> Self {
        TrialOptions {
            trials: 20,
            poses: 20,
            pivot_deg: 25.0,
            insertion_mm: [50.0, 150.0],
            robot_mm: 0.05,
            robot_deg: 0.02,
            seed: 29,
        }
    }
}

/// Line error of one detected silhouette against the world's.
#[derive(Debug, Clone, Copy)]
pub struct LineError {
    /// Largest distance of the detected segment's end points from the true line (px).
    pub px: f64,
    /// Angle between the detected and the true line (deg).
    pub deg: f64,
}

/// Hand-eye (camera in base) error of one trial: translation mm, rotation deg.
pub type PoseErr = (f64, f64);

/// Everything the trials measured.
#[derive(Debug, Clone, Default)]
pub struct TrialResults {
    /// Views rendered (shaft in view).
    pub views: usize,
    /// Views the detector refused, with the reason.
    pub refused: Vec<String>,
    /// Per detected silhouette.
    pub line_errors: Vec<LineError>,
    /// The detector's own quality figure per view (end-point 1-σ, px).
    pub quality_px: Vec<f64>,
    /// Per trial: hand-eye error with detected lines, exact lines, exact + 0.5 px noise.
    pub hand_eye: Vec<[PoseErr; 3]>,
    /// Trials whose calibration failed (which lines, why).
    pub failed: Vec<String>,
    /// Wall time per view of the detector (s), mean.
    pub detect_secs: f64,
}

/// The endoscope block of the scenario's camera.
pub fn endoscope_camera(sc: &RcmScenario) -> EndoscopeCamera {
    let c = &sc.camera;
    EndoscopeCamera {
        kind: "endoscope".into(),
        width: c.width,
        height: c.height,
        fx: c.fx,
        fy: c.fy,
        cx: c.cx,
        cy: c.cy,
        dist: c.dist,
    }
}

fn line_error(seg: &[f64; 4], truth: &[[f64; 4]; 2]) -> LineError {
    let errs = truth.iter().map(|t| {
        let (dx, dy) = (t[2] - t[0], t[3] - t[1]);
        let n = (dx * dx + dy * dy).sqrt();
        let d = |u: f64, v: f64| ((u - t[0]) * dy - (v - t[1]) * dx).abs() / n;
        let px = d(seg[0], seg[1]).max(d(seg[2], seg[3]));
        let (ex, ey) = (seg[2] - seg[0], seg[3] - seg[1]);
        let c = ((ex * dx + ey * dy) / (n * (ex * ex + ey * ey).sqrt())).abs();
        LineError {
            px,
            deg: c.min(1.0).acos().to_degrees(),
        }
    });
    errs.min_by(|a, b| a.px.total_cmp(&b.px))
        .expect("two true lines")
}

/// Runs the trials on `scenario` (its `[render]` table renders the views).
pub fn run(scenario: &RcmScenario, opts: &TrialOptions) -> anyhow::Result<TrialResults> {
    let mut sc = scenario.clone();
    sc.noise.robot_mm = opts.robot_mm;
    sc.noise.robot_deg = opts.robot_deg;
    let cell = RcmCell::new(sc);
    let renderer = RcmRenderer::new(&cell, &cell.scenario.render);
    let cam = endoscope_camera(&cell.scenario);
    let radius = cell.scenario.instrument.shaft_radius_mm;
    let model = KinematicModel::preset(&cell.scenario.robot)
        .map_err(|e| anyhow::anyhow!("robot preset {}: {e}", cell.scenario.robot))?;
    let mut out = TrialResults::default();
    let mut detect_time = 0.0;
    for trial in 0..opts.trials {
        let seed = opts.seed + trial as u64;
        let spec = RcmPlanSpec {
            trocar_mm: cell.scenario.trocar_mm,
            insertion_dir: cell.scenario.insertion_dir,
            x_hint: [0.0, 1.0, 0.0],
            pivot_deg: opts.pivot_deg,
            insertion_mm: opts.insertion_mm,
            roll_deg: 10.0,
            count: opts.poses,
            seed,
            shaft_length_mm: 350.0,
        };
        let plan = generate(&spec, Some(&model))?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed * 7919 + 1);
        let mut sets: [Vec<RcmObs>; 3] = Default::default();
        for (i, p) in plan.iter().enumerate() {
            let truth = p.instrument;
            let Some(view) = cell.view(&truth) else {
                continue;
            };
            out.views += 1;
            let reported = cell.reported(&truth, &mut rng);
            let im = renderer.render(&truth, seed * 1000 + i as u64);
            let t0 = std::time::Instant::now();
            let det = lines::detect(
                &im.data,
                im.width,
                im.height,
                &cam,
                &lines::LineOptions::default(),
            );
            detect_time += t0.elapsed().as_secs_f64();
            let d = match det {
                Ok(d) => d,
                Err(why) => {
                    out.refused
                        .push(format!("trial {trial} pose {}: {why}", i + 1));
                    continue;
                }
            };
            for l in &d.lines {
                out.line_errors.push(line_error(&l.seg, &view.shaft_lines));
            }
            out.quality_px.push(d.sigma_px());
            let noisy = noisy_view(&cell, &truth, &mut rng);
            for (k, segs) in [d.segs(), view.shaft_lines, noisy.shaft_lines]
                .into_iter()
                .enumerate()
            {
                sets[k].push(RcmObs {
                    id: i as u64 + 1,
                    line: i + 2,
                    flange: reported,
                    segs,
                });
            }
        }
        let mut errs = [(f64::NAN, f64::NAN); 3];
        let mut ok = true;
        for (k, obs) in sets.into_iter().enumerate() {
            let data = RcmData::new(cam.clone(), radius, obs);
            match rcm::calibrate(
                &data,
                &rcm::RcmOptions {
                    bootstrap: 0,
                    seed: 0,
                },
            ) {
                Ok(r) => errs[k] = rcm::pose_error(&r.ml.pose, &cell.camera),
                Err(e) => {
                    ok = false;
                    let what = ["detected", "exact", "exact + 0.5 px"][k];
                    out.failed
                        .push(format!("trial {trial} ({what} lines): {e}"));
                }
            }
        }
        if ok {
            out.hand_eye.push(errs);
        }
    }
    out.detect_secs = detect_time / (out.views.max(1)) as f64;
    Ok(out)
}

/// The exact view with the simulator's former end-point noise (0.5 px).
fn noisy_view(cell: &RcmCell, truth: &Isometry3<f64>, rng: &mut ChaCha8Rng) -> RcmView {
    cell.view_noisy(truth, Some(0.5), rng)
        .expect("the exact view exists")
}

/// Median of a list (NaN when empty).
pub fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
}

/// Quantile `q ∈ [0, 1]` (nearest rank; NaN when empty).
pub fn quantile(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[((q * (s.len() - 1) as f64).round() as usize).min(s.len() - 1)]
}

/// The results as text (what the example prints).
pub fn text(opts: &TrialOptions, r: &TrialResults) -> String {
    let px: Vec<f64> = r.line_errors.iter().map(|e| e.px).collect();
    let deg: Vec<f64> = r.line_errors.iter().map(|e| e.deg).collect();
    let col = |k: usize, f: fn(&PoseErr) -> f64| -> Vec<f64> {
        r.hand_eye.iter().map(|e| f(&e[k])).collect()
    };
    let mut s = format!(
        "RCM from rendered images: {} trials x {} planned poses (±{}° pivot, {}–{} mm insertion), robot repeatability {} mm / {}°\n",
        opts.trials, opts.poses, opts.pivot_deg, opts.insertion_mm[0], opts.insertion_mm[1], opts.robot_mm, opts.robot_deg
    );
    s += &format!(
        "views {}; refused by the detector {}; detector {:.2} s/view\n",
        r.views,
        r.refused.len(),
        r.detect_secs
    );
    s += &format!(
        "line error vs the world's silhouettes over {} lines: px median {:.3}, p95 {:.3}, max {:.3}; deg median {:.4}, p95 {:.4}, max {:.4}\n",
        px.len(),
        median(&px),
        quantile(&px, 0.95),
        quantile(&px, 1.0),
        median(&deg),
        quantile(&deg, 0.95),
        quantile(&deg, 1.0)
    );
    s += &format!(
        "detector quality figure (end-point 1-σ): median {:.3} px, max {:.3} px\n",
        median(&r.quality_px),
        quantile(&r.quality_px, 1.0)
    );
    s += &format!(
        "hand-eye error over {} trials (median / max):\n",
        r.hand_eye.len()
    );
    for (k, name) in ["detected lines", "exact lines", "exact + 0.5 px"]
        .iter()
        .enumerate()
    {
        let t = col(k, |e| e.0);
        let a = col(k, |e| e.1);
        s += &format!(
            "  {name:<15} {:.3} / {:.3} mm, {:.4} / {:.4} deg\n",
            median(&t),
            quantile(&t, 1.0),
            median(&a),
            quantile(&a, 1.0)
        );
    }
    let (td, te) = (median(&col(0, |e| e.0)), median(&col(1, |e| e.0)));
    let (ad, ae) = (median(&col(0, |e| e.1)), median(&col(1, |e| e.1)));
    s += &format!(
        "  ratio detected / exact (medians): {:.2} (mm), {:.2} (deg)\n",
        td / te,
        ad / ae
    );
    for f in &r.failed {
        s += &format!("  calibration failed: {f}\n");
    }
    for f in r.refused.iter().take(10) {
        s += &format!("  refused: {f}\n");
    }
    s
}
