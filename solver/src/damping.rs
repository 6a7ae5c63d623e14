//! The damping of the normal equations, `(H + μD) δ = −g`, and Levenberg-Marquardt's update of
//! μ (Madsen, Nielsen & Tingleff, *Methods for Non-Linear Least Squares Problems*, 2004, alg.
//! 3.16): μ ← μ max(1/3, 1 − (2ρ − 1)³), ν ← 2 after a step with gain ratio ρ is taken, and
//! μ ← μν, ν ← 2ν after one is rejected. The generic minimiser and the non-rigid warp's own system
//! both use it.

use crate::parallel::dot;

/// How the damping term D is formed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Damping {
    /// None: solve H δ = −g.
    None,
    /// μ I (Levenberg; Madsen, Nielsen & Tingleff 2004).
    Identity(f64),
    /// μ diag(H), each diagonal element clamped to [1e-6 c, 1e32 c] with c its unknown's
    /// damping scale (Marquardt; Ceres' damping: c = (1 + √v₀)², v₀ the element at the start of
    /// the solve).
    Diagonal(f64),
}

impl Damping {
    /// The damped value of a diagonal element `v` of H whose unknown has damping scale 1.
    #[inline]
    pub fn apply(self, v: f64) -> f64 {
        self.apply_scaled(v, 1.0)
    }

    /// The damped value of a diagonal element `v` of H whose unknown has damping scale `scale`
    /// (read by [`Damping::Diagonal`] only).
    #[inline]
    pub fn apply_scaled(self, v: f64, scale: f64) -> f64 {
        match self {
            Damping::None => v,
            Damping::Identity(mu) => v + mu,
            Damping::Diagonal(mu) => v + marquardt(mu, v, scale),
        }
    }
}

impl Damping {
    /// The decrease L(0) − L(δ) = ½ δᵀ(μDδ − g) that the quadratic model predicts for the exact
    /// solution δ of (H + μD) δ = −g; `diagonal` is H's diagonal with each unknown's damping
    /// scale, in the unknowns' order (read only for μ diag(H)).
    pub fn predicted_decrease(
        self,
        step: &[f64],
        gradient: &[f64],
        diagonal: impl Iterator<Item = (f64, f64)>,
    ) -> f64 {
        let damp_term: f64 = match self {
            Damping::None => 0.0,
            Damping::Identity(mu) => mu * dot(step, step),
            Damping::Diagonal(mu) => diagonal
                .zip(step)
                .map(|((h, c), s)| marquardt(mu, h, c) * s * s)
                .sum(),
        };
        0.5 * (damp_term - dot(step, gradient))
    }
}

/// Marquardt's damping of a diagonal element v of H: μ v, v clamped to [1e-6 c, 1e32 c], so
/// that a zero or huge diagonal still gets a usable damping.
///
/// The scale c is (1 + √v₀)², v₀ the element at the start of the solve ([`damping_scale`]), or 1.
/// That is the damping Ceres applies: it scales J's columns by 1 / (1 + √v₀) once, at the first
/// iteration, and clamps the scaled diagonal to [1e-6, 1e32] (`jacobi_scaling`,
/// `min_lm_diagonal`, `max_lm_diagonal`). The floor then follows each unknown's own units: an
/// unknown whose curvature has collapsed since the start (a point running off to infinity
/// behind outliers) keeps a damping of a millionth of its starting curvature, not of one.
#[inline]
fn marquardt(mu: f64, v: f64, scale: f64) -> f64 {
    mu * v.clamp(1e-6 * scale, 1e32 * scale)
}

/// The damping scale (1 + √v₀)² of an unknown whose diagonal element of H is `v0` at the start
/// of the solve (see [`marquardt`]).
#[inline]
pub fn damping_scale(v0: f64) -> f64 {
    let root = 1.0 + v0.max(0.0).sqrt();
    root * root
}

/// The smallest μ of Marquardt's damping: Ceres' largest trust region, 1e16, as 1 / μ.
pub const MIN_MARQUARDT_MU: f64 = 1e-16;

/// Levenberg-Marquardt's damping μ and its growth factor ν, with Nielsen's update.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LevenbergDamping {
    mu: f64,
    nu: f64,
    /// μ never falls below this after a taken step.
    floor: f64,
}

impl LevenbergDamping {
    /// Starts at μ₀ = `mu` with ν = 2; taken steps lower μ to `floor` at most (0 for none).
    pub fn new(mu: f64, floor: f64) -> Self {
        Self { mu, nu: 2.0, floor }
    }

    /// The current μ.
    pub fn mu(&self) -> f64 {
        self.mu
    }

    /// A step with gain ratio ρ was taken: μ ← max(floor, μ max(1/3, 1 − (2ρ − 1)³)), ν ← 2.
    pub fn taken(&mut self, gain: f64) {
        let factor = (1.0f64 / 3.0).max(1.0 - (2.0 * gain - 1.0).powi(3));
        self.mu = (self.mu * factor).max(self.floor);
        self.nu = 2.0;
    }

    /// A step was rejected (or H + μD could not be factorised): μ ← μν, ν ← 2ν. Returns whether
    /// μ is still usable (see [`Self::usable`]).
    pub fn rejected(&mut self) -> bool {
        self.mu *= self.nu;
        self.nu *= 2.0;
        self.usable()
    }

    /// False once μ has grown past 1e300 (or overflowed): no damping finds a better point.
    pub fn usable(&self) -> bool {
        self.mu.is_finite() && self.mu <= 1e300
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nielsen_update_shrinks_on_good_steps_and_doubles_its_growth_on_rejections() {
        let mut d = LevenbergDamping::new(1.0, 0.0);
        d.taken(1.0);
        assert!((d.mu() - 1.0 / 3.0).abs() < 1e-15);
        d.taken(0.5);
        assert!((d.mu() - 1.0 / 3.0).abs() < 1e-15, "ρ = ½ leaves μ");
        assert!(d.rejected() && (d.mu() - 2.0 / 3.0).abs() < 1e-15);
        assert!(
            d.rejected() && (d.mu() - 8.0 / 3.0).abs() < 1e-15,
            "ν doubled"
        );
        d.taken(0.0);
        assert!(
            (d.mu() - 16.0 / 3.0).abs() < 1e-12,
            "ρ = 0 doubles μ, ν back to 2"
        );
        // a floor stops the good steps' shrinking (Marquardt's μ at Ceres' largest radius)
        let mut d = LevenbergDamping::new(1e-15, MIN_MARQUARDT_MU);
        d.taken(1.0);
        d.taken(1.0);
        d.taken(1.0);
        assert_eq!(d.mu(), MIN_MARQUARDT_MU);
        let mut d = LevenbergDamping::new(3e299, 0.0);
        assert!(d.rejected());
        assert!(!d.rejected(), "past 1e300 the damping is exhausted");
    }

    #[test]
    fn predicted_decrease_matches_the_model_for_the_exact_step() {
        // H = diag(2, 8), g = (−2, 4): δ solves (H + μD) δ = −g; L(0) − L(δ) = −gᵀδ − ½ δᵀHδ
        let (h, g) = ([2.0, 8.0], [-2.0, 4.0]);
        for d in [
            Damping::None,
            Damping::Identity(0.5),
            Damping::Diagonal(0.5),
        ] {
            let step: Vec<f64> = (0..2).map(|i| -g[i] / d.apply(h[i])).collect();
            let model =
                -dot(&g, &step) - 0.5 * (0..2).map(|i| h[i] * step[i] * step[i]).sum::<f64>();
            let p = d.predicted_decrease(&step, &g, h.iter().map(|&v| (v, 1.0)));
            assert!((p - model).abs() < 1e-12, "{d:?}: {p} against {model}");
        }
    }
}
