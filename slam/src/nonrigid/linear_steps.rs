//! How each Levenberg-Marquardt step of a warp-field optimisation solves `(H + μI) δ = −g`.

use std::fmt;
use std::str::FromStr;

/// The linear solve of each step ([`super::RegisterParams::linear`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinearSteps {
    /// A new sparse Cholesky factorisation every step: exact, and what a registration run once
    /// uses.
    Factorise,
    /// Conjugate gradients preconditioned by the last factorisation (an earlier step's or
    /// frame's), up to this many iterations, before the system is factorised anew.
    Refine(usize),
    /// Conjugate gradients preconditioned by the inverses of H's 6 × 6 diagonal blocks, up to
    /// this many iterations (fewer once the relative residual reaches 3·10⁻³); nothing is ever
    /// factorised, so a graph that grew costs no new symbolic analysis. The products with H are
    /// taken on a single-precision copy of it (half the memory read). Each iteration starts at
    /// the step the same iteration solved in the last minimisation (the last frame's), where
    /// the quadratic model rates it better than 0. Tracking, which starts each frame at the
    /// last one's field, uses it, as real-time non-rigid systems do (DynamicFusion,
    /// VolumeDeform).
    BlockJacobi(usize),
}

/// What an optimisation's block-Jacobi steps cost and whether they converged: the steps
/// solved, their conjugate-gradient iterations in all, and how many stopped at their iteration
/// cap short of the tolerance (each still a descent direction, but not the step the damped
/// system asks for). Factorised and refined steps are not counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinearEffort {
    /// Block-Jacobi steps solved.
    pub steps: usize,
    /// Their conjugate-gradient iterations (products with H), in all.
    pub iterations: usize,
    /// Steps that reached the iteration cap before the tolerance.
    pub truncated: usize,
}

impl LinearEffort {
    /// Adds another optimisation's effort.
    pub fn add(&mut self, o: &LinearEffort) {
        self.steps += o.steps;
        self.iterations += o.iterations;
        self.truncated += o.truncated;
    }
}

impl fmt::Display for LinearSteps {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Factorise => write!(f, "factorise"),
            Self::Refine(n) => write!(f, "refine:{n}"),
            Self::BlockJacobi(n) => write!(f, "jacobi:{n}"),
        }
    }
}

/// A [`LinearSteps`] that is none of `factorise`, `refine:N` and `jacobi:N` with N ≥ 1.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("linear steps {0:?}: expected factorise, refine:N or jacobi:N with N at least 1")]
pub struct LinearStepsError(String);

impl FromStr for LinearSteps {
    type Err = LinearStepsError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || LinearStepsError(s.to_string());
        if s == "factorise" {
            return Ok(Self::Factorise);
        }
        let (kind, n) = s.split_once(':').ok_or_else(bad)?;
        let n: usize = n.parse().map_err(|_| bad())?;
        match (kind, n) {
            (_, 0) => Err(bad()),
            ("refine", n) => Ok(Self::Refine(n)),
            ("jacobi", n) => Ok(Self::BlockJacobi(n)),
            _ => Err(bad()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_steps_read_back_what_they_print_and_refuse_the_rest() {
        for steps in [
            LinearSteps::Factorise,
            LinearSteps::Refine(4),
            LinearSteps::BlockJacobi(50),
        ] {
            assert_eq!(steps.to_string().parse::<LinearSteps>(), Ok(steps));
        }
        for bad in [
            "",
            "jacobi",
            "jacobi:0",
            "jacobi:-1",
            "refine:x",
            "cholesky:3",
            "factorise:1",
        ] {
            assert!(bad.parse::<LinearSteps>().is_err(), "{bad}");
        }
    }
}
