//! The canonical band a live frame updates (DynamicFusion, Newcombe, Fox & Seitz, CVPR 2015,
//! sec. 3.3): the live surface is sampled, carried back into the canonical frame by the inverse of
//! each sample's blended node motion, and the volume's blocks within the truncation distance of
//! the samples (plus a margin for the surface between them) are the ones fused.

use super::graph::DeformationGraph;
use crate::camera::Camera;
use crate::image::{valid, Image};
use dynamap_residuals::deform::{rigid_motion, transform_point};
use kiddo::ImmutableKdTree;
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

/// The spacing of the live surface's samples at the median depth, in voxels. Blocks span
/// [`BLOCK`](crate::tsdf::BLOCK) voxels, so samples two voxels apart still find every block the
/// band touches, for a quarter of the samples one voxel apart.
const SPACING_VOXELS: f32 = 2.0;

/// The least cosine between a sample's normal and its ray that its margin assumes: a surface
/// seen more obliquely is stretched between samples as if seen at this angle (about 72°).
const COS_FLOOR: f64 = 0.3;

/// Which live pixels are carried back, and the margin each one's blocks are found with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BandSampling {
    /// Every `stride`-th pixel of every `stride`-th row.
    pub stride: usize,
    /// Voxel edge, metres.
    voxel: f64,
    /// Focal lengths, pixels.
    focal: (f64, f64),
}

impl BandSampling {
    /// The pixel stride at which the live surface is about [`SPACING_VOXELS`] voxels apart at the
    /// median depth (read at every 7th pixel).
    pub fn of(depth: &Image<f32>, camera: &Camera, voxel: f32) -> Self {
        let focal = (camera.fx.abs().max(1e-9), camera.fy.abs().max(1e-9));
        let mut z: Vec<f32> = depth
            .data
            .iter()
            .step_by(7)
            .copied()
            .filter(|d| *d > 0.0 && d.is_finite())
            .collect();
        let stride = match z.is_empty() {
            true => 1,
            false => {
                let mid = z.len() / 2;
                let median = *z.select_nth_unstable_by(mid, f32::total_cmp).1 as f64;
                let footprint = median / focal.0.max(focal.1);
                (((SPACING_VOXELS * voxel) as f64 / footprint).floor() as usize).max(1)
            }
        };
        Self {
            stride,
            voxel: voxel as f64,
            focal,
        }
    }

    /// The margin beyond the truncation distance μ for the sample at `v` (camera frame) with
    /// normal `n`: a surface point between four neighbouring samples lies within half the
    /// longer diagonal of their cell of one of them, so the blocks within μ + (that − voxel/2)
    /// of the samples miss at most half a voxel of its band. The cell's sides are one stride
    /// across at the sample's depth, `s_x = stride z / f_x` and `s_y`, tilted out of the image
    /// plane along the surface: `d_x = (s_x, 0, −n_x s_x / c)`, `d_y = (0, s_y, −n_y s_y / c)`,
    /// `c = max(|n · v̂|, COS_FLOOR)`. A sample without a normal (at a border of the depth, where
    /// a tilt cannot be told) gets the margin of a surface facing the camera.
    pub fn margin(&self, v: &[f32; 3], n: &[f32; 3]) -> f64 {
        let z = v[2] as f64;
        let (sx, sy) = (
            self.stride as f64 * z / self.focal.0,
            self.stride as f64 * z / self.focal.1,
        );
        let ray = Vector3::new(v[0] as f64, v[1] as f64, z).normalize();
        let n = Vector3::new(n[0] as f64, n[1] as f64, n[2] as f64);
        let half_diagonal = match n.iter().all(|c| c.is_finite()) {
            true => {
                let c = n.dot(&ray).abs().max(COS_FLOOR);
                let dx = Vector3::new(sx, 0.0, -n.x * sx / c);
                let dy = Vector3::new(0.0, sy, -n.y * sy / c);
                0.5 * (dx + dy).norm().max((dx - dy).norm())
            }
            false => 0.5 * (sx * sx + sy * sy).sqrt(),
        };
        (half_diagonal - 0.5 * self.voxel).max(0.0)
    }
}

/// Carries every `stride`-th live vertex (camera frame; rows of `width`) back into the canonical
/// frame, with its margin ([`BandSampling::margin`]): bound to its K nearest warped nodes, by
/// the inverse of their blended motion (DynamicFusion's way of finding where new surface lies in
/// the canonical volume).
pub(crate) fn carry_back(
    graph: &DeformationGraph,
    (vertices, normals): (&Image<[f32; 3]>, &Image<[f32; 3]>),
    sampling: &BandSampling,
    out: &mut Vec<(Vector3<f64>, f64)>,
) {
    let warped: Vec<[f64; 3]> = graph
        .nodes
        .iter()
        .map(|n| transform_point(&n.motion, &n.position).into())
        .collect();
    let tree = ImmutableKdTree::<f64, 3>::new_from_slice(&warped);
    let (width, stride) = (vertices.width, sampling.stride.max(1));
    let rows = vertices.data.len() / width.max(1);
    out.clear();
    let row_list: Vec<usize> = lattice(rows, stride).collect();
    out.par_extend(row_list.into_par_iter().flat_map_iter(|y| {
        let tree = &tree;
        lattice(width, stride).filter_map(move |x| {
            let v = vertices.data[y * width + x];
            if !valid(&v) {
                return None;
            }
            let n = normals.data.get(y * width + x).unwrap_or(&[f32::NAN; 3]);
            let q = Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64);
            let b = graph.bind_in(tree, &q);
            let motion = rigid_motion(&graph.blend(&b));
            let p = motion.inverse_transform_point(&Point3::from(q)).coords;
            Some((p, sampling.margin(&v, n)))
        })
    }));
}

/// `0, stride, 2 stride, …` below `len`, and `len − 1`: the image's last row and column are
/// sampled too, so that no pixel lies beyond the last sample.
fn lattice(len: usize, stride: usize) -> impl Iterator<Item = usize> {
    let last = len.checked_sub(1).filter(|l| l % stride != 0);
    (0..len).step_by(stride).chain(last)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::{normal_map, vertex_map};
    use crate::nonrigid::graph::GraphParams;
    use crate::tsdf::{TsdfParams, TsdfVolume};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use std::collections::BTreeSet;

    /// A 640 × 480 depth image of a plane tilted `tilt` radians about x through (0, 0, `z`),
    /// and with `sphere` a ball of radius 0.2 m in front of it.
    fn scene(camera: &Camera, z: f64, tilt: f64, sphere: bool) -> Image<f32> {
        let mut depth = Image::new(camera.width, camera.height);
        let n = Vector3::new(0.0, tilt.sin(), -tilt.cos());
        let centre = Vector3::new(0.15, -0.05, z - 0.3);
        for (i, d) in depth.data.iter_mut().enumerate() {
            let (u, v) = ((i % camera.width) as f64, (i / camera.width) as f64);
            let ray = Vector3::new(
                (u - camera.cx) / camera.fx,
                (v - camera.cy) / camera.fy,
                1.0,
            );
            let plane = n.dot(&Vector3::new(0.0, 0.0, z)) / n.dot(&ray);
            // the ball's nearer crossing along the ray, if any
            let (a, b) = (ray.norm_squared(), ray.dot(&centre));
            let disc = b * b - a * (centre.norm_squared() - 0.04);
            let ball = (sphere && disc >= 0.0).then(|| (b - disc.sqrt()) / a);
            *d = ball.filter(|t| *t > 0.0).unwrap_or(plane) as f32;
        }
        depth
    }

    fn blocks(volume: &TsdfVolume, points: &[(Vector3<f64>, f64)]) -> BTreeSet<[i32; 3]> {
        volume.blocks_near(points).into_iter().collect()
    }

    /// The band's blocks against those of every pixel, on planes at several depths and tilts
    /// (up to 46°, seen at up to 71° at the image's edge, within [`COS_FLOOR`]) and with a ball in front (its rim grazing the rays), seen through a rigid
    /// motion that turns the sampling grid against the blocks' axes: every block within
    /// μ − voxel/2 of a pixel's point is found, except beside the ball's rim, where none is
    /// missed that samples one voxel apart with no margin would find; at most a third more
    /// than those within μ of the pixels are found, from a third of the samples or fewer.
    #[test]
    fn a_sparse_band_finds_the_blocks_of_every_pixel() {
        let camera = Camera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let params = TsdfParams::default();
        let volume = TsdfVolume::new(params);
        let inner = TsdfVolume::new(TsdfParams {
            truncation_voxels: params.truncation_voxels - 0.5,
            ..params
        });
        let motion = Isometry3::from_parts(
            Translation3::new(0.03, -0.02, 0.05),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.2, 0.5, -0.3)),
        );
        let cases = [
            (0.8, 0.0, false),
            (1.5, 0.6, false),
            (2.0, 0.8, false),
            (0.8, 0.0, true),
            (1.5, 0.6, true),
        ];
        for (z, tilt, ball) in cases {
            let case = format!("z {z}, tilt {tilt}, ball {ball}");
            let depth = scene(&camera, z, tilt, ball);
            let (mut vertices, mut normals) = (Image::new(0, 0), Image::new(0, 0));
            vertex_map(&depth, &camera, &mut vertices);
            normal_map(&vertices, &camera, &mut normals);
            let exact: Vec<(Vector3<f64>, f64)> = vertices
                .data
                .iter()
                .filter(|v| valid(v))
                .map(|v| {
                    let p = Point3::new(v[0], v[1], v[2]).cast();
                    (motion.inverse_transform_point(&p).coords, 0.0)
                })
                .collect();
            let points: Vec<_> = exact.iter().map(|(p, _)| *p).collect();
            let mut graph = DeformationGraph::sample(&points, GraphParams::default()).unwrap();
            graph.premultiply(&motion);
            let sampling = BandSampling::of(&depth, &camera, params.voxel_size);
            let mut sparse = Vec::new();
            carry_back(&graph, (&vertices, &normals), &sampling, &mut sparse);
            let one_voxel = BandSampling {
                stride: (sampling.stride / 2).max(1),
                ..sampling
            };
            let mut dense = Vec::new();
            carry_back(&graph, (&vertices, &normals), &one_voxel, &mut dense);
            assert!(3 * sparse.len() <= dense.len(), "{case}");
            dense.iter_mut().for_each(|(_, m)| *m = 0.0);
            let found = blocks(&volume, &sparse);
            let needed = blocks(&inner, &exact);
            let missed: BTreeSet<_> = needed.difference(&found).collect();
            match ball {
                false => assert!(missed.is_empty(), "{case}: {missed:?}"),
                true => {
                    let before = blocks(&volume, &dense);
                    let missed_before: BTreeSet<_> = needed.difference(&before).collect();
                    assert!(missed.is_subset(&missed_before), "{case}: {missed:?}");
                }
            }
            let within = blocks(&volume, &exact).len();
            eprintln!("{case}: {} blocks for {within}", found.len());
            assert!(
                3 * found.len() <= 4 * within,
                "{case}: {} for {within}",
                found.len()
            );
        }
    }

    #[test]
    fn a_blank_frame_samples_every_pixel_and_carries_nothing() {
        let camera = Camera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let depth = Image::new(640, 480);
        let sampling = BandSampling::of(&depth, &camera, 0.01);
        assert_eq!(sampling.stride, 1);
        let graph = DeformationGraph::sample(&[Vector3::zeros()], GraphParams::default()).unwrap();
        let mut vertices = Image::new(640, 480);
        vertices.data.fill([f32::NAN; 3]);
        let mut out = vec![(Vector3::zeros(), 0.0)];
        carry_back(&graph, (&vertices, &vertices.clone()), &sampling, &mut out);
        assert!(out.is_empty());
    }

    /// A sample facing the camera gets half its cell's diagonal less half a voxel; tilted, more;
    /// without a normal, as much as facing; where samples are a voxel apart or closer, none.
    #[test]
    fn the_margin_grows_with_the_spacing_and_the_tilt() {
        let camera = Camera::new(500.0, 500.0, 319.5, 239.5, 640, 480);
        let mut depth = Image::new(640, 480);
        depth.data.fill(1.01);
        let sampling = BandSampling::of(&depth, &camera, 0.01);
        assert_eq!(
            sampling.stride, 9,
            "0.02 m over 1.01 m / 500 px, rounded down"
        );
        let v = [0.0, 0.0, 1.0];
        let facing = sampling.margin(&v, &[0.0, 0.0, -1.0]);
        let expected = 9.0 / 500.0 / 2f64.sqrt() - 0.01f32 as f64 / 2.0;
        assert!(
            (facing - expected).abs() < 1e-9,
            "{facing} against {expected}"
        );
        let tilted = sampling.margin(&v, &[0.0, 0.5f32.sin(), -0.5f32.cos()]);
        let steep = sampling.margin(&v, &[0.0, 1.4f32.sin(), -1.4f32.cos()]);
        assert!(
            facing < tilted && tilted < steep,
            "{facing} {tilted} {steep}"
        );
        assert_eq!(sampling.margin(&v, &[f32::NAN; 3]), facing);
        let near = sampling.margin(&[0.0, 0.0, 0.3], &[0.0, 0.0, -1.0]);
        assert_eq!(near, 0.0);
    }
}
