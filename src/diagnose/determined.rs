//! Which geometric parameters the training poses determine.
//!
//! A geometric fit on poses that cover a narrow workspace, or that move two joints
//! together, can move parameters along directions the poses hardly see: the real UR10
//! Series D's first 237 poses (ISO cubes, joint 5 always equal to joint 1, joint 4 within
//! ±46°) moved `phi5` by 6.1°, `alpha6` by −7.7° and the marker by 22 mm while lowering the
//! training RMS by 0.0023 mm, and the model then predicted poses outside that workspace
//! 10× worse than the nominal chain (8.5 mm against 0.80 mm). The diagnosis therefore fits
//! the geometry under a Gaussian prior centred on the nominal values ([`prior`], standard
//! deviations [`GeometricTolerance`]), and names the parameters whose standard deviation
//! from the poses alone exceeds that tolerance ([`undetermined`]).
use super::fit::{stack, Prior, State};
use crate::model::{ParamGroup, Unit};
use crate::solve::identifiability::{self, Floor};
use crate::solve::obs::PoseObs;

/// Prior standard deviation of a geometric parameter about its nominal value, and the
/// largest standard deviation the poses may leave it before it is named as undetermined:
/// lengths in mm, angles in degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GeometricTolerance {
    pub mm: f64,
    pub deg: f64,
}

/// Default: ±5 mm and ±0.5°, wide enough for an arm whose geometry is off by millimetres
/// (a cable-driven Barrett WAM: nominal 5.3 mm RMS; with ±1 mm / ±0.1° its geometric
/// held-out error rose 2.31 → 2.43 mm) and narrow enough to hold the directions a narrow
/// workspace does not see (the Series D half above: 8.5 → 1.29 mm; measured in
/// docs/findings.md, "Geometric parameters the poses do not determine").
pub const DEFAULT_GEOMETRIC_TOLERANCE: GeometricTolerance =
    GeometricTolerance { mm: 5.0, deg: 0.5 };

/// A geometric parameter the training poses do not determine: its name and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Undetermined {
    pub name: String,
    pub reason: String,
}

/// The free geometric parameters of `geometric` (a fit without effects) that `train` does
/// not determine to `tol`: the noise of one residual row is the fit's own residual
/// (`sqrt(RSS / (rows − params))`), each parameter's standard deviation that of its part
/// independent of the parameters before it in the identifiability priority order (base,
/// tool, joints from the flange down). The base pose (tracker ← robot) is always kept.
pub fn undetermined(
    geometric: &State,
    train: &[PoseObs],
    tol: GeometricTolerance,
) -> Vec<Undetermined> {
    let model = &geometric.model;
    let free = model.free_indices();
    if free.is_empty() || train.is_empty() {
        return Vec::new();
    }
    let only_model = State {
        prior: None,
        model: model.clone(),
        effects: Vec::new(),
    };
    let (r, j) = stack(&only_model, train);
    let noise = row_noise(&r, free.len());
    let params = model.params();
    let names: Vec<String> = free.iter().map(|&i| params[i].name.clone()).collect();
    let floors: Vec<Option<Floor>> = free
        .iter()
        .map(|&i| {
            let p = &params[i];
            (p.group != ParamGroup::Base).then(|| match p.unit {
                Unit::Rad => Floor {
                    noise,
                    tol: tol.deg.to_radians(),
                    unit: "°",
                    scale: 180.0 / std::f64::consts::PI,
                },
                Unit::Mm => Floor {
                    noise,
                    tol: tol.mm,
                    unit: " mm",
                    scale: 1.0,
                },
            })
        })
        .collect();
    let priority = identifiability::priority_order(model, &free, names.len());
    let idf = identifiability::analyse_with_floor(&j, &names, &priority, 0.0, Some(&floors));
    idf.dropped
        .into_iter()
        .map(|d| Undetermined {
            name: names[d.index].clone(),
            reason: d.reason,
        })
        .collect()
}

/// Noise of one residual row: `sqrt(RSS / (rows − params))`.
fn row_noise(r: &nalgebra::DVector<f64>, n_params: usize) -> f64 {
    let dof = r.len().saturating_sub(n_params).max(1);
    (r.norm_squared() / dof as f64).sqrt()
}

/// The prior of the geometric parameters for a fit on `train`: centred on `nominal`'s
/// values, standard deviations `tol`, the noise of one row taken from `geometric` (the
/// fit without a prior) on `train`. The base pose (tracker ← robot) has none.
pub fn prior(
    nominal: &State,
    geometric: &State,
    train: &[PoseObs],
    tol: GeometricTolerance,
) -> Prior {
    let r = super::fit::residuals(geometric, train);
    let noise = row_noise(&r, geometric.model.free_count());
    let centre: Vec<f64> = nominal.model.param_values().iter().copied().collect();
    let weight = nominal
        .model
        .params()
        .iter()
        .map(|p| match (p.group, p.unit) {
            (ParamGroup::Base, _) => 0.0,
            (_, Unit::Rad) => noise / tol.deg.to_radians(),
            (_, Unit::Mm) => noise / tol.mm,
        })
        .collect();
    Prior { centre, weight }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::effects::{apply_effects, Block, Effect, Ripple};
    use crate::diagnose::{diagnose, lcg_noise, Options};
    use crate::model::KinematicModel;
    use nalgebra::Point3;

    /// Poses like the real Series D's first half: joint 5 always equal to joint 1, joint 4
    /// within ±0.8 rad, joint 6 at 0 or −90°; the held-out poses cover the whole range.
    fn poses(n: u64, narrow: bool, seed: u64) -> Vec<Vec<f64>> {
        let mut u = lcg_noise(seed, 1.0);
        (0..n)
            .map(|k| {
                let mut q: Vec<f64> = (0..6).map(|_| 1.4 * u()).collect();
                q[1] = -1.6 + 0.6 * u();
                q[2] = 1.2 * u();
                if narrow {
                    q[3] *= 0.55;
                    q[4] = q[0];
                    q[5] = if k % 2 == 0 {
                        0.0
                    } else {
                        -std::f64::consts::FRAC_PI_2
                    };
                } else {
                    q[3] = 2.8 * u();
                    q[4] = 2.8 * u();
                    q[5] = 3.0 * u();
                }
                q
            })
            .collect()
    }

    /// A geometric fit on a narrow workspace: the parameter the poses do not see is named
    /// with its partners, and the prior costs nothing on the training or the held-out poses.
    #[test]
    fn a_narrow_workspace_names_the_undetermined_parameters_and_the_prior_holds_them() {
        // A marker off the flange, as the T-Mac probe of the real series.
        let mut nominal = KinematicModel::preset("ur5e").unwrap();
        for (n, v) in [("tool_x", 60.0), ("tool_y", -40.0), ("tool_z", 110.0)] {
            nominal.set_param(n, v).unwrap();
        }
        // The true arm: every joint parameter off by up to 0.3 mm / 0.03°.
        let mut truth = nominal.clone();
        let mut u = lcg_noise(7, 1.0);
        for p in nominal.params().iter().filter(|p| p.free) {
            let d = match p.unit {
                Unit::Mm => 0.3 * u(),
                Unit::Rad => 0.03f64.to_radians() * u(),
            };
            truth.set_param(&p.name, p.value + d).unwrap();
        }
        // What a geometric model leaves on a real arm: transmission ripple of joints 1–3
        // (17 cycles per turn, 0.01°, as on the real UR10), which the free fit loads onto
        // the directions the poses hardly see.
        let ripples: Vec<Effect> = (1..=3)
            .map(|joint| Effect {
                block: Block::Ripple(Ripple {
                    joint,
                    harmonic: 17,
                }),
                coefs: vec![0.01f64.to_radians(), 0.004f64.to_radians()],
                std: vec![f64::NAN; 2],
                tau_std: f64::NAN,
            })
            .collect();
        let mut e = lcg_noise(11, 0.02);
        let mut obs = |qs: Vec<Vec<f64>>, id0: u64| -> Vec<PoseObs> {
            qs.into_iter()
                .enumerate()
                .map(|(k, q)| {
                    let k = id0 + k as u64;
                    let mut o = PoseObs::at(k, k as f64, q, Point3::origin());
                    o.p = apply_effects(&truth, &ripples, &o.ctx)
                        + nalgebra::Vector3::new(e(), e(), e());
                    o
                })
                .collect()
        };
        let train = obs(poses(240, true, 3), 0);
        let held = obs(poses(150, false, 5), 1000);
        let geometric_only = Options {
            max_effects: 0,
            allow_nonparametric: false,
            transmission_map: false,
            ..Options::default()
        };
        let with = diagnose(&nominal, &train, &held, &geometric_only).unwrap();
        let without = diagnose(
            &nominal,
            &train,
            &held,
            &Options {
                geometric_tolerance: None,
                ..geometric_only.clone()
            },
        )
        .unwrap();
        let (h_with, h_without) = (
            with.heldout_rms_geometric.unwrap(),
            without.heldout_rms_geometric.unwrap(),
        );
        let h_nominal = with.heldout_rms_nominal.unwrap();
        eprintln!(
            "held-out: nominal {h_nominal:.4}, free fit {h_without:.4}, prior {h_with:.4} mm; {:?}",
            with.warnings
        );
        let named = with
            .warnings
            .iter()
            .find(|w| w.contains("held near their nominal values by the prior"))
            .expect("the undetermined parameters are named");
        assert!(named.contains("d5: redundant"), "{named}");
        assert!(without.warnings.iter().all(|w| !w.contains("by the prior")));
        // Where the free fit does not run away (this synthetic arm), the prior costs nothing;
        // where it does (the real Series A / D halves) it is measured by
        // `tests/real_narrow_workspace.rs` and docs/findings.md.
        assert!(h_with < 1.02 * h_without, "{h_with} vs {h_without}");
        // Training RMS: the prior costs nothing measurable where the poses are.
        assert!(with.train_rms_geometric < 1.05 * without.train_rms_geometric);
    }
}
