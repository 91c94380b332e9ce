//! Seed 003's non-geometric error network: 6 inputs (the desired pose `x, y, z, α, β, γ`),
//! one fully connected hidden layer of `n` noisy-ReLU neurons (`f(x) = max(0, x + y)`,
//! `y ~ N(0, σ)` while training, plain ReLU when predicting), 6 outputs (the position and
//! orientation errors `δx, δy, δz, δα, δβ, δγ`), trained by back-propagation on the mean
//! squared error (full-batch Adam, inputs and outputs standardised, L2 weight decay).
//!
//! A correction model for what the geometric calibration leaves; compare it on held-out
//! data with the physical effects and the `nonparametric` kernel correction of
//! [`crate::diagnose`] before trusting it (it has no physics and extrapolates poorly).
use nalgebra::{DMatrix, DVector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

/// Training options.
#[derive(Debug, Clone, Copy)]
pub struct NetOptions {
    pub hidden: usize,
    pub epochs: usize,
    pub learning_rate: f64,
    /// σ of the noisy ReLU while training (standardised units).
    pub noise_sigma: f64,
    pub weight_decay: f64,
    pub seed: u64,
}

impl Default for NetOptions {
    fn default() -> Self {
        NetOptions {
            hidden: 32,
            epochs: 3000,
            learning_rate: 0.01,
            noise_sigma: 0.05,
            weight_decay: 1e-4,
            seed: 1,
        }
    }
}

/// The trained network (serialisable: it is a correction model in a calibration file).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SeedNet {
    pub w1: DMatrix<f64>,
    pub b1: DVector<f64>,
    pub w2: DMatrix<f64>,
    pub b2: DVector<f64>,
    pub x_mean: DVector<f64>,
    pub x_std: DVector<f64>,
    pub y_mean: DVector<f64>,
    pub y_std: DVector<f64>,
}

fn standardise(rows: &[[f64; 6]]) -> (DMatrix<f64>, DVector<f64>, DVector<f64>) {
    let n = rows.len();
    let m = DMatrix::from_fn(6, n, |r, c| rows[c][r]);
    let mean = DVector::from_fn(6, |r, _| m.row(r).mean());
    let std = DVector::from_fn(6, |r, _| {
        let v = m.row(r).iter().map(|x| (x - mean[r]).powi(2)).sum::<f64>() / n.max(1) as f64;
        if v > 0.0 {
            v.sqrt()
        } else {
            1.0
        }
    });
    let z = DMatrix::from_fn(6, n, |r, c| (m[(r, c)] - mean[r]) / std[r]);
    (z, mean, std)
}

/// Loss `½/N Σ |W2 relu(W1 x + b1 + ε) + b2 − y|²` and its gradients (same noise `eps`).
#[allow(clippy::type_complexity)]
pub fn loss_grad(
    net: &SeedNet,
    x: &DMatrix<f64>,
    y: &DMatrix<f64>,
    eps: Option<&DMatrix<f64>>,
) -> (f64, DMatrix<f64>, DVector<f64>, DMatrix<f64>, DVector<f64>) {
    let n = x.ncols() as f64;
    let mut a = &net.w1 * x;
    for mut c in a.column_iter_mut() {
        c += &net.b1;
    }
    if let Some(e) = eps {
        a += e;
    }
    let h = a.map(|v| v.max(0.0));
    let mut out = &net.w2 * &h;
    for mut c in out.column_iter_mut() {
        c += &net.b2;
    }
    let d = out - y;
    let loss = 0.5 * d.norm_squared() / n;
    let g_out = d / n;
    let gw2 = &g_out * h.transpose();
    let gb2 = g_out.column_sum();
    let gh = net.w2.transpose() * &g_out;
    let ga = gh.zip_map(&a, |g, v| if v > 0.0 { g } else { 0.0 });
    let gw1 = &ga * x.transpose();
    let gb1 = ga.column_sum();
    (loss, gw1, gb1, gw2, gb2)
}

impl SeedNet {
    /// Trains on (desired pose, error) pairs.
    pub fn train(x: &[[f64; 6]], y: &[[f64; 6]], o: &NetOptions) -> SeedNet {
        let (xz, x_mean, x_std) = standardise(x);
        let (yz, y_mean, y_std) = standardise(y);
        let mut rng = ChaCha8Rng::seed_from_u64(o.seed);
        let h = o.hidden.max(1);
        let s1 = (2.0 / 6.0f64).sqrt();
        let s2 = (1.0 / h as f64).sqrt();
        let mut net = SeedNet {
            w1: DMatrix::from_fn(h, 6, |_, _| s1 * rng.sample::<f64, _>(StandardNormal)),
            b1: DVector::from_element(h, 0.01),
            w2: DMatrix::from_fn(6, h, |_, _| s2 * rng.sample::<f64, _>(StandardNormal)),
            b2: DVector::zeros(6),
            x_mean,
            x_std,
            y_mean,
            y_std,
        };
        // Adam state.
        let mut m = [
            DMatrix::zeros(h, 6),
            DMatrix::zeros(h, 1),
            DMatrix::zeros(6, h),
            DMatrix::zeros(6, 1),
        ];
        let mut v = m.clone();
        let (b1, b2, e): (f64, f64, f64) = (0.9, 0.999, 1e-8);
        for t in 1..=o.epochs {
            let eps = DMatrix::from_fn(h, xz.ncols(), |_, _| {
                o.noise_sigma * rng.sample::<f64, _>(StandardNormal)
            });
            let (_, mut gw1, gb1, mut gw2, gb2) = loss_grad(&net, &xz, &yz, Some(&eps));
            gw1 += &net.w1 * o.weight_decay;
            gw2 += &net.w2 * o.weight_decay;
            let grads = [
                gw1,
                DMatrix::from_column_slice(h, 1, gb1.as_slice()),
                gw2,
                DMatrix::from_column_slice(6, 1, gb2.as_slice()),
            ];
            let lr = o.learning_rate * (1.0 - b2.powi(t as i32)).sqrt() / (1.0 - b1.powi(t as i32));
            for k in 0..4 {
                m[k] = &m[k] * b1 + &grads[k] * (1.0 - b1);
                v[k] = &v[k] * b2 + grads[k].map(|g| g * g) * (1.0 - b2);
                let step = m[k].zip_map(&v[k], |mm, vv| lr * mm / (vv.sqrt() + e));
                match k {
                    0 => net.w1 -= step,
                    1 => net.b1 -= DVector::from_column_slice(step.as_slice()),
                    2 => net.w2 -= step,
                    _ => net.b2 -= DVector::from_column_slice(step.as_slice()),
                }
            }
        }
        net
    }

    /// Predicted error at a desired pose (plain ReLU).
    pub fn predict(&self, x: &[f64; 6]) -> [f64; 6] {
        let xz = DVector::from_fn(6, |r, _| (x[r] - self.x_mean[r]) / self.x_std[r]);
        let h = (&self.w1 * xz + &self.b1).map(|v| v.max(0.0));
        let o = &self.w2 * h + &self.b2;
        [0, 1, 2, 3, 4, 5].map(|k| o[k] * self.y_std[k] + self.y_mean[k])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_matches_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let x = DMatrix::from_fn(6, 20, |_, _| rng.random_range(-1.0..1.0));
        let y = DMatrix::from_fn(6, 20, |_, _| rng.random_range(-1.0..1.0));
        let net = SeedNet {
            w1: DMatrix::from_fn(5, 6, |_, _| rng.random_range(-1.0..1.0)),
            b1: DVector::from_fn(5, |_, _| rng.random_range(-0.5..0.5)),
            w2: DMatrix::from_fn(6, 5, |_, _| rng.random_range(-1.0..1.0)),
            b2: DVector::from_fn(6, |_, _| rng.random_range(-0.5..0.5)),
            x_mean: DVector::zeros(6),
            x_std: DVector::from_element(6, 1.0),
            y_mean: DVector::zeros(6),
            y_std: DVector::from_element(6, 1.0),
        };
        let (_, gw1, _, gw2, gb2) = loss_grad(&net, &x, &y, None);
        let h = 1e-6;
        for (r, c) in [(0, 0), (2, 3), (4, 5)] {
            let mut p = net.clone();
            p.w1[(r, c)] += h;
            let mut m = net.clone();
            m.w1[(r, c)] -= h;
            let fd = (loss_grad(&p, &x, &y, None).0 - loss_grad(&m, &x, &y, None).0) / (2.0 * h);
            assert!((fd - gw1[(r, c)]).abs() < 1e-6, "w1 {fd} {}", gw1[(r, c)]);
        }
        for (r, c) in [(0, 0), (5, 4)] {
            let mut p = net.clone();
            p.w2[(r, c)] += h;
            let mut m = net.clone();
            m.w2[(r, c)] -= h;
            let fd = (loss_grad(&p, &x, &y, None).0 - loss_grad(&m, &x, &y, None).0) / (2.0 * h);
            assert!((fd - gw2[(r, c)]).abs() < 1e-6);
        }
        let mut p = net.clone();
        p.b2[1] += h;
        let mut m = net.clone();
        m.b2[1] -= h;
        let fd = (loss_grad(&p, &x, &y, None).0 - loss_grad(&m, &x, &y, None).0) / (2.0 * h);
        assert!((fd - gb2[1]).abs() < 1e-6);
    }

    #[test]
    fn learns_a_smooth_error_field() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let f = |x: &[f64; 6]| -> [f64; 6] {
            let e = 0.3 * (x[0] / 200.0).sin() + 0.1 * x[2] / 300.0;
            [e, -e, 0.5 * e, 0.0, 0.01 * e, 0.0]
        };
        let xs: Vec<[f64; 6]> = (0..300)
            .map(|_| {
                [0, 1, 2, 3, 4, 5].map(|k| {
                    if k < 3 {
                        rng.random_range(-400.0..400.0)
                    } else {
                        rng.random_range(-1.0..1.0)
                    }
                })
            })
            .collect();
        let ys: Vec<[f64; 6]> = xs.iter().map(f).collect();
        let net = SeedNet::train(
            &xs[..200],
            &ys[..200],
            &NetOptions {
                epochs: 1500,
                ..NetOptions::default()
            },
        );
        let (mut e0, mut e1) = (0.0, 0.0);
        for (x, y) in xs[200..].iter().zip(&ys[200..]) {
            let p = net.predict(x);
            e0 += y[0] * y[0];
            e1 += (y[0] - p[0]).powi(2);
        }
        assert!(e1 < 0.1 * e0, "held-out residual {e1} vs {e0}");
    }
}
