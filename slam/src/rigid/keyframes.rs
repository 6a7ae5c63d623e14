//! Keyframes for relocalisation: fused frames kept when the camera has moved far enough from every
//! keyframe before, each with its pose, sparse features (FAST/BRIEF keypoints with their
//! camera-frame points, [`crate::features`]) and a place-recognition code of randomised ferns
//! (Glocker, Shotton, Criminisi & Izadi, *Real-time RGB-D camera relocalization via randomized
//! ferns for keyframe encoding*, TVCG 2015, as ElasticFusion uses them).
//!
//! A fern is a pixel of the frame shrunk to [`FERN_WIDTH`] pixels wide and four thresholds, one
//! per channel (R, G, B, depth); its code is the four bits [I_c ≥ τ_c]. Two frames' dissimilarity
//! is the fraction of ferns whose codes differ (Glocker et al.'s block-wise Hamming distance), so
//! similar views have similar codes whatever their poses.
//!
//! Memory per keyframe ([`Keyframe::bytes`]): [`KeyframeParams::max_keypoints`] keypoints of
//! 108 bytes each (pixel 8, point 24, BRIEF descriptor 40 and its 32-byte bit block, patch size
//! 4) plus one byte per fern and the record itself: with the defaults (500 keypoints, 500 ferns)
//! at most [`KEYFRAME_BYTES_BOUND`] = 56 kB, so the default 2000 keyframes hold at most 112 MB.

use crate::camera::Camera;
use crate::features::{detect, FeatureFrame, FeatureParams, Keypoints};
use crate::image::{ColorImage, DepthImage};
use nalgebra::Isometry3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// What one keyframe holds at most with the default [`KeyframeParams`], bytes (checked by a test
/// against [`Keyframe::bytes`]).
pub const KEYFRAME_BYTES_BOUND: usize = 56_000;

/// Width of the shrunk image the ferns sample (Glocker et al. use 80 × 60 for 640 × 480).
pub const FERN_WIDTH: usize = 80;

/// How keyframes are chosen and described.
#[derive(Clone, Debug, PartialEq)]
pub struct KeyframeParams {
    /// A frame becomes a keyframe when every recent keyframe (see [`Self::recent_frames`]) is
    /// further than this fraction of the frame's median depth away (default 0.1: 15 cm at 1.5 m)
    /// or turned by more than [`Self::min_turn_deg`].
    pub min_shift: f64,
    /// … or turned by more than this, degrees (default 15).
    pub min_turn_deg: f64,
    /// Ferns per code (default 500, as Glocker et al.).
    pub ferns: usize,
    /// Keypoints kept per keyframe, strongest first (default 500).
    pub max_keypoints: usize,
    /// Keyframes kept at most; beyond it the oldest is dropped (default 2000: at most 106 MB,
    /// see [`KEYFRAME_BYTES_BOUND`]).
    pub max_keyframes: usize,
    /// Seed of the ferns' pixels and thresholds.
    pub seed: u64,
    /// Only keyframes taken at most this many frames before the candidate count as near it
    /// (default: all of them). An older one's pose may have drifted against the candidate's, so
    /// with a finite window a place revisited gets a keyframe of its own, which is what loop
    /// closure matches against the old one; with sub-maps the pipeline sets it to
    /// [`super::loops::LoopParams::min_frames_apart`] when it is left at the default. (With one
    /// volume, the default: the tracker snaps to the part of the map it sees again, loops
    /// measure what it already says, and on the suite's `long` 228 keyframes instead of 34
    /// gave 123 feature loops that moved the trajectory from 3.1 to 4.7 mm, NOTES 59.)
    pub recent_frames: usize,
}

impl Default for KeyframeParams {
    fn default() -> Self {
        Self {
            min_shift: 0.1,
            min_turn_deg: 15.0,
            ferns: 500,
            max_keypoints: 500,
            max_keyframes: 2000,
            seed: 11,
            recent_frames: usize::MAX,
        }
    }
}

/// One fern: where it samples the shrunk image and its thresholds (R, G, B in 8-bit levels,
/// depth in metres).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Fern {
    x: usize,
    y: usize,
    thresholds: [f32; 4],
}

/// The randomised ferns of one image size.
#[derive(Clone, Debug, PartialEq)]
pub struct Ferns {
    ferns: Vec<Fern>,
    width: usize,
    height: usize,
    /// Shrink factor from the frame to the fern image.
    block: usize,
}

impl Ferns {
    /// `count` ferns for frames of `camera`'s size, depth thresholds in (0, `max_depth`].
    pub fn new(camera: &Camera, count: usize, max_depth: f32, seed: u64) -> Self {
        let block = (camera.width / FERN_WIDTH).max(1);
        let (width, height) = (camera.width / block, camera.height / block);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let ferns = (0..count)
            .map(|_| Fern {
                x: rng.random_range(0..width.max(1)),
                y: rng.random_range(0..height.max(1)),
                thresholds: [
                    rng.random_range(0.0..255.0),
                    rng.random_range(0.0..255.0),
                    rng.random_range(0.0..255.0),
                    rng.random_range(0.0..max_depth.max(0.1)),
                ],
            })
            .collect();
        Self {
            ferns,
            width,
            height,
            block,
        }
    }

    /// The code of a frame: four bits per fern. A block mean over the valid depth (0 where there
    /// is none, so "no depth" reads as near).
    pub fn code(&self, color: Option<&ColorImage>, depth: &DepthImage) -> Vec<u8> {
        self.ferns
            .iter()
            .map(|f| {
                let v = self.sample(color, depth, f.x, f.y);
                (0..4).fold(0u8, |c, k| c | (((v[k] >= f.thresholds[k]) as u8) << k))
            })
            .collect()
    }

    /// Mean R, G, B and valid depth over the frame's block behind fern pixel (x, y).
    fn sample(
        &self,
        color: Option<&ColorImage>,
        depth: &DepthImage,
        x: usize,
        y: usize,
    ) -> [f32; 4] {
        let b = self.block;
        let mut sum = [0f64; 4];
        let (mut n, mut nd) = (0usize, 0usize);
        for v in y * b..((y + 1) * b).min(depth.height) {
            for u in x * b..((x + 1) * b).min(depth.width) {
                let i = v * depth.width + u;
                if let Some(c) = color.and_then(|c| c.data.get(i)) {
                    for k in 0..3 {
                        sum[k] += c[k] as f64;
                    }
                }
                n += 1;
                let d = depth.data[i];
                if d > 0.0 && d.is_finite() {
                    sum[3] += d as f64;
                    nd += 1;
                }
            }
        }
        let mean = |s: f64, n: usize| if n > 0 { (s / n as f64) as f32 } else { 0.0 };
        [
            mean(sum[0], n),
            mean(sum[1], n),
            mean(sum[2], n),
            mean(sum[3], nd),
        ]
    }

    /// Size of the shrunk image the ferns sample.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }
}

/// The fraction of ferns whose codes differ (1 for codes of different lengths).
pub(crate) fn dissimilarity(a: &[u8], b: &[u8]) -> f64 {
    if a.len() != b.len() || a.is_empty() {
        return 1.0;
    }
    a.iter().zip(b).filter(|(x, y)| x != y).count() as f64 / a.len() as f64
}

/// A keyframe: pose, features and fern code.
#[derive(Clone, Debug)]
pub struct Keyframe {
    /// Index of the frame it was taken from (frames given to the pipeline, counted from 1).
    pub frame: usize,
    /// Camera-to-world pose.
    pub pose: Isometry3<f64>,
    /// Its keypoints with camera-frame points.
    pub keypoints: Keypoints,
    /// Its fern code.
    pub code: Vec<u8>,
    /// The agreement its frame was tracked with ([`super::TrackOutcome::agreement`]; `None`
    /// for the first frame): what a pose found here again should come near.
    pub agreement: Option<f64>,
}

impl Keyframe {
    /// Bytes this keyframe holds, its record and its heap blocks.
    pub fn bytes(&self) -> usize {
        std::mem::size_of::<Self>() + self.keypoints.bytes() + self.code.capacity()
    }
}

/// The keyframes of a run.
#[derive(Clone, Debug)]
pub struct Keyframes {
    /// Settings.
    pub params: KeyframeParams,
    ferns: Option<Ferns>,
    frames: Vec<Keyframe>,
    /// Depth samples of the offered frame, kept to spare an allocation per frame.
    samples: Vec<f32>,
}

/// A fused frame offered as a keyframe.
pub struct Candidate<'a> {
    /// Index of the frame.
    pub frame: usize,
    /// Its pose.
    pub pose: Isometry3<f64>,
    /// The agreement it was tracked with (`None` for the first frame).
    pub agreement: Option<f64>,
    /// Colour, if any.
    pub color: Option<&'a ColorImage>,
    /// Filtered depth, metres.
    pub depth: &'a DepthImage,
    /// The sensor.
    pub camera: &'a Camera,
}

impl Keyframes {
    /// No keyframes yet.
    pub fn new(params: KeyframeParams) -> Self {
        Self {
            params,
            ferns: None,
            frames: Vec::new(),
            samples: Vec::new(),
        }
    }

    /// The keyframes, oldest first.
    pub fn frames(&self) -> &[Keyframe] {
        &self.frames
    }

    /// Keeps `c` as a keyframe if it lies far enough from every recent keyframe (see
    /// [`KeyframeParams::min_shift`]) and has colour to describe it; whether it was kept.
    pub fn offer(&mut self, c: &Candidate<'_>, features: &FeatureParams, max_depth: f32) -> bool {
        let shift = self.params.min_shift * median_depth(c.depth, &mut self.samples);
        let turn = self.params.min_turn_deg.to_radians();
        let recent = self.params.recent_frames;
        let near = |k: &Keyframe| {
            let d = k.pose.inverse() * c.pose;
            let recent = k.frame.saturating_add(recent) >= c.frame;
            recent && d.translation.vector.norm() < shift && d.rotation.angle() < turn
        };
        if c.color.is_none() || shift <= 0.0 || self.frames.iter().any(near) {
            return false;
        }
        self.insert(c, features, max_depth)
    }

    /// Keeps `c` as a keyframe wherever it lies (the first of a new map fragment), if it has
    /// colour to describe it; whether it was kept.
    pub fn insert(&mut self, c: &Candidate<'_>, features: &FeatureParams, max_depth: f32) -> bool {
        let Some(color) = c.color else { return false };
        let p = &self.params;
        let ferns = self
            .ferns
            .get_or_insert_with(|| Ferns::new(c.camera, p.ferns, max_depth, p.seed));
        let code = ferns.code(Some(color), c.depth);
        let params = FeatureParams {
            max_keypoints: p.max_keypoints,
            ..features.clone()
        };
        let frame = FeatureFrame {
            color,
            depth: c.depth,
            camera: c.camera,
            mask: None,
        };
        let mut keypoints = detect(&frame, &params);
        keypoints.shrink_to_fit();
        if self.frames.len() >= p.max_keyframes {
            self.frames.remove(0);
        }
        self.frames.push(Keyframe {
            frame: c.frame,
            pose: c.pose,
            keypoints,
            code,
            agreement: c.agreement,
        });
        true
    }

    /// The indices of the `count` keyframes whose codes are nearest the frame's, nearest first.
    pub fn nearest(
        &self,
        color: Option<&ColorImage>,
        depth: &DepthImage,
        count: usize,
    ) -> Vec<usize> {
        self.nearest_where(color, depth, count, |_| true)
    }

    /// [`Self::nearest`] among the keyframes that `keep` accepts.
    pub fn nearest_where(
        &self,
        color: Option<&ColorImage>,
        depth: &DepthImage,
        count: usize,
        keep: impl Fn(&Keyframe) -> bool,
    ) -> Vec<usize> {
        let Some(ferns) = &self.ferns else {
            return Vec::new();
        };
        let code = ferns.code(color, depth);
        let kept = self.frames.iter().enumerate().filter(|(_, f)| keep(f));
        nearest_of(&code, kept, count)
    }
}

impl Keyframes {
    /// The indices of the `count` keyframes in `range` (of [`Self::frames`]) whose codes are
    /// nearest `code`, nearest first.
    pub(crate) fn nearest_code(
        &self,
        code: &[u8],
        range: std::ops::Range<usize>,
        count: usize,
    ) -> Vec<usize> {
        let end = range.end.min(self.frames.len());
        let start = range.start.min(end);
        let kept = self.frames.iter().enumerate().take(end).skip(start);
        nearest_of(code, kept, count)
    }
}

/// The indices of the `count` keyframes of `kept` (index, keyframe) whose codes are nearest
/// `code`, nearest first.
fn nearest_of<'a>(
    code: &[u8],
    kept: impl Iterator<Item = (usize, &'a Keyframe)>,
    count: usize,
) -> Vec<usize> {
    let mut ranked: Vec<(f64, usize)> = kept
        .map(|(k, f)| (dissimilarity(code, &f.code), k))
        .collect();
    ranked.sort_by(|a, b| a.0.total_cmp(&b.0));
    ranked.into_iter().take(count).map(|(_, k)| k).collect()
}

/// The median of a depth image's valid values, sampled every 7th pixel into `z` (0 when there
/// are none).
pub(super) fn median_depth(depth: &DepthImage, z: &mut Vec<f32>) -> f64 {
    z.clear();
    z.extend(
        depth
            .data
            .iter()
            .step_by(7)
            .copied()
            .filter(|d| *d > 0.0 && d.is_finite()),
    );
    if z.is_empty() {
        return 0.0;
    }
    let mid = z.len() / 2;
    *z.select_nth_unstable_by(mid, f32::total_cmp).1 as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// A 64 × 48 frame: a horizontal colour ramp (shifted by `shift` pixels) over a plane at
    /// depth `z`.
    fn frame(shift: usize, z: f32) -> (Camera, ColorImage, DepthImage) {
        let cam = Camera::new(60.0, 60.0, 31.5, 23.5, 64, 48);
        let mut color = ColorImage::new(64, 48);
        for (i, c) in color.data.iter_mut().enumerate() {
            let u = (i % 64 + shift) as f32;
            *c = [
                (4.0 * u) as u8,
                (255.0 - 3.0 * u) as u8,
                ((i / 64) * 5) as u8,
            ];
        }
        (cam, color, DepthImage::filled(64, 48, z))
    }

    #[test]
    fn fern_codes_are_equal_for_one_view_and_differ_for_another() {
        let (cam, c, d) = frame(0, 1.5);
        let ferns = Ferns::new(&cam, 300, 5.0, 1);
        let a = ferns.code(Some(&c), &d);
        assert_eq!(dissimilarity(&a, &ferns.code(Some(&c), &d)), 0.0);
        let (_, c2, d2) = frame(20, 3.0);
        let far = dissimilarity(&a, &ferns.code(Some(&c2), &d2));
        let (_, c3, d3) = frame(1, 1.5);
        let near = dissimilarity(&a, &ferns.code(Some(&c3), &d3));
        assert!(near < 0.1 && far > 0.3, "near {near}, far {far}");
    }

    #[test]
    fn a_frame_is_kept_only_away_from_every_keyframe_and_found_by_its_code() {
        let (cam, c, d) = frame(0, 1.5);
        let mut keys = Keyframes::new(KeyframeParams::default());
        let features = FeatureParams::default();
        let offer = |keys: &mut Keyframes, frame: usize, x: f64, color: &ColorImage| {
            let pose = Isometry3::translation(x, 0.0, 0.0);
            let c = Candidate {
                frame,
                pose,
                agreement: Some(0.5),
                color: Some(color),
                depth: &d,
                camera: &cam,
            };
            keys.offer(&c, &features, 5.0)
        };
        assert!(offer(&mut keys, 1, 0.0, &c));
        // 0.1 × the median depth 1.5 m: 15 cm
        assert!(!offer(&mut keys, 2, 0.1, &c), "kept 10 cm from a keyframe");
        let (_, c2, _) = frame(20, 1.5);
        assert!(offer(&mut keys, 3, 0.2, &c2), "not kept 20 cm away");
        assert!(!offer(&mut keys, 4, 0.01, &c2), "kept back at the first");
        assert_eq!(keys.frames().len(), 2);
        assert_eq!(keys.nearest(Some(&c2), &d, 1), vec![1]);
        assert_eq!(keys.nearest(Some(&c), &d, 2), vec![0, 1]);
        let turned = Isometry3::new(Vector3::zeros(), Vector3::y() * 0.5);
        let t = Candidate {
            frame: 5,
            pose: turned,
            agreement: None,
            color: Some(&c),
            depth: &d,
            camera: &cam,
        };
        assert!(keys.offer(&t, &features, 5.0), "not kept after a 29° turn");
    }

    /// A textured frame with far more corners than the keypoint budget keeps at most the stated
    /// bytes.
    #[test]
    fn a_keyframe_holds_at_most_the_stated_bytes() {
        let cam = Camera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let mut color = ColorImage::new(640, 480);
        for (i, c) in color.data.iter_mut().enumerate() {
            let (u, v) = (i % 640, i / 640);
            let on = ((u / 7) ^ (v / 5) ^ (u * v / 97)) & 1 == 1;
            *c = if on { [230, 200, 40] } else { [20, 30, 90] };
        }
        let depth = DepthImage::filled(640, 480, 1.5);
        let mut keys = Keyframes::new(KeyframeParams::default());
        let c = Candidate {
            frame: 1,
            pose: Isometry3::identity(),
            agreement: None,
            color: Some(&color),
            depth: &depth,
            camera: &cam,
        };
        // the relocaliser's features: six pyramid levels share the budget
        let features = FeatureParams {
            levels: 6,
            ..FeatureParams::default()
        };
        assert!(keys.offer(&c, &features, 5.0));
        let k = &keys.frames()[0];
        assert_eq!(k.keypoints.len(), KeyframeParams::default().max_keypoints);
        assert!(k.bytes() <= KEYFRAME_BYTES_BOUND, "{} bytes", k.bytes());
        assert!(
            k.bytes() > KEYFRAME_BYTES_BOUND * 9 / 10,
            "bound loose: {}",
            k.bytes()
        );
    }
}
