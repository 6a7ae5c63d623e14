//! Registering one whole surface (mesh or cloud with normals) onto another: graph sampling over the
//! source, binding, principal-axes starting guesses, and the warp-field optimiser against the target
//! by closest point ([`register_surfaces`]); for meshes, also in two passes, the second seeded by
//! geodesic descriptors ([`register_meshes`]). The source's points keep their order in the result,
//! so anyone can score them.

use super::descriptors::{descriptor_matches, DescriptorError, MeshRef};
use super::graph::{Binding, DeformationGraph, GraphError, GraphParams};
use super::register::{
    principal_axes_guesses, CloudTarget, RegisterError, RegisterParams, RegisterSummary, Seeds,
    WarpOptimiser,
};
use crate::mesh::Mesh;
use nalgebra::{Isometry3, Vector3};

/// Why a surface registration failed.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum SurfaceError {
    /// The graph could not be sampled.
    #[error(transparent)]
    Graph(#[from] GraphError),
    /// The optimiser failed.
    #[error(transparent)]
    Register(#[from] RegisterError),
    /// The geodesic descriptors could not be formed.
    #[error(transparent)]
    Descriptor(#[from] DescriptorError),
}

/// A mesh with vertex normals, as [`register_meshes`] takes it.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceMesh<'a> {
    /// Vertex positions.
    pub points: &'a [Vector3<f64>],
    /// Unit vertex normals.
    pub normals: &'a [Vector3<f64>],
    /// Triangles as vertex indices.
    pub faces: &'a [[u32; 3]],
}

/// Settings of [`register_meshes`]' second pass.
#[derive(Clone, Debug, PartialEq)]
pub struct Seeding {
    /// Stages of the second pass that take the descriptor correspondences (default 1: λ = 100
    /// of [`clean_surface_settings`]).
    pub stages: usize,
    /// Tukey's c in those stages, as a multiple of the usual one (default 8).
    pub tukey_scale: f64,
    /// The part of the source nearest its centroid over which the anchors are spread (default
    /// 0.15).
    pub core_fraction: f64,
}

impl Default for Seeding {
    fn default() -> Self {
        Self {
            stages: 1,
            tukey_scale: 8.0,
            core_fraction: 0.15,
        }
    }
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
    Passes::new(source, target, graph, params, principal_axes)?.run(None)
}

/// What every pass of a surface registration starts from: the source's graph at rest and its
/// bindings, the rigid starting guesses and the target's KD-tree, built once for all passes.
struct Passes<'a> {
    source: (&'a [Vector3<f64>], &'a [Vector3<f64>]),
    rest: DeformationGraph,
    bindings: Vec<Binding>,
    guesses: Vec<Isometry3<f64>>,
    target: CloudTarget,
    params: RegisterParams,
}

impl<'a> Passes<'a> {
    fn new(
        source: (&'a [Vector3<f64>], &'a [Vector3<f64>]),
        target: (&[Vector3<f64>], &[Vector3<f64>]),
        graph: GraphParams,
        params: RegisterParams,
        principal_axes: bool,
    ) -> Result<Self, SurfaceError> {
        let rest = DeformationGraph::sample(source.0, graph)?;
        let bindings = rest.bind_all(source.0);
        let mut guesses = principal_axes_guesses(source.0, target.0);
        if !principal_axes {
            guesses.truncate(1);
        }
        Ok(Self {
            source,
            rest,
            bindings,
            guesses,
            target: CloudTarget::new(target.0, target.1),
            params,
        })
    }

    /// One registration from the graph at rest, with a fresh optimiser.
    fn run(&self, seeds: Option<&Seeds>) -> Result<SurfaceRegistration, SurfaceError> {
        let (sp, sn) = self.source;
        let mut graph = self.rest.clone();
        let summary = WarpOptimiser::new(self.params.clone()).optimise_seeded(
            &mut graph,
            sp,
            sn,
            &self.bindings,
            &self.target,
            &self.guesses,
            seeds,
        )?;
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        graph.warp_all(&self.bindings, sp, sn, &mut points, &mut normals);
        Ok(SurfaceRegistration {
            points,
            normals,
            graph,
            summary,
        })
    }
}

/// Registers one mesh onto another in two passes, for poses far apart whose parts swing past
/// each other (a galloping animal's legs), where closest point pulls a part onto its neighbour.
///
/// 1. [`register_surfaces`] aligns the whole shape; its core lands where it belongs.
/// 2. Every source vertex is matched to the target vertex of nearest geodesic descriptor, with
///    anchors on the source's core and their partners from pass 1
///    ([`descriptor_matches`]).
/// 3. The registration runs again from the start. In its first `seeding.stages` stages a
///    point takes its descriptor match wherever that lies farther than the association gate
///    from its closest-point match ([`WarpOptimiser::optimise_seeded`]); later stages
///    associate by closest point alone.
///
/// The summary is the second pass's, with the iterations, seconds and stage times of both.
pub fn register_meshes(
    source: SurfaceMesh<'_>,
    target: SurfaceMesh<'_>,
    graph_params: GraphParams,
    params: RegisterParams,
    principal_axes: bool,
    seeding: &Seeding,
) -> Result<SurfaceRegistration, SurfaceError> {
    let start = std::time::Instant::now();
    let passes = Passes::new(
        (source.points, source.normals),
        (target.points, target.normals),
        graph_params,
        params,
        principal_axes,
    )?;
    let first = passes.run(None)?;
    let partner = descriptor_matches(
        MeshRef {
            points: source.points,
            faces: source.faces,
        },
        &first.points,
        MeshRef {
            points: target.points,
            faces: target.faces,
        },
        seeding.core_fraction,
    )?;
    let seeds = Seeds {
        matches: partner
            .iter()
            .map(|&k| (target.points[k], target.normals[k]))
            .collect(),
        stages: seeding.stages,
        tukey_scale: seeding.tukey_scale,
    };
    let mut second = passes.run(Some(&seeds))?;
    second.summary.iterations += first.summary.iterations;
    second.summary.times.add(&first.summary.times);
    second.summary.seconds = start.elapsed().as_secs_f64();
    Ok(second)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Mesh;
    use crate::nonrigid::descriptors::tube;
    use nalgebra::{Point3, Vector3};

    fn with_normals(points: &[Vector3<f64>], faces: &[[u32; 3]]) -> Vec<Vector3<f64>> {
        let mesh = Mesh {
            vertices: points
                .iter()
                .map(|p| Point3::from(p.cast::<f32>()))
                .collect(),
            faces: faces.to_vec(),
            ..Mesh::default()
        };
        mesh_points(&mesh).1
    }

    #[test]
    fn two_passes_carry_a_tube_onto_its_bent_copy() {
        let (sp, faces) = tube(24, 16, 0.0);
        let (tp, _) = tube(24, 16, 0.6);
        let (sn, tn) = (with_normals(&sp, &faces), with_normals(&tp, &faces));
        let (graph, params) = clean_surface_settings(bounding_diagonal(&sp));
        let mesh = |p, n| SurfaceMesh {
            points: p,
            normals: n,
            faces: &faces,
        };
        let reg = register_meshes(
            mesh(&sp, &sn),
            mesh(&tp, &tn),
            graph,
            params,
            false,
            &Seeding::default(),
        )
        .unwrap();
        // vertex k of the bent tube is vertex k's partner
        let mean = reg
            .points
            .iter()
            .zip(&tp)
            .map(|(a, b)| (a - b).norm())
            .sum::<f64>()
            / tp.len() as f64;
        let before = sp.iter().zip(&tp).map(|(a, b)| (a - b).norm()).sum::<f64>() / tp.len() as f64;
        assert!(
            mean < 0.01 && before > 0.1,
            "mean error {mean} (before {before})"
        );
    }

    #[test]
    fn seeds_that_are_not_one_per_point_are_an_error() {
        let (sp, faces) = tube(6, 8, 0.0);
        let sn = with_normals(&sp, &faces);
        let (graph_params, params) = clean_surface_settings(bounding_diagonal(&sp));
        let mut graph = DeformationGraph::sample(&sp, graph_params).unwrap();
        let bindings = graph.bind_all(&sp);
        let seeds = Seeds {
            matches: vec![(Vector3::zeros(), Vector3::z()); sp.len() - 1],
            stages: 1,
            tukey_scale: 8.0,
        };
        let result = WarpOptimiser::new(params).optimise_seeded(
            &mut graph,
            &sp,
            &sn,
            &bindings,
            &CloudTarget::new(&sp, &sn),
            &[nalgebra::Isometry3::identity()],
            Some(&seeds),
        );
        assert_eq!(
            result.unwrap_err(),
            RegisterError::Seeds {
                seeds: sp.len() - 1,
                points: sp.len()
            }
        );
    }
}
