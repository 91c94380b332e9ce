//! Split-half check of the transmission error maps (issue 31 §4: "uncertainty must survive a
//! split-half check on real data"), shared by `examples/map_split_half.rs` and
//! `tests/real_transmission_map.rs`.
//!
//! The training poses are cut into two halves, each half is diagnosed on its own with the
//! given options, and for every joint mapped in both the two maps `δθ₁(q)`, `δθ₂(q)`
//! ([`MapChoice::curve`]) are compared on a 1° grid inside both halves' training range of
//! that joint: the RMS of `δθ₁ − δθ₂`, the RMS of each curve, and the share of grid points
//! where `|δθ₁ − δθ₂| ≤ 2·sqrt(σ₁² + σ₂²)` (honest when ≥ 90 %).
use robocal::diagnose::effects::{Block, JointRange};
use robocal::diagnose::transmap::MapChoice;
use robocal::diagnose::{self, Diagnosis, Options};
use robocal::model::KinematicModel;
use robocal::solve::obs::PoseObs;

/// Arcseconds per radian.
pub const ARCSEC: f64 = 180.0 * 3600.0 / std::f64::consts::PI;

/// How the training poses are cut in two.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Split {
    /// Alternate time blocks of this fraction of the poses (even blocks / odd blocks).
    Alternate(f64),
    /// The first half / the second half (in file order, which is time order).
    Halves,
}

impl Split {
    pub fn name(&self) -> String {
        match self {
            Split::Alternate(f) => format!("alternate {:.0} % blocks", 100.0 * f),
            Split::Halves => "first / second half".to_string(),
        }
    }

    /// The two halves of `train` (file order kept in each).
    pub fn cut(&self, train: &[PoseObs]) -> (Vec<PoseObs>, Vec<PoseObs>) {
        let n = train.len();
        let side = |i: usize| match self {
            Split::Alternate(f) => {
                let block = ((n as f64 * f).round() as usize).max(1);
                (i / block) % 2 == 1
            }
            Split::Halves => i >= n / 2,
        };
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for (i, o) in train.iter().enumerate() {
            if side(i) {
                b.push(o.clone());
            } else {
                a.push(o.clone());
            }
        }
        (a, b)
    }
}

/// One joint's comparison (angles in rad, values in rad).
#[derive(Debug, Clone)]
pub struct JointCompare {
    /// 1-based.
    pub joint: usize,
    /// Grid points (1° apart) inside both halves' training range.
    pub n: usize,
    /// The compared range (rad).
    pub lo: f64,
    pub hi: f64,
    /// RMS of `δθ₁ − δθ₂`.
    pub rms_diff: f64,
    /// RMS of each curve over the same grid.
    pub rms_1: f64,
    pub rms_2: f64,
    /// RMS of the combined σ `sqrt(σ₁² + σ₂²)`.
    pub rms_sigma: f64,
    /// Share of grid points with `|Δ| ≤ 2 σ_combined`.
    pub within_2sigma: f64,
    /// Median, 90th percentile and largest `|Δ| / σ_combined` (the 90th percentile over 2 is
    /// the factor σ would need for 90 % of the points within 2σ).
    pub ratio_median: f64,
    pub ratio_p90: f64,
    pub ratio_max: f64,
}

/// A half's chosen map setting: harmonics and ridge.
pub type Setting = (u32, f64);

/// The result of one split.
#[derive(Debug, Clone)]
pub struct SplitHalf {
    pub split: Split,
    pub n: (usize, usize),
    /// Each half's chosen setting (harmonics, ridge), `None` when it added no map.
    pub setting: (Option<Setting>, Option<Setting>),
    /// Each half's held-out RMS (mm) on the common held-out poses, when given.
    pub heldout: (Option<f64>, Option<f64>),
    /// Each half's chain of named effects (labels, before the maps).
    pub chain: (Vec<String>, Vec<String>),
    pub joints: Vec<JointCompare>,
    /// The same comparison of each joint's whole angular transmission error: the map plus
    /// the chain's named ripples of that joint (`transmission_ripple`; their variances added,
    /// the covariance between the ripples and the map ignored). The two halves may name
    /// different ripples, which the map then absorbs or not.
    pub joints_total: Vec<JointCompare>,
}

impl SplitHalf {
    /// Share of all compared grid points within 2σ (every joint pooled).
    pub fn within_2sigma(joints: &[JointCompare]) -> f64 {
        let n: usize = joints.iter().map(|j| j.n).sum();
        let k: f64 = joints.iter().map(|j| j.within_2sigma * j.n as f64).sum();
        if n == 0 {
            f64::NAN
        } else {
            k / n as f64
        }
    }
}

/// The joints whose curve stands above its own uncertainty in at least one half (RMS of the
/// curve > RMS of the combined σ): a joint the data hardly see (a map near zero with a wide
/// σ, e.g. the last joint with the marker near its axis) passes the 2σ check trivially.
pub fn resolved(joints: &[JointCompare]) -> Vec<JointCompare> {
    joints
        .iter()
        .filter(|j| j.rms_1.max(j.rms_2) > j.rms_sigma)
        .cloned()
        .collect()
}

/// One half's transmission error curves: its maps and its named ripples
/// (`joint, harmonic, [sin, cos] coefficients, their standard deviations`, rad).
pub struct Curves<'a> {
    pub map: &'a MapChoice,
    pub ripples: Vec<(usize, f64, [f64; 2], [f64; 2])>,
    /// Whether [`Curves::at`] adds the ripples to the map.
    pub total: bool,
}

impl<'a> Curves<'a> {
    pub fn of(d: &'a Diagnosis, total: bool) -> Option<Self> {
        let ripples = d
            .state
            .effects
            .iter()
            .filter_map(|e| match &e.block {
                Block::Ripple(r) if e.coefs.len() == 2 => {
                    let s = |i: usize| e.std.get(i).copied().unwrap_or(0.0);
                    Some((
                        r.joint,
                        f64::from(r.harmonic),
                        [e.coefs[0], e.coefs[1]],
                        [s(0), s(1)],
                    ))
                }
                _ => None,
            })
            .collect();
        Some(Curves {
            map: d.transmission_map.as_ref()?,
            ripples,
            total,
        })
    }

    /// `δθ` of joint `j` (1-based) at `q` and its standard deviation (rad).
    pub fn at(&self, j: usize, q: f64) -> Option<(f64, f64)> {
        let (mut v, s) = self.map.curve(j, q)?;
        let mut var = s * s;
        if self.total {
            for (_, k, c, sd) in self.ripples.iter().filter(|r| r.0 == j) {
                let (sn, cs) = (k * q).sin_cos();
                v += c[0] * sn + c[1] * cs;
                var += (sd[0] * sn).powi(2) + (sd[1] * cs).powi(2);
            }
        }
        Some((v, var.sqrt()))
    }
}

/// Compare the curves of two halves (`tr1`, `tr2`: each half's training poses, for the
/// ranges).
pub fn compare(
    m1: &Curves,
    tr1: &[PoseObs],
    m2: &Curves,
    tr2: &[PoseObs],
    dof: usize,
) -> Vec<JointCompare> {
    let mut out = Vec::new();
    let (Some(r1), Some(r2)) = (JointRange::of(tr1), JointRange::of(tr2)) else {
        return out;
    };
    for j in 1..=dof.min(r1.lo.len()).min(r2.lo.len()) {
        if m1.at(j, 0.0).is_none() || m2.at(j, 0.0).is_none() {
            continue;
        }
        let (lo, hi) = (
            r1.lo[j - 1].max(r2.lo[j - 1]),
            r1.hi[j - 1].min(r2.hi[j - 1]),
        );
        let (dlo, dhi) = (lo.to_degrees().ceil(), hi.to_degrees().floor());
        if dhi < dlo {
            continue;
        }
        let mut d2 = 0.0;
        let (mut c1, mut c2, mut s2) = (0.0, 0.0, 0.0);
        let mut ratios = Vec::new();
        let mut k = dlo;
        while k <= dhi {
            let q = k.to_radians();
            let (Some((v1, s1)), Some((v2, sg2))) = (m1.at(j, q), m2.at(j, q)) else {
                break;
            };
            let s = (s1 * s1 + sg2 * sg2).sqrt();
            d2 += (v1 - v2).powi(2);
            c1 += v1 * v1;
            c2 += v2 * v2;
            s2 += s * s;
            ratios.push(if s > 0.0 {
                (v1 - v2).abs() / s
            } else {
                f64::INFINITY
            });
            k += 1.0;
        }
        let n = ratios.len();
        if n == 0 {
            continue;
        }
        let nf = n as f64;
        let within = ratios.iter().filter(|r| **r <= 2.0).count() as f64 / nf;
        ratios.sort_by(|a, b| a.total_cmp(b));
        out.push(JointCompare {
            joint: j,
            n,
            lo,
            hi,
            rms_diff: (d2 / nf).sqrt(),
            rms_1: (c1 / nf).sqrt(),
            rms_2: (c2 / nf).sqrt(),
            rms_sigma: (s2 / nf).sqrt(),
            within_2sigma: within,
            ratio_median: ratios[n / 2],
            ratio_p90: ratios[((n - 1) as f64 * 0.9).round() as usize],
            ratio_max: ratios[n - 1],
        });
    }
    out
}

fn named_chain(d: &Diagnosis) -> Vec<String> {
    d.steps
        .iter()
        .filter(|s| !s.evidence.label.starts_with("transmission_error_map"))
        .map(|s| s.evidence.label.clone())
        .collect()
}

/// Diagnose each half of `train` with `opt` (scored on `heldout`, which may be empty) and
/// compare their maps.
pub fn split_half(
    model: &KinematicModel,
    train: &[PoseObs],
    heldout: &[PoseObs],
    split: Split,
    opt: &Options,
) -> anyhow::Result<SplitHalf> {
    let (a, b) = split.cut(train);
    let da = diagnose::diagnose(model, &a, heldout, opt)?;
    let db = diagnose::diagnose(model, &b, heldout, opt)?;
    let setting = |d: &Diagnosis| {
        d.transmission_map
            .as_ref()
            .map(|m| (m.chosen.harmonics, m.chosen.ridge))
    };
    let cmp = |total: bool| match (Curves::of(&da, total), Curves::of(&db, total)) {
        (Some(m1), Some(m2)) => compare(&m1, &a, &m2, &b, model.dof()),
        _ => Vec::new(),
    };
    Ok(SplitHalf {
        split,
        n: (a.len(), b.len()),
        setting: (setting(&da), setting(&db)),
        heldout: (da.heldout_rms_final, db.heldout_rms_final),
        chain: (named_chain(&da), named_chain(&db)),
        joints: cmp(false),
        joints_total: cmp(true),
    })
}

/// The result as text: one line per half, then a markdown table row per joint.
pub fn text(name: &str, r: &SplitHalf) -> String {
    let mut s = String::new();
    let set = |x: Option<Setting>| match x {
        Some((h, l)) => format!("H {h}, ridge {l:e}"),
        None => "no map".to_string(),
    };
    let held = |x: Option<f64>| x.map_or("—".to_string(), |v| format!("{v:.4} mm"));
    for (k, (n, st, h, c)) in [
        (r.n.0, r.setting.0, r.heldout.0, &r.chain.0),
        (r.n.1, r.setting.1, r.heldout.1, &r.chain.1),
    ]
    .into_iter()
    .enumerate()
    {
        s += &format!(
            "{name}, {}, half {}: {n} poses, {}, held-out {}, chain: {}\n",
            r.split.name(),
            k + 1,
            set(st),
            held(h),
            if c.is_empty() {
                "—".to_string()
            } else {
                c.join(", ")
            }
        );
    }
    let same_h = match r.setting {
        (Some(a), Some(b)) => {
            if a.0 == b.0 {
                "same H"
            } else {
                "different H"
            }
        }
        _ => "—",
    };
    let share = |j: &[JointCompare]| 100.0 * SplitHalf::within_2sigma(j);
    s += &format!(
        "{name}, {}: {same_h}; share within 2σ, grid points pooled over every joint: map {:.1} %, map + named ripples {:.1} %; over the resolved joints only: map {:.1} %, map + named ripples {:.1} %\n",
        r.split.name(),
        share(&r.joints),
        share(&r.joints_total),
        share(&resolved(&r.joints)),
        share(&resolved(&r.joints_total)),
    );
    s += "| series | split | curve | joint | range (deg) | grid pts | RMS δθ₁ / δθ₂ (arcsec) | RMS Δ (arcsec) | RMS σ_comb (arcsec) | within 2σ | median / p90 / max |Δ|/σ |\n|---|---|---|---|---|---|---|---|---|---|---|\n";
    let rows = r.joints.iter().map(|j| ("map", j));
    for (what, j) in rows.chain(r.joints_total.iter().map(|j| ("map + ripples", j))) {
        s += &format!(
            "| {name} | {} | {what} | j{} | {:.0} … {:.0} | {} | {:.1} / {:.1} | {:.1} | {:.1} | {:.1} % | {:.2} / {:.2} / {:.2} |\n",
            r.split.name(),
            j.joint,
            j.lo.to_degrees(),
            j.hi.to_degrees(),
            j.n,
            j.rms_1 * ARCSEC,
            j.rms_2 * ARCSEC,
            j.rms_diff * ARCSEC,
            j.rms_sigma * ARCSEC,
            100.0 * j.within_2sigma,
            j.ratio_median,
            j.ratio_p90,
            j.ratio_max
        );
    }
    s
}
