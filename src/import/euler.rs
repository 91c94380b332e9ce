//! Euler-angle sequences and quaternion orders of imported files, SciPy's convention:
//! an uppercase sequence (`XYZ`) is intrinsic (rotations about the moving axes,
//! `R = R_X(a)·R_Y(b)·R_Z(c)`), a lowercase one (`xyz`) extrinsic (about the fixed axes,
//! `R = R_z(c)·R_y(b)·R_x(a)`), exactly as `scipy.spatial.transform.Rotation.from_euler`.
use std::fmt;
use std::str::FromStr;

use nalgebra::{Quaternion, Unit, UnitQuaternion, Vector3};

/// A three-axis Euler sequence (`XYZ`, `zyx`, `ZYZ`, ...).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EulerSeq {
    /// Axis indices (0 = x, 1 = y, 2 = z) in the order the angles are given.
    pub axes: [usize; 3],
    /// Intrinsic (uppercase) or extrinsic (lowercase).
    pub intrinsic: bool,
}

impl FromStr for EulerSeq {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let cs: Vec<char> = s.chars().collect();
        let bad = || {
            format!(
                "Euler sequence \"{s}\": expected three axes from x, y, z, all uppercase (intrinsic, e.g. XYZ) or all lowercase (extrinsic, e.g. xyz), no axis twice in a row"
            )
        };
        if cs.len() != 3 {
            return Err(bad());
        }
        let upper = cs.iter().all(|c| c.is_ascii_uppercase());
        let lower = cs.iter().all(|c| c.is_ascii_lowercase());
        if !(upper || lower) {
            return Err(bad());
        }
        let mut axes = [0; 3];
        for (i, c) in cs.iter().enumerate() {
            axes[i] = match c.to_ascii_lowercase() {
                'x' => 0,
                'y' => 1,
                'z' => 2,
                _ => return Err(bad()),
            };
        }
        if axes[0] == axes[1] || axes[1] == axes[2] {
            return Err(bad());
        }
        Ok(EulerSeq {
            axes,
            intrinsic: upper,
        })
    }
}

impl fmt::Display for EulerSeq {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for a in self.axes {
            let c = ['x', 'y', 'z'][a];
            write!(
                f,
                "{}",
                if self.intrinsic {
                    c.to_ascii_uppercase()
                } else {
                    c
                }
            )?;
        }
        Ok(())
    }
}

fn axis(i: usize) -> Unit<Vector3<f64>> {
    match i {
        0 => Vector3::x_axis(),
        1 => Vector3::y_axis(),
        _ => Vector3::z_axis(),
    }
}

impl EulerSeq {
    /// The rotation of the angles `a` (rad), given in sequence order.
    pub fn rotation(&self, a: [f64; 3]) -> UnitQuaternion<f64> {
        let r: Vec<UnitQuaternion<f64>> = (0..3)
            .map(|i| UnitQuaternion::from_axis_angle(&axis(self.axes[i]), a[i]))
            .collect();
        if self.intrinsic {
            r[0] * r[1] * r[2]
        } else {
            r[2] * r[1] * r[0]
        }
    }
}

/// Order of the four quaternion columns of a file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QuatOrder {
    /// Scalar first (robocal's own files).
    Wxyz,
    /// Scalar last (ROS, SciPy).
    Xyzw,
}

impl FromStr for QuatOrder {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "wxyz" => Ok(QuatOrder::Wxyz),
            "xyzw" => Ok(QuatOrder::Xyzw),
            _ => Err(format!(
                "quaternion order \"{s}\": expected wxyz (scalar first) or xyzw (scalar last)"
            )),
        }
    }
}

impl QuatOrder {
    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            QuatOrder::Wxyz => "wxyz",
            QuatOrder::Xyzw => "xyzw",
        }
    }

    /// The quaternion of four values in this order (not normalised).
    pub fn quaternion(&self, v: [f64; 4]) -> Quaternion<f64> {
        match self {
            QuatOrder::Wxyz => Quaternion::new(v[0], v[1], v[2], v[3]),
            QuatOrder::Xyzw => Quaternion::new(v[3], v[0], v[1], v[2]),
        }
    }
}

/// `[w, x, y, z]` of a unit quaternion, sign chosen with `w ≥ 0`.
pub fn wxyz(q: &UnitQuaternion<f64>) -> [f64; 4] {
    let q = q.quaternion();
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    [s * q.w, s * q.i, s * q.j, s * q.k]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Produced with SciPy 1.17.1 (`.venv/peers-pybotics`):
    /// `R.from_euler(s, [10.0, -35.0, 120.0], degrees=True).as_quat()` reordered to
    /// `[w, x, y, z]`, for each sequence `s`.
    const SCIPY: [(&str, [f64; 4]); 6] = [
        (
            "XYZ",
            [
                0.4977408842017601,
                -0.21786693443889596,
                -0.2217664465657473,
                0.8096960258330588,
            ],
        ),
        (
            "xyz",
            [
                0.45234688561385017,
                0.3009888436523894,
                -0.0777950765858491,
                0.8359042631373821,
            ],
        ),
        (
            "ZYX",
            [
                0.45234688561385017,
                0.8359042631373821,
                -0.0777950765858491,
                0.3009888436523894,
            ],
        ),
        (
            "zyx",
            [
                0.4977408842017601,
                0.8096960258330588,
                -0.2217664465657473,
                -0.21786693443889596,
            ],
        ),
        (
            "ZYZ",
            [
                0.403058199917856,
                -0.24632377039348102,
                -0.17247776086975317,
                0.8643610990919671,
            ],
        ),
        (
            "xzy",
            [
                0.4977408842017601,
                -0.21786693443889596,
                0.8096960258330588,
                -0.2217664465657473,
            ],
        ),
    ];

    #[test]
    fn euler_sequences_match_scipy() {
        let a = [
            10f64.to_radians(),
            (-35f64).to_radians(),
            120f64.to_radians(),
        ];
        for (s, want) in SCIPY {
            let seq: EulerSeq = s.parse().unwrap();
            assert_eq!(seq.to_string(), s);
            let got = wxyz(&seq.rotation(a));
            let err = (0..4).map(|i| (got[i] - want[i]).abs()).fold(0.0, f64::max);
            assert!(err < 1e-12, "{s}: {got:?} vs scipy {want:?}");
        }
        // An IPA-like measurement: scipy `R.from_euler('XYZ', [-90.5, -60.25, -91.0], degrees=True)`.
        let seq: EulerSeq = "XYZ".parse().unwrap();
        let got = wxyz(&seq.rotation([-90.5f64, -60.25, -91.0].map(f64::to_radians)));
        let want = [
            0.6810277906032837,
            -0.17852468281583989,
            -0.6857798940568351,
            -0.18448854424844283,
        ];
        assert!((0..4).all(|i| (got[i] - want[i]).abs() < 1e-12), "{got:?}");
    }

    #[test]
    fn bad_sequences_and_orders_are_refused() {
        for s in ["XyZ", "XXY", "xy", "abc", "XYZX", "xzz"] {
            let e = s.parse::<EulerSeq>().unwrap_err();
            assert!(e.contains(s), "{e}");
        }
        assert!("qwer".parse::<QuatOrder>().unwrap_err().contains("wxyz"));
        let q = QuatOrder::Xyzw.quaternion([1.0, 2.0, 3.0, 4.0]);
        assert_eq!((q.w, q.i, q.j, q.k), (4.0, 1.0, 2.0, 3.0));
    }
}
