//! Manifolds chosen by name, as `Problem.add_variable(value, manifold)` takes them.

use dynamap_solver::{EuclideanDyn, Manifold, UnitQuaternionManifold, SE2, SE3, SO2, SO3};
use pyo3::exceptions::PyValueError;
use pyo3::PyResult;

/// The names `Problem.add_variable` accepts, with the ambient coordinates each stores.
pub const NAMES: &str = "euclidean (Rⁿ, n from the value), so2 ([θ]), se2 ([x, y, θ]), \
     so3 (a 3 x 3 rotation, 9 numbers column-major), se3 ([tx, ty, tz, qx, qy, qz, qw]) or \
     quaternion ([qx, qy, qz, qw])";

/// The manifold called `name`, for a value of `len` coordinates (Rⁿ takes its n from it).
pub fn by_name(name: &str, len: usize) -> PyResult<Box<dyn Manifold>> {
    Ok(match name.to_ascii_lowercase().as_str() {
        "euclidean" | "rn" | "r" => Box::new(EuclideanDyn(len)),
        "so2" => Box::new(SO2),
        "se2" => Box::new(SE2),
        "so3" => Box::new(SO3),
        "se3" => Box::new(SE3),
        "quaternion" | "unit_quaternion" => Box::new(UnitQuaternionManifold),
        other => {
            return Err(PyValueError::new_err(format!(
                "unknown manifold '{other}': expected {NAMES}"
            )))
        }
    })
}
