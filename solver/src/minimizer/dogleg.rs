//! Powell's dogleg (Madsen, Nielsen & Tingleff 2004, alg. 3.21): within a trust region of radius
//! Δ, the Gauss-Newton step if it fits, else the steepest-descent (Cauchy) step cut at Δ, else the
//! point on the segment between them at distance Δ.

use super::context::{Context, Proposal};
use super::gauss_newton::regularised_step;
use crate::normal::NormalEquations;
use crate::parallel::dot;

/// The trust region and the Gauss-Newton step, kept while H is unchanged (after a rejection).
pub(super) struct Dogleg {
    radius: f64,
    gauss_newton: Vec<f64>,
    valid: bool,
}

impl Dogleg {
    /// Starts with radius `radius`; `buffer` is reused for the Gauss-Newton step.
    pub fn new(radius: f64, buffer: Vec<f64>) -> Self {
        Self {
            radius,
            gauss_newton: buffer,
            valid: false,
        }
    }

    /// The dogleg step within the current radius.
    pub fn propose(&mut self, ctx: Context<'_>) -> Proposal {
        let Context {
            ne,
            linear,
            step,
            scratch,
            max_diag,
            ..
        } = ctx;
        if !self.valid {
            regularised_step(ne, linear, max_diag, &mut self.gauss_newton);
            self.valid = true;
        }
        let predicted = dogleg_step(ne, &self.gauss_newton, self.radius, step, scratch);
        Proposal::Step {
            predicted,
            damping: self.radius,
        }
    }

    /// A step was taken: H changes, and the radius grows after a good fit or shrinks after a
    /// poor one.
    pub fn taken(&mut self, gain: f64, step_norm: f64) {
        self.valid = false;
        if gain > 0.75 {
            self.radius = self.radius.max(3.0 * step_norm);
        } else if gain < 0.25 {
            self.radius *= 0.5;
        }
    }

    /// A step was rejected: the radius halves; true once it is below `step_floor` (or 1e-300).
    pub fn rejected(&mut self, step_floor: f64) -> bool {
        self.radius *= 0.5;
        self.radius < 1e-300 || self.radius <= step_floor
    }

    /// The Gauss-Newton buffer, for the next solve.
    pub fn into_buffer(self) -> Vec<f64> {
        self.gauss_newton
    }
}

/// Powell's dogleg step inside `radius` from the Gauss-Newton step `gn`; returns the predicted
/// decrease L(0) − L(δ).
fn dogleg_step(
    ne: &NormalEquations,
    gn: &[f64],
    radius: f64,
    step: &mut [f64],
    hg: &mut [f64],
) -> f64 {
    let g = ne.gradient();
    let g2 = dot(g, g);
    let gn_norm = dot(gn, gn).sqrt();
    if gn_norm <= radius {
        step.copy_from_slice(gn);
    } else {
        let ghg = ne.quadratic(g, hg);
        // Cauchy point: −α g with α = ‖g‖² / gᵀHg.
        let alpha = if ghg > 0.0 {
            g2 / ghg
        } else {
            radius / g2.sqrt()
        };
        let sd_norm = alpha * g2.sqrt();
        if sd_norm >= radius {
            let s = radius / g2.sqrt();
            for (d, gi) in step.iter_mut().zip(g) {
                *d = -s * gi;
            }
        } else {
            blend(gn, g, alpha, g2, radius, step);
        }
    }
    -dot(g, step) - 0.5 * ne.quadratic(step, hg)
}

/// δ = a + β(b − a) with a = −αg, b = δ_gn and ‖δ‖ = radius.
fn blend(gn: &[f64], g: &[f64], alpha: f64, g2: f64, radius: f64, step: &mut [f64]) {
    let (mut ab, mut bb) = (0.0, 0.0);
    for (b, gi) in gn.iter().zip(g) {
        let a = -alpha * gi;
        ab += a * (b - a);
        bb += (b - a) * (b - a);
    }
    let c = alpha * alpha * g2 - radius * radius;
    let root = (ab * ab - bb * c).max(0.0).sqrt();
    let beta = if ab <= 0.0 {
        (-ab + root) / bb
    } else {
        -c / (ab + root)
    };
    for ((d, b), gi) in step.iter_mut().zip(gn).zip(g) {
        let a = -alpha * gi;
        *d = a + beta * (b - a);
    }
}
