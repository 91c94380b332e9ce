//! Small descriptive statistics: mean, std, quantiles, RMS and a Jarque–Bera normality test.

/// Arithmetic mean (NaN for an empty slice).
pub fn mean(x: &[f64]) -> f64 {
    if x.is_empty() {
        return f64::NAN;
    }
    x.iter().sum::<f64>() / x.len() as f64
}

/// Sample standard deviation (n − 1); 0 for fewer than two values.
pub fn std_dev(x: &[f64]) -> f64 {
    if x.len() < 2 {
        return 0.0;
    }
    let m = mean(x);
    (x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (x.len() - 1) as f64).sqrt()
}

/// Root mean square (NaN for an empty slice).
pub fn rms(x: &[f64]) -> f64 {
    if x.is_empty() {
        return f64::NAN;
    }
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

/// Linear-interpolated quantile `p ∈ [0, 1]` of unsorted data (NaN for empty).
pub fn quantile(x: &[f64], p: f64) -> f64 {
    if x.is_empty() {
        return f64::NAN;
    }
    let mut v: Vec<f64> = x.to_vec();
    v.sort_by(|a, b| a.total_cmp(b));
    let pos = p.clamp(0.0, 1.0) * (v.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = pos.ceil() as usize;
    v[lo] + (v[hi] - v[lo]) * (pos - lo as f64)
}

/// Distribution summary of one scalar.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    pub n: usize,
    pub mean: f64,
    pub std: f64,
    pub q025: f64,
    pub q975: f64,
    pub skewness: f64,
    pub excess_kurtosis: f64,
    /// Jarque–Bera statistic `n/6·(S² + K²/4)`.
    pub jarque_bera: f64,
    /// Asymptotic p-value of JB (χ² with 2 dof: `exp(−JB/2)`).
    pub normal_p: f64,
}

impl Summary {
    /// Summarise `x`.
    pub fn of(x: &[f64]) -> Summary {
        let n = x.len();
        let m = mean(x);
        let (mut m2, mut m3, mut m4) = (0.0, 0.0, 0.0);
        for v in x {
            let d = v - m;
            m2 += d * d;
            m3 += d * d * d;
            m4 += d * d * d * d;
        }
        let nf = n.max(1) as f64;
        m2 /= nf;
        m3 /= nf;
        m4 /= nf;
        let (s, k) = if m2 > 0.0 {
            (m3 / m2.powf(1.5), m4 / (m2 * m2) - 3.0)
        } else {
            (0.0, 0.0)
        };
        let jb = nf / 6.0 * (s * s + k * k / 4.0);
        Summary {
            n,
            mean: m,
            std: std_dev(x),
            q025: quantile(x, 0.025),
            q975: quantile(x, 0.975),
            skewness: s,
            excess_kurtosis: k,
            jarque_bera: jb,
            normal_p: (-jb / 2.0).exp(),
        }
    }
    /// Normality not rejected at the 1 % level.
    pub fn looks_normal(&self) -> bool {
        self.normal_p > 0.01
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Exp, Normal};

    #[test]
    fn basic_values() {
        let x = [1.0, 2.0, 3.0, 4.0];
        assert_eq!(mean(&x), 2.5);
        assert!((std_dev(&x) - 1.2909944487358056).abs() < 1e-12);
        assert!((rms(&[3.0, 4.0]) - (12.5f64).sqrt()).abs() < 1e-12);
        assert_eq!(quantile(&x, 0.5), 2.5);
        assert_eq!(quantile(&x, 0.0), 1.0);
        assert_eq!(quantile(&x, 1.0), 4.0);
        assert!(mean(&[]).is_nan());
    }

    #[test]
    fn jarque_bera_separates_normal_from_exponential() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let n = Normal::new(5.0, 2.0).unwrap();
        let xs: Vec<f64> = (0..5000).map(|_| n.sample(&mut rng)).collect();
        let s = Summary::of(&xs);
        assert!(s.looks_normal(), "{s:?}");
        assert!((s.mean - 5.0).abs() < 0.1 && (s.std - 2.0).abs() < 0.1);
        assert!((s.q025 - (5.0 - 1.96 * 2.0)).abs() < 0.2);
        let e = Exp::new(1.0).unwrap();
        let ys: Vec<f64> = (0..5000).map(|_| e.sample(&mut rng)).collect();
        let s = Summary::of(&ys);
        assert!(!s.looks_normal(), "{s:?}");
        assert!(s.skewness > 1.5);
    }
}
