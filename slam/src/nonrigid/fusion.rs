//! Dense non-rigid SLAM after DynamicFusion (Newcombe, Fox & Seitz, CVPR 2015; thesis ch. 4): a
//! canonical TSDF of the object, a deformation graph over its surface, and per frame
//!
//! 1. preprocess the live depth (masked to the object, if a mask is given);
//! 2. warp the canonical surface samples by the current field and optimise the field against the
//!    live depth (projective association, [`WarpOptimiser`]), starting from the last frame's field,
//!    and, with colour, against the live intensities: each sample's intensity in a recent tracked
//!    frame, over its local mean (module `photometric`), and the chromaticity it was first seen
//!    with (module `chroma`) hold motion along the surface;
//! 3. fuse the live depth into the canonical volume through the warp: each voxel centre near the
//!    surface is carried into the live frame by the blend of its K nearest nodes (kept across
//!    frames, `voxel_bindings`), projected, and its projective signed distance fused
//!    ([`TsdfVolume::integrate_warped`]); the blocks to update are found by carrying the live
//!    surface back into the canonical frame by the inverse of its blended node motion (module
//!    `band`: samples about two voxels apart, each with a margin for the surface between them);
//! 4. extract the canonical surface, extend the graph where it has grown beyond the nodes' reach,
//!    and re-sample the data points when the graph changed (or every few frames).
//!
//! The canonical frame is the first camera frame. The warp carries canonical points into the live
//! camera frame, so a moving camera is absorbed by the field (the optimiser's rigid pre-alignment).

use super::band::{carry_back, BandSampling};
use super::cell_nearest::bind_in_cells;
use super::chroma::{ChromaImage, ChromaReferences};
use super::colour_drift::{ColourDrift, ColourDrifted};
use super::graph::{Binding, DeformationGraph, GraphError, GraphParams};
use super::linear_steps::LinearSteps;
use super::photometric::{PhotometricTarget, RatioImage};
use super::reference_frame::ReferenceFrame;
use super::register::{
    DepthTarget, RegisterError, RegisterParams, RegisterSummary, Target, TexturedDepthTarget,
    WarpOptimiser,
};
use super::surface::mesh_points;
use super::voxel_bindings::{BlockGeometry, CachedWarp, VoxelBindings};
use crate::camera::Camera;
use crate::image::{ColorImage, Image};
use crate::mesh::Mesh;
use crate::preprocess::{PreprocessParams, Preprocessor};
use crate::tsdf::{TsdfError, TsdfParams, TsdfVolume, BLOCK};
use dynamap_residuals::deform::transform_point;
use nalgebra::{DualQuaternion, Isometry3, Vector3};
use rayon::prelude::*;
use std::time::Instant;

/// The edge of the cubes the data points are bound in, in node spacings: a cube's points share
/// one tree search (module `cell_nearest`), and its candidates stay a few dozen nodes.
const BINDING_CELL_SPACINGS: f64 = 2.0;

/// Settings of the non-rigid pipeline.
#[derive(Clone, Debug, PartialEq)]
pub struct FusionParams {
    /// Front end (default 2 levels).
    pub preprocess: PreprocessParams,
    /// The canonical volume (default 1 cm voxels, weight cap 32).
    pub tsdf: TsdfParams,
    /// The deformation graph (default spacing 5 cm).
    pub graph: GraphParams,
    /// The per-frame optimisation (default: a 3-iteration rigid start, then λ = 30 for one round
    /// of two iterations from damping τ = 1e-6, 5 cm / 30° gates, Tukey c = 5 cm, point weight
    /// 0.1, stay weight 0.01, photometric weight 0.3 under Tukey c = 0.1, chromaticity weight
    /// 0.3 under Tukey c = 0.1). Tukey's c is the distance gate: a kernel narrower than the gate
    /// gives no weight to matches the gate admits, so a part that falls behind by more than c in
    /// one frame (a plate's corners as it twists) is left to the regulariser and never catches
    /// up (NOTES 133).
    pub register: RegisterParams,
    /// The pyramid level whose depth the data term associates with (default 1: 320 × 240 from
    /// 640 × 480).
    pub data_level: usize,
    /// Canonical data points are thinned to one per cube of this edge, metres (default 1 cm).
    pub data_spacing: f64,
    /// Re-sample the data points from the canonical surface at least every this many frames, even
    /// when the graph has not changed (default 10).
    pub refresh_every: usize,
    /// A frame whose matched fraction of data points falls below this is a tracking failure
    /// (default 0.2).
    pub min_matched_fraction: f64,
    /// The photometric term compares intensities over their mean in windows of ± this many
    /// pixels of the data level (default 4; module `photometric`).
    pub photometric_window: usize,
    /// The photometric references are taken from a tracked frame every this many frames
    /// (default 5; 1, or 0, compares each frame with the one before). Each new reference frame
    /// adds its tracking error to the references, so the error walks with every one taken,
    /// while shading drifts from the reference the longer it is kept.
    pub photometric_keyframe_every: usize,
    /// A tracked frame whose median chromaticity residual exceeds this many times its floor
    /// (that of the first tracked frames, or one 8-bit level of the chromaticity where that is
    /// larger) has slid and is not fused (default 1.2, NOTES 132, 135, 136; 0: never; module
    /// `colour_drift`).
    pub colour_drift_ratio: f64,
}

impl Default for FusionParams {
    fn default() -> Self {
        // How far a match may lie from its warped point, metres; Tukey's c is the same distance.
        let gate = 0.05;
        Self {
            preprocess: PreprocessParams {
                levels: 2,
                ..PreprocessParams::default()
            },
            tsdf: TsdfParams {
                max_weight: 32.0,
                ..TsdfParams::default()
            },
            graph: GraphParams {
                spacing: 0.05,
                ..GraphParams::default()
            },
            register: RegisterParams {
                rigid_iterations: 3,
                rigid_max_distance: 0.1,
                rigid_points: 2048,
                schedule: vec![30.0],
                rounds: 1,
                iterations: 2,
                max_distance: gate,
                max_normal_angle_deg: 30.0,
                tukey: gate,
                point_weight: 0.1,
                stay_weight: 0.01,
                damping: 1e-6,
                linear: LinearSteps::BlockJacobi(50),
                photometric_weight: 0.3,
                photometric_tukey: 0.1,
                chroma_weight: 0.3,
                chroma_tukey: 0.1,
                cover: 0.0,
            },
            data_level: 1,
            data_spacing: 0.01,
            refresh_every: 10,
            min_matched_fraction: 0.2,
            photometric_window: 4,
            photometric_keyframe_every: 5,
            colour_drift_ratio: 1.2,
        }
    }
}

/// Seconds spent in each stage of a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FusionTimes {
    /// Masking, filtering and pyramids.
    pub preprocess: f64,
    /// Warp-field optimisation.
    pub optimise: f64,
    /// Fusion through the warp.
    pub fuse: f64,
    /// Surface extraction, graph extension and data re-sampling.
    pub surface: f64,
}

impl FusionTimes {
    /// Adds another frame's times.
    pub fn add(&mut self, o: &FusionTimes) {
        self.preprocess += o.preprocess;
        self.optimise += o.optimise;
        self.fuse += o.fuse;
        self.surface += o.surface;
    }
}

/// Why a frame was not fused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FusionFailure {
    /// An image of another size than the camera's.
    #[error("a {}x{} image does not match the camera's {}x{}", image.0, image.1, camera.0, camera.1)]
    ImageSize {
        /// The image's width and height.
        image: (usize, usize),
        /// The camera's.
        camera: (usize, usize),
    },
    /// The first frame has too little valid depth on the object to start the model.
    #[error("only {pixels} valid depth pixels on the object to start the model")]
    TooLittleDepth {
        /// Valid depth pixels (at least [`MIN_START_PIXELS`] are needed).
        pixels: usize,
    },
    /// The field could not be optimised.
    #[error(transparent)]
    Register(#[from] RegisterError),
    /// The frame's colour has drifted from the colour its points were first seen with: the
    /// material slid along the surface, where depth cannot see it.
    #[error(transparent)]
    ColourDrift(#[from] ColourDrifted),
    /// Too few of the surface's points matched the live depth: tracking is lost.
    #[error("only {matched} of {points} surface points matched the live depth")]
    Lost {
        /// Data points with a partner at the end.
        matched: usize,
        /// Data points.
        points: usize,
    },
    /// The deformation graph could not be sampled over the first frame's surface.
    #[error(transparent)]
    Graph(#[from] GraphError),
    /// The volume could not take the frame (its block budget).
    #[error(transparent)]
    Volume(#[from] TsdfError),
}

/// Valid depth pixels on the object that the first frame needs to start the model.
pub const MIN_START_PIXELS: usize = 100;

/// What happened to one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FusionReport {
    /// Why the frame was not fused, if it was not. The field is then left as it was, but after a
    /// [`FusionFailure::ColourDrift`]: the depth was met, and the frame's field is the best start
    /// for the next one.
    pub failure: Option<FusionFailure>,
    /// Nodes after the frame.
    pub nodes: usize,
    /// Nodes added by the frame.
    pub added_nodes: usize,
    /// The optimisation, when one ran.
    pub summary: Option<RegisterSummary>,
    /// Stage times.
    pub times: FusionTimes,
}

/// Dense non-rigid SLAM of one deforming object.
pub struct NonRigidFusion {
    /// Settings.
    pub params: FusionParams,
    camera: Camera,
    pre: Preprocessor,
    volume: TsdfVolume,
    graph: Option<DeformationGraph>,
    optimiser: WarpOptimiser,
    points: Vec<Vector3<f64>>,
    normals: Vec<Vector3<f64>>,
    bindings: Vec<Binding>,
    since_refresh: usize,
    masked: Image<u16>,
    band: Vec<(Vector3<f64>, f64)>,
    backup: Vec<DualQuaternion<f64>>,
    voxel_bindings: VoxelBindings,
    /// Each data point's intensity (over its local mean) in the reference frame (NaN: not seen
    /// there); stale once the points are re-sampled or another reference frame is taken.
    reference: Vec<f32>,
    reference_stale: bool,
    /// The data level's intensity over its local mean, when the frame has colour and the
    /// photometric term is weighted.
    ratio: RatioImage,
    has_ratio: bool,
    /// The frame the references are taken from.
    reference_frame: ReferenceFrame,
    /// The data level's chromaticity, when the frame has colour and the term is weighted.
    chroma: ChromaImage,
    has_chroma: bool,
    /// Each data point's chromaticity when first seen (NaN: not yet).
    chroma_reference: Vec<f32>,
    /// The same, per canonical cube, kept across re-samplings.
    chroma_book: ChromaReferences,
    /// The chromaticity residual's floor, and each frame's judgement against it.
    drift: ColourDrift,
}

impl NonRigidFusion {
    /// A pipeline for images from `camera`.
    pub fn new(camera: Camera, params: FusionParams) -> Self {
        Self {
            pre: Preprocessor::new(camera, params.preprocess),
            volume: TsdfVolume::new(params.tsdf),
            optimiser: WarpOptimiser::new(params.register.clone()),
            params,
            camera,
            graph: None,
            points: Vec::new(),
            normals: Vec::new(),
            bindings: Vec::new(),
            since_refresh: 0,
            masked: Image::new(0, 0),
            band: Vec::new(),
            backup: Vec::new(),
            voxel_bindings: VoxelBindings::default(),
            reference: Vec::new(),
            reference_stale: true,
            ratio: RatioImage::default(),
            has_ratio: false,
            reference_frame: ReferenceFrame::default(),
            chroma: ChromaImage::default(),
            has_chroma: false,
            chroma_reference: Vec::new(),
            chroma_book: ChromaReferences::default(),
            drift: ColourDrift::default(),
        }
    }

    /// The canonical volume.
    pub fn volume(&self) -> &TsdfVolume {
        &self.volume
    }

    /// The deformation graph (none before the first fused frame).
    pub fn graph(&self) -> Option<&DeformationGraph> {
        self.graph.as_ref()
    }

    /// One 8-bit level of the chromaticity at the last frame's brightness, the least floor of the
    /// colour verdict ([`ChromaImage::step`]; 0 before a frame with colour).
    pub fn colour_step(&self) -> f64 {
        self.chroma.step
    }

    /// The canonical surface samples the data term uses.
    pub fn data_points(&self) -> &[Vector3<f64>] {
        &self.points
    }

    /// The canonical surface (marching cubes over the canonical volume).
    pub fn canonical_mesh(&self) -> Mesh {
        self.volume.extract_mesh()
    }

    /// Canonical `points` carried into the live camera frame by the current warp (each bound to its
    /// K nearest nodes); unchanged before the first fused frame.
    pub fn warp_points(&self, points: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        match &self.graph {
            None => points.to_vec(),
            Some(graph) => points
                .par_iter()
                .map(|p| transform_point(&graph.blend(&graph.bind(p)), p))
                .collect(),
        }
    }

    /// `mesh` (canonical frame) carried into the live camera frame by the current warp, vertices in
    /// their order, normals recomputed from the faces.
    pub fn warp_mesh(&self, mesh: &Mesh) -> Mesh {
        let points: Vec<Vector3<f64>> = mesh.vertices.iter().map(|v| v.coords.cast()).collect();
        let mut out = mesh.clone();
        for (v, p) in out.vertices.iter_mut().zip(self.warp_points(&points)) {
            *v = p.cast::<f32>().into();
        }
        if !out.faces.is_empty() {
            out.compute_normals();
        }
        out
    }

    /// Processes one frame: raw depth in sensor units, optional colour, and an optional mask of
    /// the object's pixels. Never fails on bad input: a frame that cannot be tracked or fused is
    /// reported in [`FusionReport::failure`]. One that cannot be tracked leaves the field as it was;
    /// one that is tracked but cannot be fused (the block budget) keeps its field and leaves the
    /// volume as it was.
    pub fn process(
        &mut self,
        depth_raw: &Image<u16>,
        color: Option<&ColorImage>,
        mask: Option<&Image<bool>>,
    ) -> FusionReport {
        let mut report = FusionReport {
            failure: None,
            nodes: self.graph.as_ref().map_or(0, |g| g.nodes.len()),
            added_nodes: 0,
            summary: None,
            times: FusionTimes::default(),
        };
        let size = (self.camera.width, self.camera.height);
        let sizes = [(depth_raw.width, depth_raw.height)]
            .into_iter()
            .chain(color.map(|c| (c.width, c.height)))
            .chain(mask.map(|m| (m.width, m.height)));
        for s in sizes {
            if s != size {
                report.failure = Some(FusionFailure::ImageSize {
                    image: s,
                    camera: size,
                });
                return report;
            }
        }
        let t = Instant::now();
        self.masked.reset(size.0, size.1, 0);
        self.masked
            .data
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, o)| {
                if mask.is_none_or(|m| m.data[i]) {
                    *o = depth_raw.data[i];
                }
            });
        self.pre.process(&self.masked, color);
        let level = &self.pre.levels[self.data_level()];
        self.has_ratio =
            !level.intensity.data.is_empty() && self.params.register.photometric_weight > 0.0;
        if self.has_ratio {
            self.ratio
                .compute(&level.intensity, self.params.photometric_window);
        }
        self.has_chroma = color.is_some() && self.params.register.chroma_weight > 0.0;
        if let (true, Some(c)) = (self.has_chroma, color) {
            self.chroma.compute(c, self.data_level());
        }
        report.times.preprocess = t.elapsed().as_secs_f64();
        let result = match self.graph.is_some() {
            false => self.start(color, &mut report),
            true => self.track_and_fuse(color, &mut report),
        };
        if let Err(e) = result {
            report.failure = Some(e);
        }
        report.nodes = self.graph.as_ref().map_or(0, |g| g.nodes.len());
        report
    }

    /// The first frame: fused rigidly at the identity, then the graph sampled over its surface.
    fn start(
        &mut self,
        color: Option<&ColorImage>,
        report: &mut FusionReport,
    ) -> Result<(), FusionFailure> {
        let level = &self.pre.levels[0];
        let seen = level.depth.data.iter().filter(|d| **d > 0.0).count();
        if seen < MIN_START_PIXELS {
            return Err(FusionFailure::TooLittleDepth { pixels: seen });
        }
        let t = Instant::now();
        let mut volume = TsdfVolume::new(self.params.tsdf);
        volume.integrate(
            &level.depth,
            &level.normals,
            color,
            &self.camera,
            &Isometry3::identity(),
        )?;
        report.times.fuse = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let surface = mesh_points(&volume.extract_mesh());
        let graph = DeformationGraph::sample(&surface.0, self.params.graph)?;
        report.added_nodes = graph.nodes.len();
        self.volume = volume;
        self.graph = Some(graph);
        self.voxel_bindings.clear();
        self.chroma_book.clear();
        self.drift.reset();
        self.resample(&surface);
        self.learn_chroma(true);
        self.take_reference();
        report.times.surface = t.elapsed().as_secs_f64();
        Ok(())
    }

    /// Every later frame: optimise the field, fuse through it, grow the graph.
    fn track_and_fuse(
        &mut self,
        color: Option<&ColorImage>,
        report: &mut FusionReport,
    ) -> Result<(), FusionFailure> {
        self.track(report)?;
        self.fuse(color, report)?;
        let t = Instant::now();
        self.learn_chroma(false);
        let surface = mesh_points(&self.volume.extract_mesh());
        let graph = self.graph.as_mut().expect("started");
        report.added_nodes = graph.extend(&surface.0);
        self.since_refresh += 1;
        if report.added_nodes > 0 || self.since_refresh >= self.params.refresh_every {
            self.resample(&surface);
        }
        self.reference_frame.age += 1;
        if self.reference_frame.age >= self.params.photometric_keyframe_every {
            self.take_reference();
        }
        report.times.surface = t.elapsed().as_secs_f64();
        Ok(())
    }

    /// Optimises the field against the live depth (and intensities); a frame that cannot be
    /// tracked leaves the field as it was and is an error.
    fn track(&mut self, report: &mut FusionReport) -> Result<(), FusionFailure> {
        let graph = self.graph.as_mut().expect("started");
        let t = Instant::now();
        self.backup.clear();
        self.backup.extend(graph.nodes.iter().map(|n| n.motion));
        if self.reference_stale {
            let gate = (self.params.tsdf.voxel_size * self.params.tsdf.truncation_voxels) as f64;
            self.reference_frame.intensities(
                &self.points,
                &self.normals,
                &self.bindings,
                gate,
                &mut self.reference,
            );
            self.reference_stale = false;
        }
        let level = &self.pre.levels[self.params.data_level.min(self.pre.levels.len() - 1)];
        let depth = DepthTarget {
            camera: &level.camera,
            vertices: &level.vertices,
            normals: &level.normals,
        };
        let photometric = self.has_ratio.then(|| PhotometricTarget {
            live: self.ratio.live(&level.camera),
            reference: &self.reference,
        });
        let chroma = self.has_chroma.then(|| PhotometricTarget {
            live: self.chroma.live(&level.camera),
            reference: &self.chroma_reference,
        });
        let textured = (photometric.is_some() || chroma.is_some()).then_some(TexturedDepthTarget {
            depth,
            photometric,
            chroma,
        });
        let target: &dyn Target = match &textured {
            Some(t) => t,
            None => &depth,
        };
        self.optimiser.params = self.params.register.clone();
        let outcome =
            self.optimiser
                .optimise(graph, &self.points, &self.normals, &self.bindings, target);
        report.times.optimise = t.elapsed().as_secs_f64();
        let failure = match &outcome {
            Err(e) => Some(FusionFailure::Register(e.clone())),
            Ok(s)
                if (s.matched as f64)
                    < self.params.min_matched_fraction * self.points.len() as f64 =>
            {
                Some(FusionFailure::Lost {
                    matched: s.matched,
                    points: self.points.len(),
                })
            }
            Ok(s) => self
                .drift
                .judge(
                    s.chroma.as_ref(),
                    self.chroma.step,
                    self.params.colour_drift_ratio,
                )
                .err()
                .map(FusionFailure::from),
        };
        report.summary = outcome.ok();
        match failure {
            Some(f @ FusionFailure::ColourDrift(_)) => Err(f),
            Some(f) => {
                for (n, m) in graph.nodes.iter_mut().zip(&self.backup) {
                    n.motion = *m;
                }
                Err(f)
            }
            None => Ok(()),
        }
    }

    /// Fuses the live depth (and colour) into the canonical volume through the field.
    fn fuse(
        &mut self,
        color: Option<&ColorImage>,
        report: &mut FusionReport,
    ) -> Result<(), FusionFailure> {
        let graph = self.graph.as_ref().expect("started");
        let t = Instant::now();
        let level = &self.pre.levels[0];
        let sampling = BandSampling::of(&level.depth, &self.camera, self.params.tsdf.voxel_size);
        carry_back(
            graph,
            (&level.vertices, &level.normals),
            &sampling,
            &mut self.band,
        );
        let touched = self.volume.blocks_near(&self.band);
        let geometry = BlockGeometry {
            voxel: self.params.tsdf.voxel_size as f64,
            block: BLOCK,
        };
        self.voxel_bindings.update(graph, &touched, geometry);
        let warp = CachedWarp {
            graph,
            bindings: &self.voxel_bindings,
        };
        self.volume.integrate_warped(
            &level.depth,
            &level.normals,
            color,
            &self.camera,
            &touched,
            &warp,
        )?;
        report.times.fuse = t.elapsed().as_secs_f64();
        Ok(())
    }

    /// Takes the frame just tracked as the photometric references' frame (when the term is on).
    fn take_reference(&mut self) {
        self.reference_stale = true;
        let level = &self.pre.levels[self.data_level()];
        match (self.has_ratio, &self.graph) {
            (true, Some(graph)) => self.reference_frame.take(
                &self.ratio,
                (&level.vertices, &level.normals),
                &level.camera,
                graph,
            ),
            _ => self.reference_frame.clear(),
        }
    }

    /// Data points without a chromaticity take the live one where they are seen: at the start,
    /// every point whose pixel's depth lies within the gate of it (the first frame's surface, at
    /// the identity); after a tracked frame, every point matched at the end of its optimisation.
    fn learn_chroma(&mut self, start: bool) {
        if !self.has_chroma {
            return;
        }
        let cell = self.params.data_spacing.max(1e-6);
        let level = &self.pre.levels[self.data_level()];
        let live = self.chroma.live(&level.camera);
        if start {
            let depth = DepthTarget {
                camera: &level.camera,
                vertices: &level.vertices,
                normals: &level.normals,
            };
            let gate = self.params.register.max_distance;
            let seen = self.points.iter().enumerate().filter_map(|(i, p)| {
                let (q, _) = depth.associate(p)?;
                ((q - p).norm() <= gate).then_some((i, *p))
            });
            self.chroma_book
                .learn(&self.points, cell, seen, &live, &mut self.chroma_reference);
        } else {
            let seen = self.optimiser.matched_points();
            self.chroma_book
                .learn(&self.points, cell, seen, &live, &mut self.chroma_reference);
        }
    }

    /// The pyramid level the data terms work on.
    fn data_level(&self) -> usize {
        self.params.data_level.min(self.pre.levels.len() - 1)
    }

    /// Thins the canonical surface to the data points (one per `data_spacing` cube, the one
    /// nearest where the cube's chromaticity was seen), binds them, and gives them their cubes'
    /// chromaticities.
    fn resample(&mut self, (points, normals): &(Vec<Vector3<f64>>, Vec<Vector3<f64>>)) {
        let cell = self.params.data_spacing.max(1e-6);
        self.chroma_book.thin(
            (points, normals),
            cell,
            (&mut self.points, &mut self.normals),
        );
        self.chroma_book
            .assign(&self.points, cell, &mut self.chroma_reference);
        let graph = self.graph.as_ref().expect("started");
        let cell = BINDING_CELL_SPACINGS * graph.params.spacing;
        self.bindings = bind_in_cells(graph, &self.points, cell);
        self.since_refresh = 0;
        self.reference_stale = true;
    }
}
