//! The normal equations the solver forms, written out densely for inspection and tests.

use crate::damping::Damping;
use crate::error::SolveError;
use crate::normal::NormalEquations;
use crate::problem::{Problem, VarId};
use nalgebra::{DMatrix, DVector};

/// The linearisation the solver takes a step from, at a problem's current values: in the tangent
/// coordinates of the free variables (in the order of [`Self::variables`]),
/// `H = J̃ᵀJ̃` and `g = J̃ᵀr̃`, where the residuals and Jacobians carry the robust kernels'
/// correction ([`crate::robust::triggs_correct`]). So `g` is the gradient of the cost
/// ½ Σ ρ(‖rᵢ‖²), and `H` its Gauss-Newton (or, for ρ'' ≤ 0, reweighted) Hessian.
#[derive(Clone, Debug)]
pub struct Linearization {
    /// ½ Σ ρ(‖rᵢ‖²).
    pub cost: f64,
    /// g = J̃ᵀr̃.
    pub gradient: DVector<f64>,
    /// H = J̃ᵀJ̃ (both triangles).
    pub hessian: DMatrix<f64>,
    /// The free variables, whose tangent coordinates follow one another in this order.
    pub variables: Vec<VarId>,
}

/// Forms H and g as [`crate::Solver`] does at the problem's current values, through the same
/// evaluation and block assembly, and returns them dense. Meant for small problems: H takes
/// n² numbers for n unknowns.
pub fn linearize(problem: &Problem) -> Result<Linearization, SolveError> {
    let mut ne = NormalEquations::new(problem)?;
    let cost = ne.evaluate(problem, &problem.values, true);
    if !cost.is_finite() {
        return Err(SolveError::NonFiniteInitialCost(
            ne.first_non_finite().unwrap_or(0),
        ));
    }
    ne.assemble();
    let n = ne.dim();
    let mut hessian = DMatrix::zeros(n, n);
    ne.h().for_each_damped(Damping::None, |r, c, v| {
        hessian[(r, c)] = v;
        hessian[(c, r)] = v;
    });
    Ok(Linearization {
        cost,
        gradient: DVector::from_column_slice(ne.gradient()),
        hessian,
        variables: ne.var_of_block().iter().map(|&v| VarId(v)).collect(),
    })
}
