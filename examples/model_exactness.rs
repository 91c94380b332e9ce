//! Prints the measured accuracy figures of the kinematic model:
//! - max chain → MDH + Hayati conversion error over 10,000 random joint vectors
//!   (100 random chains incl. nearly parallel / anti-parallel / coincident axes × 100 q),
//! - max deviation of each preset from `tests/data/golden/fk-*.csv`,
//! - IK round-trip max error and branch counts (nominal and calibrated models),
//! - time of the analytic parameter Jacobian for 500 poses.
//!
//! Run: `cargo run --release --example model_exactness`
use std::collections::BTreeMap;
use std::path::PathBuf;

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use robocal::dataset::{ChainJoint, FixedOrigin};
use robocal::model::{pose_distance, KinematicModel, ParamGroup, SerialChain, Unit};
use serde_json::Map;

fn random_chain(rng: &mut ChaCha8Rng) -> (Vec<ChainJoint>, FixedOrigin) {
    let n = rng.random_range(1..=7);
    let mut chain = Vec::with_capacity(n);
    let mut prev = Vector3::z();
    let mut near_count = 0;
    for i in 0..n {
        let mut xyz: [f64; 3] = std::array::from_fn(|_| rng.random_range(-400.0..400.0));
        if rng.random_bool(0.3) {
            xyz[0] = 0.0;
            xyz[1] = 0.0;
        }
        let mut rpy: [f64; 3] = std::array::from_fn(|_| rng.random_range(-180.0..180.0));
        let mut axis = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        if axis.norm() < 1e-2 {
            axis = Vector3::z();
        }
        if i > 0 && rng.random_bool(0.45) {
            // nearly parallel (or anti-parallel / exactly parallel) to the previous axis
            near_count += 1;
            rpy[0] *= 1e-3;
            rpy[1] *= 1e-3;
            let r = UnitQuaternion::from_euler_angles(
                rpy[0].to_radians(),
                rpy[1].to_radians(),
                rpy[2].to_radians(),
            );
            let pa = r.inverse() * prev;
            let tilt = [0.0, 1e-8, 1e-5, 1e-3, 0.05][rng.random_range(0..5)];
            let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            axis = pa * sign + axis * tilt;
        }
        let _ = near_count;
        prev = axis;
        chain.push(ChainJoint {
            name: format!("j{i}"),
            origin_xyz: xyz,
            origin_rpy: rpy,
            axis: [axis.x, axis.y, axis.z],
            limits: None,
            extra: Map::new(),
        });
    }
    let fl = FixedOrigin {
        origin_xyz: std::array::from_fn(|_| rng.random_range(-200.0..200.0)),
        origin_rpy: std::array::from_fn(|_| rng.random_range(-180.0..180.0)),
        extra: Map::new(),
    };
    (chain, fl)
}

/// (q rad, flange pose, raw file quaternion as nalgebra coords x, y, z, w).
fn golden(preset: &str) -> Vec<(Vec<f64>, Isometry3<f64>, nalgebra::Vector4<f64>)> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join(format!("tests/data/golden/fk-{preset}.csv"));
    let mut r = csv::Reader::from_path(path).expect("golden file");
    r.records()
        .map(|rec| {
            let v: Vec<f64> = rec
                .expect("csv row")
                .iter()
                .map(|s| s.parse().expect("number"))
                .collect();
            let q = v[0..6].iter().map(|d| d.to_radians()).collect();
            let t = Translation3::new(v[6], v[7], v[8]);
            let rq = UnitQuaternion::from_quaternion(Quaternion::new(v[9], v[10], v[11], v[12]));
            (
                q,
                Isometry3::from_parts(t, rq),
                nalgebra::Vector4::new(v[10], v[11], v[12], v[9]),
            )
        })
        .collect()
}

fn perturbed(name: &str, rng: &mut ChaCha8Rng) -> KinematicModel {
    let mut m = KinematicModel::preset(name).expect("preset");
    let mut v = m.param_values();
    for (i, p) in m.params().iter().enumerate() {
        if matches!(p.group, ParamGroup::Joint(_)) {
            v[i] += match p.unit {
                Unit::Mm => rng.random_range(-0.5..0.5),
                Unit::Rad => rng.random_range(-0.005..0.005),
            };
        }
    }
    m.set_param_values(&v);
    m
}

fn main() {
    let mut rng = ChaCha8Rng::seed_from_u64(2026);

    // 1. conversion exactness
    let (mut wp, mut wr, mut nvec, mut nbeta) = (0.0f64, 0.0f64, 0usize, 0usize);
    for _ in 0..100 {
        let (chain, fl) = random_chain(&mut rng);
        let sc = SerialChain::from_chain_joints(&chain, Some(&fl)).expect("chain");
        let m = KinematicModel::from_chain(&chain, Some(&fl)).expect("conversion");
        nbeta += (2..=m.dof()).filter(|&j| m.uses_beta(j)).count();
        for _ in 0..100 {
            let q: Vec<f64> = (0..chain.len())
                .map(|_| rng.random_range(-7.0..7.0))
                .collect();
            let (dp, dr) = pose_distance(&sc.fk(&q), &m.flange_pose(&q));
            wp = wp.max(dp);
            wr = wr.max(dr);
            nvec += 1;
        }
    }
    println!("conversion: {nvec} random joint vectors on 100 random chains ({nbeta} joints using Hayati beta)");
    println!("  max position error {wp:.3e} mm, max rotation error {wr:.3e} rad");

    // 2. golden vectors
    for name in ["denso-vs060", "ur5e", "ur10e"] {
        let m = KinematicModel::preset(name).expect("preset");
        let rows = golden(name);
        let (mut gp, mut gr) = (0.0f64, 0.0f64);
        let mut gc = 0.0f64;
        for (q, pose, raw) in &rows {
            let fk = m.flange_pose(q);
            let (dp, dr) = pose_distance(&fk, pose);
            gp = gp.max(dp);
            gr = gr.max(dr);
            let (a, b) = (fk.rotation.coords, *raw);
            let t = (fk.translation.vector - pose.translation.vector).amax();
            gc = gc.max((a - b).amax().min((a + b).amax())).max(t);
        }
        println!(
            "golden {name}: {} rows, max deviation {gp:.3e} mm, {gr:.3e} rad; \
             max deviation of any file number (x, y, z, qw..qz; 6 decimals) {gc:.3e}",
            rows.len()
        );
    }

    // 3. IK round trips
    for calibrated in [false, true] {
        for name in ["denso-vs060", "ur5e", "ur10e"] {
            let m = if calibrated {
                perturbed(name, &mut rng)
            } else {
                KinematicModel::preset(name).expect("preset")
            };
            let lim = m.joint_limits();
            let mut hist: BTreeMap<usize, usize> = BTreeMap::new();
            let (mut ep, mut er, mut errors, mut in_lim, mut total) =
                (0.0f64, 0.0f64, 0usize, 0usize, 0usize);
            let mut recovered = 0usize;
            let n = 1000;
            for _ in 0..n {
                let q: Vec<f64> = lim
                    .iter()
                    .map(|&(lo, hi)| rng.random_range(lo.max(-3.1)..hi.min(3.1)))
                    .collect();
                let t = m.flange_pose(&q);
                match m.ik(&t) {
                    Ok(sols) => {
                        *hist.entry(sols.len()).or_default() += 1;
                        for s in &sols {
                            let (dp, dr) = pose_distance(&m.flange_pose(&s.q), &t);
                            ep = ep.max(dp);
                            er = er.max(dr);
                            total += 1;
                            in_lim += usize::from(s.within_limits);
                        }
                        if sols.iter().any(|s| {
                            s.q.iter().zip(&q).all(|(a, b)| {
                                let d = (a - b).rem_euclid(std::f64::consts::TAU);
                                d.min(std::f64::consts::TAU - d) < 1e-6
                            })
                        }) {
                            recovered += 1;
                        }
                    }
                    Err(_) => errors += 1,
                }
            }
            println!(
                "ik {} {name}: {n} random poses, branch-count histogram {:?}, errors {errors}, original q recovered {recovered}/{n}",
                if calibrated { "calibrated" } else { "nominal" },
                hist
            );
            println!(
                "  max round-trip error {ep:.3e} mm, {:.3e} deg; {in_lim}/{total} solutions within limits",
                er.to_degrees()
            );
        }
    }

    // 4. parameter Jacobian speed
    let m = perturbed("denso-vs060", &mut rng);
    let qs: Vec<Vec<f64>> = (0..500)
        .map(|_| (0..6).map(|_| rng.random_range(-2.0..2.0)).collect())
        .collect();
    let mut buf = nalgebra::Matrix3xX::zeros(m.params().len());
    let t0 = std::time::Instant::now();
    let reps = 100;
    let mut acc = 0.0;
    for _ in 0..reps {
        for q in &qs {
            acc += m
                .point_param_jacobian_into(q, &mut buf)
                .map(|p| p.x)
                .unwrap_or(0.0);
        }
    }
    let dt = t0.elapsed().as_secs_f64() / reps as f64;
    println!(
        "point_param_jacobian: 500 poses x {} params in {:.3} ms per pass (checksum {acc:.1})",
        m.params().len(),
        dt * 1e3
    );
}
