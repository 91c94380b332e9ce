//! Tests over the whole registry (every family) and of the file form's error messages.
use super::*;
use serde_json::json;

fn ctx() -> PoseCtx {
    PoseCtx {
        id: 1,
        t: 100.0,
        q: vec![0.3, -0.8, 1.2, 0.4, -0.6, 0.9],
        q_cmd: None,
        q_prev: None,
        approach: vec![1.0, -1.0, 1.0, -1.0, 1.0, -1.0],
        temp_c: Some(23.0),
        qd: Some(vec![0.2, -0.1, 0.3, 0.5, -0.4, 0.6]),
    }
}

fn model() -> KinematicModel {
    KinematicModel::preset("denso-vs060").unwrap()
}

/// Every family of the registry has an example, and every kind of the registry is one.
#[test]
fn every_registered_kind_has_an_example() {
    let ex = registry_examples(&model());
    assert_eq!(ex.len(), KINDS.len());
    for k in KINDS {
        assert!(ex.iter().any(|e| e.block.kind() == *k), "no example of {k}");
    }
}

/// Every family survives the calibration-file form (as JSON text, the way `calibration.json`
/// holds it) with the same block, coefficients, standard deviations and prediction, and
/// every example moves the point (a non-trivial check).
#[test]
fn every_family_round_trips_through_the_file_with_the_same_prediction() {
    let model = model();
    let ctx = ctx();
    let p0 = apply_effects(&model, &[], &ctx);
    for e in registry_examples(&model) {
        let label = e.block.label();
        let p1 = apply_effects(&model, std::slice::from_ref(&e), &ctx);
        assert!(
            (p1 - p0).norm() > 1e-4,
            "{label} moves the point by only {:.2e} mm",
            (p1 - p0).norm()
        );
        let text = serde_json::to_string(&e.to_cal()).unwrap();
        let cal: CalEffect = serde_json::from_str(&text).unwrap();
        let back = Effect::from_cal(&cal).unwrap_or_else(|err| panic!("{label}: {err}"));
        // (The kernel correction's centres pass through degrees: equal up to rounding,
        // which the prediction check below covers.)
        if !matches!(e.block, Block::Nonparametric(_)) {
            assert_eq!(back.block, e.block, "{label}");
        }
        assert_eq!(back.coefs.len(), e.coefs.len(), "{label}");
        for (a, b) in back.coefs.iter().zip(&e.coefs) {
            assert!(
                (a - b).abs() <= 1e-12 * b.abs().max(1e-9),
                "{label}: {a} vs {b}"
            );
        }
        for (a, b) in back.std.iter().zip(&e.std) {
            assert!((a - b).abs() <= 1e-12, "{label}: std {a} vs {b}");
        }
        let p2 = apply_effects(&model, &[back], &ctx);
        assert!((p2 - p1).norm() < 1e-9, "{label}: {}", (p2 - p1).norm());
        // The diagnosis' parameters: one finite value per named parameter.
        for p in e.parameters() {
            assert!(p.value.is_finite(), "{label}: {}", p.name);
        }
    }
}

/// Every family says what it found in plain words with its size: no generic
/// `effect <kind>`, no identifiers (`c_times_mass@frame3`, the kind name), a number.
#[test]
fn every_family_has_a_plain_word_sentence() {
    for e in registry_examples(&model()) {
        let s = e.sentence();
        let kind = e.block.kind();
        assert!(!s.starts_with("effect"), "{kind}: generic sentence {s:?}");
        assert!(
            !s.contains('@') && !s.contains('_'),
            "{kind}: identifier in {s:?}"
        );
        assert!(
            s.chars().any(|c| c.is_ascii_digit()),
            "{kind}: no number in {s:?}"
        );
        assert!(s.len() > 40, "{kind}: {s:?}");
    }
}

/// Every family's analytic columns (through [`eval_pose`]) match central finite
/// differences of the exact prediction [`apply_effects`] over its coefficients.
#[test]
fn every_family_columns_match_finite_differences() {
    let model = model();
    let ctx = ctx();
    for e in registry_examples(&model) {
        let ev = eval_pose(&model, std::slice::from_ref(&e), &ctx);
        assert!((ev.pred - apply_effects(&model, std::slice::from_ref(&e), &ctx)).norm() < 1e-9);
        for k in 0..e.coefs.len() {
            let h = 1e-6;
            let at = |d: f64| {
                let mut x = e.clone();
                x.coefs[k] += d;
                apply_effects(&model, &[x], &ctx)
            };
            let fd = (at(h) - at(-h)) / (2.0 * h);
            let an = ev.jac_effects.column(k).into_owned();
            let err = (fd - an).norm();
            assert!(
                err <= 1e-5 * fd.norm().max(1.0),
                "{} coef {k}: analytic {an:?} vs finite differences {fd:?}",
                e.block.label()
            );
        }
    }
}

/// The new family (tracker depth scale) moves only the tracker-z coordinate, by `s·z`, and
/// is refused as a candidate when the points hardly spread in depth.
#[test]
fn tracker_depth_scale_scales_depth_only() {
    let model = model();
    let ctx = ctx();
    let p0 = apply_effects(&model, &[], &ctx);
    let e = Effect {
        block: Block::TrackerDepthScale(TrackerDepthScale),
        coefs: vec![1e-3],
        std: vec![f64::NAN],
        tau_std: f64::NAN,
    };
    let d = apply_effects(&model, &[e], &ctx) - p0;
    assert!(d.x.abs() < 1e-12 && d.y.abs() < 1e-12, "{d:?}");
    assert!(
        (d.z - 1e-3 * p0.z).abs() < 1e-9,
        "{} vs {}",
        d.z,
        1e-3 * p0.z
    );
    let obs: Vec<PoseObs> = (0..10)
        .map(|i| {
            PoseObs::at(
                i,
                i as f64,
                ctx.q.clone(),
                Point3::new(i as f64 * 10.0, 0.0, 1500.0 + i as f64),
            )
        })
        .collect();
    let err = TrackerDepthScale
        .check_identifiable(&model, &obs)
        .unwrap_err();
    assert!(err.contains("viewing axis"), "{err}");
}

/// A transmission ripple with a bad harmonic, anisotropic link deflection with a
/// coefficient missing or unknown axes, a bad gear ratio, a missing number, an unknown
/// kind: each refused with the field's name.
#[test]
fn bad_file_entries_are_refused_by_field_name() {
    let model = model();
    let ex = registry_examples(&model);
    let find = |k: &str| ex.iter().find(|e| e.block.kind() == k).unwrap().to_cal();
    let err_of = |c: &CalEffect| Effect::from_cal(c).unwrap_err().to_string();
    let mut bad = find("transmission_ripple");
    bad.params.insert("harmonic".into(), json!(0));
    assert!(err_of(&bad).contains("harmonic"), "{}", err_of(&bad));
    bad.params.insert("harmonic".into(), json!("four"));
    assert!(err_of(&bad).contains("harmonic"), "{}", err_of(&bad));
    let mut bad = find("link_deflection");
    bad.params.insert("axes".into(), json!("isotropic"));
    assert!(err_of(&bad).contains("per point"), "{}", err_of(&bad));
    bad.params.insert("axes".into(), json!("diagonal"));
    assert!(err_of(&bad).contains("axes"), "{}", err_of(&bad));
    let mut bad = find("wave_generator");
    bad.params.insert("gear_ratio".into(), json!(-3.0));
    assert!(err_of(&bad).contains("gear_ratio"), "{}", err_of(&bad));
    let mut bad = find("backlash");
    bad.params.remove("half_lost_motion_deg");
    assert!(
        err_of(&bad).contains("half_lost_motion_deg"),
        "{}",
        err_of(&bad)
    );
    bad = find("backlash");
    bad.params
        .insert("half_lost_motion_deg".into(), json!("0.01"));
    assert!(
        err_of(&bad).contains("half_lost_motion_deg"),
        "{}",
        err_of(&bad)
    );
    bad.joint = None;
    bad.params = find("backlash").params;
    assert!(err_of(&bad).contains("joint"), "{}", err_of(&bad));
    let mut bad = find("thermal_drift");
    bad.params.remove("tau_s");
    assert!(err_of(&bad).contains("tau_s"), "{}", err_of(&bad));
    bad.kind = "gravity_waves".into();
    let e = err_of(&bad);
    assert!(e.contains("gravity_waves") && e.contains("backlash"), "{e}");
}

/// A calibration file written before the effects became typed (the hand-written map of
/// that time, keys in its order) still loads, and is written back key for key.
#[test]
fn the_wire_format_is_unchanged() {
    let old = json!([
        {"kind": "joint_compliance", "joint": 2, "params": {"model": "gravity_point_masses",
            "gravity_dir": [0.0, 0.0, -1.0], "points": ["frame3", "marker"],
            "c_times_mass_deg_kg_per_nm": [0.01, 0.02], "c_times_mass_std": [0.001, null],
            "sum_c_times_mass_deg_kg_per_nm": 0.03}},
        {"kind": "backlash", "joint": 3, "params": {"half_lost_motion_deg": 0.01,
            "half_lost_motion_std": 0.001}},
        {"kind": "thermal_drift", "joint": 2, "params": {"driver": "warm_up", "t0_s": 0.0,
            "tau_s": 900.0, "deg_per_full_warm_up": 0.02, "std": 0.001}},
        {"kind": "thermal_drift", "params": {"driver": "temp_c", "t0_c": 21.0,
            "target": "link_lengths", "ppm_per_K": 11.5, "std": 0.4}},
        {"kind": "base_shift", "params": {"t_change_s": 601.0, "dx_mm": 0.1, "dy_mm": 0.0,
            "dz_mm": -0.2, "drx_deg": 0.001, "dry_deg": 0.0, "drz_deg": 0.002,
            "std": [0.01, 0.01, 0.01, 0.0001, 0.0001, 0.0001]}},
        {"kind": "temperature_drift", "params": {"t0_c": 21.5, "growth_ppm_per_k": 11.0,
            "offset_deg_per_k": [0.001, 0.0, 0.0, 0.0, 0.0, 0.0],
            "std": [0.1, 0.0001, 0.0001, 0.0001, 0.0001, 0.0001, 0.0001]}}
    ]);
    let cals: Vec<CalEffect> = serde_json::from_value(old.clone()).unwrap();
    let back: Vec<CalEffect> = cals
        .iter()
        .map(|c| Effect::from_cal(c).unwrap().to_cal())
        .collect();
    let written = serde_json::to_value(&back).unwrap();
    for (a, b) in written
        .as_array()
        .unwrap()
        .iter()
        .zip(old.as_array().unwrap())
    {
        let keys = |v: &Value| {
            v["params"]
                .as_object()
                .unwrap()
                .keys()
                .cloned()
                .collect::<Vec<_>>()
        };
        assert_eq!(keys(a), keys(b), "{a}");
        for (k, v) in b["params"].as_object().unwrap() {
            let w = &a["params"][k];
            match (v.as_f64(), w.as_f64()) {
                (Some(x), Some(y)) => assert!((x - y).abs() < 1e-12, "{k}: {x} vs {y}"),
                _ if v.is_array() => {
                    for (x, y) in v.as_array().unwrap().iter().zip(w.as_array().unwrap()) {
                        match (x.as_f64(), y.as_f64()) {
                            (Some(x), Some(y)) => assert!((x - y).abs() < 1e-12, "{k}"),
                            _ => assert_eq!(x, y, "{k}"),
                        }
                    }
                }
                _ => assert_eq!(v, w, "{k}"),
            }
        }
    }
}
