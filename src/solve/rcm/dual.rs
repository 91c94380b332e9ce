//! Forward-mode dual numbers with `N` derivative slots: the exact (automatic) Jacobians of the
//! RCM problems. Every Jacobian built with them is still checked against finite differences in
//! the tests (the style rule), which also checks the model code itself.
use std::ops::{Add, Div, Mul, Neg, Sub};

/// A scalar the RCM models are written over: `f64` or [`Dual`].
pub trait Real:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// A constant.
    fn c(x: f64) -> Self;
    /// The value part.
    fn v(self) -> f64;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Sine.
    fn sin(self) -> Self;
    /// Cosine.
    fn cos(self) -> Self;
}

impl Real for f64 {
    fn c(x: f64) -> Self {
        x
    }
    fn v(self) -> f64 {
        self
    }
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    fn sin(self) -> Self {
        f64::sin(self)
    }
    fn cos(self) -> Self {
        f64::cos(self)
    }
}

/// `a + Σ b_k ε_k` with `ε_k ε_l = 0`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dual<const N: usize> {
    /// Value.
    pub a: f64,
    /// Derivatives.
    pub b: [f64; N],
}

impl<const N: usize> Dual<N> {
    /// The `k`-th variable with value `a`.
    pub fn var(a: f64, k: usize) -> Self {
        let mut b = [0.0; N];
        b[k] = 1.0;
        Dual { a, b }
    }
    fn chain(self, f: f64, df: f64) -> Self {
        let mut b = self.b;
        for x in &mut b {
            *x *= df;
        }
        Dual { a: f, b }
    }
}

impl<const N: usize> Add for Dual<N> {
    type Output = Self;
    fn add(mut self, o: Self) -> Self {
        self.a += o.a;
        for k in 0..N {
            self.b[k] += o.b[k];
        }
        self
    }
}
impl<const N: usize> Sub for Dual<N> {
    type Output = Self;
    fn sub(mut self, o: Self) -> Self {
        self.a -= o.a;
        for k in 0..N {
            self.b[k] -= o.b[k];
        }
        self
    }
}
impl<const N: usize> Mul for Dual<N> {
    type Output = Self;
    fn mul(self, o: Self) -> Self {
        let mut b = [0.0; N];
        for (k, x) in b.iter_mut().enumerate() {
            *x = self.b[k] * o.a + self.a * o.b[k];
        }
        Dual { a: self.a * o.a, b }
    }
}
impl<const N: usize> Div for Dual<N> {
    type Output = Self;
    fn div(self, o: Self) -> Self {
        let inv = 1.0 / o.a;
        let q = self.a * inv;
        let mut b = [0.0; N];
        for (k, x) in b.iter_mut().enumerate() {
            *x = (self.b[k] - q * o.b[k]) * inv;
        }
        Dual { a: q, b }
    }
}
impl<const N: usize> Neg for Dual<N> {
    type Output = Self;
    fn neg(self) -> Self {
        self.chain(-self.a, -1.0)
    }
}

impl<const N: usize> Real for Dual<N> {
    fn c(x: f64) -> Self {
        Dual { a: x, b: [0.0; N] }
    }
    fn v(self) -> f64 {
        self.a
    }
    fn sqrt(self) -> Self {
        let s = self.a.sqrt();
        self.chain(s, 0.5 / s)
    }
    fn sin(self) -> Self {
        self.chain(self.a.sin(), self.a.cos())
    }
    fn cos(self) -> Self {
        self.chain(self.a.cos(), -self.a.sin())
    }
}

/// A 3-vector over [`Real`].
pub type V3<T> = [T; 3];

/// `a + b`.
pub fn add<T: Real>(a: V3<T>, b: V3<T>) -> V3<T> {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
/// `a − b`.
pub fn sub<T: Real>(a: V3<T>, b: V3<T>) -> V3<T> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
/// `s·a`.
pub fn scale<T: Real>(s: T, a: V3<T>) -> V3<T> {
    [s * a[0], s * a[1], s * a[2]]
}
/// `a·b`.
pub fn dot<T: Real>(a: V3<T>, b: V3<T>) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
/// `a × b`.
pub fn cross<T: Real>(a: V3<T>, b: V3<T>) -> V3<T> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
/// `a / |a|`.
pub fn unit<T: Real>(a: V3<T>) -> V3<T> {
    let n = dot(a, a).sqrt();
    [a[0] / n, a[1] / n, a[2] / n]
}
/// Constant vector.
pub fn cv<T: Real>(a: [f64; 3]) -> V3<T> {
    [T::c(a[0]), T::c(a[1]), T::c(a[2])]
}
/// `M·a` for a constant row-major 3×3 matrix.
pub fn mulm<T: Real>(m: &[[f64; 3]; 3], a: V3<T>) -> V3<T> {
    let r = |i: usize| T::c(m[i][0]) * a[0] + T::c(m[i][1]) * a[1] + T::c(m[i][2]) * a[2];
    [r(0), r(1), r(2)]
}
/// Rotate `a` by the rotation vector `w` (Rodrigues; exact at `w = 0` for derivatives).
pub fn rotvec<T: Real>(w: V3<T>, a: V3<T>) -> V3<T> {
    let th2 = dot(w, w);
    if th2.v() < 1e-16 {
        // First order is exact for the value 0 and its first derivatives.
        return add(a, cross(w, a));
    }
    let th = th2.sqrt();
    let k = scale(T::c(1.0) / th, w);
    let (s, c) = (th.sin(), th.cos());
    let kxa = cross(k, a);
    let kda = dot(k, a);
    add(
        add(scale(c, a), scale(s, kxa)),
        scale(kda * (T::c(1.0) - c), k),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dual_matches_finite_differences() {
        let f = |x: Dual<2>, y: Dual<2>| ((x * y + x.sin()) / (y.cos() + Dual::c(2.0))).sqrt();
        let (x0, y0) = (0.7, -0.3);
        let d = f(Dual::var(x0, 0), Dual::var(y0, 1));
        let g = |x: f64, y: f64| ((x * y + x.sin()) / (y.cos() + 2.0)).sqrt();
        let h = 1e-6;
        let fx = (g(x0 + h, y0) - g(x0 - h, y0)) / (2.0 * h);
        let fy = (g(x0, y0 + h) - g(x0, y0 - h)) / (2.0 * h);
        assert!((d.a - g(x0, y0)).abs() < 1e-14);
        assert!((d.b[0] - fx).abs() < 1e-8, "{} vs {fx}", d.b[0]);
        assert!((d.b[1] - fy).abs() < 1e-8, "{} vs {fy}", d.b[1]);
    }

    #[test]
    fn rotvec_matches_nalgebra() {
        let w = [0.3, -0.2, 0.5];
        let a = [1.0, 2.0, -0.5];
        let r = rotvec(w, a);
        let q = nalgebra::Rotation3::new(nalgebra::Vector3::from(w)) * nalgebra::Vector3::from(a);
        for k in 0..3 {
            assert!((r[k] - q[k]).abs() < 1e-12);
        }
    }
}
