//! Meshes as numpy arrays: read and written (PLY, OFF, OBJ in; binary PLY out), and one mesh
//! registered onto another with the deformation graph, as `nonrigid_register meshes` does.

use crate::arrays::{self, Matrix};
use crate::errors;
use dynamap_slam::io::{meshes::read_mesh, ply};
use dynamap_slam::mesh::Mesh;
use dynamap_slam::nonrigid::{
    clean_surface_settings, mesh_points, register_mesh_or_cloud, surface_diagonal, Seeding,
    SurfaceError, SurfaceMesh, SurfaceVerdict,
};
use nalgebra::{Point3, Vector3};
use numpy::{PyArrayLike2, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// Rows of three finite numbers (`what` names the array in an error).
fn triples(a: &Matrix<'_>, what: &str) -> PyResult<Vec<[f64; 3]>> {
    let v = a.as_array();
    if v.ncols() != 3 {
        return Err(PyValueError::new_err(format!(
            "{what}: expected n x 3, got shape {:?}",
            v.shape()
        )));
    }
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "{what}: row {} holds a value that is not finite",
            i / 3
        )));
    }
    Ok(v.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect())
}

/// Faces as m × 3 vertex indices, each checked against the `n` vertices.
fn faces_of(
    f: Option<PyArrayLike2<'_, i64, numpy::AllowTypeChange>>,
    n: usize,
    what: &str,
) -> PyResult<Vec<[u32; 3]>> {
    let Some(f) = f else {
        return Ok(Vec::new());
    };
    let v = f.as_array();
    if v.ncols() != 3 {
        return Err(PyValueError::new_err(format!(
            "{what}: expected m x 3 vertex indices, got shape {:?}",
            v.shape()
        )));
    }
    v.rows()
        .into_iter()
        .enumerate()
        .map(|(k, r)| {
            let mut face = [0u32; 3];
            for (c, &i) in r.iter().enumerate() {
                face[c] = u32::try_from(i)
                    .ok()
                    .filter(|&i| (i as usize) < n)
                    .ok_or_else(|| {
                        PyValueError::new_err(format!(
                            "{what}: face {k} names vertex {i}, outside 0..{n}"
                        ))
                    })?;
            }
            Ok(face)
        })
        .collect()
}

/// A mesh from arrays; normals come from the faces when not given (a cloud needs them), after
/// the triangles wound against their neighbours are turned over (`Mesh::orient_faces`).
fn mesh_of(
    vertices: &Matrix<'_>,
    faces: Option<PyArrayLike2<'_, i64, numpy::AllowTypeChange>>,
    normals: Option<&Matrix<'_>>,
    what: &str,
) -> PyResult<Mesh> {
    let v = triples(vertices, &format!("{what} vertices"))?;
    let faces = faces_of(faces, v.len(), &format!("{what} faces"))?;
    let mut mesh = Mesh {
        vertices: v
            .iter()
            .map(|p| Point3::new(p[0] as f32, p[1] as f32, p[2] as f32))
            .collect(),
        faces,
        ..Mesh::default()
    };
    match normals {
        Some(n) => {
            let n = triples(n, &format!("{what} normals"))?;
            if n.len() != v.len() {
                return Err(PyValueError::new_err(format!(
                    "{what}: {} normals for {} vertices",
                    n.len(),
                    v.len()
                )));
            }
            if let Some(k) = n.iter().position(|n| Vector3::from(*n).norm() < 1e-12) {
                return Err(PyValueError::new_err(format!("{what}: normal {k} is zero")));
            }
            mesh.normals = n
                .iter()
                .map(|n| Vector3::from(*n).normalize().cast())
                .collect();
        }
        None if mesh.faces.is_empty() => {
            return Err(PyValueError::new_err(format!(
                "{what}: a point cloud needs normals (or give faces to compute them from)"
            )))
        }
        None => {
            mesh.compute_oriented_normals();
        }
    }
    Ok(mesh)
}

/// A mesh as a dict of arrays (float64 vertices and normals, uint8 colours, uint32 faces).
pub fn mesh_dict<'py>(py: Python<'py>, m: &Mesh) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let vertices = m
        .vertices
        .iter()
        .flat_map(|p| [p.x as f64, p.y as f64, p.z as f64])
        .collect();
    let normals = m
        .normals
        .iter()
        .flat_map(|n| [n.x as f64, n.y as f64, n.z as f64])
        .collect();
    d.set_item("vertices", arrays::rows(py, vertices, 3))?;
    d.set_item("normals", arrays::rows(py, normals, 3))?;
    d.set_item(
        "colors",
        arrays::rows(py, m.colors.iter().flatten().copied().collect(), 3),
    )?;
    d.set_item(
        "faces",
        arrays::rows(py, m.faces.iter().flatten().copied().collect(), 3),
    )?;
    Ok(d)
}

/// Reads a mesh (PLY, OFF or OBJ) as a dict: vertices (n × 3), normals (n × 3 or 0 × 3), colors
/// (n × 3 uint8 or 0 × 3), faces (m × 3 uint32). Raises `InputError` naming the file.
#[pyfunction]
#[pyo3(name = "read_mesh")]
pub fn read_mesh_file<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let m = py.detach(|| read_mesh(&path)).map_err(errors::input)?;
    mesh_dict(py, &m)
}

/// Writes a mesh as binary PLY (through a temporary file renamed into place): vertices n × 3,
/// faces m × 3 (optional), normals n × 3 and colours n × 3 uint8 (optional).
#[pyfunction]
#[pyo3(signature = (path, vertices, faces = None, normals = None, colors = None))]
pub fn write_mesh(
    py: Python<'_>,
    path: PathBuf,
    vertices: Matrix<'_>,
    faces: Option<PyArrayLike2<'_, i64, numpy::AllowTypeChange>>,
    normals: Option<Matrix<'_>>,
    colors: Option<PyReadonlyArray2<'_, u8>>,
) -> PyResult<()> {
    let v = triples(&vertices, "vertices")?;
    let mut mesh = Mesh {
        vertices: v
            .iter()
            .map(|p| Point3::new(p[0] as f32, p[1] as f32, p[2] as f32))
            .collect(),
        faces: faces_of(faces, v.len(), "faces")?,
        ..Mesh::default()
    };
    if let Some(n) = normals {
        mesh.normals = triples(&n, "normals")?
            .iter()
            .map(|n| Vector3::new(n[0] as f32, n[1] as f32, n[2] as f32))
            .collect();
    }
    if let Some(c) = colors {
        let c = c.as_array();
        if c.ncols() != 3 {
            return Err(PyValueError::new_err(format!(
                "colors: expected n x 3 uint8, got shape {:?}",
                c.shape()
            )));
        }
        mesh.colors = c.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect();
    }
    mesh.validate().map_err(PyValueError::new_err)?;
    py.detach(|| ply::write(&path, &mesh))
        .map_err(errors::input)
}

/// Registers the source surface onto the target with the deformation graph, as
/// `nonrigid_register meshes` does without flags: lengths from the source's bounding-box
/// diagonal D (node spacing 0.03 D, association gate 0.1 D, Tukey's c 0.05 D), a closest-point
/// pass then `seeded_passes` passes seeded by geodesic descriptors (closest point alone for a
/// point cloud, or with `seeded_passes=0`).
///
/// Each surface is vertices (n × 3) with faces (m × 3, optional) and normals (n × 3; computed from
/// the faces when not given, after those wound against their neighbours are turned alike).
/// Returns a dict: vertices and normals (the source's, warped, in its
/// order), nodes (the graph's node count), iterations, data_cost, regulariser_cost, matched (source
/// points with a correspondence at the end) and matched_fraction, seconds, and the verdict:
/// registered (bool), target_normals_turned (bool: both meshes closed, the target's normals
/// pointing the other way, so turned over) and fit (on_target and covered: the shares of the
/// warped source within a node spacing of the target and of the target covered; facing, the
/// share of the former whose normals point the target's way; at least half each, and 0.8
/// facing; area_ratio and
/// source_area_ratio, the source's area warped and at rest over the target's for two meshes,
/// within 1.5× of 1, else None; median_distance; tolerance). A source pulled onto a much smaller
/// target ends fully matched but not registered. slippage: for two meshes, the share of each
/// one's least-constrained rigid motion that moves it off itself (source, target); where either
/// is under 1e-3 the surface slides along itself (a sphere, a cylinder or a torus turned about
/// its axis), its points could lie anywhere along that motion, and registered is False. None for
/// a point cloud. round_trip: where the fit registered and nothing slides, the target
/// registered back onto the source carries each source point back (error, the mean distance it
/// ends from where it started; moved, the mean distance the registration moved it; their ratio);
/// a ratio over 0.35 means the surfaces do not fix where the points go, and registered is False.
/// None where it was not run. seconds counts both ways. placed_back: whether the vertices are
/// where the way back placed the source (it registered, and the way back lay closer to its
/// target). placed_rigid and placed_affine: whether the vertices are the source carried by a
/// rigid motion, or else by a global affine map (one that stretches no direction more than
/// twice; two closed meshes only), that lays the source on the target as closely as the warp
/// did (round_trip is then None). affine_slippage: for two meshes, the share of each one's
/// least-constrained affine motion that moves it off itself (source, target); where either is
/// under 1e-3 (an ellipsoid) and the vertices depart from a rigid motion of the source by more
/// than a tenth of the node spacing (departure_from_rigid, root mean square), registered is
/// False. maps_apart: where more than one rigid motion (fitted from five starts: the
/// centroids and the principal axes) or, none fitting, affine map (from six) lays the source
/// as closely as the warp, [apart, limit]: how far apart (root mean square) they carry the
/// source, and the tenth of the node spacing within which they count as one; further apart (a
/// box or an ellipsoid turned onto itself, a box's faces exchanged), none is taken and
/// registered is False. None otherwise.
#[pyfunction]
#[pyo3(signature = (source_vertices, target_vertices, source_faces = None, target_faces = None, source_normals = None, target_normals = None, seeded_passes = None, principal_axes = false))]
#[allow(clippy::too_many_arguments)]
pub fn register_meshes<'py>(
    py: Python<'py>,
    source_vertices: Matrix<'py>,
    target_vertices: Matrix<'py>,
    source_faces: Option<PyArrayLike2<'py, i64, numpy::AllowTypeChange>>,
    target_faces: Option<PyArrayLike2<'py, i64, numpy::AllowTypeChange>>,
    source_normals: Option<Matrix<'py>>,
    target_normals: Option<Matrix<'py>>,
    seeded_passes: Option<usize>,
    principal_axes: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let source = mesh_of(
        &source_vertices,
        source_faces,
        source_normals.as_ref(),
        "source",
    )?;
    let target = mesh_of(
        &target_vertices,
        target_faces,
        target_normals.as_ref(),
        "target",
    )?;
    let seeding = Seeding {
        passes: seeded_passes.unwrap_or(Seeding::default().passes),
        ..Seeding::default()
    };
    let reg = py
        .detach(|| {
            let (sp, sn) = mesh_points(&source);
            let (tp, tn) = mesh_points(&target);
            let (graph, params) = clean_surface_settings(surface_diagonal(&sp, &source.faces));
            let s = SurfaceMesh::with_faces_of(&sp, &sn, &source);
            let t = SurfaceMesh::with_faces_of(&tp, &tn, &target);
            register_mesh_or_cloud(s, t, graph, params, principal_axes, &seeding)
        })
        .map_err(|e| match e {
            // a mesh without area is the caller's input: a ValueError, as for its other faults
            SurfaceError::NoArea(_) => PyValueError::new_err(e.to_string()),
            e => errors::SolveError::new_err(format!("registering the source: {e}")),
        })?;
    let d = PyDict::new(py);
    let flat = |v: &[Vector3<f64>]| v.iter().flat_map(|p| [p.x, p.y, p.z]).collect::<Vec<f64>>();
    d.set_item("vertices", arrays::rows(py, flat(&reg.points), 3))?;
    d.set_item("normals", arrays::rows(py, flat(&reg.normals), 3))?;
    d.set_item("nodes", reg.graph.nodes.len())?;
    let s = &reg.summary;
    d.set_item("iterations", s.iterations)?;
    d.set_item("data_cost", s.data_cost)?;
    d.set_item("regulariser_cost", s.regulariser_cost)?;
    d.set_item("matched", s.matched)?;
    let fraction = s.matched as f64 / reg.points.len().max(1) as f64;
    d.set_item("matched_fraction", fraction)?;
    d.set_item("seconds", s.seconds)?;
    d.set_item("registered", reg.verdict() == SurfaceVerdict::Registered)?;
    d.set_item("target_normals_turned", reg.target_normals_turned)?;
    let fit = PyDict::new(py);
    fit.set_item("on_target", reg.fit.on_target)?;
    fit.set_item("covered", reg.fit.covered)?;
    fit.set_item("facing", reg.fit.facing)?;
    fit.set_item("area_ratio", reg.fit.area_ratio)?;
    fit.set_item("source_area_ratio", reg.fit.source_area_ratio)?;
    fit.set_item("median_distance", reg.fit.median_distance)?;
    fit.set_item("tolerance", reg.fit.tolerance)?;
    d.set_item("fit", fit)?;
    let slippage = reg.slippage.map(|[s, t]| [s.ratio, t.ratio]);
    d.set_item("slippage", slippage)?;
    let trip = reg.round_trip.map(|t| {
        let trip = PyDict::new(py);
        trip.set_item("error", t.mean)?;
        trip.set_item("moved", t.moved)?;
        trip.set_item("ratio", t.ratio())?;
        Ok::<_, PyErr>(trip)
    });
    d.set_item("round_trip", trip.transpose()?)?;
    d.set_item("placed_back", reg.placed_back)?;
    d.set_item("placed_affine", reg.placed_affine)?;
    d.set_item("placed_rigid", reg.placed_rigid)?;
    d.set_item("affine_slippage", reg.affine_slippage)?;
    d.set_item("departure_from_rigid", reg.departure_from_rigid)?;
    d.set_item("maps_apart", reg.maps_apart.map(|m| [m.apart, m.limit]))?;
    Ok(d)
}
