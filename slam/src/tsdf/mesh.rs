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
        (blk.voxels[i].weight > 0.0).then_some((blk, i))
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
    fn distances(&self, out: &mut [f32; SIDE * SIDE * SIDE]) -> bool {
        let (mut below, mut above) = (false, false);
        for (i, d) in out.iter_mut().enumerate() {
            let l = [
                (i % SIDE) as i32,
                ((i / SIDE) % SIDE) as i32,
                (i / (SIDE * SIDE)) as i32,
            ];
            *d = self
                .voxel(l)
                .map_or(f32::NAN, |(blk, v)| blk.voxels[v].tsdf);
            below |= *d < 0.0;
            above |= *d >= 0.0;
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
        // Per block, in parallel: triangles as three edge keys, plus each edge's vertex.
        let parts: Vec<BlockMesh> = self
            .blocks
            .par_iter()
            .map_init(
                || Box::new([0.0f32; SIDE * SIDE * SIDE]),
                |dist, blk| {
                    let mut part = BlockMesh::default();
                    let hood = Neighbourhood::of(self, blk.coord);
                    if !hood.distances(dist) {
                        return part;
                    }
                    let base = [
                        blk.coord[0] * BLOCK,
                        blk.coord[1] * BLOCK,
                        blk.coord[2] * BLOCK,
                    ];
                    for z in 0..BLOCK {
                        for y in 0..BLOCK {
                            for x in 0..BLOCK {
                                self.march_cube((&hood, dist), base, [x, y, z], &mut part);
                            }
                        }
                    }
                    part
                },
            )
            .collect();
        weld(&parts)
    }

    /// Marching cubes on the cube whose lowest corner is voxel `l` of the block whose first voxel
    /// is `base` (global voxel `g = base + l`): its triangles (as edge keys) and their vertices
    /// added to `part`; nothing when a corner is unobserved or a crossing lies between two
    /// corners at the truncation limit.
    fn march_cube(
        &self,
        (hood, dist): (&Neighbourhood<'_>, &[f32; SIDE * SIDE * SIDE]),
        base: [i32; 3],
        l: [i32; 3],
        part: &mut BlockMesh,
    ) {
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
        let mut keys = [([0; 3], 0u8); 12];
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
            let (ca, cb) = (corner(*a), corner(*b));
            let vertex = self.edge_vertex(g, (CORNERS[*a], &ca), (CORNERS[*b], &cb));
            keys[e] = vertex.0;
            part.verts.push(vertex);
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

    /// The crossing on the edge between corners `a` and `b` (offsets from voxel `g`): its key (the
    /// lower corner and the axis), and its point and colour interpolated linearly in the distance.
    fn edge_vertex(
        &self,
        g: [i32; 3],
        (oa, ca): ([i32; 3], &Corner),
        (ob, cb): ([i32; 3], &Corner),
    ) -> (EdgeKey, Point3<f32>, [u8; 3]) {
        let axis = (0..3).find(|&i| oa[i] != ob[i]).unwrap() as u8;
        let lower = if oa[axis as usize] < ob[axis as usize] {
            oa
        } else {
            ob
        };
        let key = ([g[0] + lower[0], g[1] + lower[1], g[2] + lower[2]], axis);
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

/// One block's marching-cubes output: triangles as three edge keys, and each edge's vertex.
#[derive(Default)]
struct BlockMesh {
    tris: Vec<[EdgeKey; 3]>,
    verts: Vec<(EdgeKey, Point3<f32>, [u8; 3])>,
}

/// The blocks' triangles joined into one mesh: a vertex per edge key (the first block's), faces
/// that collapsed to a line or a point dropped, normals from the faces.
fn weld(parts: &[BlockMesh]) -> Mesh {
    let mut mesh = Mesh::default();
    let mut index: FxHashMap<EdgeKey, u32> = FxHashMap::default();
    for part in parts {
        for (key, p, col) in &part.verts {
            index.entry(*key).or_insert_with(|| {
                mesh.vertices.push(*p);
                mesh.colors.push(*col);
                (mesh.vertices.len() - 1) as u32
            });
        }
    }
    for part in parts {
        for t in &part.tris {
            let f = t.map(|k| index[&k]);
            if f[0] != f[1] && f[1] != f[2] && f[0] != f[2] {
                mesh.faces.push(f);
            }
        }
    }
    mesh.compute_normals();
    mesh
}
