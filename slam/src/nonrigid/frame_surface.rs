//! A frame's object as a surface, for frames without a mask and for scoring a registration
//! without ground-truth flow: the object's pixels from a deformation graph's nodes (DeepDeform
//! ships its test pairs with the source's graph and no mask), the frame's points, and the median
//! distance from points to the nearest of them.

use super::frames::FrameView;
use crate::camera::Camera;
use crate::eval::Stats;
use crate::image::{DepthImage, Image};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;
use rayon::prelude::*;

/// A KD-tree over points in double precision.
fn tree(points: &[Vector3<f64>]) -> ImmutableKdTree<f64, 3> {
    let coords: Vec<[f64; 3]> = points.iter().map(|p| (*p).into()).collect();
    ImmutableKdTree::new_from_slice(&coords)
}

/// The pixels of `depth` whose back-projected point lies within `radius` of one of `nodes`
/// (camera coordinates, metres): the part of the frame a graph of that node coverage deforms.
/// Pixels without depth are not in it; with no nodes, none is.
pub fn mask_near_nodes(
    camera: &Camera,
    depth: &DepthImage,
    nodes: &[Vector3<f64>],
    radius: f64,
) -> Image<bool> {
    let mut mask = Image::filled(depth.width, depth.height, false);
    if nodes.is_empty() {
        return mask;
    }
    let tree = tree(nodes);
    let r2 = radius * radius;
    let w = depth.width.max(1);
    mask.data
        .par_iter_mut()
        .zip(&depth.data)
        .enumerate()
        .for_each(|(i, (m, &z))| {
            if z > 0.0 && z.is_finite() {
                let p = camera.back_project((i % w) as f64, (i / w) as f64, z as f64);
                let near = tree.nearest_one::<SquaredEuclidean>(&p.coords.into());
                *m = near.distance <= r2;
            }
        });
    mask
}

/// The frame's valid pixels inside its mask, back-projected (camera coordinates, metres).
pub fn frame_points(frame: &FrameView<'_>) -> Vec<Vector3<f64>> {
    let w = frame.camera.width.max(1);
    frame
        .depth
        .data
        .iter()
        .enumerate()
        .filter(|&(i, &z)| {
            z > 0.0 && z.is_finite() && frame.mask.is_none_or(|m| m.data.get(i) == Some(&true))
        })
        .map(|(i, &z)| {
            frame
                .camera
                .back_project((i % w) as f64, (i / w) as f64, z as f64)
                .coords
        })
        .collect()
}

/// The median ([`Stats`]' convention) over `points` of the distance to the nearest of `surface` (None when either is
/// empty): how far a registered source lies from the target's surface, without ground truth.
pub fn median_distance(points: &[Vector3<f64>], surface: &[Vector3<f64>]) -> Option<f64> {
    if points.is_empty() || surface.is_empty() {
        return None;
    }
    let tree = tree(surface);
    let d: Vec<f64> = points
        .par_iter()
        .map(|p| {
            tree.nearest_one::<SquaredEuclidean>(&(*p).into())
                .distance
                .sqrt()
        })
        .collect();
    Some(Stats::of(&d).median)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A wall at 1 m seen by a 40 × 30 camera.
    fn wall() -> (Camera, DepthImage) {
        let camera = Camera::new(40.0, 40.0, 19.5, 14.5, 40, 30);
        let mut depth = Image::filled(40, 30, 1.0f32);
        depth.data[0] = 0.0;
        (camera, depth)
    }

    #[test]
    fn the_mask_holds_the_pixels_near_a_node_and_no_pixel_without_depth() {
        let (camera, depth) = wall();
        // a node on the wall at the image centre, one far off it
        let nodes = [Vector3::new(0.0, 0.0, 1.0), Vector3::new(5.0, 5.0, 5.0)];
        let mask = mask_near_nodes(&camera, &depth, &nodes, 0.1);
        let inside: Vec<usize> = (0..mask.data.len()).filter(|&i| mask.data[i]).collect();
        // pixels within 0.1 m at 1 m and 40 px/m: a disc of radius 4 px about (19.5, 14.5)
        assert!((40..=60).contains(&inside.len()), "{}", inside.len());
        for i in inside {
            let (x, y) = ((i % 40) as f64 - 19.5, (i / 40) as f64 - 14.5);
            assert!(x.hypot(y) <= 4.0 + 1e-9, "pixel {i}");
        }
        assert!(mask_near_nodes(&camera, &depth, &[], 0.1)
            .data
            .iter()
            .all(|m| !m));
        let corner = [camera.back_project(0.0, 0.0, 1.0).coords];
        assert!(
            !mask_near_nodes(&camera, &depth, &corner, 0.01).data[0],
            "no depth"
        );
    }

    #[test]
    fn the_median_distance_is_the_middle_one_and_points_follow_the_mask() {
        let surface = [Vector3::zeros()];
        let points: Vec<_> = [0.3, 0.1, 0.2, 5.0, 0.05]
            .iter()
            .map(|&x| Vector3::new(x, 0.0, 0.0))
            .collect();
        assert_eq!(median_distance(&points, &surface), Some(0.2));
        assert_eq!(median_distance(&[], &surface), None);
        assert_eq!(median_distance(&points, &[]), None);
        let (camera, depth) = wall();
        let mut mask = Image::filled(40, 30, false);
        mask.data[0] = true; // no depth there
        mask.data[41] = true;
        let frame = FrameView::new(&camera, &depth, None, Some(&mask));
        let p = frame_points(&frame);
        assert_eq!(p.len(), 1);
        assert!((p[0] - camera.back_project(1.0, 1.0, 1.0).coords).norm() < 1e-12);
        let all = FrameView::new(&camera, &depth, None, None);
        assert_eq!(frame_points(&all).len(), 40 * 30 - 1);
    }
}
