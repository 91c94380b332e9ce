//! A camera fixed in the base of a cell with an RCM instrument (`[scene.instrument]`) is the
//! endoscope of seed 002: it sees the instrument's shaft through the trocar, rendered by
//! [`crate::rcm_render`] from the TRUE flange pose (the hidden kinematic errors move the shaft
//! in the image, not in the controller's report). The instrument is on the first arm, its
//! axis the flange's z, its tip `length_mm` ahead of the flange.
use std::sync::Arc;

use nalgebra::{Isometry3, Translation3, Vector3};
use rand::RngCore;

use super::{Image, WorldHandle};
use crate::rcm::{RcmCameraConfig, RcmCell, RcmInstrumentConfig, RcmNoiseConfig, RcmScenario};
use crate::rcm_render::RcmRenderer;
use crate::scenario::{CameraConfig, InstrumentConfig};

/// The RCM cell of the renderer: the scenario's fixed camera (pose, intrinsics, `k1`, `k2`,
/// blur, noise) and instrument (trocar, radius, rendering table).
pub fn rcm_cell(
    name: &str,
    seed: u64,
    robot: &str,
    cam: &CameraConfig,
    inst: &InstrumentConfig,
) -> RcmCell {
    let pose = cam.placement.isometry();
    let eye = pose.translation.vector;
    let z = pose.rotation * Vector3::z();
    let up = -(pose.rotation * Vector3::y());
    let mut render = inst.render.clone();
    render.blur_px = cam.blur_px;
    render.noise_grey = cam.noise_grey;
    let scenario = RcmScenario {
        name: name.into(),
        description: String::new(),
        seed,
        robot: robot.into(),
        trocar_mm: inst.rcm_mm,
        insertion_dir: inst.insertion_dir,
        camera: RcmCameraConfig {
            xyz_mm: eye.into(),
            look_at_mm: (eye + z * 100.0).into(),
            up: up.into(),
            width: cam.width,
            height: cam.height,
            fx: cam.fx,
            fy: cam.fy,
            cx: cam.cx,
            cy: cam.cy,
            dist: [cam.k1, cam.k2, 0.0, 0.0, 0.0],
        },
        instrument: RcmInstrumentConfig {
            shaft_radius_mm: inst.radius_mm,
            visible_mm: 60.0,
            marker_cols: 0,
            marker_rows: 0,
            marker_pitch_mm: 0.0,
            marker_offset_mm: 0.0,
        },
        noise: RcmNoiseConfig {
            line_px: 0.0,
            marker_px: 0.0,
            robot_mm: 0.0,
            robot_deg: 0.0,
        },
        render,
    };
    RcmCell {
        scenario,
        camera: pose,
    }
}

/// The instrument frame (origin at the tip, z towards the tip) of a flange pose.
pub fn instrument_in_base(flange: &Isometry3<f64>, inst: &InstrumentConfig) -> Isometry3<f64> {
    flange
        * Isometry3::from_parts(
            Translation3::new(0.0, 0.0, inst.length_mm),
            Default::default(),
        )
}

impl WorldHandle {
    /// The endoscope image of camera `camera` when it is fixed in the base and the scene has an
    /// RCM instrument; `None` otherwise (the camera then sees the chessboard). The renderer
    /// (rays, background) is built on the first frame and kept.
    pub(crate) fn render_rcm_view(&self, camera: usize) -> Option<Image> {
        let t = self.now();
        let (cfg, inst, flange, seed, cached, meta) = self.with(|w| {
            let inst = w.scene.instrument.clone()?;
            let arm = w.arms.first()?;
            let flange = arm.physics.true_flange(&arm.motion.q_at(t), &arm.ctx(t));
            let meta = (
                w.scenario.name.clone(),
                w.scenario.seed,
                w.scenario.arms.first()?.model.clone(),
            );
            let cached = w.rcm_renderers.get(&camera).cloned();
            let c = w.cameras.get_mut(camera)?;
            if c.arm.is_some() {
                return None;
            }
            Some((c.cfg.clone(), inst, flange, c.rng.next_u64(), cached, meta))
        })?;
        let renderer = match cached {
            Some(r) => r,
            None => {
                let cell = rcm_cell(&meta.0, meta.1, &meta.2, &cfg, &inst);
                let r = Arc::new(RcmRenderer::new(&cell, &cell.scenario.render));
                self.with(|w| w.rcm_renderers.insert(camera, r.clone()));
                r
            }
        };
        let im = renderer.render(&instrument_in_base(&flange, &inst), seed);
        Some(Image {
            width: im.width,
            height: im.height,
            data: im.data,
            t,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shipped RCM session scenario places its endoscope where seed 002's cell file puts
    /// it by look-at (`mocks/rcm/rcm-endoscope.toml`), and a frame of it shows the shaft.
    #[test]
    fn shipped_endoscope_matches_the_seed_cell_and_sees_the_shaft() {
        let s = crate::Scenario::from_toml(include_str!("../../scenarios/rcm-ur5e-endoscope.toml"))
            .unwrap();
        let seed = RcmCell::new(crate::rcm::RcmScenario::builtin());
        let inst = s.scene.instrument.as_ref().unwrap();
        let c = rcm_cell(&s.name, s.seed, "ur5e", &s.cameras[0], inst);
        let (dt, dr) = (
            (c.camera.translation.vector - seed.camera.translation.vector).norm(),
            c.camera.rotation.angle_to(&seed.camera.rotation),
        );
        assert!(dt < 1e-9 && dr < 1e-9, "{dt} mm {dr} rad");
        // Instrument straight down through the trocar, tip 100 mm deep.
        let flange = Isometry3::from_parts(
            Translation3::new(450.0, 0.0, 250.0 - 100.0 + 350.0),
            nalgebra::UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
        );
        let tip = instrument_in_base(&flange, inst);
        assert!((tip.translation.vector - Vector3::new(450.0, 0.0, 150.0)).norm() < 1e-9);
        assert!(c.view(&tip).is_some());
    }
}
