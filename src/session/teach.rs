//! Seed 004's hand-guided start of a camera session (`session --teach-board N`):
//! before planning, the operator guides the arm by hand (DENSO: its teach pendant holds the
//! arm and robocal only reads it; nothing is commanded) to N ≥ 4 poses where the camera sees
//! the whole board. At each pose the joints are averaged over the rest window
//! ([`crate::capture::poses`]) and one image is grabbed. From these views alone: the
//! intrinsics (Zhang's closed form, then a fit), the board in the camera per view, the initial
//! hand-eye by Tsai–Lenz (the seed: "four drag samples give the initial hand-eye") and so the
//! board in the robot base. The shell of viewpoints is then centred on it, instead of on a
//! centre typed into the cell file.
use std::path::Path;

use anyhow::{bail, Context as _};
use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

use super::{rel, write_atomic, Cell, Log, SessionFile};
use crate::model::KinematicModel;
use crate::solve::camera::detect::{detect_chessboard, BoardSpec};
use crate::solve::camera::handeye::{motion_pairs, solve as solve_handeye, Method};
use crate::solve::camera::intrinsics::calibrate_intrinsics;
use crate::solve::camera::{CameraData, DistModel, Mount, View};

/// Fewest taught poses (seed 004: four).
pub const MIN_POSES: usize = 4;
/// Most taught poses.
pub const MAX_POSES: usize = 20;

/// One taught pose and the image grabbed there.
#[derive(Debug, Clone)]
pub struct TaughtView {
    /// `P1`, `P2`, …
    pub name: String,
    /// Joint angles averaged over the rest window (deg).
    pub q_deg: Vec<f64>,
    /// The camera image at the pose.
    pub image: robocal_drivers::Image,
}

/// What the taught poses found (`session.json` `teach`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TeachSummary {
    /// Poses taught.
    pub poses: usize,
    /// Of them, views where the whole board was detected (used).
    pub views_with_board: usize,
    /// The board's centre in the robot base found from the views (mm): the shell's centre.
    pub center_mm: [f64; 3],
    /// The centre the cell file stated, if any (mm).
    pub center_stated_mm: Option<[f64; 3]>,
    /// How the camera's mount on the flange was found: `tsai-lenz` from the taught views, or
    /// `nominal` (the plan spec's camera mount) when the views' rotations do not determine it.
    pub hand_eye: String,
    /// The camera's position in the flange used (mm).
    pub hand_eye_xyz_mm: [f64; 3],
    /// Focal length from the views (px) and the fit's RMS (px).
    pub fx_px: f64,
    pub rms_px: f64,
    /// RMS of the per-view board centres about their mean (mm): how well the views agree.
    pub spread_mm: f64,
    /// The taught joints (`name,j1_deg,…`), relative to the session directory.
    pub file: String,
}

/// Reads `count` taught poses and an image at each from the cell (`cell_file` of `mode`
/// `sim` / `live`): the arm is opened but never commanded, only its joints read.
pub fn capture_views(
    mode: &str,
    cell_file: &Path,
    count: usize,
    in_process: bool,
    consent: Option<&crate::cell::LiveConsent>,
    log: Log,
) -> anyhow::Result<Vec<TaughtView>> {
    use crate::capture::poses::{capture_poses, PoseOptions};
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let cell = crate::cell::source::source(
        mode,
        cell_file,
        crate::cell::OpenOptions {
            // A dry run's operator moves on the simulated clock the reads advance.
            virtual_clock: mode == "sim",
            in_process,
            dof: 6,
            camera: true,
        },
    )?;
    let opened = cell.open(&rt, consent)?;
    let d = &opened.devices;
    let camera = d
        .camera
        .clone()
        .with_context(|| format!("{}: the cell has no camera", cell_file.display()))?;
    let (arm, clock) = (d.arm.clone(), d.clock.clone());
    let out = rt.block_on(async {
        let mut views = Vec::new();
        let opt = PoseOptions {
            count: 1,
            max_seconds: 300.0,
            ..PoseOptions::default()
        };
        let keys = crate::capture::Keys::new();
        for i in 1..=count {
            log(&format!(
                "  guide the arm to pose P{i} of {count} (the whole board in the camera's view) \
                 and hold it still"
            ));
            let mut quiet = |l: &str| {
                if l.starts_with("  not recorded") {
                    eprintln!("{l}");
                }
            };
            let p = capture_poses(&*arm, &*clock, &opt, &keys, &mut quiet)
                .await
                .with_context(|| format!("teaching pose P{i} of {count}"))?;
            // Frames already in flight may show the arm still moving: the image is taken
            // once consecutive frames agree.
            let shot = crate::capture::settle::settled_grab(&*camera)
                .await
                .with_context(|| format!("the camera image at taught pose P{i}"))?;
            if !shot.settled {
                log(&format!(
                    "  P{i}: the camera image kept changing over {} frames (by up to {:.1} grey \
                     levels): the arm or the board moved; the last frame is used",
                    shot.grabs, shot.change_grey
                ));
            }
            let image = shot.image;
            let q = &p[0].q_deg;
            log(&format!(
                "  P{i}: [{}] deg (range {:.4}°), image {}×{}",
                q.iter()
                    .map(|x| format!("{x:.2}"))
                    .collect::<Vec<_>>()
                    .join(", "),
                p[0].range_deg,
                image.width,
                image.height
            ));
            views.push(TaughtView {
                name: format!("P{i}"),
                q_deg: q.clone(),
                image,
            });
        }
        anyhow::Ok(views)
    });
    if let Some(stop) = opened.stop {
        stop();
    }
    out
}

/// Where the taught views put the board (see the module docs).
#[derive(Debug, Clone)]
pub struct Located {
    /// Board centre in the base (mm).
    pub center: Point3<f64>,
    /// Views with the board.
    pub used: usize,
    /// `tsai-lenz` or `nominal`.
    pub hand_eye: &'static str,
    /// Camera in the flange used.
    pub camera_in_flange: Isometry3<f64>,
    pub fx_px: f64,
    pub rms_px: f64,
    pub spread_mm: f64,
}

/// Locates the board `board` in the base from the taught views: `model` gives the flange
/// poses, `nominal` the camera mount used when the views do not determine the hand-eye.
pub fn locate(
    views: &[TaughtView],
    board: BoardSpec,
    model: &KinematicModel,
    nominal: &Isometry3<f64>,
) -> anyhow::Result<Located> {
    let mut used = Vec::new();
    let mut refused = Vec::new();
    for (k, v) in views.iter().enumerate() {
        match detect_chessboard(&v.image.data, v.image.width, v.image.height, &board) {
            Ok(c) => {
                let q: Vec<f64> = v.q_deg.iter().map(|x| x.to_radians()).collect();
                used.push(View {
                    id: k as u64 + 1,
                    flange: model.flange_pose(&q),
                    corners: c.into_iter().map(Some).collect(),
                });
            }
            Err(e) => refused.push(format!("{}: {e}", v.name)),
        }
    }
    if used.len() < 3 {
        bail!(
            "the board ({}×{} inner corners, {} mm squares) was found whole in {} of {} taught \
             views (need 3; {}): guide the arm so that the whole board is in the camera's view \
             at each pose, from different directions",
            board.cols,
            board.rows,
            board.square_mm,
            used.len(),
            views.len(),
            if refused.is_empty() {
                "none refused".into()
            } else {
                refused.join("; ")
            }
        );
    }
    let (w, h) = (views[0].image.width, views[0].image.height);
    let data = CameraData {
        width: w,
        height: h,
        board,
        mount: Mount::Flange,
        views: used,
    };
    let fit = calibrate_intrinsics(&data, DistModel::K1)
        .or_else(|_| calibrate_intrinsics(&data, DistModel::None))
        .context("intrinsics from the taught views")?;
    let flanges: Vec<Isometry3<f64>> = data.views.iter().map(|v| v.flange).collect();
    let pairs = motion_pairs(&flanges, &fit.poses, 5.0);
    // A hand-eye is trusted only when it puts the camera near the flange (within 0.5 m) and
    // the views agree on the board; else the plan spec's nominal mount.
    let centre_local = Point3::new(
        (board.cols + 1) as f64 * board.square_mm / 2.0,
        (board.rows + 1) as f64 * board.square_mm / 2.0,
        0.0,
    );
    let centres = |x: &Isometry3<f64>| -> Vec<Point3<f64>> {
        flanges
            .iter()
            .zip(&fit.poses)
            .map(|(f, b)| f * x * b * centre_local)
            .collect()
    };
    let solved = solve_handeye(Method::TsaiLenz, &pairs).filter(|x| {
        x.translation.vector.norm() < 500.0 && x.translation.vector.iter().all(|v| v.is_finite())
    });
    let (x, how) = match solved {
        Some(x) => (x, "tsai-lenz"),
        None => (*nominal, "nominal"),
    };
    let pts = centres(&x);
    let (mean, spread) = crate::capture::mean_spread(&pts);
    let (mean, spread, x, how) = if how == "tsai-lenz" && spread > 20.0 {
        let pts = centres(nominal);
        let (m, s) = crate::capture::mean_spread(&pts);
        (m, s, *nominal, "nominal")
    } else {
        (mean, spread, x, how)
    };
    anyhow::ensure!(
        mean.coords.iter().all(|v| v.is_finite()),
        "the taught views give no finite board position"
    );
    Ok(Located {
        center: mean,
        used: data.views.len(),
        hand_eye: how,
        camera_in_flange: x,
        fx_px: fit.k.fx,
        rms_px: fit.rms_px,
        spread_mm: spread,
    })
}

/// The teach step of a session (before planning; once): reads the taught views through
/// `cell`, locates the board, writes `teach/poses.csv`, and centres the session's board (so
/// the shell plan) on it.
pub fn run(dir: &Path, s: &mut SessionFile, cell: &mut dyn Cell, log: Log) -> anyhow::Result<()> {
    if s.teach.is_some() || s.setup.teach_board == 0 {
        return Ok(());
    }
    let Some(b) = s.cell.camera.as_ref().and_then(|c| c.board.clone()) else {
        bail!("--teach-board: the cell states no board (kind, cols, rows, square_mm)");
    };
    anyhow::ensure!(
        b.kind == "chessboard",
        "--teach-board: the board is a {:?}; the taught views are detected as a chessboard",
        b.kind
    );
    log(&format!(
        "teach: {} hand-guided poses locate the board (nothing is commanded: guide the arm)",
        s.setup.teach_board
    ));
    let views = cell.teach_views(s.setup.teach_board, &mut *log)?;
    let model = KinematicModel::preset(&s.cell.robot_model).context("the cell's robot")?;
    let spec_path = dir.join(&s.setup.spec_file);
    let spec = crate::plan::PlanSpec::from_file(&spec_path)
        .with_context(|| format!("reading {}", spec_path.display()))?;
    let nominal = crate::plan::frame_iso(&spec.tool);
    let board = BoardSpec {
        cols: b.cols as usize,
        rows: b.rows as usize,
        square_mm: b.square_mm,
    };
    let found = locate(&views, board, &model, &nominal)?;
    let csv = crate::capture::poses::poses_csv(
        &views
            .iter()
            .map(|v| crate::capture::poses::TaughtPose {
                name: v.name.clone(),
                q_deg: v.q_deg.clone(),
                range_deg: 0.0,
                samples: 0,
            })
            .collect::<Vec<_>>(),
    );
    let file = dir.join("teach").join("poses.csv");
    write_atomic(&file, csv.as_bytes())?;
    // A device file may leave the centre out (the taught views find it).
    let stated_center = match s.setup.mode {
        super::Mode::Sim => Some(b.center_mm),
        super::Mode::Live => {
            crate::acquire::devices::DevicesFile::read(dir.join(&s.setup.cell_file))
                .ok()
                .and_then(|f| f.board)
                .and_then(|b| b.center_mm)
        }
    };
    let c = found.center;
    let t = found.camera_in_flange.translation.vector;
    let summary = TeachSummary {
        poses: views.len(),
        views_with_board: found.used,
        center_mm: [c.x, c.y, c.z],
        center_stated_mm: stated_center,
        hand_eye: found.hand_eye.into(),
        hand_eye_xyz_mm: [t.x, t.y, t.z],
        fx_px: found.fx_px,
        rms_px: found.rms_px,
        spread_mm: found.spread_mm,
        file: rel(dir, &file),
    };
    log(&format!("  {}", words(&summary)));
    if let Some(board) = s.cell.camera.as_mut().and_then(|c| c.board.as_mut()) {
        board.center_mm = summary.center_mm;
    }
    s.teach = Some(summary);
    s.save(&dir.join("session.json"))
}

/// The teach step in one sentence.
pub fn words(t: &TeachSummary) -> String {
    let [x, y, z] = t.center_mm;
    let stated = t.center_stated_mm.map_or(String::new(), |c| {
        let d = ((c[0] - x).powi(2) + (c[1] - y).powi(2) + (c[2] - z).powi(2)).sqrt();
        format!(" ({d:.1} mm from the cell file's centre)")
    });
    format!(
        "board centre ({x:.1}, {y:.1}, {z:.1}) mm in the base from {} of {} taught views{stated}; \
         hand-eye {} (camera at {:.1}, {:.1}, {:.1} mm on the flange), fx {:.0} px, fit RMS \
         {:.2} px, views agree to {:.1} mm RMS",
        t.views_with_board,
        t.poses,
        if t.hand_eye == "tsai-lenz" {
            "by Tsai–Lenz from the taught views"
        } else {
            "the plan spec's nominal mount (the views' rotations do not determine it)"
        },
        t.hand_eye_xyz_mm[0],
        t.hand_eye_xyz_mm[1],
        t.hand_eye_xyz_mm[2],
        t.fx_px,
        t.rms_px,
        t.spread_mm
    )
}
