//! A small dense Levenberg–Marquardt solver with Moré column scaling.
//!
//! Why not the `levenberg-marquardt` crate: our problems are small and dense (≤ ~2000
//! residuals × ≤ ~60 parameters), we need the Jacobian of the *final* point for the
//! covariance, a named termination reason, and to run 10 000 warm-started fits in a
//! bootstrap without per-fit allocation of trait objects. The normal equations
//! `(JᵀJ + λ·diag(JᵀJ)) δ = −Jᵀr` are solved by Cholesky (falling back to an SVD
//! pseudo-inverse when the damped matrix is not positive definite), which is exactly
//! Marquardt's scaled variant: the damping acts on scaled columns, so millimetre and
//! radian parameters are treated alike.
use nalgebra::{DMatrix, DVector};

/// A least-squares problem `min ½‖r(x)‖²`.
pub trait LsqProblem {
    /// Number of parameters.
    fn n_params(&self) -> usize;
    /// Residual vector at `x`.
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64>;
    /// Residuals and Jacobian (`n_residuals × n_params`) at `x`.
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>);
}

/// Why the solver stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Termination {
    /// The scaled gradient fell below `gtol`.
    GradientSmall,
    /// The scaled step fell below `xtol` (relative to the scaled parameter norm).
    StepSmall,
    /// The relative cost decrease fell below `ftol`.
    CostConverged,
    /// The residual is (numerically) zero.
    ZeroResidual,
    /// The iteration limit was reached before convergence.
    MaxIterations,
    /// Damping grew without finding a decrease (the model is at a minimum to rounding).
    NoDecrease,
    /// Residuals or Jacobian were not finite at the start point.
    NonFinite,
}

impl Termination {
    /// Whether this counts as a converged solve.
    pub fn converged(self) -> bool {
        !matches!(self, Termination::MaxIterations | Termination::NonFinite)
    }
    /// Short human-readable description.
    pub fn describe(self) -> &'static str {
        match self {
            Termination::GradientSmall => "converged: gradient below tolerance",
            Termination::StepSmall => "converged: step below tolerance",
            Termination::CostConverged => "converged: relative cost change below tolerance",
            Termination::ZeroResidual => "converged: zero residual",
            Termination::MaxIterations => "stopped: iteration limit reached",
            Termination::NoDecrease => "converged: no further decrease possible (damping limit)",
            Termination::NonFinite => "failed: non-finite residual or Jacobian",
        }
    }
}

/// Solver settings.
#[derive(Debug, Clone, Copy)]
pub struct LmOptions {
    pub max_iter: usize,
    pub ftol: f64,
    pub xtol: f64,
    pub gtol: f64,
    /// Initial damping relative to the scaled diagonal.
    pub lambda0: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions {
            max_iter: 100,
            ftol: 1e-12,
            xtol: 1e-12,
            gtol: 1e-12,
            lambda0: 1e-3,
        }
    }
}

/// Result of a solve.
#[derive(Debug, Clone)]
pub struct LmReport {
    pub x: DVector<f64>,
    /// Residuals at `x`.
    pub residuals: DVector<f64>,
    /// Jacobian at `x` (unscaled).
    pub jacobian: DMatrix<f64>,
    /// `½‖r‖²` at `x`.
    pub cost: f64,
    pub initial_cost: f64,
    pub iterations: usize,
    pub evaluations: usize,
    pub termination: Termination,
}

fn finite_all(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Iteration bound of the SVD fallback (nalgebra's default is unbounded).
pub const SVD_MAX_ITER: usize = 1000;

/// Solve `(A + λ·diag) δ = b` for symmetric PSD `A`; pseudo-inverse fallback. Non-finite
/// input gives a zero step (never an unbounded SVD iteration).
pub fn solve_spd(a: &DMatrix<f64>, b: &DVector<f64>) -> DVector<f64> {
    if !finite_all(a.as_slice()) || !finite_all(b.as_slice()) {
        return DVector::zeros(b.len());
    }
    if let Some(ch) = a.clone().cholesky() {
        return ch.solve(b);
    }
    let Some(svd) = nalgebra::SVD::try_new(a.clone(), true, true, f64::EPSILON, SVD_MAX_ITER)
    else {
        return DVector::zeros(b.len());
    };
    let smax = svd.singular_values.max();
    svd.solve(b, smax * 1e-14)
        .unwrap_or_else(|_| DVector::zeros(b.len()))
}

/// The damping after an accepted step whose gain ratio (actual / predicted decrease) is `rho`:
/// a third when the model predicted well (> 0.75), doubled when poorly (< 0.25), never below
/// 1e-12.
pub fn next_lambda(lambda: f64, rho: f64) -> f64 {
    let f = if rho > 0.75 {
        1.0 / 3.0
    } else if rho < 0.25 {
        2.0
    } else {
        1.0
    };
    (lambda * f).max(1e-12)
}

/// Minimise `½‖r(x)‖²` from `x0`.
pub fn minimize<P: LsqProblem + ?Sized>(p: &P, x0: DVector<f64>, o: &LmOptions) -> LmReport {
    let n = p.n_params();
    let mut x = x0;
    let (mut r, mut j) = p.residuals_jacobian(&x);
    let mut evals = 1;
    let initial_cost = 0.5 * r.norm_squared();
    // Finite residuals can still overflow the cost (|r| ~ 1e308): refuse those too.
    if !finite_all(r.as_slice()) || !finite_all(j.as_slice()) || !initial_cost.is_finite() {
        return LmReport {
            x,
            cost: f64::INFINITY,
            initial_cost,
            residuals: r,
            jacobian: j,
            iterations: 0,
            evaluations: evals,
            termination: Termination::NonFinite,
        };
    }
    let mut cost = initial_cost;
    let mut lambda = o.lambda0;
    // Moré scaling: running max of column norms.
    let mut dscale = DVector::from_element(n, 0.0);
    let mut term = Termination::MaxIterations;
    let mut iters = 0;
    if n == 0 {
        return LmReport {
            x,
            cost,
            initial_cost,
            residuals: r,
            jacobian: j,
            iterations: 0,
            evaluations: evals,
            termination: Termination::GradientSmall,
        };
    }
    'outer: while iters < o.max_iter {
        iters += 1;
        if cost <= f64::MIN_POSITIVE {
            term = Termination::ZeroResidual;
            break;
        }
        // JᵀJ through a GEMM (`tr_mul` walks column dot products and is ~3× slower here).
        let jtj = j.transpose() * &j;
        let g = j.tr_mul(&r);
        if !finite_all(jtj.as_slice()) || !finite_all(g.as_slice()) {
            term = Termination::NonFinite;
            break;
        }
        for k in 0..n {
            let c = jtj[(k, k)].sqrt();
            if c > dscale[k] {
                dscale[k] = c;
            }
            if dscale[k] == 0.0 {
                dscale[k] = 1.0;
            }
        }
        // Scaled gradient test: max |g_k| / (d_k * ‖r‖).
        let rn = r.norm();
        let gmax = (0..n)
            .map(|k| (g[k] / (dscale[k] * rn)).abs())
            .fold(0.0, f64::max);
        if gmax <= o.gtol {
            term = Termination::GradientSmall;
            break;
        }
        loop {
            let mut a = jtj.clone();
            for k in 0..n {
                a[(k, k)] += lambda * dscale[k] * dscale[k];
            }
            let delta = solve_spd(&a, &(-&g));
            let xnew = &x + &delta;
            // Residuals and Jacobian in one pass: warm-started steps are nearly always
            // accepted, so this saves a forward pass per iteration.
            let (rnew, jnew) = p.residuals_jacobian(&xnew);
            evals += 1;
            let cnew = 0.5 * rnew.norm_squared();
            let dx_scaled = delta.component_mul(&dscale).norm();
            let x_scaled = x.component_mul(&dscale).norm();
            if cnew.is_finite() && cnew < cost && finite_all(jnew.as_slice()) {
                // predicted reduction for the gain ratio
                let jd = &j * &delta;
                let pred = -(g.dot(&delta)) - 0.5 * jd.norm_squared();
                let rho = if pred > 0.0 {
                    (cost - cnew) / pred
                } else {
                    0.0
                };
                let rel = (cost - cnew) / cost;
                x = xnew;
                r = rnew;
                j = jnew;
                cost = cnew;
                lambda = next_lambda(lambda, rho);
                if rel <= o.ftol {
                    term = Termination::CostConverged;
                    break 'outer;
                }
                if dx_scaled <= o.xtol * (x_scaled + o.xtol) {
                    term = Termination::StepSmall;
                    break 'outer;
                }
                break;
            }
            if dx_scaled <= o.xtol * (x_scaled + o.xtol) {
                term = Termination::StepSmall;
                break 'outer;
            }
            lambda *= 4.0;
            if lambda > 1e16 {
                term = Termination::NoDecrease;
                break 'outer;
            }
        }
    }
    LmReport {
        x,
        cost,
        initial_cost,
        residuals: r,
        jacobian: j,
        iterations: iters,
        evaluations: evals,
        termination: term,
    }
}

/// `inner` with the parameters at `held` (indices into its parameter vector) fixed at their
/// values in `at`: the free parameters are the others, in order.
pub struct Held<'a, P: LsqProblem + ?Sized> {
    pub inner: &'a P,
    pub at: DVector<f64>,
    pub held: Vec<bool>,
}

impl<'a, P: LsqProblem + ?Sized> Held<'a, P> {
    /// Hold the parameters `idx` of `inner` at their values in `at`.
    pub fn new(inner: &'a P, at: DVector<f64>, idx: impl IntoIterator<Item = usize>) -> Self {
        let mut held = vec![false; at.len()];
        for i in idx {
            held[i] = true;
        }
        Held { inner, at, held }
    }
    /// The free parameters of `full`.
    pub fn free_of(&self, full: &DVector<f64>) -> DVector<f64> {
        DVector::from_iterator(
            self.held.iter().filter(|h| !**h).count(),
            full.iter()
                .zip(&self.held)
                .filter(|(_, h)| !**h)
                .map(|(v, _)| *v),
        )
    }
    /// The full parameter vector with the free parameters `x`.
    pub fn full(&self, x: &DVector<f64>) -> DVector<f64> {
        let mut v = self.at.clone();
        let mut k = 0;
        for (i, h) in self.held.iter().enumerate() {
            if !h {
                v[i] = x[k];
                k += 1;
            }
        }
        v
    }
}

impl<P: LsqProblem + ?Sized> LsqProblem for Held<'_, P> {
    fn n_params(&self) -> usize {
        self.held.iter().filter(|h| !**h).count()
    }
    fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
        self.inner.residuals(&self.full(x))
    }
    fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let (r, j) = self.inner.residuals_jacobian(&self.full(x));
        let cols: Vec<usize> = (0..self.held.len()).filter(|i| !self.held[*i]).collect();
        (r, j.select_columns(&cols))
    }
}

/// Forward-difference Jacobian of a residual function (for tests of analytic Jacobians).
pub fn numeric_jacobian<F: Fn(&DVector<f64>) -> DVector<f64>>(
    f: F,
    x: &DVector<f64>,
    h: f64,
) -> DMatrix<f64> {
    let r0 = f(x);
    let mut j = DMatrix::zeros(r0.len(), x.len());
    for k in 0..x.len() {
        let mut xp = x.clone();
        let mut xm = x.clone();
        xp[k] += h;
        xm[k] -= h;
        let d = (f(&xp) - f(&xm)) / (2.0 * h);
        j.set_column(k, &d);
    }
    j
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Holding a parameter: the other is fitted, the held one keeps its value, and the
    /// Jacobian is the inner one's free columns.
    #[test]
    fn held_parameters_stay_and_the_rest_are_fitted() {
        // Rosenbrock with x1 held at 0.5: the minimum over x2 is x2 = 0.25.
        let h = Held::new(&Rosen, DVector::from_vec(vec![0.5, 3.0]), [0]);
        assert_eq!(h.n_params(), 1);
        let rep = minimize(&h, h.free_of(&h.at), &LmOptions::default());
        let full = h.full(&rep.x);
        assert!((full[0] - 0.5).abs() == 0.0);
        assert!((full[1] - 0.25).abs() < 1e-9, "{full}");
        let x = DVector::from_vec(vec![1.7]);
        let (_, j) = h.residuals_jacobian(&x);
        let jn = numeric_jacobian(|x| h.residuals(x), &x, 1e-6);
        assert!((j - jn).abs().max() < 1e-6);
    }

    /// Rosenbrock as least squares: r = (10(x2 − x1²), 1 − x1).
    struct Rosen;
    impl LsqProblem for Rosen {
        fn n_params(&self) -> usize {
            2
        }
        fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
            DVector::from_vec(vec![10.0 * (x[1] - x[0] * x[0]), 1.0 - x[0]])
        }
        fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
            let j = DMatrix::from_row_slice(2, 2, &[-20.0 * x[0], 10.0, -1.0, 0.0]);
            (self.residuals(x), j)
        }
    }

    #[test]
    fn rosenbrock_converges() {
        let rep = minimize(
            &Rosen,
            DVector::from_vec(vec![-1.2, 1.0]),
            &LmOptions::default(),
        );
        assert!(rep.termination.converged(), "{:?}", rep.termination);
        assert!((rep.x[0] - 1.0).abs() < 1e-8 && (rep.x[1] - 1.0).abs() < 1e-8);
    }

    /// Badly scaled exponential fit: y = a·exp(b·t) with a ~ 1e4, b ~ 1e-3.
    struct Expo {
        t: Vec<f64>,
        y: Vec<f64>,
    }
    impl LsqProblem for Expo {
        fn n_params(&self) -> usize {
            2
        }
        fn residuals(&self, x: &DVector<f64>) -> DVector<f64> {
            DVector::from_iterator(
                self.t.len(),
                self.t
                    .iter()
                    .zip(&self.y)
                    .map(|(t, y)| x[0] * (x[1] * t).exp() - y),
            )
        }
        fn residuals_jacobian(&self, x: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
            let mut j = DMatrix::zeros(self.t.len(), 2);
            for (i, t) in self.t.iter().enumerate() {
                let e = (x[1] * t).exp();
                j[(i, 0)] = e;
                j[(i, 1)] = x[0] * t * e;
            }
            (self.residuals(x), j)
        }
    }

    #[test]
    fn badly_scaled_problem_converges_and_jacobian_matches_fd() {
        let t: Vec<f64> = (0..50).map(|i| i as f64 * 20.0).collect();
        let y = t.iter().map(|t| 12_000.0 * (0.0013 * t).exp()).collect();
        let p = Expo { t, y };
        let x0 = DVector::from_vec(vec![8_000.0, 0.0005]);
        let (_, ja) = p.residuals_jacobian(&x0);
        let jn = numeric_jacobian(|x| p.residuals(x), &x0, 1e-7);
        for k in 0..2 {
            let rel = (ja.column(k) - jn.column(k)).norm() / ja.column(k).norm();
            assert!(rel < 1e-5, "column {k}: {rel}");
        }
        let rep = minimize(&p, x0, &LmOptions::default());
        assert!(rep.termination.converged(), "{:?}", rep.termination);
        assert!((rep.x[0] / 12_000.0 - 1.0).abs() < 1e-9, "{}", rep.x[0]);
        assert!((rep.x[1] / 0.0013 - 1.0).abs() < 1e-9, "{}", rep.x[1]);
    }

    #[test]
    fn overflowing_start_is_reported_not_iterated() {
        // Finite residuals whose square overflows: NonFinite at once, no SVD of infinities.
        let p = Expo {
            t: vec![1.0, 2.0],
            y: vec![1e308, -1e308],
        };
        let rep = minimize(&p, DVector::from_vec(vec![1.0, 1.0]), &LmOptions::default());
        assert_eq!(rep.termination, Termination::NonFinite);
        let a = DMatrix::from_element(2, 2, f64::INFINITY);
        assert_eq!(solve_spd(&a, &DVector::zeros(2)), DVector::zeros(2));
    }

    #[test]
    fn non_finite_start_is_reported() {
        let p = Expo {
            t: vec![1.0],
            y: vec![f64::NAN],
        };
        let rep = minimize(&p, DVector::from_vec(vec![1.0, 1.0]), &LmOptions::default());
        assert_eq!(rep.termination, Termination::NonFinite);
        assert!(!rep.termination.converged());
    }
}
