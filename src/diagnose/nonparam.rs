//! Data-driven correction of what no physical effect explains: Gaussian-kernel ridge
//! regression (a GP posterior mean) of the 3-D residual on joint space, with the length
//! scale and ridge chosen by time-blocked cross-validation. Used only after the physical
//! effects are exhausted, and labelled `nonparametric`.
use nalgebra::{DMatrix, Matrix3, Vector3};

use crate::model::KinematicModel;
use serde_json::{json, Map, Value};

/// A fitted kernel correction: `Σ_k w_k exp(−|q − c_k|² / (2ℓ²))` (mm), `q` in rad.
#[derive(Debug, Clone, PartialEq)]
pub struct Rbf {
    /// When true the inputs are the wrist centre and marker positions in MDH frame 1 (which
    /// turns with joint 1; units of 100 mm) and the correction is expressed in that frame:
    /// gravity-driven effects do not depend on `q1` there.
    pub arm_frame: bool,
    pub length_scale: f64,
    pub centers: Vec<Vec<f64>>,
    pub weights: Vec<[f64; 3]>,
}

fn kern(a: &[f64], b: &[f64], ell: f64) -> f64 {
    let d2: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    (-d2 / (2.0 * ell * ell)).exp()
}

/// Inputs (wrist centre and marker in MDH frame 1, 100 mm units) and the rotation tracker ← frame 1.
pub fn arm_frame(model: &KinematicModel, q: &[f64]) -> (Vec<f64>, Matrix3<f64>) {
    let f1 = model.joint_frame(q, 1);
    let r = model.base().rotation * f1.rotation;
    // Features: the wrist centre and the marker in frame 1 (units of 100 mm). Gravity-driven
    // effects are smooth functions of where the masses are, not of q1.
    let n = model.dof();
    let to1 =
        |p: nalgebra::Vector3<f64>| f1.rotation.inverse() * (p - f1.translation.vector) / 100.0;
    let w = to1(model
        .joint_frame(q, n.saturating_sub(2).max(1))
        .translation
        .vector);
    let m = to1(model.tool_pose_in_base(q).translation.vector);
    (
        vec![w.x, w.y, w.z, m.x, m.y, m.z],
        *r.to_rotation_matrix().matrix(),
    )
}

/// Inputs and residuals in the arm-frame representation.
pub fn arm_frame_data(
    model: &KinematicModel,
    q: &[Vec<f64>],
    r: &[Vector3<f64>],
) -> (Vec<Vec<f64>>, Vec<Vector3<f64>>) {
    q.iter()
        .zip(r)
        .map(|(qk, rk)| {
            let (x, rot) = arm_frame(model, qk);
            (x, rot.transpose() * rk)
        })
        .unzip()
}

impl Rbf {
    /// Correction (mm, tracker frame) at joint angles `q` (rad) for `model`.
    pub fn correction(&self, model: &KinematicModel, q: &[f64]) -> Vector3<f64> {
        if self.arm_frame {
            let (x, rot) = arm_frame(model, q);
            rot * self.predict(&x)
        } else {
            self.predict(q)
        }
    }

    /// Correction (mm) at the raw inputs.
    pub fn predict(&self, q: &[f64]) -> Vector3<f64> {
        let mut v = Vector3::zeros();
        for (c, w) in self.centers.iter().zip(&self.weights) {
            let k = kern(q, c, self.length_scale);
            v += Vector3::new(w[0], w[1], w[2]) * k;
        }
        v
    }

    /// Fit on residuals `r` (mm) at `q` (rad) with ridge `lambda`. `None` if singular.
    pub fn fit(q: &[Vec<f64>], r: &[Vector3<f64>], ell: f64, lambda: f64) -> Option<Rbf> {
        let n = q.len();
        let k = DMatrix::from_fn(n, n, |i, j| {
            kern(&q[i], &q[j], ell) + if i == j { lambda } else { 0.0 }
        });
        let chol = k.cholesky()?;
        let rhs = DMatrix::from_fn(n, 3, |i, j| r[i][j]);
        let w = chol.solve(&rhs);
        Some(Rbf {
            arm_frame: false,
            length_scale: ell,
            centers: q.to_vec(),
            weights: (0..n).map(|i| [w[(i, 0)], w[(i, 1)], w[(i, 2)]]).collect(),
        })
    }

    /// File form (degrees for the centres and length scale).
    pub fn to_json(&self) -> Map<String, Value> {
        let mut m = Map::new();
        m.insert("model".into(), json!("rbf_kernel_ridge"));
        m.insert(
            "frame".into(),
            json!(if self.arm_frame { "joint1" } else { "tracker" }),
        );
        m.insert(
            "length_scale_deg".into(),
            json!(self.length_scale.to_degrees()),
        );
        m.insert(
            "centers_deg".into(),
            json!(self
                .centers
                .iter()
                .map(|c| c.iter().map(|x| x.to_degrees()).collect::<Vec<_>>())
                .collect::<Vec<_>>()),
        );
        m.insert("weights_mm".into(), json!(self.weights));
        m
    }

    /// Read the file form.
    pub fn from_json(p: &Map<String, Value>) -> anyhow::Result<Rbf> {
        let ell = p
            .get("length_scale_deg")
            .and_then(|v| v.as_f64())
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or_else(|| anyhow::anyhow!("nonparametric: bad \"length_scale_deg\""))?;
        let rows = |k: &str| -> anyhow::Result<Vec<Vec<f64>>> {
            p.get(k)
                .and_then(|v| v.as_array())
                .ok_or_else(|| anyhow::anyhow!("nonparametric: missing \"{k}\""))?
                .iter()
                .map(|r| {
                    r.as_array()
                        .ok_or_else(|| anyhow::anyhow!("nonparametric: bad row in \"{k}\""))?
                        .iter()
                        .map(|x| {
                            x.as_f64().filter(|v| v.is_finite()).ok_or_else(|| {
                                anyhow::anyhow!("nonparametric: bad number in \"{k}\"")
                            })
                        })
                        .collect()
                })
                .collect()
        };
        let centers: Vec<Vec<f64>> = rows("centers_deg")?
            .into_iter()
            .map(|c| c.into_iter().map(|x| x.to_radians()).collect())
            .collect();
        let w = rows("weights_mm")?;
        if w.len() != centers.len() || w.iter().any(|r| r.len() != 3) {
            anyhow::bail!("nonparametric: weights must be one [x, y, z] per centre");
        }
        Ok(Rbf {
            arm_frame: p.get("frame").and_then(|v| v.as_str()) == Some("joint1"),
            length_scale: ell.to_radians(),
            centers,
            weights: w.into_iter().map(|r| [r[0], r[1], r[2]]).collect(),
        })
    }
}

/// Result of the cross-validated search.
#[derive(Debug, Clone)]
pub struct RbfCv {
    pub length_scale: f64,
    pub lambda: f64,
    /// CV RMS (mm, 3-D) of the residual without / with the correction.
    pub cv_rms_before: f64,
    pub cv_rms_after: f64,
}

/// Choose length scale and ridge by cross-validation over the given folds (index of the
/// fold of each sample). Returns the best setting, or `None` with fewer than 20 samples.
pub fn cross_validate(
    q: &[Vec<f64>],
    r: &[Vector3<f64>],
    fold: &[usize],
    n_folds: usize,
) -> Option<RbfCv> {
    if q.len() < 20 {
        return None;
    }
    let var: f64 = r.iter().map(|v| v.norm_squared()).sum::<f64>() / r.len() as f64;
    let before = (var / 3.0).sqrt();
    let mut best: Option<RbfCv> = None;
    for &ell in &[0.5, 1.0, 2.0, 4.0] {
        for &lam in &[0.03, 0.3, 3.0] {
            let mut sse = 0.0;
            let mut cnt = 0usize;
            for f in 0..n_folds {
                let tr: Vec<usize> = (0..q.len()).filter(|&i| fold[i] != f).collect();
                let te: Vec<usize> = (0..q.len()).filter(|&i| fold[i] == f).collect();
                if tr.len() < 10 || te.is_empty() {
                    continue;
                }
                let qt: Vec<Vec<f64>> = tr.iter().map(|&i| q[i].clone()).collect();
                let rt: Vec<Vector3<f64>> = tr.iter().map(|&i| r[i]).collect();
                let Some(m) = Rbf::fit(&qt, &rt, ell, lam) else {
                    continue;
                };
                for &i in &te {
                    sse += (r[i] - m.predict(&q[i])).norm_squared();
                    cnt += 1;
                }
            }
            if cnt == 0 {
                continue;
            }
            let after = (sse / cnt as f64 / 3.0).sqrt();
            if best.as_ref().is_none_or(|b| after < b.cv_rms_after) {
                best = Some(RbfCv {
                    length_scale: ell,
                    lambda: lam,
                    cv_rms_before: before,
                    cv_rms_after: after,
                });
            }
        }
    }
    best
}

/// Cross-validated (per-axis) RMS of the residual without / with a correction of fixed
/// length scale and ridge, over the given folds.
pub fn cv_fixed(
    q: &[Vec<f64>],
    r: &[Vector3<f64>],
    fold: &[usize],
    n_folds: usize,
    ell: f64,
    lambda: f64,
) -> Option<(f64, f64)> {
    let mut sse0 = 0.0;
    let mut sse1 = 0.0;
    let mut cnt = 0usize;
    for f in 0..n_folds {
        let tr: Vec<usize> = (0..q.len()).filter(|&i| fold[i] != f).collect();
        let te: Vec<usize> = (0..q.len()).filter(|&i| fold[i] == f).collect();
        if tr.len() < 10 || te.is_empty() {
            continue;
        }
        let qt: Vec<Vec<f64>> = tr.iter().map(|&i| q[i].clone()).collect();
        let rt: Vec<Vector3<f64>> = tr.iter().map(|&i| r[i]).collect();
        let m = Rbf::fit(&qt, &rt, ell, lambda)?;
        for &i in &te {
            sse0 += r[i].norm_squared();
            sse1 += (r[i] - m.predict(&q[i])).norm_squared();
            cnt += 1;
        }
    }
    (cnt > 0).then(|| {
        (
            (sse0 / cnt as f64 / 3.0).sqrt(),
            (sse1 / cnt as f64 / 3.0).sqrt(),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rbf_learns_a_smooth_field_and_round_trips() {
        let q: Vec<Vec<f64>> = (0..80)
            .map(|i| vec![(i as f64 * 0.07).sin() * 1.5, (i as f64 * 0.13).cos()])
            .collect();
        let r: Vec<Vector3<f64>> = q
            .iter()
            .map(|x| Vector3::new(0.1 * x[0].sin(), 0.05 * x[1], 0.0))
            .collect();
        let fold: Vec<usize> = (0..80).map(|i| i * 4 / 80).collect();
        let cv = cross_validate(&q, &r, &fold, 4).unwrap();
        assert!(cv.cv_rms_after < 0.3 * cv.cv_rms_before, "{cv:?}");
        let m = Rbf::fit(&q, &r, cv.length_scale, cv.lambda).unwrap();
        let back = Rbf::from_json(&m.to_json()).unwrap();
        let a = m.predict(&[0.2, 0.3]);
        let b = back.predict(&[0.2, 0.3]);
        assert!((a - b).norm() < 1e-9);
    }
}
