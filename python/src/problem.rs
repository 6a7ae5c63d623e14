//! `Problem`: variables on manifolds and residual blocks, solved in place.
//!
//! The cost is `½ Σ_i ρ_i(‖r_i(x_i1, …, x_ik)‖²)` with each `x_j` on its manifold and moved by
//! `x ⊞ δ = x Exp(δ)` (the library's model; see the solver crate's documentation).

use crate::arrays::{self, Vector};
use crate::builtin::{Residual, Shared};
use crate::callback::{self, Analytic, Callable, ErrorSlot};
use crate::errors;
use crate::kernels;
use crate::manifolds;
use crate::options::{Options, Summary};
use dynamap_solver::{
    IterationSummary, Problem as Core, Residual as CoreResidual, ResidualId, RobustKernel, Solver,
    VarId,
};
use numpy::PyArray1;
use pyo3::exceptions::{PyIndexError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use std::ops::ControlFlow;
use std::sync::Arc;

/// A least-squares problem: add variables (numpy arrays on a manifold) and residual blocks (the
/// built-in ones, or Python callables), then `solve`. Variables and residual blocks are named by
/// the integers `add_variable` and `add_residual` return.
#[pyclass(module = "dynamap")]
pub struct Problem {
    core: Core,
    vars: Vec<VarId>,
    blocks: Vec<ResidualId>,
    errors: Arc<ErrorSlot>,
    /// Residual blocks written in Python: the problem is then evaluated on the calling thread.
    python_blocks: usize,
}

/// The residual object for block `block`: a built-in one (shared), or a Python callable whose
/// errors go to `errors`, differentiated as `jacobians` says ("analytic" or "numeric").
pub fn residual_from(
    residual: &Bound<'_, PyAny>,
    dim: Option<usize>,
    jacobians: &str,
    block: usize,
    errors: &Arc<ErrorSlot>,
) -> PyResult<Box<dyn CoreResidual>> {
    if let Ok(r) = residual.cast::<Residual>() {
        return Ok(Box::new(Shared(r.get().inner.clone())));
    }
    if !residual.is_callable() {
        return Err(PyTypeError::new_err(
            "residual: expected a dynamap.Residual or a callable",
        ));
    }
    let dim = match dim {
        Some(d) if d > 0 => d,
        Some(_) => {
            return Err(PyValueError::new_err(
                "dim=0: a residual written in Python has at least one row",
            ))
        }
        None => {
            return Err(PyValueError::new_err(
                "a residual written in Python needs dim (its number of rows)",
            ))
        }
    };
    let c = Callable::new(residual.clone().unbind(), dim, block, errors.clone());
    Ok(match jacobians {
        "analytic" => Box::new(Analytic(c)),
        "numeric" => Box::new(callback::numeric(c)),
        other => {
            return Err(PyValueError::new_err(format!(
                "jacobians='{other}': expected 'analytic' (the callable returns them) or \
                 'numeric' (central differences)"
            )))
        }
    })
}

impl Problem {
    fn var(&self, v: usize) -> PyResult<VarId> {
        self.vars.get(v).copied().ok_or_else(|| {
            PyIndexError::new_err(format!(
                "variable {v} does not exist (the problem has {})",
                self.vars.len()
            ))
        })
    }

    /// The observer of a solve: stops on a Python residual's error or on Ctrl-C, and prints each
    /// iteration when `verbose`.
    fn observer(
        &self,
        verbose: bool,
    ) -> impl FnMut(&IterationSummary) -> ControlFlow<()> + Send + 'static {
        let errors = self.errors.clone();
        move |it: &IterationSummary| {
            Python::attach(|py| {
                if let Err(e) = py.check_signals() {
                    errors.keep_first(e);
                } else if verbose {
                    let row = match it.iteration {
                        0 => format!("{}\n{it}", IterationSummary::HEADER),
                        _ => it.to_string(),
                    };
                    if let Err(e) = py
                        .import("builtins")
                        .and_then(|b| b.call_method1("print", (row,)))
                    {
                        errors.keep_first(e);
                    }
                }
            });
            match errors.is_set() {
                true => ControlFlow::Break(()),
                false => ControlFlow::Continue(()),
            }
        }
    }
}

#[pymethods]
impl Problem {
    #[new]
    fn py_new() -> Self {
        Self {
            core: Core::new(),
            vars: Vec::new(),
            blocks: Vec::new(),
            errors: Arc::default(),
            python_blocks: 0,
        }
    }

    /// Adds a variable with initial value `value` on `manifold` ("euclidean", "so2", "se2",
    /// "so3", "se3" or "quaternion"); returns its index.
    #[pyo3(signature = (value, manifold = "euclidean"))]
    fn add_variable(&mut self, value: Vector<'_>, manifold: &str) -> PyResult<usize> {
        let value = arrays::to_vec(&value);
        let m = manifolds::by_name(manifold, value.len())?;
        let id = self
            .core
            .add_variable_boxed(&value, m)
            .map_err(errors::problem)?;
        self.vars.push(id);
        Ok(self.vars.len() - 1)
    }

    /// The variable's current value (a new array, ambient coordinates).
    fn value<'py>(&self, py: Python<'py>, variable: usize) -> PyResult<Bound<'py, PyArray1<f64>>> {
        Ok(arrays::vector(py, self.core.value(self.var(variable)?)))
    }

    /// Sets the variable's value (checked against its manifold; quaternions are normalised).
    fn set_value(&mut self, variable: usize, value: Vector<'_>) -> PyResult<()> {
        let v = self.var(variable)?;
        self.core
            .set_value(v, &arrays::to_vec(&value))
            .map_err(errors::problem)
    }

    /// Holds the variable constant (or frees it again with `fixed=False`).
    #[pyo3(signature = (variable, fixed = true))]
    fn set_fixed(&mut self, variable: usize, fixed: bool) -> PyResult<()> {
        let v = self.var(variable)?;
        self.core.set_fixed(v, fixed).map_err(errors::problem)
    }

    /// True when the variable is held constant.
    fn is_fixed(&self, variable: usize) -> PyResult<bool> {
        Ok(self.core.is_fixed(self.var(variable)?))
    }

    /// Box constraints `lower ≤ x ≤ upper` on a Euclidean variable (±inf for none), honoured at
    /// every iterate.
    fn set_bounds(
        &mut self,
        variable: usize,
        lower: Vector<'_>,
        upper: Vector<'_>,
    ) -> PyResult<()> {
        let v = self.var(variable)?;
        let (lo, hi) = (arrays::to_vec(&lower), arrays::to_vec(&upper));
        self.core.set_bounds(v, &lo, &hi).map_err(errors::problem)
    }

    /// Adds a residual block over `variables`; returns its index.
    ///
    /// `residual` is a built-in `Residual` (`between_se3(...)`, `bal_reprojection(...)`, ...) or
    /// a Python callable `f(*values)` of the variables' values (numpy arrays). A callable
    /// returns `(r, [J_1, ..., J_k])` with `J_k = ∂r/∂δ_k` of shape `(dim, tangent_dim_k)` when
    /// `jacobians="analytic"` (the default), or `r` alone when `jacobians="numeric"` (central
    /// differences on each manifold: slower and less exact, an explicit choice); `dim` is its
    /// number of rows. `kernel` is a robust kernel as "NAME:SCALE" or (name, scale): huber,
    /// cauchy, tukey, geman-mcclure, welsch, fair or dcs.
    #[pyo3(signature = (residual, variables, kernel = None, dim = None, jacobians = "analytic"))]
    fn add_residual(
        &mut self,
        residual: &Bound<'_, PyAny>,
        variables: Vec<usize>,
        kernel: Option<&Bound<'_, PyAny>>,
        dim: Option<usize>,
        jacobians: &str,
    ) -> PyResult<usize> {
        let vars = variables
            .iter()
            .map(|&v| self.var(v))
            .collect::<PyResult<Vec<_>>>()?;
        let block = self.blocks.len();
        let python = residual.cast::<Residual>().is_err();
        let r = residual_from(residual, dim, jacobians, block, &self.errors)?;
        let kernel = kernels::optional(kernel)?.map(|k| Box::new(k) as Box<dyn RobustKernel>);
        let id = self
            .core
            .add_block(r, kernel, &vars)
            .map_err(errors::problem)?;
        self.blocks.push(id);
        self.python_blocks += usize::from(python);
        Ok(block)
    }

    /// Number of variables.
    #[getter]
    fn num_variables(&self) -> usize {
        self.vars.len()
    }

    /// Number of residual blocks.
    #[getter]
    fn num_residuals(&self) -> usize {
        self.blocks.len()
    }

    /// The cost ½ Σ ρ(‖r_i‖²) at the current values.
    fn cost(&self) -> PyResult<f64> {
        let c = self.core.cost();
        self.raise_kept()?;
        Ok(c)
    }

    /// Block `block`'s residual vector at the current values (before any kernel).
    fn residual<'py>(&self, py: Python<'py>, block: usize) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let id = self.blocks.get(block).copied().ok_or_else(|| {
            PyIndexError::new_err(format!("residual block {block} does not exist"))
        })?;
        let r = self.core.residual_value(id);
        self.raise_kept()?;
        Ok(arrays::vector(py, &r))
    }

    /// Minimises the cost from the current values, which are replaced by the result. Returns
    /// the `Summary`; check `summary.converged` (a solve that stopped at its iteration limit
    /// returns normally, and says so). Raises `SolveError` when the solve cannot proceed, and the
    /// exception of a Python residual that raised. `verbose` prints each iteration's row.
    #[pyo3(signature = (options = None, verbose = false))]
    fn solve(
        &mut self,
        py: Python<'_>,
        options: Option<Options>,
        verbose: bool,
    ) -> PyResult<Summary> {
        let options = options.map_or_else(Default::default, |o| o.core);
        let mut solver = Solver::new(options).with_observer(self.observer(verbose));
        self.errors.take();
        let core = &mut self.core;
        let result = match self.python_blocks {
            0 => py.detach(|| solver.solve(core)),
            _ => callback::on_this_thread(|| solver.solve(core))?,
        };
        self.raise_kept()?;
        result.map(|run| Summary { run }).map_err(errors::solve)
    }

    /// Marginal covariances of these variables at the current values: one `tangent × tangent`
    /// array each, in the tangent coordinates of its manifold (blocks of H⁻¹; GTSAM's
    /// `Marginals`). Raises `SolveError` for a fixed variable or a gauge freedom.
    fn covariance<'py>(
        &self,
        py: Python<'py>,
        variables: Vec<usize>,
    ) -> PyResult<Vec<Bound<'py, numpy::PyArray2<f64>>>> {
        let vars = variables
            .iter()
            .map(|&v| self.var(v))
            .collect::<PyResult<Vec<_>>>()?;
        let core = &self.core;
        let blocks = match self.python_blocks {
            0 => py.detach(|| dynamap_solver::covariance(core, &vars)),
            _ => callback::on_this_thread(|| dynamap_solver::covariance(core, &vars))?,
        }
        .map_err(errors::solve);
        self.raise_kept()?;
        Ok(blocks?.iter().map(|m| arrays::matrix(py, m)).collect())
    }

    fn __repr__(&self) -> String {
        format!(
            "<dynamap.Problem {} variables, {} residual blocks>",
            self.vars.len(),
            self.blocks.len()
        )
    }
}

impl Problem {
    /// Raises the error a Python residual kept (and empties the slot).
    fn raise_kept(&self) -> PyResult<()> {
        match self.errors.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}
