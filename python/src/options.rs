//! `Options` and `Summary`: the solver's settings and what a solve reports, as Python objects.

use dynamap_solver::{Algorithm, DampingKind, LinearSolverKind, Options as Core, Summary as Run};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The solver's settings (Ceres' `Solver::Options`). Every field is a keyword of the
/// constructor and can be set afterwards; the defaults are the library's.
#[pyclass(module = "dynamap", from_py_object)]
#[derive(Clone)]
pub struct Options {
    pub(crate) core: Core,
}

fn algorithm_name(a: Algorithm) -> &'static str {
    match a {
        Algorithm::LevenbergMarquardt => "levenberg_marquardt",
        Algorithm::GaussNewton => "gauss_newton",
        Algorithm::Dogleg => "dogleg",
    }
}

fn parse_algorithm(name: &str) -> PyResult<Algorithm> {
    Ok(match name {
        "levenberg_marquardt" | "lm" => Algorithm::LevenbergMarquardt,
        "gauss_newton" | "gn" => Algorithm::GaussNewton,
        "dogleg" => Algorithm::Dogleg,
        _ => {
            return Err(PyValueError::new_err(format!(
                "unknown algorithm '{name}': expected levenberg_marquardt, gauss_newton or dogleg"
            )))
        }
    })
}

const LINEAR: [(&str, LinearSolverKind); 7] = [
    ("auto", LinearSolverKind::Auto),
    ("dense", LinearSolverKind::Dense),
    ("sparse", LinearSolverKind::Sparse),
    ("schur", LinearSolverKind::Schur),
    ("schur_dense", LinearSolverKind::SchurDense),
    ("schur_sparse", LinearSolverKind::SchurSparse),
    ("schur_iterative", LinearSolverKind::SchurIterative),
];

fn parse_linear(name: &str) -> PyResult<LinearSolverKind> {
    LINEAR
        .iter()
        .find(|(n, _)| *n == name)
        .map(|&(_, k)| k)
        .ok_or_else(|| {
            let names: Vec<&str> = LINEAR.iter().map(|(n, _)| *n).collect();
            PyValueError::new_err(format!(
                "unknown linear solver '{name}': expected one of {}",
                names.join(", ")
            ))
        })
}

fn parse_damping(name: &str) -> PyResult<DampingKind> {
    Ok(match name {
        "identity" => DampingKind::Identity,
        "diagonal" => DampingKind::Diagonal,
        _ => {
            return Err(PyValueError::new_err(format!(
                "unknown damping '{name}': expected identity (μI) or diagonal (μ diag(H))"
            )))
        }
    })
}

/// A positive finite number, or a clear error naming the option.
fn positive(name: &str, v: f64) -> PyResult<f64> {
    match v > 0.0 && !v.is_nan() {
        true => Ok(v),
        false => Err(PyValueError::new_err(format!(
            "{name} must be positive, got {v}"
        ))),
    }
}

/// A number that is not negative.
fn non_negative(name: &str, v: f64) -> PyResult<f64> {
    match v >= 0.0 {
        true => Ok(v),
        false => Err(PyValueError::new_err(format!(
            "{name} must not be negative, got {v}"
        ))),
    }
}

#[pymethods]
impl Options {
    #[new]
    #[pyo3(signature = (**kwargs))]
    fn py_new(kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        let mut o = Self {
            core: Core::default(),
        };
        if let Some(kw) = kwargs {
            let me = Bound::new(kw.py(), o.clone())?;
            for (k, v) in kw.iter() {
                let key: String = k.extract()?;
                if !Self::FIELDS.contains(&key.as_str()) {
                    return Err(PyValueError::new_err(format!(
                        "Options has no field '{key}' (fields: {})",
                        Self::FIELDS.join(", ")
                    )));
                }
                me.setattr(key.as_str(), v)?;
            }
            o = me.borrow().clone();
        }
        Ok(o)
    }

    /// "levenberg_marquardt" (default), "gauss_newton" or "dogleg".
    #[getter]
    fn algorithm(&self) -> &'static str {
        algorithm_name(self.core.algorithm)
    }
    #[setter]
    fn set_algorithm(&mut self, v: &str) -> PyResult<()> {
        self.core.algorithm = parse_algorithm(v)?;
        Ok(())
    }
    /// Largest number of iterations (default 100).
    #[getter]
    fn max_iterations(&self) -> usize {
        self.core.max_iterations
    }
    #[setter]
    fn set_max_iterations(&mut self, v: usize) {
        self.core.max_iterations = v;
    }
    /// Wall-clock limit in seconds (default: none, inf).
    #[getter]
    fn max_seconds(&self) -> f64 {
        self.core.max_seconds
    }
    #[setter]
    fn set_max_seconds(&mut self, v: f64) -> PyResult<()> {
        self.core.max_seconds = positive("max_seconds", v)?;
        Ok(())
    }
    /// Stop when max |g_i| falls to this (default 1e-10).
    #[getter]
    fn gradient_tolerance(&self) -> f64 {
        self.core.gradient_tolerance
    }
    #[setter]
    fn set_gradient_tolerance(&mut self, v: f64) -> PyResult<()> {
        self.core.gradient_tolerance = non_negative("gradient_tolerance", v)?;
        Ok(())
    }
    /// Stop when ‖δ‖ ≤ tol (‖x‖ + tol) (default 1e-10).
    #[getter]
    fn step_tolerance(&self) -> f64 {
        self.core.step_tolerance
    }
    #[setter]
    fn set_step_tolerance(&mut self, v: f64) -> PyResult<()> {
        self.core.step_tolerance = non_negative("step_tolerance", v)?;
        Ok(())
    }
    /// Stop when an accepted step lowers the cost by less than this fraction (default 1e-10).
    #[getter]
    fn function_tolerance(&self) -> f64 {
        self.core.function_tolerance
    }
    #[setter]
    fn set_function_tolerance(&mut self, v: f64) -> PyResult<()> {
        self.core.function_tolerance = non_negative("function_tolerance", v)?;
        Ok(())
    }
    /// Levenberg-Marquardt's τ: μ₀ = τ max diag(H) with identity damping, τ with diagonal
    /// damping (default 1e-4).
    #[getter]
    fn initial_damping_tau(&self) -> f64 {
        self.core.initial_damping_tau
    }
    #[setter]
    fn set_initial_damping_tau(&mut self, v: f64) -> PyResult<()> {
        self.core.initial_damping_tau = positive("initial_damping_tau", v)?;
        Ok(())
    }
    /// Levenberg-Marquardt's damping: "identity" (μI, default) or "diagonal" (μ diag(H), Ceres').
    #[getter]
    fn damping(&self) -> &'static str {
        match self.core.damping {
            DampingKind::Identity => "identity",
            DampingKind::Diagonal => "diagonal",
        }
    }
    #[setter]
    fn set_damping(&mut self, v: &str) -> PyResult<()> {
        self.core.damping = parse_damping(v)?;
        Ok(())
    }
    /// The dogleg's initial trust-region radius (default 1e4).
    #[getter]
    fn initial_trust_radius(&self) -> f64 {
        self.core.initial_trust_radius
    }
    #[setter]
    fn set_initial_trust_radius(&mut self, v: f64) -> PyResult<()> {
        self.core.initial_trust_radius = positive("initial_trust_radius", v)?;
        Ok(())
    }
    /// "auto" (default: dense up to `dense_threshold` unknowns, sparse above), "dense",
    /// "sparse", "schur" (the reduced system's solver chosen by size and structure),
    /// "schur_dense", "schur_sparse" or "schur_iterative".
    #[getter]
    fn linear_solver(&self) -> &'static str {
        LINEAR
            .iter()
            .find(|(_, k)| *k == self.core.linear_solver)
            .map_or("auto", |(n, _)| n)
    }
    #[setter]
    fn set_linear_solver(&mut self, v: &str) -> PyResult<()> {
        self.core.linear_solver = parse_linear(v)?;
        Ok(())
    }
    /// Unknowns up to which "auto" takes the dense solver (default 200).
    #[getter]
    fn dense_threshold(&self) -> usize {
        self.core.dense_threshold
    }
    #[setter]
    fn set_dense_threshold(&mut self, v: usize) {
        self.core.dense_threshold = v;
    }
    /// Look for a null space (a gauge freedom) before solving (default True).
    #[getter]
    fn check_rank(&self) -> bool {
        self.core.check_rank
    }
    #[setter]
    fn set_check_rank(&mut self, v: bool) {
        self.core.check_rank = v;
    }
    /// Conjugate gradients stop at ‖S y − b‖ ≤ tol ‖b‖ (default 1e-6).
    #[getter]
    fn pcg_tolerance(&self) -> f64 {
        self.core.pcg_tolerance
    }
    #[setter]
    fn set_pcg_tolerance(&mut self, v: f64) -> PyResult<()> {
        self.core.pcg_tolerance = positive("pcg_tolerance", v)?;
        Ok(())
    }
    /// Most conjugate-gradient iterations per step (default 500).
    #[getter]
    fn pcg_max_iterations(&self) -> usize {
        self.core.pcg_max_iterations
    }
    #[setter]
    fn set_pcg_max_iterations(&mut self, v: usize) {
        self.core.pcg_max_iterations = v;
    }

    /// The truncated-Newton forcing η of conjugate gradients (default 0.1; 0 solves to
    /// `pcg_tolerance` alone).
    #[getter]
    fn pcg_forcing(&self) -> f64 {
        self.core.pcg_forcing
    }
    #[setter]
    fn set_pcg_forcing(&mut self, v: f64) -> PyResult<()> {
        self.core.pcg_forcing = non_negative("pcg_forcing", v)?;
        Ok(())
    }

    fn __repr__(&self) -> String {
        let o = &self.core;
        format!(
            "Options(algorithm='{}', max_iterations={}, function_tolerance={:e}, \
             gradient_tolerance={:e}, step_tolerance={:e}, linear_solver='{}', damping='{}')",
            self.algorithm(),
            o.max_iterations,
            o.function_tolerance,
            o.gradient_tolerance,
            o.step_tolerance,
            self.linear_solver(),
            self.damping()
        )
    }
}

impl Options {
    const FIELDS: [&'static str; 15] = [
        "algorithm",
        "max_iterations",
        "max_seconds",
        "gradient_tolerance",
        "step_tolerance",
        "function_tolerance",
        "initial_damping_tau",
        "damping",
        "initial_trust_radius",
        "linear_solver",
        "dense_threshold",
        "check_rank",
        "pcg_tolerance",
        "pcg_max_iterations",
        "pcg_forcing",
    ];
}

/// What a solve reports (Ceres' `Solver::Summary`): costs, why it stopped, each iteration, and
/// where the time went.
#[pyclass(module = "dynamap", frozen)]
pub struct Summary {
    pub(crate) run: Run,
}

#[pymethods]
impl Summary {
    /// Cost ½ Σ ρ(‖r‖²) at the start.
    #[getter]
    fn initial_cost(&self) -> f64 {
        self.run.initial_cost
    }
    /// Cost at the end.
    #[getter]
    fn final_cost(&self) -> f64 {
        self.run.final_cost
    }
    /// Why the solve stopped, in words.
    #[getter]
    fn termination(&self) -> String {
        self.run.termination.to_string()
    }
    /// True when it stopped on a convergence test (gradient, step or function tolerance); False
    /// at the iteration or time limit or when no further decrease was found.
    #[getter]
    fn converged(&self) -> bool {
        self.run.termination.converged()
    }
    /// Iterations performed (the start point not counted).
    #[getter]
    fn num_iterations(&self) -> usize {
        self.run.num_iterations()
    }
    /// One dict per iteration, the start point (iteration 0) first: iteration, cost,
    /// cost_change, gradient_norm, step_norm, damping, accepted, evaluate_seconds,
    /// solve_seconds, total_seconds.
    #[getter]
    fn iterations<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.run
            .iterations
            .iter()
            .map(|it| {
                let d = PyDict::new(py);
                d.set_item("iteration", it.iteration)?;
                d.set_item("cost", it.cost)?;
                d.set_item("cost_change", it.cost_change)?;
                d.set_item("gradient_norm", it.gradient_norm)?;
                d.set_item("step_norm", it.step_norm)?;
                d.set_item("damping", it.damping)?;
                d.set_item("accepted", it.accepted)?;
                d.set_item("evaluate_seconds", it.evaluate_seconds)?;
                d.set_item("solve_seconds", it.solve_seconds)?;
                d.set_item("total_seconds", it.total_seconds)?;
                Ok(d)
            })
            .collect()
    }
    /// Wall-clock seconds of the whole solve.
    #[getter]
    fn total_seconds(&self) -> f64 {
        self.run.total_seconds
    }
    /// Where the time went: setup, evaluate, assemble, factorise and step, in seconds.
    #[getter]
    fn timing<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let t = &self.run.timing;
        let d = PyDict::new(py);
        for (k, v) in [
            ("setup", t.setup),
            ("evaluate", t.evaluate),
            ("assemble", t.assemble),
            ("factorise", t.factorise),
            ("step", t.step),
        ] {
            d.set_item(k, v)?;
        }
        Ok(d)
    }
    /// Unknowns: the tangent dimensions of the free variables.
    #[getter]
    fn unknowns(&self) -> usize {
        self.run.unknowns
    }
    /// The linear solver in use at the end ("dense", "sparse", "schur-dense", ...).
    #[getter]
    fn linear_solver(&self) -> &'static str {
        self.run.linear_solver
    }
    /// Conjugate-gradient iterations over the solve (0 for the exact solvers).
    #[getter]
    fn linear_iterations(&self) -> usize {
        self.run.linear_iterations
    }
    /// Trial steps rejected because a residual returned NaN or an infinity.
    #[getter]
    fn non_finite_steps(&self) -> usize {
        self.run.non_finite_steps
    }
    /// The iteration table with the closing lines, as the command-line tools print it.
    fn table(&self) -> String {
        self.run.table()
    }
    fn __repr__(&self) -> String {
        format!(
            "<dynamap.Summary {} iterations, cost {:.6e} -> {:.6e}, {}>",
            self.run.num_iterations(),
            self.run.initial_cost,
            self.run.final_cost,
            self.run.termination
        )
    }
}
