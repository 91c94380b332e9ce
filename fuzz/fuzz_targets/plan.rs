//! Plan file reader (`robocal-plan/1`) and the safety re-check of `plan --check` / `run`:
//! never panic; an accepted plan re-encodes to a file that reads back equal.
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal::plan::PlanFile;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(plan) = PlanFile::from_json_str(text) {
        let _ = robocal::plan::recheck::recheck(&plan, None);
        let json = serde_json::to_string(&plan).expect("a plan serialises");
        let again = PlanFile::from_json_str(&json)
            .expect("a plan robocal accepted re-encodes to a file robocal reads");
        let (a, b) = (
            serde_json::to_value(&again).expect("serialise"),
            serde_json::to_value(&plan).expect("serialise"),
        );
        assert!(same_json(&a, &b), "re-read plan differs");
    }
});

/// Equal JSON values, floats within a relative 1e-12 (serde_json is built without its
/// `float_roundtrip` feature: its fast float parser may land an ulp off on re-read).
fn same_json(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => match (x.as_f64(), y.as_f64()) {
            (Some(x), Some(y)) => {
                x == y
                    || (x - y).abs() <= 1e-12 * x.abs().max(y.abs())
                    || x.abs().max(y.abs()) < 1e-300
            }
            _ => x == y,
        },
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(p, q)| same_json(p, q))
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| same_json(v, w)))
        }
        _ => a == b,
    }
}
