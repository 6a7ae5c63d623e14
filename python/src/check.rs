//! `check_jacobians`: a residual's Jacobians (built-in, or returned by a Python callable) against
//! central differences on each variable's manifold, for property tests of residuals written in
//! Python.

use crate::arrays::{self, Vector};
use crate::callback::ErrorSlot;
use crate::manifolds;
use crate::problem::residual_from;
use dynamap_solver::{check_jacobians as check, check_sizes, Manifold, Var};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Arc;

/// Compares `residual`'s Jacobians at `values` with central differences (in each tangent
/// direction of each variable's manifold) and returns the worst disagreement: a dict of
/// max_abs_error, max_rel_error (|analytic − numeric| / max(1, |analytic|, |numeric|)),
/// worst_entry (variable, row, column), analytic and numeric.
///
/// `residual` is a built-in `Residual` or a callable returning `(r, [J_k])` as
/// `Problem.add_residual` takes it (then `dim` is its number of rows); `manifolds` names each
/// variable's manifold (default all "euclidean").
#[pyfunction]
#[pyo3(signature = (residual, values, manifolds = None, dim = None))]
pub fn check_jacobians<'py>(
    py: Python<'py>,
    residual: &Bound<'py, PyAny>,
    values: Vec<Vector<'py>>,
    manifolds: Option<Vec<String>>,
    dim: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let values: Vec<Vec<f64>> = values.iter().map(arrays::to_vec).collect();
    let names = manifolds.unwrap_or_else(|| vec!["euclidean".into(); values.len()]);
    if names.len() != values.len() {
        return Err(PyValueError::new_err(format!(
            "{} values and {} manifolds",
            values.len(),
            names.len()
        )));
    }
    let mut points = Vec::with_capacity(values.len());
    let mut spaces: Vec<Box<dyn Manifold>> = Vec::with_capacity(values.len());
    for (k, (v, name)) in values.iter().zip(&names).enumerate() {
        let m = manifolds::by_name(name, v.len())?;
        points.push(
            m.validate(v)
                .map_err(|e| PyValueError::new_err(format!("value {k}: {e}")))?,
        );
        spaces.push(m);
    }
    let errors = Arc::new(ErrorSlot::default());
    let r = residual_from(residual, dim, "analytic", 0, &errors)?;
    if let Some(expected) = r.arity().filter(|&a| a != values.len()) {
        return Err(PyValueError::new_err(format!(
            "the residual takes {expected} variables, {} values were given",
            values.len()
        )));
    }
    let sizes = spaces.iter().map(|m| (m.ambient_dim(), m.tangent_dim()));
    if let Err(e) = check_sizes(r.as_ref(), sizes) {
        return Err(PyValueError::new_err(format!(
            "value {}: the residual expects a variable of {} coordinates and {} tangent \
             directions, and the value's manifold has {} and {} (give its manifold in `manifolds`)",
            e.argument, e.expected.0, e.expected.1, e.got.0, e.got.1
        )));
    }
    let vars: Vec<Var<'_>> = points
        .iter()
        .zip(&spaces)
        .map(|(v, m)| Var {
            value: v,
            manifold: m.as_ref(),
        })
        .collect();
    let c = check(r.as_ref(), &vars);
    if let Some(e) = errors.take() {
        return Err(e);
    }
    let d = PyDict::new(py);
    d.set_item("max_abs_error", c.max_abs_error)?;
    d.set_item("max_rel_error", c.max_rel_error)?;
    d.set_item("worst_entry", c.worst_entry)?;
    d.set_item("analytic", c.analytic)?;
    d.set_item("numeric", c.numeric)?;
    Ok(d)
}
