//! Whether a frame registration's warped object still stands before its background, as it did in
//! the source: the depth's half of a frame registration's verdict for plain objects, whose colour
//! check has no textured patch to judge by.
//!
//! Where the source's object ends against a background at least the gap behind it (or nothing),
//! the object's outline points `b` are those of module `outline_start`, each with its outward
//! probe `b'`, kept where the surface meets the outline at most [`MAX_EDGE_SLOPE`] steep (an edge
//! of the object, not a silhouette the view makes). After the registration, `b` is at `w(b)` and
//! its probe at `w(b) + R (b' − b)`, `R` the rotation of the warp's best rigid fit (Horn's
//! absolute orientation of the points onto their warped places). An outline point is seen when
//! the target's depth at `w(b)`'s pixel agrees with `w(b)_z` within the association gate; a
//! seen point stands when its probe sees no depth or depth at least the gap behind `w(b)_z`,
//! and lies flush when the probe sees depth within the gap of it (a surface that goes on where
//! the object should end). A probe that leaves the image or sees something nearer (an occluder)
//! says nothing either way.
//!
//! A plain object registered onto a plain surface it is not on (a wall beside it, a larger plain
//! object) has its points on the surface, which is all the verdict's depth count asks, but its
//! outline lies flush (NOTES 148): with [`MAX_FLUSH_FRACTION`] of the seen outline flush, the
//! registration is not trusted.

use super::outline_start::{depth_at, outline_points, OutlineInput};
use crate::eval::umeyama;
use nalgebra::{Point3, UnitQuaternion, Vector3};

/// The object's points sampled for the rotation's fit, at most.
const FIT_SAMPLES: usize = 2000;

/// The steepest depth slope across the outline (module `outline_start`'s `slope`, the tangent
/// of the surface's angle to the image plane) at which an outline point is checked: 45°. A
/// steeper outline may be an occluding contour, which the view makes and a motion moves over
/// the surface (a ball turned shows surface beyond its old silhouette), not the object's edge.
pub const MAX_EDGE_SLOPE: f64 = 1.0;

/// Seen outline points below which the check says nothing.
pub const MIN_SEEN: usize = 20;

/// The fraction of the seen outline that may lie flush in a registration that counts.
pub const MAX_FLUSH_FRACTION: f64 = 0.5;

/// The outline check's counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OutlineCheck {
    /// The source's outline points: those standing before their background in the source, at
    /// an edge of the object's surface ([`MAX_EDGE_SLOPE`]).
    pub outline: usize,
    /// Of them, those seen on the target's surface after the warp with a probe that says
    /// something (inside the image, not occluded).
    pub seen: usize,
    /// Of those, the ones whose probe sees a surface going on within the gap.
    pub flush: usize,
}

impl OutlineCheck {
    /// `flush / seen` (0 with nothing seen).
    pub fn fraction_flush(&self) -> f64 {
        self.flush as f64 / self.seen.max(1) as f64
    }

    /// Whether the check judges: at least [`MIN_SEEN`] outline points seen.
    pub fn judges(&self) -> bool {
        self.seen >= MIN_SEEN
    }

    /// Whether the warped object lies flush in a larger surface: it judges and more than
    /// [`MAX_FLUSH_FRACTION`] of its seen outline is flush.
    pub fn lies_flush(&self) -> bool {
        self.judges() && self.fraction_flush() > MAX_FLUSH_FRACTION
    }
}

/// The outline check of `input`'s object carried to `warped` (one per point). None when the
/// source's object has no outline before its background (nothing to check) or `warped` does
/// not match the points.
pub fn check_outline(input: &OutlineInput<'_>, warped: &[Vector3<f64>]) -> Option<OutlineCheck> {
    if warped.len() != input.points.len() {
        return None;
    }
    let mut outline = outline_points(input);
    outline.retain(|b| b.slope <= MAX_EDGE_SLOPE);
    if outline.is_empty() {
        return None;
    }
    let rotation = fitted_rotation(input.points, warped);
    let (mut seen, mut flush) = (0, 0);
    for b in &outline {
        let w = warped[b.index];
        let probe = w + rotation * (b.probe - b.point);
        if let Some(edge) = judged(input, &w, &probe) {
            seen += 1;
            flush += usize::from(edge == Edge::Flush);
        }
    }
    Some(OutlineCheck {
        outline: outline.len(),
        seen,
        flush,
    })
}

/// What a seen outline point's probe finds on the target.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Edge {
    /// No depth, or depth at least the gap behind: the object ends there.
    Stands,
    /// Depth within the gap: a surface goes on where the object should end.
    Flush,
}

/// How the outline point at `w` with its probe at `probe` ends on the target; None when it is
/// not seen or the probe says nothing.
fn judged(input: &OutlineInput<'_>, w: &Vector3<f64>, probe: &Vector3<f64>) -> Option<Edge> {
    let camera = input.target_camera;
    let at = camera.project_to_pixel(&Point3::from(*w))?;
    let z = depth_at(input.target_depth, at)?;
    if (z - w.z).abs() > input.gate {
        return None;
    }
    let beyond = camera.project_to_pixel(&Point3::from(*probe))?;
    match depth_at(input.target_depth, beyond) {
        None => Some(Edge::Stands),
        Some(zp) if zp >= w.z + input.gap => Some(Edge::Stands),
        Some(zp) if zp <= w.z - input.gap => None,
        Some(_) => Some(Edge::Flush),
    }
}

/// The rotation of the best rigid fit of `points` onto `warped`, from an even sample; the
/// identity when there is none (fewer than three points, all on a line).
fn fitted_rotation(points: &[Vector3<f64>], warped: &[Vector3<f64>]) -> UnitQuaternion<f64> {
    let stride = points.len().div_ceil(FIT_SAMPLES).max(1);
    let pick = |v: &[Vector3<f64>]| -> Vec<Point3<f64>> {
        v.iter().step_by(stride).map(|p| Point3::from(*p)).collect()
    };
    umeyama(&pick(points), &pick(warped), false)
        .map_or_else(UnitQuaternion::identity, |s| s.isometry.rotation)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::image::DepthImage;
    use nalgebra::Isometry3;

    /// A 60 × 60 pixel plate at 1 m before a wall at `wall` m (0: none), in a 160 × 120 view,
    /// its left edge at column `left`: the depth, the plate's pixels and points.
    fn plate(
        camera: &Camera,
        left: usize,
        wall: f32,
    ) -> (DepthImage, Vec<usize>, Vec<Vector3<f64>>) {
        let mut depth = DepthImage::filled(160, 120, wall);
        let (mut pixels, mut points) = (Vec::new(), Vec::new());
        for v in 30..90 {
            for u in left..left + 60 {
                depth.data[v * 160 + u] = 1.0;
                pixels.push(v * 160 + u);
                points.push(camera.back_project(u as f64, v as f64, 1.0).coords);
            }
        }
        (depth, pixels, points)
    }

    fn input<'a>(
        camera: &'a Camera,
        (source, pixels, points): (&'a DepthImage, &'a [usize], &'a [Vector3<f64>]),
        target: &'a DepthImage,
    ) -> OutlineInput<'a> {
        OutlineInput {
            source_camera: camera,
            source_depth: source,
            pixels,
            points,
            target_camera: camera,
            target_depth: target,
            gate: 0.03,
            gap: 0.05,
        }
    }

    #[test]
    fn a_plate_carried_onto_its_place_stands_and_one_carried_onto_the_wall_lies_flush() {
        let camera = Camera::new(150.0, 150.0, 80.0, 60.0, 160, 120);
        let (source, pixels, points) = plate(&camera, 20, 2.0);
        let (target, _, moved) = plate(&camera, 90, 2.0);
        let check = |warped: &[Vector3<f64>]| {
            check_outline(
                &input(&camera, (&source, &pixels, &points), &target),
                warped,
            )
            .unwrap()
        };
        let right = check(&moved);
        assert!(right.judges() && !right.lies_flush(), "{right:?}");
        assert_eq!(right.flush, 0, "{right:?}");
        // the same plate pressed onto the wall at its own place: on the target's surface, flush
        let onto_wall: Vec<_> = points.iter().map(|p| p * 2.0).collect();
        let wrong = check(&onto_wall);
        assert!(wrong.lies_flush(), "{wrong:?}");
        assert!(wrong.fraction_flush() > 0.9, "{wrong:?}");
    }

    #[test]
    fn a_plate_turned_upside_down_stands_with_its_probes_turned() {
        let camera = Camera::new(150.0, 150.0, 80.0, 60.0, 160, 120);
        let (source, pixels, points) = plate(&camera, 50, 0.0);
        // the target shows the plate turned by 3 rad about the view axis through its centre:
        // probes not turned with it would point into the plate and find it flush
        let centre = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
        let turn = Isometry3::rotation_wrt_point(
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 3.0),
            Point3::from(centre),
        );
        let turned: Vec<_> = points
            .iter()
            .map(|p| (turn * Point3::from(*p)).coords)
            .collect();
        let mut target = DepthImage::filled(160, 120, 0.0);
        for p in &turned {
            for (du, dv) in [(0.0, 0.0), (0.5, 0.0), (0.0, 0.5), (0.5, 0.5)] {
                let q = Point3::from(*p);
                if let Some((u, v)) = camera.project(&q).and_then(|(u, v)| {
                    camera.project_to_pixel(&camera.back_project(u + du, v + dv, q.z))
                }) {
                    target.data[v * 160 + u] = q.z as f32;
                }
            }
        }
        let check = check_outline(
            &input(&camera, (&source, &pixels, &points), &target),
            &turned,
        )
        .unwrap();
        assert!(check.judges() && !check.lies_flush(), "{check:?}");
    }

    #[test]
    fn an_object_flush_in_its_source_or_a_mismatched_warp_is_not_checked() {
        let camera = Camera::new(150.0, 150.0, 80.0, 60.0, 160, 120);
        let (_, pixels, points) = plate(&camera, 20, 0.0);
        let flat = DepthImage::filled(160, 120, 1.0);
        let flush = input(&camera, (&flat, &pixels, &points), &flat);
        assert_eq!(check_outline(&flush, &points), None);
        let (source, _, _) = plate(&camera, 20, 0.0);
        let standing = input(&camera, (&source, &pixels, &points), &flat);
        assert_eq!(check_outline(&standing, &points[1..]), None);
        // nothing of the warped object on the target's surface: no judgement
        let empty = DepthImage::filled(160, 120, 0.0);
        let unseen = input(&camera, (&source, &pixels, &points), &empty);
        let check = check_outline(&unseen, &points).unwrap();
        assert!(!check.judges() && !check.lies_flush(), "{check:?}");
    }
}
