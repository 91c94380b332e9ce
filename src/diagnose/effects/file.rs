//! The calibration-file side shared by the families: the reader's error type and the
//! helpers that turn a family's typed parameter struct into / out of the `params` map of a
//! [`CalEffect`] (the wire format of `calibration.json` is the structs' field names).
use serde::de::DeserializeOwned;
use serde::{Deserialize, Deserializer, Serialize};
use serde_json::{Map, Value};

use crate::dataset::CalEffect;

/// Why a calibration-file effect cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum EffectFileError {
    /// No family of the registry claims the kind.
    #[error("unknown effect kind \"{0}\" (robocal knows: {known})", known = super::known_kinds())]
    UnknownKind(String),
    /// The family needs a joint and the entry has none (or joint 0).
    #[error("effect {kind}: needs a joint (1-based)")]
    NeedsJoint { kind: String },
    /// A parameter is missing or has the wrong type.
    #[error("effect {kind}: {what}")]
    Params { kind: String, what: String },
    /// The parameters are present but inconsistent (a named field out of range).
    #[error("{kind}: {why}")]
    Invalid { kind: String, why: String },
}

impl EffectFileError {
    /// An inconsistent entry of `e`, `why` naming the field.
    pub fn invalid(e: &CalEffect, why: String) -> Self {
        EffectFileError::Invalid {
            kind: e.kind.clone(),
            why,
        }
    }
}

/// The entry's joint (1-based), required.
pub fn joint(e: &CalEffect) -> Result<usize, EffectFileError> {
    e.joint
        .filter(|j| *j >= 1)
        .ok_or_else(|| EffectFileError::NeedsJoint {
            kind: e.kind.clone(),
        })
}

/// The typed parameters as the `params` map (non-finite numbers become `null`).
pub fn to_params<T: Serialize>(p: &T) -> Map<String, Value> {
    match serde_json::to_value(p) {
        Ok(Value::Object(m)) => m,
        // A parameter struct always serializes to an object.
        _ => Map::new(),
    }
}

/// The typed parameters of `e`. An error names the field: serde names a missing one; a
/// field of the wrong type is found by comparing with the type the struct's default has.
pub fn from_params<T: DeserializeOwned + Serialize + Default>(
    e: &CalEffect,
) -> Result<T, EffectFileError> {
    serde_json::from_value(Value::Object(e.params.clone())).map_err(|err| {
        let expected = to_params(&T::default());
        let bad = expected.iter().find_map(|(k, want)| {
            let got = e.params.get(k)?;
            (!want.is_null() && type_name(got) != type_name(want))
                .then(|| format!("\"{k}\" must be {} (got {})", type_name(want), short(got)))
        });
        EffectFileError::Params {
            kind: e.kind.clone(),
            what: bad.unwrap_or_else(|| err.to_string()),
        }
    })
}

fn type_name(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

fn short(v: &Value) -> String {
    let s = v.to_string();
    if s.chars().count() > 40 {
        format!("{}…", s.chars().take(40).collect::<String>())
    } else {
        s
    }
}

/// A standard deviation as read: a number, or NaN for `null`, a missing field or anything
/// else (standard deviations are informative; the reader never fails on them).
pub fn lenient<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    let v = Value::deserialize(d)?;
    Ok(v.as_f64().unwrap_or(f64::NAN))
}

/// An array of standard deviations as read (see [`lenient`]).
pub fn lenient_vec<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
    let v = Value::deserialize(d)?;
    Ok(v.as_array()
        .map(|a| a.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect())
        .unwrap_or_default())
}

/// A count (harmonic, joint number) as read: a non-negative integer, else 0 (which the
/// family's range check then refuses by the field's name).
pub fn count<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
    let v = Value::deserialize(d)?;
    Ok(v.as_u64().unwrap_or(0))
}

/// NaN (the default of a standard deviation a file does not give).
pub fn nan() -> f64 {
    f64::NAN
}

/// Degrees of each value (rad inside).
pub fn deg(v: &[f64]) -> Vec<f64> {
    v.iter().map(|x| x.to_degrees()).collect()
}

/// Radians of each value (degrees in files).
pub fn rad(v: &[f64]) -> Vec<f64> {
    v.iter().map(|x| x.to_radians()).collect()
}
