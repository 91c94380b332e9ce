//! The synthesiser: shape, determinism, truth consistency; and the world's conventions against
//! the independent simulator that wrote `tests/data/kin-*`.

use nalgebra::{Isometry3, Matrix4, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use robocal_mocks::scenario::Scenario;
use robocal_mocks::synth::{synthesize, SynthConfig};
use robocal_mocks::world::chain::UrdfChain;
use robocal_mocks::world::effects::{ArmPhysics, JointContext};
use robocal_mocks::WorldHandle;
use serde_json::Value;

fn data(path: &str) -> String {
    let p = format!("{}/../tests/data/{path}", env!("CARGO_MANIFEST_DIR"));
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{p}: {e}"))
}

fn iso_from_rows(v: &Value) -> Isometry3<f64> {
    let mut m = Matrix4::zeros();
    for r in 0..4 {
        for c in 0..4 {
            m[(r, c)] = v[r][c].as_f64().unwrap();
        }
    }
    let rot = Rotation3::from_matrix(&m.fixed_view::<3, 3>(0, 0).into_owned());
    Isometry3::from_parts(
        Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

/// Rebuild the independent simulator's truth for `case` with this crate's chain code and check
/// it reproduces `truth.csv`: proves θ = q + offset, URDF rpy order and the tracker_in_base
/// direction are the same conventions.
fn check_case(case: &str) -> f64 {
    check_case_with(case, |_| {})
}

fn check_case_with(case: &str, extra: impl Fn(&mut ArmPhysics)) -> f64 {
    let c: Value = serde_json::from_str(&data(&format!("{case}/case.json"))).unwrap();
    let mut chain = UrdfChain::preset("denso-vs060").unwrap();
    for (j, tj) in chain
        .joints
        .iter_mut()
        .zip(c["true_chain"].as_array().unwrap())
    {
        for k in 0..3 {
            j.origin_xyz_mm[k] = tj["origin_xyz"][k].as_f64().unwrap();
            j.origin_rpy_rad[k] = tj["origin_rpy_deg"][k].as_f64().unwrap().to_radians();
        }
    }
    let mut phys = ArmPhysics::ideal(UrdfChain::preset("denso-vs060").unwrap());
    phys.chain = chain;
    phys.offsets_rad = c["joint_offsets_deg"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap().to_radians())
        .collect();
    extra(&mut phys);
    let mof = iso_from_rows(&c["marker_on_flange"]);
    let tib = iso_from_rows(&c["tracker_in_base"]);
    let truth: std::collections::HashMap<u64, Vector3<f64>> = data(&format!("{case}/truth.csv"))
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            (f[0] as u64, Vector3::new(f[1], f[2], f[3]))
        })
        .collect();
    let mut worst: f64 = 0.0;
    for line in data(&format!("{case}/heldout.jsonl")).lines().skip(1) {
        let r: Value = serde_json::from_str(line).unwrap();
        let q: Vec<f64> = r["q"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap().to_radians())
            .collect();
        let f = phys.true_flange(&q, &JointContext::at_rest(6));
        let p = tib.inverse() * f * mof * Point3::origin();
        let want = truth[&r["id"].as_u64().unwrap()];
        worst = worst.max((p.coords - want).norm());
    }
    worst
}

#[test]
fn world_conventions_match_the_independent_simulator() {
    let worst = check_case("kin-geometric");
    println!("kin-geometric: worst |world - truth.csv| = {worst:.6} mm");
    // truth.csv has 5 decimals, q in the file 5 decimals of a degree (≤ 1e-5° ⇒ ≤ 0.2 µm at 1 m).
    assert!(worst < 1e-3, "{worst}");
}

fn small_cfg() -> SynthConfig {
    SynthConfig {
        n_train: 40,
        n_heldout: 12,
        seed: 7,
        ..SynthConfig::default()
    }
}

fn noisy_scenario() -> Scenario {
    let mut s = Scenario::single_arm("denso-vs060", 11);
    s.trackers[0].effects.noise_lateral_mm = 0.03;
    s.trackers[0].effects.noise_depth_mm = 0.1;
    s.arms[0].effects.servo_error_deg = 0.0005;
    s
}

#[test]
fn synth_is_deterministic_and_well_formed() {
    let s = noisy_scenario();
    let a = synthesize(&WorldHandle::from_scenario(&s).unwrap(), &small_cfg()).unwrap();
    let b = synthesize(&WorldHandle::from_scenario(&s).unwrap(), &small_cfg()).unwrap();
    assert_eq!(a, b, "same scenario + seed must give byte-identical files");
    let mut s2 = s.clone();
    s2.seed = 12;
    let c = synthesize(&WorldHandle::from_scenario(&s2).unwrap(), &small_cfg()).unwrap();
    assert_ne!(a.train_jsonl, c.train_jsonl);

    let train: Vec<Value> = a
        .train_jsonl
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let held: Vec<Value> = a
        .heldout_jsonl
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(train[0]["format"], "robocal-dataset/1");
    assert_eq!(train.len(), 41);
    assert_eq!(held.len(), 13);
    assert!(train[1..].iter().all(|r| r["group"] == "train"));
    assert!(held[1..].iter().all(|r| r["group"] == "validation"));
    // Time stamps increase ~9 s apart.
    let mut all: Vec<&Value> = train[1..].iter().chain(held[1..].iter()).collect();
    all.sort_by_key(|r| r["id"].as_u64().unwrap());
    let ts: Vec<f64> = all.iter().map(|r| r["t"].as_f64().unwrap()).collect();
    let mut gaps: Vec<f64> = ts.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(gaps.iter().all(|g| *g > 3.0 && *g < 16.0), "{gaps:?}");
    gaps.sort_by(f64::total_cmp);
    let median = gaps[gaps.len() / 2];
    assert!(median > 8.0 && median < 10.0, "median gap {median}");
    // Truth rows = held-out ids; measurement − truth is at the noise level.
    let truth: Vec<Vec<f64>> = a
        .truth_csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
        .collect();
    assert_eq!(truth.len(), 12);
    let mut sq = 0.0;
    for (t, r) in truth.iter().zip(&held[1..]) {
        assert_eq!(t[0] as u64, r["id"].as_u64().unwrap());
        for k in 0..3 {
            let d = r["marker"]["p"][k].as_f64().unwrap() - t[k + 1];
            sq += d * d;
        }
        // q (encoders) differs from q_cmd by the servo error only.
        for k in 0..6 {
            let d = r["q"][k].as_f64().unwrap() - r["q_cmd"][k].as_f64().unwrap();
            assert!(d.abs() < 0.005, "{d}");
        }
    }
    let rms = (sq / 36.0).sqrt();
    // Per-frame noise 0.03/0.03/0.1 mm averaged over 30 frames: ≈ 0.02 mm per axis.
    assert!(rms > 0.003 && rms < 0.06, "rms {rms}");
    let case: Value = serde_json::from_str(&a.case_json).unwrap();
    assert_eq!(case["true_chain"].as_array().unwrap().len(), 6);
    assert_eq!(case["n_heldout"], 12);
}

#[test]
fn compliance_physics_matches_the_independent_simulator() {
    use robocal_mocks::world::effects::{JointCompliance, PointMass};
    // README: 3 kg mid link 3 (halfway from joint 3 to the wrist centre), 1.5 kg at the wrist
    // centre (joint 5), 0.8 kg tool 120 mm past the flange.
    let worst = check_case_with("kin-compliance-j2", |p| {
        p.masses = vec![
            PointMass {
                link: 3,
                xyz_mm: [-5.0, 0.0, 150.0],
                kg: 3.0,
            },
            PointMass {
                link: 5,
                xyz_mm: [0.0, 0.0, 0.0],
                kg: 1.5,
            },
            PointMass {
                link: 7,
                xyz_mm: [0.0, 0.0, 120.0],
                kg: 0.8,
            },
        ];
        p.effects.joint_compliance = vec![JointCompliance {
            joint: 2,
            rad_per_nm: 0.00025,
        }];
    });
    let geometric_only = check_case("kin-compliance-j2");
    println!("kin-compliance-j2: worst |world - truth.csv| = {worst:.6} mm (geometric only {geometric_only:.3} mm)");
    assert!(worst < 0.01, "{worst} vs {geometric_only}");
}

#[test]
fn synth_from_a_scenario_file_records_its_effects() {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("scenarios/lab-vs060-optotrak-il600.toml");
    let s = Scenario::load(&path).unwrap();
    let cfg = SynthConfig {
        n_train: 20,
        n_heldout: 5,
        ..SynthConfig::default()
    };
    let out = synthesize(&WorldHandle::from_scenario(&s).unwrap(), &cfg).unwrap();
    let case: Value = serde_json::from_str(&out.case_json).unwrap();
    let kinds: Vec<&str> = case["effects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["kind"].as_str().unwrap())
        .collect();
    assert!(kinds.contains(&"joint_compliance"), "{kinds:?}");
    assert_eq!(
        case["masses"].as_array().unwrap().len(),
        3,
        "two links + payload"
    );
    assert_eq!(out.truth_csv.lines().count(), 6);
    let rec: Value = serde_json::from_str(out.train_jsonl.lines().nth(1).unwrap()).unwrap();
    assert_eq!(rec["approach"].as_array().unwrap().len(), 6);
    assert_eq!(rec["marker"]["frames"], 30);
}
