//! The seed 000 operator on the five-direction plate (§2.3.1, §3): after the arm has aimed the
//! beam at a target dot, the operator jogs it until the laser spot sits on the dot (to within
//! the scenario's `sd_mm`). Without this the five spots of one "target" land wherever the
//! controller's (erroneous) kinematics put them, and their spread measures the aim, not the
//! hand-eye calibration. The jog is the smallest joint change (pseudo-inverse Gauss–Newton on
//! the TRUE arm) that moves the spot onto the dot; the encoders then read the jogged joints.
use nalgebra::{Matrix2, Vector2};

use super::motion::Move;
use super::{laser_ray, normal, ArmRuntime, LaserRuntime};
use crate::scenario::{Centring, PlateConfig, SceneConfig};

/// The spot on the plate (plate x, y in mm) for joints `q`, if the beam hits the plate plane
/// in front of the sensor.
fn spot(
    arm: &ArmRuntime,
    l: &LaserRuntime,
    plate: &PlateConfig,
    q: &[f64],
    t: f64,
) -> Option<Vector2<f64>> {
    let flange = arm.physics.true_flange(q, &arm.ctx(t));
    let (o, u) = laser_ray(&flange, &l.cfg);
    let pt = plate.placement.isometry();
    let (o, u) = (pt.inverse() * o, pt.inverse_transform_vector(&u));
    if u.z.abs() < 1e-9 {
        return None;
    }
    let d = -o.z / u.z;
    (d > 0.0).then(|| (o + u * d).xy().coords)
}

/// Centres the spot on the nearest dot within `c.capture_mm`, once per arm move, when the arm
/// has settled.
pub(crate) fn centre(
    arm: &mut ArmRuntime,
    l: &mut LaserRuntime,
    scene: &SceneConfig,
    plate: &PlateConfig,
    c: &Centring,
    t: f64,
) {
    let end = arm.motion.end();
    if t < end || l.centred_end == Some(end) {
        return;
    }
    l.centred_end = Some(end);
    let mut q = arm.motion.q_at(t);
    // Only a spot the operator sees on the plate (not one on a calibration plane).
    let flange = arm.physics.true_flange(&q, &arm.ctx(t));
    let (o, u) = laser_ray(&flange, &l.cfg);
    if super::sensors::cast_ray(scene, &o, &u).is_none_or(|h| h.surface != "plate") {
        return;
    }
    let Some(s0) = spot(arm, l, plate, &q, t) else {
        return;
    };
    let Some(dot) = plate
        .targets
        .iter()
        .map(|d| Vector2::from(d.xy_mm))
        .filter(|d| (d - s0).norm() <= c.capture_mm)
        .min_by(|a, b| (a - s0).norm().total_cmp(&(b - s0).norm()))
    else {
        return;
    };
    let aim = dot + Vector2::new(normal(&mut l.rng), normal(&mut l.rng)) * c.sd_mm;
    for _ in 0..8 {
        let Some(s) = spot(arm, l, plate, &q, t) else {
            return;
        };
        let r = s - aim;
        if r.norm() < 1e-6 {
            break;
        }
        let h = 1e-7;
        let mut j = nalgebra::Matrix2xX::<f64>::zeros(q.len());
        for k in 0..q.len() {
            let mut qk = q.clone();
            qk[k] += h;
            let Some(sk) = spot(arm, l, plate, &qk, t) else {
                return;
            };
            j.set_column(k, &((sk - s) / h));
        }
        let jjt: Matrix2<f64> = &j * j.transpose();
        let Some(inv) = jjt.try_inverse() else {
            return;
        };
        let dq = j.transpose() * (inv * r);
        for (qk, d) in q.iter_mut().zip(dq.iter()) {
            *qk -= d;
        }
    }
    match spot(arm, l, plate, &q, t) {
        Some(s) if (s - aim).norm() < 0.01 => {
            arm.motion = Move::hold(q, t);
            l.centred_end = Some(arm.motion.end());
        }
        _ => {}
    }
}
