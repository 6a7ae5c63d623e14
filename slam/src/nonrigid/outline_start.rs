//! A rigid start for a frame registration from the object's outline, for an object that moved
//! too far for projective association and whose colour gives no feature match that agrees
//! (DeepDeform's seq017: a plain grey shirt lifted 45 cm; issue 26, point 3).
//!
//! An object seen in front of its background stays in front of it. Where the source's object
//! ends, the source sees something well behind it, or nothing; a placement of the object in the
//! target's view is right only if the target shows the same. A placement `T` (source camera to
//! target camera) is scored by two fractions:
//! - the surface fraction `s(T)`: of the object's sampled points `p`, those whose target depth at
//!   the pixel of `T p` agrees with `(T p)_z` within the association gate, less those where the
//!   target sees more than the gate behind `T p` (nothing can stand there);
//! - the outline fraction `o(T)`: of the object's outline points `b` (object pixels whose
//!   neighbour outwards is not the object's, and a few pixels out is background at least the gap
//!   behind, or no depth), those whose outward probe `T b'` (that pixel back-projected at `b`'s
//!   depth) sees the target at least the gap behind `(T b)_z`, or no depth; a probe outside the
//!   target's image counts half (unknown).
//!
//! The score is `max(s, 0) · o`. A plain object laid on a plain wall agrees with the surface but
//! has no outline there (`o ≈ 0`), which a registration's own verdict, counting points on the
//! surface, cannot tell (NOTES 68). The placements searched translate the object: its centroid's
//! pixel over a grid covering the target's image, at the depth that puts the object's points on
//! the target's median depth under them; the best few are refined by a pattern search down to a
//! pixel. Turns are left to the dense fit that follows: an outline does not fix them (a ball's
//! is a circle), and a turn taken from the outline laid textured balls 10 cm off where the
//! verdict could not tell (NOTES 147). A placement is taken only when it beats the source's own
//! place, most of its outline stands before the background, and nothing elsewhere (farther than
//! the object's extent) scores within Lowe's ratio of it. Lengths come from the registration's
//! settings (the gate; the graph's node spacing as the gap), pixel steps from the object's size
//! in the image: nothing is fitted to one pair.

use crate::camera::Camera;
use crate::image::DepthImage;
use nalgebra::{Isometry3, Point3, Translation3, Vector3};
use rayon::prelude::*;

/// The object's points sampled for the surface fraction, at most.
const SURFACE_SAMPLES: usize = 600;
/// Outline points sampled for the outline fraction, at most.
const OUTLINE_SAMPLES: usize = 400;
/// Grid cells across the object's extent in the image.
const CELLS_PER_EXTENT: f64 = 6.0;
/// The probe beyond the outline, as a fraction of the object's extent in the image (at least
/// two pixels).
const PROBE_FRACTION: f64 = 1.0 / 30.0;
/// Grid placements refined by the pattern search.
const REFINED: usize = 6;

/// What an outline search works on: the source's object and the target's depth.
pub struct OutlineInput<'a> {
    /// The source's camera (its object's points are in its frame).
    pub source_camera: &'a Camera,
    /// The source's depth, metres (0: none), unmasked: the background around the object.
    pub source_depth: &'a DepthImage,
    /// The object's pixels (row-major) and their points.
    pub pixels: &'a [usize],
    /// The object's points, one per pixel.
    pub points: &'a [Vector3<f64>],
    /// The target's camera.
    pub target_camera: &'a Camera,
    /// The target's depth, metres (0: none).
    pub target_depth: &'a DepthImage,
    /// Depth agreement for the surface fraction, metres (the association gate).
    pub gate: f64,
    /// How far behind the object its background must lie, metres.
    pub gap: f64,
}

/// A scored placement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    /// Source camera frame to target camera frame.
    pub motion: Isometry3<f64>,
    /// `s(T)`, the surface fraction (agreeing less seen-through).
    pub surface: f64,
    /// `o(T)`, the outline fraction.
    pub outline: f64,
}

impl Placement {
    /// `max(s, 0) · o`.
    pub fn score(&self) -> f64 {
        self.surface.max(0.0) * self.outline
    }
}

/// The result of [`search`]: the best placement found, the best of those elsewhere (farther than
/// the object's extent in the image), and the source's own place, scored alike.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OutlineStart {
    /// The best placement of the search.
    pub best: Placement,
    /// The best placement elsewhere, if any scored above zero.
    pub elsewhere: Option<Placement>,
    /// The identity's.
    pub identity: Placement,
}

/// A placement is taken only if every placement elsewhere scores below this fraction of it:
/// Lowe's ratio test (0.8, as for SIFT's matches), for a place that is unique.
pub const UNIQUE_RATIO: f64 = 0.8;

/// The outline fraction a placement needs to be taken: most of the object's outline must stand
/// before its background (the plain meaning of "most", as for a frame registration's verdict).
pub const MIN_OUTLINE: f64 = 0.5;

impl OutlineStart {
    /// The best placement, when it scores above the source's own place, most of its outline
    /// stands before the background ([`MIN_OUTLINE`]) and it is unique ([`UNIQUE_RATIO`]); None
    /// otherwise (an object that fits equally well in two places gives no start).
    pub fn start(&self) -> Option<Isometry3<f64>> {
        let best = self.best.score();
        let unique = self
            .elsewhere
            .is_none_or(|e| e.score() < UNIQUE_RATIO * best);
        let outlined = self.best.outline >= MIN_OUTLINE;
        (best > self.identity.score() && unique && outlined).then_some(self.best.motion)
    }
}

/// An outline point and its outward probe, both in the source's camera frame.
#[derive(Clone, Copy, Debug)]
pub(super) struct OutlinePoint {
    /// Its index in the object's points.
    pub(super) index: usize,
    pub(super) point: Vector3<f64>,
    pub(super) probe: Vector3<f64>,
    /// The object's steepest depth slope over the probe's length along the image's axes,
    /// `max |z_n − z| / (reach · z / f)` over the pixels `n` that far away that are the object's
    /// (the tangent of the surface's angle to the image plane, near enough); infinite when none
    /// is. The outline's own direction is not used: along a round outline's staircase it runs
    /// nearly tangent to the outline. A sheet's edge seen face-on has a small one; an occluding
    /// contour (a ball's or a tube's side, a silhouette the view makes) a large one.
    pub(super) slope: f64,
}

/// The prepared search: sampled points, outline, centroid and steps.
struct Search<'a> {
    input: &'a OutlineInput<'a>,
    surface: Vec<Vector3<f64>>,
    outline: Vec<OutlinePoint>,
    centroid: Vector3<f64>,
    /// The centroid's pixel in the target's camera.
    centre: (f64, f64),
    /// The object's extent in the image (the square root of its pixel count).
    extent: f64,
    /// The grid's step, pixels.
    step: f64,
}

/// A placement's parameters: the centroid's pixel shift.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Pose {
    du: f64,
    dv: f64,
}

impl Pose {
    /// How far apart two placements put the centroid, pixels.
    fn distance(&self, other: &Pose) -> f64 {
        (self.du - other.du).hypot(self.dv - other.dv)
    }
}

/// Searches the placements of the source's object in the target (module doc). None when the
/// object has no outline against its background (it fills the view or touches what is behind
/// it everywhere) or no point.
pub fn search(input: &OutlineInput<'_>) -> Option<OutlineStart> {
    let search = Search::new(input)?;
    let identity = search.scored(&Isometry3::identity());
    let mut grid = search.grid();
    grid.sort_by(|a, b| b.1.score().total_cmp(&a.1.score()));
    let mut seeds = distinct(&grid, 2.0 * search.step);
    // the source's own place too, for a motion the features missed but that is small
    seeds.push((Pose::default(), identity));
    let (pose, best) = seeds
        .par_iter()
        .filter_map(|&(pose, _)| search.refined(pose, None))
        .max_by(|a, b| a.1.score().total_cmp(&b.1.score()))?;
    let elsewhere = grid
        .iter()
        .find(|(p, s)| s.score() > 0.0 && p.distance(&pose) > search.extent)
        .and_then(|&(p, _)| search.refined(p, Some(&pose)))
        .map(|(_, s)| s);
    Some(OutlineStart {
        best,
        elsewhere,
        identity,
    })
}

/// The first [`REFINED`] grid placements at least `apart` pixels from every one kept before.
fn distinct(sorted: &[(Pose, Placement)], apart: f64) -> Vec<(Pose, Placement)> {
    let mut kept: Vec<(Pose, Placement)> = Vec::new();
    for &(pose, placement) in sorted {
        if placement.score() <= 0.0 || kept.len() == REFINED {
            break;
        }
        let far = kept.iter().all(|(k, _)| k.distance(&pose) >= apart);
        if far {
            kept.push((pose, placement));
        }
    }
    kept
}

impl<'a> Search<'a> {
    fn new(input: &'a OutlineInput<'a>) -> Option<Self> {
        if input.points.is_empty() || input.points.len() != input.pixels.len() {
            return None;
        }
        let extent = (input.pixels.len() as f64).sqrt();
        let outline = outline_points(input);
        if outline.is_empty() {
            return None;
        }
        let centroid = input.points.iter().sum::<Vector3<f64>>() / input.points.len() as f64;
        let centre = input.target_camera.project(&Point3::from(centroid))?;
        Some(Self {
            surface: strided(input.points, SURFACE_SAMPLES),
            outline: strided(&outline, OUTLINE_SAMPLES),
            centroid,
            centre,
            step: (extent / CELLS_PER_EXTENT).max(1.0),
            extent,
            input,
        })
    }

    /// Every grid placement, scored.
    fn grid(&self) -> Vec<(Pose, Placement)> {
        let cam = self.input.target_camera;
        let us = steps(-self.centre.0, cam.width as f64 - self.centre.0, self.step);
        let vs = steps(-self.centre.1, cam.height as f64 - self.centre.1, self.step);
        let poses: Vec<Pose> = us
            .iter()
            .flat_map(|&du| vs.iter().map(move |&dv| Pose { du, dv }))
            .collect();
        poses
            .par_iter()
            .map_init(Vec::new, |offsets, &pose| {
                self.placed(pose, offsets).map(|p| (pose, p))
            })
            .flatten()
            .collect()
    }

    /// A pattern search from `pose`: the step from half the grid's, halved when no neighbour
    /// scores better, down to a pixel; never within the object's extent of `away`, when given.
    fn refined(&self, mut pose: Pose, away: Option<&Pose>) -> Option<(Pose, Placement)> {
        let mut offsets = Vec::with_capacity(self.surface.len());
        let mut best = self.placed(pose, &mut offsets)?;
        let mut step = self.step / 2.0;
        while step >= 1.0 {
            let moves = [(step, 0.0), (-step, 0.0), (0.0, step), (0.0, -step)];
            let better = moves
                .iter()
                .filter_map(|&(du, dv)| {
                    let p = Pose {
                        du: pose.du + du,
                        dv: pose.dv + dv,
                    };
                    let near = away.is_some_and(|a| a.distance(&p) <= self.extent);
                    (!near).then(|| self.placed(p, &mut offsets).map(|s| (p, s)))?
                })
                .filter(|(_, s)| s.score() > best.score())
                .max_by(|a, b| a.1.score().total_cmp(&b.1.score()));
            match better {
                Some((p, s)) => (pose, best) = (p, s),
                None => step /= 2.0,
            }
        }
        Some((pose, best))
    }

    /// The placement of `pose`, scored: the object moved so that its centroid lands on the
    /// shifted pixel at its own depth, then along that pixel's ray to the target's median depth
    /// under the object's points. None when too few land on the target.
    fn placed(&self, pose: Pose, offsets: &mut Vec<f64>) -> Option<Placement> {
        let cam = self.input.target_camera;
        let c = self.centroid;
        let moved = cam.back_project(self.centre.0 + pose.du, self.centre.1 + pose.dv, c.z);
        let level = Isometry3::translation(moved.x - c.x, moved.y - c.y, 0.0);
        let offset = self.depth_offset(&level, offsets)?;
        let scale = (moved.z + offset) / moved.z;
        if !(scale > 0.0 && scale.is_finite()) {
            return None;
        }
        let motion = Translation3::from((scale - 1.0) * moved.coords) * level;
        Some(self.scored(&motion))
    }

    /// The median of (target depth − point depth) over the sampled points that land on target
    /// depth under `motion` (gathered in `offsets`); None when fewer than a tenth do.
    fn depth_offset(&self, motion: &Isometry3<f64>, offsets: &mut Vec<f64>) -> Option<f64> {
        offsets.clear();
        offsets.extend(self.surface.iter().filter_map(|p| {
            let q = motion * Point3::from(*p);
            self.target_depth(&q).map(|z| z - q.z)
        }));
        if offsets.len() * 10 < self.surface.len() {
            return None;
        }
        let mid = offsets.len() / 2;
        Some(*offsets.select_nth_unstable_by(mid, f64::total_cmp).1)
    }

    /// `s(T)` and `o(T)` of `motion`.
    fn scored(&self, motion: &Isometry3<f64>) -> Placement {
        let gate = self.input.gate;
        let mut on = 0i64;
        for p in &self.surface {
            let q = motion * Point3::from(*p);
            match self.target_depth(&q) {
                Some(z) if (z - q.z).abs() <= gate => on += 1,
                Some(z) if z > q.z + gate => on -= 1,
                _ => {}
            }
        }
        let gap = self.input.gap;
        // a probe without depth sees nothing behind (as the source's outline may); one outside
        // the image is unknown: half
        let outside: f64 = self
            .outline
            .iter()
            .map(|b| {
                let q = motion * Point3::from(b.point);
                let probe = motion * Point3::from(b.probe);
                let Some(pixel) = self.input.target_camera.project_to_pixel(&probe) else {
                    return 0.5;
                };
                match self.depth_at(pixel) {
                    Some(z) if z <= q.z + gap => 0.0,
                    _ => 1.0,
                }
            })
            .sum();
        Placement {
            motion: *motion,
            surface: on as f64 / self.surface.len() as f64,
            outline: outside / self.outline.len() as f64,
        }
    }

    /// The target's depth at the pixel `q` projects to; None outside the image or without depth.
    fn target_depth(&self, q: &Point3<f64>) -> Option<f64> {
        self.depth_at(self.input.target_camera.project_to_pixel(q)?)
    }

    /// The target's depth at pixel (u, v); None without depth.
    fn depth_at(&self, pixel: (usize, usize)) -> Option<f64> {
        depth_at(self.input.target_depth, pixel)
    }
}

/// `depth` at pixel (u, v), metres; None outside it or without depth.
pub(super) fn depth_at(depth: &DepthImage, (u, v): (usize, usize)) -> Option<f64> {
    if u >= depth.width {
        return None;
    }
    let z = *depth.data.get(v * depth.width + u)? as f64;
    (z > 0.0 && z.is_finite()).then_some(z)
}

/// The object's outline points: object pixels whose next pixel in one of the four directions is
/// not the object's, and whose pixel a probe's length out that way ([`PROBE_FRACTION`] of the
/// object's extent in the image, at least two pixels) has no depth or depth at least the gap
/// behind; each with its probe back-projected at the point's depth.
pub(super) fn outline_points(input: &OutlineInput<'_>) -> Vec<OutlinePoint> {
    let probe = ((input.pixels.len() as f64).sqrt() * PROBE_FRACTION).max(2.0);
    let depth = input.source_depth;
    let (w, h) = (depth.width as i64, depth.height as i64);
    let mut object = vec![false; depth.data.len()];
    for &i in input.pixels {
        if let Some(o) = object.get_mut(i) {
            *o = true;
        }
    }
    let at = |x: i64, y: i64| (x >= 0 && y >= 0 && x < w && y < h).then(|| (y * w + x) as usize);
    let reach = probe.round() as i64;
    let mut out = Vec::new();
    for (index, (&i, p)) in input.pixels.iter().zip(input.points).enumerate() {
        let (x, y) = ((i as i64) % w, (i as i64) / w);
        for (dx, dy) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
            let next = at(x + dx, y + dy);
            if next.is_none_or(|n| object[n]) {
                continue;
            }
            let Some(far) = at(x + reach * dx, y + reach * dy) else {
                continue;
            };
            let z = depth.data[far] as f64;
            if z > 0.0 && z.is_finite() && z < p.z + input.gap {
                continue;
            }
            let (u, v) = ((x + reach * dx) as f64, (y + reach * dy) as f64);
            let probe = input.source_camera.back_project(u, v, p.z).coords;
            let run = reach as f64 * p.z / input.source_camera.fx;
            let slope = [(1, 0), (-1, 0), (0, 1), (0, -1)]
                .iter()
                .filter_map(|&(ex, ey)| at(x + reach * ex, y + reach * ey).filter(|&n| object[n]))
                .map(|n| (depth.data[n] as f64 - p.z).abs() / run)
                .reduce(f64::max)
                .unwrap_or(f64::INFINITY);
            out.push(OutlinePoint {
                index,
                point: *p,
                probe,
                slope,
            });
            break;
        }
    }
    out
}

/// Every `len / max`-th element (rounded up), at most about `max`.
fn strided<T: Copy>(items: &[T], max: usize) -> Vec<T> {
    let stride = items.len().div_ceil(max.max(1)).max(1);
    items.iter().step_by(stride).copied().collect()
}

/// `from, from + step, …` below `to`.
fn steps(from: f64, to: f64, step: f64) -> Vec<f64> {
    let n = ((to - from) / step).ceil().max(0.0) as usize;
    (0..n).map(|k| from + (k as f64 + 0.5) * step).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 40 × 30 cm plate at `z` metres whose top-left corner is at (x, y), on a wall at 2.5 m,
    /// seen by the default camera: depth, and the plate's pixels and points.
    fn plate_scene(
        camera: &Camera,
        (x, y, z): (f64, f64, f64),
        wall: bool,
    ) -> (DepthImage, Vec<usize>, Vec<Vector3<f64>>) {
        let mut depth = DepthImage::filled(camera.width, camera.height, 0.0);
        let (mut pixels, mut points) = (Vec::new(), Vec::new());
        for v in 0..camera.height {
            for u in 0..camera.width {
                let i = v * camera.width + u;
                let p = camera.back_project(u as f64, v as f64, z);
                let inside = (x..x + 0.4).contains(&p.x) && (y..y + 0.3).contains(&p.y);
                if inside {
                    depth.data[i] = z as f32;
                    pixels.push(i);
                    points.push(p.coords);
                } else if wall {
                    depth.data[i] = 2.5;
                }
            }
        }
        (depth, pixels, points)
    }

    fn input<'a>(
        camera: &'a Camera,
        source: &'a (DepthImage, Vec<usize>, Vec<Vector3<f64>>),
        target: &'a DepthImage,
    ) -> OutlineInput<'a> {
        OutlineInput {
            source_camera: camera,
            source_depth: &source.0,
            pixels: &source.1,
            points: &source.2,
            target_camera: camera,
            target_depth: target,
            gate: 0.1,
            gap: 0.05,
        }
    }

    #[test]
    fn a_plate_moved_half_a_metre_across_a_wall_is_placed_within_a_centimetre() {
        let camera = Camera::tum_default();
        let source = plate_scene(&camera, (-0.6, -0.35, 1.5), true);
        let (target, _, _) = plate_scene(&camera, (0.05, 0.1, 1.6), true);
        let found = search(&input(&camera, &source, &target)).expect("the plate has an outline");
        let motion = found.start().expect("one place fits");
        // the plate's corner onto the moved plate's corner
        let moved = motion * Point3::new(-0.6, -0.35, 1.5) - Point3::new(0.05, 0.1, 1.6);
        assert!(moved.norm() < 0.01, "{moved:?}");
        assert!(
            found.best.outline > 0.9 && found.best.surface > 0.9,
            "{found:?}"
        );
    }

    #[test]
    fn a_plate_on_a_wall_that_no_longer_shows_it_gets_no_start() {
        let camera = Camera::tum_default();
        let source = plate_scene(&camera, (-0.2, -0.15, 1.5), true);
        let wall = DepthImage::filled(camera.width, camera.height, 2.5);
        let found = search(&input(&camera, &source, &wall)).expect("the plate has an outline");
        // it lies flat on the wall anywhere, with its outline nowhere
        assert!(found.best.outline < MIN_OUTLINE, "{found:?}");
        assert_eq!(found.start(), None);
    }

    #[test]
    fn a_plate_that_fits_two_places_equally_gets_no_start() {
        let camera = Camera::tum_default();
        let source = plate_scene(&camera, (-0.2, -0.15, 1.5), true);
        let (mut target, _, _) = plate_scene(&camera, (-0.7, -0.15, 1.6), true);
        let (right, _, _) = plate_scene(&camera, (0.3, -0.15, 1.6), true);
        for (t, r) in target.data.iter_mut().zip(&right.data) {
            *t = t.min(*r);
        }
        let found = search(&input(&camera, &source, &target)).expect("the plate has an outline");
        let elsewhere = found.elsewhere.expect("the other plate");
        assert!(
            elsewhere.score() > UNIQUE_RATIO * found.best.score(),
            "{found:?}"
        );
        assert_eq!(found.start(), None);
        // either plate alone is found
        let (one, _, _) = plate_scene(&camera, (0.3, -0.15, 1.6), true);
        assert!(search(&input(&camera, &source, &one))
            .and_then(|f| f.start())
            .is_some());
    }

    #[test]
    fn an_object_without_an_outline_or_points_gives_no_search() {
        let camera = Camera::tum_default();
        // the plate touches what is behind it everywhere: no outline
        let (depth, pixels, points) = plate_scene(&camera, (-0.2, -0.15, 2.5), true);
        let flush = (depth.clone(), pixels, points);
        assert!(search(&input(&camera, &flush, &depth)).is_none());
        let empty = (depth.clone(), Vec::new(), Vec::new());
        assert!(search(&input(&camera, &empty, &depth)).is_none());
    }
}
