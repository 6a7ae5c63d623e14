//! Robust kernels given from Python: "NAME:SCALE" (as the command lines take them) or a
//! (name, scale) pair.

use dynamap_solver::robust::NamedKernel;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

/// The kernel `k` names.
pub fn kernel_of(k: &Bound<'_, PyAny>) -> PyResult<NamedKernel> {
    let text = match k.extract::<(String, f64)>() {
        Ok((name, scale)) => format!("{name}:{scale}"),
        Err(_) => k.extract::<String>().map_err(|_| {
            PyTypeError::new_err("kernel: expected 'NAME:SCALE' or a (name, scale) pair")
        })?,
    };
    text.parse::<NamedKernel>()
        .map_err(|e| PyValueError::new_err(e.to_string()))
}

/// An optional kernel.
pub fn optional(k: Option<&Bound<'_, PyAny>>) -> PyResult<Option<NamedKernel>> {
    k.map(kernel_of).transpose()
}
