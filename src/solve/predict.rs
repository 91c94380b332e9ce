//! Prediction of pose records with a calibration file (what `robocal predict` writes):
//! CSV `id,x_mm,y_mm,z_mm`, one row per `pose` record in file order
//! (`docs/dataset-format.md`, "Prediction"):
//! - kinematic calibration: the predicted marker origin in the tracker frame from the
//!   record's `q` (and `t`, `temp_c`, `q_prev` where an effect needs them);
//! - laser calibration (`"kind": "laser"`): the predicted laser spot in the robot base frame
//!   (computed by `crate::solve::laser`).
use std::io::Write;
use std::path::Path;

use anyhow::{bail, Context as _};
use nalgebra::Point3;

use crate::dataset::{CalEffect, CalibrationFile, CalibrationKind, Dataset, PoseRecord};
use crate::model::KinematicModel;

/// One predicted point (mm): a marker origin in the tracker frame (kinematic) or a laser
/// spot in the robot base frame (laser).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PredictedPoint {
    /// The pose record's `id`.
    pub id: u64,
    /// The predicted point (mm).
    pub p: Point3<f64>,
}

/// What a calibration file predicts with.
#[derive(Debug, Clone)]
enum Engine {
    /// Kinematic model (internal units mm / rad) and the file's effects.
    Kinematic {
        model: Box<KinematicModel>,
        effects: Vec<CalEffect>,
        /// The training poses' joint ranges of the effects (files since round 8).
        range: Option<crate::diagnose::effects::JointRange>,
    },
    /// Laser beam in the flange frame; flange poses from the record, else FK of `q`.
    Laser {
        beam: crate::solve::laser::Beam,
        effects: Vec<CalEffect>,
        model: Option<Box<KinematicModel>>,
    },
}

/// A calibration ready to predict pose records.
#[derive(Debug, Clone)]
pub struct Predictor {
    engine: Engine,
    /// Seed 003's correction network of the file (kinematic calibrations), added last.
    net: Option<Box<crate::schema::navnet::NavNetBlock>>,
}

impl Predictor {
    /// Builds the predictor of a calibration file.
    pub fn new(cal: &CalibrationFile) -> anyhow::Result<Predictor> {
        let mut p = Self::new_engine(cal)?;
        p.net = crate::navchain::correction::from_calibration(cal)?.map(Box::new);
        if p.net.is_some() && !matches!(p.engine, Engine::Kinematic { .. }) {
            bail!("a correction network (`navchain_net`) is only valid in a kinematic calibration");
        }
        Ok(p)
    }

    /// The point plus the correction network's offset, when the file has one.
    fn corrected(&self, model: &KinematicModel, q_rad: &[f64], p: Point3<f64>) -> Point3<f64> {
        match &self.net {
            Some(b) => p + crate::navchain::correction::correction(b, model, q_rad),
            None => p,
        }
    }

    fn new_engine(cal: &CalibrationFile) -> anyhow::Result<Predictor> {
        match cal.kind() {
            CalibrationKind::Kinematic => {
                let mut model = KinematicModel::from_robot_block(&cal.robot)
                    .context("building the kinematic model of the calibration's robot block")?;
                model
                    .apply_cal_params(&cal.params)
                    .context("applying the calibration's params")?;
                let range = cal
                    .effects_joint_range
                    .as_ref()
                    .map(|r| crate::diagnose::effects::JointRange::from_cal(r, model.dof()))
                    .transpose()?;
                Ok(Predictor {
                    engine: Engine::Kinematic {
                        model: Box::new(model),
                        effects: cal.effects.clone(),
                        range,
                    },
                    net: None,
                })
            }
            // Dispatch point of the laser (range sensor) calibration: `crate::solve::laser`.
            CalibrationKind::Laser => {
                let beam = crate::solve::laser::beam_from_calibration(cal)?;
                let model = KinematicModel::from_robot_block(&cal.robot)
                    .ok()
                    .map(Box::new);
                Ok(Predictor {
                    engine: Engine::Laser {
                        beam,
                        effects: cal.effects.clone(),
                        model,
                    },
                    net: None,
                })
            }
            CalibrationKind::Other(k) => bail!(
                "calibration kind \"{k}\" cannot be used for prediction (expected kinematic or laser)"
            ),
        }
    }

    /// The prediction for one pose record of `ds` (the single place every prediction is
    /// computed; `ds` gives the session context effects may need: neighbouring poses for
    /// the approach direction, times, temperatures).
    pub fn predict_record(&self, rec: &PoseRecord, ds: &Dataset) -> anyhow::Result<Point3<f64>> {
        let _ = ds; // Session context: used once effects are applied.
        match &self.engine {
            Engine::Kinematic {
                model,
                effects,
                range,
            } => {
                let Some(q) = &rec.q else {
                    bail!(
                        "pose {} has no measured joints `q` (a kinematic prediction needs them)",
                        rec.id
                    );
                };
                if q.len() != model.dof() {
                    bail!(
                        "pose {}: {} joint angles but the calibrated robot has {} joints",
                        rec.id,
                        q.len(),
                        model.dof()
                    );
                }
                let q_rad: Vec<f64> = q.iter().map(|d| d.to_radians()).collect();
                let p = if !effects.is_empty() {
                    // Effects on top of the kinematics (owned by the diagnosis).
                    crate::diagnose::effects::predict_record(
                        model,
                        effects,
                        range.as_ref(),
                        rec,
                        ds,
                    )?
                } else {
                    model.measured_point(&q_rad)
                };
                Ok(self.corrected(model, &q_rad, p))
            }
            Engine::Laser {
                beam,
                effects,
                model,
            } => match crate::solve::laser::predict_spot(beam, effects, rec, model.as_deref())? {
                Some(p) => Ok(p),
                None => bail!(
                    "pose {} has no range reading (`range` absent or null): no laser spot",
                    rec.id
                ),
            },
        }
    }

    /// Predictions for every pose record of `ds`, in file order.
    pub fn predict_dataset(&self, ds: &Dataset) -> anyhow::Result<Vec<PredictedPoint>> {
        Ok(self.predict_dataset_warn(ds)?.0)
    }

    /// Predictions for every pose record of `ds`, in file order, and the warnings of the
    /// prediction (an effect that needs the approach direction on records without
    /// `q_prev`: the previous record of the file in time stands in for it).
    pub fn predict_dataset_warn(
        &self,
        ds: &Dataset,
    ) -> anyhow::Result<(Vec<PredictedPoint>, Vec<String>)> {
        self.predict_in_session(ds, &[])
    }

    /// As [`Predictor::predict_dataset_warn`], with `session`: the other pose records of the
    /// same session (e.g. the training file of a diagnosis), used only for the context of
    /// `ds`'s records (the pose the arm came from when a record has no `q_prev`: in a
    /// held-out file alone, the previous held-out pose is not where the arm came from).
    pub fn predict_in_session(
        &self,
        ds: &Dataset,
        session: &[&PoseRecord],
    ) -> anyhow::Result<(Vec<PredictedPoint>, Vec<String>)> {
        if let Engine::Laser {
            beam,
            effects,
            model,
        } = &self.engine
        {
            // The whole file at once: the incidence term needs the validation plate.
            use crate::solve::laser::predict::{incidence_note, predict_spots};
            let recs: Vec<&PoseRecord> = ds.poses().collect();
            let spots = predict_spots(beam, effects, &recs, model.as_deref())?;
            let rows = recs
                .iter()
                .zip(spots)
                .map(|(rec, p)| match p {
                    Some(p) => Ok(PredictedPoint { id: rec.id, p }),
                    None => self
                        .predict_record(rec, ds)
                        .map(|p| PredictedPoint { id: rec.id, p }),
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            return Ok((rows, incidence_note(effects, &recs).into_iter().collect()));
        }
        let Engine::Kinematic {
            model,
            effects,
            range,
        } = &self.engine
        else {
            let rows = ds
                .poses()
                .map(|rec| {
                    Ok(PredictedPoint {
                        id: rec.id,
                        p: self.predict_record(rec, ds)?,
                    })
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            return Ok((rows, vec![]));
        };
        // Session context once for the whole file (approach directions, times).
        let recs: Vec<&PoseRecord> = ds.poses().collect();
        let all: Vec<&PoseRecord> = recs.iter().chain(session).copied().collect();
        let (ctx, inferred) = crate::solve::obs::contexts_counted(&all, model.dof());
        let by_key: std::collections::HashMap<usize, &crate::solve::obs::PoseCtx> =
            ctx.iter().map(|(k, c)| (*k, c)).collect();
        let parsed = effects
            .iter()
            .map(crate::diagnose::effects::Effect::from_cal)
            .collect::<Result<Vec<_>, _>>()?;
        let mut warnings = Vec::new();
        if inferred > 0 && effects.iter().any(|e| e.kind == "backlash") {
            warnings.push(crate::solve::obs::q_prev_warning(
                inferred,
                "the backlash effect",
            ));
        }
        let mut rows = Vec::with_capacity(recs.len());
        let mut held = Vec::new();
        for rec in recs {
            self.check_joints(rec)?;
            let q_rad: Vec<f64> = rec.q.iter().flatten().map(|d| d.to_radians()).collect();
            let p = if parsed.is_empty() {
                model.measured_point(&q_rad)
            } else {
                let c = by_key
                    .get(&crate::solve::obs::record_key(rec))
                    .ok_or_else(|| {
                        anyhow::anyhow!("pose {}: no usable time or joints for the effects", rec.id)
                    })?;
                held.push(*c);
                crate::diagnose::effects::apply_effects_held(model, &parsed, c, range.as_ref())
            };
            let p = self.corrected(model, &q_rad, p);
            rows.push(PredictedPoint { id: rec.id, p });
        }
        if let Some(r) = range {
            let o = crate::diagnose::effects::Outside::count(r, held);
            warnings.extend(o.as_ref().map(crate::diagnose::effects::Outside::warning));
        }
        Ok((rows, warnings))
    }

    /// The record has joints of the calibrated robot's dof (kinematic calibrations).
    fn check_joints(&self, rec: &PoseRecord) -> anyhow::Result<()> {
        let Engine::Kinematic { model, .. } = &self.engine else {
            return Ok(());
        };
        let Some(q) = &rec.q else {
            bail!(
                "pose {} has no measured joints `q` (a kinematic prediction needs them)",
                rec.id
            );
        };
        if q.len() != model.dof() {
            bail!(
                "pose {}: {} joint angles but the calibrated robot has {} joints",
                rec.id,
                q.len(),
                model.dof()
            );
        }
        Ok(())
    }
}

/// Writes predictions as CSV `id,x_mm,y_mm,z_mm` (µm resolution).
pub fn write_csv<W: Write>(mut w: W, rows: &[PredictedPoint]) -> std::io::Result<()> {
    writeln!(w, "id,x_mm,y_mm,z_mm")?;
    for r in rows {
        writeln!(w, "{},{:.6},{:.6},{:.6}", r.id, r.p.x, r.p.y, r.p.z)?;
    }
    w.flush()
}

/// `robocal predict` as a library call: reads both files and predicts.
pub fn predict_files(cal: &Path, data: &Path) -> anyhow::Result<Vec<PredictedPoint>> {
    Ok(predict_files_warn(cal, data)?.0)
}

/// [`predict_files`] with the prediction's warnings (see [`Predictor::predict_dataset_warn`]).
pub fn predict_files_warn(
    cal: &Path,
    data: &Path,
) -> anyhow::Result<(Vec<PredictedPoint>, Vec<String>)> {
    predict_files_in_session(cal, data, None)
}

/// [`predict_files_warn`] with the other records of the session in `session` (a dataset of
/// the same robot; see [`Predictor::predict_in_session`]).
pub fn predict_files_in_session(
    cal: &Path,
    data: &Path,
    session: Option<&Path>,
) -> anyhow::Result<(Vec<PredictedPoint>, Vec<String>)> {
    // Strict reader + plausibility of every file, and one robot model (no silent wrong answer).
    let (ds, other) = crate::plausible::load_with_heldout(data, session)?;
    let cal = crate::plausible::calibration::load_for(cal, &ds.header.robot, data)?;
    let predictor = Predictor::new(&cal)?;
    let others: Vec<&PoseRecord> = other.iter().flat_map(|o| o.poses()).collect();
    predictor
        .predict_in_session(&ds, &others)
        .with_context(|| format!("predicting {}", data.display()))
}
