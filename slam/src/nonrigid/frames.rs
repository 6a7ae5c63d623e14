//! Registering one RGB-D frame onto another, DeepDeform's setting (Bozic et al., CVPR 2020): two
//! frames of one sensor, the object masked in the source, and a motion too large for projective
//! association alone. The source's valid pixels become points; a deformation graph is sampled over
//! them; sparse colour matches ([`crate::features`]) give the rigid start and, grown by local
//! agreement, a first fit of the warp that they hold throughout ([`super::frame_matches`]); the
//! warp-field optimiser then refines it against the target's depth (projective association, and
//! the nearest point where the target sees through a point: [`super::frame_target`]). The result
//! is each source pixel's scene flow.

use super::chroma::{chromaticity, ChromaImage};
use super::colour_check::{check_colour, CheckInput, ColourCheck};
use super::frame_matches::{
    fit_to_matches, grown_and_tied, held_seeds, Bound, MatchFrames, TiedMatch,
};
use super::frame_target::SeenThroughTarget;
use super::graph::{Binding, DeformationGraph, GraphError, GraphParams};
use super::linear_steps::LinearSteps;
use super::outline_check::{check_outline, OutlineCheck};
use super::outline_start::{search, OutlineInput, Placement};
use super::photometric::PhotometricTarget;
use super::register::{DepthTarget, RegisterError, RegisterParams, RegisterSummary, WarpOptimiser};
use crate::camera::Camera;
use crate::features::{match_frames, FeatureFrame, FeatureParams, FrameMatches};
use crate::image::{
    valid, BilateralParams, ColorImage, DepthImage, Image, NormalMap, VertexMap, INVALID,
};
use crate::preprocess::{Level, PreprocessParams, Preprocessor};
use nalgebra::{Isometry3, Vector3};

/// A borrowed view of one RGB-D frame for registration (the frames read from disk are
/// [`crate::io::tum::RgbdFrame`]): depth in metres (0 where missing), optional colour and object
/// mask, all of the camera's size.
#[derive(Clone, Copy, Debug)]
pub struct FrameView<'a> {
    /// Intrinsics.
    pub camera: &'a Camera,
    /// Depth, metres.
    pub depth: &'a DepthImage,
    /// Colour (needed for feature matches).
    pub color: Option<&'a ColorImage>,
    /// The object's pixels (None: all).
    pub mask: Option<&'a Image<bool>>,
}

/// Settings of a frame-to-frame registration.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameSettings {
    /// The graph over the source.
    pub graph: GraphParams,
    /// The optimiser.
    pub register: RegisterParams,
    /// Feature matching for the rigid start (None: start where the source is).
    pub features: Option<FeatureParams>,
    /// Data terms on every `data_stride`-th source pixel each way (default 2).
    pub data_stride: usize,
    /// Depth smoothing before normals.
    pub bilateral: BilateralParams,
    /// Where the target's camera sees through a warped point (no depth at its pixel, or depth
    /// beyond the association gate behind it), the point takes the nearest of the target's points
    /// within this distance, metres ([`SeenThroughTarget`]; default 0.05, half the gate).
    pub nearest_within: f64,
    /// Whether the feature matches shape the warp, not only give the rigid start (default true):
    /// RANSAC's inliers grown by the matches that agree with them locally, the warp fitted to
    /// them before the depth is looked at, and held through every stage
    /// ([`super::frame_matches`]).
    pub hold_matches: bool,
    /// Without a feature start, whether to search for one by the object's outline against the
    /// target's depth (default true; [`super::outline_start`]).
    pub outline_start: bool,
}

impl Default for FrameSettings {
    /// Nodes 5 cm apart (DeepDeform's graphs use 5 cm); a rigid refinement within 10 cm of the
    /// feature-matched start; λ from 100 to 1 over three stages; association within 10 cm and 45°;
    /// Tukey's c 8 cm (a tighter c rejects the parts that deform most from the rigid start before
    /// the field can reach them: 3 cm left 2.7 cm of error on the generated pair of
    /// `tests/integration/nonrigid.rs`, 8 cm 0.8 cm); a weak stay prior for what depth cannot see;
    /// the chromaticity term at weight 0.3 under Tukey's c 0.1, as in tracking (NOTES 96).
    fn default() -> Self {
        Self {
            graph: GraphParams {
                spacing: 0.05,
                ..GraphParams::default()
            },
            register: RegisterParams {
                rigid_iterations: 20,
                rigid_max_distance: 0.1,
                schedule: vec![100.0, 10.0, 1.0],
                rounds: 3,
                iterations: 5,
                max_distance: 0.1,
                max_normal_angle_deg: 45.0,
                tukey: 0.08,
                point_weight: 0.1,
                stay_weight: 0.01,
                damping: 1e-4,
                linear: LinearSteps::Factorise,
                chroma_weight: 0.3,
                ..RegisterParams::default()
            },
            features: Some(FeatureParams::default()),
            data_stride: 2,
            bilateral: BilateralParams::default(),
            nearest_within: 0.05,
            hold_matches: true,
            outline_start: true,
        }
    }
}

/// Why two frames could not be registered.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum FrameError {
    /// An image of another size than its camera.
    #[error("the {what} is {}×{} but the camera is {}×{}", image.0, image.1, camera.0, camera.1)]
    Size {
        /// Which image.
        what: &'static str,
        /// Its size.
        image: (usize, usize),
        /// The camera's.
        camera: (usize, usize),
    },
    /// No valid (masked) source pixel.
    #[error("the source frame has no valid depth inside its mask")]
    NoPoints,
    /// The graph could not be sampled.
    #[error(transparent)]
    Graph(#[from] GraphError),
    /// The optimiser failed.
    #[error(transparent)]
    Register(#[from] RegisterError),
}

/// The result of [`register_frames`].
#[derive(Clone, Debug)]
pub struct FrameRegistration {
    /// Row-major pixel index of each source point.
    pub pixels: Vec<usize>,
    /// The source points (source camera frame), in row-major pixel order.
    pub points: Vec<Vector3<f64>>,
    /// Where the warp carries them (target camera frame).
    pub warped: Vec<Vector3<f64>>,
    /// Their warped normals.
    pub normals: Vec<Vector3<f64>>,
    /// The optimised graph.
    pub graph: DeformationGraph,
    /// What the optimiser did.
    pub summary: RegisterSummary,
    /// The feature matches that gave the rigid start (None: none were asked for or none agreed).
    pub matches: Option<FrameMatches>,
    /// Where the rigid start came from.
    pub start: FrameStart,
    /// Source pixels that carried data terms.
    pub data_points: usize,
    /// Whether the colour agrees with the warp (module `colour_check`; None without colour or
    /// when the warped source is nowhere in the target's view).
    pub colour: Option<ColourCheck>,
    /// Whether the warped object still stands before its background (module `outline_check`;
    /// None when the source's object has no outline before its background).
    pub outline: Option<OutlineCheck>,
}

/// Where a frame registration's rigid start came from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FrameStart {
    /// Colour feature matches that agreed on a rigid motion ([`FrameRegistration::matches`]).
    Features,
    /// The outline search's placement ([`super::outline_start`]), with its scores.
    Outline(Placement),
    /// The source's own place: no feature start, and the outline search gave none or was off.
    Identity,
}

impl FrameStart {
    /// "features", "outline" or "none".
    pub fn name(&self) -> &'static str {
        match self {
            Self::Features => "features",
            Self::Outline(_) => "outline",
            Self::Identity => "none",
        }
    }
}

/// Whether a frame registration can be trusted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FrameVerdict {
    /// At least [`MIN_MATCHED_FRACTION`] of the data points found a partner on the target at
    /// the end (within the association gates). Necessary, not sufficient: a plain object can
    /// end on another plain surface (NOTES 68).
    Registered,
    /// Fewer did: most of the source was not carried onto the target (a motion too large for
    /// the start, or an object the target does not show), whatever the optimiser reports.
    NotRegistered {
        /// Data points with a partner at the end.
        matched: usize,
        /// Data points.
        data_points: usize,
    },
    /// The source lies on the target's surface, but where it stood before its background in the
    /// source, more than [`super::outline_check::MAX_FLUSH_FRACTION`] of its seen outline now
    /// lies flush in a surface that goes on (module `outline_check`): a plain object laid on a
    /// plain surface it is not.
    LiesFlush(OutlineCheck),
    /// The source lies on the target's surface, but its colour does not: on more than
    /// [`MAX_OFF_FRACTION`] of the textured patches the warped source's chromaticity differs
    /// from the target's by more than a slide of the tolerance could explain, or over the whole
    /// judged area a textured source's colour is unrelated to the target's
    /// ([`ColourCheck::unrelated`]; module `colour_check`). The material slid along the surface.
    ColourDisagrees(ColourCheck),
}

/// The fraction of the source's data points that must end with a partner on the target for a
/// registration to count: most of the object. DeepDeform's shirt (seq258), registered to 1.8 cm
/// EPE, ends with 88 %; its test pair seq017, whose shirt is lifted 45 cm and no feature match
/// starts it, with 12 %.
pub const MIN_MATCHED_FRACTION: f64 = 0.5;

/// The fraction of the colour check's textured patches that may be off in a registration that
/// counts. Chosen on seeds 1–8 of `nonrigid_register pairs` (pairs under 1 cm EPE have at most
/// 0.12 off, those from 1.9 cm 0.20–0.50) and held out on seeds 9–14 (NOTES 97).
pub const MAX_OFF_FRACTION: f64 = 0.2;

/// A patch of the colour check is off when its colour fits better more than this fraction of
/// the graph's node spacing away (1.5 cm at the default 5 cm).
pub const COLOUR_TOLERANCE: f64 = 0.3;

/// [`FrameVerdict`] of a registration that left `matched` of `data_points` with a partner, and
/// whose outline and colour checks, when there were any, came out as `outline` and `colour`:
/// the depth's count first, then the outline, then the colour.
pub fn frame_verdict(
    (matched, data_points): (usize, usize),
    outline: Option<&OutlineCheck>,
    colour: Option<&ColourCheck>,
) -> FrameVerdict {
    if data_points == 0 || (matched as f64) < MIN_MATCHED_FRACTION * data_points as f64 {
        return FrameVerdict::NotRegistered {
            matched,
            data_points,
        };
    }
    if let Some(o) = outline.filter(|o| o.lies_flush()) {
        return FrameVerdict::LiesFlush(*o);
    }
    match colour {
        Some(c) if c.fraction_off() > MAX_OFF_FRACTION || c.unrelated() => {
            FrameVerdict::ColourDisagrees(*c)
        }
        _ => FrameVerdict::Registered,
    }
}

impl FrameVerdict {
    /// The verdict by name: "registered", "depth" (too little of the source ended on the
    /// target), "outline" (on a surface, but flush in it) or "colour" (on the surface, but slid
    /// along it).
    pub fn name(&self) -> &'static str {
        match self {
            Self::Registered => "registered",
            Self::NotRegistered { .. } => "depth",
            Self::LiesFlush(_) => "outline",
            Self::ColourDisagrees(_) => "colour",
        }
    }
}

impl FrameRegistration {
    /// Whether most of the source ended on the target, its outline standing as it stood and
    /// its colour with it ([`frame_verdict`]).
    pub fn verdict(&self) -> FrameVerdict {
        frame_verdict(
            (self.summary.matched, self.data_points),
            self.outline.as_ref(),
            self.colour.as_ref(),
        )
    }

    /// Per-pixel scene flow `warped − point` (NaN where the source had no point), `width × height`.
    pub fn scene_flow(&self, width: usize, height: usize) -> Image<[f32; 3]> {
        let mut flow = Image::filled(width, height, [f32::NAN; 3]);
        for ((&i, p), q) in self.pixels.iter().zip(&self.points).zip(&self.warped) {
            if let Some(o) = flow.data.get_mut(i) {
                let d = q - p;
                *o = [d.x as f32, d.y as f32, d.z as f32];
            }
        }
        flow
    }

    /// The source's points moved by another per-pixel scene flow (a ground truth's), those
    /// whose pixel has a finite one. Their median distance to the target's surface is what the
    /// flow's own answer leaves: with a ground truth, the floor that the depth's noise and the
    /// truth's own error set for any registration.
    pub fn points_moved_by(&self, flow: &Image<[f32; 3]>) -> Vec<Vector3<f64>> {
        self.pixels
            .iter()
            .zip(&self.points)
            .filter_map(|(&i, p)| {
                let f = flow.data.get(i)?;
                f.iter()
                    .all(|v| v.is_finite())
                    .then(|| p + Vector3::from(*f).cast::<f64>())
            })
            .collect()
    }
}

fn check(what: &'static str, size: (usize, usize), camera: &Camera) -> Result<(), FrameError> {
    if size != (camera.width, camera.height) {
        return Err(FrameError::Size {
            what,
            image: size,
            camera: (camera.width, camera.height),
        });
    }
    Ok(())
}

impl<'a> FrameView<'a> {
    /// A frame of these images.
    pub fn new(
        camera: &'a Camera,
        depth: &'a DepthImage,
        color: Option<&'a ColorImage>,
        mask: Option<&'a Image<bool>>,
    ) -> Self {
        Self {
            camera,
            depth,
            color,
            mask,
        }
    }

    /// Every image must be the camera's size; `names` are the depth's, colour's and mask's, for the
    /// error.
    fn check(&self, names: [&'static str; 3]) -> Result<(), FrameError> {
        check(names[0], (self.depth.width, self.depth.height), self.camera)?;
        if let Some(c) = self.color {
            check(names[1], (c.width, c.height), self.camera)?;
        }
        if let Some(m) = self.mask {
            check(names[2], (m.width, m.height), self.camera)?;
        }
        Ok(())
    }

    /// Vertex and normal maps of the smoothed depth (the front end's full-resolution level),
    /// invalid outside the mask.
    fn maps(&self, bilateral: &BilateralParams) -> (VertexMap, NormalMap) {
        let params = PreprocessParams {
            levels: 1,
            bilateral: *bilateral,
        };
        let mut pre = Preprocessor::new(*self.camera, params);
        pre.process_metres(self.depth, None);
        let Level {
            mut vertices,
            mut normals,
            ..
        } = pre.levels.swap_remove(0);
        if let Some(mask) = self.mask {
            for ((v, n), &m) in vertices
                .data
                .iter_mut()
                .zip(&mut normals.data)
                .zip(&mask.data)
            {
                if !m {
                    (*v, *n) = (INVALID, INVALID);
                }
            }
        }
        (vertices, normals)
    }
}

fn vector(v: &[f32; 3]) -> Vector3<f64> {
    Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64)
}

/// The source frame's points: each valid pixel inside the mask, back-projected, with its normal.
struct SourcePoints {
    /// The pixels (row-major index) the points come from.
    pixels: Vec<usize>,
    points: Vec<Vector3<f64>>,
    /// A pixel without a normal (at an edge) faces the camera.
    normals: Vec<Vector3<f64>>,
    /// The points that carry data terms: those with a normal, on every `stride`-th pixel.
    data: Vec<usize>,
}

/// [`SourcePoints`] of `source`, its normals `source_normals`, data terms every `stride` pixels.
fn source_points(
    source: &FrameView<'_>,
    source_normals: &NormalMap,
    stride: usize,
) -> SourcePoints {
    let (w, h) = (source.camera.width, source.camera.height);
    let (mut pixels, mut points, mut normals) = (Vec::new(), Vec::new(), Vec::new());
    let mut data = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let z = source.depth.data[i];
            if !(z > 0.0 && z.is_finite()) || source.mask.is_some_and(|m| !m.data[i]) {
                continue;
            }
            let n = source_normals.data[i];
            if valid(&n) && x % stride == 0 && y % stride == 0 {
                data.push(points.len());
            }
            pixels.push(i);
            points.push(
                source
                    .camera
                    .back_project(x as f64, y as f64, z as f64)
                    .coords,
            );
            normals.push(if valid(&n) { vector(&n) } else { -Vector3::z() });
        }
    }
    SourcePoints {
        pixels,
        points,
        normals,
        data,
    }
}

/// The colour feature matches between the frames (and their rigid motion), when both have colour
/// and the settings ask for them.
fn feature_start(
    source: &FrameView<'_>,
    target: &FrameView<'_>,
    settings: &FrameSettings,
) -> Option<FrameMatches> {
    match (&settings.features, source.color, target.color) {
        (Some(params), Some(sc), Some(tc)) => match_frames(
            &FeatureFrame {
                color: sc,
                depth: source.depth,
                camera: source.camera,
                mask: source.mask,
            },
            &FeatureFrame {
                color: tc,
                depth: target.depth,
                camera: target.camera,
                mask: target.mask,
            },
            params,
        ),
        _ => None,
    }
}

/// Without a feature start: the outline search's placement when it gives one
/// ([`super::outline_start::OutlineStart::start`]), else the source's own place.
fn searched_start(
    source: &FrameView<'_>,
    target: &FrameView<'_>,
    (pixels, points): (&[usize], &[Vector3<f64>]),
    settings: &FrameSettings,
) -> (FrameStart, Isometry3<f64>) {
    let input = outline_input([source, target], (pixels, points), settings);
    let found = settings.outline_start.then(|| search(&input)).flatten();
    match found.and_then(|f| f.start().map(|motion| (f.best, motion))) {
        Some((best, motion)) => (FrameStart::Outline(best), motion),
        None => (FrameStart::Identity, Isometry3::identity()),
    }
}

/// The outline search's and check's input: the source's object at `pixels` with its `points`
/// against the target's depth, the association gate and the node spacing as the gap.
fn outline_input<'a>(
    [source, target]: [&'a FrameView<'a>; 2],
    (pixels, points): (&'a [usize], &'a [Vector3<f64>]),
    settings: &FrameSettings,
) -> OutlineInput<'a> {
    OutlineInput {
        source_camera: source.camera,
        source_depth: source.depth,
        pixels,
        points,
        target_camera: target.camera,
        target_depth: target.depth,
        gate: settings.register.max_distance,
        gap: settings.graph.spacing,
    }
}

/// The matches that shape the warp ([`super::frame_matches`]): none without matches or when the
/// settings keep them to the rigid start.
fn held_matches(
    matches: Option<&FrameMatches>,
    frames: &MatchFrames<'_>,
    settings: &FrameSettings,
) -> Vec<TiedMatch> {
    let tolerance = settings
        .features
        .as_ref()
        .map_or(0.0, |f| f.inlier_distance);
    match matches.filter(|_| settings.hold_matches) {
        Some(m) => grown_and_tied(m, frames, settings.graph.spacing, tolerance),
        None => Vec::new(),
    }
}

/// Registers `source` onto `target`: every valid source pixel inside its mask is a point (its raw
/// depth back-projected), a graph is sampled over them, the rigid start comes from feature matches
/// when both frames have colour, and the field is optimised against the target's depth with data
/// terms on a strided subset of the pixels (those with a normal).
pub fn register_frames(
    source: &FrameView<'_>,
    target: &FrameView<'_>,
    settings: &FrameSettings,
) -> Result<FrameRegistration, FrameError> {
    source.check(["source depth", "source colour", "source mask"])?;
    target.check(["target depth", "target colour", "target mask"])?;
    let (_, source_normals) = source.maps(&settings.bilateral);
    let (target_vertices, target_normals) = target.maps(&settings.bilateral);
    let SourcePoints {
        pixels,
        points,
        normals,
        mut data,
    } = source_points(source, &source_normals, settings.data_stride.max(1));
    if points.is_empty() {
        return Err(FrameError::NoPoints);
    }
    let mut graph = DeformationGraph::sample(&points, settings.graph)?;
    let bindings = graph.bind_all(&points);
    let matches = feature_start(source, target, settings);
    let (how, start) = match &matches {
        Some(m) => (FrameStart::Features, m.motion),
        None => searched_start(source, target, (&pixels, &points), settings),
    };
    let frames = MatchFrames {
        source: source.camera,
        target: target.camera,
        target_normals: &target_normals,
        pixels: &pixels,
    };
    let held = held_matches(matches.as_ref(), &frames, settings);
    let bound = Bound {
        points: &points,
        normals: &normals,
        bindings: &bindings,
    };
    let fit = fit_to_matches(&mut graph, &held, &bound, &settings.register, &start)?;
    // a fit to the matches has moved the nodes already
    let start = fit.as_ref().map_or(start, |_| Isometry3::identity());
    let seeds = held_seeds(&held, &normals, &mut data);
    let pick = |v: &[Vector3<f64>]| -> Vec<Vector3<f64>> { data.iter().map(|&k| v[k]).collect() };
    let data_bindings: Vec<_> = data.iter().map(|&k| bindings[k]).collect();
    let chroma = FrameChroma::of([source, target], (&data, &pixels));
    let depth_target = seen_through(
        DepthTarget {
            camera: target.camera,
            vertices: &target_vertices,
            normals: &target_normals,
        },
        chroma.as_ref(),
        settings,
    );
    let mut optimiser = WarpOptimiser::new(settings.register.clone());
    let mut summary = optimiser.optimise_from(
        &mut graph,
        &pick(&points),
        &pick(&normals),
        &data_bindings,
        &depth_target,
        &[start],
        seeds.as_ref(),
    )?;
    fit.iter().for_each(|f| summary.take_in_first(f));
    let (warped, warped_normals) = warped_by(&graph, &bindings, (&points, &normals));
    let (colour, outline) = verdict_checks(
        [source, target],
        chroma.as_ref(),
        (&pixels, &points, &warped),
        (&target_vertices, settings),
    );
    Ok(FrameRegistration {
        colour,
        outline,
        pixels,
        points,
        warped,
        normals: warped_normals,
        graph,
        summary,
        matches,
        start: how,
        data_points: data.len(),
    })
}

/// The verdict's colour and outline checks (modules `colour_check`, `outline_check`) of the
/// source's `points` at `pixels` carried to `warped`; the colour's only when both frames have
/// colour (`chroma`).
fn verdict_checks(
    [source, target]: [&FrameView<'_>; 2],
    chroma: Option<&FrameChroma>,
    (pixels, points, warped): (&[usize], &[Vector3<f64>], &[Vector3<f64>]),
    (target_vertices, settings): (&VertexMap, &FrameSettings),
) -> (Option<ColourCheck>, Option<OutlineCheck>) {
    let colour = chroma.and_then(|c| c.check(target, warped, (target_vertices, settings)));
    let input = outline_input([source, target], (pixels, points), settings);
    (colour, check_outline(&input, warped))
}

/// `points` with their `normals` carried by `graph` through their `bindings`.
fn warped_by(
    graph: &DeformationGraph,
    bindings: &[Binding],
    (points, normals): (&[Vector3<f64>], &[Vector3<f64>]),
) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let (mut warped, mut warped_normals) = (Vec::new(), Vec::new());
    graph.warp_all(bindings, points, normals, &mut warped, &mut warped_normals);
    (warped, warped_normals)
}

/// The target as the optimiser sees it: its depth, seen through where it has none, and its
/// chromaticity when the term is weighted.
fn seen_through<'a>(
    depth: DepthTarget<'a>,
    chroma: Option<&'a FrameChroma>,
    settings: &FrameSettings,
) -> SeenThroughTarget<'a> {
    SeenThroughTarget::new(
        depth,
        settings.register.max_distance,
        settings.nearest_within,
    )
    .with_chroma(
        chroma
            .filter(|_| settings.register.chroma_weight > 0.0)
            .map(|c| c.term(depth.camera)),
    )
}

/// The chromaticity of a frame pair (module `chroma`), when both frames have colour: the
/// target's at full resolution, the source's at each of its points' pixels (read by the colour
/// check), and at the data points' pixels the references of the term, when it is weighted.
/// Shading and exposure leave the chromaticity as it is, so the source's own pixel can be the
/// reference.
struct FrameChroma {
    target: ChromaImage,
    /// Per source point (NaN: too dark).
    source: Vec<f32>,
    /// Per data point (0: too dark, as in the target's image).
    references: Vec<f32>,
}

impl FrameChroma {
    /// From `[source, target]`, for the source's points at `pixels` and the data points `data`
    /// (indices into `pixels`), when both have colour (the colour check needs it whether or not
    /// the term is weighted).
    fn of(
        [source, target]: [&FrameView<'_>; 2],
        (data, pixels): (&[usize], &[usize]),
    ) -> Option<Self> {
        let (Some(sc), Some(tc)) = (source.color, target.color) else {
            return None;
        };
        let source: Vec<f32> = pixels
            .iter()
            .map(|&k| chromaticity(sc.data[k]).unwrap_or(f32::NAN))
            .collect();
        let references = data
            .iter()
            .map(|&k| if source[k].is_nan() { 0.0 } else { source[k] })
            .collect();
        let mut image = ChromaImage::default();
        image.compute(tc, 0);
        Some(Self {
            target: image,
            source,
            references,
        })
    }

    /// The colour check (module `colour_check`) of the source's points carried to `warped`, on
    /// patches of a twentieth of the image's width, with a tolerance of [`COLOUR_TOLERANCE`] of
    /// the graph's node spacing.
    fn check(
        &self,
        target: &FrameView<'_>,
        warped: &[Vector3<f64>],
        (target_vertices, settings): (&VertexMap, &FrameSettings),
    ) -> Option<ColourCheck> {
        let input = CheckInput {
            camera: target.camera,
            target: &self.target.image,
            target_vertices,
            source: &self.source,
            warped,
            gate: settings.register.max_distance,
        };
        let patch = (target.camera.width / 20).max(8);
        check_colour(&input, patch, COLOUR_TOLERANCE * settings.graph.spacing)
    }

    /// The term, the target's chromaticities seen through `camera`.
    fn term<'a>(&'a self, camera: &'a Camera) -> PhotometricTarget<'a> {
        PhotometricTarget {
            live: self.target.live(camera),
            reference: &self.references,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn most_of_the_source_must_end_on_the_target() {
        assert_eq!(
            frame_verdict((50, 100), None, None),
            FrameVerdict::Registered
        );
        let not = |matched, data_points| FrameVerdict::NotRegistered {
            matched,
            data_points,
        };
        assert_eq!(frame_verdict((49, 100), None, None), not(49, 100));
        assert_eq!(
            frame_verdict((0, 0), None, None),
            not(0, 0),
            "no data is no registration"
        );
    }

    #[test]
    fn more_than_a_fifth_of_the_textured_patches_off_is_a_slide() {
        let check = |aligned, off| ColourCheck {
            aligned,
            off,
            flat: 100,
            floor: 1e-4,
            correlation: 0.9,
            contrast: 20.0,
        };
        let fine = check(40, 10);
        assert_eq!(
            frame_verdict((90, 100), None, Some(&fine)),
            FrameVerdict::Registered
        );
        let slid = check(39, 10);
        assert_eq!(
            frame_verdict((90, 100), None, Some(&slid)),
            FrameVerdict::ColourDisagrees(slid)
        );
        assert!(
            matches!(
                frame_verdict((10, 100), None, Some(&fine)),
                FrameVerdict::NotRegistered { .. }
            ),
            "the depth's verdict comes first"
        );
        let names = [
            frame_verdict((90, 100), None, Some(&fine)).name(),
            frame_verdict((10, 100), None, Some(&fine)).name(),
            frame_verdict((90, 100), None, Some(&slid)).name(),
        ];
        assert_eq!(names, ["registered", "depth", "colour"]);
        let grey = check(0, 0);
        assert_eq!(
            frame_verdict((90, 100), None, Some(&grey)),
            FrameVerdict::Registered
        );
    }

    #[test]
    fn a_textured_colour_unrelated_to_the_target_is_a_slide_with_every_patch_flat() {
        let check = |correlation, contrast| ColourCheck {
            flat: 30,
            floor: 1e-2,
            correlation,
            contrast,
            ..ColourCheck::default()
        };
        let verdict = |c: &ColourCheck| frame_verdict((90, 100), None, Some(c));
        let unrelated = check(0.1, 15.0);
        assert_eq!(
            verdict(&unrelated),
            FrameVerdict::ColourDisagrees(unrelated)
        );
        assert_eq!(verdict(&check(0.5, 15.0)), FrameVerdict::Registered);
        // a plain source (its variance about its noise's) says nothing
        assert_eq!(verdict(&check(0.1, 1.5)), FrameVerdict::Registered);
    }

    #[test]
    fn an_outline_mostly_flush_is_not_registered_before_the_colour_is_asked() {
        let outline = |seen, flush| OutlineCheck {
            outline: 100,
            seen,
            flush,
        };
        let check = ColourCheck {
            aligned: 40,
            off: 0,
            flat: 100,
            floor: 1e-4,
            correlation: 0.9,
            contrast: 20.0,
        };
        let verdict = |o: &OutlineCheck| frame_verdict((90, 100), Some(o), Some(&check));
        assert_eq!(verdict(&outline(60, 30)), FrameVerdict::Registered);
        let flush = outline(60, 31);
        assert_eq!(verdict(&flush), FrameVerdict::LiesFlush(flush));
        assert_eq!(verdict(&flush).name(), "outline");
        // too few seen to judge: the colour decides
        assert_eq!(verdict(&outline(19, 19)), FrameVerdict::Registered);
        assert!(matches!(
            frame_verdict((10, 100), Some(&flush), None),
            FrameVerdict::NotRegistered { .. }
        ));
    }
}
