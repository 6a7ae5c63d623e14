//! A mesh's boundary loop (a sheet's rim) and what is intrinsic about it: its length, the arc
//! length of each vertex along it, and how much it turns at each vertex, π less the angles of
//! the triangles meeting there (the discrete geodesic curvature). Bending without stretch
//! changes none of them.

use super::descriptors::MeshRef;
use super::mesh_point::MeshPoint;
use nalgebra::Vector3;
use std::collections::{HashMap, HashSet};
use std::f64::consts::PI;

/// Bins of the turning signal around a rim.
pub(crate) const BINS: usize = 512;
/// The Gaussian that spreads each vertex's turning over the bins, as a share of the rim.
const SPREAD: f64 = 0.01;
/// A rim vertex that turns by at least this (radians) and no less than its neighbours is a
/// corner: a rectangle's turn by π/2 however the sheet bends, a round rim of n vertices by 2π/n.
const CORNER: f64 = PI / 6.0;

/// One closed boundary loop: its vertices in order, each vertex's arc length from the first,
/// the loop's length, and how much it turns at each vertex.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Rim {
    pub(crate) vertices: Vec<u32>,
    pub(crate) arc: Vec<f64>,
    pub(crate) length: f64,
    pub(crate) turning: Vec<f64>,
}

/// The boundary loops of a triangle mesh: a directed edge a→b of a face whose reverse b→a no face
/// has is on the boundary, and the loops follow those edges. `None` where the boundary is not a
/// set of simple loops (a vertex with two boundary edges leaving it: a non-manifold rim).
pub(crate) fn boundary_loops(faces: &[[u32; 3]]) -> Option<Vec<Vec<u32>>> {
    let directed: HashSet<(u32, u32)> = faces
        .iter()
        .flat_map(|f| [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])])
        .collect();
    let mut next: HashMap<u32, u32> = HashMap::new();
    for &(a, b) in directed
        .iter()
        .filter(|&&(a, b)| !directed.contains(&(b, a)) && a != b)
    {
        if next.insert(a, b).is_some() {
            return None;
        }
    }
    let mut starts: Vec<u32> = next.keys().copied().collect();
    starts.sort_unstable();
    let mut seen = HashSet::new();
    let mut loops = Vec::new();
    for start in starts {
        if seen.contains(&start) {
            continue;
        }
        let mut cycle = vec![start];
        seen.insert(start);
        let mut v = *next.get(&start)?;
        while v != start {
            if !seen.insert(v) {
                return None;
            }
            cycle.push(v);
            v = *next.get(&v)?;
        }
        loops.push(cycle);
    }
    Some(loops)
}

/// Σ of the triangle angles at each vertex.
fn angle_sums(mesh: MeshRef<'_>) -> Vec<f64> {
    let mut sums = vec![0.0; mesh.points.len()];
    for f in mesh.faces {
        for k in 0..3 {
            let (a, b, c) = (
                f[k] as usize,
                f[(k + 1) % 3] as usize,
                f[(k + 2) % 3] as usize,
            );
            let (u, v) = (
                mesh.points[b] - mesh.points[a],
                mesh.points[c] - mesh.points[a],
            );
            let angle = u.cross(&v).norm().atan2(u.dot(&v));
            if angle.is_finite() {
                sums[a] += angle;
            }
        }
    }
    sums
}

impl Rim {
    /// The mesh's longest boundary loop, or `None` for a closed mesh, a non-manifold rim or a
    /// face that names a vertex the mesh does not have.
    pub(crate) fn longest(mesh: MeshRef<'_>) -> Option<Rim> {
        let n = mesh.points.len();
        if mesh.faces.iter().flatten().any(|&v| v as usize >= n) {
            return None;
        }
        let loops = boundary_loops(mesh.faces)?;
        let sums = angle_sums(mesh);
        loops
            .into_iter()
            .filter(|l| l.len() >= 3)
            .map(|vertices| Rim::of_loop(mesh.points, &sums, vertices))
            .max_by(|a, b| a.length.total_cmp(&b.length))
    }

    fn of_loop(points: &[Vector3<f64>], sums: &[f64], vertices: Vec<u32>) -> Rim {
        let mut arc = Vec::with_capacity(vertices.len());
        let mut length = 0.0;
        for (k, &v) in vertices.iter().enumerate() {
            arc.push(length);
            let w = vertices[(k + 1) % vertices.len()];
            length += (points[w as usize] - points[v as usize]).norm();
        }
        let turning = vertices.iter().map(|&v| PI - sums[v as usize]).collect();
        Rim {
            vertices,
            arc,
            length,
            turning,
        }
    }

    /// The width, in bins, this rim's turning needs spreading over: [`SPREAD`] × the length, or
    /// twice the mean spacing of its vertices where that is wider (so that a coarse round rim
    /// reads as round, not as a ripple).
    pub(crate) fn spread(&self) -> f64 {
        (SPREAD * BINS as f64).max(2.0 * BINS as f64 / self.vertices.len() as f64)
    }

    /// The turning spread over [`BINS`] bins of equal arc length, each vertex's by a circular
    /// Gaussian of `sigma` bins. Two rims are compared at one width, the wider of their
    /// [`Self::spread`]s: a corner spread over 16 bins correlates with one spread over 5 by only
    /// 0.77, and a coarse sheet's rim was not aligned with a fine copy's.
    pub(crate) fn signal(&self, sigma: f64) -> Vec<f64> {
        let mut out = vec![0.0; BINS];
        let reach = (4.0 * sigma).ceil() as isize;
        for (&s, &t) in self.arc.iter().zip(&self.turning) {
            let centre = s / self.length * BINS as f64;
            let c = centre.round() as isize;
            for b in c - reach..=c + reach {
                let d = (b as f64 - centre) / sigma;
                out[b.rem_euclid(BINS as isize) as usize] += t * (-0.5 * d * d).exp();
            }
        }
        out
    }

    /// The rim indices of its corners: vertices that turn by at least [`CORNER`] and by no less
    /// than either neighbour.
    pub(crate) fn corners(&self) -> Vec<usize> {
        let n = self.turning.len();
        (0..n)
            .filter(|&k| {
                let t = self.turning[k];
                t >= CORNER && t >= self.turning[(k + n - 1) % n] && t >= self.turning[(k + 1) % n]
            })
            .collect()
    }

    /// The rim edge at arc length `s` (taken modulo the length): the indices of its two ends in
    /// the loop, and how far along it `s` lies, from 0 to 1.
    pub(crate) fn edge_at(&self, s: f64) -> (usize, usize, f64) {
        let s = s.rem_euclid(self.length);
        let k = self.arc.partition_point(|&a| a <= s).max(1) - 1;
        let after = (k + 1) % self.vertices.len();
        let end = if after == 0 {
            self.length
        } else {
            self.arc[after]
        };
        let t = ((s - self.arc[k]) / (end - self.arc[k])).clamp(0.0, 1.0);
        (k, after, if t.is_finite() { t } else { 0.0 })
    }

    /// The point of the loop at arc length `s`, between the two rim vertices it falls between.
    pub(crate) fn point_at(&self, s: f64) -> MeshPoint {
        let (k, after, t) = self.edge_at(s);
        MeshPoint::on_edge(self.vertices[k], self.vertices[after], t)
    }

    /// The index (in the loop) of the rim vertex nearest arc length `s`.
    pub(crate) fn index_at(&self, s: f64) -> usize {
        let (k, after, t) = self.edge_at(s);
        if t > 0.5 {
            after
        } else {
            k
        }
    }
}

/// One way of laying the source's rim onto the target's: the target's arc length (as a share of
/// its length) at the source's share u is `shift + direction · u`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct RimAlignment {
    /// +1 or −1.
    pub(crate) direction: f64,
    /// Share of the target's rim.
    pub(crate) shift: f64,
    /// Normalised correlation of the two turning signals, at most 1.
    pub(crate) score: f64,
}
