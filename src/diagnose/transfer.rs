//! Carry a diagnosis over to a new setup: the same robot measured with the tracker (and the
//! marker) somewhere else — another day, another series, another cell. Only the tracker ←
//! base transform (6) and the marker position on the flange (3) are re-fitted on the new
//! poses; every joint parameter, every effect coefficient and the nonparametric correction
//! stay as identified. This is how a correction is shown to generalise: scored on data it
//! was never fitted to, with only the setup registration re-done.
use nalgebra::{DMatrix, DVector, Point3};

use super::effects::apply_effects;
use super::error::FitError;
use super::fit::{residuals, rms3, stack, State};
use crate::model::ParamGroup;
use crate::solve::lm::{minimize, LmOptions, LsqProblem};
use crate::solve::obs::PoseObs;

/// Whether a parameter is part of the setup registration (re-fitted on a new setup).
fn is_setup(group: ParamGroup, name: &str) -> bool {
    match group {
        ParamGroup::Base => true,
        ParamGroup::Tool => matches!(name, "tool_x" | "tool_y" | "tool_z"),
        _ => false,
    }
}

/// The registration-only problem: residual `pred − y`, parameters = the free setup
/// parameters of `state.model` (effects fixed).
struct SetupProblem<'a> {
    state: &'a State,
    obs: &'a [PoseObs],
}

impl SetupProblem<'_> {
    fn at(&self, x: &DVector<f64>) -> State {
        let mut st = self.state.clone();
        st.model.set_free_values(x);
        st
    }
}

impl LsqProblem for SetupProblem<'_> {
    fn n_params(&self) -> usize {
        self.state.model.free_count()
    }
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        -residuals(&self.at(x), self.obs)
    }
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let st = self.at(x);
        let (r, j) = stack(&st, self.obs);
        // `stack` puts the free model parameters first, then the effect coefficients.
        let p = st.model.free_count();
        (-r, j.columns(0, p).into_owned())
    }
}

/// `state` with the tracker ← base and marker position re-fitted on `obs` (at least 6
/// poses); everything else as identified. The free flags of the returned model are those of
/// `state`.
pub fn refit_setup(state: &State, obs: &[PoseObs]) -> Result<State, FitError> {
    refit(state, obs, Refit::Setup)
}

/// [`refit_setup`] with the joint zero offsets (`phi*`, those free in `state`) re-fitted
/// too: what carries over when the arm was re-homed between the two setups (every other
/// joint parameter and every effect as identified).
pub fn refit_setup_and_joint_offsets(state: &State, obs: &[PoseObs]) -> Result<State, FitError> {
    refit(state, obs, Refit::SetupAndOffsets)
}

/// Every geometric parameter free in `state` re-fitted on `obs`, the effects (and any
/// correction) held as identified: whether the effects found on one series carry physics
/// that another series' own geometric calibration lacks.
pub fn refit_geometry(state: &State, obs: &[PoseObs]) -> Result<State, FitError> {
    refit(state, obs, Refit::Geometry)
}

#[derive(Clone, Copy, PartialEq)]
enum Refit {
    Setup,
    SetupAndOffsets,
    Geometry,
}

fn refit(state: &State, obs: &[PoseObs], what: Refit) -> Result<State, FitError> {
    if obs.len() < 6 {
        return Err(FitError::TooFewPoses {
            what: "re-registering a setup needs",
            need: 6,
            got: obs.len(),
        });
    }
    let mut st = state.clone();
    // Start: rigid registration of the model's predictions (robot base frame, effects
    // applied) onto the measurements.
    let base0 = st.model.base();
    let inv = base0.inverse();
    let pred: Vec<Point3<f64>> = obs
        .iter()
        .map(|o| inv * apply_effects(&st.model, &st.effects, &o.ctx))
        .collect();
    let ys: Vec<Point3<f64>> = obs.iter().map(|o| o.p).collect();
    let b = crate::solve::rigid::register_points(&pred, &ys).map_err(|e| FitError::Register {
        what: "the new setup",
        why: e.to_string(),
    })?;
    st.model.set_base(&b);
    let saved = st.model.free_flags();
    let setup: Vec<(String, bool)> = st
        .model
        .params()
        .iter()
        .map(|p| {
            if what == Refit::Geometry {
                return (p.name.clone(), p.free || is_setup(p.group, &p.name));
            }
            let offset = what == Refit::SetupAndOffsets
                && p.free
                && matches!(p.group, ParamGroup::Joint(_))
                && p.name.starts_with("phi");
            (p.name.clone(), offset || is_setup(p.group, &p.name))
        })
        .collect();
    for (n, f) in &setup {
        st.model.set_free(n, *f)?;
    }
    let x0 = st.model.free_values();
    let rep = minimize(
        &SetupProblem { state: &st, obs },
        x0,
        &LmOptions {
            max_iter: 50,
            ftol: 1e-12,
            xtol: 1e-12,
            gtol: 1e-12,
            lambda0: 1e-3,
        },
    );
    if !rep.cost.is_finite() {
        return Err(FitError::NotFinite(
            "re-registering the new setup diverged (cost not finite)",
        ));
    }
    if rep.cost <= rep.initial_cost {
        st.model.set_free_values(&rep.x);
    }
    st.model.set_free_flags(&saved)?;
    let r = rms3(&residuals(&st, obs));
    if !r.is_finite() {
        return Err(FitError::NotFinite(
            "re-registered setup: residual not finite",
        ));
    }
    Ok(st)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::KinematicModel;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

    /// A state identified in one setup predicts a second setup (tracker moved by 1.2 m and
    /// turned 40°, marker moved 15 mm) to the same error once only the setup is re-fitted;
    /// and joint parameters are not touched.
    #[test]
    fn refit_setup_recovers_a_moved_tracker_and_keeps_the_robot() {
        let mut truth = KinematicModel::preset("ur10e").expect("ur10e preset");
        truth.set_param("phi2", 0.002).unwrap();
        truth
            .set_param("a3", truth.param("a3").unwrap() + 0.4)
            .unwrap();
        let mut moved = truth.clone();
        moved.set_base(&Isometry3::from_parts(
            Translation3::new(1200.0, -300.0, 150.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 40f64.to_radians()),
        ));
        moved
            .set_param("tool_x", truth.param("tool_x").unwrap() + 15.0)
            .unwrap();
        let obs: Vec<PoseObs> = (0..30)
            .map(|k| {
                let f = k as f64;
                let q = crate::diagnose::test_joints(f, 0.8, 1.7);
                let mut o = PoseObs::at(k, f, q.clone(), moved.measured_point(&q));
                o.ctx.approach = vec![1.0; 6];
                o
            })
            .collect();
        let state = State {
            prior: None,
            model: truth.clone(),
            effects: vec![],
        };
        let before = rms3(&residuals(&state, &obs));
        let st = refit_setup(&state, &obs).unwrap();
        let after = rms3(&residuals(&st, &obs));
        assert!(before > 100.0, "the setup did move: {before}");
        assert!(after < 1e-6, "after re-registration: {after} mm");
        assert_eq!(st.model.param("phi2"), truth.param("phi2"));
        assert_eq!(st.model.param("a3"), truth.param("a3"));
        assert!(refit_setup(&state, &obs[..5]).is_err());
        // Re-homed: joint 3's zero moved 0.05°. Setup alone leaves it; with the offsets the
        // poses are predicted again, and the link lengths stay as identified.
        let mut rehomed = moved.clone();
        let phi3 = rehomed.param("phi3").unwrap();
        rehomed
            .set_param("phi3", phi3 + 0.05f64.to_radians())
            .unwrap();
        let obs: Vec<PoseObs> = obs
            .iter()
            .map(|o| {
                PoseObs::at(
                    o.ctx.id,
                    o.ctx.t,
                    o.ctx.q.clone(),
                    rehomed.measured_point(&o.ctx.q),
                )
            })
            .collect();
        let setup_only = rms3(&residuals(&refit_setup(&state, &obs).unwrap(), &obs));
        let st = refit_setup_and_joint_offsets(&state, &obs).unwrap();
        let with_offsets = rms3(&residuals(&st, &obs));
        assert!(setup_only > 0.05, "setup alone: {setup_only} mm");
        assert!(with_offsets < 1e-3, "with the offsets: {with_offsets} mm");
        let dphi3 = st.model.param("phi3").unwrap() - phi3;
        assert!(
            (dphi3 - 0.05f64.to_radians()).abs() < 1e-5,
            "phi3 moved {dphi3} rad"
        );
        assert_eq!(st.model.param("a3"), truth.param("a3"));
    }

    /// The same robot with a link 0.3 mm longer (another session's geometric fit): the setup
    /// and the offsets cannot absorb it, the whole geometry re-fitted does, to the link.
    #[test]
    fn refit_geometry_takes_up_a_changed_link() {
        let model = KinematicModel::preset("ur10e").expect("ur10e preset");
        let mut other = model.clone();
        let a3 = model.param("a3").unwrap();
        other.set_param("a3", a3 + 0.3).unwrap();
        let obs: Vec<PoseObs> = (0..40)
            .map(|k| {
                let f = k as f64;
                let q = crate::diagnose::test_joints(f, 0.8, 1.7);
                let mut o = PoseObs::at(k, f, q.clone(), other.measured_point(&q));
                o.ctx.approach = vec![1.0; 6];
                o
            })
            .collect();
        let state = State {
            prior: None,
            model: model.clone(),
            effects: vec![],
        };
        let offsets = rms3(&residuals(
            &refit_setup_and_joint_offsets(&state, &obs).unwrap(),
            &obs,
        ));
        let st = refit_geometry(&state, &obs).unwrap();
        let geometry = rms3(&residuals(&st, &obs));
        assert!(offsets > 0.01, "setup and offsets: {offsets} mm");
        assert!(geometry < 1e-4, "geometry re-fitted: {geometry} mm");
        let da3 = st.model.param("a3").unwrap() - a3;
        assert!((da3 - 0.3).abs() < 1e-3, "a3 moved {da3} mm");
        assert_eq!(st.model.free_flags(), state.model.free_flags());
    }
}
