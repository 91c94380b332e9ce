//! Link / bearing deflection under the full gravity wrench at a joint: the part downstream
//! of the joint rotates by `δφ = Σ_c coef_c M⊥_c(q)` about the joint origin, `M⊥_c` the
//! gravity moment (N·m) of 1 kg at mass point `c` about the joint origin with its component
//! along the joint axis removed (bending about the two axes orthogonal to the axis; the
//! axial part is [`super::Compliance`]). Isotropic bending compliance per mass point (coef:
//! rad·kg/(N·m)). The gravity force at a joint is the same vector in every pose, so a shear
//! displacement under it is a constant offset the base absorbs: only the moment is
//! identifiable. Small-deflection (first-order) model: the marker moves by
//! `R_base (δφ × (p − o_j))`, p and o_j at the measured angles (kind `link_deflection`).
//!
//! `anisotropic`: separate compliances for bending about the two link-fixed axes orthogonal
//! to the joint axis (the `x` and `y` axes of MDH frame `joint`, which turn with the joint):
//! `δφ = Σ_c (a_c (x·M⊥_c) x + b_c (y·M⊥_c) y)`, two coefficients per mass point (a link's
//! cross-section and a bearing are stiffer one way than the other).
use nalgebra::{Matrix3xX, Point3, Vector3};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::compliance::{points_in_words, read_points};
use super::file::{self, deg, lenient_vec, rad, EffectFileError};
use super::{mass_points, Coefs, EffectModel, Family, MassPoint, GRAVITY, GRAVITY_DIR};
use crate::dataset::CalEffect;
use crate::model::{KinematicModel, PoseFrames};
use crate::schema::EffectParameter;
use crate::solve::obs::{PoseCtx, PoseObs};

/// Bending at `joint` (1-based) with one (isotropic) or two (anisotropic) coefficients per
/// mass point.
#[derive(Debug, Clone, PartialEq)]
pub struct LinkDeflection {
    pub joint: usize,
    pub points: Vec<MassPoint>,
    pub anisotropic: bool,
}

impl LinkDeflection {
    /// [`EffectModel::columns`] at the pose whose frames are `f`.
    pub fn columns_in(&self, f: &PoseFrames) -> Vec<Vector3<f64>> {
        let mut cols = vec![Vector3::zeros(); self.n_params()];
        let (rb, lever, dirs) = deflection_terms_in(f, self.joint, &self.points, self.anisotropic);
        for (c, d) in dirs.iter().enumerate() {
            cols[c] = rb * d.cross(&lever);
        }
        cols
    }
}

/// The calibration-file parameters (`gravity_bending_point_masses`; anisotropic:
/// coefficients in point order, x then y of each point).
/// The parameters as `calibration.json` holds them.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct File {
    #[serde(default)]
    model: String,
    #[serde(default)]
    axes: Option<String>,
    #[serde(default)]
    gravity_dir: Vec<f64>,
    points: Vec<String>,
    c_bend_times_mass_deg_kg_per_nm: Vec<f64>,
    #[serde(default, deserialize_with = "lenient_vec")]
    std: Vec<f64>,
}

/// The terms of a [`LinkDeflection`] at `q`: the base rotation (tracker ← robot base), the
/// lever from the joint origin to the marker (robot base, mm) and, per mass point, the
/// bending moment of 1 kg about the joint origin with its axial component removed (N·m per
/// kg, robot base frame). The marker moves by `R_base (Σ_c coef_c M⊥_c) × lever`.
/// `anisotropic`: two terms per mass point, the components of `M⊥_c` along the link-fixed
/// `x` and `y` axes of frame `joint` (`(x·M⊥_c) x`, `(y·M⊥_c) y`), one coefficient each.
pub fn deflection_terms(
    model: &KinematicModel,
    q: &[f64],
    joint: usize,
    points: &[MassPoint],
    anisotropic: bool,
) -> (nalgebra::Rotation3<f64>, Vector3<f64>, Vec<Vector3<f64>>) {
    deflection_terms_in(&model.pose_frames(q), joint, points, anisotropic)
}

/// [`deflection_terms`] at the pose whose frames are `f` (the same values).
pub fn deflection_terms_in(
    f: &PoseFrames,
    joint: usize,
    points: &[MassPoint],
    anisotropic: bool,
) -> (nalgebra::Rotation3<f64>, Vector3<f64>, Vec<Vector3<f64>>) {
    let fj = f.joint_frame(joint);
    let z = fj.rotation * Vector3::z();
    let o = fj.translation.vector;
    let g = Vector3::from(GRAVITY_DIR) * GRAVITY;
    let marker = f.tool_origin();
    let dirs = points
        .iter()
        .map(|p| {
            let c = match p {
                MassPoint::Marker => marker,
                _ => p.position_in(f),
            };
            let m = ((c - o) * 1e-3).cross(&g);
            m - z * z.dot(&m)
        })
        .flat_map(|m: Vector3<f64>| {
            if anisotropic {
                let x = fj.rotation * Vector3::x();
                let y = fj.rotation * Vector3::y();
                vec![x * x.dot(&m), y * y.dot(&m)]
            } else {
                vec![m]
            }
        })
        .collect();
    (*f.base_rotation(), marker - o, dirs)
}

impl EffectModel for LinkDeflection {
    fn kind(&self) -> &'static str {
        Self::KIND
    }
    fn joint(&self) -> Option<usize> {
        Some(self.joint)
    }
    fn n_params(&self) -> usize {
        self.points.len() * if self.anisotropic { 2 } else { 1 }
    }
    fn param_names(&self) -> Vec<String> {
        self.points
            .iter()
            .flat_map(|p| {
                if self.anisotropic {
                    vec![
                        format!("c_bend_x·m@{} [rad·kg/Nm]", p.label()),
                        format!("c_bend_y·m@{} [rad·kg/Nm]", p.label()),
                    ]
                } else {
                    vec![format!("c_bend·m@{} [rad·kg/Nm]", p.label())]
                }
            })
            .collect()
    }
    fn label(&self) -> String {
        if self.anisotropic {
            format!("{}(j{}, link x/y)", Self::KIND, self.joint)
        } else {
            format!("{}(j{})", Self::KIND, self.joint)
        }
    }
    fn point_displacement(
        &self,
        model: &KinematicModel,
        coefs: &[f64],
        ctx: &PoseCtx,
    ) -> Option<Vector3<f64>> {
        let (rb, lever, dirs) =
            deflection_terms(model, &ctx.q, self.joint, &self.points, self.anisotropic);
        let phi: Vector3<f64> = dirs.iter().zip(coefs).map(|(m, c)| m * *c).sum();
        Some(rb * phi.cross(&lever))
    }
    fn columns(
        &self,
        model: &KinematicModel,
        _jm: &Matrix3xX<f64>,
        _p: &Point3<f64>,
        ctx: &PoseCtx,
    ) -> Vec<Vector3<f64>> {
        self.columns_in(&model.pose_frames(&ctx.q))
    }
    fn check_identifiable(&self, model: &KinematicModel, train: &[PoseObs]) -> Result<(), String> {
        // The bending moment must vary over the poses (its direction or size).
        let joint = self.joint;
        let m: Vec<Vector3<f64>> = train
            .iter()
            .map(|o| {
                deflection_terms(model, &o.q, joint, &self.points, false)
                    .2
                    .iter()
                    .sum::<Vector3<f64>>()
            })
            .collect();
        let n = m.len().max(1) as f64;
        let mean = m.iter().sum::<Vector3<f64>>() / n;
        let sd = (m.iter().map(|v| (v - mean).norm_squared()).sum::<f64>() / n).sqrt();
        if self.points.is_empty() || sd <= 0.05 {
            return Err(format!(
                "the bending moment at joint {joint} hardly varies over the poses (sd {sd:.3} N·m per kg)"
            ));
        }
        Ok(())
    }
    fn parameters(&self, c: &Coefs) -> Vec<EffectParameter> {
        let axes: &[&str] = if self.anisotropic {
            &["_x", "_y"]
        } else {
            &[""]
        };
        self.points
            .iter()
            .flat_map(|pt| axes.iter().map(move |a| (pt, *a)))
            .enumerate()
            .map(|(k, (pt, a))| {
                EffectParameter::new(
                    &format!("c_bend{a}_times_mass@{}", pt.label()),
                    "deg*kg/(N*m)",
                    c.v(k).to_degrees(),
                    c.s(k).to_degrees(),
                )
            })
            .collect()
    }
    fn file_params(&self, c: &Coefs) -> Map<String, Value> {
        file::to_params(&File {
            model: "gravity_bending_point_masses".into(),
            axes: Some(
                if self.anisotropic {
                    "link_x_y"
                } else {
                    "isotropic"
                }
                .into(),
            ),
            gravity_dir: GRAVITY_DIR.to_vec(),
            points: self.points.iter().map(|x| x.label()).collect(),
            c_bend_times_mass_deg_kg_per_nm: deg(c.value),
            std: deg(c.std),
        })
    }
    fn sentence(&self, c: &Coefs) -> String {
        let sum = |k0: usize, step: usize| -> f64 {
            c.value
                .iter()
                .skip(k0)
                .step_by(step)
                .sum::<f64>()
                .to_degrees()
        };
        let size = if self.anisotropic {
            format!(
                "{}° about the link's x axis and {}° about its y axis",
                super::plain_number(sum(0, 2), 4),
                super::plain_number(sum(1, 2), 4)
            )
        } else {
            format!("{}°", super::plain_number(sum(0, 1), 4))
        };
        format!(
            "the link at joint {} bends sideways under gravity (link or bearing deflection): {size} \
             per N·m of bending moment per kg of load (summed over {})",
            self.joint,
            points_in_words(&self.points)
        )
    }
    fn plot_driver(&self, model: &KinematicModel, o: &PoseObs) -> (f64, String) {
        let (_, _, m) = deflection_terms(model, &o.ctx.q, self.joint, &self.points, false);
        (
            m.iter().sum::<Vector3<f64>>().norm(),
            format!(
                "bending moment at joint {} (N·m per kg, summed)",
                self.joint
            ),
        )
    }
}

impl Family for LinkDeflection {
    const KIND: &'static str = "link_deflection";
    type File = File;
    fn from_file(e: &CalEffect, f: File) -> Result<(Self, Vec<f64>, Vec<f64>), EffectFileError> {
        let anisotropic = match f.axes.as_deref() {
            None | Some("isotropic") => false,
            Some("link_x_y") => true,
            Some(other) => {
                return Err(EffectFileError::invalid(
                    e,
                    format!("\"axes\" must be \"isotropic\" or \"link_x_y\" (got \"{other}\")"),
                ))
            }
        };
        let (points, c) = read_points(
            e,
            &f.points,
            &f.c_bend_times_mass_deg_kg_per_nm,
            if anisotropic { 2 } else { 1 },
        )?;
        Ok((
            LinkDeflection {
                joint: file::joint(e)?,
                points,
                anisotropic,
            },
            c,
            rad(&f.std),
        ))
    }
    fn joint_candidates(
        model: &KinematicModel,
        _opt: &crate::diagnose::Options,
        j: usize,
    ) -> Vec<Vec<Self>> {
        // Isotropic, or with separate compliances about the two link-fixed bending axes
        // (both count as tests; ΔBIC charges the anisotropic variant its extra coefficients).
        vec![[false, true]
            .iter()
            .map(|&anisotropic| LinkDeflection {
                joint: j,
                points: mass_points(model, j),
                anisotropic,
            })
            .collect()]
    }
    fn example(model: &KinematicModel) -> (Self, Vec<f64>) {
        let points = mass_points(model, 1);
        let n = 2 * points.len();
        (
            LinkDeflection {
                joint: 1,
                points,
                anisotropic: true,
            },
            (0..n)
                .map(|k| if k % 2 == 0 { 4e-4 } else { -1e-4 })
                .collect(),
        )
    }
}
