//! The exceptions the module raises, and the conversions of the library's errors into them.
//!
//! Every error of the library becomes one of these, with the message the command-line tools would
//! print; a Rust panic becomes PyO3's `PanicException` at the call's boundary (never an abort).

use dynamap_solver::{ProblemError as Problem, SolveError as Solve};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::PyErr;

create_exception!(
    _dynamap,
    DynamapError,
    PyException,
    "The base of every error dynamap raises."
);
create_exception!(
    _dynamap,
    InputError,
    DynamapError,
    "A file or array that cannot be read as asked: the message names the file, line or frame."
);
create_exception!(
    _dynamap,
    ProblemError,
    DynamapError,
    "A problem that cannot be built as asked (an unknown variable, a value off its manifold, a \
     residual of the wrong arity)."
);
create_exception!(
    _dynamap,
    SolveError,
    DynamapError,
    "A solve that could not proceed (an untouched variable, a rank-deficient start, a \
     non-finite initial cost, or a residual written in Python that raised)."
);

/// The library's problem error as `ProblemError`.
pub fn problem(e: Problem) -> PyErr {
    ProblemError::new_err(e.to_string())
}

/// The library's solve error as `SolveError`.
pub fn solve(e: Solve) -> PyErr {
    SolveError::new_err(e.to_string())
}

/// Anything displayable that names bad input, as `InputError`.
pub fn input(e: impl std::fmt::Display) -> PyErr {
    InputError::new_err(e.to_string())
}
