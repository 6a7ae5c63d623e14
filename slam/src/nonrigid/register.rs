//! The warp-field optimiser (thesis 4.4): the node motions of a [`DeformationGraph`] that carry a
//! canonical surface onto a target, minimising
//!
//! ```text
//! E = Σ_points ρ_Tukey(nᵀ(W(v) − q)) + w_pt Σ_points ρ_Tukey(|W(v) − q|) + λ Σ_edges φ_ij |A_i g_j − A_j g_j|²
//! ```
//!
//! (eq. 4.4-4.7), plus, for a target with intensities, the photometric term
//! `λ_I Σ_points ρ_Tukey(N(π(W(v))) − N_ref)` (module `photometric`), with correspondences (q, n)
//! re-found between rounds (closest point or projective) and rejected by distance and normal
//! angle. Coarse to fine: a rigid point-to-plane pre-alignment
//! (the solver's dense 6-DoF path), then stages of decreasing λ, each a few association rounds of
//! Levenberg-Marquardt on the solver's block-sparse Cholesky ([`dynamap_solver::BlockSystem`]):
//! 6×6 node blocks assembled in the blend's coordinates (module `system`), and one symbolic
//! factorisation for as long as the graph stays the same and the points' node pairs fit its
//! structure (rounds, stages, and further calls and frames).

use super::coverage::{sampling_spacing, Coverage, CoverageGates};
use super::graph::{Binding, DeformationGraph};
use super::linear_steps::{LinearEffort, LinearSteps};
use super::photometric::{PhotometricFit, PhotometricTarget};
use super::system::{match_terms, Minimised, Photometric, Steps, WarpSystem, WarpTerms};
use crate::camera::Camera;
use crate::image::{valid, NormalMap, VertexMap};
use dynamap_residuals::deform::{
    as_rigid_as_possible, dual_quaternion, rigid_motion, MAX_NEIGHBOURS,
};
use dynamap_residuals::icp::{point_to_plane, RigidMotion};
use dynamap_solver::dense::{self, DenseOptions, DenseTerms, DenseWorkspace, Group};
use dynamap_solver::lie::se3;
use dynamap_solver::robust::Huber;
use dynamap_solver::FactorPrecision;
use dynamap_solver::{SolveError, SE3};
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;
use std::time::Instant;

/// Why an optimisation failed.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum RegisterError {
    /// The solver refused it.
    #[error("warp-field solve: {0}")]
    Solve(#[from] SolveError),
    /// Points, normals and bindings that do not belong together.
    #[error("{points} points, {normals} normals and {bindings} bindings (to {nodes} nodes) do not match")]
    Mismatch {
        /// Points given.
        points: usize,
        /// Normals given.
        normals: usize,
        /// Bindings given.
        bindings: usize,
        /// Nodes in the graph.
        nodes: usize,
    },
    /// Reference intensities that are not one per point.
    #[error("{references} reference intensities for {points} points")]
    Intensities {
        /// Intensities given.
        references: usize,
        /// Points given.
        points: usize,
    },
    /// Seeds that are not one per point.
    #[error("{seeds} seed correspondences for {points} points")]
    Seeds {
        /// Seeds given.
        seeds: usize,
        /// Points given.
        points: usize,
    },
    /// A pinned seed names a point that is not there.
    #[error("seed {index} is pinned, but there are {points} points")]
    Pinned {
        /// The index named.
        index: u32,
        /// Points given.
        points: usize,
    },
}

/// A whole-shape target's points and their unit normals ([`Target::samples`]).
pub type Samples<'a> = (&'a [Vector3<f64>], &'a [Vector3<f64>]);

/// Where warped points find their partners.
pub trait Target: Sync {
    /// The target point and unit normal associated with the warped point `p` (before rejection).
    fn associate(&self, p: &Vector3<f64>) -> Option<(Vector3<f64>, Vector3<f64>)>;

    /// [`Self::associate`] for a point whose partner at the last association was the target's
    /// point `*last` (`u32::MAX` for none; [`Self::samples`]' index): a target that can tell
    /// without a search that it still is keeps it, and writes the partner it found to `last`
    /// otherwise. The answer is the one [`Self::associate`] gives; by default it is that call.
    fn associate_from(
        &self,
        p: &Vector3<f64>,
        last: &mut u32,
    ) -> Option<(Vector3<f64>, Vector3<f64>)> {
        let _ = last;
        self.associate(p)
    }

    /// The live intensities and the data points' reference intensities, for the photometric
    /// term (module `photometric`), if the target has them.
    fn photometric(&self) -> Option<PhotometricTarget<'_>> {
        None
    }

    /// The live chromaticities and the data points' reference chromaticities (where each was
    /// first seen, or its own source pixel's), for the chromaticity term (module `chroma`), if
    /// the target has them.
    fn chroma(&self) -> Option<PhotometricTarget<'_>> {
        None
    }

    /// The target's own points and unit normals, for coverage matches (module `coverage`), if it
    /// is a whole shape: a mesh or a cloud, not a view.
    fn samples(&self) -> Option<Samples<'_>> {
        None
    }
}

/// A live depth frame's vertex and normal maps (camera frame), associated projectively.
#[derive(Clone, Copy)]
pub struct DepthTarget<'a> {
    /// Intrinsics of the maps.
    pub camera: &'a Camera,
    /// Vertices.
    pub vertices: &'a VertexMap,
    /// Normals.
    pub normals: &'a NormalMap,
}

impl Target for DepthTarget<'_> {
    fn associate(&self, p: &Vector3<f64>) -> Option<(Vector3<f64>, Vector3<f64>)> {
        let (x, y) = self.camera.project_to_pixel(&Point3::from(*p))?;
        let i = y * self.vertices.width + x;
        let (v, n) = (self.vertices.data[i], self.normals.data[i]);
        if !valid(&v) || !valid(&n) {
            return None;
        }
        Some((
            Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64),
            Vector3::new(n[0] as f64, n[1] as f64, n[2] as f64),
        ))
    }
}

/// A live depth frame with its colour: projective association as [`DepthTarget`], and the
/// photometric and chromaticity terms beside it.
pub struct TexturedDepthTarget<'a> {
    /// The depth.
    pub depth: DepthTarget<'a>,
    /// The intensities over their local means, with references from a recent frame.
    pub photometric: Option<PhotometricTarget<'a>>,
    /// The chromaticities, with each point's first-seen one as its reference.
    pub chroma: Option<PhotometricTarget<'a>>,
}

impl Target for TexturedDepthTarget<'_> {
    fn associate(&self, p: &Vector3<f64>) -> Option<(Vector3<f64>, Vector3<f64>)> {
        self.depth.associate(p)
    }

    fn photometric(&self) -> Option<PhotometricTarget<'_>> {
        self.photometric
    }

    fn chroma(&self) -> Option<PhotometricTarget<'_>> {
        self.chroma
    }
}

/// Optimiser settings.
#[derive(Clone, Debug, PartialEq)]
pub struct RegisterParams {
    /// Gauss-Newton iterations of the rigid pre-alignment (0: none, the closest starting guess is
    /// taken as it is; default 30).
    pub rigid_iterations: usize,
    /// Correspondences of the rigid pre-alignment farther than this are rejected, metres (default
    /// 0.5: it has to bridge the whole initial misalignment).
    pub rigid_max_distance: f64,
    /// Points the rigid pre-alignment fits and scores at most, taken evenly through the points
    /// (default 0: all). A rigid motion has six unknowns, so a few thousand points fix it as
    /// well as all of them; tracking, which pre-aligns every frame, takes fewer.
    pub rigid_points: usize,
    /// Regulariser weights λ, one stage each, largest first (default 100, 10, 1, 0.1).
    pub schedule: Vec<f64>,
    /// Association rounds per stage (default 4).
    pub rounds: usize,
    /// Levenberg-Marquardt iterations per round (default 4).
    pub iterations: usize,
    /// Correspondences farther than this are rejected, metres (default 0.1).
    pub max_distance: f64,
    /// … or with normals further apart than this, degrees (default 45).
    pub max_normal_angle_deg: f64,
    /// Tukey's c of the data terms, metres (default 0.05).
    pub tukey: f64,
    /// Weight of the point-to-point term beside point-to-plane (default 0.1; 0 leaves it out).
    pub point_weight: f64,
    /// Weight w of a prior holding each node near its motion after the rigid pre-alignment,
    /// `√w Log(A₀⁻¹ A)` (default 0: none). Tracking uses it: surface that slides along itself
    /// leaves no trace in depth, so without it such motions are free.
    pub stay_weight: f64,
    /// Levenberg-Marquardt's initial damping τ: each round starts from μ = τ max diag H (default
    /// 1e-4, the solver's). Tracking from the last frame's field starts near the optimum, where a
    /// small τ lets the first steps go most of the way.
    pub damping: f64,
    /// How each step solves its linear system (default [`LinearSteps::Factorise`]). Tracking,
    /// where each frame starts at the last one's field, takes truncated conjugate-gradient
    /// steps instead.
    pub linear: LinearSteps,
    /// Weight λ of the photometric term `λ ρ(I(π(W(v))) − I_ref)` beside the depth terms, for a
    /// target that has intensities ([`Target::photometric`]; default 0: none). Intensities are
    /// in [0, 1] and the depth residuals in metres, so λ is the ratio of their noise variances.
    pub photometric_weight: f64,
    /// Tukey's c of the photometric term, intensity units (default 0.1).
    pub photometric_tukey: f64,
    /// Weight of the chromaticity term `λ ρ(c(π(W(v))) − c_ref)` (module `chroma`), for a target
    /// that has chromaticities ([`Target::chroma`]; default 0: none).
    pub chroma_weight: f64,
    /// Tukey's c of the chromaticity term (default 0.1).
    pub chroma_tukey: f64,
    /// Coverage distance, in multiples of the points' sampling spacing (their median distance to
    /// the nearest other point): in every round, a sample of a whole-shape target
    /// ([`Target::samples`]) farther than this from every warped point is uncovered, and the
    /// warped point nearest it takes it as its partner (module `coverage`; default 0: none; a
    /// view's target, a depth frame, has no samples).
    pub cover: f64,
}

impl Default for RegisterParams {
    fn default() -> Self {
        Self {
            rigid_iterations: 30,
            rigid_max_distance: 0.5,
            rigid_points: 0,
            schedule: vec![100.0, 10.0, 1.0, 0.1],
            rounds: 4,
            iterations: 4,
            max_distance: 0.1,
            max_normal_angle_deg: 45.0,
            tukey: 0.05,
            point_weight: 0.1,
            stay_weight: 0.0,
            damping: 1e-4,
            linear: LinearSteps::Factorise,
            photometric_weight: 0.0,
            photometric_tukey: 0.1,
            chroma_weight: 0.0,
            chroma_tukey: 0.1,
            cover: 0.0,
        }
    }
}

/// Correspondences given per point for the first stages of an optimisation, overriding
/// association where the two disagree ([`WarpOptimiser::optimise_from`]): for parts that
/// closest point would pull onto the wrong partner, such as legs that swing past each other.
#[derive(Clone, Debug, PartialEq)]
pub struct Seeds {
    /// One target point and unit normal per source point.
    pub matches: Vec<(Vector3<f64>, Vector3<f64>)>,
    /// How many stages of the schedule use them (the rest associate as usual).
    pub stages: usize,
    /// Tukey's c in those stages, as a multiple of [`RegisterParams::tukey`]: the seeds are far
    /// from where the points start, and a narrow kernel would reject them.
    pub tukey_scale: f64,
    /// Weight of the point-to-point term in those stages, in place of
    /// [`RegisterParams::point_weight`]. A seed names the point itself, so all of its offset
    /// counts; a closest-point partner is right along the normal only, its place along the
    /// surface being wherever the warp happens to stand.
    pub point_weight: f64,
    /// Whether the seeds replace every association in their stages (seeds found without
    /// comparing positions, which closest point cannot improve on early), not only where the
    /// two disagree by more than the gate.
    pub replace_all: bool,
    /// Levenberg-Marquardt steps per round in those stages, at least: the seeds lie far from
    /// where the points start, farther than one step on each matching goes (a sheet folded
    /// through 112° ended 20 % off with one).
    pub iterations: usize,
    /// Points whose seed holds in every stage, not only in the seeded ones: a sheet's rim,
    /// matched by the rims' own shape. Closest point would let it slide, along the rim and
    /// inwards, wherever that stretches the sheet less.
    pub pinned: Vec<u32>,
}

/// What one optimisation did.
#[derive(Clone, Debug, PartialEq)]
pub struct RegisterSummary {
    /// Levenberg-Marquardt iterations over all rounds.
    pub iterations: usize,
    /// Data cost Σ ½ρ at the end.
    pub data_cost: f64,
    /// Regulariser cost ½ λ Σ φ |r|² at the end (last stage's λ).
    pub regulariser_cost: f64,
    /// Points with a correspondence at the last association.
    pub matched: usize,
    /// Wall-clock seconds.
    pub seconds: f64,
    /// Where they went.
    pub times: RegisterTimes,
    /// The block-Jacobi steps' conjugate gradients, over all rounds.
    pub linear: LinearEffort,
    /// The rigid pre-alignment's motion, applied to every node before the warp was optimised
    /// (identity when none was found).
    pub prealigned: Isometry3<f64>,
    /// How well the photometric term is met at the end, when it was used.
    pub photometric: Option<PhotometricFit>,
    /// How well the chromaticity term is met at the end, when it was used.
    pub chroma: Option<PhotometricFit>,
}

impl RegisterSummary {
    /// Counts `first`, an optimisation run before this one on the same graph, in this summary:
    /// its iterations, seconds and times are added, and the rigid motion it applied comes before
    /// this one's pre-alignment.
    pub fn take_in_first(&mut self, first: &RegisterSummary) {
        self.iterations += first.iterations;
        self.seconds += first.seconds;
        self.times.add(&first.times);
        self.linear.add(&first.linear);
        self.prealigned *= first.prealigned;
    }
}

/// Seconds spent in each stage of one optimisation.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RegisterTimes {
    /// Rigid pre-alignment.
    pub prealign: f64,
    /// Warping the points and finding their partners.
    pub associate: f64,
    /// Readying the system's structure and the terms' weights, and copying motions back.
    pub update: f64,
    /// Assembling the normal equations (residuals, Jacobians, H and g) and trial costs.
    pub evaluate: f64,
    /// Factorising and solving the damped normal equations.
    pub linear: f64,
}

impl RegisterTimes {
    /// Adds another optimisation's times.
    pub fn add(&mut self, o: &RegisterTimes) {
        self.prealign += o.prealign;
        self.associate += o.associate;
        self.update += o.update;
        self.evaluate += o.evaluate;
        self.linear += o.linear;
    }
}

/// The warp-field optimiser; keeps its system, structure and symbolic factorisation between calls.
pub struct WarpOptimiser {
    /// Settings.
    pub params: RegisterParams,
    system: WarpSystem,
    /// Directed regulariser edges (i, j, g_j, λ φ_ij) of the current stage.
    edges: Vec<(u32, u32, Vector3<f64>, f64)>,
    /// `A₀⁻¹` of every node's motion after the pre-alignment (the stay priors).
    anchors: Vec<Isometry3<f64>>,
    rigid_ws: DenseWorkspace<6>,
    warped: Vec<Vector3<f64>>,
    warped_normals: Vec<Vector3<f64>>,
    matches: Vec<Option<(Vector3<f64>, Vector3<f64>)>>,
    /// Per point, its partner's index at the last association, for [`Target::associate_from`]
    /// (`u32::MAX` for none; forgotten when an optimisation starts, as its target may differ).
    partners: Vec<u32>,
    coverage: Coverage,
}

impl WarpOptimiser {
    /// An optimiser with these settings.
    pub fn new(params: RegisterParams) -> Self {
        Self {
            params,
            system: WarpSystem::default(),
            edges: Vec::new(),
            anchors: Vec::new(),
            rigid_ws: DenseWorkspace::default(),
            warped: Vec::new(),
            warped_normals: Vec::new(),
            matches: Vec::new(),
            partners: Vec::new(),
            coverage: Coverage::default(),
        }
    }

    /// The data points that had a partner at the end of the last optimisation, with their
    /// warped positions.
    pub fn matched_points(&self) -> impl Iterator<Item = (usize, Vector3<f64>)> + '_ {
        self.warped
            .iter()
            .zip(&self.matches)
            .enumerate()
            .filter_map(|(i, (w, m))| m.map(|_| (i, *w)))
    }

    /// Moves `graph`'s nodes so the canonical `points` (with `normals`, bound by `bindings`) land on
    /// `target`. Inputs that do not belong together are an error, not a panic.
    pub fn optimise(
        &mut self,
        graph: &mut DeformationGraph,
        points: &[Vector3<f64>],
        normals: &[Vector3<f64>],
        bindings: &[Binding],
        target: &dyn Target,
    ) -> Result<RegisterSummary, RegisterError> {
        self.optimise_from(
            graph,
            points,
            normals,
            bindings,
            target,
            &[Isometry3::identity()],
            None,
        )
    }

    /// [`Self::optimise`] with the rigid pre-alignment started from each of `guesses` (see
    /// [`principal_axes_guesses`](super::principal_axes::principal_axes_guesses) for whole
    /// shapes far apart); the closest fit is kept.
    ///
    /// With `seeds`, the first `seeds.stages` stages, under a wider Tukey kernel, give a point its
    /// seed wherever the seed lies farther than the distance gate from its closest-point partner
    /// (or it has none); the later stages associate with `target` as usual. Seeds that are not
    /// one per point are an error.
    #[allow(clippy::too_many_arguments)]
    pub fn optimise_from(
        &mut self,
        graph: &mut DeformationGraph,
        points: &[Vector3<f64>],
        normals: &[Vector3<f64>],
        bindings: &[Binding],
        target: &dyn Target,
        guesses: &[Isometry3<f64>],
        seeds: Option<&Seeds>,
    ) -> Result<RegisterSummary, RegisterError> {
        let start = Instant::now();
        check_inputs(graph, points, normals, bindings, seeds)?;
        let colour = colour_terms(target, &self.params, points.len())?;
        let mut times = RegisterTimes::default();
        let mut clock = Instant::now();
        let mut lap = |t: &mut f64| {
            let now = Instant::now();
            *t += (now - clock).as_secs_f64();
            clock = now;
        };
        let cover = self.coverage_distance(points, target);
        self.partners.clear();
        self.coverage.forget();
        let prealigned = self.prealign(graph, points, normals, bindings, target, guesses);
        lap(&mut times.prealign);
        self.start_system(graph, bindings)?;
        let (mut iterations, mut linear) = (0, LinearEffort::default());
        let mut lambda = 0.0;
        for stage in 0..self.params.schedule.len() {
            lambda = self.params.schedule[stage];
            self.set_regulariser(graph, lambda);
            let seeded = seeds.filter(|s| stage < s.stages);
            for _ in 0..self.params.rounds {
                lap(&mut times.update);
                self.associate(graph, points, normals, bindings, target);
                self.cover(target, cover);
                if let Some(s) = seeded {
                    self.take_seeds(s);
                }
                if let Some(s) = seeds {
                    self.take_pinned(s);
                }
                lap(&mut times.associate);
                let mut evaluate = 0.0;
                let done = self.minimise_round(points, bindings, seeded, colour, &mut evaluate)?;
                iterations += done.iterations;
                linear.add(&done.linear);
                lap(&mut times.linear);
                // the round's wall time went to `linear`; its assembly belongs to `evaluate`
                times.evaluate += evaluate;
                times.linear -= evaluate;
                if !done.moved {
                    // nothing moved, so the next round would match and minimise the same
                    break;
                }
                for (node, m) in graph.nodes.iter_mut().zip(self.system.motions()) {
                    node.motion = dual_quaternion(m);
                }
            }
        }
        lap(&mut times.update);
        self.associate(graph, points, normals, bindings, target);
        lap(&mut times.associate);
        let (data_cost, matched) = self.data_cost();
        let [photometric, chroma] = colour.map(|term| term.map(|ph| self.colour_fit(&ph)));
        Ok(RegisterSummary {
            iterations,
            data_cost,
            regulariser_cost: regulariser_cost(graph, lambda),
            matched,
            seconds: start.elapsed().as_secs_f64(),
            times,
            linear,
            prealigned,
            photometric,
            chroma,
        })
    }

    /// How well a colour term is met by the warped points matched at the last association.
    fn colour_fit(&self, term: &Photometric<'_>) -> PhotometricFit {
        PhotometricFit::measure(
            &term.target,
            &self.warped,
            self.matches.iter().map(Option::is_some),
        )
    }

    /// One round's Levenberg-Marquardt iterations on the current association (with `seeded`'s
    /// kernel and iterations in a seeded stage); adds the assembly's seconds to `evaluate`.
    fn minimise_round(
        &mut self,
        points: &[Vector3<f64>],
        bindings: &[Binding],
        seeded: Option<&Seeds>,
        [photometric, chroma]: [Option<Photometric<'_>>; 2],
        evaluate: &mut f64,
    ) -> Result<Minimised, RegisterError> {
        let terms = WarpTerms {
            points,
            bindings,
            matches: &self.matches,
            tukey: self.params.tukey * seeded.map_or(1.0, |s| s.tukey_scale),
            point_weight: seeded.map_or(self.params.point_weight, |s| s.point_weight),
            edges: &self.edges,
            anchors: &self.anchors,
            stay_weight: self.params.stay_weight,
            photometric,
            chroma,
        };
        let steps = Steps {
            iterations: seeded.map_or(self.params.iterations, |s| {
                s.iterations.max(self.params.iterations)
            }),
            damping: self.params.damping,
            linear: self.params.linear,
        };
        Ok(self.system.minimise(&terms, steps, evaluate)?)
    }

    /// Builds the system's structure for `graph` and `bindings`, starts it from the nodes'
    /// motions, and with the stay prior anchors each node at its start.
    fn start_system(
        &mut self,
        graph: &DeformationGraph,
        bindings: &[Binding],
    ) -> Result<(), RegisterError> {
        // steps that iterate on a factorisation take it in single precision, and block-Jacobi
        // steps their products (stopped at a relative residual of 10⁻³ or 3·10⁻³, they do not
        // see it)
        let precision = match self.params.linear {
            LinearSteps::Refine(_) | LinearSteps::BlockJacobi(_) => FactorPrecision::Single,
            LinearSteps::Factorise => FactorPrecision::Double,
        };
        self.system.prepare(graph, bindings, precision)?;
        self.system
            .set_motions(graph.nodes.iter().map(|n| rigid_motion(&n.motion)));
        self.anchors.clear();
        if self.params.stay_weight > 0.0 {
            self.anchors
                .extend(self.system.motions().iter().map(|m| m.inverse()));
        }
        Ok(())
    }

    /// Warps the points by the current field and finds each one's partner, rejecting by distance
    /// and normal angle.
    fn associate(
        &mut self,
        graph: &DeformationGraph,
        points: &[Vector3<f64>],
        normals: &[Vector3<f64>],
        bindings: &[Binding],
        target: &dyn Target,
    ) {
        graph.warp_all(
            bindings,
            points,
            normals,
            &mut self.warped,
            &mut self.warped_normals,
        );
        let (d2, min_cos) = (
            self.params.max_distance * self.params.max_distance,
            self.params.max_normal_angle_deg.to_radians().cos(),
        );
        self.matches.resize(points.len(), None);
        self.partners.resize(points.len(), u32::MAX);
        self.matches
            .par_iter_mut()
            .zip(self.partners.par_iter_mut())
            .zip(self.warped.par_iter().zip(self.warped_normals.par_iter()))
            .for_each(|((m, last), (p, n))| {
                *m = target
                    .associate_from(p, last)
                    .filter(|(q, nq)| (q - p).norm_squared() <= d2 && nq.dot(n) >= min_cos);
            });
    }

    /// With a coverage distance (`cover`, from [`Self::coverage_distance`]) and a whole-shape
    /// target, gives the warped points nearest the target's uncovered samples those samples as
    /// partners (module `coverage`).
    fn cover(&mut self, target: &dyn Target, cover: f64) {
        let Some(samples) = target.samples().filter(|_| cover > 0.0) else {
            return;
        };
        let gates = CoverageGates {
            cover,
            max_distance: self.params.max_distance,
            min_cos: self.params.max_normal_angle_deg.to_radians().cos(),
        };
        self.coverage.pull(
            (&self.warped, &self.warped_normals),
            samples,
            gates,
            &mut self.matches,
        );
    }

    /// The coverage distance of an optimisation of `points` onto `target`:
    /// [`RegisterParams::cover`] times the points' sampling spacing, 0 for none (no coverage
    /// set, or a target that is a view, not a whole shape).
    fn coverage_distance(&self, points: &[Vector3<f64>], target: &dyn Target) -> f64 {
        if self.params.cover > 0.0 && target.samples().is_some() {
            self.params.cover * sampling_spacing(points)
        } else {
            0.0
        }
    }

    /// Replaces each point's association by its seed where the two disagree by more than the
    /// distance gate (or the point found no partner): the seeds are coarse, closest point is
    /// exact where it is right, and they disagree where closest point took the wrong part.
    fn take_seeds(&mut self, seeds: &Seeds) {
        let gate = self.params.max_distance * self.params.max_distance;
        for (m, s) in self.matches.iter_mut().zip(&seeds.matches) {
            if seeds.replace_all || m.is_none_or(|(q, _)| (q - s.0).norm_squared() > gate) {
                *m = Some(*s);
            }
        }
    }

    /// Gives every pinned point its seed ([`check_inputs`] saw that they are there).
    fn take_pinned(&mut self, seeds: &Seeds) {
        for &i in &seeds.pinned {
            self.matches[i as usize] = Some(seeds.matches[i as usize]);
        }
    }

    /// Σ ½ρ of the data terms at the current association, and the number matched.
    fn data_cost(&self) -> (f64, usize) {
        let mut cost = 0.0;
        let mut matched = 0;
        for (p, m) in self.warped.iter().zip(&self.matches) {
            if let Some((q, n)) = m {
                matched += 1;
                let d = p - q;
                cost += match_terms(&d, n, self.params.tukey, self.params.point_weight).0;
            }
        }
        (cost, matched)
    }

    /// Rigid ICP (point-to-plane and point-to-point) of the warped points onto the target from each
    /// of `guesses`; the motion that leaves the points closest to the target (mean distance to their
    /// closest partner, capped at the gate) is applied to every node. With no rigid iterations, the
    /// closest of the guesses themselves is applied. Returns the motion applied.
    fn prealign(
        &mut self,
        graph: &mut DeformationGraph,
        points: &[Vector3<f64>],
        normals: &[Vector3<f64>],
        bindings: &[Binding],
        target: &dyn Target,
        guesses: &[Isometry3<f64>],
    ) -> Isometry3<f64> {
        if self.params.rigid_iterations == 0 && guesses.len() <= 1 {
            // a single guess taken as it is needs no scoring
            let t = guesses.first().copied().unwrap_or_else(Isometry3::identity);
            graph.premultiply(&t);
            return t;
        }
        graph.warp_all(
            bindings,
            points,
            normals,
            &mut self.warped,
            &mut self.warped_normals,
        );
        let stride = match self.params.rigid_points {
            0 => 1,
            m => points.len().div_ceil(m).max(1),
        };
        let terms = RigidTerms {
            points: &self.warped,
            normals: &self.warped_normals,
            stride,
            target,
            max_distance: self.params.rigid_max_distance,
            min_cos: self.params.max_normal_angle_deg.to_radians().cos(),
        };
        let huber = Huber(self.params.tukey);
        let group = Group {
            weight: 1.0,
            kernel: Some(&huber),
        };
        let groups = [group, group];
        let mut best: Option<(f64, Isometry3<f64>)> = None;
        if self.params.rigid_iterations == 0 {
            // no refinement: the guess that fits best as it is
            let best = guesses
                .iter()
                .map(|g| (terms.spread(g), *g))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let t = best.map_or_else(Isometry3::identity, |(_, t)| t);
            graph.premultiply(&t);
            return t;
        }
        for guess in guesses {
            let mut x = [0.0; 7];
            se3::to_slice(guess, &mut x);
            let summary = dense::solve(
                &terms,
                &SE3,
                &mut x,
                &DenseOptions {
                    groups: &groups,
                    max_iterations: self.params.rigid_iterations,
                    step_tolerance: 1e-9,
                    damping: 0.0,
                },
                &mut self.rigid_ws,
            );
            if matches!(
                summary.stop,
                dense::DenseStop::Singular | dense::DenseStop::NoTerms
            ) || !x.iter().all(|v| v.is_finite())
            {
                continue;
            }
            let t = se3::from_slice(&x);
            let score = terms.spread(&t);
            if best.is_none_or(|(b, _)| score < b) {
                best = Some((score, t));
            }
        }
        let t = best.map_or_else(Isometry3::identity, |(_, t)| t);
        graph.premultiply(&t);
        t
    }

    /// The regulariser edges of a stage: every directed edge (i, j) with weight λ φ_ij.
    fn set_regulariser(&mut self, graph: &DeformationGraph, lambda: f64) {
        self.edges.clear();
        for (i, js) in graph.edges.iter().enumerate() {
            for &j in js {
                let weight = lambda * edge_weight(graph, i as u32, j);
                self.edges
                    .push((i as u32, j, graph.nodes[j as usize].position, weight));
            }
        }
    }
}

/// φ_ij of eq. 4.7: `exp(−|g_i − g_j|² / (2 max(r_i, r_j)²))`, nearer neighbours held more rigidly.
fn edge_weight(graph: &DeformationGraph, i: u32, j: u32) -> f64 {
    let (a, b) = (&graph.nodes[i as usize], &graph.nodes[j as usize]);
    let r = a.radius.max(b.radius);
    (-(a.position - b.position).norm_squared() / (2.0 * r * r)).exp()
}

/// ½ λ Σ φ_ij |A_i g_j − A_j g_j|² over the directed edges.
pub fn regulariser_cost(graph: &DeformationGraph, lambda: f64) -> f64 {
    let motions: Vec<Isometry3<f64>> = graph
        .nodes
        .iter()
        .map(|n| rigid_motion(&n.motion))
        .collect();
    let mut cost = 0.0;
    for (i, edges) in graph.edges.iter().enumerate() {
        for &j in edges {
            let (r, _, _) = as_rigid_as_possible(
                &motions[i],
                &motions[j as usize],
                &graph.nodes[j as usize].position,
            );
            cost += 0.5 * lambda * edge_weight(graph, i as u32, j) * r.norm_squared();
        }
    }
    cost
}

/// Rigid point-to-plane terms of the pre-alignment: warped points against their closest target.
struct RigidTerms<'a> {
    points: &'a [Vector3<f64>],
    normals: &'a [Vector3<f64>],
    /// Every `stride`-th point is fitted and scored.
    stride: usize,
    target: &'a dyn Target,
    max_distance: f64,
    min_cos: f64,
}

impl RigidTerms<'_> {
    /// Mean distance of the moved points to their partners, each capped at the gate: how well a
    /// rigid motion fits, comparable between starting guesses.
    fn spread(&self, t: &Isometry3<f64>) -> f64 {
        let gate = self.max_distance;
        let sum: f64 = self
            .points
            .par_iter()
            .step_by(self.stride)
            .map(|p| {
                let moved = t * Point3::from(*p);
                self.target
                    .associate(&moved.coords)
                    .map_or(gate, |(q, _)| (q - moved.coords).norm().min(gate))
            })
            .sum();
        sum / self.len().max(1) as f64
    }
}

impl DenseTerms<6> for RigidTerms<'_> {
    type Point = RigidMotion;
    fn len(&self) -> usize {
        self.points.len().div_ceil(self.stride)
    }
    fn prepare(&self, x: &[f64]) -> RigidMotion {
        RigidMotion::new(&se3::from_slice(x))
    }
    fn evaluate<E: FnMut(f64, &[f64; 6], usize)>(&self, i: usize, t: &RigidMotion, emit: &mut E) {
        let i = i * self.stride;
        let p = &self.points[i];
        let moved = t.apply(p);
        let Some((q, n)) = self.target.associate(&moved) else {
            return;
        };
        if (q - moved).norm_squared() > self.max_distance * self.max_distance
            || n.dot(&(t.r * self.normals[i])) < self.min_cos
        {
            return;
        }
        let (r, j) = point_to_plane(t, p, &q, &n);
        emit(r, &j, 0);
        // point-to-point rows: r = T p − q, ∂r/∂δ = R [−[p]×, I]; they hold the in-plane motion a
        // flat surface leaves free
        let d = moved - q;
        for (row, axis) in t.r.row_iter().enumerate() {
            let a = axis.transpose();
            let w = p.cross(&a);
            emit(d[row], &[w.x, w.y, w.z, a.x, a.y, a.z], 1);
        }
    }
}

/// Seeds one per point (when given), and normals and bindings one per point, each binding to
/// nodes of `graph`.
fn check_inputs(
    graph: &DeformationGraph,
    points: &[Vector3<f64>],
    normals: &[Vector3<f64>],
    bindings: &[Binding],
    seeds: Option<&Seeds>,
) -> Result<(), RegisterError> {
    if let Some(s) = seeds.filter(|s| s.matches.len() != points.len()) {
        return Err(RegisterError::Seeds {
            seeds: s.matches.len(),
            points: points.len(),
        });
    }
    let pinned = seeds.map_or(&[][..], |s| &s.pinned);
    if let Some(&index) = pinned.iter().find(|&&i| i as usize >= points.len()) {
        return Err(RegisterError::Pinned {
            index,
            points: points.len(),
        });
    }
    let nodes = graph.nodes.len();
    if points.len() != normals.len()
        || points.len() != bindings.len()
        || bindings.iter().any(|b| {
            b.count > MAX_NEIGHBOURS || b.nodes[..b.count].iter().any(|&k| k as usize >= nodes)
        })
    {
        return Err(RegisterError::Mismatch {
            points: points.len(),
            normals: normals.len(),
            bindings: bindings.len(),
            nodes,
        });
    }
    Ok(())
}

/// The photometric and chromaticity terms, each when it is weighted and `target` has it.
fn colour_terms<'t>(
    target: &'t dyn Target,
    p: &RegisterParams,
    points: usize,
) -> Result<[Option<Photometric<'t>>; 2], RegisterError> {
    let photometric = (p.photometric_weight, p.photometric_tukey);
    Ok([
        colour_term(target.photometric(), photometric, points)?,
        colour_term(target.chroma(), (p.chroma_weight, p.chroma_tukey), points)?,
    ])
}

/// A colour term of `(weight, tukey)` when it is weighted and the target has it; references that
/// are not one per point are an error.
fn colour_term(
    target: Option<PhotometricTarget<'_>>,
    (weight, tukey): (f64, f64),
    points: usize,
) -> Result<Option<Photometric<'_>>, RegisterError> {
    let Some(t) = target.filter(|_| weight > 0.0) else {
        return Ok(None);
    };
    if t.reference.len() != points {
        return Err(RegisterError::Intensities {
            references: t.reference.len(),
            points,
        });
    }
    Ok(Some(Photometric {
        target: t,
        weight,
        tukey,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;
    use crate::nonrigid::cloud_target::CloudTarget;

    #[test]
    fn a_first_optimisation_is_counted_and_its_rigid_motion_comes_first() {
        let summary = |iterations, seconds, prealigned| RegisterSummary {
            iterations,
            data_cost: 1.0,
            regulariser_cost: 2.0,
            matched: 3,
            seconds,
            times: RegisterTimes {
                linear: seconds,
                ..RegisterTimes::default()
            },
            linear: LinearEffort {
                steps: iterations,
                iterations: 10 * iterations,
                truncated: 1,
            },
            prealigned,
            photometric: None,
            chroma: None,
        };
        let a = Isometry3::new(Vector3::new(0.1, 0.0, 0.0), Vector3::new(0.0, 0.3, 0.0));
        let b = Isometry3::new(Vector3::new(0.0, 0.2, 0.0), Vector3::new(0.1, 0.0, 0.0));
        let mut last = summary(5, 0.5, b);
        last.take_in_first(&summary(7, 0.25, a));
        assert_eq!(
            (last.iterations, last.seconds, last.times.linear),
            (12, 0.75, 0.75)
        );
        let effort = LinearEffort {
            steps: 12,
            iterations: 120,
            truncated: 2,
        };
        assert_eq!(last.linear, effort);
        let p = Point3::new(0.3, -0.2, 1.0);
        assert!((last.prealigned * p - b * (a * p)).norm() < 1e-12);
        assert_eq!(
            (last.data_cost, last.matched),
            (1.0, 3),
            "the last one's fit stands"
        );
    }

    #[test]
    fn a_seed_overrides_only_a_partner_beyond_the_gate_or_a_missing_one() {
        let mut optimiser = WarpOptimiser::new(RegisterParams {
            max_distance: 0.1,
            ..RegisterParams::default()
        });
        let n = Vector3::z();
        let at = |x: f64| (Vector3::new(x, 0.0, 0.0), n);
        // near its seed, far from it, and unmatched
        optimiser.matches = vec![Some(at(0.05)), Some(at(0.5)), None];
        let seeds = Seeds {
            matches: vec![at(0.0), at(0.0), at(0.0)],
            stages: 1,
            tukey_scale: 8.0,
            point_weight: 1.0,
            replace_all: false,
            iterations: 2,
            pinned: vec![2],
        };
        optimiser.take_seeds(&seeds);
        assert_eq!(
            optimiser.matches,
            vec![Some(at(0.05)), Some(at(0.0)), Some(at(0.0))]
        );
        // seeds that replace every association
        optimiser.matches = vec![Some(at(0.05)), Some(at(0.5)), None];
        optimiser.take_seeds(&Seeds {
            replace_all: true,
            ..seeds.clone()
        });
        assert_eq!(optimiser.matches, vec![Some(at(0.0)); 3]);
        // a pinned seed holds wherever its point matched
        optimiser.matches = vec![Some(at(0.05)), Some(at(0.5)), Some(at(0.02))];
        optimiser.take_pinned(&seeds);
        assert_eq!(
            optimiser.matches,
            vec![Some(at(0.05)), Some(at(0.5)), Some(at(0.0))]
        );
    }

    /// A depth frame of the plane z = 1 facing the camera.
    fn wall(camera: &Camera) -> (VertexMap, NormalMap) {
        let mut vertices = Image::filled(camera.width, camera.height, [0.0f32; 3]);
        for y in 0..camera.height {
            for x in 0..camera.width {
                let p = camera.back_project(x as f64, y as f64, 1.0);
                vertices.data[y * camera.width + x] = [p.x as f32, p.y as f32, p.z as f32];
            }
        }
        let normals = Image::filled(camera.width, camera.height, [0.0, 0.0, -1.0f32]);
        (vertices, normals)
    }

    #[test]
    fn depth_targets_associate_through_the_pixel_a_point_projects_to() {
        let camera = Camera::new(100.0, 100.0, 31.5, 23.5, 64, 48);
        let (mut vertices, normals) = wall(&camera);
        let target = DepthTarget {
            camera: &camera,
            vertices: &vertices,
            normals: &normals,
        };
        let p = Vector3::new(0.05, -0.02, 1.03);
        let (q, n) = target.associate(&p).unwrap();
        // the wall's point on the same ray (to a pixel), facing the camera
        assert!((q.z - 1.0).abs() < 1e-6 && (q.x / q.z - p.x / p.z).abs() < 0.006);
        assert_eq!(n, Vector3::new(0.0, 0.0, -1.0));
        assert!(
            target.associate(&Vector3::new(5.0, 0.0, 1.0)).is_none(),
            "outside the image"
        );
        assert!(
            target.associate(&Vector3::new(0.0, 0.0, -1.0)).is_none(),
            "behind the camera"
        );
        let (x, y) = camera.project_to_pixel(&Point3::from(p)).unwrap();
        vertices.data[y * camera.width + x] = [f32::NAN; 3];
        let target = DepthTarget {
            camera: &camera,
            vertices: &vertices,
            normals: &normals,
        };
        assert!(target.associate(&p).is_none(), "a hole in the depth");
    }

    #[test]
    fn mismatched_inputs_are_errors() {
        let points = vec![Vector3::zeros(), Vector3::x()];
        let normals = vec![Vector3::z(); 2];
        let mut graph = DeformationGraph::sample(&points, Default::default()).unwrap();
        let mut bindings = graph.bind_all(&points);
        let target = CloudTarget::new(&points, &normals);
        let mut optimiser = WarpOptimiser::new(RegisterParams::default());
        let short = &normals[..1];
        assert!(matches!(
            optimiser.optimise(&mut graph, &points, short, &bindings, &target),
            Err(RegisterError::Mismatch { normals: 1, .. })
        ));
        bindings[1].nodes[0] = 99;
        assert!(optimiser
            .optimise(&mut graph, &points, &normals, &bindings, &target)
            .is_err());
    }

    /// A graph sampled over `points` with nodes `spacing` apart, and the points' bindings.
    fn graph_over(points: &[Vector3<f64>], spacing: f64) -> (DeformationGraph, Vec<Binding>) {
        let params = crate::nonrigid::GraphParams {
            spacing,
            ..Default::default()
        };
        let graph = DeformationGraph::sample(points, params).unwrap();
        let bindings = graph.bind_all(points);
        (graph, bindings)
    }

    /// The rigid pre-alignment fitted on every seventh point finds the motion it finds on all of
    /// them: a curved patch moved by 1.2° and 1.5 cm onto its own moved copy.
    #[test]
    fn a_prealignment_on_a_share_of_the_points_finds_the_motion_all_of_them_find() {
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        for i in 0..60 {
            for j in 0..60 {
                let (x, y) = (i as f64 / 59.0 - 0.5, j as f64 / 59.0 - 0.5);
                // a saddle with a bump: no motion slides it along itself
                let bump = 0.1 * (-(x * x + y * y) / 0.02).exp();
                let (dzx, dzy) = (0.3 * y - 100.0 * x * bump, 0.3 * x - 100.0 * y * bump);
                points.push(Vector3::new(x, y, 0.3 * x * y + bump));
                normals.push(Vector3::new(-dzx, -dzy, 1.0).normalize());
            }
        }
        let truth = Isometry3::new(
            Vector3::new(0.01, -0.005, 0.01),
            Vector3::new(0.01, 0.015, -0.01),
        );
        let moved: Vec<Vector3<f64>> = points
            .iter()
            .map(|p| truth * Point3::from(*p))
            .map(|p| p.coords)
            .collect();
        let moved_normals: Vec<Vector3<f64>> = normals.iter().map(|n| truth.rotation * n).collect();
        let target = CloudTarget::new(&moved, &moved_normals);
        let fit = |rigid_points: usize| {
            let (mut graph, bindings) = graph_over(&points, 0.2);
            let mut optimiser = WarpOptimiser::new(RegisterParams {
                rigid_iterations: 60,
                rigid_points,
                ..RegisterParams::default()
            });
            let guesses = [Isometry3::identity()];
            optimiser.prealign(&mut graph, &points, &normals, &bindings, &target, &guesses)
        };
        let (all, share) = (fit(0), fit(points.len() / 7));
        let off = |t: &Isometry3<f64>| {
            let d = t.inverse() * truth;
            (d.translation.vector.norm(), d.rotation.angle())
        };
        assert!(off(&all).0 < 1e-3 && off(&all).1 < 1e-3, "{:?}", off(&all));
        assert!(
            off(&share).0 < 1e-3 && off(&share).1 < 1e-3,
            "{:?}",
            off(&share)
        );
    }

    #[test]
    fn a_bent_plate_registers_onto_its_depth_frame() {
        // a gentle bend of the thesis' grid seen by a camera 1.5 m away: projective association,
        // default settings
        use crate::synthetic::plate::flat_grid;
        let camera = Camera::new(300.0, 300.0, 159.5, 119.5, 320, 240);
        let grid = flat_grid();
        let to_camera = |p: &Point3<f64>| Vector3::new(p.x, p.y, 1.5 - p.z);
        let source: Vec<Vector3<f64>> =
            grid.vertices.iter().map(|p| to_camera(&p.cast())).collect();
        let normals = vec![Vector3::new(0.0, 0.0, -1.0); source.len()];
        // the bent plate's depth, rendered per pixel by intersecting its rows: z(x) of the bend
        let k = 0.6;
        let mut vertices = Image::filled(camera.width, camera.height, [f32::NAN; 3]);
        let mut vnormals = Image::filled(camera.width, camera.height, [f32::NAN; 3]);
        for s in 0..=4000 {
            for t in 0..=400 {
                let (x, y) = (-0.5 + s as f64 / 4000.0, -0.3 + 0.6 * t as f64 / 400.0);
                let bent = Point3::new((k * x).sin() / k, y, (1.0 - (k * x).cos()) / k);
                let c = to_camera(&bent);
                if let Some((u, v)) = camera.project_to_pixel(&Point3::from(c)) {
                    let i = v * camera.width + u;
                    vertices.data[i] = [c.x as f32, c.y as f32, c.z as f32];
                    let n = Vector3::new(-(k * x).sin(), 0.0, -(k * x).cos());
                    vnormals.data[i] = [n.x as f32, n.y as f32, n.z as f32];
                }
            }
        }
        let target = DepthTarget {
            camera: &camera,
            vertices: &vertices,
            normals: &vnormals,
        };
        let (mut graph, bindings) = graph_over(&source, 0.1);
        let mut optimiser = WarpOptimiser::new(RegisterParams::default());
        let summary = optimiser
            .optimise(&mut graph, &source, &normals, &bindings, &target)
            .unwrap();
        // every warped vertex lies on the bent surface: its depth matches the depth map there
        let mut worst: f64 = 0.0;
        for (p, b) in source.iter().zip(&bindings) {
            let (w, _) = graph.warp(b, p, &Vector3::z());
            if let Some((q, n)) = target.associate(&w) {
                worst = worst.max(n.dot(&(w - q)).abs());
            }
        }
        // one depth map leaves the plate free to slide along itself (here the last three columns and
        // two rows slide off the surface), so only the distance to the surface is asked
        assert!(summary.matched > source.len() * 2 / 3, "{summary:?}");
        assert!(worst < 2e-3, "worst point-to-plane distance {worst}");
    }
}
