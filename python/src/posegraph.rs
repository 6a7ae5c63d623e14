//! Pose graphs from g2o files: read, inspect as numpy arrays, solve as the `pose_graph` tool does,
//! write back.

use crate::arrays::{self, Vector};
use crate::errors;
use crate::kernels;
use crate::options::{Options, Summary};
use dynamap_residuals::pose_graph::{
    self, g2o, g2o::InformationPolicy, init, init::Start, Dimension, Measurement, Pose,
    PoseGraph as Core,
};
use dynamap_solver::lie::{se2, se3};
use dynamap_solver::robust::NamedKernel;
use dynamap_solver::{Manifold, Solver, SE2, SE3};
use nalgebra::DMatrix;
use numpy::PyArray1;
use pyo3::exceptions::{PyUserWarning, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Poses by vertex id: `[x, y, θ]` in 2-D, `[tx, ty, tz, qx, qy, qz, qw]` in 3-D.
type Poses = BTreeMap<usize, Pose>;

/// A pose graph (SE(2) or SE(3)) as read from a g2o file.
#[pyclass(module = "dynamap", frozen)]
pub struct PoseGraph {
    core: Core,
}

/// Poses as a dict of numpy arrays.
fn poses_to_dict<'py>(py: Python<'py>, poses: &Poses) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (id, p) in poses {
        d.set_item(id, arrays::vector(py, &p.coordinates()))?;
    }
    Ok(d)
}

/// A pose from its coordinates, checked (and its quaternion normalised) by the manifold of
/// `dimension`.
fn pose_of(dimension: Dimension, id: usize, v: &[f64]) -> PyResult<Pose> {
    let manifold: &dyn Manifold = match dimension {
        Dimension::Two => &SE2,
        Dimension::Three => &SE3,
    };
    let v = manifold
        .validate(v)
        .map_err(|e| PyValueError::new_err(format!("vertex {id}: {e}")))?;
    Ok(match dimension {
        Dimension::Two => Pose::Se2(se2::from_coordinates(&v)),
        Dimension::Three => Pose::Se3(se3::from_slice(&v)),
    })
}

/// Poses from a dict of arrays (every vertex of the graph must be there).
fn poses_from_dict(graph: &Core, d: &Bound<'_, PyDict>) -> PyResult<Poses> {
    let mut poses = Poses::new();
    for (k, v) in d.iter() {
        let id: usize = k.extract()?;
        let v: Vector<'_> = v.extract()?;
        poses.insert(id, pose_of(graph.dimension, id, &arrays::to_vec(&v))?);
    }
    if let Some((line, v)) = graph.missing_in(&poses).first() {
        return Err(PyValueError::new_err(format!(
            "{}:{line}: vertex {v} has no pose in the dict",
            graph.source
        )));
    }
    Ok(poses)
}

/// The start of a solve by name: "file", "odometry" or "chordal".
fn start_of(init_kind: &str) -> PyResult<Start> {
    match init_kind {
        "file" => Ok(Start::File),
        "odometry" => Ok(Start::Odometry),
        "chordal" => Ok(Start::Chordal),
        other => Err(PyValueError::new_err(format!(
            "init='{other}': expected file, odometry or chordal"
        ))),
    }
}

/// Reads a g2o file; an information matrix that is not positive definite is repaired (a
/// `UserWarning` names each such edge) unless `strict`, which refuses the file.
fn read(py: Python<'_>, path: PathBuf, strict: bool) -> PyResult<Core> {
    let policy = match strict {
        true => InformationPolicy::Refuse,
        false => InformationPolicy::Repair,
    };
    let (graph, repairs) = py
        .detach(|| g2o::read_with(&path, policy))
        .map_err(errors::input)?;
    let warnings = py.import("warnings")?;
    let category = py.get_type::<PyUserWarning>();
    for r in &repairs {
        let message = format!("{}: {r}", path.display());
        warnings.call_method1("warn", (message, &category, 2))?;
    }
    Ok(graph)
}

impl PoseGraph {
    /// Solves from `start` with `options`, under `kernel` on every edge: the poses and the
    /// summary.
    fn solve_from(
        &self,
        py: Python<'_>,
        start: &Poses,
        options: dynamap_solver::Options,
        kernel: Option<NamedKernel>,
    ) -> PyResult<(Poses, Summary)> {
        let graph = &self.core;
        let mut pg = graph
            .build_robust_problem(start, kernel)
            .map_err(errors::input)?;
        let solved = py.detach(|| Solver::new(options).solve(&mut pg.problem));
        let run = solved.map_err(|e| match pg.describe(&e, &graph.source) {
            Some(message) => errors::SolveError::new_err(message),
            None => errors::solve(e),
        })?;
        Ok((pg.poses(), Summary { run }))
    }
}

#[pymethods]
impl PoseGraph {
    /// Reads a g2o file (VERTEX_SE2 / EDGE_SE2 or VERTEX_SE3:QUAT / EDGE_SE3:QUAT, or TORO's planar
    /// VERTEX2 / EDGE2). Raises `InputError` naming the file and line of a fault.
    #[staticmethod]
    #[pyo3(signature = (path, strict = false))]
    fn read(py: Python<'_>, path: PathBuf, strict: bool) -> PyResult<Self> {
        Ok(Self {
            core: read(py, path, strict)?,
        })
    }

    /// 2 or 3.
    #[getter]
    fn dimension(&self) -> usize {
        match self.core.dimension {
            Dimension::Two => 2,
            Dimension::Three => 3,
        }
    }

    /// Where the graph came from.
    #[getter]
    fn source(&self) -> &str {
        &self.core.source
    }

    /// Number of vertices.
    #[getter]
    fn num_vertices(&self) -> usize {
        self.core.vertices.len()
    }

    /// Number of edges.
    #[getter]
    fn num_edges(&self) -> usize {
        self.core.edges.len()
    }

    /// The vertices held fixed: g2o's FIX lines, and the lowest vertex of every connected piece
    /// that has none (`PoseGraph::anchors`).
    #[getter]
    fn anchors(&self) -> Vec<usize> {
        self.core.anchors()
    }

    /// The poses in the file, by vertex id.
    fn vertices<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        poses_to_dict(py, &self.core.vertices)
    }

    /// The edges as (from, to, measurement, information), the information in the tangent order
    /// (`[v_x, v_y, ω]` in 2-D, `[ω; v]` in 3-D).
    #[allow(clippy::type_complexity)]
    fn edges<'py>(
        &self,
        py: Python<'py>,
    ) -> Vec<(
        usize,
        usize,
        Bound<'py, PyArray1<f64>>,
        Bound<'py, numpy::PyArray2<f64>>,
    )> {
        self.core
            .edges
            .iter()
            .map(|e| {
                let info = match &e.measurement {
                    Measurement::Se2 { information, .. } => {
                        DMatrix::from_column_slice(3, 3, information.as_slice())
                    }
                    Measurement::Se3 { information, .. } => {
                        DMatrix::from_column_slice(6, 6, information.as_slice())
                    }
                };
                let z = arrays::vector(py, &e.measurement.pose().coordinates());
                (e.from, e.to, z, arrays::matrix(py, &info))
            })
            .collect()
    }

    /// chi2 = Σ eᵀΩe at `poses` (a dict by vertex id; default the file's poses).
    #[pyo3(signature = (poses = None))]
    fn chi2(&self, poses: Option<&Bound<'_, PyDict>>) -> PyResult<f64> {
        match poses {
            Some(d) => Ok(self.core.chi2(&poses_from_dict(&self.core, d)?)),
            None => Ok(self.core.chi2(&self.core.vertices)),
        }
    }

    /// Optimises the graph as `pose_graph` does and returns `(poses, summary)`: the poses by
    /// vertex id, and the `Summary` (its `final_cost` is chi2 / 2 without a kernel).
    ///
    /// `init` is "file", "odometry" or "chordal"; `options` defaults to the tool's (dogleg, 100
    /// iterations, function tolerance 1e-9); `kernel` ("NAME:SCALE") makes every edge robust.
    #[pyo3(signature = (init = "file", options = None, kernel = None))]
    fn solve<'py>(
        &self,
        py: Python<'py>,
        init: &str,
        options: Option<Options>,
        kernel: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<(Bound<'py, PyDict>, Summary)> {
        let kernel = kernels::optional(kernel)?;
        let options = options.map_or_else(pose_graph::options, |o| o.core);
        let start = init::start(&self.core, start_of(init)?).map_err(errors::input)?;
        let (poses, summary) = self.solve_from(py, &start, options, kernel)?;
        Ok((poses_to_dict(py, &poses)?, summary))
    }

    /// Writes the graph with `poses` (default the file's) to a g2o file, through a temporary file
    /// renamed into place.
    #[pyo3(signature = (path, poses = None))]
    fn write(
        &self,
        py: Python<'_>,
        path: PathBuf,
        poses: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<()> {
        let poses = match poses {
            Some(d) => poses_from_dict(&self.core, d)?,
            None => self.core.vertices.clone(),
        };
        py.detach(|| g2o::write(&path, &self.core, &poses))
            .map_err(errors::input)
    }

    fn __repr__(&self) -> String {
        format!(
            "<dynamap.PoseGraph {}-D, {} vertices, {} edges, from {}>",
            self.dimension(),
            self.core.vertices.len(),
            self.core.edges.len(),
            self.core.source
        )
    }
}

/// Reads a g2o file and optimises it as `pose_graph` does: returns `(poses, summary)` (see
/// `PoseGraph.solve`).
#[pyfunction]
#[pyo3(signature = (path, init = "file", options = None, kernel = None, strict = false))]
pub fn solve_pose_graph<'py>(
    py: Python<'py>,
    path: PathBuf,
    init: &str,
    options: Option<Options>,
    kernel: Option<&Bound<'py, PyAny>>,
    strict: bool,
) -> PyResult<(Bound<'py, PyDict>, Summary)> {
    let graph = PoseGraph::read(py, path, strict)?;
    graph.solve(py, init, options, kernel)
}
