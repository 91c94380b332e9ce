//! `robocal-calibration/1` output of the kinematic fits (file units: mm, degrees).
use serde_json::{json, Map, Value};

use super::kinematics::IdentResult;
use super::nominal::NominalFit;
use crate::dataset::{CalibrationFile, RobotBlock};
use crate::model::{KinematicModel, Unit};

fn num(x: f64) -> Value {
    if x.is_finite() {
        json!(x)
    } else {
        Value::Null
    }
}

/// Calibration file of a model (params from `model.to_cal_params()`), `kind: kinematic`.
pub fn kinematic_file(robot: &RobotBlock, model: &KinematicModel) -> CalibrationFile {
    let mut f = CalibrationFile::new(robot.clone(), model.to_cal_params());
    f.set_kind("kinematic");
    f
}

/// Calibration file of the nominal fit, with `train_rms_mm` and `heldout_rms_mm_before`.
pub fn nominal_file(robot: &RobotBlock, fit: &NominalFit) -> CalibrationFile {
    let mut f = kinematic_file(robot, &fit.model);
    let m = &mut f.metrics;
    m.insert("train_rms_mm".into(), num(fit.train_rms_mm));
    if let Some(h) = fit.heldout_rms_mm_before {
        m.insert("heldout_rms_mm_before".into(), num(h));
        // The nominal model is the final model here: after = before.
        m.insert("heldout_rms_mm_after".into(), num(h));
    }
    if let Some(h) = fit.heldout_max_mm_before {
        m.insert("heldout_max_mm_before".into(), num(h));
    }
    m.insert("n_train".into(), json!(fit.n_train));
    m.insert("n_heldout".into(), json!(fit.n_heldout));
    m.insert("termination".into(), json!(fit.termination.describe()));
    f.extra.insert(
        "solver".into(),
        json!("robocal nominal: closed-form base/tool + Levenberg-Marquardt"),
    );
    f
}

/// Calibration file of a kinematic identification: every parameter with value, std and
/// unit; metrics; the identifiability report; the effects (kind + params).
pub fn ident_file(robot: &RobotBlock, res: &IdentResult) -> CalibrationFile {
    let mut f = kinematic_file(robot, &res.model);
    let by_name: std::collections::HashMap<&str, &super::kinematics::ParamEstimate> =
        res.params.iter().map(|p| (p.name.as_str(), p)).collect();
    for c in f.params.iter_mut() {
        if let Some(p) = by_name.get(c.name.as_str()) {
            c.std = p.std.map(|s| match p.unit {
                Unit::Mm => s,
                Unit::Rad => s.to_degrees(),
            });
            let nominal = match p.unit {
                Unit::Mm => p.nominal,
                Unit::Rad => p.nominal.to_degrees(),
            };
            c.extra.insert("nominal".into(), num(nominal));
        }
        if let Some(fx) = res.fixed.iter().find(|x| x.name == c.name) {
            c.extra.insert("fixed_reason".into(), json!(fx.reason));
        }
    }
    let m = &mut f.metrics;
    m.insert("train_rms_mm".into(), num(res.train_rms_mm));
    m.insert("train_rms_mm_before".into(), num(res.train_rms_mm_before));
    m.insert("sigma_mm".into(), num(res.sigma_mm));
    m.insert("n_train".into(), json!(res.train_obs.len()));
    if let Some(h) = &res.heldout {
        m.insert("heldout_rms_mm_before".into(), num(h.rms_before));
        m.insert("heldout_rms_mm_after".into(), num(h.rms_after));
        m.insert("heldout_max_mm_before".into(), num(h.max_before));
        m.insert("heldout_max_mm_after".into(), num(h.max_after));
        m.insert("n_heldout".into(), json!(h.n));
        m.insert("heldout_source".into(), json!(h.source.describe()));
    }
    m.insert("termination".into(), json!(res.termination.describe()));
    m.insert("iterations".into(), json!(res.iterations));
    let idf = &res.identifiability;
    let mut im = Map::new();
    im.insert("condition".into(), num(idf.condition));
    im.insert("o1".into(), num(idf.o1));
    im.insert("o2".into(), num(idf.o2));
    im.insert("o3".into(), num(idf.o3));
    im.insert("o4".into(), num(idf.o4));
    im.insert("o5".into(), num(idf.o5));
    im.insert(
        "fixed".into(),
        Value::Array(
            res.fixed
                .iter()
                .map(|x| json!({"name": x.name, "reason": x.reason}))
                .collect(),
        ),
    );
    f.extra.insert("identifiability".into(), Value::Object(im));
    if let Some(c) = res.huber_mm {
        f.extra.insert(
            "robust".into(),
            json!({"loss": "huber", "threshold_mm": c,
                   "outliers": res.outliers.iter().map(|(id, e)| json!({"id": id, "error_mm": e})).collect::<Vec<_>>()}),
        );
    }
    f.extra.insert(
        "solver".into(),
        json!(
            "robocal kinematics: Levenberg-Marquardt (Moré scaling), covariance sigma^2 (J^T J)^-1"
        ),
    );
    f
}
