//! Registering one whole surface (mesh or cloud with normals) onto another: graph sampling over the
//! source, binding, principal-axes starting guesses, and the warp-field optimiser against the target
//! by closest point ([`register_surfaces`]); for meshes, also in further passes seeded by geodesic
//! descriptors ([`register_meshes`]). The source's points keep their order in the result,
//! so anyone can score them.

use super::affine_fit::AffineMap;
use super::affine_slippage::{affine_slippage, departure_from_rigid, AffineSlide, RIGID_SHARE};
use super::boundary::{rim_matches, RimMatches};
use super::cloud_target::CloudTarget;
use super::coverage::{sampling_gap, sampling_spacing};
use super::descriptors::{DescriptorError, DescriptorPair, MeshRef};
use super::extent::centroid;
pub use super::extent::{bounding_diagonal, surface_diagonal};
use super::global_maps::{fit_maps, Choice, Closeness, MapKind, Maps, MapsApart};
use super::graph::{Binding, DeformationGraph, GraphError, GraphParams};
use super::mesh_point::MeshPoint;
use super::mesh_target::MeshTarget;
use super::orientation::{boundary_edges, relation, Oriented, Relation};
use super::principal_axes::principal_axes_guesses;
use super::register::{
    RegisterError, RegisterParams, RegisterSummary, Seeds, Target, WarpOptimiser,
};
use super::round_trip::{placed_back, RoundTrip};
use super::slippage::{slippage, Slippage};
use super::surface_area::area;
use super::surface_fit::{SurfaceFit, SurfaceVerdict, MIN_SHARE};
use super::weld::{weld, Welded};
use crate::eval::umeyama;
use crate::mesh::Mesh;
use nalgebra::{Isometry3, Point3, Vector3};

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
    /// The target's normals are not one per point (a point cloud given without normals).
    #[error(
        "the target has {normals} normals for {points} points (a point cloud needs its normals)"
    )]
    TargetNormals {
        /// Target points given.
        points: usize,
        /// Target normals given.
        normals: usize,
    },
    /// A mesh has faces, but none of them has area.
    #[error("the {0}'s faces have no area (every triangle's corners lie on one line)")]
    NoArea(MeshRole),
}

/// Which of a registration's two surfaces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshRole {
    /// The surface moved.
    Source,
    /// The surface it is moved onto.
    Target,
}

impl std::fmt::Display for MeshRole {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Source => "source",
            Self::Target => "target",
        })
    }
}

/// Refuses a mesh with faces none of which has area: a sheet registered onto a target whose
/// triangles all lay on one line fitted the line and was reported registered (its area ratio
/// cannot be formed). A cloud (no faces) is not a mesh and passes.
fn has_area(mesh: &SurfaceMesh<'_>, role: MeshRole) -> Result<(), SurfaceError> {
    if mesh.faces.is_empty() || area(mesh.points, mesh.faces) > 0.0 {
        Ok(())
    } else {
        Err(SurfaceError::NoArea(role))
    }
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

impl<'a> SurfaceMesh<'a> {
    /// `points` and `normals` ([`mesh_points`] of `mesh`) with `mesh`'s faces.
    pub fn with_faces_of(
        points: &'a [Vector3<f64>],
        normals: &'a [Vector3<f64>],
        mesh: &'a Mesh,
    ) -> Self {
        Self {
            points,
            normals,
            faces: &mesh.faces,
        }
    }

    /// The mesh as module `orientation` takes it.
    fn oriented(&self) -> Oriented<'a> {
        (self.points, self.normals, self.faces)
    }
}

/// Settings of [`register_meshes`]' seeded passes.
#[derive(Clone, Debug, PartialEq)]
pub struct Seeding {
    /// Seeded passes after the first, unseeded one (default 2); each places its anchors with the
    /// pass before it. 0 is one closest-point pass, as [`register_surfaces`] (in units of the
    /// source's size), with no seeds at all: not the rim's either.
    pub passes: usize,
    /// Stages of a seeded pass that take the descriptor correspondences (default 1: λ = 100
    /// of [`clean_surface_settings`]).
    pub stages: usize,
    /// Tukey's c in those stages, as a multiple of the usual one (default 8).
    pub tukey_scale: f64,
    /// Weight of the point-to-point term in those stages (default 1; [`Seeds::point_weight`]).
    pub point_weight: f64,
    /// Levenberg-Marquardt steps per round in those stages, at least (default 2).
    pub iterations: usize,
    /// Rounds per stage of the first, unseeded pass when seeded passes follow (default 3, at
    /// most the settings' rounds): that pass only places the anchors of the next, and on the
    /// camel three rounds placed them as well as ten.
    pub anchor_rounds: usize,
    /// The part of the source nearest its centroid over which the anchors are spread (default
    /// 0.15).
    pub core_fraction: f64,
}

impl Default for Seeding {
    fn default() -> Self {
        Self {
            passes: 2,
            stages: 1,
            tukey_scale: 8.0,
            point_weight: 1.0,
            iterations: 2,
            anchor_rounds: 3,
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
    /// How closely the result and the target lie on each other at the end.
    pub fit: SurfaceFit,
    /// Whether the target's normals were turned over to point the way the source's do (both
    /// meshes closed, one's normals out and the other's in, module `orientation`; or, where
    /// that cannot be told, the registration with them as given did not register and this one
    /// did).
    pub target_normals_turned: bool,
    /// The source's and the target's least-constrained rigid motions (module `slippage`), where
    /// [`register_mesh_or_cloud`] or [`register_mesh_pair`] measured them (both surfaces
    /// meshes); `None` otherwise.
    pub slippage: Option<[Slippage; 2]>,
    /// The source's and the target's least affine slippage ratios (module `affine_slippage`),
    /// where the rigid ones were measured.
    pub affine_slippage: Option<[f64; 2]>,
    /// How far [`Self::points`] are from a rigid motion of the source
    /// (`affine_slippage::departure_from_rigid`), where the affine slippage was measured.
    pub departure_from_rigid: Option<f64>,
    /// The round trip (module `round_trip`): the target registered back onto the source, where
    /// [`register_mesh_or_cloud`] or [`register_mesh_pair`] ran it (the registration fitted and
    /// neither surface slides); `None` otherwise.
    pub round_trip: Option<RoundTrip>,
    /// Whether [`Self::points`] and [`Self::normals`] are where the round trip's way back placed
    /// the source (it lay closer to its target than the way out did; the graph and the fit are
    /// still the way out's).
    pub placed_back: bool,
    /// Whether [`Self::points`] and [`Self::normals`] are the source carried by a global affine
    /// map (module `global_maps`): a moderate one that lays the source on the target at least as
    /// closely as the warp did. The graph and the fit are still the warp's, and the round trip
    /// is not run.
    pub placed_affine: bool,
    /// Whether [`Self::points`] and [`Self::normals`] are the source carried by a rigid motion
    /// (module `global_maps`) that lays it on the target at least as closely as the warp did:
    /// of the answers that fit, the one that deforms nothing (NOTES 197). The graph and the fit
    /// are still the warp's, and the round trip is not run.
    pub placed_rigid: bool,
    /// Where more than one map of the kind taken (or refused) lays the source on the target at
    /// least as closely as the warp (module `global_maps`): how far apart they carry it. Where
    /// they disagree ([`MapsApart::disagree`]), none is taken, the points are the warp's, and
    /// the verdict is [`SurfaceVerdict::MapsDisagree`].
    pub maps_apart: Option<MapsApart>,
}

impl SurfaceRegistration {
    /// Whether the source ended on the target and covers it ([`SurfaceFit::verdict`]), and if
    /// so, whether either surface slides along itself ([`SurfaceVerdict::Ambiguous`]: a
    /// registration that fits may still have its points anywhere along the slide), whether
    /// the round trip brings the points back ([`SurfaceVerdict::Inconsistent`]), and whether
    /// either surface slides under a stretch while the answer is not rigid
    /// ([`SurfaceVerdict::AffineAmbiguous`], module `affine_slippage`), and last whether two
    /// maps of one kind that each fit carry the source apart ([`SurfaceVerdict::MapsDisagree`],
    /// module `global_maps`).
    pub fn verdict(&self) -> SurfaceVerdict {
        match (self.verdict_of_the_fit(), self.affine_slide()) {
            (SurfaceVerdict::Registered, Some(a)) if a.is_free() => {
                SurfaceVerdict::AffineAmbiguous(a)
            }
            (SurfaceVerdict::Registered, _) => match self.maps_apart {
                Some(m) if m.disagree() => SurfaceVerdict::MapsDisagree(m),
                _ => SurfaceVerdict::Registered,
            },
            (verdict, _) => verdict,
        }
    }

    /// [`Self::verdict`] before the affine slide is judged: the fit, the rigid slippage and the
    /// round trip.
    fn verdict_of_the_fit(&self) -> SurfaceVerdict {
        let verdict = self.fit.verdict();
        let freest = self
            .slippage
            .and_then(|s| s.into_iter().min_by(|a, b| a.ratio.total_cmp(&b.ratio)));
        if verdict != SurfaceVerdict::Registered {
            return verdict;
        }
        match (freest, self.round_trip) {
            (Some(s), _) if s.is_free() => SurfaceVerdict::Ambiguous(s),
            (_, Some(r)) if !r.holds() => SurfaceVerdict::Inconsistent(r),
            _ => verdict,
        }
    }

    /// Both surfaces' affine slippage beside the answer's departure from rigid (module
    /// `affine_slippage`), where the slippage was measured; a departure not measured is NaN,
    /// which [`AffineSlide::is_free`] counts as not rigid.
    pub fn affine_slide(&self) -> Option<AffineSlide> {
        self.affine_slippage.map(|ratios| AffineSlide {
            ratios,
            departure: self.departure_from_rigid.unwrap_or(f64::NAN),
            limit: RIGID_SHARE * self.fit.tolerance,
        })
    }
}

/// Settings for clean (noise-free) surfaces whose bounding-box diagonal is `d`: node spacing
/// 0.03 d, association gate 0.1 d, Tukey's c 0.05 d, rigid gate 0.5 d, point-to-point weight
/// [`CLOSEST_POINT_WEIGHT`] on closest-point partners (a seeded stage weighs its seeds by
/// [`Seeding::point_weight`]), coverage matches beyond [`COVER_SPACINGS`] of the source's
/// sampling (module `coverage`), and the regulariser relaxed over six stages (100 down to 1e-3)
/// until the data terms decide, each stage ten rounds of matching and one Levenberg-Marquardt
/// step (as ICP alternates them). Six steps on each of six matchings did no better on the camel
/// and took four times as long, and stages past 1e-3 moved nothing (NOTES 67).
pub fn clean_surface_settings(d: f64) -> (GraphParams, RegisterParams) {
    (
        GraphParams {
            spacing: 0.03 * d,
            ..GraphParams::default()
        },
        RegisterParams {
            schedule: vec![100.0, 10.0, 1.0, 0.1, 1e-2, 1e-3],
            rounds: 10,
            iterations: 1,
            max_distance: 0.1 * d,
            rigid_max_distance: 0.5 * d,
            tukey: 0.05 * d,
            point_weight: CLOSEST_POINT_WEIGHT,
            cover: COVER_SPACINGS,
            ..RegisterParams::default()
        },
    )
}

/// The point-to-point weight of [`clean_surface_settings`] on closest-point partners, beside
/// point-to-plane's 1. A closest-point partner tells where the surface is, along the normal; its
/// place along the surface is only where the warp stands now, so a full weight holds each point
/// where it happened to land (a box twisted 0.6 rad ended with a tenth of its vertices 14–18 % of
/// the twist's largest displacement off at weight 1; all within 1.1 % at 0.3). Seeds, which name
/// the point itself, keep weight 1 ([`Seeding::point_weight`]). Chosen on the 30 camel maps (0.2,
/// 0.3, 0.5; 0.3 left the fewest maps worse; NOTES 178).
pub const CLOSEST_POINT_WEIGHT: f64 = 0.3;

/// The coverage distance of [`clean_surface_settings`], in the source's sampling spacings
/// ([`RegisterParams::cover`]). Chosen on the odd-numbered camel maps: 1, 1.25 and 1.5 left
/// their mean within 0.03 points of each other (1.56–1.59 %, 1.74 % without), 2 and 3 higher;
/// the widest of the three keeps the most margin for surfaces meshed apart (NOTES 101).
pub const COVER_SPACINGS: f64 = 1.5;

/// How much less of the two shares (on the target, covered) a seeded pass may leave than the pass
/// before it and still replace it ([`fits_as_well`]).
const PASS_SLACK: f64 = 0.02;

/// Whether `next` lies on its target about as well as `last` or better: the sum of the shares on
/// the target and covered is at most [`PASS_SLACK`] lower.
fn fits_as_well(next: &SurfaceFit, last: &SurfaceFit) -> bool {
    next.on_target + next.covered >= last.on_target + last.covered - PASS_SLACK
}

/// A mesh's vertices and normals in double precision, the normals computed from its faces where
/// it has not one per vertex (on a copy whose triangles are wound alike, [`Mesh::orient_faces`]).
/// A point cloud (no faces) keeps the normals it has: none are made up for it, and the
/// registrations refuse a cloud whose normals are missing.
pub fn mesh_points(m: &Mesh) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let points = m.vertices.iter().map(|p| p.coords.cast()).collect();
    if m.normals.len() == m.vertices.len() || m.faces.is_empty() {
        return (points, m.normals.iter().map(|n| n.cast()).collect());
    }
    let mut with_normals = Mesh {
        vertices: m.vertices.clone(),
        faces: m.faces.clone(),
        ..Mesh::default()
    };
    with_normals.compute_oriented_normals();
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
    Passes::new(
        source,
        SurfaceMesh {
            points: target.0,
            normals: target.1,
            faces: &[],
        },
        graph,
        params,
        principal_axes,
        None,
    )?
    .run(None)
}

/// What every pass of a surface registration starts from: the source's graph at rest and its
/// bindings, the rigid starting guesses and the target's KD-tree, built once for all passes.
///
/// Inside, points are taken relative to the source's centroid (`origin`): the pre-alignment's
/// rotation and the node motions' rotations then turn about the shape, not about the origin of the
/// caller's frame, and the damping and stopping tests, which weigh rotations against
/// translations, do the same wherever the shape lies. Before, the camel pair 1 → 3 (diagonal
/// 1.27) moved by (30, 0, 0) ended at 1.08 % mean error against 0.75 % where it was.
///
/// For [`register_meshes`] every length inside is in units of the source's size (`unit`, the
/// bounding-box diagonal of the vertices its faces use, [`surface_diagonal`]), the points and
/// the settings alike, and the result is scaled back: with settings relative to the size (as
/// [`clean_surface_settings`] makes them) a registration then does the same at 10 cm as at 2 m.
/// The optimiser's damping and stopping tests mix rotations (radians) and translations
/// (lengths), so in metres it did not: a saddle-shaped sheet registered to 0.85 % at 1 m and
/// left rim vertices 16 % off at 2 m. [`register_surfaces`] keeps the caller's
/// units (`unit` 1): the thesis' grid experiment is set in metres, and its wave lands 10× worse
/// at one vertex in units of its diagonal (NOTES 66).
struct Passes {
    unit: f64,
    origin: Vector3<f64>,
    source: (Vec<Vector3<f64>>, Vec<Vector3<f64>>),
    target_points: Vec<Vector3<f64>>,
    rest: DeformationGraph,
    bindings: Vec<Binding>,
    guesses: Vec<Isometry3<f64>>,
    target: Box<dyn Target>,
    params: RegisterParams,
}

impl Passes {
    /// The passes of `source` onto `target` (points, normals and triangles: a target with
    /// triangles is associated by the nearest point of its surface, [`MeshTarget`], one without
    /// by the nearest point of the cloud).
    fn new(
        source: (&[Vector3<f64>], &[Vector3<f64>]),
        target: SurfaceMesh<'_>,
        mut graph: GraphParams,
        mut params: RegisterParams,
        principal_axes: bool,
        size: Option<f64>,
    ) -> Result<Self, SurfaceError> {
        if target.normals.len() != target.points.len() {
            return Err(SurfaceError::TargetNormals {
                points: target.points.len(),
                normals: target.normals.len(),
            });
        }
        let unit = match size {
            Some(d) if d.is_finite() && d > 0.0 => d,
            _ => 1.0,
        };
        let origin = centroid(source.0);
        let local = |p: &[Vector3<f64>]| p.iter().map(|p| (p - origin) / unit).collect::<Vec<_>>();
        let (sp, tp) = (local(source.0), local(target.points));
        graph.spacing /= unit;
        params.max_distance /= unit;
        params.rigid_max_distance /= unit;
        params.tukey /= unit;
        let rest = DeformationGraph::sample(&sp, graph)?;
        let bindings = rest.bind_all(&sp);
        let mut guesses = principal_axes_guesses(&sp, &tp);
        if !principal_axes {
            guesses.truncate(1);
        }
        Ok(Self {
            unit,
            origin,
            target: if target.faces.is_empty() {
                Box::new(CloudTarget::new(&tp, target.normals))
            } else {
                Box::new(MeshTarget::new(&tp, target.normals, target.faces))
            },
            source: (sp, source.1.to_vec()),
            target_points: tp,
            rest,
            bindings,
            guesses,
            params,
        })
    }

    /// Adds the rigid motion that best carries each source point onto its partner (Horn's
    /// absolute orientation) to the pre-alignment's starting guesses.
    fn add_guess(&mut self, partner: &[MeshPoint]) {
        let from: Vec<Point3<f64>> = self.source.0.iter().map(|p| Point3::from(*p)).collect();
        let to: Vec<Point3<f64>> = partner
            .iter()
            .map(|m| Point3::from(m.blend(&self.target_points)))
            .collect();
        if let Some(fit) = umeyama(&from, &to, false) {
            self.guesses.push(fit.isometry);
        }
    }

    /// Starts every later pass from `start` (a pass's pre-alignment, in the caller's frame) with
    /// no rigid iterations: the passes share the rigid start, and it need not be found again.
    fn keep_rigid_start(&mut self, start: &Isometry3<f64>) {
        self.guesses = vec![self.to_local(start)];
        self.params.rigid_iterations = 0;
    }

    /// A rigid motion of the caller's frame in the passes' frame, x' = (x − o) / u: the same
    /// rotation, the translation (t − o + R o) / u.
    fn to_local(&self, t: &Isometry3<f64>) -> Isometry3<f64> {
        let mut local = *t;
        local.translation.vector =
            (t.translation.vector - self.origin + t.rotation * self.origin) / self.unit;
        local
    }

    /// The inverse of [`Self::to_local`]: the translation u t' + o − R o.
    fn to_caller(&self, t: &Isometry3<f64>) -> Isometry3<f64> {
        let mut caller = *t;
        caller.translation.vector =
            t.translation.vector * self.unit + self.origin - t.rotation * self.origin;
        caller
    }

    /// Each source point's partner on the target (with the target's `normals`) as [`Seeds`].
    fn seeds(&self, partner: &[MeshPoint], normals: &[Vector3<f64>], seeding: &Seeding) -> Seeds {
        Seeds {
            matches: partner
                .iter()
                .map(|m| (m.blend(&self.target_points), m.normal(normals)))
                .collect(),
            stages: seeding.stages,
            tukey_scale: seeding.tukey_scale,
            point_weight: seeding.point_weight,
            replace_all: false,
            iterations: seeding.iterations,
            pinned: Vec::new(),
        }
    }

    /// The one pass of a mesh with a rim: the rim's matches ([`rim_matches`]) seed the points in
    /// the first stages (where closest point disagrees) and hold the rim itself in all, and their
    /// Horn fit joins the rigid guesses.
    fn run_by_rim(
        &mut self,
        found: RimMatches,
        normals: &[Vector3<f64>],
        seeding: &Seeding,
    ) -> Result<SurfaceRegistration, SurfaceError> {
        self.add_guess(&found.partners);
        // the rim holds the sheet from the start, so an inside seed replaces closest point only
        // where the two disagree by more than the gate: a sheet of many vertices onto a
        // coarser Delaunay mesh kept the seeds' errors (twist 6.8 % largest; 1.2 % so)
        let seeds = Seeds {
            pinned: found.rim,
            ..self.seeds(&found.partners, normals, seeding)
        };
        self.run(Some(&seeds))
    }

    /// One registration from the graph at rest, with a fresh optimiser, in the caller's units.
    fn run(&self, seeds: Option<&Seeds>) -> Result<SurfaceRegistration, SurfaceError> {
        self.run_with(self.params.clone(), seeds)
    }

    /// [`Self::run`] with other settings (in the passes' units).
    fn run_with(
        &self,
        params: RegisterParams,
        seeds: Option<&Seeds>,
    ) -> Result<SurfaceRegistration, SurfaceError> {
        let (sp, sn) = (&self.source.0, &self.source.1);
        let mut graph = self.rest.clone();
        let mut summary = WarpOptimiser::new(params).optimise_from(
            &mut graph,
            sp,
            sn,
            &self.bindings,
            self.target.as_ref(),
            &self.guesses,
            seeds,
        )?;
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        graph.warp_all(&self.bindings, sp, sn, &mut points, &mut normals);
        let mut fit = SurfaceFit::measure(
            (&points, &normals),
            self.target.as_ref(),
            &self.target_points,
            &graph,
        );
        fit.tolerance *= self.unit;
        fit.median_distance *= self.unit;
        points
            .iter_mut()
            .for_each(|p| *p = *p * self.unit + self.origin);
        graph.scale(self.unit);
        graph.shift(&self.origin);
        summary.prealigned = self.to_caller(&summary.prealigned);
        // both costs are sums of squared lengths
        summary.data_cost *= self.unit * self.unit;
        summary.regulariser_cost *= self.unit * self.unit;
        Ok(SurfaceRegistration {
            points,
            normals,
            graph,
            summary,
            fit,
            target_normals_turned: false,
            slippage: None,
            affine_slippage: None,
            departure_from_rigid: None,
            round_trip: None,
            placed_back: false,
            placed_affine: false,
            placed_rigid: false,
            maps_apart: None,
        })
    }
}

/// [`register_meshes`] of two [`Mesh`]es with [`clean_surface_settings`] relative to the
/// source's bounding-box diagonal, from where the source is: what `nonrigid_register meshes`
/// does without flags.
pub fn register_mesh_pair(
    source: &Mesh,
    target: &Mesh,
    seeding: &Seeding,
) -> Result<SurfaceRegistration, SurfaceError> {
    let (sp, sn) = mesh_points(source);
    let (tp, tn) = mesh_points(target);
    let (graph, params) = clean_surface_settings(surface_diagonal(&sp, &source.faces));
    let source = SurfaceMesh::with_faces_of(&sp, &sn, source);
    let target = SurfaceMesh::with_faces_of(&tp, &tn, target);
    let band = graph.spacing;
    let (back_graph, back_params) = for_the_way_back(graph, params.clone(), (source, target));
    both_ways(
        (source, target),
        || register_meshes(source, target, graph, params, false, seeding),
        || register_meshes(target, source, back_graph, back_params, false, seeding),
        Some(band),
    )
}

/// `graph` and `params`, set relative to `source`'s size ([`surface_diagonal`]), set alike
/// relative to `target`'s: each length (the node spacing, the association and rigid gates,
/// Tukey's c) times the ratio of the sizes, so that the round trip's way back is set relative to
/// its own source, as the way out is. The camel's poses differ in size by up to a fifth; with
/// the way out's lengths the way back of the map 1 → 5 came back 0.52 of its displacement off,
/// with its own 0.18 (NOTES 188).
fn for_the_way_back(
    mut graph: GraphParams,
    mut params: RegisterParams,
    (source, target): (SurfaceMesh<'_>, SurfaceMesh<'_>),
) -> (GraphParams, RegisterParams) {
    let k = surface_diagonal(target.points, target.faces)
        / surface_diagonal(source.points, source.faces);
    if k.is_finite() && k > 0.0 {
        graph.spacing *= k;
        params.max_distance *= k;
        params.rigid_max_distance *= k;
        params.tukey *= k;
    }
    (graph, params)
}

/// Registers `source` onto `target` by `there` and, beside it, `target` back onto `source` by
/// `back` (the same procedure with the roles swapped) and, for two meshes, fits rigid motions of
/// the source onto the target, and affine maps (which place the source only where both are
/// closed, module `global_maps`). Then measures the slippage, rigid and affine (meshes: `band`
/// given), and, where the fit registers and nothing slides rigidly, places the source
/// ([`place`]: by a map, or by the warp judged by the round trip); last, the answer's departure
/// from rigid, which the verdict weighs against the affine slippage
/// ([`SurfaceRegistration::verdict`]). The directions and the maps run at once (`rayon::join`):
/// each one's parallel loops leave part of the cores idle, and the pair took 1.0–1.4 times one
/// direction's time on the camel against 2 times one after the other (NOTES 188). The summary's
/// seconds are the wall time of all. An error on the way back is returned where the check is
/// needed: a check that could not run must not pass.
fn both_ways(
    (source, target): (SurfaceMesh<'_>, SurfaceMesh<'_>),
    there: impl FnOnce() -> Result<SurfaceRegistration, SurfaceError> + Send,
    back: impl FnOnce() -> Result<SurfaceRegistration, SurfaceError> + Send,
    band: Option<f64>,
) -> Result<SurfaceRegistration, SurfaceError> {
    let start = std::time::Instant::now();
    // affine maps that may place the source only where both are closed (global_maps::fit_maps)
    let closed = is_closed(source) && is_closed(target);
    let target_surface = (target.points, target.normals);
    let meshes = !source.faces.is_empty() && !target.faces.is_empty();
    let maps = || meshes.then(|| fit_maps(source.points, target_surface, closed));
    let (reg, (backward, maps)) = rayon::join(there, || rayon::join(back, maps));
    let mut reg = reg?;
    if let Some(band) = band {
        reg = with_slippage(reg, source, target, band);
    }
    if reg.verdict_of_the_fit() == SurfaceVerdict::Registered {
        place(&mut reg, (source, target), maps, backward)?;
    }
    if reg.affine_slippage.is_some() {
        reg.departure_from_rigid = departure_from_rigid(source.points, &reg.points);
    }
    reg.summary.seconds = start.elapsed().as_secs_f64();
    Ok(reg)
}

/// Where a registration that fits places the source, the least deformed first (module
/// `global_maps`, fitted beside the registrations for meshes): a rigid motion, or else an
/// affine map (closed meshes), that lays it on the target at least as closely as the warp,
/// where all of its kind that do agree; where they carry the source apart (an open mesh's
/// affine maps too), none, and the verdict says so (`maps_apart`, NOTES 198–199); else the
/// warp's points, judged by the round
/// trip against `backward` and moved to the way back's where that lies closer.
fn place(
    reg: &mut SurfaceRegistration,
    (source, target): (SurfaceMesh<'_>, SurfaceMesh<'_>),
    maps: Option<Maps>,
    backward: Result<SurfaceRegistration, SurfaceError>,
) -> Result<(), SurfaceError> {
    if let Some(maps) = maps {
        let closeness = Closeness::new(maps, source.points, &reg.points, reg.fit.tolerance);
        match closeness.choose() {
            Choice::Disagree(apart) => {
                reg.maps_apart = Some(apart);
                return Ok(());
            }
            Choice::Map { kind, map, apart } => {
                take_the_map(reg, source, &map);
                reg.maps_apart = apart;
                reg.placed_rigid = kind == MapKind::Rigid;
                reg.placed_affine = kind == MapKind::Affine;
                return Ok(());
            }
            Choice::Warp => {}
        }
    }
    let backward = backward?;
    reg.round_trip = RoundTrip::measure(
        source.points,
        &reg.points,
        (target.points, &backward.points),
        (reg.fit.tolerance, reg.fit.median_distance),
    );
    if reg.verdict_of_the_fit() == SurfaceVerdict::Registered && back_fits_closer(reg, &backward) {
        take_the_way_back(reg, source, target, &backward.points);
        reg.placed_back = true;
    }
    Ok(())
}

/// Whether the way back (`backward`, the target registered onto the source) lies closer to its
/// target than the way out (`reg`) does: its data cost per point is lower. Each direction's
/// regulariser pulls its answer its own way, and the one that fits closer was the better map on
/// the camel: the 30 maps' mean error went 0.872 → 0.610 % (none over 2 %), and on the 38 chained
/// pairs, held out, 1.109 → 0.809 % (3 → 0 over 2 %; NOTES 189).
fn back_fits_closer(reg: &SurfaceRegistration, backward: &SurfaceRegistration) -> bool {
    let per_point = |r: &SurfaceRegistration| r.summary.data_cost / r.points.len().max(1) as f64;
    per_point(backward) < per_point(reg)
}

/// Whether `mesh` has faces and no boundary edge.
fn is_closed(mesh: SurfaceMesh<'_>) -> bool {
    !mesh.faces.is_empty() && boundary_edges(mesh.faces).is_empty()
}

/// Moves `reg`'s points and normals to where `map` carries the source's (a normal the map
/// cannot carry, A singular or the normal sent to 0, is left as the source's).
fn take_the_map(reg: &mut SurfaceRegistration, source: SurfaceMesh<'_>, map: &AffineMap) {
    let normals = map.normal_transform();
    for ((p, n), (q, m)) in
        (reg.points.iter_mut().zip(&mut reg.normals)).zip(source.points.iter().zip(source.normals))
    {
        *p = map.apply(q);
        *n = normals
            .and_then(|a| (a * m).try_normalize(0.0))
            .unwrap_or(*m);
    }
    reg.round_trip = None;
}

/// Moves `reg`'s points and normals to where the way back places them ([`placed_back`]), where
/// it reaches; elsewhere they stay the way out's. The graph and the fit stay the way out's.
fn take_the_way_back(
    reg: &mut SurfaceRegistration,
    source: SurfaceMesh<'_>,
    target: SurfaceMesh<'_>,
    backward: &[Vector3<f64>],
) {
    let back = placed_back(
        source.points,
        (target.points, target.normals),
        backward,
        reg.fit.tolerance,
    );
    let flip = if reg.target_normals_turned { -1.0 } else { 1.0 };
    for ((p, n), b) in reg.points.iter_mut().zip(&mut reg.normals).zip(back) {
        if let Some((q, m)) = b {
            (*p, *n) = (q, flip * m);
        }
    }
}

/// `reg` with both meshes' least-constrained motions (module `slippage`), their boundaries
/// counted as bands `band` wide; `None` where either has none (a cloud).
fn with_slippage(
    mut reg: SurfaceRegistration,
    source: SurfaceMesh<'_>,
    target: SurfaceMesh<'_>,
    band: f64,
) -> SurfaceRegistration {
    let slip = |m: &SurfaceMesh<'_>| slippage(m.points, m.normals, m.faces, band);
    reg.slippage = slip(&source).zip(slip(&target)).map(|(s, t)| [s, t]);
    let affine = |m: &SurfaceMesh<'_>| affine_slippage(m.points, m.normals, m.faces, band);
    reg.affine_slippage = affine(&source).zip(affine(&target)).map(|(s, t)| [s, t]);
    reg
}

/// [`register_meshes`] where both surfaces have faces and `seeding.passes` > 0, else
/// [`register_surfaces`] (closest point alone; point clouds have no geodesics to seed from),
/// with the target's normals turned as [`register_meshes`] turns them (a cloud's where the
/// registration did not register): what `nonrigid_register meshes` and the Python bindings run.
pub fn register_mesh_or_cloud(
    source: SurfaceMesh<'_>,
    target: SurfaceMesh<'_>,
    graph_params: GraphParams,
    params: RegisterParams,
    principal_axes: bool,
    seeding: &Seeding,
) -> Result<SurfaceRegistration, SurfaceError> {
    let one_way = |source, target, graph, params| {
        one_way_mesh_or_cloud(source, target, graph, params, principal_axes, seeding)
    };
    let meshes = !source.faces.is_empty() && !target.faces.is_empty();
    let (back_graph, back_params) =
        for_the_way_back(graph_params, params.clone(), (source, target));
    both_ways(
        (source, target),
        || one_way(source, target, graph_params, params),
        || one_way(target, source, back_graph, back_params),
        meshes.then_some(graph_params.spacing),
    )
}

/// [`register_mesh_or_cloud`] one way, without its checks of slippage and the round trip.
fn one_way_mesh_or_cloud(
    source: SurfaceMesh<'_>,
    target: SurfaceMesh<'_>,
    graph_params: GraphParams,
    params: RegisterParams,
    principal_axes: bool,
    seeding: &Seeding,
) -> Result<SurfaceRegistration, SurfaceError> {
    let meshes = !source.faces.is_empty() && !target.faces.is_empty();
    if seeding.passes == 0 || !meshes {
        // register_meshes checks its meshes' area itself
        has_area(&source, MeshRole::Source)?;
        has_area(&target, MeshRole::Target)?;
        facing_the_source(source, target, |target| {
            let (s, t) = (
                (source.points, source.normals),
                (target.points, target.normals),
            );
            register_surfaces(s, t, graph_params, params.clone(), principal_axes)
        })
    } else {
        register_meshes(
            source,
            target,
            graph_params,
            params,
            principal_axes,
            seeding,
        )
    }
}

/// Registers by `register` onto `target` with its normals pointing the source's way: as they
/// are where both meshes are closed and point the same way, turned over where they point
/// opposite ways (module `orientation`), and where that cannot be told (an open mesh, a cloud)
/// as they are and, when that did not register, turned over, keeping the turned one if it
/// registers ([`SurfaceRegistration::target_normals_turned`]); its summary counts both tries'
/// iterations and seconds.
fn facing_the_source(
    source: SurfaceMesh<'_>,
    target: SurfaceMesh<'_>,
    register: impl Fn(SurfaceMesh<'_>) -> Result<SurfaceRegistration, SurfaceError>,
) -> Result<SurfaceRegistration, SurfaceError> {
    let turned_normals: Vec<Vector3<f64>> = target.normals.iter().map(|n| -n).collect();
    let turned = || {
        let mut reg = register(SurfaceMesh {
            normals: &turned_normals,
            ..target
        })?;
        reg.target_normals_turned = true;
        Ok::<_, SurfaceError>(reg)
    };
    match relation(source.oriented(), target.oriented()) {
        Relation::Same => register(target),
        Relation::Opposite => turned(),
        Relation::Unknown => {
            let first = register(target)?;
            if first.verdict() == SurfaceVerdict::Registered {
                return Ok(first);
            }
            let second = turned()?;
            let (mut kept, other) = if second.verdict() == SurfaceVerdict::Registered {
                (second, first)
            } else {
                (first, second)
            };
            kept.summary.iterations += other.summary.iterations;
            kept.summary.seconds += other.summary.seconds;
            kept.summary.times.add(&other.summary.times);
            Ok(kept)
        }
    }
}

/// Registers one mesh onto another in several passes, for poses far apart whose parts swing
/// past each other (a galloping animal's legs), where closest point pulls a part onto its
/// neighbour.
///
/// 1. [`register_surfaces`] aligns the whole shape, with `seeding.anchor_rounds` rounds per
///    stage; its core lands where it belongs.
/// 2. Every source vertex is matched to the target vertex of nearest geodesic descriptor, with
///    anchors on the source's core and their partners from the pass before
///    ([`DescriptorPair::matches`]).
/// 3. The registration runs again from the start. In its first `seeding.stages` stages a
///    point takes its descriptor match wherever that lies farther than the association gate
///    from its closest-point match ([`WarpOptimiser::optimise_from`]); later stages
///    associate by closest point alone.
///
/// Steps 2 and 3 repeat `seeding.passes` times: a better pass places the anchors better; they
/// stop at a pass that left most of the source off the target ([`SurfaceFit::on_target`]). The
/// later passes start from the first one's rigid pre-alignment. The summary is the last
/// pass's, with the iterations, seconds and stage times of all.
///
/// Meshes with a rim that aligns ([`rim_matches`]: sheets) are registered in one pass instead,
/// its first stage taking the rim's matches where closest point disagrees with them, every
/// stage holding the rim's own vertices to theirs, and closest point taken on the target's
/// triangles ([`MeshTarget`]), not its vertices (NOTES 84). All of it runs in units of the
/// source's bounding-box diagonal, so that it does the same at any size.
///
/// A mesh stored as a triangle soup (vertices repeated at equal positions, one set per triangle,
/// as STL exports are) is registered welded (module `weld`), so that its triangles share
/// their edges; every vertex of `source`, in its order, is then warped by the graph found.
/// Registered as a soup, the camel pair 1 → 3 ended at 3.76 % mean error and 21 % at worst
/// against 0.72 % and 6.3 % welded, and was reported as registered.
///
/// Where both meshes are closed and the target's normals point into it while the source's point
/// out (or the other way round: a mesh wound the other way), the target's normals are turned
/// over (module `orientation`); where a mesh is open, so that no way is known to be right, a
/// registration that did not register is tried again with them turned
/// ([`SurfaceRegistration::target_normals_turned`]).
pub fn register_meshes(
    source: SurfaceMesh<'_>,
    target: SurfaceMesh<'_>,
    graph_params: GraphParams,
    params: RegisterParams,
    principal_axes: bool,
    seeding: &Seeding,
) -> Result<SurfaceRegistration, SurfaceError> {
    has_area(&source, MeshRole::Source)?;
    has_area(&target, MeshRole::Target)?;
    facing_the_source(source, target, |target| {
        as_welded(source, target, |s, t| {
            let params = params.clone();
            register_welded(s, t, graph_params, params, principal_axes, seeding)
        })
    })
}

/// Registers by `register` the meshes welded (module `weld`), and warps every vertex of `source`
/// by the graph found.
fn as_welded(
    source: SurfaceMesh<'_>,
    target: SurfaceMesh<'_>,
    register: impl FnOnce(SurfaceMesh<'_>, SurfaceMesh<'_>) -> Result<SurfaceRegistration, SurfaceError>,
) -> Result<SurfaceRegistration, SurfaceError> {
    let (ws, wt) = (
        weld(source.points, source.normals, source.faces),
        weld(target.points, target.normals, target.faces),
    );
    let mut done = register(welded_view(source, &ws), welded_view(target, &wt))?;
    if ws.is_some() {
        let bindings = done.graph.bind_all(source.points);
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        done.graph.warp_all(
            &bindings,
            source.points,
            source.normals,
            &mut points,
            &mut normals,
        );
        (done.points, done.normals) = (points, normals);
    }
    Ok(done)
}

/// `mesh` welded, when welding joined any of its vertices.
fn welded_view<'a>(mesh: SurfaceMesh<'a>, welded: &'a Option<Welded>) -> SurfaceMesh<'a> {
    match welded {
        Some(w) => SurfaceMesh {
            points: &w.points,
            normals: &w.normals,
            faces: &w.faces,
        },
        None => mesh,
    }
}

/// [`register_meshes`] of meshes whose vertices each have a position of their own.
fn register_welded(
    source: SurfaceMesh<'_>,
    target: SurfaceMesh<'_>,
    graph_params: GraphParams,
    params: RegisterParams,
    principal_axes: bool,
    seeding: &Seeding,
) -> Result<SurfaceRegistration, SurfaceError> {
    let start = std::time::Instant::now();
    let (source_mesh, target_mesh) = (
        MeshRef {
            points: source.points,
            faces: source.faces,
        },
        MeshRef {
            points: target.points,
            faces: target.faces,
        },
    );
    let rim = if seeding.passes > 0 {
        rim_matches(source_mesh, target_mesh)
    } else {
        None
    };
    // A sheet's graph has about a node per vertex, so closest point to the target's vertices
    // would carry each node onto a vertex: where the target is meshed apart, that is up to half
    // its spacing off, along the surface. Its target is the surface itself. The camel's graph has
    // a node per 18 vertices, and there the surface did no better (NOTES 84): its poses are
    // sampled alike, so a vertex's partner is about a vertex. A target sampled coarser than the
    // source is matched to its surface; onto one sampled finer, the coverage distance is measured
    // in the source's widest gaps, where the target's samples fall (NOTES 185).
    let sampling = Sampling::of(source.points, target.points);
    let target_faces = if rim.is_some() || sampling.target_coarser() {
        target.faces
    } else {
        &[]
    };
    let mut params = params;
    if sampling.target_finer() {
        params.cover *= sampling.gap_spacings(source.points);
    }
    let mut passes = Passes::new(
        (source.points, source.normals),
        SurfaceMesh {
            faces: target_faces,
            ..target
        },
        graph_params,
        params,
        principal_axes,
        Some(surface_diagonal(source.points, source.faces)),
    )?;
    let mut done = match rim {
        Some(found) => passes.run_by_rim(found, target.normals, seeding)?,
        None => passes.run_seeded((source_mesh, target_mesh), target.normals, seeding)?,
    };
    done.summary.seconds = start.elapsed().as_secs_f64();
    done.fit.add_areas(
        source.points,
        &done.points,
        source.faces,
        (target.points, target.faces),
    );
    Ok(done)
}

/// How the target is sampled beside the source: the source's sampling spacing
/// ([`sampling_spacing`]) and the target's over it.
struct Sampling {
    source: f64,
    ratio: f64,
}

/// How far apart two samplings may be and still count as alike: the camel's poses, one mesh
/// posed, lie within 2.3 % of each other.
const ALIKE: f64 = 1.25;

impl Sampling {
    fn of(source: &[Vector3<f64>], target: &[Vector3<f64>]) -> Self {
        let (s, t) = (sampling_spacing(source), sampling_spacing(target));
        Self {
            source: s,
            ratio: if s > 0.0 && t > 0.0 { t / s } else { 1.0 },
        }
    }

    /// The gap ([`sampling_gap`]) of the `source` it was measured on, in its sampling
    /// spacings, at least 1: on long, thin triangles a point of the surface can lie several
    /// nearest-neighbour distances from every vertex.
    fn gap_spacings(&self, source: &[Vector3<f64>]) -> f64 {
        if self.source > 0.0 {
            (sampling_gap(source) / self.source).max(1.0)
        } else {
            1.0
        }
    }

    fn target_coarser(&self) -> bool {
        self.ratio > ALIKE
    }

    fn target_finer(&self) -> bool {
        self.ratio < 1.0 / ALIKE
    }
}

impl Passes {
    /// The passes of a mesh without a rim (steps 1–3 of [`register_meshes`]): a first,
    /// unseeded pass of `seeding.anchor_rounds` rounds per stage, then `seeding.passes` passes
    /// seeded by the descriptor matches of the pass before (with the target's `normals`). The
    /// summary counts the iterations and stage times of all.
    fn run_seeded(
        &mut self,
        (source, target): (MeshRef<'_>, MeshRef<'_>),
        normals: &[Vector3<f64>],
        seeding: &Seeding,
    ) -> Result<SurfaceRegistration, SurfaceError> {
        let mut first = self.params.clone();
        if seeding.passes > 0 {
            first.rounds = seeding.anchor_rounds.max(1).min(first.rounds);
        }
        let mut last = self.run_with(first, None)?;
        self.keep_rigid_start(&last.summary.prealigned);
        let (mut iterations, mut times) = (last.summary.iterations, last.summary.times);
        // what the descriptors need that no pass changes, prepared for the first seeded pass
        let mut pair: Option<DescriptorPair<'_>> = None;
        for _ in 0..seeding.passes {
            // anchors are placed by the pass before: one that left the source off the target
            // (a target beyond the rigid gate) has nothing to place them by, and seeds from it
            // carried the camel two diagonals over but 14 % off, with 98 % of it on the target
            // (NOTES 85)
            if last.fit.on_target < MIN_SHARE {
                break;
            }
            if pair.is_none() {
                pair = Some(DescriptorPair::new(source, target, seeding.core_fraction)?);
            }
            let partner = pair
                .as_ref()
                .expect("prepared above")
                .matches(&last.points)?;
            let partner: Vec<MeshPoint> = partner
                .into_iter()
                .map(|k| MeshPoint::vertex(k as u32))
                .collect();
            let next = self.run(Some(&self.seeds(&partner, normals, seeding)))?;
            iterations += next.summary.iterations;
            times.add(&next.summary.times);
            // seeds that carried the shape off (limbs' extremities assigned wrongly) leave it
            // lying on the target less well than the pass before: that pass is kept, and the
            // next would be seeded the same way
            if !fits_as_well(&next.fit, &last.fit) {
                tracing::debug!(
                    before = ?last.fit,
                    seeded = ?next.fit,
                    "a seeded pass fitted worse than the pass before; kept the one before"
                );
                break;
            }
            last = next;
        }
        last.summary.iterations = iterations;
        last.summary.times = times;
        Ok(last)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Mesh;
    use crate::nonrigid::descriptors::tube;
    use nalgebra::{Point3, Vector3};

    #[test]
    fn a_mesh_whose_faces_have_no_area_is_refused() {
        let source = crate::synthetic::plate::flat_grid();
        let mut line = source.clone();
        (line.vertices.iter_mut().enumerate())
            .for_each(|(k, p)| *p = Point3::new(k as f32, 0.0, 0.0));
        let seeding = Seeding::default();
        let refused = |s: &Mesh, t: &Mesh| register_mesh_pair(s, t, &seeding).err();
        assert_eq!(
            refused(&source, &line),
            Some(SurfaceError::NoArea(MeshRole::Target))
        );
        assert_eq!(
            refused(&line, &source),
            Some(SurfaceError::NoArea(MeshRole::Source))
        );
    }

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

    /// A mesh whose triangles are wound against each other gives the normals of the one wound
    /// alike: the faces are oriented before the normals are averaged from them.
    #[test]
    fn mesh_points_orients_the_faces_before_making_normals() {
        let (points, faces) = tube(10, 8, 0.3);
        let mixed: Vec<[u32; 3]> = faces
            .iter()
            .enumerate()
            .map(|(i, &[a, b, c])| if i % 3 == 1 { [a, c, b] } else { [a, b, c] })
            .collect();
        let (wound, unwound) = (with_normals(&points, &faces), with_normals(&points, &mixed));
        assert_eq!(wound.len(), points.len());
        for (i, (n, m)) in wound.iter().zip(&unwound).enumerate() {
            assert!((n - m).norm() < 1e-6, "vertex {i}: {n:?} against {m:?}");
        }
    }

    /// A tube and its copy bent by `bend` radians, with normals.
    struct TubePair {
        source: (Vec<Vector3<f64>>, Vec<Vector3<f64>>),
        target: (Vec<Vector3<f64>>, Vec<Vector3<f64>>),
        faces: Vec<[u32; 3]>,
    }

    impl TubePair {
        fn new(rings: usize, sides: usize, bend: f64) -> Self {
            let (sp, faces) = tube(rings, sides, 0.0);
            let (tp, _) = tube(rings, sides, bend);
            let (sn, tn) = (with_normals(&sp, &faces), with_normals(&tp, &faces));
            Self {
                source: (sp, sn),
                target: (tp, tn),
                faces,
            }
        }

        /// The pair with every point of both tubes mapped by `f` (moved or scaled), normals kept.
        fn mapped(&self, f: impl Fn(&Vector3<f64>) -> Vector3<f64>) -> Self {
            let map = |(p, n): &(Vec<Vector3<f64>>, Vec<Vector3<f64>>)| {
                (p.iter().map(&f).collect(), n.clone())
            };
            Self {
                source: map(&self.source),
                target: map(&self.target),
                faces: self.faces.clone(),
            }
        }

        fn settings(&self) -> (GraphParams, RegisterParams) {
            clean_surface_settings(bounding_diagonal(&self.source.0))
        }

        fn register(&self, passes: usize) -> SurfaceRegistration {
            self.register_weighted(passes, CLOSEST_POINT_WEIGHT)
        }

        /// [`Self::register`] with closest-point partners weighed point-to-point by `weight`.
        fn register_weighted<'a>(&'a self, passes: usize, weight: f64) -> SurfaceRegistration {
            let (graph, mut params) = self.settings();
            params.point_weight = weight;
            let mesh =
                |(points, normals): &'a (Vec<Vector3<f64>>, Vec<Vector3<f64>>)| SurfaceMesh {
                    points,
                    normals,
                    faces: &self.faces,
                };
            let seeding = Seeding {
                passes,
                ..Seeding::default()
            };
            register_meshes(
                mesh(&self.source),
                mesh(&self.target),
                graph,
                params,
                false,
                &seeding,
            )
            .unwrap()
        }

        /// Mean distance from `points` to their partners: vertex k of the bent tube is vertex
        /// k's partner.
        fn error(&self, points: &[Vector3<f64>]) -> f64 {
            let target = &self.target.0;
            let sum: f64 = points.iter().zip(target).map(|(a, b)| (a - b).norm()).sum();
            sum / target.len() as f64
        }
    }

    #[test]
    fn seeded_passes_carry_a_tube_onto_its_bent_copy() {
        let pair = TubePair::new(24, 16, 0.6);
        let before = pair.error(&pair.source.0);
        let one = pair.register(1);
        let two = pair.register(2);
        for (passes, reg) in [(1, &one), (2, &two)] {
            let mean = pair.error(&reg.points);
            assert!(
                mean < 0.01 && before > 0.1,
                "{passes} seeded passes: mean error {mean} (before {before})"
            );
        }
        for reg in [&one, &two] {
            assert_eq!(reg.verdict(), SurfaceVerdict::Registered, "{:?}", reg.fit);
        }
        // Each pass starts from the graph at rest: the second seeded pass is a whole registration
        // of its own, and the summary counts the iterations of all three.
        assert!(two.summary.iterations > one.summary.iterations);
    }

    /// A scan's noise on the target's vertices multiplies its triangles' area, but the verdict
    /// measures areas without it (NOTES 107): onto a bent copy whose vertices are jittered by up
    /// to 0.04 per coordinate (about an edge's length), the tube registers and says so.
    #[test]
    fn a_noisy_target_is_registered() {
        use rand::{RngExt, SeedableRng};
        let mut pair = TubePair::new(48, 32, 0.6);
        let clean = TubePair::new(48, 32, 0.6);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut noise = || rng.random_range(-0.04..0.04);
        for p in pair.target.0.iter_mut() {
            *p += Vector3::new(noise(), noise(), noise());
        }
        pair.target.1 = with_normals(&pair.target.0, &pair.faces);
        let raw = crate::nonrigid::surface_area::area;
        let inflated = raw(&pair.target.0, &pair.faces) / raw(&pair.source.0, &pair.faces);
        assert!(
            inflated > 1.5,
            "the noise raises the target's area {inflated} times"
        );
        let reg = pair.register(1);
        let (before, after) = (clean.error(&pair.source.0), clean.error(&reg.points));
        assert!(
            after < 0.5 * before,
            "against the clean copy {after} (before {before})"
        );
        assert_eq!(reg.verdict(), SurfaceVerdict::Registered, "{:?}", reg.fit);
    }

    /// Onto a copy beyond the rigid gate (two diagonals away), or onto a third of the bent
    /// copy, the optimiser still returns a field; the verdict says it did not register.
    #[test]
    fn a_target_out_of_reach_or_a_part_is_not_registered() {
        let mut far = TubePair::new(12, 8, 0.4);
        let d = bounding_diagonal(&far.source.0);
        far.target.0.iter_mut().for_each(|p| p.x += 2.0 * d);
        let reg = far.register(1);
        assert!(reg.fit.on_target < 0.01, "{:?}", reg.fit);
        assert!(matches!(reg.verdict(), SurfaceVerdict::NotRegistered(_)));
        // the first 4 of 12 rings: their vertices and the faces between them only
        let mut part = TubePair::new(12, 8, 0.4);
        let kept = 4 * 8;
        part.target.0.truncate(kept);
        part.target.1.truncate(kept);
        let faces: Vec<[u32; 3]> = part
            .faces
            .iter()
            .filter(|f| f.iter().all(|&v| (v as usize) < kept))
            .copied()
            .collect();
        let (graph, params) = part.settings();
        let reg = register_meshes(
            SurfaceMesh {
                points: &part.source.0,
                normals: &part.source.1,
                faces: &part.faces,
            },
            SurfaceMesh {
                points: &part.target.0,
                normals: &part.target.1,
                faces: &faces,
            },
            graph,
            params,
            false,
            &Seeding::default(),
        )
        .unwrap();
        assert!(
            matches!(reg.verdict(), SurfaceVerdict::NotRegistered(_)),
            "{:?}",
            reg.fit
        );
    }

    #[test]
    fn no_seeded_pass_is_the_one_pass_registration_in_units_of_the_size() {
        let pair = TubePair::new(12, 8, 0.4);
        let meshes = pair.register(0);
        // the same registration of the pair scaled to a unit diagonal, scaled back
        let d = bounding_diagonal(&pair.source.0);
        let unit = |p: &[Vector3<f64>]| p.iter().map(|p| p / d).collect::<Vec<_>>();
        let (sp, tp) = (unit(&pair.source.0), unit(&pair.target.0));
        let (graph, params) = clean_surface_settings(1.0);
        let surfaces = register_surfaces(
            (&sp, &pair.source.1),
            (&tp, &pair.target.1),
            graph,
            params,
            false,
        )
        .unwrap();
        assert_eq!(meshes.summary.iterations, surfaces.summary.iterations);
        // (both centred on the source's centroid, computed before and after the scaling)
        for (a, b) in meshes.points.iter().zip(&surfaces.points) {
            assert!((a - b * d).norm() < 1e-6 * d, "{a:?} {:?}", b * d);
        }
        // and the graph comes back in the caller's units
        let spacing = meshes.graph.params.spacing;
        assert!((spacing - 0.03 * d).abs() < 1e-12 * d, "{spacing}");
    }

    #[test]
    fn a_registration_of_meshes_is_the_same_at_any_size() {
        let pair = TubePair::new(12, 8, 0.4);
        let base = pair.register(1);
        for k in [0.05, 20.0] {
            let reg = pair.mapped(|p| p * k).register(1);
            for (a, b) in reg.points.iter().zip(&base.points) {
                assert!((a - b * k).norm() < 1e-6 * k, "at {k}: {a:?} {:?}", b * k);
            }
        }
    }

    /// A mesh stored as a triangle soup: three vertices of its own per triangle, in the
    /// triangles' order.
    fn soup(mesh: &Mesh) -> Mesh {
        let corners = mesh.faces.iter().flatten().map(|&v| v as usize);
        Mesh {
            vertices: corners.clone().map(|v| mesh.vertices[v]).collect(),
            normals: corners.map(|v| mesh.normals[v]).collect(),
            faces: (0..mesh.faces.len() as u32)
                .map(|f| [3 * f, 3 * f + 1, 3 * f + 2])
                .collect(),
            ..Mesh::default()
        }
    }

    /// A sheet stored as a triangle soup is registered by its rim as the mesh with shared
    /// vertices is (issue 26's bounds: the largest vertex error at most 10 % of the largest
    /// displacement, the mean 3 %), and every vertex of the soup is warped, in its order. As
    /// soups, each triangle's edges are all rim: the S-bend ended 19 % off at its worst and 13 %
    /// on average.
    #[test]
    fn a_mesh_stored_as_a_triangle_soup_registers_as_the_welded_mesh() {
        use crate::synthetic::sheet::{case_motion, flat_sheet, SheetDeformation, SheetShape};
        let width = 0.5;
        let case = SheetDeformation {
            shape: SheetShape::SBend { tilt: 1.2 },
            rigid: Some(case_motion(15.0, 0.03)),
        };
        let source = flat_sheet(21, 13, width);
        let target = case.deformed(&source, width);
        let reg = register_mesh_pair(&soup(&source), &soup(&target), &Seeding::default()).unwrap();
        assert_eq!(reg.points.len(), 3 * source.faces.len());
        // each vertex of the sheet where the soup first repeats it
        let mut warped = vec![Vector3::zeros(); source.vertices.len()];
        let corners: Vec<u32> = source.faces.iter().flatten().copied().collect();
        for (corner, &v) in corners.iter().enumerate().rev() {
            warped[v as usize] = reg.points[corner];
        }
        let score = case.score(&source, &warped, width);
        assert!(
            score.max <= 0.10 && score.mean <= 0.03,
            "max {}, mean {}",
            score.max,
            score.mean
        );
    }

    /// Moved far from the origin, a pair registers as it does where it lies: the passes turn it
    /// about its centroid. Turned about the origin, the camel pair 1 → 3 moved 24 diagonals out
    /// ended at 1.08 % mean error against 0.75 % in place, and this tube did not end where it
    /// did in place either. Run at point-to-point weight 1: this tube is exactly symmetric, and
    /// where rounding breaks its ties differently (placements about 90 diagonals out) a weight
    /// of 0.3–0.5 ended in another basin at 2 of 16 placements, 0.7 and 1 at none (NOTES 178).
    #[test]
    fn a_registration_of_meshes_is_the_same_wherever_the_shape_lies() {
        let pair = TubePair::new(12, 8, 0.4);
        let base = pair.register_weighted(1, 1.0);
        let d = bounding_diagonal(&pair.source.0);
        for o in [Vector3::new(1.5, 0.0, 0.0), Vector3::new(30.0, -20.0, 50.0)] {
            let o = o * d;
            let reg = pair.mapped(|p| p + o).register_weighted(1, 1.0);
            for (a, b) in reg.points.iter().zip(&base.points) {
                assert!((a - o - b).norm() < 1e-6 * d, "at {o:?}: {:?} {b:?}", a - o);
            }
            let t = reg.summary.prealigned;
            let expected = base.summary.prealigned.translation.vector + o
                - base.summary.prealigned.rotation * o;
            assert!((t.translation.vector - expected).norm() < 1e-6 * d, "{t:?}");
        }
    }

    /// Normals pointing the other way on the target alone (a mesh wound the other way round)
    /// are turned over when both meshes are closed: an ellipsoid onto its bent copy registers as
    /// onto the copy wound as it is. An open tube has no inside to tell which way is right: onto
    /// a target whose normals all point the other way it did not register (12 % of it on the
    /// target), and is registered again with them turned, as onto the target as it was.
    #[test]
    fn a_target_wound_the_other_way_is_registered_with_its_normals_turned() {
        use crate::nonrigid::orientation::tests::sphere;
        let (ball, faces) = sphere(1.0, Vector3::zeros(), 12);
        let source: Vec<Vector3<f64>> = ball
            .iter()
            .map(|p| p.component_mul(&Vector3::new(1.0, 0.5, 0.5)))
            .collect();
        let bent: Vec<Vector3<f64>> = source
            .iter()
            .map(|p| p + Vector3::z() * 0.3 * p.x * p.x)
            .collect();
        let reversed: Vec<[u32; 3]> = faces.iter().map(|&[a, b, c]| [a, c, b]).collect();
        let (sn, tn, tn_in) = (
            with_normals(&source, &faces),
            with_normals(&bent, &faces),
            with_normals(&bent, &reversed),
        );
        let (graph, params) = clean_surface_settings(bounding_diagonal(&source));
        let register = |target: SurfaceMesh<'_>| {
            let source = SurfaceMesh {
                points: &source,
                normals: &sn,
                faces: &faces,
            };
            let seeding = Seeding::default();
            register_meshes(source, target, graph, params.clone(), false, &seeding).unwrap()
        };
        let same = register(SurfaceMesh {
            points: &bent,
            normals: &tn,
            faces: &faces,
        });
        let turned = register(SurfaceMesh {
            points: &bent,
            normals: &tn_in,
            faces: &reversed,
        });
        assert!(!same.target_normals_turned && turned.target_normals_turned);
        assert_eq!(
            turned.verdict(),
            SurfaceVerdict::Registered,
            "{:?}",
            turned.fit
        );
        let d = bounding_diagonal(&source);
        for (a, b) in turned.points.iter().zip(&same.points) {
            assert!((a - b).norm() < 1e-6 * d, "{a:?} {b:?}");
        }
        let mut pair = TubePair::new(12, 8, 0.4);
        let as_wound = pair.register(1);
        pair.target.1.iter_mut().for_each(|n| *n = -*n);
        let open = pair.register(1);
        assert!(!as_wound.target_normals_turned && open.target_normals_turned);
        assert_eq!(open.verdict(), SurfaceVerdict::Registered, "{:?}", open.fit);
        let d = bounding_diagonal(&pair.source.0);
        for (a, b) in open.points.iter().zip(&as_wound.points) {
            assert!((a - b).norm() < 1e-6 * d, "{a:?} {b:?}");
        }
    }

    /// A point cloud without normals gets none made up: as the target it is refused, as the
    /// source the optimiser refuses it, each with an error rather than a registration by +z.
    #[test]
    fn a_cloud_without_normals_is_refused() {
        let pair = TubePair::new(12, 8, 0.4);
        let mesh = |p: &[Vector3<f64>]| Mesh {
            vertices: p.iter().map(|p| Point3::from(p.cast::<f32>())).collect(),
            faces: pair.faces.clone(),
            ..Mesh::default()
        };
        let (source, target) = (mesh(&pair.source.0), mesh(&pair.target.0));
        let cloud = |m: &Mesh| Mesh {
            faces: Vec::new(),
            ..m.clone()
        };
        assert!(mesh_points(&cloud(&target)).1.is_empty());
        let seeding = Seeding::default();
        assert_eq!(
            register_mesh_pair(&source, &cloud(&target), &seeding).unwrap_err(),
            SurfaceError::TargetNormals {
                points: target.vertices.len(),
                normals: 0
            }
        );
        assert!(matches!(
            register_mesh_pair(&cloud(&source), &target, &seeding),
            Err(SurfaceError::Register(RegisterError::Mismatch {
                normals: 0,
                ..
            }))
        ));
    }

    /// The later passes start from the first pass's rigid motion, carried in the caller's
    /// units (a tube 20 times the size, so that a unit slip would show) and reported.
    #[test]
    fn the_passes_share_the_rigid_start_in_the_callers_units() {
        let mut pair = TubePair::new(12, 8, 0.0);
        let shift = Vector3::new(0.3, -0.2, 0.1) * 0.1 * bounding_diagonal(&pair.source.0);
        for p in pair.source.0.iter_mut().chain(pair.target.0.iter_mut()) {
            *p *= 20.0;
        }
        pair.target.0.iter_mut().for_each(|p| *p += shift * 20.0);
        let reg = pair.register(2);
        let t = reg.summary.prealigned;
        assert!((t.translation.vector - shift * 20.0).norm() < 1e-3 * shift.norm() * 20.0);
        assert!(t.rotation.angle() < 1e-3, "{t:?}");
        let d = bounding_diagonal(&pair.source.0);
        assert!(
            pair.error(&reg.points) < 1e-3 * d,
            "{}",
            pair.error(&reg.points)
        );
    }

    /// A strip 1 × 0.2 of 121 × 25 points, its far half folded up by `fold` radians about the
    /// line x = ½; a point's partner on the flat strip is the same point unfolded.
    fn folded_strip(fold: f64) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let (sin, cos) = fold.sin_cos();
        let mut points = Vec::new();
        let mut normals = Vec::new();
        for j in 0..25 {
            for i in 0..121 {
                let (x, y) = (i as f64 / 120.0, j as f64 * 0.2 / 24.0);
                let t = (x - 0.5).max(0.0);
                points.push(Vector3::new(x.min(0.5) + t * cos, y, t * sin));
                normals.push(if t > 0.0 {
                    Vector3::new(-sin, 0.0, cos)
                } else {
                    Vector3::z()
                });
            }
        }
        (points, normals)
    }

    /// Closest point from the folded strip alone leaves the flap short of the flat strip's far
    /// end; the coverage matches draw it out (module `coverage`). Run at the point-to-point
    /// weight the matches were built under (1): at [`CLOSEST_POINT_WEIGHT`] closest point alone
    /// draws the flap most of the way (mean 0.0134 against 0.0157), and the coverage adds less.
    #[test]
    fn coverage_matches_draw_a_folded_flap_out_to_the_end() {
        let (source, target) = (folded_strip(0.4), folded_strip(0.0));
        let errors = |cover: f64| {
            let (graph, mut params) = clean_surface_settings(bounding_diagonal(&source.0));
            params.cover = cover;
            params.point_weight = 1.0;
            let reg = register_surfaces(
                (&source.0, &source.1),
                (&target.0, &target.1),
                graph,
                params,
                false,
            )
            .unwrap();
            let e: Vec<f64> = reg
                .points
                .iter()
                .zip(&target.0)
                .map(|(a, b)| (a - b).norm())
                .collect();
            let mean = e.iter().sum::<f64>() / e.len() as f64;
            (mean, e.iter().copied().fold(0.0, f64::max))
        };
        let (without, with) = (errors(0.0), errors(COVER_SPACINGS));
        assert!(
            with.0 < 0.9 * without.0 && with.1 < 0.8 * without.1,
            "mean and largest error with coverage {with:?}, without {without:?}"
        );
    }

    #[test]
    fn a_pass_is_kept_unless_it_lies_on_the_target_worse_than_the_one_before() {
        let fit = |on_target, covered| SurfaceFit {
            on_target,
            covered,
            facing: 1.0,
            median_distance: 0.0,
            tolerance: 0.03,
            area_ratio: None,
            source_area_ratio: None,
        };
        let before = fit(1.0, 0.95);
        assert!(fits_as_well(&fit(1.0, 0.99), &before));
        assert!(fits_as_well(&fit(0.99, 0.94), &before), "within the slack");
        assert!(
            !fits_as_well(&fit(0.98, 0.86), &before),
            "a shape carried off"
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
            point_weight: 1.0,
            replace_all: false,
            iterations: 2,
            pinned: Vec::new(),
        };
        let result = WarpOptimiser::new(params).optimise_from(
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

    /// The thesis' plain sheet (21 × 13 vertices, 0.5 m) stretched by 1.3 along its length lies
    /// on its target as closely as a right registration does, but nothing on it tells where each
    /// point goes: its moment stretches lay it as closely at each of its symmetries, so the
    /// affine maps disagree and it is not registered (before NOTES 199 the round trip refused
    /// it: the way back disagreed with the way out by 0.77 of the displacement). Rolled half
    /// round (a bend that keeps its lengths) it registers, and its round trip holds.
    #[test]
    fn a_featureless_sheet_stretched_does_not_come_back_and_is_not_registered() {
        use crate::synthetic::sheet::{flat_sheet, SheetDeformation, SheetShape};
        let sheet = flat_sheet(21, 13, 0.5);
        let mut stretched = sheet.clone();
        for v in &mut stretched.vertices {
            v.x *= 1.3;
        }
        let reg = register_mesh_pair(&sheet, &stretched, &Seeding::default()).unwrap();
        assert!(
            reg.fit.verdict() == SurfaceVerdict::Registered,
            "{:?}",
            reg.fit
        );
        let SurfaceVerdict::MapsDisagree(apart) = reg.verdict() else {
            panic!("{:?} {:?}", reg.verdict(), reg.round_trip);
        };
        assert!(apart.apart > 100.0 * apart.limit, "{apart:?}");
        assert!(!reg.placed_affine && !reg.placed_rigid);
        let roll = SheetDeformation {
            shape: SheetShape::Roll {
                angle: std::f64::consts::PI,
            },
            rigid: None,
        };
        let rolled = roll.deformed(&sheet, 0.5);
        let reg = register_mesh_pair(&sheet, &rolled, &Seeding::default()).unwrap();
        assert_eq!(reg.verdict(), SurfaceVerdict::Registered);
        let trip = reg.round_trip.unwrap();
        assert!(trip.holds() && trip.ratio() < 0.1, "{trip:?}");
    }

    /// A closed mesh with `points` and `faces`, its normals from the faces.
    fn closed_mesh(points: &[Vector3<f64>], faces: &[[u32; 3]]) -> Mesh {
        let mut mesh = Mesh {
            vertices: points.iter().map(|p| p.cast::<f32>().into()).collect(),
            faces: faces.to_vec(),
            ..Mesh::default()
        };
        mesh.compute_normals();
        mesh
    }

    /// A sphere mesh made an ellipsoid (axes 0.3, 0.21, 0.14 m, turned), its radius first
    /// modulated by `bumps` (a function of the unit sphere's point), with its faces and its
    /// long axis.
    fn egg(
        bumps: impl Fn(&Vector3<f64>) -> f64,
    ) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>, Vector3<f64>) {
        use crate::nonrigid::orientation::tests::sphere;
        let (unit, faces) = sphere(1.0, Vector3::zeros(), 16);
        let turn = nalgebra::Rotation3::from_euler_angles(0.4, -0.7, 1.1);
        let points = (unit.iter())
            .map(|p| turn * (bumps(p) * p).component_mul(&Vector3::new(0.3, 0.21, 0.14)))
            .collect();
        (points, faces, turn * Vector3::x())
    }

    /// `source` onto `target` (both closed, over `faces`) by `register_mesh_pair`, and the
    /// largest distance of a result from its target point over the largest displacement.
    fn registered_onto(
        source: &[Vector3<f64>],
        target: &[Vector3<f64>],
        faces: &[[u32; 3]],
    ) -> (SurfaceRegistration, f64) {
        let (from, to) = (closed_mesh(source, faces), closed_mesh(target, faces));
        let reg = register_mesh_pair(&from, &to, &Seeding::default()).unwrap();
        let reach = (source.iter().zip(target))
            .map(|(p, q)| (q - p).norm())
            .fold(0.0, f64::max);
        let worst = (reg.points.iter().zip(target))
            .map(|(p, q)| (p - q).norm())
            .fold(0.0, f64::max);
        (reg, worst / reach)
    }

    /// A bumpy egg stretched by 1.25 along its long axis lies on its target under many warps,
    /// and the warp's regulariser slides it (NOTES 195); the affine map that lays it on the
    /// target is the stretch, and is taken: every vertex within 1 % of the largest
    /// displacement. A plain ellipsoid has a family of such maps (module `affine_slippage`), and
    /// stretched it is reported ambiguous whichever the registration chose (NOTES 197); turned,
    /// it is refused (its half turns lay it as exactly), and the bumpy egg turned is placed by
    /// its rigid motion; bent, neither is placed by a map.
    #[test]
    fn a_stretched_egg_is_placed_by_its_affine_map_and_a_stretched_ellipsoid_is_ambiguous() {
        use crate::nonrigid::orientation::tests::bumps;
        let stretch = |(points, faces, axis): (Vec<Vector3<f64>>, Vec<[u32; 3]>, Vector3<f64>)| {
            let moved: Vec<Vector3<f64>> = (points.iter())
                .map(|p| p + axis * (0.25 * p.dot(&axis)))
                .collect();
            (points, moved, faces)
        };
        let (source, target, faces) = stretch(egg(bumps));
        let (reg, worst) = registered_onto(&source, &target, &faces);
        assert_eq!(reg.verdict(), SurfaceVerdict::Registered);
        assert!(reg.placed_affine && reg.round_trip.is_none());
        assert!(worst < 0.01, "{worst}");
        let (source, target, faces) = stretch(egg(|_| 1.0));
        let (reg, _) = registered_onto(&source, &target, &faces);
        let SurfaceVerdict::AffineAmbiguous(slide) = reg.verdict() else {
            panic!("{:?} {:?}", reg.verdict(), reg.affine_slide());
        };
        assert!(
            slide.ratios[0] < 1e-4 && slide.departure > 10.0 * slide.limit,
            "{slide:?}"
        );
        // moved and turned, it lies as exactly on its target under the turn after each of its
        // half turns about its axes: the maps disagree, none is taken, and it is not
        // registered (the warp alone slid it along itself, NOTES 197–198)
        let turn = nalgebra::Rotation3::from_euler_angles(0.3, 0.2, -0.5);
        let moved: Vec<Vector3<f64>> = (source.iter())
            .map(|p| turn * p + Vector3::new(0.02, 0.0, 0.01))
            .collect();
        let (reg, _) = registered_onto(&source, &moved, &faces);
        assert_ne!(reg.verdict(), SurfaceVerdict::Registered);
        let apart = reg.maps_apart.unwrap();
        assert!(apart.apart > 10.0 * apart.limit, "{apart:?}");
        assert!(!reg.placed_rigid && !reg.placed_affine);
        // the bumpy egg has no such turn, and is placed by its rigid motion; turned 150° too,
        // where the motion from the centroids alone stops short (NOTES 198)
        let (bumpy, _, _) = egg(bumps);
        for (angle, axis) in [
            (30.0, Vector3::z()),
            (150f64, Vector3::new(0.4, -0.5, 0.75)),
        ] {
            let axis = nalgebra::Unit::new_normalize(axis);
            let turn = nalgebra::Rotation3::from_axis_angle(&axis, angle.to_radians());
            let moved: Vec<Vector3<f64>> = (bumpy.iter())
                .map(|p| turn * p + Vector3::new(0.02, 0.0, 0.01))
                .collect();
            let (reg, worst) = registered_onto(&bumpy, &moved, &faces);
            assert_eq!(reg.verdict(), SurfaceVerdict::Registered, "{angle}°");
            assert!(reg.placed_rigid && worst < 1e-3, "{angle}° {worst}");
        }
        let bent: Vec<Vector3<f64>> = source
            .iter()
            .map(|p| {
                let a = 1.5 * p.x;
                Vector3::new(
                    (1.0 / 1.5 - p.z) * a.sin(),
                    p.y,
                    1.0 / 1.5 - (1.0 / 1.5 - p.z) * a.cos(),
                )
            })
            .collect();
        let (reg, _) = registered_onto(&source, &bent, &faces);
        assert!(!reg.placed_affine && !reg.placed_rigid, "{:?}", reg.fit);
    }

    /// A flat rectangle lies on itself after half a turn about its normal. Turned 150° about
    /// it, the warp laid it exactly at that half turn's member, 52–56 % off, and it was
    /// reported registered (NOTES 198); the rigid motions from its principal axes lay it as
    /// exactly at both, and it is refused.
    #[test]
    fn a_flat_sheet_turned_150_degrees_is_refused_where_its_half_turn_fits_as_well() {
        use crate::synthetic::sheet::flat_sheet;
        let sheet = flat_sheet(21, 13, 0.5);
        let (points, _) = mesh_points(&sheet);
        let turn = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 150f64.to_radians());
        let moved: Vec<Vector3<f64>> = (points.iter())
            .map(|p| turn * p + Vector3::new(0.01, -0.02, 0.005))
            .collect();
        let (reg, _) = registered_onto(&points, &moved, &sheet.faces);
        let SurfaceVerdict::MapsDisagree(apart) = reg.verdict() else {
            panic!("{:?} {:?}", reg.verdict(), reg.maps_apart);
        };
        assert!(apart.apart > 10.0 * apart.limit, "{apart:?}");
        assert!(!reg.placed_rigid && !reg.placed_affine);
    }

    /// An L-shaped sheet (0.5 × 0.3 m on a 21 × 13 lattice, a corner of 9 × 6 cells cut out),
    /// open: its vertices and faces, the vertices no face uses left out.
    fn l_sheet() -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let (columns, rows) = (21, 13);
        let cut = |i: usize, j: usize| i >= 12 && j >= 7;
        let mut index = vec![u32::MAX; columns * rows];
        let mut points = Vec::new();
        let mut faces = Vec::new();
        let mut at = |i: usize, j: usize| {
            let k = j * columns + i;
            if index[k] == u32::MAX {
                index[k] = points.len() as u32;
                points.push(Vector3::new(0.025 * i as f64, 0.025 * j as f64, 0.0));
            }
            index[k]
        };
        for (i, j) in (0..rows - 1).flat_map(|j| (0..columns - 1).map(move |i| (i, j))) {
            if !cut(i, j) {
                let [a, b, c, d] = [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)];
                faces.extend([[a, b, c], [a, c, d]]);
            }
        }
        (points, faces)
    }

    /// The L-shaped sheet stretched by 1.25 along its longest principal axis, then turned 120°
    /// and moved: nothing in the plane tells the warp where each point goes, and one moment
    /// stretch lays the sheet exactly; it is taken, every vertex within 0.1 % of the largest
    /// displacement. Stretched along a direction 40° off that axis, a whitened turn refined
    /// lays it as exactly. The plain rectangle stretched and turned is refused: its four moment
    /// stretches each lay it at one of its symmetries (NOTES 199).
    #[test]
    fn an_l_shaped_sheet_stretched_and_turned_is_placed_by_its_moment_stretch() {
        let (points, faces) = l_sheet();
        let centre = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
        let spread = (points.iter())
            .map(|p| (p - centre) * (p - centre).transpose())
            .sum::<nalgebra::Matrix3<f64>>();
        let eig = spread.symmetric_eigen();
        let axis = eig.eigenvectors.column(eig.eigenvalues.imax()).into_owned();
        let turn = nalgebra::Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(0.3, -0.8, 0.5)),
            120f64.to_radians(),
        );
        // along that axis, a moment stretch; 40° off it in the sheet's plane, a whitened turn
        let off = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 40f64.to_radians());
        for along in [axis, off * axis] {
            let moved: Vec<Vector3<f64>> = (points.iter())
                .map(|p| {
                    let stretched = p + 0.25 * (p - centre).dot(&along) * along;
                    turn * stretched + Vector3::new(0.02, -0.01, 0.03)
                })
                .collect();
            let (reg, worst) = registered_onto(&points, &moved, &faces);
            let verdict = reg.verdict();
            assert_eq!(verdict, SurfaceVerdict::Registered, "{:?}", reg.maps_apart);
            assert!(reg.placed_affine && !reg.placed_rigid);
            assert!(worst < 1e-3, "{worst}");
        }
        let sheet = crate::synthetic::sheet::flat_sheet(21, 13, 0.5);
        let (points, _) = mesh_points(&sheet);
        let moved: Vec<Vector3<f64>> = (points.iter())
            .map(|p| turn * Vector3::new(1.25 * p.x, p.y, p.z) + Vector3::new(0.02, -0.01, 0.03))
            .collect();
        let (reg, _) = registered_onto(&points, &moved, &sheet.faces);
        let SurfaceVerdict::MapsDisagree(apart) = reg.verdict() else {
            panic!("{:?} {:?}", reg.verdict(), reg.maps_apart);
        };
        assert!(apart.apart > 10.0 * apart.limit, "{apart:?}");
    }
}
