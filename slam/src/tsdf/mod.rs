//! The map: a voxel-hashed truncated signed distance field (Curless & Levoy 1996; Newcombe et al.,
//! KinectFusion, 2011; Nießner et al., *Real-time 3D reconstruction at scale using voxel hashing*,
//! 2013; thesis sec. 2.8 and 3.3).
//!
//! Space is cut into blocks of 8³ voxels, allocated only where a depth ray's truncation band passes
//! and kept in a hash map keyed by block coordinate, so memory follows the observed surface. Each
//! voxel holds a truncated signed distance in [−1, 1] (units of the truncation μ), a weight and a
//! colour. [`TsdfVolume::integrate`] fuses a depth frame, [`TsdfVolume::raycast`] renders the model
//! from any pose, and [`TsdfVolume::extract_mesh`] runs marching cubes.

mod integrate;
mod mesh;
mod raycast;

pub use integrate::{IntegrateStats, VoxelWarp};
pub use raycast::RaycastMaps;

use nalgebra::{Point3, Vector3};
use rustc_hash::FxHashMap;
use thiserror::Error;

/// Voxels along a block edge.
pub(crate) const BLOCK: i32 = 8;
/// Voxels in a block.
pub(crate) const BLOCK_VOXELS: usize = 512;
/// Blocks along a region edge: the volume keeps a mask of its allocated blocks per region of 4³
/// blocks, so that a ray crosses a region without any in one step.
pub(crate) const REGION: i32 = 4;

/// The smallest voxel edge a volume is meant to be given, metres: 0.1 mm, below the depth
/// resolution of any RGB-D sensor. The ray march steps by voxels, so below it one frame's
/// raycast takes minutes (at 0.01 mm, 20 frames of 320 × 240 did not finish in two minutes);
/// the applications and the Python bindings refuse smaller voxels ([`usable_voxel_size`]).
pub const MIN_VOXEL_SIZE: f32 = 1e-4;

/// The largest voxel edge a volume is meant to be given, metres: a block of eight is then
/// already twice the default depth range.
pub const MAX_VOXEL_SIZE: f32 = 1.0;

/// Whether `voxel_size` lies in [`MIN_VOXEL_SIZE`, `MAX_VOXEL_SIZE`] (compared in single
/// precision, as [`TsdfParams::voxel_size`] is stored, so that 0.0001 as given is in).
pub fn usable_voxel_size(voxel_size: f32) -> bool {
    (MIN_VOXEL_SIZE..=MAX_VOXEL_SIZE).contains(&voxel_size)
}

/// Settings of the volume.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TsdfParams {
    /// Voxel edge, metres (default 1 cm).
    pub voxel_size: f32,
    /// Truncation μ in voxels (default 4).
    pub truncation_voxels: f32,
    /// Weight cap W_max (default 64): the model follows a changed scene after about this many frames.
    pub max_weight: f32,
    /// Most blocks that may be allocated (default 150 000, about 0.8 GiB).
    pub max_blocks: usize,
    /// When the budget is reached, evict the blocks farthest from the camera (default true);
    /// otherwise the frame fails with [`TsdfError::BudgetExceeded`].
    pub evict: bool,
    /// Depths beyond this are not fused, metres (default 4).
    pub max_depth: f32,
    /// In a run of holes in a raycast's hint, every how many rays march the whole range (default
    /// 4; 1 marches them all): see [`TsdfVolume::raycast_with_hint`].
    pub hole_stride: usize,
}

impl Default for TsdfParams {
    fn default() -> Self {
        Self {
            voxel_size: 0.01,
            truncation_voxels: 4.0,
            max_weight: 64.0,
            max_blocks: 150_000,
            evict: true,
            max_depth: 4.0,
            hole_stride: 4,
        }
    }
}

impl TsdfParams {
    /// The truncation distance μ in metres.
    pub fn truncation(&self) -> f32 {
        self.voxel_size * self.truncation_voxels
    }
}

/// One voxel's fused distance and weight (thesis eq. 3.24-3.25).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Voxel {
    /// Truncated signed distance, in units of μ (1 where unobserved).
    pub tsdf: f32,
    /// Fusion weight (0 where unobserved).
    pub weight: f32,
}

impl Voxel {
    /// The distance, if the voxel was observed (its weight is positive).
    #[inline]
    pub fn observed(&self) -> Option<f32> {
        (self.weight > 0.0).then_some(self.tsdf)
    }
}

/// A block of 8³ voxels (voxel hashing's unit of allocation).
#[derive(Clone, Debug)]
pub struct Block {
    /// Block coordinate (voxel coordinate / 8).
    pub coord: [i32; 3],
    /// Distance and weight per voxel, interleaved so that reading a voxel touches one cache line.
    pub voxels: Box<[Voxel; BLOCK_VOXELS]>,
    /// Fused colour per voxel, RGB and a padding byte (apart: only surface hits and meshes read
    /// it; one 32-bit word a voxel, so that fusion blends a row of eight at once).
    pub color: Box<[[u8; 4]; BLOCK_VOXELS]>,
}

impl Block {
    /// Unobserved voxels at `coord`, in storage taken from an evicted block.
    fn reset(&mut self, coord: [i32; 3]) {
        self.coord = coord;
        self.voxels.fill(Voxel {
            tsdf: 1.0,
            weight: 0.0,
        });
        self.color.fill([0; 4]);
    }

    fn new(coord: [i32; 3]) -> Self {
        Self {
            coord,
            voxels: Box::new(
                [Voxel {
                    tsdf: 1.0,
                    weight: 0.0,
                }; BLOCK_VOXELS],
            ),
            color: Box::new([[0; 4]; BLOCK_VOXELS]),
        }
    }
}

/// The last few blocks looked up (allocated or not), so that neighbouring samples (along a ray,
/// of neighbouring rays, of a cell's corners) skip the hash map; replaced round-robin.
pub(crate) struct BlockCache<'a> {
    coords: [[i32; 3]; 8],
    blocks: [Option<&'a Block>; 8],
    last: usize,
    next: usize,
}

impl<'a> BlockCache<'a> {
    /// An empty cache.
    pub(crate) fn new() -> Self {
        Self {
            coords: [[i32::MIN; 3]; 8],
            blocks: [None; 8],
            last: 0,
            next: 0,
        }
    }

    /// The block at `coord` in `volume`, `None` where unallocated.
    #[inline(always)]
    pub(crate) fn get(&mut self, volume: &'a TsdfVolume, coord: [i32; 3]) -> Option<&'a Block> {
        let hit = self.coords[self.last];
        if (hit[0] == coord[0]) & (hit[1] == coord[1]) & (hit[2] == coord[2]) {
            return self.blocks[self.last];
        }
        self.miss(volume, coord)
    }

    /// [`Self::get`] past the last block used.
    #[inline(never)]
    fn miss(&mut self, volume: &'a TsdfVolume, coord: [i32; 3]) -> Option<&'a Block> {
        if let Some(k) = self.coords.iter().position(|c| *c == coord) {
            self.last = k;
            return self.blocks[k];
        }
        let k = self.next;
        self.next = (k + 1) % self.coords.len();
        self.coords[k] = coord;
        self.blocks[k] = volume.block(&coord);
        self.last = k;
        self.blocks[k]
    }
}

/// Index of local voxel (x, y, z) in a block.
#[inline]
pub(crate) fn local_index(x: i32, y: i32, z: i32) -> usize {
    (x + BLOCK * (y + BLOCK * z)) as usize
}

/// Errors of the map.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum TsdfError {
    /// Allocation would exceed the block budget.
    #[error("the TSDF block budget is exhausted: {needed} blocks needed, {max} allowed (raise max_blocks or the voxel size)")]
    BudgetExceeded {
        /// Blocks the frame needs in all.
        needed: usize,
        /// The budget.
        max: usize,
    },
    /// The camera is so far from the origin that the surface it sees lies beyond the range of
    /// block coordinates ([`MAX_BLOCK_COORD`]).
    #[error(
        "the camera at {position:?} sees beyond the volume's range of ±{} blocks per axis",
        MAX_BLOCK_COORD
    )]
    OutOfRange {
        /// The camera's position, metres.
        position: [f64; 3],
    },
    /// Images and intrinsics of different sizes.
    #[error("a {image:?} image does not match the camera's {camera:?}")]
    Size {
        /// Width and height of the image.
        image: (usize, usize),
        /// Width and height of the camera.
        camera: (usize, usize),
    },
}

/// The voxel-hashed TSDF.
#[derive(Clone, Debug)]
pub struct TsdfVolume {
    /// Its settings.
    pub params: TsdfParams,
    pub(crate) blocks: Vec<Block>,
    pub(crate) index: FxHashMap<[i32; 3], u32>,
    /// Per region of [`REGION`]³ blocks, which of its blocks are allocated: bit
    /// [`region_bit`] of a block (regions without any are absent).
    pub(crate) regions: FxHashMap<[i32; 3], u64>,
    /// Scratch: blocks the current frame updates.
    pub(crate) active: Vec<bool>,
    /// Scratch: the current frame's per-pixel depth and fusion weight, and one empty sample past
    /// the last pixel.
    pub(crate) samples: Vec<[f32; 2]>,
    /// Scratch: the current frame's per-pixel colour, packed `r | g << 8 | b << 16`.
    pub(crate) sample_color: Vec<u32>,
    /// Storage of evicted blocks, reused by later allocations.
    pub(crate) spare: Vec<Block>,
    /// Blocks evicted so far.
    pub(crate) evicted: usize,
}

/// ⌊x⌋ as an integer without a libm call (x86-64's baseline has no vector or scalar floor
/// instruction, and `f32::floor` becomes a function call in the hot loops).
#[inline(always)]
pub(crate) fn floor_i32(x: f32) -> i32 {
    let t = x as i32;
    t - ((x < t as f32) as i32)
}

/// Block coordinates are limited to |c| < 2²⁰ on each axis (±84 km at 1 cm voxels), so that one
/// fits a 64-bit sort key.
pub const MAX_BLOCK_COORD: i32 = 1 << 20;

/// A block coordinate as a key whose order is the coordinate's lexicographic order; `None` beyond
/// [`MAX_BLOCK_COORD`].
#[inline(always)]
pub(crate) fn block_key(x: i32, y: i32, z: i32) -> Option<u64> {
    let lift = |c: i32| {
        let u = c.wrapping_add(MAX_BLOCK_COORD) as u32 as u64;
        (u < 2 * MAX_BLOCK_COORD as u64).then_some(u)
    };
    Some((lift(x)? << 42) | (lift(y)? << 21) | lift(z)?)
}

/// The block coordinate of a [`block_key`].
#[inline(always)]
pub(crate) fn block_of_key(key: u64) -> [i32; 3] {
    let part = |shift: u32| ((key >> shift) & ((1 << 21) - 1)) as i32 - MAX_BLOCK_COORD;
    [part(42), part(21), part(0)]
}

/// The region (of [`REGION`]³ blocks) holding a block, by block coordinate.
#[inline(always)]
pub(crate) fn region_of(block: [i32; 3]) -> [i32; 3] {
    block.map(|v| v.div_euclid(REGION))
}

/// The bit of a block (by block coordinate) in its region's mask of allocated blocks.
#[inline(always)]
pub(crate) fn region_bit(block: [i32; 3]) -> u64 {
    let l = block.map(|v| v.rem_euclid(REGION));
    1 << (l[0] + REGION * (l[1] + REGION * l[2]))
}

/// Splits a global voxel coordinate into (block coordinate, local coordinate).
#[inline]
pub fn split(g: [i32; 3]) -> ([i32; 3], [i32; 3]) {
    let b = g.map(|v| v.div_euclid(BLOCK));
    let l = [
        g[0] - b[0] * BLOCK,
        g[1] - b[1] * BLOCK,
        g[2] - b[2] * BLOCK,
    ];
    (b, l)
}

impl TsdfVolume {
    /// An empty volume.
    pub fn new(params: TsdfParams) -> Self {
        Self {
            params,
            blocks: Vec::new(),
            index: FxHashMap::default(),
            regions: FxHashMap::default(),
            active: Vec::new(),
            samples: Vec::new(),
            sample_color: Vec::new(),
            spare: Vec::new(),
            evicted: 0,
        }
    }

    /// Number of allocated blocks.
    pub fn num_blocks(&self) -> usize {
        self.blocks.len()
    }

    /// Bytes held by voxel data (allocated blocks and the spare storage of evicted ones).
    pub fn memory_bytes(&self) -> usize {
        (self.blocks.len() + self.spare.len())
            * (BLOCK_VOXELS * (std::mem::size_of::<Voxel>() + std::mem::size_of::<[u8; 4]>())
                + std::mem::size_of::<Block>())
    }

    /// Blocks evicted so far to stay within the budget.
    pub fn evicted_blocks(&self) -> usize {
        self.evicted
    }

    /// The allocated blocks.
    pub fn blocks(&self) -> &[Block] {
        &self.blocks
    }

    /// The block at a block coordinate.
    #[inline]
    pub fn block(&self, coord: &[i32; 3]) -> Option<&Block> {
        self.index.get(coord).map(|&i| &self.blocks[i as usize])
    }

    /// Which blocks of the region (of [`REGION`]³ blocks) at a region coordinate are allocated,
    /// one bit each ([`region_bit`]).
    #[inline]
    pub(crate) fn region_blocks(&self, region: &[i32; 3]) -> u64 {
        self.regions.get(region).copied().unwrap_or(0)
    }

    /// Files a block newly allocated at `coord` (after it is pushed to `blocks`).
    pub(crate) fn index_block(&mut self, coord: [i32; 3]) {
        self.index.insert(coord, self.blocks.len() as u32 - 1);
        *self.regions.entry(region_of(coord)).or_insert(0) |= region_bit(coord);
    }

    /// (tsdf, weight) of a global voxel, `None` where unallocated.
    #[inline]
    pub fn voxel(&self, g: [i32; 3]) -> Option<(f32, f32)> {
        let (b, l) = split(g);
        let blk = self.block(&b)?;
        let i = local_index(l[0], l[1], l[2]);
        Some((blk.voxels[i].tsdf, blk.voxels[i].weight))
    }

    /// World position of a global voxel's centre.
    #[inline]
    pub fn voxel_center(&self, g: [i32; 3]) -> Point3<f32> {
        Point3::new(g[0] as f32, g[1] as f32, g[2] as f32) * self.params.voxel_size
    }

    /// Trilinear interpolation of the TSDF (in metres) at a world point, `None` where any of the 8
    /// surrounding voxels is unobserved (thesis sec. 2.6).
    pub fn sdf(&self, p: &Point3<f32>) -> Option<f32> {
        self.trilinear(p).map(|(v, _)| v * self.params.truncation())
    }

    /// Trilinear TSDF (units of μ) and interpolated colour at a world point.
    pub(crate) fn trilinear(&self, p: &Point3<f32>) -> Option<(f32, [f32; 3])> {
        self.trilinear_gradient(p).map(|(v, _, c)| (v, c))
    }

    /// Trilinear TSDF (units of μ), its gradient (per voxel) and colour at a world point, from the 8
    /// surrounding voxels; `None` where one is unobserved.
    pub(crate) fn trilinear_gradient(
        &self,
        p: &Point3<f32>,
    ) -> Option<(f32, Vector3<f32>, [f32; 3])> {
        self.trilinear_gradient_near(p, &mut BlockCache::new())
    }

    /// [`Self::trilinear_gradient`] through the caller's `cache` of recent blocks (e.g. those of
    /// a ray and its neighbours), so that a block already seen costs no hash lookup. A cell inside
    /// one block (343 of 512) reads its corners at fixed offsets.
    pub(crate) fn trilinear_gradient_near<'a>(
        &'a self,
        p: &Point3<f32>,
        cache: &mut BlockCache<'a>,
    ) -> Option<(f32, Vector3<f32>, [f32; 3])> {
        let s = p.coords / self.params.voxel_size;
        let g0 = [floor_i32(s.x), floor_i32(s.y), floor_i32(s.z)];
        let f = Vector3::new(s.x - g0[0] as f32, s.y - g0[1] as f32, s.z - g0[2] as f32);
        let (b, l) = split(g0);
        // the corners' blocks: b + (ex, ey, ez), where e is 1 only on an axis whose corner crosses
        // the block's upper face
        let cross = [l[0] == BLOCK - 1, l[1] == BLOCK - 1, l[2] == BLOCK - 1];
        if !(cross[0] | cross[1] | cross[2]) {
            // the whole cell in one block: fixed offsets, no per-corner lookup
            let blk = cache.get(self, b)?;
            return Self::trilinear_in_block(blk, local_index(l[0], l[1], l[2]), &f);
        }
        let mut blocks: [Option<&Block>; 8] = [None; 8];
        let mut lookup = |e: usize| -> Option<&'a Block> {
            let c = [
                b[0] + (e & 1) as i32,
                b[1] + ((e >> 1) & 1) as i32,
                b[2] + ((e >> 2) & 1) as i32,
            ];
            cache.get(self, c)
        };
        let w = Self::corner_weights(&f);
        let mut v = [0.0f32; 8];
        let mut color = [0.0f32; 3];
        for (c, value) in v.iter_mut().enumerate() {
            let (dx, dy, dz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
            let e = (dx & cross[0] as usize)
                | ((dy & cross[1] as usize) << 1)
                | ((dz & cross[2] as usize) << 2);
            let blk = match blocks[e] {
                Some(blk) => blk,
                None => {
                    let blk = lookup(e)?;
                    blocks[e] = Some(blk);
                    blk
                }
            };
            let wrap = |l: i32, d: usize| (l + d as i32) & (BLOCK - 1);
            let i = local_index(wrap(l[0], dx), wrap(l[1], dy), wrap(l[2], dz));
            let vox = blk.voxels[i];
            if vox.weight <= 0.0 {
                return None;
            }
            *value = vox.tsdf;
            for (k, v) in color.iter_mut().zip(blk.color[i]) {
                *k += w[c] * v as f32;
            }
        }
        let (value, grad) = Self::interpolate(&v, &f);
        Some((value, grad, color))
    }

    /// [`Self::trilinear_gradient_near`] for a cell whose 8 corners lie in `blk`, its lower corner
    /// at local index `i0`.
    #[inline]
    fn trilinear_in_block(
        blk: &Block,
        i0: usize,
        f: &Vector3<f32>,
    ) -> Option<(f32, Vector3<f32>, [f32; 3])> {
        const STEP: [usize; 8] = [0, 1, 8, 9, 64, 65, 72, 73];
        let corners: [Voxel; 8] = STEP.map(|d| blk.voxels[i0 + d]);
        if !corners.iter().fold(true, |ok, c| ok & (c.weight > 0.0)) {
            return None;
        }
        let v = corners.map(|c| c.tsdf);
        let w = Self::corner_weights(f);
        let mut color = [0.0f32; 3];
        for (d, wc) in STEP.iter().zip(w) {
            let c = blk.color[i0 + d];
            for k in 0..3 {
                color[k] += wc * c[k] as f32;
            }
        }
        let (value, grad) = Self::interpolate(&v, f);
        Some((value, grad, color))
    }

    /// The trilinear weight of each corner `dx + 2 dy + 4 dz` of a cell at fractional position
    /// `f`: the product over the axes of `f` (corner on the upper side) or `1 − f`.
    #[inline(always)]
    fn corner_weights(f: &Vector3<f32>) -> [f32; 8] {
        let (gx, gy, gz) = (1.0 - f.x, 1.0 - f.y, 1.0 - f.z);
        [
            gx * gy * gz,
            f.x * gy * gz,
            gx * f.y * gz,
            f.x * f.y * gz,
            gx * gy * f.z,
            f.x * gy * f.z,
            gx * f.y * f.z,
            f.x * f.y * f.z,
        ]
    }

    /// The trilinear value and gradient (per voxel) of corner values `v[dx + 2 dy + 4 dz]` at
    /// fractional position `f` in the cell.
    #[inline(always)]
    fn interpolate(v: &[f32; 8], f: &Vector3<f32>) -> (f32, Vector3<f32>) {
        // interpolate along x, then y, then z
        let lx = |a: f32, b: f32| a + (b - a) * f.x;
        let (x00, x10, x01, x11) = (
            lx(v[0], v[1]),
            lx(v[2], v[3]),
            lx(v[4], v[5]),
            lx(v[6], v[7]),
        );
        let (y0, y1) = (x00 + (x10 - x00) * f.y, x01 + (x11 - x01) * f.y);
        let value = y0 + (y1 - y0) * f.z;
        let gz = y1 - y0;
        let gy = (x10 - x00) * (1.0 - f.z) + (x11 - x01) * f.z;
        let dxs = |a: f32, b: f32| b - a;
        let gx = (dxs(v[0], v[1]) * (1.0 - f.y) + dxs(v[2], v[3]) * f.y) * (1.0 - f.z)
            + (dxs(v[4], v[5]) * (1.0 - f.y) + dxs(v[6], v[7]) * f.y) * f.z;
        (value, Vector3::new(gx, gy, gz))
    }
}
