//! Predictions outside the calibrated joint ranges (issue 31 §4): `robocal diagnose` writes
//! the training poses' joint ranges into `calibration.json` (`effects_joint_range`); a held-out
//! pose outside them is predicted with every effect of the joint angles held at the edge, by the diagnosis and by
//! `robocal predict` alike, and both print one warning line naming the pose, the joint and the
//! degrees. A calibration file without the ranges (older files) still loads and predicts.
use std::collections::HashMap;
use std::path::Path;

use serde_json::Value;

use crate::common::{bin, heldout_argv, predict_argv};
use crate::diagnose::table;
use crate::diagnose_predict::{points, synth_files};

/// Moves joint 2 of the first pose record of `path` to `deg`; returns its id.
fn move_joint2(path: &Path, deg: f64) -> u64 {
    let text = std::fs::read_to_string(path).unwrap();
    let mut id = None;
    let lines: Vec<String> = text
        .lines()
        .map(|l| {
            let mut v: Value = serde_json::from_str(l).unwrap();
            if id.is_none() && v.get("q").is_some_and(Value::is_array) {
                v["q"][1] = serde_json::json!(deg);
                id = v["id"].as_u64();
                return serde_json::to_string(&v).unwrap();
            }
            l.to_string()
        })
        .collect();
    std::fs::write(path, lines.join("\n") + "\n").unwrap();
    id.expect("a pose record")
}

/// `robocal predict` (the binary); asserts success and returns its stderr.
fn predict(cal: &Path, data: &Path, out: &Path) -> String {
    let (code, _, err) = bin(&predict_argv(cal, data, out));
    assert_eq!(code, Some(0), "{err}");
    err
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[test]
fn predict_outside_the_calibrated_range_holds_the_effects_and_warns() {
    let w = table::worlds()
        .into_iter()
        .find(|w| w.name.starts_with("transmission j2"))
        .unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let (train, held) = synth_files(&w, 1, dir);
    // Joint 2's training range, from the training file itself.
    let tr = robocal::dataset::read_dataset(&train).unwrap().dataset;
    let hi = tr
        .poses()
        .filter_map(|p| p.q.as_ref().map(|q| q[1]))
        .fold(f64::NEG_INFINITY, f64::max);
    let id = move_joint2(&held, hi + 20.0);
    let out = dir.join("diag");
    let (code, _, err) = bin(&heldout_argv(&["diagnose"], &train, &held, &out, &[]));
    assert_eq!(code, Some(0), "{err}");
    let want = format!("pose {id}: joint 2 is 20.0° outside the calibrated range");
    assert!(
        err.contains(&want)
            && err.contains("every effect of the joint angles is held at its value at the edge"),
        "diagnose: no `{want}` in\n{err}"
    );
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains(&want), "report.md: no `{want}`");
    let cal = out.join("calibration.json");
    let calv: Value = serde_json::from_str(&std::fs::read_to_string(&cal).unwrap()).unwrap();
    let max2 = calv["effects_joint_range"]["max_deg"][1].as_f64().unwrap();
    assert!((max2 - hi).abs() < 1e-9, "max_deg {max2} vs training {hi}");
    let kinds: Vec<&str> = calv["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|e| e["kind"].as_str())
        .collect();
    assert!(kinds.contains(&"transmission_ratio"), "{kinds:?}");

    // `robocal predict` gives the diagnosis' own held-out predictions and the same warning.
    let pred = dir.join("pred.csv");
    let err = predict(&cal, &held, &pred);
    assert!(
        err.contains("of 60 predicted pose(s) lie outside") && err.contains(&want),
        "predict: no `{want}` in\n{err}"
    );
    let written: HashMap<u64, [f64; 3]> = points(&out.join("heldout_predictions.csv"))
        .into_iter()
        .collect();
    let got: HashMap<u64, [f64; 3]> = points(&pred).into_iter().collect();
    for (k, p) in &written {
        assert!(dist(*p, got[k]) < 1e-5, "pose {k}: {p:?} vs {:?}", got[k]);
    }

    // An older file without the ranges loads and predicts (extrapolating, without warning).
    let mut old = calv.clone();
    old.as_object_mut().unwrap().remove("effects_joint_range");
    let old_cal = dir.join("old.json");
    std::fs::write(&old_cal, serde_json::to_string_pretty(&old).unwrap()).unwrap();
    let pred_old = dir.join("pred_old.csv");
    let err = predict(&old_cal, &held, &pred_old);
    assert!(!err.contains("outside the calibrated"), "{err}");
    let got_old: HashMap<u64, [f64; 3]> = points(&pred_old).into_iter().collect();
    assert!(
        dist(got_old[&id], got[&id]) > 1e-3,
        "the held prediction of pose {id} differs from the extrapolated one"
    );
    // Poses inside every range: the same prediction either way.
    let range = |k: &str| -> Vec<f64> {
        calv["effects_joint_range"][k]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let (lo, hi) = (range("min_deg"), range("max_deg"));
    let he = robocal::dataset::read_dataset(&held).unwrap().dataset;
    let mut inside = 0;
    for p in he.poses() {
        let q = p.q.as_ref().unwrap();
        if (0..q.len()).all(|j| lo[j] <= q[j] && q[j] <= hi[j]) {
            inside += 1;
            let k = &p.id;
            assert!(
                dist(got_old[k], got[k]) < 1e-9,
                "pose {k} inside: unchanged"
            );
        }
    }
    assert!(inside > 40, "{inside} poses inside the ranges");
}
