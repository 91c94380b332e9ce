//! What a session deploys: the calibrated geometry as a URDF (metres, radians, the URDF
//! convention) beside the `robocal-calibration/1` file (which also carries the effects).
//!
//! Link frames of the URDF are the MDH joint frames of the calibrated model at q = 0; every
//! joint turns about its frame's z axis, so the URDF reproduces the calibrated flange pose at
//! every q (tested by reading it back). Effects (compliance, backlash, ...) have no URDF
//! form: they stay in the calibration file.
use std::fmt::Write as _;

use nalgebra::Isometry3;

use crate::model::KinematicModel;

fn origin(iso: &Isometry3<f64>) -> String {
    let t = iso.translation.vector / 1000.0;
    let (r, p, y) = iso.rotation.euler_angles();
    format!(
        "<origin xyz=\"{:.10} {:.10} {:.10}\" rpy=\"{:.12} {:.12} {:.12}\"/>",
        t.x, t.y, t.z, r, p, y
    )
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// URDF of the calibrated geometry of `model`; `datasets` (the session's dataset SHA-256s)
/// goes into a comment so the file names what it came from.
pub fn urdf(model: &KinematicModel, name: &str, datasets: &serde_json::Value) -> String {
    // The robot alone: the tracker → base transform is the cell's, not the robot's.
    let mut model = model.clone();
    model.set_base(&Isometry3::identity());
    let model = &model;
    let dof = model.dof();
    let zero = vec![0.0; dof];
    let frames: Vec<Isometry3<f64>> = (0..=dof).map(|k| model.joint_frame(&zero, k)).collect();
    let limits = model.joint_limits();
    let mut s = String::new();
    let _ = writeln!(s, "<?xml version=\"1.0\"?>");
    let _ = writeln!(
        s,
        "<!-- Calibrated by robocal from datasets {} (SHA-256). Geometry only: effects are in calibration.json. -->",
        esc(&datasets.to_string()).replace("--", "- -")
    );
    let _ = writeln!(s, "<robot name=\"{}\">", esc(name));
    let _ = writeln!(s, "  <link name=\"base_link\"/>");
    let mut parent = "base_link".to_string();
    let mut prev = Isometry3::identity();
    for i in 0..dof {
        let f = frames[i + 1];
        let link = format!("link{}", i + 1);
        let (lo, hi) = limits
            .get(i)
            .copied()
            .unwrap_or((-std::f64::consts::PI, std::f64::consts::PI));
        let _ = writeln!(s, "  <link name=\"{link}\"/>");
        let _ = writeln!(
            s,
            "  <joint name=\"{}\" type=\"revolute\">\n    <parent link=\"{parent}\"/>\n    <child link=\"{link}\"/>\n    {}\n    <axis xyz=\"0 0 1\"/>\n    <limit lower=\"{lo:.12}\" upper=\"{hi:.12}\" effort=\"0\" velocity=\"0\"/>\n  </joint>",
            esc(model.joint_names().get(i).map_or("joint", |n| n.as_str())),
            origin(&(prev.inverse() * f))
        );
        parent = link;
        prev = f;
    }
    let flange = model.flange_pose(&zero);
    let _ = writeln!(s, "  <link name=\"flange\"/>");
    let _ = writeln!(
        s,
        "  <joint name=\"flange_fixed\" type=\"fixed\">\n    <parent link=\"{parent}\"/>\n    <child link=\"flange\"/>\n    {}\n  </joint>",
        origin(&(prev.inverse() * flange))
    );
    let _ = writeln!(s, "</robot>");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The URDF read back gives the calibrated flange pose at random joint angles.
    #[test]
    fn urdf_round_trip_reproduces_the_calibrated_flange() {
        let mut m = KinematicModel::preset("denso-vs060").unwrap();
        // A calibrated-looking model: perturb every length / angle parameter a little.
        let mut v = m.param_values();
        for (i, x) in v.iter_mut().enumerate() {
            *x += 1e-3 * ((i as f64 * 1.7).sin());
        }
        m.set_param_values(&v);
        m.set_base(&Isometry3::identity());
        let text = urdf(&m, "vs060-test", &serde_json::json!({"train": "ab"}));
        let back = KinematicModel::from_urdf_str(&text, None, Some("flange")).unwrap();
        let mut worst: f64 = 0.0;
        for k in 0..20 {
            let q: Vec<f64> = (0..6)
                .map(|j| ((k * 7 + j * 3) as f64 * 0.37).sin())
                .collect();
            let a = m.flange_pose(&q);
            let b = back.flange_pose(&q);
            worst = worst.max((a.translation.vector - b.translation.vector).norm());
            worst = worst.max(a.rotation.angle_to(&b.rotation) * 1000.0);
        }
        println!("URDF round trip: worst flange difference {worst:.2e} mm (or mrad·1000)");
        assert!(worst < 1e-5, "{worst}");
    }
}
