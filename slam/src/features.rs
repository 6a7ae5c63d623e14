//! Sparse colour correspondences between two RGB-D frames, for motions too large for projective or
//! closest-point association to bridge: FAST-9 corners (Rosten & Drummond, *Machine learning for
//! high-speed corner detection*, ECCV 2006) with BRIEF descriptors (Calonder et al., ECCV 2010),
//! both from `imageproc`; matched by Hamming distance under Lowe's ratio test (IJCV 2004) and a
//! mutual-best check; lifted to 3D through the depth maps; and a rigid motion fitted to them by
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
    /// FAST intensity threshold (default 5: cloth is faintly textured; DeepDeform's shirt gives
    /// about 30 corners at 15 and 700 at 5, of which RANSAC keeps about 80).
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

/// Keypoints of one frame with valid depth: pixel, camera-frame point and descriptor.
#[derive(Clone, Default)]
pub struct Keypoints {
    /// Pixel (x, y) of each keypoint.
    pub pixels: Vec<(u32, u32)>,
    /// Its back-projected point, camera frame.
    pub points: Vec<Vector3<f64>>,
    descriptors: Vec<BriefDescriptor>,
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
    }

    /// Bytes held: the three arrays as allocated plus each descriptor's bit block.
    pub fn bytes(&self) -> usize {
        use std::mem::size_of;
        let bits: usize = self.descriptors.iter().map(|d| d.bits.capacity()).sum();
        self.pixels.capacity() * size_of::<(u32, u32)>()
            + self.points.capacity() * size_of::<Vector3<f64>>()
            + self.descriptors.capacity() * size_of::<BriefDescriptor>()
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
/// mask and away from the border, with valid depth; the strongest `max_keypoints`.
pub fn detect(frame: &FeatureFrame<'_>, params: &FeatureParams) -> Keypoints {
    let (w, h) = (frame.color.width as u32, frame.color.height as u32);
    let mut keypoints = Keypoints {
        pixels: Vec::new(),
        points: Vec::new(),
        descriptors: Vec::new(),
    };
    if w <= 2 * BORDER || h <= 2 * BORDER || frame.depth.data.len() != frame.color.data.len() {
        return keypoints;
    }
    let mut luma = Image::new(0, 0);
    intensity(frame.color, &mut luma);
    let gray = image::GrayImage::from_fn(w, h, |x, y| {
        image::Luma([(luma.data[(y * w + x) as usize] * 255.0).round() as u8])
    });
    let corners = imageproc::corners::corners_fast9(&gray, params.fast_threshold);
    let mut corners = imageproc::suppress::local_maxima(&corners, params.suppression_radius);
    corners.retain(|c| {
        let i = (c.y * w + c.x) as usize;
        c.x >= BORDER
            && c.y >= BORDER
            && c.x + BORDER < w
            && c.y + BORDER < h
            && frame.depth.data[i] > 0.0
            && frame.depth.data[i].is_finite()
            && frame
                .mask
                .is_none_or(|m| m.data.get(i).copied().unwrap_or(false))
    });
    corners.sort_by(|a, b| b.score.total_cmp(&a.score));
    corners.truncate(params.max_keypoints);
    let at: Vec<Point<u32>> = corners.iter().map(|c| Point::new(c.x, c.y)).collect();
    let Ok((descriptors, _)) = brief(&gray, &at, BITS, Some(&test_pairs(params.seed))) else {
        // every keypoint is inside the border, so this cannot fail; no features if it did
        return keypoints;
    };
    for (c, d) in corners.iter().zip(descriptors) {
        let z = frame.depth.data[(c.y * w + c.x) as usize] as f64;
        keypoints.pixels.push((c.x, c.y));
        keypoints
            .points
            .push(frame.camera.back_project(c.x as f64, c.y as f64, z).coords);
        keypoints.descriptors.push(d);
    }
    keypoints
}

/// For each descriptor of `a`, the index in `b` of its nearest one when it is within
/// `max_hamming` and clearly nearer than the second nearest (Lowe's ratio).
fn nearest(a: &Keypoints, b: &Keypoints, params: &FeatureParams) -> Vec<Option<usize>> {
    use rayon::prelude::*;
    a.descriptors
        .par_iter()
        .map(|da| {
            let (mut best, mut second, mut arg) = (u32::MAX, u32::MAX, 0);
            for (j, db) in b.descriptors.iter().enumerate() {
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
}
