//! Seed 003's correction network as a calibration stage: trained on the residual a kinematic
//! calibration leaves on a dataset's poses (measured marker − the calibration's prediction),
//! stored in the calibration file (`extra.navchain_net`, [`crate::schema::navnet`]) and added
//! by [`crate::solve::predict::Predictor`] to every kinematic prediction.
//!
//! `robocal calibrate navchain` is the command; the held-out RMS before / after is measured on
//! a separate file with the same predictor `robocal predict` uses.
use std::collections::HashMap;
use std::path::Path;

use anyhow::Context as _;
use nalgebra::{Point3, Vector3};

use crate::dataset::{CalibrationFile, CalibrationKind, Dataset, PoseRecord};
use crate::model::KinematicModel;
use crate::navchain::nn::{NetOptions, SeedNet};
use crate::schema::navnet::{NavNetBlock, NAVNET_FORMAT, NAVNET_INPUTS, NAVNET_KEY};
use crate::solve::obs::session_observations;
use crate::solve::predict::Predictor;

/// The network's input at joints `q` (rad): the tool pose in the base, mm and degrees.
pub fn pose_inputs(model: &KinematicModel, q_rad: &[f64]) -> [f64; 6] {
    let t = model.tool_pose_in_base(q_rad);
    let (r, p, y) = t.rotation.euler_angles();
    let v = t.translation.vector;
    [
        v.x,
        v.y,
        v.z,
        r.to_degrees(),
        p.to_degrees(),
        y.to_degrees(),
    ]
}

/// The correction (mm) the block adds at joints `q` (rad).
pub fn correction(block: &NavNetBlock, model: &KinematicModel, q_rad: &[f64]) -> Vector3<f64> {
    let c = block.net.predict(&pose_inputs(model, q_rad));
    Vector3::new(c[0], c[1], c[2])
}

/// The block of a calibration file, checked (None when it has none).
pub fn from_calibration(cal: &CalibrationFile) -> anyhow::Result<Option<NavNetBlock>> {
    let Some(v) = cal.extra.get(NAVNET_KEY) else {
        return Ok(None);
    };
    let block: NavNetBlock = serde_json::from_value(v.clone())
        .map_err(|e| anyhow::anyhow!("field `{NAVNET_KEY}`: {e}"))?;
    block
        .check()
        .map_err(|e| anyhow::anyhow!("field `{NAVNET_KEY}`: {e}"))?;
    Ok(Some(block))
}

/// The kinematic model of a calibration file (its params applied).
fn model_of(cal: &CalibrationFile) -> anyhow::Result<KinematicModel> {
    let mut model = KinematicModel::from_robot_block(&cal.robot)
        .context("building the kinematic model of the calibration's robot block")?;
    model
        .apply_cal_params(&cal.params)
        .context("applying the calibration's params")?;
    Ok(model)
}

/// (network input, residual measured − predicted) of every usable pose of `ds`.
fn residuals(
    pred: &Predictor,
    model: &KinematicModel,
    ds: &Dataset,
    session: &[&PoseRecord],
) -> anyhow::Result<Vec<([f64; 6], Vector3<f64>)>> {
    let (rows, _) = pred.predict_in_session(ds, session)?;
    let by_id: HashMap<u64, Point3<f64>> = rows.iter().map(|r| (r.id, r.p)).collect();
    let recs: Vec<&PoseRecord> = ds.poses().collect();
    let all: Vec<&PoseRecord> = recs.iter().chain(session).copied().collect();
    let obs = session_observations(&recs, &all, model.dof()).0;
    Ok(obs
        .iter()
        .filter_map(|o| {
            let p = by_id.get(&o.ctx.id)?;
            Some((pose_inputs(model, &o.ctx.q), o.p - p))
        })
        .collect())
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v {
        s += x;
        n += 1;
    }
    (s / n.max(1) as f64).sqrt()
}

/// RMS (mm) of the residuals before and after the network.
fn before_after(net: &SeedNet, r: &[([f64; 6], Vector3<f64>)]) -> (f64, f64) {
    let before = rms(r.iter().map(|(_, e)| e.norm_squared()));
    let after = rms(r.iter().map(|(x, e)| {
        let c = net.predict(x);
        (e - Vector3::new(c[0], c[1], c[2])).norm_squared()
    }));
    (before, after)
}

/// Trains the network on `train` (context from `heldout`'s records is not used) on top of
/// the kinematic calibration `cal`, scores it on `heldout` (the training records as the
/// session context, as `robocal predict --session` does), and returns `cal` with the block.
pub fn train(
    cal: &CalibrationFile,
    train: &Dataset,
    heldout: Option<&Dataset>,
    opts: &NetOptions,
) -> anyhow::Result<CalibrationFile> {
    if cal.kind() != CalibrationKind::Kinematic {
        anyhow::bail!(
            "the correction network goes on top of a kinematic calibration; this one is {:?}",
            cal.kind()
        );
    }
    let mut base = cal.clone();
    base.extra.remove(NAVNET_KEY);
    let model = model_of(&base)?;
    let pred = Predictor::new(&base)?;
    let tr = residuals(&pred, &model, train, &[])?;
    const MIN_POSES: usize = 30;
    if tr.len() < MIN_POSES {
        anyhow::bail!(
            "{} usable training poses (with joints and a marker measurement): the network \
             needs at least {MIN_POSES}",
            tr.len()
        );
    }
    let xs: Vec<[f64; 6]> = tr.iter().map(|(x, _)| *x).collect();
    let ys: Vec<[f64; 6]> = tr
        .iter()
        .map(|(_, e)| [e.x, e.y, e.z, 0.0, 0.0, 0.0])
        .collect();
    let net = SeedNet::train(&xs, &ys, opts);
    let (tb, ta) = before_after(&net, &tr);
    let held = match heldout {
        Some(h) => {
            let session: Vec<&PoseRecord> = train.poses().collect();
            let r = residuals(&pred, &model, h, &session)?;
            let (b, a) = before_after(&net, &r);
            Some((r.len(), b, a))
        }
        None => None,
    };
    let block = NavNetBlock {
        format: NAVNET_FORMAT.into(),
        inputs: NAVNET_INPUTS.into(),
        hidden: opts.hidden.max(1),
        epochs: opts.epochs,
        train_poses: tr.len(),
        train_rms_mm_before: tb,
        train_rms_mm_after: ta,
        heldout_poses: held.map(|h| h.0),
        heldout_rms_mm_before: held.map(|h| h.1),
        heldout_rms_mm_after: held.map(|h| h.2),
        net,
    };
    block
        .check()
        .map_err(|e| anyhow::anyhow!("trained network: {e}"))?;
    let mut out = base;
    out.extra
        .insert(NAVNET_KEY.into(), serde_json::to_value(&block)?);
    Ok(out)
}

/// [`train`] from files (strict readers, plausibility, the calibration for the same robot).
pub fn train_files(
    cal: &Path,
    data: &Path,
    heldout: Option<&Path>,
    opts: &NetOptions,
) -> anyhow::Result<CalibrationFile> {
    let (ds, held) = crate::plausible::load_with_heldout(data, heldout)?;
    let cal = crate::plausible::calibration::load_for(cal, &ds.header.robot, data)?;
    train(&cal, &ds, held.as_ref(), opts)
        .with_context(|| format!("training the correction network on {}", data.display()))
}

/// One line of figures of a block.
pub fn summary(b: &NavNetBlock) -> String {
    let mut s = format!(
        "seed 003 network 6-{}-6 ({} epochs) on {} poses: training RMS {:.4} → {:.4} mm",
        b.hidden, b.epochs, b.train_poses, b.train_rms_mm_before, b.train_rms_mm_after
    );
    if let (Some(n), Some(x), Some(y)) = (
        b.heldout_poses,
        b.heldout_rms_mm_before,
        b.heldout_rms_mm_after,
    ) {
        s.push_str(&format!("; held-out ({n} poses) RMS {x:.4} → {y:.4} mm"));
    }
    s
}
