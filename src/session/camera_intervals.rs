//! The camera report's interval plots: the 95 % intervals of the deployed
//! camera calibration (intrinsics in px, hand-eye and board translation in mm, hand-eye
//! rotation in degrees), one row per parameter. Each row's dot is the deployed (diagnosed)
//! value minus the calibration stage's, its bar the deployed value's 95 % interval (1.96 σ of
//! the final fit's covariance): a bar that crosses 0 means the diagnosis moved the parameter by
//! less than its uncertainty. Drawn from `session.json`'s camera summary at report time.
use nalgebra::{Quaternion, UnitQuaternion};

use super::camera::CameraSummary;
use super::svg::param_changes;

/// A row: name, deployed − calibration stage, 95 % half-width.
type Row = (String, f64, Option<f64>);

fn half(sd: Option<f64>) -> Option<f64> {
    sd.filter(|x| x.is_finite() && *x > 0.0).map(|x| 1.96 * x)
}

fn quat(q: [f64; 4]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]))
}

/// The interval plots (SVG) of a camera session's calibration: intrinsics (px), translations
/// (mm), hand-eye rotation (deg). Empty when the summary carries no interval at all.
pub fn svgs(c: &CameraSummary) -> Vec<String> {
    let d = c.diagnosed.as_ref().unwrap_or(&c.calibrated);
    let cal = &c.calibrated;
    let (i, ic) = (&d.intrinsics, &cal.intrinsics);
    let sd = |k: usize| i.std.map(|s| s[k]);
    let intr: Vec<Row> = [
        ("fx", i.fx - ic.fx),
        ("fy", i.fy - ic.fy),
        ("cx", i.cx - ic.cx),
        ("cy", i.cy - ic.cy),
    ]
    .iter()
    .enumerate()
    .map(|(k, (n, v))| (n.to_string(), *v, half(sd(k))))
    .collect();
    let axes = ["x", "y", "z"];
    let (he, hc) = (&d.hand_eye, &cal.hand_eye);
    let mut trans: Vec<Row> = (0..3)
        .map(|k| {
            (
                format!("hand-eye {}", axes[k]),
                he.xyz_mm[k] - hc.xyz_mm[k],
                half(he.std_mm.map(|s| s[k])),
            )
        })
        .collect();
    let board = d
        .target_in_base
        .as_ref()
        .zip(cal.target_in_base.as_ref())
        .map(|(t, tc)| ("board", t, tc))
        .or_else(|| {
            d.target_in_flange
                .as_ref()
                .zip(cal.target_in_flange.as_ref())
                .map(|(t, tc)| ("board (flange)", t, tc))
        });
    if let Some((label, t, tc)) = board {
        trans.extend((0..3).map(|k| {
            (
                format!("{label} {}", axes[k]),
                t.xyz_mm[k] - tc.xyz_mm[k],
                half(t.std_mm.map(|s| s[k])),
            )
        }));
    }
    // Rotation: the deployed hand-eye's rotation relative to the calibration stage's, as a
    // rotation vector (deg) about the camera's x, y, z.
    let dr = (quat(hc.quat).inverse() * quat(he.quat))
        .scaled_axis()
        .map(f64::to_degrees);
    let rot: Vec<Row> = (0..3)
        .map(|k| {
            (
                format!("hand-eye about {}", axes[k]),
                dr[k],
                half(he.std_deg.map(|s| s[k])),
            )
        })
        .collect();
    let mut out = Vec::new();
    for (title, unit, rows) in [
        (
            "Intrinsics: 95 % intervals (dot: deployed − calibration stage)",
            "px",
            intr,
        ),
        (
            "Hand-eye and board position: 95 % intervals (dot: deployed − calibration stage)",
            "mm",
            trans,
        ),
        (
            "Hand-eye rotation: 95 % intervals (dot: deployed − calibration stage)",
            "°",
            rot,
        ),
    ] {
        if rows.iter().any(|r| r.2.is_some()) {
            out.push(param_changes(title, unit, &rows));
        }
    }
    out
}
