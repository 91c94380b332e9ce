//! `robocal session --navchain`: a kinematic session closed with seed 003's
//! correction network, trained on the session's training poses on top of its geometric
//! calibration (`calibrate/calibration.json`), scored on its held-out poses with the predictor
//! `robocal predict` uses, and reported beside the physical diagnosis validated on the same
//! poses. Writes `navchain/calibration.json` (the geometric calibration with the network:
//! `robocal predict` / `robocal correct` apply it). The verdict stays the diagnosed model's.
use std::path::Path;
use std::time::Instant;

use anyhow::Context as _;
use serde::{Deserialize, Serialize};

use super::{SessionFile, Work};
use crate::dataset::CalibrationFile;
use crate::navchain::nn::NetOptions;

/// Where the stage writes the calibration with the network (relative to the session).
pub const NAVCHAIN_CALIBRATION: &str = "navchain/calibration.json";

/// The network beside the physical diagnosis on the session's held-out poses (mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NavchainSummary {
    /// The calibration file with the network ([`NAVCHAIN_CALIBRATION`]).
    pub calibration: String,
    /// 6–`hidden`–6, `epochs` of full-batch Adam.
    pub hidden: usize,
    pub epochs: usize,
    pub train_poses: usize,
    pub heldout_poses: usize,
    /// Training RMS: geometric calibration, + network.
    pub train_rms_mm_geometric: f64,
    pub train_rms_mm_network: f64,
    /// Held-out RMS: geometric calibration, + network, the physical diagnosis (the session's
    /// validated "after", same held-out poses).
    pub heldout_rms_mm_geometric: f64,
    pub heldout_rms_mm_network: f64,
    pub heldout_rms_mm_diagnosis: Option<f64>,
    /// Wall time of the training (s).
    pub train_seconds: f64,
}

/// Trains, scores and writes the network of the session in `dir` (after its validation).
pub fn stage(dir: &Path, s: &mut SessionFile, work: &mut Work) -> anyhow::Result<()> {
    let cal_path = dir.join("calibrate").join("calibration.json");
    let cal = CalibrationFile::load(&cal_path)
        .with_context(|| format!("the session's geometric calibration {}", cal_path.display()))?;
    let val = work.dataset(dir, s, "validation")?.1.dataset.clone();
    let train = &work.dataset(dir, s, "train")?.1.dataset;
    let opts = NetOptions::default();
    let t0 = Instant::now();
    let mut out = crate::navchain::correction::train(&cal, train, Some(&val), &opts)
        .context("the session's correction network (--navchain)")?;
    let secs = t0.elapsed().as_secs_f64();
    out.extra.insert("datasets".into(), s.dataset_hashes());
    let block = crate::navchain::correction::from_calibration(&out)?
        .context("the trained calibration has no network block")?;
    let path = dir.join(NAVCHAIN_CALIBRATION);
    std::fs::create_dir_all(path.parent().unwrap_or(dir))?;
    out.save(&path)
        .with_context(|| format!("writing {}", path.display()))?;
    s.navchain = Some(NavchainSummary {
        calibration: NAVCHAIN_CALIBRATION.into(),
        hidden: block.hidden,
        epochs: block.epochs,
        train_poses: block.train_poses,
        heldout_poses: block.heldout_poses.unwrap_or(0),
        train_rms_mm_geometric: block.train_rms_mm_before,
        train_rms_mm_network: block.train_rms_mm_after,
        heldout_rms_mm_geometric: block.heldout_rms_mm_before.unwrap_or(f64::NAN),
        heldout_rms_mm_network: block.heldout_rms_mm_after.unwrap_or(f64::NAN),
        heldout_rms_mm_diagnosis: s.measured.heldout_rms_mm_after,
        train_seconds: secs,
    });
    Ok(())
}

/// One line for the console.
pub fn text(n: &NavchainSummary) -> String {
    format!(
        "navchain (seed 003 network 6-{}-6 on {} training poses, {:.1} s): held-out RMS over {} \
         poses: geometric {:.4} mm, + network {:.4} mm, physical diagnosis {} (training: {:.4} → \
         {:.4} mm); {}",
        n.hidden,
        n.train_poses,
        n.train_seconds,
        n.heldout_poses,
        n.heldout_rms_mm_geometric,
        n.heldout_rms_mm_network,
        n.heldout_rms_mm_diagnosis
            .map_or("—".into(), |d| format!("{d:.4} mm")),
        n.train_rms_mm_geometric,
        n.train_rms_mm_network,
        n.calibration
    )
}

/// The report section.
pub fn html(n: &NavchainSummary) -> String {
    let f = |v: f64| format!("{v:.4}");
    format!(
        "<h2>Correction network (seed 003) beside the physical diagnosis</h2>\
         <p id=\"navchain\">A 6-{}-6 network ({} epochs) trained on what the geometric \
         calibration leaves on the {} training poses ({:.1} s), scored on the same {} held-out \
         poses as the diagnosis. The verdict is the diagnosed model's; the network is in \
         <code>{}</code>.</p>\
         <table id=\"navchain-heldout\"><tr><th>model</th><th>training RMS (mm)</th>\
         <th>held-out RMS (mm)</th></tr>\
         <tr><td>geometric calibration</td><td>{}</td><td>{}</td></tr>\
         <tr><td>geometric + network</td><td>{}</td><td>{}</td></tr>\
         <tr><td>physical diagnosis (deployed)</td><td>—</td><td>{}</td></tr></table>",
        n.hidden,
        n.epochs,
        n.train_poses,
        n.train_seconds,
        n.heldout_poses,
        n.calibration,
        f(n.train_rms_mm_geometric),
        f(n.heldout_rms_mm_geometric),
        f(n.train_rms_mm_network),
        f(n.heldout_rms_mm_network),
        n.heldout_rms_mm_diagnosis.map_or("—".into(), f)
    )
}

/// Where the session's chain stage writes its calibration with a bootstrap covariance.
pub const CHAIN_CALIBRATION: &str = "chain/calibration.json";

/// Bootstrap fits of the chain's robot link (subsets of 75 % of the training poses).
const CHAIN_BOOTSTRAP_K: usize = 100;

/// The robot link of a session's chain report: the calibration file carrying the bootstrap
/// covariance of the geometric calibration, the joints (deg) it is propagated at, and what
/// to tell the user.
#[derive(Debug, Clone)]
pub struct ChainRobotLink {
    pub calibration: std::path::PathBuf,
    pub joints_deg: Vec<f64>,
    pub notes: Vec<String>,
}

/// The session's chain robot link (the calibration's bootstrap covariance, not
/// one robot σ): the geometric identification of the training poses is bootstrapped
/// ([`CHAIN_BOOTSTRAP_K`] fits on 75 % subsets), its parameter covariance written with the
/// calibration to [`CHAIN_CALIBRATION`] and propagated to the tip at `joints_deg`, or, when
/// none are given, at the held-out pose whose tool is nearest the CT targets' centroid in the
/// robot base (`Y · T · x̄`, registration and robot-world files).
pub fn chain_robot_link(
    dir: &Path,
    registration: &Path,
    robot_world: &Path,
    targets: &Path,
    joints_deg: Option<&[f64]>,
) -> anyhow::Result<ChainRobotLink> {
    use crate::solve::bootstrap::{bootstrap, BootstrapOptions};
    let s = SessionFile::load(&dir.join("session.json"))?;
    let mut work = Work::default();
    let robot = work
        .dataset(dir, &s, "train")?
        .1
        .dataset
        .header
        .robot
        .clone();
    let res = work.identification(dir, &s)?;
    let bo = BootstrapOptions {
        k: CHAIN_BOOTSTRAP_K,
        ..Default::default()
    };
    let b = bootstrap(res, &[], &bo).context("bootstrapping the session's calibration")?;
    let mut file = crate::solve::calfile::ident_file(&robot, res);
    file.extra.insert("datasets".into(), s.dataset_hashes());
    file.extra.insert(
        "bootstrap".into(),
        serde_json::json!({"k": CHAIN_BOOTSTRAP_K, "converged": b.samples.len(),
            "subset": b.subset_size, "seed": bo.seed, "seconds": b.elapsed_s,
            "covariance": crate::navchain::BootstrapCovariance::from_samples(&b.names, &b.samples)}),
    );
    let path = dir.join(CHAIN_CALIBRATION);
    std::fs::create_dir_all(path.parent().unwrap_or(dir))?;
    file.save(&path)
        .with_context(|| format!("writing {}", path.display()))?;
    let mut notes = vec![format!(
        "robot link: bootstrap covariance of the session's geometric calibration ({} of {} fits \
         on {} of {} training poses, {:.1} s), written to {CHAIN_CALIBRATION}",
        b.samples.len(),
        CHAIN_BOOTSTRAP_K,
        b.subset_size,
        res.train_obs.len(),
        b.elapsed_s
    )];
    let joints_deg = match joints_deg {
        Some(q) => q.to_vec(),
        None => {
            let reg = crate::register::RegistrationFile::load(registration)?;
            let (y, _) = crate::register::robot_world::RobotWorldFile::load(robot_world)?.y()?;
            let t = reg.transform()?;
            let pts = crate::register::points::read_points_csv(targets)?;
            anyhow::ensure!(!pts.is_empty(), "{}: no CT target", targets.display());
            let c = pts
                .iter()
                .fold(nalgebra::Vector3::zeros(), |a, p| a + p.p.coords)
                / pts.len() as f64;
            let goal = y * (t * nalgebra::Point3::from(c));
            let (o, d) = res
                .heldout_obs
                .iter()
                .map(|o| {
                    let p = res.model.tool_pose_in_base(&o.q).translation.vector;
                    (o, (p - goal.coords).norm())
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .context("no held-out pose to take the joints of the chain's robot link from")?;
            notes.push(format!(
                "robot link at the joints of held-out pose {} (tool {d:.1} mm from the targets' \
                 centroid in the robot base; give --chain-joints-deg for the pose that reaches them)",
                o.id
            ));
            o.q.iter().map(|x| x.to_degrees()).collect()
        }
    };
    if let Some(r) = s.measured.heldout_rms_mm_after {
        notes.push(format!(
            "for comparison: the deployed model's measured held-out RMS is {r:.4} mm (validation \
             run, tracker noise included); this link is the geometric calibration's parameter \
             uncertainty only"
        ));
    }
    Ok(ChainRobotLink {
        calibration: path,
        joints_deg,
        notes,
    })
}
