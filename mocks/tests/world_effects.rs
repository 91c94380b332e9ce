//! Each hidden effect, switched on alone, produces the signature and magnitude its parameters say.

use nalgebra::{Point3, Vector3};
use robocal_drivers::{MoveSpeed, RangeReading, ToolStatus};
use robocal_mocks::scenario::{
    BaseBump, GeometricErrors, LaserConfig, LaserEffects, Occluder, PlaneConfig, Protocol,
    Scenario, VolumeKind,
};
use robocal_mocks::world::effects::{
    ArmPhysics, Backlash, Eccentricity, JointCompliance, JointContext, LinkDeflection, PointMass,
    Thermal, Transmission,
};
use robocal_mocks::WorldHandle;

fn deg(v: &[f64]) -> Vec<f64> {
    v.iter().map(|x| x.to_radians()).collect()
}

/// A VS060 with no geometric error, unbounded tracker volume, no noise.
fn clean() -> Scenario {
    let mut s = Scenario::single_arm("denso-vs060", 5);
    s.arms[0].errors = GeometricErrors::none();
    s.trackers[0].effects.volume = Some(VolumeKind::Unbounded);
    s
}

fn masses() -> Vec<PointMass> {
    vec![
        PointMass {
            link: 3,
            xyz_mm: [-5.0, 0.0, 150.0],
            kg: 3.0,
        },
        PointMass {
            link: 7,
            xyz_mm: [0.0, 0.0, 120.0],
            kg: 4.0,
        },
    ]
}

/// Position of the flange origin for physics `a` at q (base frame).
fn flange_p(a: &ArmPhysics, q: &[f64], ctx: &JointContext) -> Vector3<f64> {
    a.true_flange(q, ctx).translation.vector
}

/// ∂p/∂θ_j of the flange origin (central difference on the true chain).
fn joint_column(a: &ArmPhysics, q: &[f64], j: usize) -> Vector3<f64> {
    let h = 1e-6;
    let (mut qp, mut qm) = (q.to_vec(), q.to_vec());
    qp[j] += h;
    qm[j] -= h;
    let c = a.chain.clone();
    (c.fk(&qp).translation.vector - c.fk(&qm).translation.vector) / (2.0 * h)
}

/// The joint-angle error of joint j that explains Δp (least squares on the J column).
fn project(d: &Vector3<f64>, col: &Vector3<f64>) -> f64 {
    d.dot(col) / col.norm_squared()
}

#[test]
fn joint_compliance_follows_gravity_torque_and_scales_linearly() {
    let mut a =
        ArmPhysics::ideal(robocal_mocks::world::chain::UrdfChain::preset("denso-vs060").unwrap());
    a.masses = masses();
    let ctx = JointContext::at_rest(6);
    let c2 = 2.5e-4;
    for qd in [
        [0.0, 60.0, 30.0, 0.0, 0.0, 0.0],
        [20.0, -30.0, 100.0, 40.0, 30.0, 10.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    ] {
        let q = deg(&qd);
        let p0 = flange_p(&a, &q, &ctx);
        let mut b = a.clone();
        b.effects.joint_compliance = vec![JointCompliance {
            joint: 2,
            rad_per_nm: c2,
        }];
        let p1 = flange_p(&b, &q, &ctx);
        let tau = a.gravity_torques(&a.chain.frames(&q, 1.0, None))[1];
        let dtheta = project(&(p1 - p0), &joint_column(&a, &q, 1));
        println!(
            "q {qd:?}: τ2 = {tau:.3} N·m, Δθ2 = {:.6} mrad (expect {:.6}), |Δp| = {:.4} mm",
            dtheta * 1e3,
            c2 * tau * 1e3,
            (p1 - p0).norm()
        );
        assert!((dtheta - c2 * tau).abs() <= 1e-3 * (c2 * tau).abs() + 1e-9);
        // Doubling the compliance doubles the displacement.
        let mut d = b.clone();
        d.effects.joint_compliance[0].rad_per_nm = 2.0 * c2;
        let p2 = flange_p(&d, &q, &ctx);
        assert!(((p2 - p0).norm() - 2.0 * (p1 - p0).norm()).abs() < 1e-3 * (p1 - p0).norm() + 1e-9);
    }
    // Vertical arm: no torque, no deflection.
    let q = deg(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let tau = a.gravity_torques(&a.chain.frames(&q, 1.0, None))[1];
    assert!(tau.abs() < 1.0, "nearly vertical arm has small τ2: {tau}");
}

#[test]
fn backlash_depends_on_approach_direction() {
    let b_deg = 0.02;
    let mut s = clean();
    s.arms[0].effects.backlash = vec![Backlash {
        joint: 1,
        lost_motion_deg: b_deg,
    }];
    let w = WorldHandle::from_scenario(&s).unwrap();
    let q = deg(&[10.0, 40.0, 80.0, 0.0, 30.0, 0.0]);
    let sp = MoveSpeed::default();
    let measure = |pre: f64| {
        let mut q0 = q.clone();
        q0[0] += pre.to_radians();
        w.arm_start_move(0, &q0, sp).unwrap();
        w.advance(w.arm_motion_end(0) - w.now());
        w.arm_start_move(0, &q, sp).unwrap();
        w.advance(w.arm_motion_end(0) - w.now());
        w.arm_true_flange(0).translation.vector
    };
    let from_below = measure(-10.0);
    let from_above = measure(10.0);
    let truth = w.truth();
    let col = joint_column(&truth.arms[0].physics, &q, 0);
    let dtheta = project(&(from_below - from_above), &col);
    println!(
        "backlash: Δθ1(+ − −) = {:.5}° (lost motion {b_deg}°), |Δp| = {:.4} mm",
        dtheta.to_degrees(),
        (from_below - from_above).norm()
    );
    assert!((dtheta.to_degrees() - b_deg).abs() < 1e-3 * b_deg);
    // A repeated approach from the same side reproduces exactly.
    assert!((measure(-5.0) - from_below).norm() < 1e-9);
}

#[test]
fn eccentricity_is_a_first_and_second_harmonic_of_the_joint_angle() {
    let base =
        ArmPhysics::ideal(robocal_mocks::world::chain::UrdfChain::preset("denso-vs060").unwrap());
    let mut a = base.clone();
    let e = Eccentricity {
        joint: 4,
        sin1_deg: 0.01,
        cos1_deg: -0.005,
        sin2_deg: 0.004,
        cos2_deg: 0.002,
    };
    a.effects.eccentricity = vec![e.clone()];
    let ctx = JointContext::at_rest(6);
    // Sweep joint 4 over a full turn, recover Δθ4 from the marker displacement, fit harmonics.
    let n = 72;
    let mut rows = Vec::new();
    for k in 0..n {
        let q4 = -std::f64::consts::PI + 2.0 * std::f64::consts::PI * k as f64 / n as f64;
        let q = vec![0.0, 0.6, 1.2, q4, 0.7, 0.0];
        // Point off the joint-4 axis so its rotation is visible: use flange + offset.
        let off = nalgebra::Translation3::new(30.0, 20.0, 100.0);
        let p0 = (base.true_flange(&q, &ctx) * off).translation.vector;
        let p1 = (a.true_flange(&q, &ctx) * off).translation.vector;
        let h = 1e-6;
        let mut qp = q.clone();
        qp[3] += h;
        let col = ((base.true_flange(&qp, &ctx) * off).translation.vector - p0) / h;
        rows.push((q4, project(&(p1 - p0), &col)));
    }
    // Least squares on [sin, cos, sin2, cos2] by orthogonality over a full uniform sweep.
    let fit =
        |f: &dyn Fn(f64) -> f64| rows.iter().map(|(x, y)| y * f(*x)).sum::<f64>() * 2.0 / n as f64;
    let got = [
        fit(&|x| x.sin()),
        fit(&|x| x.cos()),
        fit(&|x| (2.0 * x).sin()),
        fit(&|x| (2.0 * x).cos()),
    ];
    let want = [e.sin1_deg, e.cos1_deg, e.sin2_deg, e.cos2_deg].map(f64::to_radians);
    println!("eccentricity: fitted (deg) {:?}", got.map(f64::to_degrees));
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).abs() < 2e-3 * 0.01f64.to_radians(), "{g} vs {w}");
    }
}

#[test]
fn thermal_drift_is_an_exponential_warm_up() {
    let mut s = clean();
    let tau = 1800.0;
    s.arms[0].effects.thermal = Some(Thermal {
        delta_t_inf_k: 8.0,
        tau_s: tau,
        expansion_per_k: 23e-6,
        offset_drift_deg_per_k: vec![0.0, 0.001, 0.0, 0.0, 0.0, 0.0],
        t_power_on_s: 0.0,
    });
    let w = WorldHandle::from_scenario(&s).unwrap();
    w.arm_start_move(
        0,
        &deg(&[0.0, 45.0, 60.0, 0.0, 30.0, 0.0]),
        MoveSpeed::default(),
    )
    .unwrap();
    let t0 = w.arm_motion_end(0);
    w.advance(t0 - w.now());
    let p = |w: &WorldHandle| w.marker_truth(0).unwrap().translation.vector;
    let p0 = p(&w);
    w.advance(tau);
    let p_tau = p(&w);
    w.advance(20.0 * tau);
    let p_inf = p(&w);
    let total = (p_inf - p0).norm();
    let frac = (p_tau - p0).norm() / total;
    println!("thermal: total drift {total:.4} mm, fraction after τ = {frac:.4}");
    // From t0 (≈ seconds) to t0 + τ the warm-up covers ≈ 1 − e^−1 of what remains.
    assert!((frac - (1.0 - (-1.0f64).exp())).abs() < 0.01, "{frac}");
    assert!(total > 0.1 && total < 5.0, "{total}");
}

#[test]
fn transmission_ratio_error_grows_linearly_with_the_joint_angle() {
    let base =
        ArmPhysics::ideal(robocal_mocks::world::chain::UrdfChain::preset("denso-vs060").unwrap());
    let mut a = base.clone();
    let ppm = 300.0;
    a.effects.transmission = vec![Transmission {
        joint: 1,
        ratio_error_ppm: ppm,
    }];
    let ctx = JointContext::at_rest(6);
    for q1 in [-2.0, -1.0, 0.5, 2.5] {
        let q = vec![q1, 0.6, 1.2, 0.0, 0.7, 0.0];
        let d = flange_p(&a, &q, &ctx) - flange_p(&base, &q, &ctx);
        let dt = project(&d, &joint_column(&base, &q, 0));
        assert!(
            (dt - q1 * ppm * 1e-6).abs() < 1e-3 * (q1 * ppm * 1e-6).abs(),
            "{dt}"
        );
    }
}

#[test]
fn link_deflection_tilts_perpendicular_to_the_joint_axis() {
    let mut a =
        ArmPhysics::ideal(robocal_mocks::world::chain::UrdfChain::preset("denso-vs060").unwrap());
    a.masses = masses();
    let ctx = JointContext::at_rest(6);
    let q = deg(&[90.0, 60.0, 30.0, 0.0, 0.0, 0.0]);
    let p0 = flange_p(&a, &q, &ctx);
    let c = 2e-5;
    let mut b = a.clone();
    b.effects.link_deflection = vec![LinkDeflection {
        joint: 1,
        rad_per_nm: c,
    }];
    let p1 = flange_p(&b, &q, &ctx);
    let frames = a.chain.frames(&q, 1.0, None);
    let m = a.gravity_moments(&frames)[0];
    // Joint 1 is vertical: the whole horizontal gravity moment bends it.
    let tilt = c * m.norm();
    let lever = {
        let o = frames.joint_origin(0);
        let r = p0 - o.coords;
        (r - m.normalize() * r.dot(&m.normalize())).norm()
    };
    let d = p1 - p0;
    println!(
        "link deflection: |M⟂| = {:.2} N·m, tilt = {:.4} mrad, |Δp| = {:.4} mm (expect ≈ {:.4})",
        m.norm(),
        tilt * 1e3,
        d.norm(),
        tilt * lever
    );
    assert!((d.norm() - tilt * lever).abs() < 0.01 * tilt * lever);
    assert!(d.z < 0.0, "sags under gravity");
    // Joint 1's own axis (vertical) cannot produce a vertical displacement: the signature is
    // out of the span of joint 1's encoder column.
    let col = joint_column(&a, &q, 0);
    assert!(
        d.dot(&col).abs() < 1e-3 * d.norm() * col.norm(),
        "{d} vs {col}"
    );
}

fn frames_stats(w: &WorldHandle, n: usize) -> Vec<Vector3<f64>> {
    (0..n)
        .filter_map(|_| match w.tracker_frame().tools[0].status {
            ToolStatus::Visible { pose, .. } => Some(pose.0.translation.vector),
            _ => None,
        })
        .collect()
}

fn home_world(s: &Scenario) -> WorldHandle {
    let w = WorldHandle::from_scenario(s).unwrap();
    w.arm_start_move(
        0,
        &deg(&[0.0, 45.0, 60.0, 0.0, 30.0, 0.0]),
        MoveSpeed::default(),
    )
    .unwrap();
    w.advance(w.arm_motion_end(0) - w.now());
    w
}

#[test]
fn tracker_noise_is_anisotropic_depth_much_larger_than_lateral() {
    let mut s = clean();
    s.trackers[0].effects.noise_lateral_mm = 0.02;
    s.trackers[0].effects.noise_depth_mm = 0.12;
    let w = home_world(&s);
    let truth = w.marker_truth(0).unwrap().translation.vector;
    let los = truth.normalize();
    let samples = frames_stats(&w, 4000);
    let (mut sd, mut sl) = (0.0, 0.0);
    for p in &samples {
        let e = p - truth;
        let along = e.dot(&los);
        sd += along * along;
        sl += (e - los * along).norm_squared() / 2.0;
    }
    let n = samples.len() as f64;
    let (depth, lateral) = ((sd / n).sqrt(), (sl / n).sqrt());
    println!("tracker noise: depth σ = {depth:.4} mm (0.12), lateral σ = {lateral:.4} mm (0.02)");
    assert!((depth - 0.12).abs() < 0.006 && (lateral - 0.02).abs() < 0.001);
}

#[test]
fn tracker_scale_error_scales_about_the_tracker_origin() {
    let mut s = clean();
    s.trackers[0].effects.scale_ppm = 500.0;
    let w = home_world(&s);
    let truth = w.marker_truth(0).unwrap().translation.vector;
    let m = frames_stats(&w, 1)[0];
    println!(
        "tracker scale: |Δ| = {:.4} mm at {:.1} mm",
        (m - truth).norm(),
        truth.norm()
    );
    assert!((m - truth * (1.0 + 500e-6)).norm() < 1e-9);
}

#[test]
fn tracker_volume_view_angle_occlusion() {
    // Polaris pyramid: a tracker 1.5 m in front of the marker, looking at it: inside.
    let mut s = clean();
    let w0 = home_world(&s);
    let m = (w0.arm_true_flange(0) * w0.truth().trackers[0].marker_on_flange)
        .translation
        .vector;
    s.trackers[0].tracker_in_base = robocal_mocks::scenario::Placement {
        xyz_mm: [m.x + 1500.0, m.y, m.z],
        rpy_deg: [0.0, 90.0, 0.0],
    };
    s.trackers[0].effects.volume = Some(VolumeKind::PolarisPyramid);
    let w = home_world(&s);
    let p = w.marker_truth(0).unwrap().translation.vector;
    assert!(
        (p - nalgebra::Vector3::new(0.0, 0.0, -1500.0)).norm() < 1e-6,
        "{p}"
    );
    assert!(matches!(
        w.tracker_frame().tools[0].status,
        ToolStatus::Visible { .. }
    ));
    // Sideways beyond the pyramid's half-angle: out of volume.
    let mut side = s.clone();
    side.trackers[0].tracker_in_base.xyz_mm[1] += 0.4 * 1500.0;
    assert_eq!(
        home_world(&side).tracker_frame().tools[0].status,
        ToolStatus::OutOfVolume
    );
    // Move the tracker 1.5 m further away: beyond 2400 mm → out of volume.
    s.trackers[0].tracker_in_base.xyz_mm[0] += 1500.0;
    let w2 = home_world(&s);
    assert_eq!(w2.tracker_frame().tools[0].status, ToolStatus::OutOfVolume);
    // View angle: 0.5° cone → not facing → missing.
    let mut s3 = clean();
    s3.trackers[0].effects.max_view_angle_deg = Some(0.5);
    assert_eq!(
        home_world(&s3).tracker_frame().tools[0].status,
        ToolStatus::Missing
    );
    // Occluder sphere halfway along the line of sight.
    let w4 = home_world(&clean());
    let truth = w4.truth();
    let tib = truth.trackers[0].tracker_in_base;
    let marker = w4.arm_true_flange(0) * truth.trackers[0].marker_on_flange;
    let mid = (tib.translation.vector + marker.translation.vector) / 2.0;
    let mut s5 = clean();
    s5.trackers[0].effects.occluders = vec![Occluder {
        center_mm: mid.into(),
        radius_mm: 30.0,
    }];
    assert_eq!(
        home_world(&s5).tracker_frame().tools[0].status,
        ToolStatus::Missing
    );
    // Out-of-band occlusion.
    w4.control().set_occluded(0, true);
    assert_eq!(w4.tracker_frame().tools[0].status, ToolStatus::Missing);
    w4.control().set_occluded(0, false);
    assert!(matches!(
        w4.tracker_frame().tools[0].status,
        ToolStatus::Visible { .. }
    ));
}

#[test]
fn base_bump_moves_every_reading_by_one_rigid_transform_after_its_time() {
    let mut s = clean();
    s.trackers[0].effects.base_bump = Some(BaseBump {
        t_s: 100.0,
        shift_mm: [0.5, -0.3, 0.2],
        rot_deg: [0.0, 0.02, 0.0],
    });
    let w = WorldHandle::from_scenario(&s).unwrap();
    let clean_w = WorldHandle::from_scenario(&clean()).unwrap();
    let qs = [
        deg(&[0.0, 45.0, 60.0, 0.0, 30.0, 0.0]),
        deg(&[-30.0, 20.0, 90.0, 40.0, -30.0, 10.0]),
    ];
    for (i, q) in qs.iter().enumerate() {
        for ww in [&w, &clean_w] {
            ww.arm_start_move(0, q, MoveSpeed::default()).unwrap();
            ww.advance(ww.arm_motion_end(0) - ww.now());
        }
        let before = frames_stats(&w, 1)[0] - frames_stats(&clean_w, 1)[0];
        assert!(before.norm() < 1e-9, "pose {i}: no change before the bump");
    }
    w.advance(200.0);
    clean_w.advance(200.0);
    let truth = w.truth();
    let tib = truth.trackers[0].tracker_in_base;
    let bump = robocal_mocks::world::tracker_in_base_at(tib, &truth.trackers[0].effects, 150.0);
    for q in &qs {
        for ww in [&w, &clean_w] {
            ww.arm_start_move(0, q, MoveSpeed::default()).unwrap();
            ww.advance(ww.arm_motion_end(0) - ww.now());
        }
        let bumped = frames_stats(&w, 1)[0];
        let unbumped = frames_stats(&clean_w, 1)[0];
        // The same base-frame point seen from the moved tracker.
        let base_p = tib * Point3::from(unbumped);
        let expect = bump.inverse() * base_p;
        assert!((bumped - expect.coords).norm() < 1e-9);
        println!("base bump: |Δ| = {:.4} mm", (bumped - unbumped).norm());
        assert!((bumped - unbumped).norm() > 0.3);
    }
}

#[test]
fn latency_shows_the_marker_where_it_was_latency_seconds_ago() {
    let lat = 0.014;
    let mut s = clean();
    s.trackers[0].effects.latency_s = lat;
    let a = WorldHandle::from_scenario(&s).unwrap();
    let b = WorldHandle::from_scenario(&clean()).unwrap();
    let target = deg(&[40.0, 30.0, 70.0, 0.0, 30.0, 0.0]);
    for w in [&a, &b] {
        w.arm_start_move(0, &target, MoveSpeed::default()).unwrap();
    }
    let rate = 60.0;
    a.advance(0.5 - 1.0 / rate);
    b.advance(0.5 - lat - 1.0 / rate);
    let pa = frames_stats(&a, 1)[0];
    let pb = frames_stats(&b, 1)[0];
    assert!((pa - pb).norm() < 1e-9);
    let now = frames_stats(
        &{
            let c = WorldHandle::from_scenario(&clean()).unwrap();
            c.arm_start_move(0, &target, MoveSpeed::default()).unwrap();
            c.advance(0.5 - 1.0 / rate);
            c
        },
        1,
    )[0];
    println!(
        "latency: lag {:.4} mm at t = 0.5 s of the move",
        (pa - now).norm()
    );
    assert!((pa - now).norm() > 0.1);
    // Static: no effect.
    for w in [&a, &b] {
        w.advance(w.arm_motion_end(0) - w.now() + 1.0);
    }
    assert!((frames_stats(&a, 1)[0] - frames_stats(&b, 1)[0]).norm() < 1e-9);
}

fn laser_scenario(effects: LaserEffects) -> Scenario {
    let mut s = clean();
    s.lasers = vec![LaserConfig {
        name: "il600".into(),
        kind: "keyence-il600".into(),
        protocol: Protocol::DlRs1a,
        arm: "arm".into(),
        beam_origin_mm: [0.0, 0.0, 50.0],
        beam_dir: [0.0, 0.0, 1.0],
        min_mm: 200.0,
        max_mm: 1000.0,
        max_incidence_deg: 60.0,
        rate_hz: 1000.0,
        effects,
    }];
    s.scene.planes = vec![PlaneConfig {
        name: "P3".into(),
        normal: [0.0, 0.0, 1.0],
        through_mm: [0.0, 0.0, -100.0],
    }];
    s
}

/// Move so the flange looks straight down (z_flange = −z_base), tilted by `tilt_deg` about y.
fn point_down(w: &WorldHandle, tilt_deg: f64) {
    // VS060: q2 + q3 + q5 = 180° puts the flange z straight down with q1 = q4 = 0.
    let q = deg(&[0.0, 30.0, 60.0, 0.0, 90.0 + tilt_deg, 0.0]);
    w.arm_start_move(0, &q, MoveSpeed::default()).unwrap();
    w.advance(w.arm_motion_end(0) - w.now());
}

fn readings(w: &WorldHandle, n: usize) -> Vec<f64> {
    (0..n)
        .filter_map(|_| match w.laser_reading() {
            RangeReading::Distance(d) => Some(d),
            RangeReading::OutOfRange => None,
        })
        .collect()
}

#[test]
fn laser_noise_window_scale_offset_and_incidence() {
    // Repeatability noise.
    let w = WorldHandle::from_scenario(&laser_scenario(LaserEffects {
        noise_mm: 0.05,
        ..Default::default()
    }))
    .unwrap();
    point_down(&w, 0.0);
    let (d_true, spot, surface) = w.laser_truth(0).unwrap();
    assert_eq!(surface, "P3");
    assert!((spot.z + 100.0).abs() < 1e-9);
    let r = readings(&w, 4000);
    let mean = r.iter().sum::<f64>() / r.len() as f64;
    let sd = (r.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / r.len() as f64).sqrt();
    println!("laser: true distance {d_true:.3} mm, mean {mean:.4}, σ = {sd:.4} mm (0.05)");
    assert!((sd - 0.05).abs() < 0.003 && (mean - d_true).abs() < 0.005);
    // Scale and offset.
    let w = WorldHandle::from_scenario(&laser_scenario(LaserEffects {
        scale_ppm: 1000.0,
        offset_mm: 0.3,
        ..Default::default()
    }))
    .unwrap();
    point_down(&w, 0.0);
    let (d, _, _) = w.laser_truth(0).unwrap();
    assert!((readings(&w, 1)[0] - (d * 1.001 + 0.3)).abs() < 1e-9);
    // Incidence bias: even in the tilt, = incidence_mm (1 − cos γ).
    let w = WorldHandle::from_scenario(&laser_scenario(LaserEffects {
        incidence_mm: 2.0,
        ..Default::default()
    }))
    .unwrap();
    for tilt in [-20.0f64, 20.0] {
        point_down(&w, tilt);
        let (d, _, _) = w.laser_truth(0).unwrap();
        let bias = readings(&w, 1)[0] - d;
        let truth = w.truth();
        let flange = w.arm_true_flange(0);
        let u = flange.rotation * Vector3::from(truth.lasers[0].config.beam_dir);
        let cos_g = (-u).z;
        println!(
            "laser incidence: tilt {tilt}°, γ = {:.2}°, bias = {bias:.4} mm",
            cos_g.acos().to_degrees()
        );
        assert!((bias - 2.0 * (1.0 - cos_g)).abs() < 1e-9 && bias > 0.05);
    }
    // Window: plane 1.2 m away → out of range; forced out-of-range via control.
    let mut s = laser_scenario(LaserEffects::default());
    s.scene.planes[0].through_mm[2] = -1500.0;
    let w = WorldHandle::from_scenario(&s).unwrap();
    point_down(&w, 0.0);
    assert_eq!(w.laser_reading(), RangeReading::OutOfRange);
    let w = WorldHandle::from_scenario(&laser_scenario(LaserEffects::default())).unwrap();
    point_down(&w, 0.0);
    w.control().force_out_of_range(0, 2);
    assert_eq!(w.laser_reading(), RangeReading::OutOfRange);
    assert_eq!(w.laser_reading(), RangeReading::OutOfRange);
    assert!(matches!(w.laser_reading(), RangeReading::Distance(_)));
}
