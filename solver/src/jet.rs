//! Forward-mode dual numbers with a const-generic number of derivative directions.
//!
//! A `Jet<N>` is `a + Σ v_i ε_i` with `ε_i ε_j = 0` (Ceres' jets; Griewank & Walther 2008, ch. 3):
//! evaluating f on jets seeded with unit directions yields f and its N partial derivatives, exact to
//! rounding.

use crate::real::Real;
use std::ops::{Add, AddAssign, Div, DivAssign, Mul, MulAssign, Neg, Sub, SubAssign};

/// A dual number: value `re` and derivatives `v` along N directions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Jet<const N: usize> {
    /// The value.
    pub re: f64,
    /// The partial derivatives.
    pub v: [f64; N],
}

impl<const N: usize> Jet<N> {
    /// A constant.
    #[inline]
    pub fn constant(re: f64) -> Self {
        Self { re, v: [0.0; N] }
    }
    /// The independent variable number `i`: value `re`, derivative 1 along direction `i`.
    #[inline]
    pub fn variable(re: f64, i: usize) -> Self {
        let mut v = [0.0; N];
        v[i] = 1.0;
        Self { re, v }
    }
    /// Chain rule for a unary function with value `f` and derivative `df` at `self.re`.
    #[inline]
    fn chain(self, f: f64, df: f64) -> Self {
        let mut v = self.v;
        for x in v.iter_mut() {
            *x *= df;
        }
        Self { re: f, v }
    }
}

impl<const N: usize> PartialOrd for Jet<N> {
    /// Jets compare by value, as branches in a cost function do.
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        self.re.partial_cmp(&other.re)
    }
}

impl<const N: usize> Add for Jet<N> {
    type Output = Self;
    #[inline]
    fn add(mut self, o: Self) -> Self {
        self.re += o.re;
        for (a, b) in self.v.iter_mut().zip(o.v.iter()) {
            *a += b;
        }
        self
    }
}
impl<const N: usize> Sub for Jet<N> {
    type Output = Self;
    #[inline]
    fn sub(mut self, o: Self) -> Self {
        self.re -= o.re;
        for (a, b) in self.v.iter_mut().zip(o.v.iter()) {
            *a -= b;
        }
        self
    }
}
impl<const N: usize> Mul for Jet<N> {
    type Output = Self;
    #[inline]
    #[allow(clippy::suspicious_arithmetic_impl)] // product rule: d(ab) = a db + b da
    fn mul(self, o: Self) -> Self {
        let v = std::array::from_fn(|i| self.re * o.v[i] + o.re * self.v[i]);
        Self {
            re: self.re * o.re,
            v,
        }
    }
}
impl<const N: usize> Div for Jet<N> {
    type Output = Self;
    #[inline]
    fn div(self, o: Self) -> Self {
        let inv = 1.0 / o.re;
        let re = self.re * inv;
        let v = std::array::from_fn(|i| (self.v[i] - re * o.v[i]) * inv);
        Self { re, v }
    }
}
impl<const N: usize> Neg for Jet<N> {
    type Output = Self;
    #[inline]
    fn neg(mut self) -> Self {
        self.re = -self.re;
        for a in self.v.iter_mut() {
            *a = -*a;
        }
        self
    }
}
impl<const N: usize> Add<f64> for Jet<N> {
    type Output = Self;
    #[inline]
    fn add(mut self, o: f64) -> Self {
        self.re += o;
        self
    }
}
impl<const N: usize> Sub<f64> for Jet<N> {
    type Output = Self;
    #[inline]
    fn sub(mut self, o: f64) -> Self {
        self.re -= o;
        self
    }
}
impl<const N: usize> Mul<f64> for Jet<N> {
    type Output = Self;
    #[inline]
    fn mul(mut self, o: f64) -> Self {
        self.re *= o;
        for a in self.v.iter_mut() {
            *a *= o;
        }
        self
    }
}
impl<const N: usize> Div<f64> for Jet<N> {
    type Output = Self;
    #[inline]
    fn div(self, o: f64) -> Self {
        self * (1.0 / o)
    }
}
macro_rules! assign_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl<const N: usize> $tr for Jet<N> {
            #[inline]
            fn $f(&mut self, o: Self) {
                *self = *self $op o;
            }
        }
    };
}
assign_op!(AddAssign, add_assign, +);
assign_op!(SubAssign, sub_assign, -);
assign_op!(MulAssign, mul_assign, *);
assign_op!(DivAssign, div_assign, /);

impl<const N: usize> Real for Jet<N> {
    #[inline]
    fn from_f64(v: f64) -> Self {
        Self::constant(v)
    }
    #[inline]
    fn value(self) -> f64 {
        self.re
    }
    #[inline]
    fn sin(self) -> Self {
        let (s, c) = self.re.sin_cos();
        self.chain(s, c)
    }
    #[inline]
    fn cos(self) -> Self {
        let (s, c) = self.re.sin_cos();
        self.chain(c, -s)
    }
    #[inline]
    fn tan(self) -> Self {
        let t = self.re.tan();
        self.chain(t, 1.0 + t * t)
    }
    #[inline]
    fn asin(self) -> Self {
        self.chain(self.re.asin(), 1.0 / (1.0 - self.re * self.re).sqrt())
    }
    #[inline]
    fn acos(self) -> Self {
        self.chain(self.re.acos(), -1.0 / (1.0 - self.re * self.re).sqrt())
    }
    #[inline]
    fn atan(self) -> Self {
        self.chain(self.re.atan(), 1.0 / (1.0 + self.re * self.re))
    }
    #[inline]
    fn atan2(self, x: Self) -> Self {
        // d atan2(y, x) = (x dy - y dx) / (x^2 + y^2)
        let inv = 1.0 / (x.re * x.re + self.re * self.re);
        let v = std::array::from_fn(|i| (x.re * self.v[i] - self.re * x.v[i]) * inv);
        Self {
            re: self.re.atan2(x.re),
            v,
        }
    }
    #[inline]
    fn sqrt(self) -> Self {
        let s = self.re.sqrt();
        self.chain(s, 0.5 / s)
    }
    #[inline]
    fn exp(self) -> Self {
        let e = self.re.exp();
        self.chain(e, e)
    }
    #[inline]
    fn ln(self) -> Self {
        self.chain(self.re.ln(), 1.0 / self.re)
    }
    #[inline]
    fn abs(self) -> Self {
        if self.re < 0.0 {
            -self
        } else if self.re > 0.0 {
            self
        } else {
            self.chain(0.0, 0.0)
        }
    }
    #[inline]
    fn powi(self, n: i32) -> Self {
        if n == 0 {
            return Self::constant(1.0);
        }
        self.chain(self.re.powi(n), n as f64 * self.re.powi(n - 1))
    }
    #[inline]
    fn powf(self, p: f64) -> Self {
        self.chain(self.re.powf(p), p * self.re.powf(p - 1.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use proptest::prelude::*;

    /// A function exercising every elementary operation.
    fn f<T: Real>(x: T, y: T) -> T {
        let a = x.sin() * y.cos() + (x * y).exp() / (T::one() + x * x);
        let b = (x * x + y * y + 1.0).sqrt().ln() + y.atan2(x + 3.0) - (x * 0.3).tan();
        let c = (x * 0.4).asin() + (y * 0.4).acos() + (x - y).atan() + x.abs() * y.powi(3);
        a + b + c + (y * y + 1.0).powf(1.5)
    }

    proptest! {
        #[test]
        fn jet_derivatives_match_central_differences(x in -2.0f64..2.0, y in -2.0f64..2.0) {
            let j = f(Jet::<2>::variable(x, 0), Jet::<2>::variable(y, 1));
            let h = 1e-6;
            let dx = (f(x + h, y) - f(x - h, y)) / (2.0 * h);
            let dy = (f(x, y + h) - f(x, y - h)) / (2.0 * h);
            prop_assert!((j.re - f(x, y)).abs() < 1e-12);
            assert_relative_eq!(j.v[0], dx, epsilon = 1e-6, max_relative = 1e-6);
            assert_relative_eq!(j.v[1], dy, epsilon = 1e-6, max_relative = 1e-6);
        }
    }
}
