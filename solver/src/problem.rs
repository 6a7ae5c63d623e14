//! The problem: variables on manifolds and the residual blocks that tie them together.

use crate::error::ProblemError;
use crate::manifold::Manifold;
use crate::residual::{Jacobians, Residual, Var};
use crate::robust::{triggs_correct, RobustKernel};
use smallvec::SmallVec;
use std::sync::atomic::{AtomicU64, Ordering};

/// Handle of a variable in a [`Problem`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct VarId(pub(crate) usize);

/// Handle of a residual block in a [`Problem`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ResidualId(pub(crate) usize);

impl VarId {
    /// The variable's index in its problem, in the order it was added (the number errors and
    /// diagnostics name it by).
    pub fn index(self) -> usize {
        self.0
    }
}

impl ResidualId {
    /// The residual block's index in its problem, in the order it was added (the number
    /// [`crate::Summary::non_finite_block`] names it by).
    pub fn index(self) -> usize {
        self.0
    }
}

pub(crate) struct Variable {
    pub offset: usize,
    /// The manifold's ambient dimension (kept here: evaluation reads it for every block).
    pub ambient: usize,
    pub manifold: Box<dyn Manifold>,
    pub fixed: bool,
    /// Per-coordinate bounds (Euclidean variables only), boxed: most variables have none, and a
    /// 1 M-variable problem keeps 8 bytes for each instead of 48.
    pub bounds: Option<Box<CoordinateBounds>>,
}

/// Lower and upper bounds of each coordinate of a variable.
pub(crate) struct CoordinateBounds {
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
}

pub(crate) struct ResidualBlock {
    pub residual: Box<dyn Residual>,
    pub kernel: Option<Box<dyn RobustKernel>>,
    pub vars: SmallVec<[usize; 4]>,
    /// Tangent dimension of each variable, the column counts of the Jacobian blocks.
    pub cols: SmallVec<[usize; 4]>,
}

/// A non-linear least-squares problem `min ½ Σ_i ρ_i(‖r_i(x)‖²)` over variables on manifolds.
///
/// ```
/// use dynamap_solver::{Euclidean, Problem, Solver, Options, AutoDiff, CostFunctor, Real};
/// // minimise (x - 3)² + (y + x)²
/// struct F;
/// impl CostFunctor for F {
///     fn parameter_sizes(&self) -> &[usize] { &[2] }
///     fn evaluate<T: Real>(&self, p: &[&[T]], r: &mut [T]) {
///         r[0] = p[0][0] - 3.0;
///         r[1] = p[0][1] + p[0][0];
///     }
/// }
/// let mut problem = Problem::new();
/// let x = problem.add_variable(&[0.0, 0.0], Euclidean::<2>).unwrap();
/// problem.add_residual(AutoDiff::<_, 2, 2>::new(F), &[x]).unwrap();
/// let summary = Solver::new(Options::default()).solve(&mut problem).unwrap();
/// assert!(summary.final_cost < 1e-20);
/// assert!((problem.value(x)[1] + 3.0).abs() < 1e-10);
/// ```
pub struct Problem {
    /// Unique per problem, so a [`crate::Solver`] knows whose structure it cached.
    pub(crate) id: u64,
    pub(crate) values: Vec<f64>,
    pub(crate) variables: Vec<Variable>,
    pub(crate) blocks: Vec<ResidualBlock>,
    /// Bumped whenever the sparsity structure changes (variables, residuals, fixed flags).
    pub(crate) structure_version: u64,
}

impl Default for Problem {
    fn default() -> Self {
        static NEXT: AtomicU64 = AtomicU64::new(1);
        Self {
            id: NEXT.fetch_add(1, Ordering::Relaxed),
            values: Vec::new(),
            variables: Vec::new(),
            blocks: Vec::new(),
            structure_version: 0,
        }
    }
}

impl Problem {
    /// An empty problem.
    pub fn new() -> Self {
        Self::default()
    }

    /// Reserves room for `variables` more variables and `blocks` more residual blocks, so that
    /// building a large problem does not leave up to twice the memory it needs.
    pub fn reserve(&mut self, variables: usize, blocks: usize) {
        self.variables.reserve_exact(variables);
        self.blocks.reserve_exact(blocks);
    }

    /// Adds a variable with initial value `value` (ambient coordinates) on `manifold`.
    pub fn add_variable(
        &mut self,
        value: &[f64],
        manifold: impl Manifold + 'static,
    ) -> Result<VarId, ProblemError> {
        self.add_variable_boxed(value, Box::new(manifold))
    }

    /// Adds a variable whose manifold is already boxed.
    pub fn add_variable_boxed(
        &mut self,
        value: &[f64],
        manifold: Box<dyn Manifold>,
    ) -> Result<VarId, ProblemError> {
        let id = self.variables.len();
        let v = manifold
            .validate(value)
            .map_err(|reason| ProblemError::InvalidValue {
                variable: id,
                reason,
            })?;
        let offset = self.values.len();
        self.values.extend_from_slice(&v);
        self.variables.push(Variable {
            offset,
            ambient: manifold.ambient_dim(),
            manifold,
            fixed: false,
            bounds: None,
        });
        self.structure_version += 1;
        Ok(VarId(id))
    }

    fn check(&self, v: VarId) -> Result<&Variable, ProblemError> {
        self.variables
            .get(v.0)
            .ok_or(ProblemError::UnknownVariable(v.0))
    }

    /// Holds a variable constant (or frees it again).
    pub fn set_fixed(&mut self, v: VarId, fixed: bool) -> Result<(), ProblemError> {
        self.check(v)?;
        if self.variables[v.0].fixed != fixed {
            self.variables[v.0].fixed = fixed;
            self.structure_version += 1;
        }
        Ok(())
    }

    /// Bounds each coordinate of a Euclidean variable to `[lower_i, upper_i]` (use ±∞ for a side
    /// without a bound). The minimisers keep every iterate inside: a damped step that would leave
    /// the box is replaced by the solution of the box-constrained quadratic model (solved with
    /// Clarabel), and Levenberg-Marquardt and Gauss-Newton honour the bounds exactly. The current
    /// value must lie inside.
    pub fn set_bounds(
        &mut self,
        v: VarId,
        lower: &[f64],
        upper: &[f64],
    ) -> Result<(), ProblemError> {
        let var = self.check(v)?;
        let n = var.manifold.ambient_dim();
        let invalid = |reason: String| ProblemError::InvalidValue {
            variable: v.0,
            reason,
        };
        if !var.manifold.is_euclidean() {
            return Err(invalid(
                "bounds apply to Euclidean variables only".to_string(),
            ));
        }
        if lower.len() != n || upper.len() != n {
            return Err(invalid(format!(
                "bounds need {n} lower and {n} upper values, got {} and {}",
                lower.len(),
                upper.len()
            )));
        }
        let value = self.value(v);
        for i in 0..n {
            if lower[i].is_nan() || upper[i].is_nan() || lower[i] > upper[i] {
                return Err(invalid(format!(
                    "coordinate {i}: bounds [{}, {}] are not an interval",
                    lower[i], upper[i]
                )));
            }
            if value[i] < lower[i] || value[i] > upper[i] {
                return Err(invalid(format!(
                    "coordinate {i}: value {} lies outside its bounds [{}, {}]",
                    value[i], lower[i], upper[i]
                )));
            }
        }
        let var = &mut self.variables[v.0];
        let first = var.bounds.is_none();
        var.bounds = Some(Box::new(CoordinateBounds {
            lower: lower.to_vec(),
            upper: upper.to_vec(),
        }));
        if first {
            // a Schur solver lays out H whole once some variable is bounded (NOTES 75)
            self.structure_version += 1;
        }
        Ok(())
    }

    /// The bounds of a variable, if it has any.
    pub fn bounds(&self, v: VarId) -> Option<(&[f64], &[f64])> {
        let b = self.variables[v.0].bounds.as_deref()?;
        Some((b.lower.as_slice(), b.upper.as_slice()))
    }

    /// Whether a variable is held constant.
    pub fn is_fixed(&self, v: VarId) -> bool {
        self.variables[v.0].fixed
    }

    /// The current value of a variable (ambient coordinates).
    ///
    /// # Panics
    /// If `v` was not issued by this problem.
    pub fn value(&self, v: VarId) -> &[f64] {
        let var = &self.variables[v.0];
        &self.values[var.offset..var.offset + var.manifold.ambient_dim()]
    }

    /// Sets the value of a variable, checked against its manifold.
    pub fn set_value(&mut self, v: VarId, value: &[f64]) -> Result<(), ProblemError> {
        let var = self.check(v)?;
        let checked =
            var.manifold
                .validate(value)
                .map_err(|reason| ProblemError::InvalidValue {
                    variable: v.0,
                    reason,
                })?;
        if let Some(b) = &var.bounds {
            for (i, x) in checked.iter().enumerate() {
                if *x < b.lower[i] || *x > b.upper[i] {
                    return Err(ProblemError::InvalidValue {
                        variable: v.0,
                        reason: format!(
                            "coordinate {i}: value {x} lies outside its bounds [{}, {}]",
                            b.lower[i], b.upper[i]
                        ),
                    });
                }
            }
        }
        let off = var.offset;
        self.values[off..off + checked.len()].copy_from_slice(&checked);
        Ok(())
    }

    /// The manifold of a variable.
    pub fn manifold(&self, v: VarId) -> &dyn Manifold {
        self.variables[v.0].manifold.as_ref()
    }

    /// Number of variables.
    pub fn num_variables(&self) -> usize {
        self.variables.len()
    }

    /// Number of residual blocks.
    pub fn num_residuals(&self) -> usize {
        self.blocks.len()
    }

    /// Adds a residual block over `vars`, with plain least-squares cost ½‖r‖².
    pub fn add_residual(
        &mut self,
        residual: impl Residual + 'static,
        vars: &[VarId],
    ) -> Result<ResidualId, ProblemError> {
        self.add_block(Box::new(residual), None, vars)
    }

    /// Adds a residual block with a robust kernel, cost ½ρ(‖r‖²).
    pub fn add_robust_residual(
        &mut self,
        residual: impl Residual + 'static,
        kernel: impl RobustKernel + 'static,
        vars: &[VarId],
    ) -> Result<ResidualId, ProblemError> {
        self.add_block(Box::new(residual), Some(Box::new(kernel)), vars)
    }

    /// Adds an already boxed residual, with an optional kernel.
    pub fn add_block(
        &mut self,
        residual: Box<dyn Residual>,
        kernel: Option<Box<dyn RobustKernel>>,
        vars: &[VarId],
    ) -> Result<ResidualId, ProblemError> {
        if let Some(expected) = residual.arity() {
            if expected != vars.len() {
                return Err(ProblemError::Arity {
                    expected,
                    got: vars.len(),
                });
            }
        }
        for (i, v) in vars.iter().enumerate() {
            self.check(*v)?;
            if vars[..i].contains(v) {
                return Err(ProblemError::DuplicateVariable(v.0));
            }
        }
        let ids: SmallVec<[usize; 4]> = vars.iter().map(|v| v.0).collect();
        self.check_sizes(residual.as_ref(), &ids)?;
        let cols = vars
            .iter()
            .map(|v| self.variables[v.0].manifold.tangent_dim())
            .collect();
        self.blocks.push(ResidualBlock {
            residual,
            kernel,
            vars: ids,
            cols,
        });
        self.structure_version += 1;
        Ok(ResidualId(self.blocks.len() - 1))
    }

    /// Refuses variables whose sizes differ from those `residual` declares.
    fn check_sizes(&self, residual: &dyn Residual, vars: &[usize]) -> Result<(), ProblemError> {
        let sizes = vars.iter().map(|&v| {
            let m = &self.variables[v].manifold;
            (m.ambient_dim(), m.tangent_dim())
        });
        crate::residual::check_sizes(residual, sizes).map_err(|e| ProblemError::VariableSize {
            variable: vars[e.argument],
            argument: e.argument,
            expected: e.expected,
            got: e.got,
        })
    }

    /// Replaces block `r`'s residual with another of the same size over the same variables (new
    /// data, same structure: the next ICP correspondences, a new regulariser weight). The sparsity
    /// of the normal equations is unchanged, so a [`crate::Solver`] keeps its symbolic
    /// factorisation and buffers for this problem.
    pub fn replace_residual(
        &mut self,
        r: ResidualId,
        residual: Box<dyn Residual>,
    ) -> Result<(), ProblemError> {
        let block = self
            .blocks
            .get_mut(r.0)
            .ok_or(ProblemError::UnknownResidual(r.0))?;
        if residual.dim() != block.residual.dim() {
            return Err(ProblemError::Dimension {
                block: r.0,
                expected: block.residual.dim(),
                got: residual.dim(),
            });
        }
        if let Some(expected) = residual.arity() {
            if expected != block.vars.len() {
                return Err(ProblemError::Arity {
                    expected,
                    got: block.vars.len(),
                });
            }
        }
        self.check_sizes(residual.as_ref(), &self.blocks[r.0].vars)?;
        self.blocks[r.0].residual = residual;
        Ok(())
    }

    /// Replaces block `r`'s robust kernel (or removes it with `None`): the weights change, the
    /// sparsity does not, so a [`crate::Solver`] keeps its symbolic factorisation and buffers
    /// for this problem (a graduated schedule of kernels solved one after another).
    pub fn set_kernel(
        &mut self,
        r: ResidualId,
        kernel: Option<Box<dyn RobustKernel>>,
    ) -> Result<(), ProblemError> {
        let block = self
            .blocks
            .get_mut(r.0)
            .ok_or(ProblemError::UnknownResidual(r.0))?;
        block.kernel = kernel;
        Ok(())
    }

    /// The variables of a residual block.
    pub fn residual_variables(&self, r: ResidualId) -> Vec<VarId> {
        self.blocks[r.0].vars.iter().map(|&v| VarId(v)).collect()
    }

    pub(crate) fn vars_of<'a>(
        &'a self,
        block: &ResidualBlock,
        values: &'a [f64],
    ) -> SmallVec<[Var<'a>; 4]> {
        block
            .vars
            .iter()
            .map(|&v| {
                let var = &self.variables[v];
                Var {
                    value: &values[var.offset..var.offset + var.ambient],
                    manifold: var.manifold.as_ref(),
                }
            })
            .collect()
    }

    /// Evaluates block `k` at `values`: writes the (kernel-corrected, when `jac` is given) residual
    /// and returns the block's cost ½ρ(‖r‖²).
    pub(crate) fn evaluate_block(
        &self,
        k: usize,
        values: &[f64],
        r: &mut [f64],
        jac: Option<&mut [f64]>,
    ) -> f64 {
        let block = &self.blocks[k];
        let vars = self.vars_of(block, values);
        let m = r.len();
        match jac {
            Some(j) => {
                block
                    .residual
                    .evaluate(&vars, r, Some(&mut Jacobians::new(j, m, &block.cols)));
                let s: f64 = r.iter().map(|v| v * v).sum();
                // A point where the Jacobian is undefined is no more usable than one where the
                // residual is: the block reports a non-finite cost, so the step is rejected.
                if !j.iter().all(|v| v.is_finite()) {
                    return f64::NAN;
                }
                match &block.kernel {
                    Some(kernel) => {
                        let rho = kernel.evaluate(s);
                        triggs_correct(rho, r, Some(j));
                        0.5 * rho[0]
                    }
                    None => 0.5 * s,
                }
            }
            None => {
                block.residual.evaluate(&vars, r, None);
                let s: f64 = r.iter().map(|v| v * v).sum();
                match &block.kernel {
                    Some(kernel) => 0.5 * kernel.evaluate(s)[0],
                    None => 0.5 * s,
                }
            }
        }
    }

    /// The residual vector of one block at the current values (before any kernel).
    pub fn residual_value(&self, r: ResidualId) -> Vec<f64> {
        let block = &self.blocks[r.0];
        let mut out = vec![0.0; block.residual.dim()];
        let vars = self.vars_of(block, &self.values);
        block.residual.evaluate(&vars, &mut out, None);
        out
    }

    /// The cost ½ Σ ρ(‖r_i‖²) at the current values, summed in block order.
    pub fn cost(&self) -> f64 {
        let mut r = Vec::new();
        let mut total = 0.0;
        for k in 0..self.blocks.len() {
            r.resize(self.blocks[k].residual.dim(), 0.0);
            total += self.evaluate_block(k, &self.values, &mut r, None);
        }
        total
    }
}
