//! What differs between the minimisers: how a step is chosen with its predicted decrease, when it
//! is taken, and how the damping or trust region follows the outcome. The shared loop is in
//! [`super::Solver`].

use super::context::{Context, Proposal};
use super::dogleg::Dogleg;
use super::{gauss_newton, levenberg_marquardt};
use crate::damping::{LevenbergDamping, MIN_MARQUARDT_MU};
use crate::error::SolveError;
use crate::options::{Algorithm, DampingKind, Options};

/// One minimiser's state across iterations.
pub(super) enum Method {
    /// δ = −H⁻¹g, every finite step taken.
    GaussNewton,
    /// Levenberg-Marquardt: μ, ν and the factorisations retried with more damping.
    Levenberg(LevenbergDamping, usize),
    /// Powell's dogleg.
    Dogleg(Dogleg),
}

impl Method {
    /// The method `opts` names, its damping started from H's largest diagonal `max_diag`;
    /// the dogleg borrows `buffer` for its Gauss-Newton step until [`Self::finish`].
    pub fn new(opts: &Options, max_diag: f64, buffer: &mut Vec<f64>) -> Self {
        match opts.algorithm {
            Algorithm::GaussNewton => Self::GaussNewton,
            Algorithm::LevenbergMarquardt => Self::Levenberg(
                match opts.damping {
                    DampingKind::Identity => LevenbergDamping::new(
                        opts.initial_damping_tau * max_diag.max(f64::MIN_POSITIVE),
                        0.0,
                    ),
                    // μ of Marquardt's damping has no units: floored as Ceres' trust radius is
                    DampingKind::Diagonal => {
                        LevenbergDamping::new(opts.initial_damping_tau, MIN_MARQUARDT_MU)
                    }
                },
                0,
            ),
            Algorithm::Dogleg => Self::Dogleg(Dogleg::new(
                opts.initial_trust_radius,
                std::mem::take(buffer),
            )),
        }
    }

    /// Chooses a step at the current point.
    pub fn propose(&mut self, ctx: Context<'_>, opts: &Options) -> Result<Proposal, SolveError> {
        match self {
            Self::GaussNewton => gauss_newton::propose(ctx),
            Self::Levenberg(lm, retries) => levenberg_marquardt::propose(ctx, opts, lm, retries),
            Self::Dogleg(d) => Ok(d.propose(ctx)),
        }
    }

    /// Whether a step with a finite cost, this gain ratio and predicted decrease is taken.
    pub fn takes(&self, gain: f64, predicted: f64) -> bool {
        match self {
            Self::GaussNewton => true,
            _ => gain > 0.0 && predicted > 0.0,
        }
    }

    /// Follows a taken step of gain ratio `gain` and length `step_norm`.
    pub fn taken(&mut self, gain: f64, step_norm: f64) {
        match self {
            Self::GaussNewton => {}
            Self::Levenberg(lm, _) => lm.taken(gain),
            Self::Dogleg(d) => d.taken(gain, step_norm),
        }
    }

    /// Follows a rejected step; true when the method can make no further progress (`step_floor`
    /// is the step tolerance's length at the current point).
    pub fn rejected(&mut self, step_floor: f64) -> bool {
        match self {
            // a non-finite cost after a Gauss-Newton step: keep the last good point
            Self::GaussNewton => true,
            Self::Levenberg(lm, _) => !lm.rejected(),
            Self::Dogleg(d) => d.rejected(step_floor),
        }
    }

    /// Ends the solve: logs retried factorisations and hands back the dogleg's buffer.
    pub fn finish(self) -> Option<Vec<f64>> {
        match self {
            Self::Levenberg(_, retries) if retries > 0 => {
                tracing::debug!(
                    factor_retries = retries,
                    "damped normal equations not positive definite; retried with more damping"
                );
                None
            }
            Self::Dogleg(d) => Some(d.into_buffer()),
            _ => None,
        }
    }
}
