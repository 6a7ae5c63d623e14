//! Errors of problem construction and solving.

use thiserror::Error;

/// A problem that cannot be built as asked.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ProblemError {
    /// A variable id that this problem never issued.
    #[error("variable {0} does not exist")]
    UnknownVariable(usize),
    /// A value that is not a point of the variable's manifold.
    #[error("variable {variable}: {reason}")]
    InvalidValue {
        /// The variable (or the one being created).
        variable: usize,
        /// Why the value was refused.
        reason: String,
    },
    /// A residual given the wrong number of variables.
    #[error("residual expects {expected} variables, got {got}")]
    Arity {
        /// What the residual declares.
        expected: usize,
        /// What it was given.
        got: usize,
    },
    /// A variable of other sizes than the residual reads (an SE(3) residual given a vector).
    #[error(
        "variable {variable} (the residual's argument {argument}) has {} coordinates and {} tangent \
         directions; the residual expects {} and {}",
        got.0, got.1, expected.0, expected.1
    )]
    VariableSize {
        /// The variable.
        variable: usize,
        /// Its position among the residual's variables.
        argument: usize,
        /// The sizes the residual expects, (ambient, tangent).
        expected: (usize, usize),
        /// The variable's.
        got: (usize, usize),
    },
    /// The same variable passed twice to one residual.
    #[error("variable {0} appears twice in one residual")]
    DuplicateVariable(usize),
    /// A residual block id that this problem never issued.
    #[error("residual block {0} does not exist")]
    UnknownResidual(usize),
    /// A replacement residual whose row count differs from the block it replaces.
    #[error("residual block {block} has {expected} rows; its replacement has {got}")]
    Dimension {
        /// The block being replaced.
        block: usize,
        /// Rows of the block.
        expected: usize,
        /// Rows of the replacement.
        got: usize,
    },
}

/// Why a solve could not proceed.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SolveError {
    /// A free variable that no residual touches: its value is undetermined.
    #[error("variable {0} is touched by no residual (fix it or remove it)")]
    UntouchedVariable(usize),
    /// The normal equations are rank-deficient at the start point.
    #[error("{message}")]
    RankDeficient {
        /// Dimension of the numerical null space.
        nullity: usize,
        /// Variables with the largest share of the null space.
        variables: Vec<usize>,
        /// A sentence naming the cause.
        message: String,
    },
    /// The initial cost is not finite.
    #[error("the cost at the initial point is not finite (residual block {0} is the first non-finite one)")]
    NonFiniteInitialCost(usize),
    /// The box-constrained step could not be computed, or bounds were used where they are not
    /// supported.
    #[error("bounds: {0}")]
    Bounds(String),
    /// A covariance that cannot be computed as asked.
    #[error("covariance: {0}")]
    Covariance(String),
    /// The sparse factorisation could not be set up.
    #[error("linear solver: {0}")]
    LinearSolver(String),
    /// An option outside the values it can take (checked before anything is evaluated, as
    /// Ceres' `Solver::Options::IsValid` does).
    #[error("option {name} = {value} {must}")]
    InvalidOption {
        /// The field of [`crate::Options`].
        name: &'static str,
        /// Its value.
        value: f64,
        /// What it must be, as the end of a sentence ("must be 0 or more").
        must: &'static str,
    },
}
