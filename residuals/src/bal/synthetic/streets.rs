//! The streets layout: a photographer walks a grid of streets and photographs the façades of the
//! buildings between them, as the tourists' photographs of BAL's Venice and Final sets do.
//!
//! The city is `m × m` square blocks of [`BLOCK`] metres, each holding one building whose
//! façades stand [`SETBACK`] metres from the streets' centre lines, of random height. `m` grows
//! as the square root of the number of cameras so that the walk (one photograph every [`STEP`]
//! metres, a random turn at crossings) covers every street about twice: the density of cameras
//! and points stays the same at every size, and every street is seen again later in the walk.
//! Each camera looks 20–160° to the left or right of the way it walks, slightly upwards, at a building, with a
//! focal length of 500–800 pixels over a 1000 × 750 image.
//!
//! Every camera contributes its share of the points, as a structure-from-motion track starts from
//! a feature of one image: a ray through a random pixel meets a façade within [`RANGE`] metres.
//! The cameras that have that point in view are those within [`RANGE`] metres (in plan) that it
//! faces, whose image holds it, and whose line of sight no building blocks (in plan). The track
//! is the camera that found it and the nearest of those (by camera centre; cameras from a later
//! pass along the same street among them), between `lo` and `hi` in all
//! ([`SyntheticOptions::views`]). A ray that meets nothing, or a point in view of fewer than `lo`
//! cameras, is drawn again (at most 50 draws per point wanted, so a camera looking at little
//! yields fewer).

use super::{in_camera, look_camera, Scene, SyntheticOptions};
use crate::bal::camera_centre;
use nalgebra::{SVector, Vector2, Vector3};
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

/// Street spacing (metres).
pub const BLOCK: f64 = 20.0;
/// Distance of a façade from the street's centre line (metres).
pub const SETBACK: f64 = 6.0;
/// Distance walked between photographs (metres).
pub const STEP: f64 = 1.5;
/// How far a camera sees (metres).
pub const RANGE: f64 = 30.0;
/// Half the image's width and height (pixels).
const HALF_IMAGE: [f64; 2] = [500.0, 375.0];
/// Height of the camera above the street (metres).
const EYE: f64 = 1.6;

/// The city's grid: `m × m` blocks and the buildings' heights.
struct City {
    m: usize,
    heights: Vec<f64>,
}

impl City {
    /// A city whose streets are about half as long as a walk of `cameras` steps.
    fn for_cameras(cameras: usize, rng: &mut ChaCha8Rng) -> Self {
        // The grid's streets are 2 m (m + 1) BLOCK long, about 2 m² BLOCK.
        let walk = cameras as f64 * STEP;
        let m = ((walk / (4.0 * BLOCK)).sqrt().round() as usize).max(1);
        let heights = (0..m * m).map(|_| rng.random_range(4.0..16.0)).collect();
        Self { m, heights }
    }

    /// The plan of block `(i, j)`'s building: its lower and upper corner.
    fn footprint(&self, i: usize, j: usize) -> (Vector2<f64>, Vector2<f64>) {
        let lo = Vector2::new(i as f64 * BLOCK + SETBACK, j as f64 * BLOCK + SETBACK);
        let hi = Vector2::new(
            (i + 1) as f64 * BLOCK - SETBACK,
            (j + 1) as f64 * BLOCK - SETBACK,
        );
        (lo, hi)
    }

    /// The block (along one axis) holding coordinate `x`, clamped to the grid.
    fn cell(&self, x: f64) -> usize {
        ((x / BLOCK).floor().max(0.0) as usize).min(self.m - 1)
    }

    /// True when the segment from `a` to `b` (in plan) passes through a building.
    fn blocked(&self, a: Vector2<f64>, b: Vector2<f64>) -> bool {
        let (i0, i1) = (self.cell(a.x.min(b.x)), self.cell(a.x.max(b.x)));
        let (j0, j1) = (self.cell(a.y.min(b.y)), self.cell(a.y.max(b.y)));
        (i0..=i1).any(|i| {
            (j0..=j1).any(|j| {
                let (lo, hi) = self.footprint(i, j);
                slab(a, b - a, lo, hi, 1.0).is_some_and(|(t0, t1, _)| t1 - t0 > 1e-9)
            })
        })
    }
}

/// The slab test: the interval `[t₀, t₁]` of `t ∈ [0, t_max]` over which `o + t d` lies in the
/// box `(lo, hi)`, and the axis whose face bounds it from below (`usize::MAX` if none: `o` is
/// inside on every axis that moves). `None` when the line runs parallel to an axis outside or on
/// the box's faces. The interval is empty when `t₀ ≥ t₁`.
fn slab<const N: usize>(
    o: SVector<f64, N>,
    d: SVector<f64, N>,
    lo: SVector<f64, N>,
    hi: SVector<f64, N>,
    t_max: f64,
) -> Option<(f64, f64, usize)> {
    let (mut t0, mut t1, mut axis) = (0.0f64, t_max, usize::MAX);
    for k in 0..N {
        if d[k].abs() < 1e-12 {
            if o[k] <= lo[k] || o[k] >= hi[k] {
                return None;
            }
            continue;
        }
        let (ta, tb) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
        if ta.min(tb) > t0 {
            t0 = ta.min(tb);
            axis = k;
        }
        t1 = t1.min(ta.max(tb));
    }
    Some((t0, t1, axis))
}

/// The walk: a camera every [`STEP`] metres along the streets from the corner (0, 0), turning
/// at random at crossings (straight on twice as often as either turn, never off the grid).
fn walk(city: &City, n: usize, rng: &mut ChaCha8Rng) -> Vec<[f64; 9]> {
    let size = city.m as f64 * BLOCK;
    let (mut at, mut heading) = (Vector2::new(0.0, 0.0), Vector2::new(1.0, 0.0));
    let mut to_crossing = BLOCK;
    let mut cameras = Vec::with_capacity(n);
    for _ in 0..n {
        cameras.push(photograph(city, at, heading, rng));
        let mut left = STEP;
        while left >= to_crossing {
            at += heading * to_crossing;
            left -= to_crossing;
            at = at.map(|x| (x / BLOCK).round() * BLOCK);
            heading = turn(at, heading, size, rng);
            to_crossing = BLOCK;
        }
        at += heading * left;
        to_crossing -= left;
    }
    cameras
}

/// The heading after a crossing at `at`: straight on, left or right (2 : 1 : 1), on the grid.
fn turn(at: Vector2<f64>, heading: Vector2<f64>, size: f64, rng: &mut ChaCha8Rng) -> Vector2<f64> {
    let on_grid = |h: Vector2<f64>| {
        let next = at + h * BLOCK;
        (-1e-6..=size + 1e-6).contains(&next.x) && (-1e-6..=size + 1e-6).contains(&next.y)
    };
    let left = Vector2::new(-heading.y, heading.x);
    let mut options = vec![heading, heading, left, -left];
    options.retain(|h| on_grid(*h));
    if options.is_empty() {
        return -heading;
    }
    options[rng.random_range(0..options.len())]
}

/// A photograph from `at` walking along `heading`: 20–160° to a random side, 0–10° upwards, aimed
/// at a building (of up to 64 random aims, the first whose centre ray meets a façade; near a
/// crossing or on the city's edge many do not).
fn photograph(
    city: &City,
    at: Vector2<f64>,
    heading: Vector2<f64>,
    rng: &mut ChaCha8Rng,
) -> [f64; 9] {
    let centre = Vector3::new(at.x, at.y, EYE);
    let mut forward = Vector3::x();
    for _ in 0..64 {
        let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let yaw = heading.y.atan2(heading.x) + side * rng.random_range(20f64..160.0).to_radians();
        let pitch = rng.random_range(0f64..10.0).to_radians();
        forward = Vector3::new(
            yaw.cos() * pitch.cos(),
            yaw.sin() * pitch.cos(),
            pitch.sin(),
        );
        if cast(city, centre, forward).is_some() {
            break;
        }
    }
    look_camera(
        centre,
        forward,
        Vector3::z(),
        rng.random_range(500.0..800.0),
    )
}

/// Where the ray from `origin` along unit `dir` first meets a façade within [`RANGE`], with the
/// façade's outward normal (in plan); `None` if it meets the ground, a roof or nothing first.
fn cast(city: &City, origin: Vector3<f64>, dir: Vector3<f64>) -> Option<([f64; 3], Vector2<f64>)> {
    let far = origin + dir * RANGE;
    let ground = if dir.z < 0.0 {
        -origin.z / dir.z
    } else {
        f64::INFINITY
    };
    let mut best: Option<(f64, usize)> = None;
    for i in city.cell(origin.x.min(far.x))..=city.cell(origin.x.max(far.x)) {
        for j in city.cell(origin.y.min(far.y))..=city.cell(origin.y.max(far.y)) {
            let (lo, hi) = city.footprint(i, j);
            let lo = Vector3::new(lo.x, lo.y, 0.0);
            let hi = Vector3::new(hi.x, hi.y, city.heights[i * city.m + j]);
            // Entered through a face (not starting inside) before leaving.
            let entered = slab(origin, dir, lo, hi, f64::INFINITY)
                .filter(|&(t0, t1, axis)| axis != usize::MAX && t0 < t1);
            if let Some((t, _, axis)) = entered {
                if t <= RANGE && t < ground && best.is_none_or(|(b, _)| t < b) {
                    best = Some((t, axis));
                }
            }
        }
    }
    let (t, axis) = best?;
    if axis == 2 {
        return None;
    }
    let p = origin + dir * t;
    let mut normal = Vector2::zeros();
    normal[axis] = -dir[axis].signum();
    Some(([p.x, p.y, p.z], normal))
}

/// A façade point through a random pixel of camera `cam` at `centre`, if the pixel shows one.
fn facade_point(
    city: &City,
    cam: &[f64; 9],
    centre: Vector3<f64>,
    rng: &mut ChaCha8Rng,
) -> Option<([f64; 3], Vector2<f64>)> {
    let u = rng.random_range(-HALF_IMAGE[0]..HALF_IMAGE[0]) / cam[6];
    let v = rng.random_range(-HALF_IMAGE[1]..HALF_IMAGE[1]) / cam[6];
    // The camera's frame to the world's: the inverse rotation.
    let w = Vector3::new(-cam[0], -cam[1], -cam[2]);
    let dir = super::rotate(&w, &Vector3::new(u, v, -1.0)).normalize();
    cast(city, centre, dir)
}

/// The cameras, bucketed by [`RANGE`]-sized cells of the plan for the visibility queries.
struct Buckets {
    cells: Vec<Vec<usize>>,
    side: usize,
}

impl Buckets {
    fn new(centres: &[Vector3<f64>], size: f64) -> Self {
        let side = (size / RANGE).ceil() as usize + 1;
        let mut cells = vec![Vec::new(); side * side];
        for (c, p) in centres.iter().enumerate() {
            cells[Self::cell(p.x, side) * side + Self::cell(p.y, side)].push(c);
        }
        Self { cells, side }
    }

    fn cell(x: f64, side: usize) -> usize {
        ((x / RANGE).floor().max(0.0) as usize).min(side - 1)
    }

    /// The cameras in the cells within [`RANGE`] of `(x, y)`, written into `out`.
    fn near(&self, x: f64, y: f64, out: &mut Vec<usize>) {
        out.clear();
        let (ci, cj) = (Self::cell(x, self.side), Self::cell(y, self.side));
        for i in ci.saturating_sub(1)..=(ci + 1).min(self.side - 1) {
            for j in cj.saturating_sub(1)..=(cj + 1).min(self.side - 1) {
                out.extend_from_slice(&self.cells[i * self.side + j]);
            }
        }
    }
}

/// True when camera `cam` at `centre` sees the façade point `p` with outward normal `normal`.
fn sees(
    city: &City,
    cam: &[f64; 9],
    centre: &Vector3<f64>,
    p: &[f64; 3],
    normal: Vector2<f64>,
) -> bool {
    let to_camera = Vector2::new(centre.x - p[0], centre.y - p[1]);
    if to_camera.dot(&normal) <= 0.0 || to_camera.norm() > RANGE {
        return false;
    }
    let pc = in_camera(cam, p);
    if pc.z > -1.0 {
        return false;
    }
    let (u, v) = (-cam[6] * pc.x / pc.z, -cam[6] * pc.y / pc.z);
    if u.abs() > HALF_IMAGE[0] || v.abs() > HALF_IMAGE[1] {
        return false;
    }
    let from = Vector2::new(p[0], p[1]) + normal * 1e-6;
    !city.blocked(from, Vector2::new(centre.x, centre.y))
}

/// The street walk's cameras, façade points and visibility (see the module documentation).
pub(crate) fn scene(o: &SyntheticOptions, rng: &mut ChaCha8Rng) -> Scene {
    let (lo, hi) = o.views.unwrap_or((2, 20));
    let (lo, hi) = (lo.max(1), hi.max(lo.max(1)));
    let city = City::for_cameras(o.cameras, rng);
    let cameras = walk(&city, o.cameras, rng);
    let centres: Vec<Vector3<f64>> = cameras.iter().map(camera_centre).collect();
    let buckets = Buckets::new(&centres, city.m as f64 * BLOCK);
    let (mut points, mut seen_by) = (Vec::new(), Vec::new());
    let mut near = Vec::new();
    for (c, cam) in cameras.iter().enumerate() {
        // This camera's share of the points, each through a random pixel of its image.
        let share = o.points / o.cameras.max(1) + usize::from(c < o.points % o.cameras.max(1));
        let mut made = 0;
        for _ in 0..50 * share {
            if made == share {
                break;
            }
            let Some((p, normal)) = facade_point(&city, cam, centres[c], rng) else {
                continue;
            };
            buckets.near(p[0], p[1], &mut near);
            near.retain(|&d| d != c && sees(&city, &cameras[d], &centres[d], &p, normal));
            if near.len() + 1 < lo || !sees(&city, cam, &centres[c], &p, normal) {
                continue;
            }
            let k = rng.random_range(lo..=hi).min(near.len() + 1);
            // The track: the cameras nearest the one that found the point.
            let d2 = |d: &usize| (centres[*d] - centres[c]).norm_squared();
            near.sort_by(|a, b| d2(a).total_cmp(&d2(b)));
            let mut chosen = near[..k - 1].to_vec();
            chosen.push(c);
            chosen.sort_unstable();
            points.push(p);
            seen_by.push(chosen);
            made += 1;
        }
    }
    Scene {
        cameras,
        points,
        seen_by,
    }
}

#[cfg(test)]
mod tests {
    use super::super::{generate, project, Layout, SyntheticOptions};
    use super::*;

    fn options(cameras: usize) -> SyntheticOptions {
        SyntheticOptions {
            layout: Layout::Streets,
            cameras,
            points: cameras * 30,
            ..SyntheticOptions::default()
        }
    }

    #[test]
    fn every_point_is_seen_by_two_to_twenty_cameras_that_have_it_in_their_image() {
        let s = generate(&options(300));
        // A camera facing a crossing may find fewer than its share of 30.
        assert!(s.truth.points.len() >= 8000, "{}", s.truth.points.len());
        let mut count = vec![0usize; s.truth.points.len()];
        for o in &s.truth.observations {
            count[o.point] += 1;
            let uv = project(&s.truth.cameras[o.camera], &s.truth.points[o.point]);
            assert!(uv[0].abs() <= 500.0 && uv[1].abs() <= 375.0, "{uv:?}");
            assert_eq!(uv, o.uv);
            let pc = in_camera(&s.truth.cameras[o.camera], &s.truth.points[o.point]);
            assert!(pc.z < -1.0 && pc.norm() <= RANGE + 5.0);
        }
        assert!(count.iter().all(|&c| (2..=20).contains(&c)));
        let mut per_camera = vec![0usize; s.truth.cameras.len()];
        for o in &s.truth.observations {
            per_camera[o.camera] += 1;
        }
        let least = per_camera.iter().min().unwrap();
        assert!(*least >= 10, "a camera sees {least} points");
        let mean = count.iter().sum::<usize>() as f64 / count.len() as f64;
        assert!((6.0..=14.0).contains(&mean), "mean views {mean}");
    }

    #[test]
    fn the_city_grows_with_the_walk_and_the_walk_returns_to_its_streets() {
        for n in [100, 1000, 4000] {
            let s = generate(&options(n));
            let centres: Vec<Vector3<f64>> = s.truth.cameras.iter().map(camera_centre).collect();
            // Every camera sees about the same number of points at every size.
            let per_camera = s.truth.observations.len() as f64 / n as f64;
            assert!((150.0..=450.0).contains(&per_camera), "{n}: {per_camera}");
            // Cameras stand on the streets, at the eye's height.
            for c in &centres {
                let off = |x: f64| (x - (x / BLOCK).round() * BLOCK).abs();
                assert!(
                    off(c.x).min(off(c.y)) < 1e-6 && (c.z - EYE).abs() < 1e-6,
                    "{c}"
                );
            }
            // Some camera comes back within 3 m of one taken at least 100 steps before.
            let back =
                (100..n).any(|i| (0..i - 99).any(|j| (centres[i] - centres[j]).norm() < 3.0));
            assert!(back || n < 200, "{n}: the walk never returns");
        }
    }

    #[test]
    fn a_wall_between_hides_a_point() {
        let city = City {
            m: 2,
            heights: vec![10.0; 4],
        };
        // Across block (0, 0)'s building, from the street x = 0 to the street x = 20.
        assert!(city.blocked(Vector2::new(0.0, 10.0), Vector2::new(20.0, 10.0)));
        // Along the street y = 20, between the buildings.
        assert!(!city.blocked(Vector2::new(0.0, 20.0), Vector2::new(40.0, 20.0)));
        // From a façade point outwards to the street it faces.
        assert!(!city.blocked(Vector2::new(14.0 + 1e-6, 10.0), Vector2::new(20.0, 12.0)));
    }
}
