//! Correspondences between two meshes with a boundary (sheets, cloth, an open tube), from the
//! boundary's own shape: where no texture and no feature tells points apart, the rim still does.
//!
//! How much a boundary turns at a vertex is intrinsic, π less the angles of the triangles
//! meeting there (the discrete geodesic curvature), and so is the length along the boundary:
//! bending without stretch changes neither. A rectangle's corners turn by π/2 wherever the sheet
//! is rolled or folded. So the boundary of the source and of the target are described by their
//! turning along the arc length, the two descriptions are aligned by circular cross-correlation
//! (both directions), and each alignment that fits places 16 anchors around the rim
//! with their partners. Every vertex is then matched by its geodesic distances to them
//! (over the mesh's edges and second ring).
//!
//! A symmetric rim fits several ways (a rectangle four: turned by a half turn, mirrored). All
//! are intrinsically equal, so the choice is the one that moves the surface least: the least
//! mean distance between each source vertex and its match.

use super::descriptors::{MeshRef, SurfacePaths, ANCHORS};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};
use std::f64::consts::PI;

/// Bins of the turning signal around a rim.
const BINS: usize = 512;
/// The Gaussian that spreads each vertex's turning over the bins, as a share of the rim.
const SPREAD: f64 = 0.01;
/// An alignment fits when its correlation is at least this share of the best one's.
const FIT: f64 = 0.9;
/// Two rims are taken for one only when their best alignment's correlation reaches this: a
/// rectangle of another aspect, or a sheet cut in half, correlates about 0.5.
const SAME_RIM: f64 = 0.8;
/// … and when their lengths differ by less than this factor (a saddle of rims 0.15 of the
/// width high stretches its rim by a few percent).
const LENGTH_RATIO: f64 = 1.25;
/// A rim whose turning varies, root mean square about its mean, by less than this share of 2π
/// per bin (a disc's rim turns 2π in all) has nothing to align by: a circle, or a tube's rim,
/// turns the same everywhere.
const CONTRAST: f64 = 0.2;

/// One closed boundary loop: its vertices in order, each vertex's arc length from the first,
/// the loop's length, and how much it turns at each vertex.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Rim {
    vertices: Vec<u32>,
    arc: Vec<f64>,
    length: f64,
    turning: Vec<f64>,
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

    /// The turning spread over [`BINS`] bins of equal arc length, each vertex's by a circular
    /// Gaussian of [`SPREAD`] × the length, or of twice the mean spacing of the rim's vertices
    /// where that is wider (so that a coarse round rim reads as round, not as a ripple).
    fn signal(&self) -> Vec<f64> {
        let mut out = vec![0.0; BINS];
        let sigma = (SPREAD * BINS as f64).max(2.0 * BINS as f64 / self.vertices.len() as f64);
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

    /// The index (in this loop) of the partner of `source`'s vertex `i` under `alignment`: the
    /// vertex nearest the same share of the length, laid on as `alignment` says.
    fn partner_of(&self, source: &Rim, i: usize, alignment: &RimAlignment) -> usize {
        let u = source.arc[i] / source.length;
        self.index_at((alignment.shift + alignment.direction * u) * self.length)
    }

    /// The index (in the loop) of the rim vertex nearest arc length `s`, taken modulo the length.
    fn index_at(&self, s: f64) -> usize {
        let s = s.rem_euclid(self.length);
        let k = self.arc.partition_point(|&a| a <= s).max(1) - 1;
        let after = (k + 1) % self.vertices.len();
        let end = if after == 0 {
            self.length
        } else {
            self.arc[after]
        };
        if end - s < s - self.arc[k] {
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

/// The alignments of two rims' turning signals that fit: local maxima of the circular
/// correlation, in both directions, within [`FIT`] of the best, best first. Empty when the best
/// correlates less than [`SAME_RIM`] (not the same outline) or when either rim
/// turns the same everywhere.
pub(crate) fn rim_alignments(source: &Rim, target: &Rim) -> Vec<RimAlignment> {
    let (f, g) = (source.signal(), target.signal());
    if !(contrast(&f) > CONTRAST && contrast(&g) > CONTRAST) {
        return Vec::new();
    }
    let (f, g) = (centred(f), centred(g));
    let norm = (dot(&f, &f) * dot(&g, &g)).sqrt();
    let mut found = Vec::new();
    for direction in [1.0, -1.0] {
        let scores: Vec<f64> = (0..BINS)
            .map(|k| {
                (0..BINS)
                    .map(|b| f[b] * g[target_bin(b, k, direction)])
                    .sum::<f64>()
                    / norm
            })
            .collect();
        for k in 0..BINS {
            let (before, after) = (scores[(k + BINS - 1) % BINS], scores[(k + 1) % BINS]);
            if scores[k] > 0.0 && scores[k] >= before && scores[k] > after {
                found.push(RimAlignment {
                    direction,
                    shift: k as f64 / BINS as f64,
                    score: scores[k],
                });
            }
        }
    }
    found.sort_by(|a, b| b.score.total_cmp(&a.score));
    let best = found.first().map_or(0.0, |a| a.score);
    if best < SAME_RIM {
        return Vec::new();
    }
    found.retain(|a| a.score >= FIT * best);
    found
}

/// The target bin that source bin `b` falls on under shift `k` (bins) and `direction`.
fn target_bin(b: usize, k: usize, direction: f64) -> usize {
    if direction > 0.0 {
        (k + b) % BINS
    } else {
        (k + BINS - b) % BINS
    }
}

/// Root mean square of a signal about its mean, over 2π per bin.
fn contrast(v: &[f64]) -> f64 {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let rms = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
    rms / (2.0 * PI / n)
}

fn centred(mut v: Vec<f64>) -> Vec<f64> {
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    v.iter_mut().for_each(|x| *x -= mean);
    v
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The rim indices of [`ANCHORS`] vertices evenly spaced by arc length round `rim`.
fn anchor_indices(rim: &Rim) -> [usize; ANCHORS] {
    std::array::from_fn(|k| rim.index_at(k as f64 / ANCHORS as f64 * rim.length))
}

/// For every source vertex a target vertex, found from the two meshes' rims alone: no position
/// is compared until the choice between symmetric fits, which takes the least motion (the least
/// mean distance from each source vertex to its match). `None` when either mesh has no usable
/// rim (closed, non-manifold, or a rim that turns the same everywhere) or is too small, or when
/// the two rims are not one outline (lengths or turning too different: another shape, or part
/// of it).
pub fn rim_matches(source: MeshRef<'_>, target: MeshRef<'_>) -> Option<Vec<usize>> {
    if source.points.len() < ANCHORS || target.points.len() < ANCHORS {
        return None;
    }
    let (s_rim, t_rim) = (Rim::longest(source)?, Rim::longest(target)?);
    let ratio = t_rim.length / s_rim.length;
    if !(1.0 / LENGTH_RATIO..=LENGTH_RATIO).contains(&ratio) {
        return None;
    }
    let alignments = rim_alignments(&s_rim, &t_rim);
    if alignments.is_empty() {
        return None;
    }
    // the source's anchors and descriptors are the same under every alignment
    let at = anchor_indices(&s_rim);
    let d_source = SurfacePaths::two_ring(source)
        .ok()?
        .descriptors(&at.map(|i| s_rim.vertices[i] as usize));
    let target_paths = SurfacePaths::two_ring(target).ok()?;
    // a surface that stretches (a saddle) stretches its rim too: compare distances in units of
    // each rim's length
    let shrink = s_rim.length / t_rim.length;
    alignments
        .par_iter()
        .map(|a| {
            let to = at.map(|i| t_rim.vertices[t_rim.partner_of(&s_rim, i, a)] as usize);
            let mut d_target = target_paths.descriptors(&to);
            d_target
                .iter_mut()
                .for_each(|d| d.iter_mut().for_each(|x| *x *= shrink));
            let tree: ImmutableKdTree<f64, ANCHORS> = ImmutableKdTree::new_from_slice(&d_target);
            let mut matches: Vec<usize> = d_source
                .iter()
                .map(|d| tree.nearest_one::<SquaredEuclidean>(d).item as usize)
                .collect();
            // the rim itself is matched by arc length
            for (i, &v) in s_rim.vertices.iter().enumerate() {
                matches[v as usize] = t_rim.vertices[t_rim.partner_of(&s_rim, i, a)] as usize;
            }
            let motion = matches
                .iter()
                .enumerate()
                .map(|(v, &m)| (target.points[m] - source.points[v]).norm())
                .sum::<f64>();
            (motion, matches)
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, m)| m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::sheet::{flat_sheet, SheetDeformation, SheetShape};

    fn points_of(m: &crate::mesh::Mesh) -> Vec<Vector3<f64>> {
        m.vertices.iter().map(|p| p.coords.cast()).collect()
    }

    #[test]
    fn a_sheet_has_one_rim_that_turns_at_four_corners() {
        let sheet = flat_sheet(21, 13, 1.0);
        let points = points_of(&sheet);
        let mesh = MeshRef {
            points: &points,
            faces: &sheet.faces,
        };
        assert_eq!(boundary_loops(&sheet.faces).unwrap().len(), 1);
        let rim = Rim::longest(mesh).unwrap();
        assert_eq!(rim.vertices.len(), 2 * (20 + 12));
        assert!((rim.length - 3.2).abs() < 1e-6, "{}", rim.length);
        let corners = rim
            .turning
            .iter()
            .filter(|t| (*t - PI / 2.0).abs() < 1e-6)
            .count();
        assert_eq!(corners, 4);
        let total: f64 = rim.turning.iter().sum();
        assert!((total - 2.0 * PI).abs() < 1e-6, "a disc's rim turns once");
    }

    #[test]
    fn a_rolled_and_renumbered_sheet_is_matched_vertex_for_vertex() {
        let sheet = flat_sheet(21, 13, 0.5);
        let roll = SheetDeformation {
            shape: SheetShape::Roll { angle: PI },
            rigid: Some(crate::synthetic::sheet::case_motion(15.0, 0.03)),
        }
        .deformed(&sheet, 0.5);
        let n = sheet.vertices.len();
        let new_of = |v: usize| (v * 11 + 5) % n; // 11 is prime to 273 = 3 · 7 · 13
        let mut target = vec![Vector3::zeros(); n];
        for (v, p) in points_of(&roll).into_iter().enumerate() {
            target[new_of(v)] = p;
        }
        let faces: Vec<[u32; 3]> = roll
            .faces
            .iter()
            .map(|f| f.map(|v| new_of(v as usize) as u32))
            .collect();
        let source = points_of(&sheet);
        let matches = rim_matches(
            MeshRef {
                points: &source,
                faces: &sheet.faces,
            },
            MeshRef {
                points: &target,
                faces: &faces,
            },
        )
        .expect("the rims align");
        let right = (0..n).filter(|&v| matches[v] == new_of(v)).count();
        assert_eq!(right, n);
    }

    fn sheet_points(
        columns: usize,
        rows: usize,
        width: f64,
        height: f64,
    ) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let mut sheet = flat_sheet(columns, rows, width);
        // flat_sheet is 0.6 × width tall; stretch it to `height`
        sheet
            .vertices
            .iter_mut()
            .for_each(|v| v.y *= (height / (0.6 * width)) as f32);
        (points_of(&sheet), sheet.faces)
    }

    #[test]
    fn a_square_that_fits_eight_ways_takes_the_least_motion() {
        // a square rim aligns four ways round and four mirrored; an S-bend moved by 15° and
        // 3 cm leaves one of them the least motion
        let (points, faces) = sheet_points(17, 17, 0.8, 0.8);
        let case = SheetDeformation {
            shape: SheetShape::SBend { tilt: 1.2 },
            rigid: Some(crate::synthetic::sheet::case_motion(15.0, 0.03)),
        };
        let target: Vec<Vector3<f64>> = points
            .iter()
            .map(|p| case.apply(&nalgebra::Point3::from(*p), 0.8).coords)
            .collect();
        let mesh = |p| MeshRef {
            points: p,
            faces: &faces,
        };
        let s_rim = Rim::longest(mesh(&points)).unwrap();
        let t_rim = Rim::longest(mesh(&target)).unwrap();
        assert_eq!(rim_alignments(&s_rim, &t_rim).len(), 8);
        let matches = rim_matches(mesh(&points), mesh(&target)).unwrap();
        let right = matches.iter().enumerate().filter(|(v, m)| v == *m).count();
        assert_eq!(right, points.len());
    }

    #[test]
    fn another_outline_or_a_part_is_not_aligned() {
        let (rect, rect_faces) = sheet_points(21, 13, 1.0, 0.6);
        let (square, square_faces) = sheet_points(17, 17, 0.8, 0.8);
        let (half, half_faces) = sheet_points(11, 13, 0.5, 0.6);
        let rect = MeshRef {
            points: &rect,
            faces: &rect_faces,
        };
        // the same perimeter, corners elsewhere
        let square = MeshRef {
            points: &square,
            faces: &square_faces,
        };
        assert!(rim_matches(rect, square).is_none());
        let half = MeshRef {
            points: &half,
            faces: &half_faces,
        };
        assert!(rim_matches(rect, half).is_none());
        assert!(rim_matches(rect, rect).is_some());
    }

    #[test]
    fn closed_and_round_rims_give_nothing() {
        let (points, faces) = super::super::descriptors::tube(6, 8, 0.0);
        // an open tube has two round rims: no corner to align by
        let mesh = MeshRef {
            points: &points,
            faces: &faces,
        };
        assert!(rim_matches(mesh, mesh).is_none());
        // two triangles that share only a vertex: two rim edges leave it
        assert!(boundary_loops(&[[0, 1, 2], [0, 3, 4]]).is_none());
        // a face naming a vertex that is not there
        let few = &points[..3];
        assert!(Rim::longest(MeshRef {
            points: few,
            faces: &faces,
        })
        .is_none());
    }
}
