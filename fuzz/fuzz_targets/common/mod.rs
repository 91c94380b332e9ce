//! Helpers shared by the file-reader fuzz targets (not a target itself).

/// Equal JSON values, floats within a relative 1e-12 (a margin kept from before serde_json's
/// `float_roundtrip` feature was enabled; round trips are now exact).
pub fn same_json(a: &serde_json::Value, b: &serde_json::Value) -> bool {
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
