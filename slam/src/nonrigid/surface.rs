//! Registering one whole surface (mesh or cloud with normals) onto another: graph sampling over the
//! source, binding, principal-axes starting guesses, and the warp-field optimiser against the target
//! by closest point. The source's points keep their order in the result, so anyone can score them.

use super::graph::{DeformationGraph, GraphError, GraphParams};
use super::register::{
    principal_axes_guesses, CloudTarget, RegisterError, RegisterParams, RegisterSummary,
    WarpOptimiser,
};
use crate::mesh::Mesh;
use nalgebra::Vector3;

/// Why a surface registration failed.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum SurfaceError {
    /// The graph could not be sampled.
    #[error(transparent)]
    Graph(#[from] GraphError),
    /// The optimiser failed.
    #[error(transparent)]
    Register(#[from] RegisterError),
}

/// The result of [`register_surfaces`].
#[derive(Clone, Debug)]
pub struct SurfaceRegistration {
    /// The source points warped, in the source's order.
    pub points: Vec<Vector3<f64>>,
    /// Their warped normals.
    pub normals: Vec<Vector3<f64>>,
    /// The optimised graph.
    pub graph: DeformationGraph,
    /// What the optimiser did.
    pub summary: RegisterSummary,
}

/// Settings for clean (noise-free) surfaces whose bounding-box diagonal is `d`: node spacing
/// 0.03 d, association gate 0.1 d, Tukey's c 0.05 d, rigid gate 0.5 d, point-to-point weight 1, and
/// the regulariser relaxed over eight stages (100 down to 1e-5) until the data terms decide.
pub fn clean_surface_settings(d: f64) -> (GraphParams, RegisterParams) {
    (
        GraphParams {
            spacing: 0.03 * d,
            ..GraphParams::default()
        },
        RegisterParams {
            schedule: vec![100.0, 10.0, 1.0, 0.1, 1e-2, 1e-3, 1e-4, 1e-5],
            rounds: 6,
            iterations: 6,
            max_distance: 0.1 * d,
            rigid_max_distance: 0.5 * d,
            tukey: 0.05 * d,
            point_weight: 1.0,
            ..RegisterParams::default()
        },
    )
}

/// The diagonal of the points' axis-aligned bounding box.
pub fn bounding_diagonal(points: &[Vector3<f64>]) -> f64 {
    let (lo, hi) = points.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), p| (lo.inf(p), hi.sup(p)),
    );
    (hi - lo).norm()
}

/// A mesh's vertices and normals in double precision.
pub fn mesh_points(m: &Mesh) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let points = m.vertices.iter().map(|p| p.coords.cast()).collect();
    if m.normals.len() == m.vertices.len() {
        return (points, m.normals.iter().map(|n| n.cast()).collect());
    }
    let mut with_normals = Mesh {
        vertices: m.vertices.clone(),
        faces: m.faces.clone(),
        ..Mesh::default()
    };
    with_normals.compute_normals();
    (
        points,
        with_normals.normals.iter().map(|n| n.cast()).collect(),
    )
}

/// Registers `source` (points with normals) onto `target`, whole shape onto whole shape. The rigid
/// pre-alignment starts from where the source is or, with `principal_axes`, also from the four
/// principal-axes alignments ([`principal_axes_guesses`]), keeping the closest fit: for shapes far
/// apart, but a nearly symmetric shape turned over can fit closer than the right way up (the
/// camel poses do), so it is a choice.
pub fn register_surfaces(
    source: (&[Vector3<f64>], &[Vector3<f64>]),
    target: (&[Vector3<f64>], &[Vector3<f64>]),
    graph: GraphParams,
    params: RegisterParams,
    principal_axes: bool,
) -> Result<SurfaceRegistration, SurfaceError> {
    let (sp, sn) = source;
    let mut graph = DeformationGraph::sample(sp, graph)?;
    let bindings = graph.bind_all(sp);
    let mut guesses = principal_axes_guesses(sp, target.0);
    if !principal_axes {
        guesses.truncate(1);
    }
    let mut optimiser = WarpOptimiser::new(params);
    let summary = optimiser.optimise_from(
        &mut graph,
        sp,
        sn,
        &bindings,
        &CloudTarget::new(target.0, target.1),
        &guesses,
    )?;
    let (mut points, mut normals) = (Vec::new(), Vec::new());
    graph.warp_all(&bindings, sp, sn, &mut points, &mut normals);
    Ok(SurfaceRegistration {
        points,
        normals,
        graph,
        summary,
    })
}
