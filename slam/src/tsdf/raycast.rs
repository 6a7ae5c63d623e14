//! Rendering the model: march each pixel's ray through the TSDF, skipping unallocated blocks,
//! stepping by the stored distance inside them, and refining the + → − zero crossing by linear
//! interpolation of trilinear samples (Parker et al. 1998; KinectFusion's raycaster). Normals are the
//! normalised TSDF gradient (central differences of trilinear samples).

use super::{split, TsdfVolume, BLOCK};
use crate::camera::Camera;
use crate::image::{ColorImage, DepthImage, Image, NormalMap, VertexMap, INVALID};
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

/// What the model looks like from a pose: per pixel, the surface point and normal (world frame),
/// the z-depth in the camera frame and the fused colour (all invalid/zero where the ray misses).
#[derive(Clone, Debug)]
pub struct RaycastMaps {
    /// Surface points, world frame.
    pub vertices: VertexMap,
    /// Unit normals, world frame, facing the camera.
    pub normals: NormalMap,
    /// z-depth in the camera frame, metres (0 where missed).
    pub depth: DepthImage,
    /// Fused colour.
    pub colors: ColorImage,
}

impl RaycastMaps {
    /// Empty maps (sized on first use).
    pub fn new() -> Self {
        Self {
            vertices: Image::filled(0, 0, INVALID),
            normals: Image::filled(0, 0, INVALID),
            depth: Image::new(0, 0),
            colors: Image::filled(0, 0, [0; 3]),
        }
    }
}

impl Default for RaycastMaps {
    fn default() -> Self {
        Self::new()
    }
}

/// A hit of one ray: world point, normal, colour and depth along the ray.
type RayHit = (Point3<f32>, Vector3<f32>, [u8; 3], f32);

impl TsdfVolume {
    /// The TSDF sample (units of μ) nearest to `p`, or `None` if its block is unallocated (the
    /// `bool` says whether the block exists).
    #[inline]
    fn nearest(&self, p: &Point3<f32>) -> (Option<f32>, bool) {
        let s = p.coords / self.params.voxel_size;
        let g = [s.x.round() as i32, s.y.round() as i32, s.z.round() as i32];
        let (b, l) = split(g);
        match self.block(&b) {
            Some(blk) => {
                let i = super::local_index(l[0], l[1], l[2]);
                (
                    if blk.weight[i] > 0.0 {
                        Some(blk.tsdf[i])
                    } else {
                        None
                    },
                    true,
                )
            }
            None => (None, false),
        }
    }

    /// The normalised TSDF gradient at `p`.
    fn gradient(&self, p: &Point3<f32>) -> Option<Vector3<f32>> {
        let h = self.params.voxel_size;
        let mut g = Vector3::zeros();
        for a in 0..3 {
            let mut e = Vector3::zeros();
            e[a] = h;
            let (f1, _) = self.trilinear(&(p + e))?;
            let (f0, _) = self.trilinear(&(p - e))?;
            g[a] = f1 - f0;
        }
        g.try_normalize(1e-12)
    }

    /// Marches one ray from `origin` along the unit `dir` between `t_min` and `t_max`.
    pub fn cast_ray(
        &self,
        origin: &Point3<f32>,
        dir: &Vector3<f32>,
        t_min: f32,
        t_max: f32,
    ) -> Option<RayHit> {
        let vs = self.params.voxel_size;
        let mu = self.params.truncation();
        let block_len = vs * BLOCK as f32;
        let mut t = t_min;
        let mut prev: Option<(f32, f32)> = None; // (t, tsdf) of the last observed sample
        while t < t_max {
            let p = origin + dir * t;
            let (value, allocated) = self.nearest(&p);
            if !allocated {
                prev = None;
                t += block_len * 0.9;
                continue;
            }
            let Some(f) = value else {
                prev = None;
                t += vs;
                continue;
            };
            if let Some((tp, fp)) = prev {
                if fp > 0.0 && f <= 0.0 {
                    // refine with trilinear samples at both ends
                    let (a, b) = (self.trilinear(&(origin + dir * tp)), self.trilinear(&p));
                    let (fa, fb) = match (a, b) {
                        (Some((fa, _)), Some((fb, _))) if fa > 0.0 && fb <= 0.0 => (fa, fb),
                        _ => (fp, f),
                    };
                    let ts = tp + (t - tp) * fa / (fa - fb);
                    let hit = origin + dir * ts;
                    let n = self.gradient(&hit)?;
                    let color = self
                        .trilinear(&hit)
                        .map(|(_, c)| c.map(|v| v.round().clamp(0.0, 255.0) as u8))
                        .unwrap_or([0; 3]);
                    return Some((hit, n, color, ts));
                }
                if fp < 0.0 && f > 0.0 {
                    return None; // seen from behind: a back face
                }
            }
            prev = Some((t, f));
            // step by the distance to the surface, at least one voxel
            t += (f * mu * 0.8).max(vs);
        }
        None
    }

    /// Renders the model seen by `camera` at `pose` (camera-to-world) into `out`.
    pub fn raycast(&self, camera: &Camera, pose: &Isometry3<f64>, out: &mut RaycastMaps) {
        let (w, h) = (camera.width, camera.height);
        out.vertices.resize(w, h, INVALID);
        out.normals.resize(w, h, INVALID);
        out.depth.resize(w, h, 0.0);
        out.colors.resize(w, h, [0; 3]);
        let origin = Point3::from(pose.translation.vector.cast::<f32>());
        let rot = pose
            .rotation
            .to_rotation_matrix()
            .into_inner()
            .cast::<f32>();
        let (t_min, t_max) = (camera.depth_min as f32, self.params.max_depth * 1.5);
        let rows: Vec<(usize, Vec<Option<RayHit>>, Vec<f32>)> = (0..h)
            .into_par_iter()
            .map(|y| {
                let mut hits = Vec::with_capacity(w);
                let mut zs = Vec::with_capacity(w);
                for x in 0..w {
                    let rc = camera
                        .back_project(x as f64, y as f64, 1.0)
                        .coords
                        .cast::<f32>();
                    let len = rc.norm();
                    let dir = rot * (rc / len);
                    let hit = self.cast_ray(&origin, &dir, t_min * len, t_max * len);
                    zs.push(hit.map_or(0.0, |hh| hh.3 / len));
                    hits.push(hit);
                }
                (y, hits, zs)
            })
            .collect();
        for (y, hits, zs) in rows {
            for (x, (hit, z)) in hits.into_iter().zip(zs).enumerate() {
                let i = y * w + x;
                match hit {
                    Some((p, n, c, _)) => {
                        out.vertices.data[i] = [p.x, p.y, p.z];
                        out.normals.data[i] = [n.x, n.y, n.z];
                        out.depth.data[i] = z;
                        out.colors.data[i] = c;
                    }
                    None => {
                        out.vertices.data[i] = INVALID;
                        out.normals.data[i] = INVALID;
                        out.depth.data[i] = 0.0;
                        out.colors.data[i] = [0; 3];
                    }
                }
            }
        }
    }
}
