//! Sparse colour correspondences between two RGB-D frames, for motions too large for projective or
//! closest-point association to bridge: FAST-9 corners (Rosten & Drummond, *Machine learning for
//! high-speed corner detection*, ECCV 2006) with BRIEF descriptors (Calonder et al., ECCV 2010),
//! both from `imageproc`, optionally on each level of an image pyramid as ORB has them (Rublee et
//! al., ICCV 2011), with the depth telling which levels can match (a patch's size in metres);
//! matched by Hamming distance under Lowe's ratio test (IJCV 2004) and a mutual-best check;
//! lifted to 3D through the depth maps; and a rigid motion fitted to them by
//! RANSAC (Fischler & Bolles 1981) with the closed-form least-squares fit of Umeyama (1991).

use crate::camera::Camera;
use crate::eval::umeyama;
use crate::image::{intensity, ColorImage, DepthImage, Image};
use imageproc::binary_descriptors::brief::{brief, BriefDescriptor, TestPair};
use imageproc::binary_descriptors::BinaryDescriptor;
use imageproc::point::Point;
use nalgebra::{Isometry3, Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// BRIEF's patch is 31 × 31 pixels; keypoints keep this far from the border.
const BORDER: u32 = 17;
/// Bits per descriptor.
const BITS: usize = 256;

/// Settings of detection, matching and the rigid fit.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureParams {
    /// FAST intensity threshold (default 5: cloth is faintly textured; at 5, DeepDeform's shirt
    /// (seq258, frame 0 masked onto frame 110) gives 814 and 966 keypoints with depth, of which
    /// RANSAC keeps 102).
    pub fast_threshold: u8,
    /// Corners kept per image, strongest first (default 3000).
    pub max_keypoints: usize,
    /// Non-maximum suppression radius, pixels (default 3).
    pub suppression_radius: u32,
    /// A match's Hamming distance at most (default 80 of 256 bits).
    pub max_hamming: u32,
    /// Lowe's ratio: best distance below this fraction of the second best (default 0.85).
    pub ratio: f32,
    /// RANSAC hypotheses (default 2000).
    pub ransac_iterations: usize,
    /// A match is an inlier of a motion when it lands within this distance, metres (default 0.03).
    pub inlier_distance: f64,
    /// Fewer inliers than this and there is no motion (default 12).
    pub min_inliers: usize,
    /// Seed of the descriptor pattern and of RANSAC, for repeatable runs (default 7).
    pub seed: u64,
    /// Image pyramid levels corners are detected and described on, as ORB does (Rublee et al.,
    /// ICCV 2011), so that a surface seen from nearer or further matches (default 1: the image
    /// alone). With more than one, two keypoints match only where their depths agree with
    /// their levels: a patch's size in metres is its level's scale times its depth.
    pub levels: usize,
    /// Scale between two pyramid levels (default 1.25; at most 1, only the image itself).
    pub level_scale: f64,
}

impl Default for FeatureParams {
    fn default() -> Self {
        Self {
            fast_threshold: 5,
            max_keypoints: 3000,
            suppression_radius: 3,
            max_hamming: 80,
            ratio: 0.85,
            ransac_iterations: 2000,
            inlier_distance: 0.03,
            min_inliers: 12,
            seed: 7,
            levels: 1,
            level_scale: 1.25,
        }
    }
}

/// One frame as the features see it: colour, depth in metres, the camera, and optionally the
/// pixels that belong to the object.
#[derive(Clone, Copy, Debug)]
pub struct FeatureFrame<'a> {
    /// Colour.
    pub color: &'a ColorImage,
    /// Depth, metres (0 where missing).
    pub depth: &'a DepthImage,
    /// Intrinsics.
    pub camera: &'a Camera,
    /// Object mask (None: every pixel).
    pub mask: Option<&'a Image<bool>>,
}

/// Keypoints of one frame with valid depth: pixel, camera-frame point, descriptor and the size
/// of its patch.
#[derive(Clone, Default)]
pub struct Keypoints {
    /// Pixel (x, y) of each keypoint (on the full image, whatever level it was found on).
    pub pixels: Vec<(u32, u32)>,
    /// Its back-projected point, camera frame.
    pub points: Vec<Vector3<f64>>,
    descriptors: Vec<BriefDescriptor>,
    /// ln(s^l z) of each: the log of its patch's size in metres up to a constant, for level l
    /// of scale s at depth z ([`FeatureParams::levels`]).
    sizes: Vec<f32>,
}

impl std::fmt::Debug for Keypoints {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Keypoints")
            .field("pixels", &self.pixels)
            .field("points", &self.points)
            .finish_non_exhaustive()
    }
}

impl Keypoints {
    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.pixels.len()
    }

    /// True when there are none.
    pub fn is_empty(&self) -> bool {
        self.pixels.is_empty()
    }

    /// Frees the arrays' spare capacity (for keypoints kept long).
    pub(crate) fn shrink_to_fit(&mut self) {
        self.pixels.shrink_to_fit();
        self.points.shrink_to_fit();
        self.descriptors.shrink_to_fit();
        self.sizes.shrink_to_fit();
    }

    /// Bytes held: the three arrays as allocated plus each descriptor's bit block.
    pub fn bytes(&self) -> usize {
        use std::mem::size_of;
        let bits: usize = self.descriptors.iter().map(|d| d.bits.capacity()).sum();
        self.pixels.capacity() * size_of::<(u32, u32)>()
            + self.points.capacity() * size_of::<Vector3<f64>>()
            + self.descriptors.capacity() * size_of::<BriefDescriptor>()
            + self.sizes.capacity() * size_of::<f32>()
            + bits * size_of::<u128>()
    }
}

/// The fixed BRIEF test pattern of a seed: pairs within the 31 × 31 patch, each coordinate drawn
/// from N(15, 6.6²) as in Calonder et al.'s isotropic Gaussian pattern (G II).
fn test_pairs(seed: u64) -> Vec<TestPair> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(15.0f32, 6.6).expect("a valid deviation");
    let mut pairs = Vec::with_capacity(BITS);
    while pairs.len() < BITS {
        let c: [f32; 4] = std::array::from_fn(|_| normal.sample(&mut rng).round());
        if c.iter().all(|v| (0.0..31.0).contains(v)) {
            pairs.push(TestPair {
                p0: Point::new(c[0] as u32, c[1] as u32),
                p1: Point::new(c[2] as u32, c[3] as u32),
            });
        }
    }
    pairs
}

/// Detects and describes the keypoints of a frame: FAST-9 corners, locally maximal, inside the
/// mask and away from the border, with valid depth, on each level of an image pyramid
/// ([`FeatureParams::levels`]); the strongest of each level, the budget of `max_keypoints`
/// shared between the levels by their areas (as ORB shares it).
pub fn detect(frame: &FeatureFrame<'_>, params: &FeatureParams) -> Keypoints {
    let (w, h) = (frame.color.width as u32, frame.color.height as u32);
    let mut keypoints = Keypoints::default();
    if w <= 2 * BORDER || h <= 2 * BORDER || frame.depth.data.len() != frame.color.data.len() {
        return keypoints;
    }
    let mut luma = Image::new(0, 0);
    intensity(frame.color, &mut luma);
    let gray = image::GrayImage::from_fn(w, h, |x, y| {
        image::Luma([(luma.data[(y * w + x) as usize] * 255.0).round() as u8])
    });
    let pairs = test_pairs(params.seed);
    // each level from the one before, as ORB's pyramid is built
    let mut pyramid = vec![(gray, 1.0)];
    for l in 1..pyramid_levels(params) {
        let scale = params.level_scale.powi(l as i32);
        let (lw, lh) = ((w as f64 / scale) as u32, (h as f64 / scale) as u32);
        if lw <= 2 * BORDER || lh <= 2 * BORDER {
            break;
        }
        let Some(level) = shrink(&pyramid[l - 1].0, lw, lh) else {
            break;
        };
        pyramid.push((level, scale));
    }
    // the coarser levels' shares of the budget (by area) rounded down, the finest level's the rest
    let area = |l: usize| params.level_scale.powi(-2 * l as i32);
    let total: f64 = (0..pyramid.len()).map(area).sum();
    let share = |l: usize| (params.max_keypoints as f64 * area(l) / total) as usize;
    let coarse: usize = (1..pyramid.len()).map(share).sum();
    use rayon::prelude::*;
    let described: Vec<Keypoints> = pyramid
        .par_iter()
        .enumerate()
        .map(|(l, (image, scale))| {
            let budget = if l == 0 {
                params.max_keypoints - coarse
            } else {
                share(l)
            };
            describe_level(frame, params, (image, *scale, &pairs), budget)
        })
        .collect();
    for level in described {
        keypoints.pixels.extend(level.pixels);
        keypoints.points.extend(level.points);
        keypoints.descriptors.extend(level.descriptors);
        keypoints.sizes.extend(level.sizes);
    }
    keypoints
}

/// The pyramid levels `params` ask for: [`FeatureParams::levels`] (at least 1), or the image
/// alone where the scale between levels does not shrink.
fn pyramid_levels(params: &FeatureParams) -> usize {
    if params.level_scale > 1.0 {
        params.levels.max(1)
    } else {
        1
    }
}

/// `image` shrunk to `w` × `h` by a bilinear filter widened to the scale (no aliasing), with
/// `fast_image_resize`'s SIMD convolution; `None` if it refused (the sizes are consistent by
/// construction, so it should not). Called on its one-byte pixel type (`resize_typed`): its
/// untyped `resize` compiled the convolutions of all 13 pixel types into this crate, about half
/// of its LLVM IR (NOTES 161).
fn shrink(image: &image::GrayImage, w: u32, h: u32) -> Option<image::GrayImage> {
    use fast_image_resize::images::{TypedImage, TypedImageRef};
    use fast_image_resize::{pixels::U8, FilterType, ResizeAlg, ResizeOptions, Resizer};
    let (iw, ih) = image.dimensions();
    let src = TypedImageRef::<U8>::from_buffer(iw, ih, image.as_raw()).ok()?;
    let mut shrunk = vec![0u8; w as usize * h as usize];
    let mut out = TypedImage::<U8>::from_buffer(w, h, &mut shrunk).ok()?;
    let options = ResizeOptions::new().resize_alg(ResizeAlg::Convolution(FilterType::Bilinear));
    thread_local! {
        static RESIZER: std::cell::RefCell<Resizer> = std::cell::RefCell::new(Resizer::new());
    }
    RESIZER
        .with_borrow_mut(|r| r.resize_typed(&src, &mut out, &options))
        .ok()?;
    image::GrayImage::from_raw(w, h, shrunk)
}

/// The keypoints of one pyramid level (`image` at `scale` of the frame's), at most `budget`.
fn describe_level(
    frame: &FeatureFrame<'_>,
    params: &FeatureParams,
    (image, scale, pairs): (&image::GrayImage, f64, &Vec<TestPair>),
    budget: usize,
) -> Keypoints {
    let mut out = Keypoints::default();
    let (lw, lh) = image.dimensions();
    let w = frame.color.width as u32;
    // a level pixel's centre on the full image
    let full = |v: u32, n: u32| (((v as f64 + 0.5) * scale - 0.5).round() as u32).min(n - 1);
    let depth_at = |x: u32, y: u32| {
        let i = (full(y, frame.color.height as u32) * w + full(x, w)) as usize;
        (i, frame.depth.data[i])
    };
    let corners = imageproc::corners::corners_fast9(image, params.fast_threshold);
    let mut corners = imageproc::suppress::local_maxima(&corners, params.suppression_radius);
    corners.retain(|c| {
        let (i, z) = depth_at(c.x, c.y);
        c.x >= BORDER
            && c.y >= BORDER
            && c.x + BORDER < lw
            && c.y + BORDER < lh
            && z > 0.0
            && z.is_finite()
            && frame
                .mask
                .is_none_or(|m| m.data.get(i).copied().unwrap_or(false))
    });
    corners.sort_by(|a, b| b.score.total_cmp(&a.score));
    corners.truncate(budget);
    let at: Vec<Point<u32>> = corners.iter().map(|c| Point::new(c.x, c.y)).collect();
    let Ok((descriptors, _)) = brief(image, &at, BITS, Some(pairs)) else {
        // every keypoint is inside the border, so this cannot fail; no features if it did
        return out;
    };
    for (c, d) in corners.iter().zip(descriptors) {
        let (i, z) = depth_at(c.x, c.y);
        let (x, y) = (i as u32 % w, i as u32 / w);
        out.pixels.push((x, y));
        out.points.push(
            frame
                .camera
                .back_project(x as f64, y as f64, z as f64)
                .coords,
        );
        out.descriptors.push(d);
        out.sizes.push((scale * z as f64).ln() as f32);
    }
    out
}

/// For each descriptor of `a`, the index in `b` of its nearest one when it is within
/// `max_hamming` and clearly nearer than the second nearest (Lowe's ratio). With pyramid levels,
/// only keypoints whose patches have about the same size in metres are compared (within one and a
/// half levels: half a level of rounding and a corner found on the next level too).
fn nearest(a: &Keypoints, b: &Keypoints, params: &FeatureParams) -> Vec<Option<usize>> {
    use rayon::prelude::*;
    let gate = if pyramid_levels(params) > 1 {
        (1.5 * params.level_scale.ln()) as f32
    } else {
        f32::INFINITY
    };
    a.descriptors
        .par_iter()
        .zip(&a.sizes)
        .map(|(da, sa)| {
            let (mut best, mut second, mut arg) = (u32::MAX, u32::MAX, 0);
            for (j, (db, sb)) in b.descriptors.iter().zip(&b.sizes).enumerate() {
                if (sa - sb).abs() > gate {
                    continue;
                }
                let d = da.hamming_distance(db);
                if d < best {
                    (second, best, arg) = (best, d, j);
                } else if d < second {
                    second = d;
                }
            }
            (best <= params.max_hamming && (best as f32) < params.ratio * second as f32)
                .then_some(arg)
        })
        .collect()
}

/// Matches keypoints of `a` and `b`: pairs (i, j) that are each other's ratio-test nearest.
pub fn match_keypoints(
    a: &Keypoints,
    b: &Keypoints,
    params: &FeatureParams,
) -> Vec<(usize, usize)> {
    let (ab, ba) = (nearest(a, b, params), nearest(b, a, params));
    ab.iter()
        .enumerate()
        .filter_map(|(i, j)| j.filter(|&j| ba[j] == Some(i)).map(|j| (i, j)))
        .collect()
}

/// A rigid motion fitted to 3D matches.
#[derive(Clone, Debug, PartialEq)]
pub struct RigidFit {
    /// Maps the first frame's points onto the second's.
    pub motion: Isometry3<f64>,
    /// Whether each match is an inlier.
    pub inliers: Vec<bool>,
}

impl RigidFit {
    /// Number of inliers.
    pub fn inlier_count(&self) -> usize {
        self.inliers.iter().filter(|&&b| b).count()
    }
}

/// The least-squares rigid motion taking `src[k]` to `dst[k]` over the selected `k`.
fn fit(src: &[Vector3<f64>], dst: &[Vector3<f64>], select: &[usize]) -> Option<Isometry3<f64>> {
    let a: Vec<Point3<f64>> = select.iter().map(|&k| Point3::from(src[k])).collect();
    let b: Vec<Point3<f64>> = select.iter().map(|&k| Point3::from(dst[k])).collect();
    Some(umeyama(&a, &b, false)?.isometry)
}

/// RANSAC over minimal samples of three matches, then a least-squares refit on the inliers of the
/// best hypothesis (twice, re-selecting inliers). `None` with fewer than `min_inliers` inliers.
pub fn ransac_rigid(
    src: &[Vector3<f64>],
    dst: &[Vector3<f64>],
    params: &FeatureParams,
) -> Option<RigidFit> {
    let n = src.len().min(dst.len());
    if n < params.min_inliers.max(3) {
        return None;
    }
    let tol2 = params.inlier_distance * params.inlier_distance;
    let inliers_of = |t: &Isometry3<f64>| -> Vec<usize> {
        (0..n)
            .filter(|&k| (t * Point3::from(src[k]) - Point3::from(dst[k])).norm_squared() <= tol2)
            .collect()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
    let mut best: Vec<usize> = Vec::new();
    for _ in 0..params.ransac_iterations {
        let s = [
            rng.random_range(0..n),
            rng.random_range(0..n),
            rng.random_range(0..n),
        ];
        if s[0] == s[1] || s[1] == s[2] || s[0] == s[2] {
            continue;
        }
        // a degenerate (near-collinear) sample fixes no rotation
        let (a, b, c) = (src[s[0]], src[s[1]], src[s[2]]);
        if (b - a).cross(&(c - a)).norm() < 1e-4 {
            continue;
        }
        let Some(t) = fit(src, dst, &s) else { continue };
        let inliers = inliers_of(&t);
        if inliers.len() > best.len() {
            best = inliers;
        }
    }
    let mut motion = Isometry3::identity();
    for _ in 0..2 {
        if best.len() < params.min_inliers.max(3) {
            return None;
        }
        motion = fit(src, dst, &best)?;
        best = inliers_of(&motion);
    }
    if best.len() < params.min_inliers {
        return None;
    }
    let mut inliers = vec![false; n];
    for k in best {
        inliers[k] = true;
    }
    Some(RigidFit { motion, inliers })
}

/// The 3D correspondences between two frames that survive matching and the rigid RANSAC: source
/// and target points (camera frames) of the inlier matches, and the fitted motion.
#[derive(Clone, Debug)]
pub struct FrameMatches {
    /// Source points of the inlier matches.
    pub source: Vec<Vector3<f64>>,
    /// Their partners in the target.
    pub target: Vec<Vector3<f64>>,
    /// The rigid motion fitted to them (source camera frame to target camera frame).
    pub motion: Isometry3<f64>,
    /// Keypoints found in each frame.
    pub keypoints: (usize, usize),
    /// Matches before RANSAC.
    pub matches: usize,
    /// The matches the rigid motion did not fit (source and target points): on a deforming
    /// object many are true ([`crate::nonrigid::frame_matches::grow_matches`]).
    pub rejected: Vec<(Vector3<f64>, Vector3<f64>)>,
}

/// The matches of two keypoint sets and the rigid motion RANSAC fits to them.
#[derive(Clone, Debug)]
pub struct KeypointFit {
    /// Source points of every match (camera frame).
    pub source: Vec<Vector3<f64>>,
    /// Their partners in the target.
    pub target: Vec<Vector3<f64>>,
    /// The fit: motion from the source's camera frame to the target's, and each match's
    /// inlier flag.
    pub fit: RigidFit,
}

/// Matches `source`'s keypoints to `target`'s and fits a rigid motion to the 3D matches: `None`
/// when too few matches agree on one.
pub fn fit_keypoints(
    source: &Keypoints,
    target: &Keypoints,
    params: &FeatureParams,
) -> Option<KeypointFit> {
    let pairs = match_keypoints(source, target, params);
    let src: Vec<Vector3<f64>> = pairs.iter().map(|&(i, _)| source.points[i]).collect();
    let dst: Vec<Vector3<f64>> = pairs.iter().map(|&(_, j)| target.points[j]).collect();
    let fit = ransac_rigid(&src, &dst, params)?;
    Some(KeypointFit {
        source: src,
        target: dst,
        fit,
    })
}

/// Detects, matches and fits: `None` when too few matches agree on a rigid motion.
pub fn match_frames(
    source: &FeatureFrame<'_>,
    target: &FeatureFrame<'_>,
    params: &FeatureParams,
) -> Option<FrameMatches> {
    let (ka, kb) = (detect(source, params), detect(target, params));
    let m = fit_keypoints(&ka, &kb, params)?;
    let keep = |v: &[Vector3<f64>]| -> Vec<Vector3<f64>> {
        v.iter()
            .zip(&m.fit.inliers)
            .filter(|(_, &k)| k)
            .map(|(p, _)| *p)
            .collect()
    };
    let rejected = (m.source.iter().zip(&m.target))
        .zip(&m.fit.inliers)
        .filter(|(_, &k)| !k)
        .map(|((s, t), _)| (*s, *t))
        .collect();
    Some(FrameMatches {
        source: keep(&m.source),
        target: keep(&m.target),
        motion: m.fit.motion,
        keypoints: (ka.len(), kb.len()),
        matches: m.source.len(),
        rejected,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ransac_finds_a_motion_among_outliers() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let truth = Isometry3::new(Vector3::new(0.2, -0.1, 0.05), Vector3::new(0.1, -0.2, 0.15));
        let src: Vec<Vector3<f64>> = (0..200)
            .map(|_| Vector3::new(rng.random(), rng.random(), 1.0 + rng.random::<f64>()))
            .collect();
        let mut dst: Vec<Vector3<f64>> = src
            .iter()
            .map(|p| (truth * Point3::from(*p)).coords)
            .collect();
        // 40 % outliers
        for d in dst.iter_mut().take(80) {
            *d +=
                Vector3::new(rng.random(), rng.random(), rng.random()) * 0.5 + Vector3::repeat(0.1);
        }
        let fit = ransac_rigid(&src, &dst, &FeatureParams::default()).expect("a motion");
        let err = fit.motion.inverse() * truth;
        assert!(err.translation.vector.norm() < 1e-9 && err.rotation.angle() < 1e-9);
        assert!(fit.inliers[80..].iter().all(|&b| b));
        assert!(fit.inliers[..80].iter().filter(|&&b| b).count() < 5);
    }

    /// A floor textured with wave numbers `min_k..max_k` (rad/m) seen from 2 m straight above,
    /// and from `forward` metres nearer along the optical axis after a turn of `yaw` degrees
    /// about the camera's y axis:
    /// the features' motion from the first view to the second, if any, and its error against
    /// the truth (metres, degrees).
    fn fit_across(
        (min_k, max_k): (f64, f64),
        (forward, yaw): (f64, f64),
        params: &FeatureParams,
    ) -> Option<(f64, f64)> {
        use crate::synthetic::{render::render, scene::Scene, scene::Shape, texture::Texture};
        let cam = Camera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let mut scene = Scene::default();
        let floor = Shape::Plane { hx: 5.0, hy: 5.0 };
        scene.add(
            floor,
            Isometry3::identity(),
            Texture::random(3, min_k, max_k),
        );
        let above = Vector3::new(0.3, 0.2, 2.0);
        let a = Isometry3::new(above, Vector3::x() * std::f64::consts::PI);
        let step = Isometry3::new(
            Vector3::new(0.0, 0.0, forward),
            Vector3::new(0.0, yaw.to_radians(), 0.0),
        );
        let b = a * step;
        let (ra, rb) = (render(&scene, &cam, &a), render(&scene, &cam, &b));
        let keypoints = |r: &crate::synthetic::render::Rendering| {
            let frame = FeatureFrame {
                color: &r.color,
                depth: &r.depth,
                camera: &cam,
                mask: None,
            };
            detect(&frame, params)
        };
        // the motion takes points of the first camera's frame into the second's
        let truth = step.inverse();
        fit_keypoints(&keypoints(&ra), &keypoints(&rb), params).map(|m| {
            let e = m.fit.motion.inverse() * truth;
            (e.translation.vector.norm(), e.rotation.angle().to_degrees())
        })
    }

    #[test]
    fn a_pyramid_matches_a_view_from_nearly_twice_as_near_and_a_blurred_texture() {
        let one = FeatureParams::default();
        let pyramid = FeatureParams {
            levels: 6,
            ..FeatureParams::default()
        };
        let sharp = (10.0, 150.0);
        let close = |e: Option<(f64, f64)>| e.is_some_and(|(t, r)| t < 0.01 && r < 0.5);
        // a small step: both match, and so do levels that a scale of 1 leaves at one
        let flat = FeatureParams {
            levels: 6,
            level_scale: 1.0,
            ..FeatureParams::default()
        };
        for p in [&one, &pyramid, &flat] {
            assert!(
                close(fit_across(sharp, (0.1, 10.0), p)),
                "{p:?}: a 5 % step"
            );
        }
        // from 2 m down to 1.1 and 1.0 m: the texture looks 1.8 and 2 times larger
        for step in [(0.9, 0.0), (1.0, 10.0)] {
            let e = fit_across(sharp, step, &pyramid);
            assert!(close(e), "{step:?}: the pyramid's motion is {e:?} off");
            let e = fit_across(sharp, step, &one);
            assert!(!close(e), "{step:?}: one level matched ({e:?} off)");
        }
        // a texture too smooth for a corner at full size has corners on the coarser levels
        let smooth = (2.0, 30.0);
        assert!(close(fit_across(smooth, (0.3, 10.0), &pyramid)));
        assert!(fit_across(smooth, (0.0, 0.0), &one).is_none());
    }

    #[test]
    fn too_few_agreeing_matches_give_no_motion() {
        let src: Vec<Vector3<f64>> = (0..20)
            .map(|k| Vector3::new(k as f64, (k * k) as f64, 1.0))
            .collect();
        let dst: Vec<Vector3<f64>> = (0..20)
            .map(|k| Vector3::new((k * 7 % 5) as f64, k as f64, -(k as f64)))
            .collect();
        assert!(ransac_rigid(&src, &dst, &FeatureParams::default()).is_none());
    }

    /// FAST-9 (Rosten & Drummond 2006): a pixel is a corner when 9 contiguous pixels of the
    /// 16-pixel circle of radius 3 about it are all brighter, or all darker, than it by more
    /// than the threshold, wherever on the circle the arc starts. imageproc before 0.27 missed
    /// the arcs whose compass points its quick rejection test had mislabelled (NOTES 162).
    #[test]
    fn a_corner_is_found_wherever_its_arc_of_nine_starts() {
        const CIRCLE: [(i64, i64); 16] = [
            (0, -3),
            (1, -3),
            (2, -2),
            (3, -1),
            (3, 0),
            (3, 1),
            (2, 2),
            (1, 3),
            (0, 3),
            (-1, 3),
            (-2, 2),
            (-3, 1),
            (-3, 0),
            (-3, -1),
            (-2, -2),
            (-1, -3),
        ];
        let (n, c) = (64usize, 32i64);
        let camera = Camera::new(60.0, 60.0, 32.0, 32.0, n, n);
        let depth = Image::filled(n, n, 1.0f32);
        let params = FeatureParams {
            suppression_radius: 0,
            ..FeatureParams::default()
        };
        let corner_at_centre = |color: &ColorImage| {
            let frame = FeatureFrame {
                color,
                depth: &depth,
                camera: &camera,
                mask: None,
            };
            detect(&frame, &params)
                .pixels
                .contains(&(c as u32, c as u32))
        };
        let at = |(dx, dy): (i64, i64)| ((c + dy) * n as i64 + c + dx) as usize;
        for arc in [200u8, 0] {
            for (start, &first) in CIRCLE.iter().enumerate() {
                let mut color = Image::filled(n, n, [100u8; 3]);
                for &offset in CIRCLE.iter().cycle().skip(start).take(9) {
                    color.data[at(offset)] = [arc; 3];
                }
                assert!(
                    corner_at_centre(&color),
                    "the arc of {arc} from circle pixel {start} gave no corner at its centre"
                );
                // eight contiguous pixels are not a FAST-9 corner
                color.data[at(first)] = [100; 3];
                assert!(
                    !corner_at_centre(&color),
                    "eight pixels from {start} made a corner"
                );
            }
        }
    }
}
