//! `robocal predict --calibration CAL.json --data DATA.jsonl [--out FILE.csv]`.
//!
//! Writes CSV `id,x_mm,y_mm,z_mm`, one row per `pose` record of DATA in file order
//! (`docs/dataset-format.md`, "Prediction"):
//! - kinematic calibration: the predicted marker origin in the tracker frame from the
//!   record's `q`;
//! - laser calibration (`"kind": "laser"`): the predicted laser spot in the robot base frame
//!   (computed by `crate::solve::laser`).
//!
//! Every prediction goes through [`Predictor::predict_record`], the one place to extend
//! (calibration `effects` are applied there).
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _};
use nalgebra::Point3;

use crate::dataset::{CalEffect, CalibrationFile, CalibrationKind, Dataset, PoseRecord};
use crate::model::KinematicModel;

/// Arguments of `robocal predict`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Calibration file (`robocal-calibration/1`).
    #[arg(long, value_name = "CAL.json")]
    pub calibration: PathBuf,
    /// Dataset (`robocal-dataset/1`) whose pose records are predicted.
    #[arg(long, value_name = "DATA.jsonl")]
    pub data: PathBuf,
    /// Write the CSV here instead of to stdout.
    #[arg(long, value_name = "FILE.csv")]
    pub out: Option<PathBuf>,
}

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
}

impl Predictor {
    /// Builds the predictor of a calibration file.
    pub fn new(cal: &CalibrationFile) -> anyhow::Result<Predictor> {
        match cal.kind() {
            CalibrationKind::Kinematic => {
                let mut model = KinematicModel::from_robot_block(&cal.robot)
                    .context("building the kinematic model of the calibration's robot block")?;
                model
                    .apply_cal_params(&cal.params)
                    .context("applying the calibration's params")?;
                Ok(Predictor {
                    engine: Engine::Kinematic {
                        model: Box::new(model),
                        effects: cal.effects.clone(),
                    },
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
            Engine::Kinematic { model, effects } => {
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
                if !effects.is_empty() {
                    // Effects on top of the kinematics (owned by the diagnosis).
                    return crate::diagnose::effects::predict_record(model, effects, rec, ds);
                }
                let q_rad: Vec<f64> = q.iter().map(|d| d.to_radians()).collect();
                Ok(model.measured_point(&q_rad))
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
        ds.poses()
            .map(|rec| {
                Ok(PredictedPoint {
                    id: rec.id,
                    p: self.predict_record(rec, ds)?,
                })
            })
            .collect()
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
    // Strict reader + plausibility of both files, and one robot model (issue 14 §5).
    let ds = crate::plausible::load_checked(data)?;
    let cal = crate::plausible::calibration::load_for(cal, &ds.header.robot, data)?;
    let predictor = Predictor::new(&cal)?;
    predictor
        .predict_dataset(&ds)
        .with_context(|| format!("predicting {}", data.display()))
}

/// Run `robocal predict`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    if CalibrationFile::load(&args.calibration)?.kind() == CalibrationKind::Other("camera".into()) {
        return camera_exec(&args);
    }
    let rows = predict_files(&args.calibration, &args.data)?;
    match &args.out {
        Some(path) => {
            let f = std::fs::File::create(path)
                .with_context(|| format!("creating {}", path.display()))?;
            write_csv(std::io::BufWriter::new(f), &rows)
                .with_context(|| format!("writing {}", path.display()))?;
        }
        None => {
            let stdout = std::io::stdout();
            write_csv(stdout.lock(), &rows).context("writing to stdout")?;
        }
    }
    Ok(())
}

/// `robocal predict` on a camera calibration: CSV `id,corner,u_px,v_px`.
fn camera_exec(args: &Args) -> anyhow::Result<()> {
    let rows = crate::cli::calibrate::camera::predict_rows(&args.calibration, &args.data)?;
    let mut text = String::from("id,corner,u_px,v_px\n");
    for (id, c, uv) in rows {
        text += &format!("{id},{c},{:.6},{:.6}\n", uv[0], uv[1]);
    }
    match &args.out {
        Some(p) => std::fs::write(p, text).with_context(|| format!("writing {}", p.display()))?,
        None => print!("{text}"),
    }
    Ok(())
}
