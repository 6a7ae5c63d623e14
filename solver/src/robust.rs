//! Robust kernels ρ(s) of the squared residual norm s = ‖r‖², with ρ(0) = 0, ρ'(0) = 1, and the
//! Triggs correction that folds a kernel into the residual and Jacobian (Triggs et al., *Bundle
//! Adjustment — A Modern Synthesis*, 2000, sec. 4.3; Ceres' `Corrector`).
//!
//! Each kernel has a scale c: residuals with ‖r‖ well below c are treated as with plain least squares.

use std::fmt::Debug;

/// A robust loss ρ(s) of the squared norm s, returning `[ρ(s), ρ'(s), ρ''(s)]`.
pub trait RobustKernel: Send + Sync + Debug {
    /// `[ρ(s), ρ'(s), ρ''(s)]` at s ≥ 0.
    fn evaluate(&self, s: f64) -> [f64; 3];
}

/// Huber: ρ = s for s ≤ c², 2c√s − c² beyond (Huber 1964).
#[derive(Clone, Copy, Debug)]
pub struct Huber(pub f64);
/// Cauchy: ρ = c² ln(1 + s/c²).
#[derive(Clone, Copy, Debug)]
pub struct Cauchy(pub f64);
/// Tukey's biweight: ρ = c²/3 (1 − (1 − s/c²)³) for s ≤ c², c²/3 beyond.
#[derive(Clone, Copy, Debug)]
pub struct Tukey(pub f64);
/// Geman-McClure: ρ = c² s / (c² + s).
#[derive(Clone, Copy, Debug)]
pub struct GemanMcClure(pub f64);
/// Welsch (Leclerc): ρ = c² (1 − exp(−s/c²)).
#[derive(Clone, Copy, Debug)]
pub struct Welsch(pub f64);
/// Fair: ρ = 2c² (√s/c − ln(1 + √s/c)).
#[derive(Clone, Copy, Debug)]
pub struct Fair(pub f64);
/// Dynamic covariance scaling (Agarwal et al., ICRA 2013) with Φ = c: ρ = s for s ≤ Φ,
/// Φ(3s − Φ)/(Φ + s) beyond, so that ρ'(s) = (2Φ/(Φ + s))², the square of DCS's scale.
#[derive(Clone, Copy, Debug)]
pub struct Dcs(pub f64);
/// Barron's general and adaptive kernel (CVPR 2019) with shape α and scale c, scaled so that
/// ρ(s) ≈ s near 0: ρ = 2c² |α−2|/α ((s/(c²|α−2|) + 1)^{α/2} − 1). α = 2 is least squares, α = 0
/// Cauchy-like, α = −∞ Welsch-like.
#[derive(Clone, Copy, Debug)]
pub struct Barron {
    /// Shape α (any real, or −∞).
    pub alpha: f64,
    /// Scale c.
    pub scale: f64,
}

impl RobustKernel for Huber {
    fn evaluate(&self, s: f64) -> [f64; 3] {
        let c2 = self.0 * self.0;
        if s <= c2 {
            [s, 1.0, 0.0]
        } else {
            let r = s.sqrt();
            [2.0 * self.0 * r - c2, self.0 / r, -0.5 * self.0 / (s * r)]
        }
    }
}

impl RobustKernel for Cauchy {
    fn evaluate(&self, s: f64) -> [f64; 3] {
        let c2 = self.0 * self.0;
        let u = 1.0 + s / c2;
        [c2 * u.ln(), 1.0 / u, -1.0 / (c2 * u * u)]
    }
}

impl RobustKernel for Tukey {
    fn evaluate(&self, s: f64) -> [f64; 3] {
        let c2 = self.0 * self.0;
        if s <= c2 {
            let u = 1.0 - s / c2;
            [c2 / 3.0 * (1.0 - u * u * u), u * u, -2.0 * u / c2]
        } else {
            [c2 / 3.0, 0.0, 0.0]
        }
    }
}

impl RobustKernel for GemanMcClure {
    fn evaluate(&self, s: f64) -> [f64; 3] {
        let c2 = self.0 * self.0;
        let d = c2 + s;
        [c2 * s / d, c2 * c2 / (d * d), -2.0 * c2 * c2 / (d * d * d)]
    }
}

impl RobustKernel for Welsch {
    fn evaluate(&self, s: f64) -> [f64; 3] {
        let c2 = self.0 * self.0;
        let e = (-s / c2).exp();
        [c2 * (1.0 - e), e, -e / c2]
    }
}

impl RobustKernel for Fair {
    fn evaluate(&self, s: f64) -> [f64; 3] {
        let c = self.0;
        let u = s.sqrt();
        let d = 1.0 + u / c;
        let rho = 2.0 * c * c * (u / c - d.ln());
        // ρ'' is unbounded at 0, where the residual is zero and the correction unused.
        let rho2 = if u > 0.0 {
            -1.0 / (2.0 * c * u * d * d)
        } else {
            0.0
        };
        [rho, 1.0 / d, rho2]
    }
}

impl RobustKernel for Dcs {
    fn evaluate(&self, s: f64) -> [f64; 3] {
        let p = self.0;
        if s <= p {
            [s, 1.0, 0.0]
        } else {
            let d = p + s;
            [
                p * (3.0 * s - p) / d,
                4.0 * p * p / (d * d),
                -8.0 * p * p / (d * d * d),
            ]
        }
    }
}

impl RobustKernel for Barron {
    fn evaluate(&self, s: f64) -> [f64; 3] {
        let (a, c2) = (self.alpha, self.scale * self.scale);
        if a == 2.0 {
            return [s, 1.0, 0.0];
        }
        if a == 0.0 {
            let u = 1.0 + s / (2.0 * c2);
            return [2.0 * c2 * u.ln(), 1.0 / u, -1.0 / (2.0 * c2 * u * u)];
        }
        if a == f64::NEG_INFINITY {
            let e = (-s / (2.0 * c2)).exp();
            return [2.0 * c2 * (1.0 - e), e, -e / (2.0 * c2)];
        }
        let b = (a - 2.0).abs();
        let u = 1.0 + s / (c2 * b);
        let p = u.powf(0.5 * a - 1.0);
        [
            2.0 * c2 * b / a * (p * u - 1.0),
            p,
            (0.5 * a - 1.0) * p / (u * c2 * b),
        ]
    }
}

/// A built-in kernel chosen by name and scale, as a command line or a file gives it:
/// `huber:1`, `cauchy:0.5`, `tukey:4.7`, `geman-mcclure:1`, `welsch:1`, `fair:1`, `dcs:1`
/// ([`FromStr`](std::str::FromStr) reads that form, [`Display`](std::fmt::Display) writes it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum NamedKernel {
    /// [`Huber`] with this scale.
    Huber(f64),
    /// [`Cauchy`] with this scale.
    Cauchy(f64),
    /// [`Tukey`] with this scale.
    Tukey(f64),
    /// [`GemanMcClure`] with this scale.
    GemanMcClure(f64),
    /// [`Welsch`] with this scale.
    Welsch(f64),
    /// [`Fair`] with this scale.
    Fair(f64),
    /// [`Dcs`] with this Φ.
    Dcs(f64),
}

/// Why a kernel's name and scale could not be read.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum KernelParseError {
    /// The name is none of the built-in kernels.
    #[error("unknown robust kernel '{0}' (expected huber, cauchy, tukey, geman-mcclure, welsch, fair or dcs, as NAME:SCALE)")]
    UnknownName(String),
    /// The text after the colon is missing, not a number, not finite or not positive.
    #[error("robust kernel '{0}': the scale must be a positive finite number, as NAME:SCALE")]
    BadScale(String),
}

impl NamedKernel {
    const NAMES: [&'static str; 7] = [
        "huber",
        "cauchy",
        "tukey",
        "geman-mcclure",
        "welsch",
        "fair",
        "dcs",
    ];

    /// The kernel's name, as [`FromStr`](std::str::FromStr) reads it.
    pub fn name(&self) -> &'static str {
        Self::NAMES[self.index()]
    }

    /// The scale c (Φ for DCS).
    pub fn scale(&self) -> f64 {
        match *self {
            Self::Huber(c)
            | Self::Cauchy(c)
            | Self::Tukey(c)
            | Self::GemanMcClure(c)
            | Self::Welsch(c)
            | Self::Fair(c)
            | Self::Dcs(c) => c,
        }
    }

    fn index(&self) -> usize {
        match self {
            Self::Huber(_) => 0,
            Self::Cauchy(_) => 1,
            Self::Tukey(_) => 2,
            Self::GemanMcClure(_) => 3,
            Self::Welsch(_) => 4,
            Self::Fair(_) => 5,
            Self::Dcs(_) => 6,
        }
    }
}

impl std::str::FromStr for NamedKernel {
    type Err = KernelParseError;
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let (name, scale) = text.split_once(':').unwrap_or((text, ""));
        let name = name.trim().to_ascii_lowercase();
        let kind = Self::NAMES
            .iter()
            .position(|&n| n == name)
            .ok_or_else(|| KernelParseError::UnknownName(name.clone()))?;
        let c: f64 = scale
            .trim()
            .parse()
            .ok()
            .filter(|c: &f64| c.is_finite() && *c > 0.0)
            .ok_or_else(|| KernelParseError::BadScale(text.to_string()))?;
        Ok([
            Self::Huber,
            Self::Cauchy,
            Self::Tukey,
            Self::GemanMcClure,
            Self::Welsch,
            Self::Fair,
            Self::Dcs,
        ][kind](c))
    }
}

impl std::fmt::Display for NamedKernel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}", self.name(), self.scale())
    }
}

impl RobustKernel for NamedKernel {
    fn evaluate(&self, s: f64) -> [f64; 3] {
        match *self {
            Self::Huber(c) => Huber(c).evaluate(s),
            Self::Cauchy(c) => Cauchy(c).evaluate(s),
            Self::Tukey(c) => Tukey(c).evaluate(s),
            Self::GemanMcClure(c) => GemanMcClure(c).evaluate(s),
            Self::Welsch(c) => Welsch(c).evaluate(s),
            Self::Fair(c) => Fair(c).evaluate(s),
            Self::Dcs(c) => Dcs(c).evaluate(s),
        }
    }
}

/// Applies the Triggs correction for kernel values `[ρ, ρ', ρ'']` at s = ‖r‖² to a residual and its
/// Jacobian (m rows, column-major), so that plain Gauss-Newton on the corrected pair has the
/// robustified cost's gradient ρ' Jᵀr (Triggs et al. 2000, sec. 4.3).
///
/// Where ρ'' > 0 the corrected Hessian approximation is ρ' JᵀJ + 2ρ'' Jᵀr rᵀJ, the second-order
/// model of ½ρ(‖r‖²). Where ρ'' ≤ 0, which is everywhere for the outlier-robust kernels
/// (Huber, Cauchy, Tukey, DCS, ...), it is ρ' JᵀJ alone: iteratively reweighted least squares, as
/// Ceres' `Corrector` does. Keeping the negative term there would remove the curvature along r,
/// all of it for Huber beyond its kink (2sρ''/ρ' = −1), so an outlier would leave its variables
/// almost unconstrained and LM would spend its iterations on rejected steps (NOTES 49).
pub fn triggs_correct(rho: [f64; 3], residual: &mut [f64], jacobian: Option<&mut [f64]>) {
    let m = residual.len();
    let s: f64 = residual.iter().map(|v| v * v).sum();
    let sqrt_rho1 = rho[1].max(0.0).sqrt();
    let (residual_scale, alpha_sq_norm) = if s == 0.0 || rho[2] <= 0.0 || rho[1] <= 0.0 {
        (sqrt_rho1, 0.0)
    } else {
        // α solves ½α² − α − sρ''/ρ' = 0 (the smaller root), so that J̃ᵀJ̃ = ρ'JᵀJ + 2ρ''Jᵀr rᵀJ.
        // With ρ'' > 0 the discriminant exceeds 1 and α < 0.
        let d = 1.0 + 2.0 * s * rho[2] / rho[1];
        let alpha = 1.0 - d.sqrt();
        (sqrt_rho1 / (1.0 - alpha), alpha / s)
    };
    if residual_scale == 1.0 && alpha_sq_norm == 0.0 && sqrt_rho1 == 1.0 {
        return; // the kernel's quadratic part (an inlier of Huber's): nothing to correct
    }
    if let Some(j) = jacobian {
        let cols = j.len() / m.max(1);
        for c in 0..cols {
            let col = &mut j[c * m..(c + 1) * m];
            if alpha_sq_norm != 0.0 {
                let dot: f64 = col.iter().zip(residual.iter()).map(|(a, b)| a * b).sum();
                for (x, r) in col.iter_mut().zip(residual.iter()) {
                    *x = sqrt_rho1 * (*x - alpha_sq_norm * r * dot);
                }
            } else {
                for x in col.iter_mut() {
                    *x *= sqrt_rho1;
                }
            }
        }
    }
    for r in residual.iter_mut() {
        *r *= residual_scale;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn kernels() -> Vec<Box<dyn RobustKernel>> {
        vec![
            Box::new(Huber(0.7)),
            Box::new(Cauchy(1.3)),
            Box::new(Tukey(2.0)),
            Box::new(GemanMcClure(0.9)),
            Box::new(Welsch(1.1)),
            Box::new(Fair(0.8)),
            Box::new(Dcs(1.5)),
            Box::new(Barron {
                alpha: 1.0,
                scale: 0.6,
            }),
            Box::new(Barron {
                alpha: -2.5,
                scale: 1.2,
            }),
            Box::new(Barron {
                alpha: 0.0,
                scale: 1.0,
            }),
            Box::new(Barron {
                alpha: f64::NEG_INFINITY,
                scale: 1.0,
            }),
            Box::new(Barron {
                alpha: 2.0,
                scale: 1.0,
            }),
            Box::new(Barron {
                alpha: 4.0,
                scale: 0.5,
            }),
        ]
    }

    proptest! {
        #[test]
        fn derivatives_match_central_differences(s in 0.01f64..9.0) {
            for k in kernels() {
                // Keep away from the kinks of Huber, Tukey and DCS, where ρ'' jumps.
                let [_, d1, d2] = k.evaluate(s);
                let h = 1e-6 * s.max(1.0);
                let (p, m) = (k.evaluate(s + h), k.evaluate(s - h));
                let near_kink = [0.49, 4.0, 1.5].iter().any(|&kink| (s - kink).abs() < 2.0 * h);
                if near_kink { continue; }
                prop_assert!((d1 - (p[0] - m[0]) / (2.0 * h)).abs() < 1e-6 * (1.0 + d1.abs()), "{k:?} rho' at {s}");
                prop_assert!((d2 - (p[1] - m[1]) / (2.0 * h)).abs() < 1e-5 * (1.0 + d2.abs()), "{k:?} rho'' at {s}");
            }
        }

        #[test]
        fn kernels_are_non_decreasing_and_bounded_by_least_squares(s in 0.0f64..50.0) {
            for k in kernels() {
                let [rho, d1, _] = k.evaluate(s);
                prop_assert!(d1 >= 0.0, "{k:?}");
                // Every kernel here except Barron with α > 2 grows no faster than s.
                let superquadratic = matches!(format!("{k:?}").as_str(), s if s.contains("alpha: 4.0"));
                if !superquadratic {
                    prop_assert!(rho <= s + 1e-12, "{k:?}: rho({s}) = {rho}");
                }
            }
        }

        #[test]
        fn triggs_correction_gives_the_robust_gradient(r0 in -3.0f64..3.0, r1 in -3.0f64..3.0, j in prop::array::uniform4(-2.0f64..2.0)) {
            for k in kernels() {
                let mut r = [r0, r1];
                let mut jac = j;
                let s = r0 * r0 + r1 * r1;
                let rho = k.evaluate(s);
                triggs_correct(rho, &mut r, Some(&mut jac));
                // The corrected Jᵀr equals ρ'(s) Jᵀr of the original (gradient of ½ρ).
                for c in 0..2 {
                    let corrected = jac[c * 2] * r[0] + jac[c * 2 + 1] * r[1];
                    let expected = rho[1] * (j[c * 2] * r0 + j[c * 2 + 1] * r1);
                    prop_assert!((corrected - expected).abs() < 1e-9 * (1.0 + expected.abs()), "{k:?}");
                }
            }
        }
    }

    #[test]
    fn named_kernels_round_trip_and_bad_names_are_refused() {
        for k in [
            NamedKernel::Huber(1.0),
            NamedKernel::Cauchy(0.5),
            NamedKernel::Tukey(4.685),
            NamedKernel::GemanMcClure(2.0),
            NamedKernel::Welsch(1.5),
            NamedKernel::Fair(0.25),
            NamedKernel::Dcs(3.0),
        ] {
            let back: NamedKernel = k.to_string().parse().unwrap();
            assert_eq!(back, k);
            assert_eq!(back.evaluate(7.0), k.evaluate(7.0));
        }
        assert_eq!("Huber:2".parse(), Ok(NamedKernel::Huber(2.0)));
        assert!(matches!(
            "l2:1".parse::<NamedKernel>(),
            Err(KernelParseError::UnknownName(_))
        ));
        for bad in [
            "huber",
            "huber:",
            "huber:0",
            "huber:-1",
            "huber:nan",
            "huber:inf",
            "huber:x",
        ] {
            assert!(
                matches!(
                    bad.parse::<NamedKernel>(),
                    Err(KernelParseError::BadScale(_))
                ),
                "{bad}"
            );
        }
    }

    #[test]
    fn every_kernel_starts_like_least_squares() {
        for k in kernels() {
            let [rho, d1, _] = k.evaluate(0.0);
            assert!(rho.abs() < 1e-15 && (d1 - 1.0).abs() < 1e-12, "{k:?}");
        }
    }
}
