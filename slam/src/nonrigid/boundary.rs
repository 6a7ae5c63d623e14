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
//! (over the mesh's edges and second ring). The matches are points of the target's surface
//! ([`MeshPoint`]), not its vertices: two meshes of one sheet meshed apart share no vertex.
//!
//! A symmetric rim fits several ways (a rectangle four: turned by a half turn, mirrored). All
//! are intrinsically equal, so the choice is the one that moves the surface least: the least
//! mean distance between each source vertex and its match.

use super::descriptors::{MeshRef, SurfacePaths, ANCHORS};
use super::mesh_point::{nearest_in_triangle, MeshPoint};
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
/// A rim vertex that turns by at least this (radians) and no less than its neighbours is a
/// corner: a rectangle's turn by π/2 however the sheet bends, a round rim of n vertices by 2π/n.
const CORNER: f64 = PI / 6.0;
/// A source corner takes a target corner at most this share of the target's rim from where the
/// alignment puts it.
const CORNER_REACH: f64 = 0.05;

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

    /// The arc length of this loop at which the partner of `source`'s vertex `i` lies under
    /// `alignment`: the same share of the length, moved by `corners`' offsets.
    fn partner_arc(
        &self,
        source: &Rim,
        i: usize,
        alignment: &RimAlignment,
        corners: &CornerOffsets,
    ) -> f64 {
        let u = source.arc[i] / source.length;
        let aligned = (alignment.shift + alignment.direction * u) * self.length;
        corners.target_arc(source.arc[i], aligned)
    }

    /// The rim indices of its corners: vertices that turn by at least [`CORNER`] and by no less
    /// than either neighbour.
    fn corners(&self) -> Vec<usize> {
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
    fn edge_at(&self, s: f64) -> (usize, usize, f64) {
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
    fn point_at(&self, s: f64) -> MeshPoint {
        let (k, after, t) = self.edge_at(s);
        MeshPoint::on_edge(self.vertices[k], self.vertices[after], t)
    }

    /// The index (in the loop) of the rim vertex nearest arc length `s`.
    fn index_at(&self, s: f64) -> usize {
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

/// How the source's rim is laid onto the target's between corners. Each source corner takes the
/// target corner nearest where the alignment puts it (within [`CORNER_REACH`] of the target's
/// length): a twist stretches a sheet's long edges and not its short ones, so the same share of
/// each whole rim is off by up to a few percent of it near the corners. Between two matched
/// corners a point lands at the same share of the span's length where the span kept its length
/// better than the straight line between its corners did (bending keeps the length and
/// shortens the line), and at the same share along that line where the line kept its length
/// better: a surface pushed across it (a saddle, a sheet pressed into a bowl) stretches most
/// where it is steepest, and a point of the rim keeps its place between the corners as seen
/// from the line through them. That share must grow along both spans; where it does not (a
/// span that both stretched and curled round), the share of the length is taken. With no
/// corner matched, the same share of each whole rim.
#[derive(Clone, Debug, Default)]
pub(crate) struct CornerOffsets {
    /// The source's arc length at each matched corner, ascending.
    arc: Vec<f64>,
    /// The target's arc length less the aligned one there.
    offset: Vec<f64>,
    /// The source rim's length.
    length: f64,
    /// Per matched corner, the span to the next one where it is laid by its chord.
    chords: Vec<Option<ChordSpan>>,
}

/// A span of both rims between two matched corners, laid by the share along each one's chord:
/// for each rim vertex of the span its share along the chord and its distance from the first
/// corner along the rim, both ascending.
#[derive(Clone, Debug)]
struct ChordSpan {
    source: Vec<(f64, f64)>,
    target: Vec<(f64, f64)>,
    /// The target's arc length at the first corner, and the way its arc runs (±1).
    target_start: f64,
    direction: f64,
}

/// A matched pair of corners: their indices in each rim's loop.
struct CornerPair {
    source: usize,
    target: usize,
}

impl CornerOffsets {
    /// The corners of `source` matched to those of `target` under `alignment`, and the spans
    /// between them laid by their chords where they stretched (`source_points` and
    /// `target_points` are the meshes' vertices).
    fn new(
        source: (&Rim, &[Vector3<f64>]),
        target: (&Rim, &[Vector3<f64>]),
        alignment: &RimAlignment,
    ) -> Self {
        let (s_rim, t_rim) = (source.0, target.0);
        let none = Self::default();
        let t_corners = t_rim.corners();
        let mut out = Self {
            length: s_rim.length,
            ..Self::default()
        };
        let mut pairs = Vec::new();
        for i in s_rim.corners() {
            let aligned = t_rim.partner_arc(s_rim, i, alignment, &none);
            let nearest = t_corners
                .iter()
                .map(|&c| (c, circular_difference(t_rim.arc[c] - aligned, t_rim.length)))
                .min_by(|a, b| a.1.abs().total_cmp(&b.1.abs()));
            if let Some((c, d)) = nearest.filter(|(_, d)| d.abs() <= CORNER_REACH * t_rim.length) {
                out.arc.push(s_rim.arc[i]);
                out.offset.push(d);
                pairs.push(CornerPair {
                    source: i,
                    target: c,
                });
            }
        }
        let n = pairs.len();
        out.chords = (0..n)
            .map(|k| {
                let (a, b) = (&pairs[k], &pairs[(k + 1) % n]);
                ChordSpan::new(source, target, (a, b), alignment.direction)
            })
            .collect();
        out
    }

    /// The target's arc length for the source's arc length `s`, which the alignment alone
    /// puts at `aligned`.
    fn target_arc(&self, s: f64, aligned: f64) -> f64 {
        let n = self.arc.len();
        match n {
            0 => aligned,
            1 => aligned + self.offset[0],
            _ => {
                let k = self.arc.partition_point(|&a| a <= s);
                // the corners before and after s, round the loop
                let (before, after) = ((k + n - 1) % n, k % n);
                let into = (s - self.arc[before]).rem_euclid(self.length);
                if let Some(chord) = &self.chords[before] {
                    return chord.target_arc(into);
                }
                let span = (self.arc[after] - self.arc[before]).rem_euclid(self.length);
                let t = if span > 0.0 { into / span } else { 0.0 };
                aligned + self.offset[before] + t * (self.offset[after] - self.offset[before])
            }
        }
    }
}

impl ChordSpan {
    /// The span from corner pair `a` to `b`, or `None` where it kept its length, or where the
    /// share along a chord does not grow along its span.
    fn new(
        source: (&Rim, &[Vector3<f64>]),
        target: (&Rim, &[Vector3<f64>]),
        (a, b): (&CornerPair, &CornerPair),
        direction: f64,
    ) -> Option<Self> {
        let s_table = chord_table(source.0, source.1, a.source, b.source, 1.0)?;
        let t_table = chord_table(target.0, target.1, a.target, b.target, direction)?;
        let chord = |rim: &Rim, points: &[Vector3<f64>], p: &CornerPair, q: &CornerPair, side| {
            let (i, j) = if side {
                (p.source, q.source)
            } else {
                (p.target, q.target)
            };
            (points[rim.vertices[j] as usize] - points[rim.vertices[i] as usize]).norm()
        };
        let arc_change = (t_table.last()?.1 / s_table.last()?.1 - 1.0).abs();
        let chord_change =
            (chord(target.0, target.1, a, b, false) / chord(source.0, source.1, a, b, true) - 1.0)
                .abs();
        // bent, the span keeps its length and its chord shortens; stretched across the line
        // between its corners, the chord keeps its length
        // (NaN, from a span of no length, is neither)
        if chord_change.partial_cmp(&arc_change) != Some(std::cmp::Ordering::Less) {
            return None;
        }
        Some(Self {
            source: s_table,
            target: t_table,
            target_start: target.0.arc[a.target],
            direction,
        })
    }

    /// The target's arc length for the point `into` along the source's span.
    fn target_arc(&self, into: f64) -> f64 {
        let share = interpolate(&self.source, into, |p| p.1, |p| p.0);
        self.target_start + self.direction * interpolate(&self.target, share, |p| p.0, |p| p.1)
    }
}

/// For the rim vertices from loop index `from` to `to` (inclusive, walking the loop forwards
/// for `direction` +1, backwards for −1): each one's share along the chord between the two and
/// its distance from `from` along the rim. `None` unless the share grows strictly from 0 to 1.
fn chord_table(
    rim: &Rim,
    points: &[Vector3<f64>],
    from: usize,
    to: usize,
    direction: f64,
) -> Option<Vec<(f64, f64)>> {
    let n = rim.vertices.len();
    let at = |k: usize| points[rim.vertices[k] as usize];
    let (start, chord) = (at(from), at(to) - at(from));
    let length = chord.norm_squared();
    if length.is_nan() || length <= 0.0 {
        return None;
    }
    let mut table = vec![(0.0, 0.0)];
    let (mut k, mut walked) = (from, 0.0);
    while k != to {
        let next = if direction > 0.0 {
            (k + 1) % n
        } else {
            (k + n - 1) % n
        };
        walked += (at(next) - at(k)).norm();
        let share = (at(next) - start).dot(&chord) / length;
        if share <= table.last()?.0 {
            return None;
        }
        table.push((share, walked));
        k = next;
    }
    Some(table)
}

/// The linear interpolation through `table` (ascending in `key`) of `value` at `x`, held at the
/// ends.
fn interpolate<T>(table: &[T], x: f64, key: impl Fn(&T) -> f64, value: impl Fn(&T) -> f64) -> f64 {
    let k = table.partition_point(|p| key(p) <= x);
    if k == 0 {
        return table.first().map_or(0.0, &value);
    }
    if k == table.len() {
        return table.last().map_or(0.0, &value);
    }
    let (p, q) = (&table[k - 1], &table[k]);
    let t = (x - key(p)) / (key(q) - key(p));
    value(p) + t * (value(q) - value(p))
}

/// `d` taken round a loop of `length` into (−length/2, length/2].
fn circular_difference(d: f64, length: f64) -> f64 {
    let d = d.rem_euclid(length);
    if d > 0.5 * length {
        d - length
    } else {
        d
    }
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
                    shift: (k as f64 + peak_offset(before, scores[k], after)) / BINS as f64,
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

/// Where the peak of the parabola through three equally spaced samples lies, in samples from
/// the middle one (within ±½ when the middle one is the largest): a bin is 1/512 of the rim,
/// 3 mm of a 1.6 m rim, and an alignment off by a bin moves every match along the rim.
fn peak_offset(before: f64, at: f64, after: f64) -> f64 {
    let curvature = before - 2.0 * at + after;
    if curvature < 0.0 {
        (0.5 * (before - after) / curvature).clamp(-0.5, 0.5)
    } else {
        0.0
    }
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

/// What [`rim_matches`] found.
#[derive(Clone, Debug, PartialEq)]
pub struct RimMatches {
    /// Each source vertex's partner on the target.
    pub partners: Vec<MeshPoint>,
    /// The source's rim vertices, in order round the rim: their partners come from the rims'
    /// alignment itself, not from distances over the surface.
    pub rim: Vec<u32>,
}

/// For every source vertex a point on the target, found from the two meshes' rims alone: no
/// position is compared until the choice between symmetric fits, which takes the least motion
/// (the least mean distance from each source vertex to its match). The rim's vertices land at
/// the same share of the target's rim; every other vertex where the target's descriptors,
/// interpolated over a triangle, come nearest its own, so that two meshes
/// of one surface meshed apart match between the target's vertices. `None` when either mesh has
/// no usable rim (closed, non-manifold, or a rim that turns the same everywhere) or is too small,
/// or when the two rims are not one outline (lengths or turning too different: another shape, or
/// part of it).
pub fn rim_matches(source: MeshRef<'_>, target: MeshRef<'_>) -> Option<RimMatches> {
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
    let faces_of = faces_of_vertices(target);
    // a surface that stretches (a saddle) stretches its rim too: compare distances in units of
    // each rim's length
    let shrink = s_rim.length / t_rim.length;
    alignments
        .par_iter()
        .map(|a| {
            let corners = CornerOffsets::new((&s_rim, source.points), (&t_rim, target.points), a);
            let on_target = |i: usize| t_rim.point_at(t_rim.partner_arc(&s_rim, i, a, &corners));
            let starts = at.map(|i| {
                let p = on_target(i);
                let here = p.blend(target.points);
                (0..2)
                    .map(|k| {
                        let v = p.vertices[k];
                        (v, (target.points[v as usize] - here).norm())
                    })
                    .collect::<Vec<_>>()
            });
            let mut d_target = target_paths.descriptors_from(&starts);
            d_target
                .iter_mut()
                .for_each(|d| d.iter_mut().for_each(|x| *x *= shrink));
            let tree: ImmutableKdTree<f64, ANCHORS> = ImmutableKdTree::new_from_slice(&d_target);
            let mut matches: Vec<MeshPoint> = d_source
                .iter()
                .map(|d| nearest_in_faces(d, &tree, &d_target, &faces_of, target.faces))
                .collect();
            // the rim itself is matched by arc length
            for (i, &v) in s_rim.vertices.iter().enumerate() {
                matches[v as usize] = on_target(i);
            }
            let motion = matches
                .iter()
                .enumerate()
                .map(|(v, m)| (m.blend(target.points) - source.points[v]).norm())
                .sum::<f64>();
            (motion, matches)
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, partners)| RimMatches {
            partners,
            rim: s_rim.vertices.clone(),
        })
}

/// The faces around each vertex of `mesh` (its faces name only vertices it has: [`Rim::longest`]
/// checked).
fn faces_of_vertices(mesh: MeshRef<'_>) -> Vec<Vec<u32>> {
    let mut out = vec![Vec::new(); mesh.points.len()];
    for (f, face) in mesh.faces.iter().enumerate() {
        for &v in face {
            out[v as usize].push(f as u32);
        }
    }
    out
}

/// How many of the target's vertices nearest a descriptor have their triangles searched.
const NEAREST: usize = 3;

/// The point of the target whose descriptor, interpolated linearly over a triangle, lies nearest
/// `d`: over the triangles around the [`NEAREST`] vertices of nearest descriptor.
fn nearest_in_faces(
    d: &[f64; ANCHORS],
    tree: &ImmutableKdTree<f64, ANCHORS>,
    table: &[[f64; ANCHORS]],
    faces_of: &[Vec<u32>],
    faces: &[[u32; 3]],
) -> MeshPoint {
    let near = tree.nearest_n::<SquaredEuclidean>(d, std::num::NonZero::new(NEAREST).unwrap());
    let first = near.first().map_or(0, |n| n.item as u32);
    let mut best = (MeshPoint::vertex(first), f64::INFINITY);
    for n in &near {
        for &f in &faces_of[n.item as usize] {
            let fit = fit_in_face(faces[f as usize], table, d);
            if fit.1 < best.1 {
                best = fit;
            }
        }
    }
    best.0
}

/// The point of triangle `face` whose descriptor, interpolated from its corners' in `table`,
/// lies nearest `d`, and the squared distance.
fn fit_in_face(face: [u32; 3], table: &[[f64; ANCHORS]], d: &[f64; ANCHORS]) -> (MeshPoint, f64) {
    let corners = face.map(|v| &table[v as usize]);
    let (weights, cost) = nearest_in_triangle(corners, d);
    (
        MeshPoint {
            vertices: face,
            weights,
        },
        cost,
    )
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

    /// [`rim_matches`] of two meshes given as points and faces, which must align.
    fn match_sheets(
        source: (&[Vector3<f64>], &[[u32; 3]]),
        target: (&[Vector3<f64>], &[[u32; 3]]),
    ) -> RimMatches {
        let mesh = |(points, faces)| MeshRef { points, faces };
        rim_matches(mesh(source), mesh(target)).expect("the rims align")
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
        let matches = match_sheets((&source, &sheet.faces), (&target, &faces));
        // the rim lands on its own vertices; inside, the second ring's chords are shorter on
        // the rolled copy than on the flat sheet, and the interpolated match moves by that
        let spacing = 0.5 / 20.0;
        let off = |v: usize| (matches.partners[v].blend(&target) - target[new_of(v)]).norm();
        let rim = matches
            .rim
            .iter()
            .map(|&v| off(v as usize))
            .fold(0.0, f64::max);
        let worst = (0..n).map(off).fold(0.0, f64::max);
        assert!(rim < 1e-6 * spacing, "{rim}");
        assert!(worst < 0.1 * spacing, "{worst}");
        assert_eq!(matches.rim.len(), 2 * (20 + 12));
    }

    /// A flat sheet and the same sheet meshed apart (1.4 × the vertices, inner ones moved at
    /// random by up to 0.3 of the spacing) and rolled: the matches land between the target's
    /// vertices, where the roll sent each source vertex, to a small share of the spacing; a
    /// match that must land on a vertex is off by up to half of it.
    #[test]
    fn a_sheet_meshed_apart_is_matched_between_the_targets_vertices() {
        use crate::synthetic::sheet::jittered;
        let (width, columns, rows) = (0.5, 21, 13);
        let sheet = flat_sheet(columns, rows, width);
        let (c, r) = (29, 18);
        let case = SheetDeformation {
            shape: SheetShape::Roll { angle: PI },
            rigid: Some(crate::synthetic::sheet::case_motion(15.0, 0.03)),
        };
        let target_mesh = case.deformed(&jittered(flat_sheet(c, r, width), c, r, 0.3, 11), width);
        let (source, target) = (points_of(&sheet), points_of(&target_mesh));
        let matches = match_sheets((&source, &sheet.faces), (&target, &target_mesh.faces));
        let errors: Vec<f64> = source
            .iter()
            .zip(&matches.partners)
            .map(|(p, m)| {
                let truth = case.apply(&nalgebra::Point3::from(*p), width);
                (m.blend(&target) - truth.coords).norm()
            })
            .collect();
        let spacing = width / (c - 1) as f64;
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let rim = matches
            .rim
            .iter()
            .map(|&v| errors[v as usize])
            .fold(0.0, f64::max);
        assert!(mean < 0.2 * spacing, "mean {mean}, spacing {spacing}");
        assert!(rim < 0.05 * spacing, "rim {rim}, spacing {spacing}");
    }

    /// A saddle stretches the rim most near the corners: its rim lands where each point's place
    /// between the corners along the line through them says (the generated saddle moves points
    /// only across the sheet's plane), not at the same share of each edge's length, which is a
    /// third of the spacing off here.
    #[test]
    fn a_stretched_rim_is_laid_by_the_line_between_its_corners() {
        use crate::synthetic::sheet::jittered;
        let (width, c, r) = (0.5, 29, 18);
        let sheet = flat_sheet(21, 13, width);
        let case = SheetDeformation {
            shape: SheetShape::Saddle { height: 0.25 },
            rigid: Some(crate::synthetic::sheet::case_motion(10.0, 0.02)),
        };
        let target_mesh = case.deformed(&jittered(flat_sheet(c, r, width), c, r, 0.3, 5), width);
        let (source, target) = (points_of(&sheet), points_of(&target_mesh));
        let matches = match_sheets((&source, &sheet.faces), (&target, &target_mesh.faces));
        let worst = matches
            .rim
            .iter()
            .map(|&v| {
                let truth = case.apply(&nalgebra::Point3::from(source[v as usize]), width);
                (matches.partners[v as usize].blend(&target) - truth.coords).norm()
            })
            .fold(0.0, f64::max);
        let spacing = width / (c - 1) as f64;
        assert!(worst < 0.02 * spacing, "rim {worst}, spacing {spacing}");
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
        let worst = (0..points.len())
            .map(|v| (matches.partners[v].blend(&target) - target[v]).norm())
            .fold(0.0, f64::max);
        // a wrong one of the eight would be off by the sheet's size
        assert!(worst < 0.1 * 0.8 / 16.0, "{worst}");
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
