//! Strict structural checks of the JSON values of a dataset / calibration file.
//!
//! Serde alone reports a type error without saying which field it was in; these checks run
//! on the parsed `serde_json::Value` first so every error names its field. Semantic checks
//! that need the typed structs (dof, quaternion norms, id order) live in `io.rs`.
use serde_json::{Map, Value};

use super::error::Problem;

/// How far from 1 the norm of a stored quaternion may be (files carry ~7 decimals).
pub const QUAT_NORM_TOL: f64 = 1e-3;
/// How far from 1 the norm of a chain joint axis may be.
pub const AXIS_NORM_TOL: f64 = 1e-3;

/// The expected JSON type of a field.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Ty {
    Num,
    UInt,
    U32,
    Str,
    Bool,
    /// An array of exactly n numbers.
    Nums(usize),
    /// An array of `[u, v]` pairs.
    PairList,
    Obj,
    /// A number or `null`.
    NumOrNull,
}

fn describe(ty: Ty) -> String {
    match ty {
        Ty::Num => "expected a number".into(),
        Ty::UInt => "expected a non-negative integer".into(),
        Ty::U32 => "expected a non-negative integer below 2^32".into(),
        Ty::Str => "expected a string".into(),
        Ty::Bool => "expected true or false".into(),
        Ty::Nums(n) => format!("expected an array of {n} numbers"),
        Ty::PairList => "expected an array of [u, v] number pairs".into(),
        Ty::Obj => "expected an object".into(),
        Ty::NumOrNull => "expected a number or null".into(),
    }
}

fn is_num_array(v: &Value, n: usize) -> bool {
    match v.as_array() {
        Some(a) => a.len() == n && a.iter().all(Value::is_number),
        None => false,
    }
}

fn matches(v: &Value, ty: Ty) -> bool {
    match ty {
        Ty::Num => v.is_number(),
        Ty::UInt => v.is_u64(),
        Ty::U32 => v.as_u64().is_some_and(|x| x <= u64::from(u32::MAX)),
        Ty::Str => v.is_string(),
        Ty::Bool => v.is_boolean(),
        Ty::Nums(n) => is_num_array(v, n),
        Ty::PairList => v
            .as_array()
            .is_some_and(|a| a.iter().all(|p| is_num_array(p, 2))),
        Ty::Obj => v.is_object(),
        Ty::NumOrNull => v.is_number() || v.is_null(),
    }
}

fn short(v: &Value) -> String {
    let s = v.to_string();
    if s.chars().count() > 40 {
        let cut: String = s.chars().take(37).collect();
        format!("{cut}...")
    } else {
        s
    }
}

/// Joins a prefix (`marker`) and a key (`p`) into `marker.p`.
pub(crate) fn join(prefix: &str, key: &str) -> String {
    if prefix.is_empty() {
        key.to_string()
    } else {
        format!("{prefix}.{key}")
    }
}

/// Checks that `obj[key]` has type `ty`. A missing key is an error when `required`;
/// `null` counts as absent for optional fields, except for [`Ty::NumOrNull`].
pub(crate) fn field(
    obj: &Map<String, Value>,
    prefix: &str,
    key: &str,
    ty: Ty,
    required: bool,
) -> Result<(), Problem> {
    match obj.get(key) {
        None => {
            if required {
                Err(Problem::field(join(prefix, key), "missing"))
            } else {
                Ok(())
            }
        }
        Some(Value::Null) if !required && !matches!(ty, Ty::NumOrNull) => Ok(()),
        Some(v) => {
            if matches(v, ty) {
                Ok(())
            } else {
                Err(Problem::field(
                    join(prefix, key),
                    format!("{}, got {}", describe(ty), short(v)),
                ))
            }
        }
    }
}

/// `obj[key]` as an object, checked; `None` when absent (and not required) or null.
pub(crate) fn object<'a>(
    obj: &'a Map<String, Value>,
    prefix: &str,
    key: &str,
    required: bool,
) -> Result<Option<&'a Map<String, Value>>, Problem> {
    field(obj, prefix, key, Ty::Obj, required)?;
    Ok(obj.get(key).and_then(Value::as_object))
}

/// The norm check of a unit quaternion `[w, x, y, z]`.
/// (The one quaternion check, [`crate::plausible::quat::unit_wxyz`].)
pub(crate) fn unit_quat(q: &[f64; 4], field: &str) -> Result<(), Problem> {
    crate::plausible::quat::unit_wxyz(q)
        .map(|_| ())
        .map_err(|e| Problem::field(field, format!("[w, x, y, z] must be unit: {e}")))
}

/// Checks a `{p, quat}` pose object.
pub(crate) fn file_pose(obj: &Map<String, Value>, prefix: &str) -> Result<(), Problem> {
    field(obj, prefix, "p", Ty::Nums(3), true)?;
    field(obj, prefix, "quat", Ty::Nums(4), true)
}

/// Checks a marker observation object.
pub(crate) fn marker(obj: &Map<String, Value>, prefix: &str) -> Result<(), Problem> {
    field(obj, prefix, "p", Ty::Nums(3), false)?;
    field(obj, prefix, "quat", Ty::Nums(4), false)?;
    field(obj, prefix, "rms", Ty::Num, false)?;
    field(obj, prefix, "visible", Ty::Bool, false)?;
    field(obj, prefix, "frames", Ty::U32, false)
}

/// Checks a robot block (`robot` in a header or a calibration file).
pub(crate) fn robot(obj: &Map<String, Value>, prefix: &str) -> Result<(), Problem> {
    field(obj, prefix, "model", Ty::Str, true)?;
    field(obj, prefix, "serial", Ty::Str, false)?;
    if let Some(chain) = obj.get("chain").filter(|v| !v.is_null()) {
        let chain_field = join(prefix, "chain");
        let Some(joints) = chain.as_array() else {
            return Err(Problem::field(
                chain_field,
                format!("expected an array of joints, got {}", short(chain)),
            ));
        };
        for (i, j) in joints.iter().enumerate() {
            let jp = format!("{chain_field}[{i}]");
            let Some(j) = j.as_object() else {
                return Err(Problem::field(jp, "expected an object"));
            };
            field(j, &jp, "name", Ty::Str, true)?;
            field(j, &jp, "origin_xyz", Ty::Nums(3), true)?;
            field(j, &jp, "origin_rpy", Ty::Nums(3), true)?;
            field(j, &jp, "axis", Ty::Nums(3), true)?;
            field(j, &jp, "limits", Ty::Nums(2), false)?;
        }
    }
    if let Some(fl) = object(obj, prefix, "flange", false)? {
        let fp = join(prefix, "flange");
        field(fl, &fp, "origin_xyz", Ty::Nums(3), true)?;
        field(fl, &fp, "origin_rpy", Ty::Nums(3), true)?;
    }
    Ok(())
}
