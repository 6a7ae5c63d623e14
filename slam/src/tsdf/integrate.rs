//! Fusing a depth frame (thesis eq. 3.23-3.25): allocate the blocks the truncation band crosses,
//! then update every voxel of the blocks in view with the projective signed distance.

use super::{
    block_key, block_of_key, floor_i32, local_index, Block, TsdfError, TsdfParams, TsdfVolume,
    BLOCK,
};
use crate::camera::Camera;
use crate::image::{ColorImage, DepthImage, NormalMap};
use nalgebra::{Isometry3, Vector3};
use rayon::prelude::*;
use rustc_hash::FxHashSet;
use std::sync::atomic::{AtomicUsize, Ordering};
use wide::{f32x8, i32x8};

/// The sensor model's axial noise at 1 m, the reference of the distance weight.
const SIGMA_1M: f32 = 0.0012 + 0.0019 * 0.6 * 0.6;

/// What one integration did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct IntegrateStats {
    /// Blocks allocated by this frame.
    pub new_blocks: usize,
    /// Blocks updated (in view).
    pub updated_blocks: usize,
    /// Blocks evicted to stay within the budget.
    pub evicted_blocks: usize,
}

impl TsdfVolume {
    /// The block coordinates the truncation band [d − μ, d + μ] of each valid pixel's ray crosses
    /// (every `step`-th pixel), sorted and deduplicated; an error if one lies beyond the range of
    /// block coordinates ([`super::MAX_BLOCK_COORD`]).
    fn touched_blocks(
        &self,
        depth: &DepthImage,
        camera: &Camera,
        pose: &Isometry3<f64>,
        step: usize,
    ) -> Result<Vec<[i32; 3]>, TsdfError> {
        let mu = self.params.truncation();
        let inv_block = 1.0 / (self.params.voxel_size * BLOCK as f32);
        let origin = pose.translation.vector.cast::<f32>() * inv_block;
        let rot = pose
            .rotation
            .to_rotation_matrix()
            .into_inner()
            .cast::<f32>();
        let (w, h) = (depth.width, depth.height);
        let max_depth = self.params.max_depth;
        let (ifx, ify) = (1.0 / camera.fx as f32, 1.0 / camera.fy as f32);
        let (cx, cy) = (camera.cx as f32, camera.cy as f32);
        // samples half a block apart along the band, in block units
        let n = ((2.0 * mu * inv_block) / 0.5).ceil() as usize + 1;
        let out_of_range = AtomicUsize::new(0);
        let mut keys: Vec<u64> = (0..h)
            .into_par_iter()
            .step_by(step)
            .flat_map_iter(|y| {
                let mut out = Vec::new();
                let ry = (y as f32 - cy) * ify;
                for x in (0..w).step_by(step) {
                    let d = depth.data[y * w + x];
                    // written so that NaN fails too
                    if !(d > 0.0 && d <= max_depth) {
                        continue;
                    }
                    // the ray through the pixel, scaled so that its camera-frame z is 1, in block
                    // units: a point at z-depth t lies at origin + dir · t
                    let dir = rot * Vector3::new((x as f32 - cx) * ifx, ry, 1.0) * inv_block;
                    let len = dir.norm() / inv_block;
                    // the band [d − μ, d + μ] along the ray, as z-depths
                    let (t0, t1) = (d - mu / len, d + mu / len);
                    let mut last = u64::MAX;
                    for k in 0..=n {
                        let t = t0 + (t1 - t0) * k as f32 / n as f32;
                        let p = origin + dir * t;
                        match block_key(floor_i32(p.x), floor_i32(p.y), floor_i32(p.z)) {
                            Some(key) if key != last => {
                                out.push(key);
                                last = key;
                            }
                            Some(_) => {}
                            None => {
                                out_of_range.fetch_add(1, Ordering::Relaxed);
                            }
                        }
                    }
                }
                out
            })
            .collect();
        if out_of_range.into_inner() > 0 {
            return Err(TsdfError::OutOfRange {
                position: pose.translation.vector.into(),
            });
        }
        keys.par_sort_unstable();
        keys.dedup();
        Ok(keys.into_iter().map(block_of_key).collect())
    }

    /// Allocates the missing blocks among `touched` (within the budget) and marks exactly the
    /// `touched` blocks active for this frame: the surface and the free space just in front of it
    /// (voxel hashing's "visible set"; far free space keeps its last value). Returns the number of
    /// blocks allocated and evicted.
    ///
    /// When the budget would be exceeded and `camera` (the viewpoint, in the volume's frame) is
    /// given and eviction is on, the untouched blocks farthest from it are dropped first (down to
    /// 15/16 of the budget, so that eviction is rare), as voxel hashing streams blocks out of the
    /// GPU; otherwise the frame fails with [`TsdfError::BudgetExceeded`].
    fn allocate(
        &mut self,
        touched: &[[i32; 3]],
        camera: Option<Vector3<f32>>,
    ) -> Result<(usize, usize), TsdfError> {
        let missing = touched
            .iter()
            .filter(|c| !self.index.contains_key(*c))
            .count();
        let max = self.params.max_blocks;
        let mut evicted = 0;
        if self.blocks.len() + missing > max {
            let needed = self.blocks.len() + missing;
            match camera {
                Some(eye) if self.params.evict && touched.len() <= max => {
                    let keep = (max - max / 16).max(touched.len()).min(max) - missing;
                    evicted = self.evict(touched, &eye, keep);
                }
                _ => return Err(TsdfError::BudgetExceeded { needed, max }),
            }
        }
        for c in touched {
            if !self.index.contains_key(c) {
                let block = match self.spare.pop() {
                    Some(mut b) => {
                        b.reset(*c);
                        b
                    }
                    None => Block::new(*c),
                };
                self.blocks.push(block);
                self.index_block(*c);
            }
        }
        self.active.clear();
        self.active.resize(self.blocks.len(), false);
        for c in touched {
            self.active[self.index[c] as usize] = true;
        }
        Ok((missing, evicted))
    }

    /// Drops blocks not in `touched` (sorted), farthest from `eye` first, until at most `keep`
    /// remain (never a touched one); their storage goes to the spare pool that later allocations
    /// take from, so a long run's memory stays flat. Returns how many were dropped.
    fn evict(&mut self, touched: &[[i32; 3]], eye: &Vector3<f32>, keep: usize) -> usize {
        let block_size = self.params.voxel_size * BLOCK as f32;
        let mut far: Vec<(f32, u32)> = self
            .blocks
            .iter()
            .enumerate()
            .filter(|(_, b)| touched.binary_search(&b.coord).is_err())
            .map(|(i, b)| {
                let c = Vector3::new(
                    b.coord[0] as f32 + 0.5,
                    b.coord[1] as f32 + 0.5,
                    b.coord[2] as f32 + 0.5,
                ) * block_size;
                ((c - eye).norm_squared(), i as u32)
            })
            .collect();
        let drop = self.blocks.len().saturating_sub(keep).min(far.len());
        if drop == 0 {
            return 0;
        }
        far.select_nth_unstable_by(drop - 1, |a, b| b.0.total_cmp(&a.0));
        let mut gone = vec![false; self.blocks.len()];
        for &(_, i) in &far[..drop] {
            gone[i as usize] = true;
        }
        let blocks = std::mem::take(&mut self.blocks);
        self.index.clear();
        self.regions.clear();
        for (b, g) in blocks.into_iter().zip(gone) {
            if g {
                self.spare.push(b);
            } else {
                let coord = b.coord;
                self.blocks.push(b);
                self.index_block(coord);
            }
        }
        self.evicted += drop;
        tracing::debug!(
            evicted = drop,
            kept = self.blocks.len(),
            "TSDF budget reached: far blocks evicted"
        );
        drop
    }

    /// Each pixel's sample for fusion, once per frame, into `self.samples`: its depth and fusion
    /// weight cos θ (≥ 0.1) · (σ(1 m)/σ(z))², θ between the pixel's ray and its normal (0.1 where
    /// the normal is missing); [0, 0] where the depth is missing or beyond the fusion range, and one
    /// more such entry at the end, the sample of voxels that project nowhere. With colour, each
    /// pixel's colour packed as `r | g << 8 | b << 16` into `self.sample_color`.
    fn pixel_samples(
        &mut self,
        depth: &DepthImage,
        normals: &NormalMap,
        color: Option<&ColorImage>,
        camera: &Camera,
    ) {
        let w = depth.width;
        let n = w * depth.height;
        let (ifx, ify) = (1.0 / camera.fx as f32, 1.0 / camera.fy as f32);
        let (cx, cy) = (camera.cx as f32, camera.cy as f32);
        let max_depth = self.params.max_depth;
        self.samples.resize(n + 1, [0.0; 2]);
        self.samples[n] = [0.0; 2];
        self.samples[..n]
            .par_chunks_mut(w.max(1))
            .enumerate()
            .for_each(|(y, row)| {
                let ry = (y as f32 - cy) * ify;
                let (d_row, n_row) = (
                    &depth.data[y * w..(y + 1) * w],
                    &normals.data[y * w..(y + 1) * w],
                );
                for (x, (o, (&d, n))) in row.iter_mut().zip(d_row.iter().zip(n_row)).enumerate() {
                    let rx = (x as f32 - cx) * ifx;
                    // −ray · n over |ray|: NaN for a missing normal, which the test below takes
                    // as grazing
                    let c = -(rx * n[0] + ry * n[1] + n[2]) / (rx * rx + ry * ry + 1.0).sqrt();
                    let cos = if c >= 0.1 { c.min(1.0) } else { 0.1 };
                    let sigma = 0.0012 + 0.0019 * (d - 0.4) * (d - 0.4);
                    let weight = cos * (SIGMA_1M / sigma) * (SIGMA_1M / sigma);
                    // written so that NaN fails too
                    *o = if d > 0.0 && d <= max_depth {
                        [d, weight]
                    } else {
                        [0.0; 2]
                    };
                }
            });
        if let Some(c) = color {
            self.sample_color.resize(n + 1, 0);
            self.sample_color[..n]
                .par_chunks_mut(w.max(1))
                .zip(c.data.par_chunks(w.max(1)))
                .for_each(|(out, row)| {
                    for (o, p) in out.iter_mut().zip(row) {
                        *o = p[0] as u32 | (p[1] as u32) << 8 | (p[2] as u32) << 16;
                    }
                });
        }
    }

    /// Fuses a frame: `depth` in metres (0 where missing) seen by `camera` at `pose`
    /// (camera-to-world), with its camera-frame `normals` (for the viewing-angle weight) and optional
    /// colour. The projective signed distance `sdf = D(u) − z` of each voxel in view is truncated to
    /// μ and averaged with the stored value under the weight `cos θ · (σ(1 m)/σ(z))²`: the cosine
    /// between the pixel's ray and normal (at least 0.1) times the inverse axial noise variance of the
    /// sensor model (σ(z) = 0.0012 + 0.0019 (z − 0.4)², Nguyen et al. 2012), so near, frontal views
    /// dominate. Weights are capped at W_max. Colour is fused with the same weights.
    pub fn integrate(
        &mut self,
        depth: &DepthImage,
        normals: &NormalMap,
        color: Option<&ColorImage>,
        camera: &Camera,
        pose: &Isometry3<f64>,
    ) -> Result<IntegrateStats, TsdfError> {
        check_sizes(depth, normals, color, camera)?;
        let touched = self.touched_blocks(depth, camera, pose, 4)?;
        let eye = pose.translation.vector.cast::<f32>();
        let (new_blocks, evicted_blocks) = self.allocate(&touched, Some(eye))?;
        self.pixel_samples(depth, normals, color, camera);
        let params = self.params;
        let view = BlockProjection::new(camera, pose, &params, (depth.width, depth.height));
        let updated = std::sync::atomic::AtomicUsize::new(0);
        let active = &self.active;
        let frame = FrameView::new(
            &self.samples,
            color.map(|_| &self.sample_color[..]),
            &params,
        );
        self.blocks
            .par_iter_mut()
            .enumerate()
            .for_each(|(bi, blk)| {
                if active[bi] && view.sees(blk) && view.fuse(blk, &frame) {
                    updated.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
            });
        Ok(IntegrateStats {
            new_blocks,
            updated_blocks: updated.into_inner(),
            evicted_blocks,
        })
    }
}

/// Depth, normals and colour must all be the camera's size.
fn check_sizes(
    depth: &DepthImage,
    normals: &NormalMap,
    color: Option<&ColorImage>,
    camera: &Camera,
) -> Result<(), TsdfError> {
    let sizes = [(depth.width, depth.height), (normals.width, normals.height)];
    for size in sizes.into_iter().chain(color.map(|c| (c.width, c.height))) {
        if size != (camera.width, camera.height) {
            return Err(TsdfError::Size {
                image: size,
                camera: (camera.width, camera.height),
            });
        }
    }
    Ok(())
}

/// The frame's camera as the blocks see it: world to camera, the intrinsics, the image's size, and
/// the block's bounding sphere.
struct BlockProjection {
    rot: nalgebra::Matrix3<f32>,
    trans: Vector3<f32>,
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    /// The image's width and height, and the sample index past the last pixel.
    w: i32,
    h: i32,
    none: i32,
    voxel_size: f32,
    block_size: f32,
    half_diag: f32,
    /// The farthest distance a block in view may hold: the largest depth plus μ.
    far: f32,
}

impl BlockProjection {
    fn new(
        camera: &Camera,
        pose: &Isometry3<f64>,
        params: &TsdfParams,
        (w, h): (usize, usize),
    ) -> Self {
        let inv = pose.inverse();
        let block_size = params.voxel_size * BLOCK as f32;
        Self {
            rot: inv.rotation.to_rotation_matrix().into_inner().cast::<f32>(),
            trans: inv.translation.vector.cast::<f32>(),
            fx: camera.fx as f32,
            fy: camera.fy as f32,
            cx: camera.cx as f32,
            cy: camera.cy as f32,
            w: w as i32,
            h: h as i32,
            none: (w * h) as i32,
            voxel_size: params.voxel_size,
            block_size,
            half_diag: block_size * 0.5 * 3f32.sqrt(),
            far: params.max_depth + params.truncation(),
        }
    }

    /// Whether the block's bounding sphere may meet the view frustum (depth range and image).
    #[inline]
    fn sees(&self, blk: &Block) -> bool {
        let centre = Vector3::new(
            blk.coord[0] as f32 + 0.5,
            blk.coord[1] as f32 + 0.5,
            blk.coord[2] as f32 + 0.5,
        ) * self.block_size
            - Vector3::repeat(0.5 * self.voxel_size);
        let pc = self.rot * centre + self.trans;
        let half_diag = self.half_diag;
        if pc.z + half_diag <= 0.0 || pc.z - half_diag > self.far {
            return false;
        }
        if pc.z > half_diag {
            let (u, v) = (
                self.fx * pc.x / pc.z + self.cx,
                self.fy * pc.y / pc.z + self.cy,
            );
            let margin = (half_diag / pc.z) * self.fx.abs().max(self.fy.abs());
            let (w, h) = (self.w as f32, self.h as f32);
            if u < -margin || v < -margin || u > w + margin || v > h + margin {
                return false;
            }
        }
        true
    }

    /// Fuses every voxel of `blk` from `frame`, a row of eight at a time: each voxel centre is
    /// taken to the camera, projected to its nearest pixel (a voxel behind the camera or outside
    /// the image gets the empty sample past the last pixel). Returns whether any voxel changed.
    #[inline]
    fn fuse(&self, blk: &mut Block, frame: &FrameView) -> bool {
        let (rot, trans, voxel_size) = (&self.rot, &self.trans, self.voxel_size);
        let mut any = false;
        let base = [
            blk.coord[0] * BLOCK,
            blk.coord[1] * BLOCK,
            blk.coord[2] * BLOCK,
        ];
        // voxel (x, y, z) of the block in the camera frame: q0 + x c0 + y c1 + z c2
        let q0 = rot * (Vector3::new(base[0] as f32, base[1] as f32, base[2] as f32) * voxel_size)
            + trans;
        let (c0, c1, c2) = (
            rot.column(0) * voxel_size,
            rot.column(1) * voxel_size,
            rot.column(2) * voxel_size,
        );
        // the x-steps of a row, eight lanes at once
        let steps = f32x8::new(std::array::from_fn(|k| k as f32));
        let row = [c0.x, c0.y, c0.z].map(|c| f32x8::splat(c) * steps);
        let (w, h, none) = (self.w, self.h, self.none);
        for z in 0..BLOCK {
            for y in 0..BLOCK {
                let qyz = q0 + c1 * y as f32 + c2 * z as f32;
                let [qx, qy, qz] = std::array::from_fn(|i| f32x8::splat(qyz[i]) + row[i]);
                let front = qz.simd_gt(f32x8::ZERO);
                let iz = f32x8::ONE / qz;
                let pixel = |f: f32, q: f32x8, c: f32| {
                    let p = f32x8::splat(f) * q * iz + f32x8::splat(c + 0.5);
                    // ⌊p + ½⌋, the nearest pixel; −1 behind the camera
                    front.select(p, f32x8::splat(-1.0)).floor().trunc_int()
                };
                let (u, v) = (pixel(self.fx, qx, self.cx), pixel(self.fy, qy, self.cy));
                let inside = u.simd_ge(i32x8::ZERO)
                    & v.simd_ge(i32x8::ZERO)
                    & u.simd_lt(i32x8::splat(w))
                    & v.simd_lt(i32x8::splat(h));
                // lanes outside are zeroed before the product, which then cannot overflow
                let (u, v) = (inside.select(u, i32x8::ZERO), inside.select(v, i32x8::ZERO));
                let index = inside.select(v * i32x8::splat(w) + u, i32x8::splat(none));
                let pixels = index.to_array().map(|i| i as u32);
                any |= frame.fuse_row(blk, local_index(0, y, z), &pixels, &qz.to_array());
            }
        }
        any
    }
}

/// One frame as the voxel updates read it: per pixel, and one empty sample past the last.
struct FrameView<'a> {
    samples: &'a [[f32; 2]],
    color: Option<&'a [u32]>,
    mu: f32,
    max_weight: f32,
}

impl<'a> FrameView<'a> {
    fn new(samples: &'a [[f32; 2]], color: Option<&'a [u32]>, params: &TsdfParams) -> Self {
        Self {
            samples,
            color,
            mu: params.truncation(),
            max_weight: params.max_weight,
        }
    }

    /// Fuses the 8 voxels of a row of `blk` from local index `i0`, whose centres lie at `depths`
    /// in the camera frame and project to `pixels` (the index past the last pixel: none): the
    /// projective signed distance `D(u) − z`, truncated to μ (voxels more than μ behind the surface
    /// are left alone), enters a running weighted average (eq. 3.23-3.25) with the pixel's weight,
    /// colour with it; the stored weight is capped at W_max. The eight voxels are the lanes of one
    /// SIMD vector (`wide`'s `f32x8`: the compiler did not vectorise the plain loop over the
    /// interleaved distance and weight). A voxel not updated takes weight 0, which leaves it as it
    /// was. Returns whether any voxel was updated.
    #[inline(always)]
    fn fuse_row(
        &self,
        blk: &mut Block,
        i0: usize,
        pixels: &[u32; BLOCK as usize],
        depths: &[f32; BLOCK as usize],
    ) -> bool {
        const N: usize = BLOCK as usize;
        // in phases: the samples gathered, the row's distances and weights read apart, updated as
        // vectors, and written back
        let last = self.samples.len() - 1;
        let (mut d, mut pw) = ([0.0f32; N], [0.0f32; N]);
        for k in 0..N {
            [d[k], pw[k]] = self.samples[(pixels[k] as usize).min(last)];
        }
        let voxels = &mut blk.voxels[i0..i0 + N];
        let (mut t, mut w) = ([0.0f32; N], [0.0f32; N]);
        for k in 0..N {
            (t[k], w[k]) = (voxels[k].tsdf, voxels[k].weight);
        }
        // the new sample's share of each voxel's value, and whether it enters at all
        let zero = f32x8::ZERO;
        let (d, pw, z) = (f32x8::new(d), f32x8::new(pw), f32x8::new(*depths));
        let (t_old, w_old) = (f32x8::new(t), f32x8::new(w));
        let sdf = d - z;
        let ok = pw.simd_gt(zero) & sdf.simd_ge(f32x8::splat(-self.mu));
        let weight = ok.select(pw, zero);
        let sum = w_old + weight;
        let b = ok.select(weight / sum, zero);
        let t_new = t_old + ((sdf * f32x8::splat(1.0 / self.mu)).min(f32x8::ONE) - t_old) * b;
        // a stored weight never exceeds W_max, so a voxel not updated (weight 0) keeps its own
        let w_new = sum.min(f32x8::splat(self.max_weight));
        let (t, w) = (t_new.to_array(), w_new.to_array());
        // b is in [0, 1]: the share is in [0, 256]
        let share = (b * f32x8::splat(256.0) + f32x8::splat(0.5)).trunc_int();
        for k in 0..N {
            voxels[k].tsdf = t[k];
            voxels[k].weight = w[k];
        }
        if let Some(c) = self.color {
            // per channel (old (256 − s) + new s + 128) / 256: within [0, 255], and old where s = 0
            let colors = &mut blk.color[i0..i0 + N];
            let last = c.len() - 1;
            let new = i32x8::new(std::array::from_fn(|k| {
                c[(pixels[k] as usize).min(last)] as i32
            }));
            let old = i32x8::new(std::array::from_fn(|k| {
                u32::from_le_bytes(colors[k]) as i32
            }));
            let (keep, byte) = (i32x8::splat(256) - share, i32x8::splat(0xff));
            let mut blend = i32x8::ZERO;
            for shift in [0, 8, 16] {
                let (o, n) = ((old >> shift) & byte, (new >> shift) & byte);
                blend |= ((o * keep + n * share + i32x8::splat(128)) >> 8) << shift;
            }
            for (out, v) in colors.iter_mut().zip(blend.to_array()) {
                *out = (v as u32).to_le_bytes();
            }
        }
        ok.any()
    }
}

/// A map of the volume's (canonical) space into a live camera frame, voxel by voxel: the warp of
/// non-rigid fusion (Newcombe et al., *DynamicFusion*, CVPR 2015, sec. 3.3), where each voxel
/// centre is carried into the live frame before the projective signed distance is taken.
pub trait VoxelWarp: Sync {
    /// Per-thread scratch, reused from block to block.
    type Scratch: Send + Default;
    /// Prepares the warp of the voxels of block `block` (volume frame; voxel (x, y, z) of it is
    /// the volume's voxel `block · BLOCK + (x, y, z)`). `false` leaves the block alone (nothing
    /// there can be warped reliably).
    fn prepare(&self, block: [i32; 3], scratch: &mut Self::Scratch) -> bool;
    /// Where the centre `p` of voxel `voxel` (index `x + 8 (y + 8 z)` in the prepared block) lands
    /// in the live camera frame, `None` for a voxel that cannot be warped reliably.
    fn warp(&self, voxel: usize, p: &Vector3<f64>, scratch: &Self::Scratch)
        -> Option<Vector3<f64>>;
}

/// Points per task of [`TsdfVolume::blocks_near`].
const NEAR_CHUNK: usize = 2048;

impl TsdfVolume {
    /// The blocks within μ + m of any point p of `points` (pairs (p, m): volume frame, metres;
    /// per axis), sorted and deduplicated: the blocks [`Self::integrate_warped`] updates for a
    /// live surface carried back into the volume's frame. The margin m covers the surface
    /// between the points where they sample it sparsely.
    pub fn blocks_near(&self, points: &[(Vector3<f64>, f64)]) -> Vec<[i32; 3]> {
        let truncation = self.params.truncation() as f64;
        let block_size = (self.params.voxel_size * BLOCK as f32) as f64;
        // neighbouring points share their blocks: each chunk collects its own set, so the
        // candidates are deduplicated as they are found instead of sorted all together
        let found = points
            .par_chunks(NEAR_CHUNK)
            .fold(FxHashSet::default, |mut set, chunk| {
                for (p, margin) in chunk
                    .iter()
                    .filter(|(p, m)| p.iter().all(|v| v.is_finite()) && m.is_finite())
                {
                    let mu = truncation + margin.max(0.0);
                    let lo = p.map(|v| ((v - mu) / block_size).floor() as i32);
                    let hi = p.map(|v| ((v + mu) / block_size).floor() as i32);
                    for z in lo.z..=hi.z {
                        for y in lo.y..=hi.y {
                            set.extend((lo.x..=hi.x).map(|x| [x, y, z]));
                        }
                    }
                }
                set
            })
            .reduce(FxHashSet::default, |mut a, b| {
                a.extend(b);
                a
            });
        let mut coords: Vec<[i32; 3]> = found.into_iter().collect();
        coords.sort_unstable();
        coords
    }

    /// Fuses a live frame through a non-rigid warp (DynamicFusion, sec. 3.3): the blocks `touched`
    /// (each once; [`Self::blocks_near`] the live surface carried back into the volume's frame)
    /// are allocated and updated;
    /// each of their voxel centres is warped into the live camera frame, projected, and its
    /// projective signed distance `D(u) − z` fused as in [`Self::integrate`], with the same weights.
    pub fn integrate_warped<W: VoxelWarp>(
        &mut self,
        depth: &DepthImage,
        normals: &NormalMap,
        color: Option<&ColorImage>,
        camera: &Camera,
        touched: &[[i32; 3]],
        warp: &W,
    ) -> Result<IntegrateStats, TsdfError> {
        check_sizes(depth, normals, color, camera)?;
        // no viewpoint in the canonical frame to evict by: a full budget is an error here
        let (new_blocks, evicted_blocks) = self.allocate(touched, None)?;
        self.pixel_samples(depth, normals, color, camera);
        let params = self.params;
        let none = (depth.width * depth.height) as u32;
        let voxel = params.voxel_size as f64;
        let updated = std::sync::atomic::AtomicUsize::new(0);
        let active = &self.active;
        let frame = FrameView::new(
            &self.samples,
            color.map(|_| &self.sample_color[..]),
            &params,
        );
        self.blocks.par_iter_mut().enumerate().for_each_init(
            W::Scratch::default,
            |scratch, (bi, blk)| {
                if !active[bi] {
                    return;
                }
                let base = Vector3::new(
                    (blk.coord[0] * BLOCK) as f64,
                    (blk.coord[1] * BLOCK) as f64,
                    (blk.coord[2] * BLOCK) as f64,
                ) * voxel;
                if !warp.prepare(blk.coord, scratch) {
                    return;
                }
                let mut any = false;
                for z in 0..BLOCK {
                    for y in 0..BLOCK {
                        // the row's voxels carried into the live frame and projected (the empty
                        // sample past the last pixel: not warped or not in the image)
                        let mut pixels = [none; BLOCK as usize];
                        let mut depths = [0.0f32; BLOCK as usize];
                        for x in 0..BLOCK {
                            let p = base + Vector3::new(x as f64, y as f64, z as f64) * voxel;
                            let Some(q) = warp.warp(local_index(x, y, z), &p, scratch) else {
                                continue;
                            };
                            let Some((u, v)) = camera.project_to_pixel(&q.into()) else {
                                continue;
                            };
                            pixels[x as usize] = (v * depth.width + u) as u32;
                            depths[x as usize] = q.z as f32;
                        }
                        any |= frame.fuse_row(blk, local_index(0, y, z), &pixels, &depths);
                    }
                }
                if any {
                    updated.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
            },
        );
        Ok(IntegrateStats {
            new_blocks,
            updated_blocks: updated.into_inner(),
            evicted_blocks,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::{region_bit, region_of};
    use super::*;
    use crate::image::Image;

    /// The blocks near points with margins are those whose extent meets a point's box of half
    /// side μ + margin, found by testing every block of the span; points that are not finite, or
    /// whose margin is not, find none.
    #[test]
    fn blocks_near_are_the_blocks_each_points_box_meets() {
        use rand::{RngExt, SeedableRng};
        let vol = TsdfVolume::new(TsdfParams::default());
        let (mu, size) = (
            vol.params.truncation() as f64,
            (vol.params.voxel_size * BLOCK as f32) as f64,
        );
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut points: Vec<(Vector3<f64>, f64)> = (0..3000)
            .map(|_| {
                let p = Vector3::new(
                    rng.random_range(-0.5..0.5),
                    rng.random_range(-0.3..0.3),
                    rng.random_range(0.5..0.9),
                );
                (p, rng.random_range(-0.01..0.05))
            })
            .collect();
        points.push((Vector3::new(f64::NAN, 0.0, 0.0), 0.0));
        points.push((Vector3::new(9.0, 9.0, 9.0), f64::INFINITY));
        let found = vol.blocks_near(&points);
        let mut expected = Vec::new();
        for z in -2..14 {
            for y in -7..7 {
                for x in -10..10 {
                    let meets = points[..3000].iter().any(|(p, m)| {
                        let r = mu + m.max(0.0);
                        (0..3).all(|k| {
                            let lo = [x, y, z][k] as f64 * size;
                            lo <= p[k] + r && lo + size > p[k] - r
                        })
                    });
                    if meets {
                        expected.push([x, y, z]);
                    }
                }
            }
        }
        expected.sort_unstable();
        assert_eq!(found, expected);
    }

    /// Every region's mask holds exactly the bits of its allocated blocks.
    fn masks_match_blocks(vol: &TsdfVolume) {
        let mut expected: rustc_hash::FxHashMap<[i32; 3], u64> = Default::default();
        for b in vol.blocks() {
            *expected.entry(region_of(b.coord)).or_insert(0) |= region_bit(b.coord);
        }
        assert_eq!(vol.regions, expected);
    }

    /// A wall fused from three places, under a budget that the third view's blocks overflow: the
    /// region masks follow allocation and eviction.
    #[test]
    fn region_masks_follow_allocation_and_eviction() {
        let cam = Camera::new(131.25, 131.25, 79.5, 59.5, 160, 120);
        // a wall square to the camera 1 m ahead, its normals facing the camera
        let depth: Image<f32> = Image::filled(160, 120, 1.0);
        let n = Image::filled(160, 120, [0.0f32, 0.0, -1.0]);
        let mut vol = TsdfVolume::new(TsdfParams::default());
        let at = |x: f64| Isometry3::translation(x, 0.0, 0.0);
        vol.integrate(&depth, &n, None, &cam, &at(0.0)).unwrap();
        masks_match_blocks(&vol);
        let one_view = vol.num_blocks();
        vol.params.max_blocks = 2 * one_view;
        vol.integrate(&depth, &n, None, &cam, &at(3.0)).unwrap();
        masks_match_blocks(&vol);
        vol.integrate(&depth, &n, None, &cam, &at(-3.0)).unwrap();
        assert!(vol.evicted_blocks() > 0, "the third view evicts");
        masks_match_blocks(&vol);
    }
}
