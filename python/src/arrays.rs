//! numpy arrays in and out: vectors and matrices of `f64` read from anything array-like (lists
//! included), and written back as new arrays.

use nalgebra::{DMatrix, SMatrix};
use numpy::{AllowTypeChange, PyArray1, PyArray2, PyArrayLike1, PyArrayLike2, PyArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// A one-dimensional array-like of numbers, converted to `float64` if needed.
pub type Vector<'py> = PyArrayLike1<'py, f64, AllowTypeChange>;
/// A two-dimensional array-like of numbers, converted to `float64` if needed.
pub type Matrix<'py> = PyArrayLike2<'py, f64, AllowTypeChange>;

/// The numbers of a vector, in order.
pub fn to_vec(a: &Vector<'_>) -> Vec<f64> {
    a.as_array().iter().copied().collect()
}

/// The numbers of a vector that must have `n` of them (`what` names it in the error).
pub fn to_fixed<const N: usize>(a: &Vector<'_>, what: &str) -> PyResult<[f64; N]> {
    let v = to_vec(a);
    v.as_slice().try_into().map_err(|_| {
        PyValueError::new_err(format!("{what}: expected {N} numbers, got {}", v.len()))
    })
}

/// An N × N matrix (`what` names it in the error).
pub fn to_square<const N: usize>(m: &Matrix<'_>, what: &str) -> PyResult<SMatrix<f64, N, N>> {
    let a = m.as_array();
    if a.shape() != [N, N] {
        return Err(PyValueError::new_err(format!(
            "{what}: expected a {N} x {N} matrix, got shape {:?}",
            a.shape()
        )));
    }
    Ok(SMatrix::from_fn(|i, j| a[[i, j]]))
}

/// A new vector holding `v`.
pub fn vector<'py>(py: Python<'py>, v: &[f64]) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_slice(py, v)
}

/// A new matrix holding `m` (row-major, as numpy's default).
pub fn matrix<'py>(py: Python<'py>, m: &DMatrix<f64>) -> Bound<'py, PyArray2<f64>> {
    let rows: Vec<Vec<f64>> = m.row_iter().map(|r| r.iter().copied().collect()).collect();
    PyArray2::from_vec2(py, &rows).expect("the rows of a matrix have equal lengths")
}

/// A new `n × k` matrix from `k` numbers per row, laid end to end.
pub fn rows<'py, T: numpy::Element + Copy>(
    py: Python<'py>,
    data: Vec<T>,
    k: usize,
) -> Bound<'py, PyArray2<T>> {
    let n = data.len() / k.max(1);
    PyArray1::from_vec(py, data)
        .reshape([n, k])
        .expect("the data holds n rows of k numbers")
}
