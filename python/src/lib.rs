//! # dynamap (Python)
//!
//! The extension module `dynamap._dynamap`, which the Python package `dynamap` re-exports: the
//! solver (`Problem`, `Options`, `Summary`, the built-in residuals and residuals written in
//! Python), g2o pose graphs and BAL problems, dense rigid SLAM and non-rigid registration of
//! meshes and RGB-D frames, with numpy arrays in and out. Build it with maturin (`pip install ./python`); its
//! tests are Python's (`python/tests`, pytest).
//!
//! Modules:
//! - `errors` (the exceptions), `arrays` (numpy conversions), `manifolds` and `kernels` (by
//!   name);
//! - `options` (`Options`, `Summary`), `builtin` (the library's residuals), `callback`
//!   (residuals written in Python), `check` (`check_jacobians`), `problem` (`Problem`);
//! - `posegraph` (`PoseGraph`), `bal` (`BalProblem`), `meshes` (`read_mesh`, `write_mesh`,
//!   `register_meshes`), `frames` (`register_frames`), `slam` (`RigidSlam`, `Sequence`,
//!   `generate_sequence`).

mod arrays;
mod bal;
mod builtin;
mod callback;
mod check;
mod errors;
mod frames;
mod kernels;
mod manifolds;
mod meshes;
mod options;
mod posegraph;
mod problem;
mod slam;

use pyo3::prelude::*;

/// The extension module: every class, function and exception of the package.
#[pymodule]
fn _dynamap(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("DynamapError", py.get_type::<errors::DynamapError>())?;
    m.add("InputError", py.get_type::<errors::InputError>())?;
    m.add("ProblemError", py.get_type::<errors::ProblemError>())?;
    m.add("SolveError", py.get_type::<errors::SolveError>())?;
    m.add_class::<options::Options>()?;
    m.add_class::<options::Summary>()?;
    m.add_class::<problem::Problem>()?;
    m.add_class::<builtin::Residual>()?;
    m.add_class::<posegraph::PoseGraph>()?;
    m.add_class::<bal::BalProblem>()?;
    m.add_function(wrap_pyfunction!(builtin::between_se2, m)?)?;
    m.add_function(wrap_pyfunction!(builtin::between_se3, m)?)?;
    m.add_function(wrap_pyfunction!(builtin::prior_se2, m)?)?;
    m.add_function(wrap_pyfunction!(builtin::prior_se3, m)?)?;
    m.add_function(wrap_pyfunction!(builtin::bal_reprojection, m)?)?;
    m.add_function(wrap_pyfunction!(builtin::point_to_plane, m)?)?;
    m.add_function(wrap_pyfunction!(check::check_jacobians, m)?)?;
    m.add_function(wrap_pyfunction!(posegraph::solve_pose_graph, m)?)?;
    m.add_function(wrap_pyfunction!(bal::solve_bal, m)?)?;
    m.add_class::<slam::RigidSlam>()?;
    m.add_class::<slam::Sequence>()?;
    m.add_function(wrap_pyfunction!(slam::generate_sequence, m)?)?;
    m.add_function(wrap_pyfunction!(meshes::read_mesh_file, m)?)?;
    m.add_function(wrap_pyfunction!(meshes::write_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(meshes::register_meshes, m)?)?;
    m.add_function(wrap_pyfunction!(frames::register_frames, m)?)?;
    Ok(())
}
