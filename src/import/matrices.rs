//! Tracked-pose tables as tracker software exports them for pivot calibration: one pose per
//! line, the first three rows of the 4×4 marker pose in the tracker frame, row-major (12
//! numbers, translation in mm), optionally preceded by an id / time stamp (13 numbers);
//! blank lines and lines starting with `#` are skipped (the format of scikit-surgery's and
//! MPHY0026's pivot recordings). Parsed from `&str`; every bad line is an error naming the
//! file, line and field with the likely cause; nothing panics.
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion};

use super::error::ImportError;

/// Fields of a row after the optional id.
const FIELDS: [&str; 12] = [
    "m00", "m01", "m02", "m03", "m10", "m11", "m12", "m13", "m20", "m21", "m22", "m23",
];

/// Parse the table `text` read from `file` (the name is only used in errors).
pub fn parse_pose_matrices(file: &str, text: &str) -> Result<Vec<Isometry3<f64>>, ImportError> {
    let mut out = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let ln = k + 1;
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let tok: Vec<&str> = l
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty())
            .collect();
        let vals = match tok.len() {
            12 => &tok[..],
            13 => &tok[1..],
            16 | 17 => {
                return Err(ImportError::bad(
                    file,
                    Some(ln),
                    None,
                    format!(
                        "{} numbers: give the first three rows of the 4×4 pose (12 numbers, \
                         optionally after an id), without the constant last row 0 0 0 1",
                        tok.len()
                    ),
                ))
            }
            n => {
                return Err(ImportError::bad(
                    file,
                    Some(ln),
                    None,
                    format!("{n} fields, expected 12 (m00 … m23, row-major) or 13 (id then 12)"),
                ))
            }
        };
        let mut m = [0.0; 12];
        for (i, t) in vals.iter().enumerate() {
            let v: f64 = t.parse().map_err(|_| {
                ImportError::bad(
                    file,
                    Some(ln),
                    Some(FIELDS[i]),
                    format!("`{t}` is not a number"),
                )
            })?;
            if !v.is_finite() || v.abs() > 1e7 {
                return Err(ImportError::bad(
                    file,
                    Some(ln),
                    Some(FIELDS[i]),
                    format!("{v} is not a finite pose entry (translation in mm, |x| ≤ 1e7)"),
                ));
            }
            m[i] = v;
        }
        let r = Matrix3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
        let err = (r.transpose() * r - Matrix3::identity()).amax();
        if err > 1e-3 || r.determinant() < 0.0 {
            return Err(ImportError::bad(
                file,
                Some(ln),
                Some("m00..m22"),
                format!(
                    "the 3×3 block is not a rotation (|RᵀR − I| = {err:.2e}, det = {:.4}): \
                     column-major export, a scaled matrix, or the wrong columns",
                    r.determinant()
                ),
            ));
        }
        let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
        out.push(Isometry3::from_parts(
            Translation3::new(m[3], m[7], m[11]),
            rot,
        ));
    }
    if out.is_empty() {
        return Err(ImportError::bad(
            file,
            None,
            None,
            "no pose rows (only comments or blank lines)",
        ));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_with_and_without_id_and_bad_rows() {
        let t = "# header\n7 1 0 0 10 0 1 0 20 0 0 1 30\n0 -1 0 1  1 0 0 2  0 0 1 3\n";
        let f = parse_pose_matrices("f.txt", t).unwrap();
        assert_eq!(f.len(), 2);
        assert!(
            (f[0].translation.vector - nalgebra::Vector3::new(10.0, 20.0, 30.0)).norm() < 1e-12
        );
        assert!((f[1].rotation.angle() - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
        let e = parse_pose_matrices("f.txt", "1 0 0 10 0 1 0 20 0 0 1 x")
            .unwrap_err()
            .to_string();
        assert!(e.contains("f.txt:1") && e.contains("m23"), "{e}");
        let e = parse_pose_matrices("f.txt", "\n2 0 0 10 0 1 0 20 0 0 1 3")
            .unwrap_err()
            .to_string();
        assert!(e.contains("f.txt:2") && e.contains("not a rotation"), "{e}");
        assert!(parse_pose_matrices("f.txt", "1 2 3").is_err());
        assert!(parse_pose_matrices("f.txt", "1 0 0 1e308 0 1 0 0 0 0 1 0").is_err());
        assert!(parse_pose_matrices("f.txt", "# x\n").is_err());
    }
}
