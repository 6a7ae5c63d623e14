//! Rendering the model: march each pixel's ray through the TSDF, skipping unallocated blocks,
//! stepping by the stored distance inside them, and refining the + → − zero crossing by linear
//! interpolation of trilinear samples (Parker et al. 1998; KinectFusion's raycaster). Where a depth
//! is expected (the frame just fused), Newton's method on the trilinear field along the ray finds
//! the crossing from there first. Normals are the normalised TSDF gradient (of the trilinear
//! interpolant).

use super::{floor_i32, region_bit, region_of, BlockCache, TsdfVolume, BLOCK, REGION};
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

/// The hit at distance `t` along the ray, its normal the field's gradient `grad` (none where it
/// vanishes) and its colour the interpolated `color`, rounded.
fn ray_hit(
    origin: &Point3<f32>,
    dir: &Vector3<f32>,
    t: f32,
    grad: &Vector3<f32>,
    color: &[f32; 3],
) -> Option<RayHit> {
    let n = grad.try_normalize(1e-12)?;
    let color = color.map(|v| v.round().clamp(0.0, 255.0) as u8);
    Some((origin + dir * t, n, color, t))
}

/// Voxels along a region's edge.
const REGION_VOXELS: f32 = (BLOCK * REGION) as f32;

/// The distance along a ray from `q` to where it leaves the axis-aligned cell of edge `cell`
/// holding `q` (the cell ⌊q / cell⌋ per axis), metres; `q` is in voxels, and the ray advances
/// `per_metre` voxels per metre.
#[inline]
fn cell_exit(q: &Vector3<f32>, per_metre: &Vector3<f32>, cell: f32) -> f32 {
    let mut exit = f32::INFINITY;
    for i in 0..3 {
        let d = per_metre[i];
        if d != 0.0 {
            let lower = floor_i32(q[i] / cell) as f32 * cell;
            let face = if d > 0.0 { lower + cell } else { lower };
            exit = exit.min((face - q[i]) / d);
        }
    }
    exit.max(0.0)
}

impl TsdfVolume {
    /// The TSDF sample (units of μ) of the voxel holding `q` (voxel coordinates shifted by half
    /// a voxel, so that voxel ⌊q⌋ is the one nearest), in block `b`; `None` if unobserved or
    /// unallocated.
    #[inline]
    fn sample<'a>(
        &'a self,
        q: &Vector3<f32>,
        b: [i32; 3],
        cache: &mut BlockCache<'a>,
    ) -> Option<f32> {
        let blk = cache.get(self, b)?;
        let l = |k: usize| floor_i32(q[k]) - b[k] * BLOCK;
        blk.voxels[super::local_index(l(0), l(1), l(2))].observed()
    }

    /// Marches one ray from `origin` along the unit `dir` between `t_min` and `t_max`. Free space
    /// is crossed a cell at a time, to the exact face where the ray leaves it (Amanatides & Woo
    /// 1987): a whole region of 4³ blocks where none is allocated, else the unallocated block. So
    /// the ray enters every allocated block at its face and cannot step over a surface whose band
    /// in front of it is thinner than the step (thin, one-sided surfaces).
    pub fn cast_ray(
        &self,
        origin: &Point3<f32>,
        dir: &Vector3<f32>,
        t_min: f32,
        t_max: f32,
    ) -> Option<RayHit> {
        let vs = self.params.voxel_size;
        let mu = self.params.truncation();
        // voxel coordinates per metre along the ray, and how far past a face a step lands (at
        // least a few units in the last place of t, so that a step always moves it)
        let per_metre = dir / vs;
        let nudge = |t: f32| (0.01 * vs).max(4.0 * f32::EPSILON * t.abs());
        let mut t = t_min;
        let mut prev: Option<(f32, f32)> = None; // (t, tsdf) of the last observed sample
        let mut cache = BlockCache::new();
        // the region the last sample lay in, and its allocated blocks
        let mut region: ([i32; 3], u64) = ([i32::MIN; 3], 0);
        while t < t_max {
            let p = origin + dir * t;
            let q = p.coords / vs + Vector3::repeat(0.5);
            let b = (q / BLOCK as f32).map(floor_i32);
            let b = [b.x, b.y, b.z];
            let r = region_of(b);
            if r != region.0 {
                region = (r, self.region_blocks(&r));
            }
            let cell = match region.1 {
                0 => REGION_VOXELS,
                mask if mask & region_bit(b) == 0 => BLOCK as f32,
                _ => 0.0,
            };
            if cell > 0.0 {
                prev = None;
                t += cell_exit(&q, &per_metre, cell) + nudge(t);
                continue;
            }
            let Some(f) = self.sample(&q, b, &mut cache) else {
                prev = None;
                t += vs;
                continue;
            };
            if let Some((tp, fp)) = prev {
                if fp > 0.0 && f <= 0.0 {
                    // linear zero crossing between the two samples, then the field's value, gradient
                    // (the normal) and colour there by trilinear interpolation
                    let mut ts = tp + (t - tp) * fp / (fp - f);
                    let (value, grad, color) =
                        self.trilinear_gradient_near(&(origin + dir * ts), &mut cache)?;
                    // one Newton step on the interpolated field along the ray; the normal and colour
                    // stay those sampled at the linear estimate, under a voxel away
                    let slope = grad.dot(dir) / vs;
                    if slope.abs() > 1e-6 {
                        let tn = ts - value / slope;
                        if (tn - ts).abs() < vs {
                            ts = tn;
                        }
                    }
                    return ray_hit(origin, dir, ts, &grad, &color);
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

    /// The surface near an expected distance `t_hint` along the ray from `origin` along the unit
    /// `dir`: Newton's method on the trilinear TSDF along the ray, from the hint. Where the hint is
    /// within the band of the surface the field is close to linear along the ray, so two or three
    /// samples reach the zero crossing; `None` (the caller marches instead) when a sample is
    /// unobserved or saturated, the surface is seen from behind, or the steps add up to more than
    /// μ. `cache` keeps the blocks of the previous rays of the row, as neighbouring rays share them.
    fn cast_near_hint<'a>(
        &'a self,
        origin: &Point3<f32>,
        dir: &Vector3<f32>,
        t_hint: f32,
        cache: &mut BlockCache<'a>,
    ) -> Option<RayHit> {
        let vs = self.params.voxel_size;
        let mu = self.params.truncation();
        let inv_vs = 1.0 / vs;
        let mut t = t_hint;
        let mut travelled = 0.0f32;
        for _ in 0..4 {
            let p = origin + dir * t;
            let (value, grad, color) = self.trilinear_gradient_near(&p, cache)?;
            // d(tsdf)/dt per metre: negative where the ray enters the surface from the front
            let slope = grad.dot(dir) * inv_vs;
            if value.abs() >= 1.0 || slope >= -1e-3 {
                return None;
            }
            let dt = -value / slope;
            travelled += dt.abs();
            if travelled > mu {
                return None;
            }
            t += dt;
            if dt.abs() < 0.05 * vs {
                return ray_hit(origin, dir, t, &grad, &color);
            }
        }
        None
    }

    /// Renders the model seen by `camera` at `pose` (camera-to-world) into `out`.
    pub fn raycast(&self, camera: &Camera, pose: &Isometry3<f64>, out: &mut RaycastMaps) {
        self.raycast_with_hint(camera, pose, None, out)
    }

    /// [`Self::raycast`], starting each ray near a depth it is expected to hit (`hint`: z-depth per
    /// pixel, e.g. the frame just fused; 0 = unknown, where the previous pixel's hit is used). A ray
    /// first takes Newton steps from its hint; if they fail it marches [z − μ − 2 voxels, z + 3μ],
    /// and if that finds no surface, the whole range. So the hint changes speed, not the surface
    /// found, but for one nearer than the hint's band (a surface the live frame did not see).
    ///
    /// Where the hint has a run of holes and the previous pixel found nothing either (a border
    /// the sensor does not measure, a view onto what the map has not seen), only every
    /// [`TsdfParams::hole_stride`]-th ray of the run marches the whole range. When one of them
    /// hits, the rays skipped before it are found from its depth as the pixels after it are, so a
    /// surface that spans the stride's pixels of the run is found on them as with a stride of 1;
    /// a narrower one between two marched rays is not.
    ///
    /// [`TsdfParams::hole_stride`]: super::TsdfParams::hole_stride
    pub fn raycast_with_hint(
        &self,
        camera: &Camera,
        pose: &Isometry3<f64>,
        hint: Option<&DepthImage>,
        out: &mut RaycastMaps,
    ) {
        let (w, h) = (camera.width, camera.height);
        out.vertices.resize(w, h, INVALID);
        out.normals.resize(w, h, INVALID);
        out.depth.resize(w, h, 0.0);
        out.colors.resize(w, h, [0; 3]);
        let rays = Rays::new(self, camera, pose);
        let hint = hint.filter(|d| d.width == w && d.height == h);
        out.vertices
            .data
            .par_chunks_mut(w)
            .zip(out.normals.data.par_chunks_mut(w))
            .zip(out.depth.data.par_chunks_mut(w))
            .zip(out.colors.data.par_chunks_mut(w))
            .enumerate()
            .for_each(|(y, (((vr, nr), dr), cr))| {
                let mut row = RowMaps { vr, nr, dr, cr };
                let hint = hint.map(|d| &d.data[y * w..(y + 1) * w]);
                rays.cast_row(y, hint, &mut row);
            });
    }
}

/// One row of the output maps.
struct RowMaps<'a> {
    vr: &'a mut [[f32; 3]],
    nr: &'a mut [[f32; 3]],
    dr: &'a mut [f32],
    cr: &'a mut [[u8; 3]],
}

impl RowMaps<'_> {
    /// Writes pixel `x`'s hit, or marks it missed.
    fn set(&mut self, x: usize, hit: Option<RayHit>, len: f32) {
        match hit {
            Some((p, n, c, t)) => {
                self.vr[x] = [p.x, p.y, p.z];
                self.nr[x] = [n.x, n.y, n.z];
                self.dr[x] = t / len;
                self.cr[x] = c;
            }
            None => {
                self.vr[x] = INVALID;
                self.nr[x] = INVALID;
                self.dr[x] = 0.0;
                self.cr[x] = [0; 3];
            }
        }
    }
}

/// The rays of a raycast: the camera's pixels seen from a pose, and the range they march.
struct Rays<'a> {
    volume: &'a TsdfVolume,
    camera: &'a Camera,
    origin: Point3<f32>,
    rot: nalgebra::Matrix3<f32>,
    t_min: f32,
    t_max: f32,
    /// How far past a hint its surface is looked for.
    band: f32,
    /// How far before a hint its surface is looked for.
    lead: f32,
    /// [`super::TsdfParams::hole_stride`], at least 1.
    stride: usize,
}

impl<'a> Rays<'a> {
    fn new(volume: &'a TsdfVolume, camera: &'a Camera, pose: &Isometry3<f64>) -> Self {
        let mu = volume.params.truncation();
        Self {
            volume,
            camera,
            origin: Point3::from(pose.translation.vector.cast::<f32>()),
            rot: pose
                .rotation
                .to_rotation_matrix()
                .into_inner()
                .cast::<f32>(),
            // Nothing beyond max_depth was fused: rays stop a truncation band past it.
            t_min: camera.depth_min as f32,
            t_max: volume.params.max_depth + 2.0 * mu,
            band: 3.0 * mu,
            // the hinted surface lies within the sensor noise of the hint: start just outside its
            // truncation band, where the stored distance lets the march take long steps at once
            lead: mu + 2.0 * volume.params.voxel_size,
            stride: volume.params.hole_stride.max(1),
        }
    }

    /// The unit direction (world frame) of pixel (x, y)'s ray, and the ray's length per unit of
    /// z-depth.
    fn ray(&self, x: usize, y: usize) -> (Vector3<f32>, f32) {
        let rc = self
            .camera
            .back_project(x as f64, y as f64, 1.0)
            .coords
            .cast::<f32>();
        let len = rc.norm();
        (self.rot * (rc / len), len)
    }

    /// The surface near z-depth `z` (> 0): Newton steps, then the band's march.
    fn near(
        &self,
        dir: &Vector3<f32>,
        len: f32,
        z: f32,
        cache: &mut BlockCache<'a>,
    ) -> Option<RayHit> {
        let v = self.volume;
        v.cast_near_hint(&self.origin, dir, z * len, cache)
            .or_else(|| {
                let (from, to) = ((z - self.lead).max(self.t_min), z + self.band);
                v.cast_ray(&self.origin, dir, from * len, to * len)
            })
    }

    /// The first surface along the whole range.
    fn whole(&self, dir: &Vector3<f32>, len: f32) -> Option<RayHit> {
        let (from, to) = (self.t_min * len, self.t_max * len);
        self.volume.cast_ray(&self.origin, dir, from, to)
    }

    /// Row `y`, with its hint's row (see [`TsdfVolume::raycast_with_hint`]).
    fn cast_row(&self, y: usize, hint: Option<&[f32]>, row: &mut RowMaps) {
        let mut cache = BlockCache::new();
        // pixels of the current run without a guess and without a hit so far
        let mut run = 0;
        for x in 0..row.dr.len() {
            let (dir, len) = self.ray(x, y);
            // where the hint has a hole, the surface the previous pixel of the row hit is
            // the best guess
            let z = match hint.map_or(0.0, |d| d[x]) {
                z if z > 0.0 || x == 0 || hint.is_none() => z,
                _ => row.dr[x - 1],
            };
            let hit = if z > self.t_max + self.band {
                None // the hint says the surface is beyond the fused range
            } else if z > 0.0 {
                self.near(&dir, len, z, &mut cache)
                    .or_else(|| self.whole(&dir, len))
            } else if hint.is_some() && run % self.stride != 0 {
                None // skipped in a run of holes
            } else {
                self.whole(&dir, len)
            };
            let found = hit.is_some();
            row.set(x, hit, len);
            if hint.is_some() && z == 0.0 && !found {
                run += 1;
            } else {
                if found && run > 0 {
                    // the run ends on a hit: the rays skipped since its last marched one
                    let skipped = (run - 1) % self.stride;
                    self.back_fill(y, x, skipped, row, &mut cache);
                }
                run = 0;
            }
        }
    }

    /// The `skipped` pixels before pixel `x`, a hit that ends a run of holes (a marched ray of
    /// the run, or a hinted pixel after it): each from its right neighbour's depth, until one
    /// finds nothing there.
    fn back_fill(
        &self,
        y: usize,
        x: usize,
        skipped: usize,
        row: &mut RowMaps,
        cache: &mut BlockCache<'a>,
    ) {
        for i in (x - skipped..x).rev() {
            let (dir, len) = self.ray(i, y);
            let hit = self.near(&dir, len, row.dr[i + 1], cache);
            if hit.is_none() {
                break;
            }
            row.set(i, hit, len);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// A step of `cell_exit` ends on a face of the cell holding the start (one coordinate on
        /// the face, the others within the cell), and a nudge past it is in a cell ahead.
        #[test]
        fn a_cell_exit_lands_on_the_cells_face(
            q in prop::array::uniform3(-100.0f32..100.0),
            d in prop::array::uniform3(-1.0f32..1.0),
            big in any::<bool>(),
        ) {
            let per_metre = Vector3::from(d) * 100.0;
            prop_assume!(per_metre.norm() > 1.0);
            let q = Vector3::from(q);
            let cell = if big { REGION_VOXELS } else { BLOCK as f32 };
            let of = |v: &Vector3<f32>| v.map(|x| floor_i32(x / cell));
            let exit = cell_exit(&q, &per_metre, cell);
            prop_assert!(exit.is_finite() && exit >= 0.0);
            let at = q + per_metre * exit;
            let lower = of(&q).map(|c| c as f32 * cell);
            let tol = 1e-3 * cell;
            let mut on_face = false;
            for i in 0..3 {
                prop_assert!(at[i] >= lower[i] - tol && at[i] <= lower[i] + cell + tol);
                let face = if per_metre[i] > 0.0 { lower[i] + cell } else { lower[i] };
                on_face |= per_metre[i] != 0.0 && (at[i] - face).abs() <= tol;
            }
            prop_assert!(on_face, "{at:?} is on no face of the cell at {lower:?}");
            // a hundredth of a voxel further on: in the next cell along the ray (across two or
            // three faces where the exit lies that near an edge or a corner)
            let past = q + per_metre * (exit + 0.01 / per_metre.norm());
            let moved = of(&past) - of(&q);
            prop_assert!(moved.abs().sum() >= 1, "no face crossed");
            for i in 0..3 {
                let ahead = per_metre[i].signum() as i32;
                prop_assert!(moved[i] == 0 || (per_metre[i] != 0.0 && moved[i] == ahead), "{moved:?}");
            }
        }
    }
}
