//! Marching cubes over the allocated blocks (Lorensen & Cline 1987, with the case tables of Paul
//! Bourke's listing as shipped by the `marching-cubes` crate). Cubes straddling block borders read the
//! neighbouring blocks, and vertices are shared through a key per lattice edge, so the mesh is
//! watertight across blocks.

use super::{local_index, Block, TsdfVolume, BLOCK};
use crate::mesh::Mesh;
use marching_cubes::tables::{EDGE_TABLE, TRI_TABLE};
use nalgebra::Point3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use std::cell::Cell;

/// Corner offsets in Bourke's numbering.
const CORNERS: [[i32; 3]; 8] = [
    [0, 0, 0],
    [1, 0, 0],
    [1, 1, 0],
    [0, 1, 0],
    [0, 0, 1],
    [1, 0, 1],
    [1, 1, 1],
    [0, 1, 1],
];
/// The corner pair of each edge in Bourke's numbering.
const EDGES: [[usize; 2]; 12] = [
    [0, 1],
    [1, 2],
    [2, 3],
    [3, 0],
    [4, 5],
    [5, 6],
    [6, 7],
    [7, 4],
    [0, 4],
    [1, 5],
    [2, 6],
    [3, 7],
];

/// A lattice edge: its lower global voxel corner and axis (0, 1, 2).
type EdgeKey = ([i32; 3], u8);

/// Each edge of [`EDGES`] as its lower corner's offset in the cube and its axis.
const EDGE_LOWER: [([i32; 3], u8); 12] = {
    let mut out = [([0; 3], 0); 12];
    let mut e = 0;
    while e < 12 {
        let (a, b) = (CORNERS[EDGES[e][0]], CORNERS[EDGES[e][1]]);
        let mut axis = 0;
        while a[axis] == b[axis] {
            axis += 1;
        }
        out[e] = (if a[axis] < b[axis] { a } else { b }, axis as u8);
        e += 1;
    }
    out
};

/// Edge `e` of the cube whose lower corner is at `at` (voxel coordinates).
#[inline]
fn edge_at(at: [i32; 3], e: usize) -> EdgeKey {
    let (lower, axis) = EDGE_LOWER[e];
    ([at[0] + lower[0], at[1] + lower[1], at[2] + lower[2]], axis)
}

struct Corner {
    tsdf: f32,
    color: [u8; 3],
}

/// A block and its seven neighbours towards +x, +y and +z (where allocated): every corner the
/// block's cubes read, looked up once per block instead of once per corner.
struct Neighbourhood<'a> {
    blocks: [Option<&'a Block>; 8],
}

impl<'a> Neighbourhood<'a> {
    fn of(volume: &'a TsdfVolume, coord: [i32; 3]) -> Self {
        Self {
            blocks: std::array::from_fn(|k| {
                let d = [(k & 1) as i32, ((k >> 1) & 1) as i32, ((k >> 2) & 1) as i32];
                volume.block(&[coord[0] + d[0], coord[1] + d[1], coord[2] + d[2]])
            }),
        }
    }

    /// The block holding the voxel at `l` (0..=BLOCK on each axis) from the block's first
    /// voxel, and its index there, if the voxel is observed.
    #[inline]
    fn voxel(&self, l: [i32; 3]) -> Option<(&'a Block, usize)> {
        let (bx, by, bz) = (l[0] / BLOCK, l[1] / BLOCK, l[2] / BLOCK);
        let blk = self.blocks[(bx + 2 * by + 4 * bz) as usize]?;
        let i = local_index(l[0] - bx * BLOCK, l[1] - by * BLOCK, l[2] - bz * BLOCK);
        blk.voxels[i].observed().map(|_| (blk, i))
    }

    /// The voxel at `l`'s distance and colour, if observed.
    fn corner(&self, l: [i32; 3]) -> Option<Corner> {
        self.voxel(l).map(|(blk, i)| Corner {
            tsdf: blk.voxels[i].tsdf,
            color: [blk.color[i][0], blk.color[i][1], blk.color[i][2]],
        })
    }

    /// The distances at every corner the block's cubes read (NaN where unobserved), and whether
    /// they change sign: a block whose observed corners all lie on one side has no surface.
    /// Filled block by block: the block's own 8³ corners, then the one-voxel layers its
    /// neighbours towards +x, +y and +z lend.
    fn distances(&self, out: &mut [f32; SIDE * SIDE * SIDE]) -> bool {
        let (mut below, mut above) = (false, false);
        for (k, blk) in self.blocks.iter().enumerate() {
            let d = [(k & 1) as i32, ((k >> 1) & 1) as i32, ((k >> 2) & 1) as i32];
            // along each axis: the block's own 0..BLOCK, or the neighbour's first layer at BLOCK
            let span = d.map(|o| if o == 0 { 0..BLOCK } else { 0..1 });
            for z in span[2].clone() {
                for y in span[1].clone() {
                    for x in span[0].clone() {
                        let at = side_index([x + d[0] * BLOCK, y + d[1] * BLOCK, z + d[2] * BLOCK]);
                        let value = blk
                            .and_then(|b| b.voxels[local_index(x, y, z)].observed())
                            .unwrap_or(f32::NAN);
                        below |= value < 0.0;
                        above |= value >= 0.0;
                        out[at] = value;
                    }
                }
            }
        }
        below && above
    }
}

/// Corners along a block's edge, the next block's first included.
const SIDE: usize = BLOCK as usize + 1;

/// Index of corner `l` in [`Neighbourhood::distances`]' array.
#[inline]
fn side_index(l: [i32; 3]) -> usize {
    l[0] as usize + SIDE * (l[1] as usize + SIDE * l[2] as usize)
}

impl TsdfVolume {
    /// The zero level set of the TSDF as a coloured triangle mesh (world frame, normals from the
    /// faces), watertight across blocks. Cubes with an unobserved corner, or with a sign change
    /// between two corners both at the truncation limit (|tsdf| ≥ 1, a band edge, not a surface), are
    /// skipped.
    pub fn extract_mesh(&self) -> Mesh {
        // Per block, in parallel: triangles over the block's own vertices, one per edge key.
        let parts: Vec<BlockMesh> = self
            .blocks
            .par_iter()
            .map_init(Scratch::new, |scratch, blk| {
                let hood = Neighbourhood::of(self, blk.coord);
                let base = blk.coord.map(|c| c * BLOCK);
                let mut part = BlockMesh {
                    base,
                    ..BlockMesh::default()
                };
                if !hood.distances(&mut scratch.dist) {
                    return part;
                }
                for z in 0..BLOCK {
                    for y in 0..BLOCK {
                        for x in 0..BLOCK {
                            self.march_cube((&hood, &*scratch), [x, y, z], &mut part);
                        }
                    }
                }
                scratch.forget(&part);
                part
            })
            .collect();
        weld(&parts)
    }

    /// Marching cubes on the cube whose lowest corner is voxel `l` of the block whose first voxel
    /// is `base` (global voxel `g = base + l`): its triangles (as edge keys) and their vertices
    /// added to `part`; nothing when a corner is unobserved or a crossing lies between two
    /// corners at the truncation limit.
    fn march_cube(
        &self,
        (hood, scratch): (&Neighbourhood<'_>, &Scratch),
        l: [i32; 3],
        part: &mut BlockMesh,
    ) {
        let (dist, base) = (&scratch.dist, part.base);
        let g = [base[0] + l[0], base[1] + l[1], base[2] + l[2]];
        let mut c = [0.0f32; 8];
        let mut index = 0usize;
        for (k, off) in CORNERS.iter().enumerate() {
            let d = dist[side_index([l[0] + off[0], l[1] + off[1], l[2] + off[2]])];
            if d.is_nan() {
                return;
            }
            if d < 0.0 {
                index |= 1 << k;
            }
            c[k] = d;
        }
        let mask = EDGE_TABLE[index] as u16;
        if mask == 0 {
            return;
        }
        let mut keys = [0u32; 12];
        for (e, [a, b]) in EDGES.iter().enumerate() {
            if mask & (1 << e) == 0 {
                continue;
            }
            if c[*a].abs() >= 1.0 && c[*b].abs() >= 1.0 {
                return;
            }
            let corner = |k: usize| {
                let off = CORNERS[k];
                hood.corner([l[0] + off[0], l[1] + off[1], l[2] + off[2]])
                    .expect("observed: its distance was read")
            };
            let (oa, ob) = (CORNERS[*a], CORNERS[*b]);
            let slot = &scratch.slots[edge_slot(l, e)];
            keys[e] = match slot.get() {
                u32::MAX => {
                    let (ca, cb) = (corner(*a), corner(*b));
                    let vertex = self.edge_vertex(g, edge_at(g, e), (oa, &ca), (ob, &cb));
                    part.verts.push(vertex);
                    slot.set(part.verts.len() as u32 - 1);
                    part.verts.len() as u32 - 1
                }
                known => known,
            };
        }
        for tri in TRI_TABLE[index].chunks(3) {
            if tri[0] < 0 {
                break;
            }
            // Bourke's winding faces the "below iso" side; ours faces outward (towards positive
            // distance), so reverse it.
            part.tris.push([
                keys[tri[0] as usize],
                keys[tri[2] as usize],
                keys[tri[1] as usize],
            ]);
        }
    }

    /// The crossing on the edge `key` between corners `a` and `b` (offsets from voxel `g`): the
    /// key, and its point and colour interpolated linearly in the distance.
    fn edge_vertex(
        &self,
        g: [i32; 3],
        key: EdgeKey,
        (oa, ca): ([i32; 3], &Corner),
        (ob, cb): ([i32; 3], &Corner),
    ) -> (EdgeKey, Point3<f32>, [u8; 3]) {
        let t = ca.tsdf / (ca.tsdf - cb.tsdf);
        let pa = self.voxel_center([g[0] + oa[0], g[1] + oa[1], g[2] + oa[2]]);
        let pb = self.voxel_center([g[0] + ob[0], g[1] + ob[1], g[2] + ob[2]]);
        let p = pa + (pb - pa) * t;
        let col: [u8; 3] = std::array::from_fn(|k| {
            (ca.color[k] as f32 + (cb.color[k] as f32 - ca.color[k] as f32) * t).round() as u8
        });
        (key, p, col)
    }
}

/// One block's marching-cubes output: each edge's vertex once, in the order the cubes first
/// met it, and triangles as three indices into them.
#[derive(Default)]
struct BlockMesh {
    /// The block's first voxel (global voxel coordinates).
    base: [i32; 3],
    tris: Vec<[u32; 3]>,
    verts: Vec<(EdgeKey, Point3<f32>, [u8; 3])>,
}

impl BlockMesh {
    /// Whether no other block's cubes touch the lattice edge `key`: its lower corner lies in
    /// this block along the edge's axis, and away from the block's lower faces across it (the
    /// cubes sharing it lie at that corner and one voxel lower on each other axis).
    fn owns_alone(&self, (g, axis): &EdgeKey) -> bool {
        (0..3).all(|k| {
            let l = g[k] - self.base[k];
            let low = if k == *axis as usize { 0 } else { 1 };
            (low..BLOCK).contains(&l)
        })
    }
}

/// One thread's buffers for [`TsdfVolume::extract_mesh`]: the block's corner distances and,
/// per lattice edge the block's cubes can touch, its vertex's index in the block's mesh
/// (`u32::MAX`: none yet).
struct Scratch {
    dist: Box<[f32; SIDE * SIDE * SIDE]>,
    slots: Vec<Cell<u32>>,
}

impl Scratch {
    fn new() -> Self {
        Self {
            dist: Box::new([0.0; SIDE * SIDE * SIDE]),
            slots: vec![Cell::new(u32::MAX); SIDE * SIDE * SIDE * 3],
        }
    }

    /// Clears the slots `part`'s vertices took, for the next block.
    fn forget(&mut self, part: &BlockMesh) {
        for (key, ..) in &part.verts {
            let l = [0, 1, 2].map(|k| key.0[k] - part.base[k]);
            self.slots[side_index(l) * 3 + key.1 as usize].set(u32::MAX);
        }
    }
}

/// The slot in [`Scratch::slots`] of edge `e` of the cube at `l` (from the block's first voxel).
#[inline]
fn edge_slot(l: [i32; 3], e: usize) -> usize {
    let (lower, axis) = edge_at(l, e);
    side_index(lower) * 3 + axis as usize
}

/// The blocks' triangles joined into one mesh: a vertex per edge key (the first block's), faces
/// that collapsed to a line or a point dropped, normals from the faces.
fn weld(parts: &[BlockMesh]) -> Mesh {
    let mut mesh = Mesh::default();
    // only edges on a block's lower faces or beyond its upper ones can come from two blocks
    let mut shared: FxHashMap<EdgeKey, u32> = FxHashMap::default();
    let mut global: Vec<u32> = Vec::new();
    for part in parts {
        global.clear();
        for (key, p, col) in &part.verts {
            let mut add = || {
                mesh.vertices.push(*p);
                mesh.colors.push(*col);
                (mesh.vertices.len() - 1) as u32
            };
            let index = if part.owns_alone(key) {
                add()
            } else {
                *shared.entry(*key).or_insert_with(add)
            };
            global.push(index);
        }
        for t in &part.tris {
            let f = t.map(|k| global[k as usize]);
            if f[0] != f[1] && f[1] != f[2] && f[0] != f[2] {
                mesh.faces.push(f);
            }
        }
    }
    mesh.compute_normals();
    mesh
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every lattice edge the cubes of the block at block coordinate `coord` touch.
    fn edges_of_cubes(coord: [i32; 3]) -> Vec<EdgeKey> {
        let base = coord.map(|c| c * BLOCK);
        let mut keys = Vec::new();
        for z in 0..BLOCK {
            for y in 0..BLOCK {
                for x in 0..BLOCK {
                    let at = [0, 1, 2].map(|k| base[k] + [x, y, z][k]);
                    keys.extend((0..12).map(|e| edge_at(at, e)));
                }
            }
        }
        keys
    }

    /// Each edge's lower corner and axis: its two corners differ along the axis alone, by one,
    /// the lower one first.
    #[test]
    fn the_edge_table_gives_each_edge_its_lower_corner_and_axis() {
        for (e, [a, b]) in EDGES.iter().enumerate() {
            let (lower, axis) = EDGE_LOWER[e];
            let upper = std::array::from_fn(|k| lower[k] + i32::from(k == axis as usize));
            let ends = [CORNERS[*a], CORNERS[*b]];
            assert!(ends == [lower, upper] || ends == [upper, lower], "edge {e}");
        }
    }

    #[test]
    fn an_edge_a_block_owns_alone_is_touched_by_no_other_blocks_cubes() {
        let part = BlockMesh {
            base: [BLOCK, -2 * BLOCK, 0],
            ..BlockMesh::default()
        };
        let own = edges_of_cubes([1, -2, 0]);
        let alone: Vec<EdgeKey> = own.iter().copied().filter(|k| part.owns_alone(k)).collect();
        // the block's interior edges, and no more: 3 · 8 · 7 · 7 lattice edges
        let distinct: std::collections::HashSet<EdgeKey> = alone.iter().copied().collect();
        assert_eq!(distinct.len(), 3 * 8 * 7 * 7);
        for d in 0..27 {
            let shift = [d % 3 - 1, (d / 3) % 3 - 1, d / 9 - 1];
            if shift == [0, 0, 0] {
                continue;
            }
            let other = edges_of_cubes([1 + shift[0], -2 + shift[1], shift[2]]);
            assert!(
                other.iter().all(|k| !distinct.contains(k)),
                "the block at {shift:?} touches an edge owned alone"
            );
        }
        // every other edge the block touches is on its border, shared with a neighbour
        let shared = own.iter().filter(|k| !part.owns_alone(k)).count();
        assert!(shared > 0);
    }

    #[test]
    fn each_edge_gets_one_vertex_and_the_mesh_is_the_one_welded_by_key() {
        // a ball of radius 5.3 voxels about a block corner, its distance truncated at 3 voxels
        let mut volume = TsdfVolume::new(super::super::TsdfParams {
            voxel_size: 1.0,
            ..Default::default()
        });
        let centre = [7.5f32, 8.2, 8.9];
        for coord in (0..27).map(|k| [k % 3, (k / 3) % 3, k / 9]) {
            let mut block = Block::new(coord);
            for (i, v) in block.voxels.iter_mut().enumerate() {
                let l = [
                    i as i32 % BLOCK,
                    (i as i32 / BLOCK) % BLOCK,
                    i as i32 / (BLOCK * BLOCK),
                ];
                let g = volume.voxel_center([0, 1, 2].map(|k| coord[k] * BLOCK + l[k]));
                let r = (g - nalgebra::Point3::from(centre)).norm();
                v.tsdf = ((r - 5.3) / 3.0).clamp(-1.0, 1.0);
                v.weight = 1.0;
            }
            volume.blocks.push(block);
            volume.index_block(coord);
        }
        let mesh = volume.extract_mesh();
        assert!(mesh.faces.len() > 100);
        // one vertex per place: welding by key over all blocks leaves no twins
        let mut seen = std::collections::HashSet::new();
        for v in &mesh.vertices {
            assert!(
                seen.insert([v.x.to_bits(), v.y.to_bits(), v.z.to_bits()]),
                "twin vertex {v:?}"
            );
        }
        // closed: every edge of a face is shared by exactly two faces
        let mut count = std::collections::HashMap::new();
        for f in &mesh.faces {
            for k in 0..3 {
                let (a, b) = (f[k].min(f[(k + 1) % 3]), f[k].max(f[(k + 1) % 3]));
                *count.entry((a, b)).or_insert(0) += 1;
            }
        }
        assert!(count.values().all(|&c| c == 2));
    }
}
