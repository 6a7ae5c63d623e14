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
use super::mesh_point::{faces_around, MeshPoint};
use super::rim::{Rim, RimAlignment, BINS};
use super::rim_map::RimMap;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use std::f64::consts::PI;

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
/// The alignments of two rims' turning signals that fit: local maxima of the circular
/// correlation, in both directions, within [`FIT`] of the best, best first. Empty when the best
/// correlates less than [`SAME_RIM`] (not the same outline) or when either rim
/// turns the same everywhere.
pub(crate) fn rim_alignments(source: &Rim, target: &Rim) -> Vec<RimAlignment> {
    let sigma = source.spread().max(target.spread());
    let (f, g) = (source.signal(sigma), target.signal(sigma));
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
    // (the faces name only vertices the mesh has: `Rim::longest` checked)
    let faces_of = faces_around(target.faces, target.points.len());
    // a surface that stretches (a saddle) stretches its rim too: compare distances in units of
    // each rim's length
    let shrink = s_rim.length / t_rim.length;
    alignments
        .par_iter()
        .map(|a| {
            let map = RimMap::new((&s_rim, source.points), (&t_rim, target.points), a);
            let on_target = |i: usize| t_rim.point_at(map.partner_arc(&s_rim, &t_rim, i, a));
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
            let fit = MeshPoint::nearest_in_face(faces[f as usize], table, d);
            if fit.1 < best.1 {
                best = fit;
            }
        }
    }
    best.0
}

#[cfg(test)]
mod tests {
    use super::super::rim::boundary_loops;
    use super::*;
    use crate::synthetic::sheet::{flat_sheet, SheetDeformation, SheetShape};
    use nalgebra::Vector3;

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

    /// The largest distance from each of `vertices`' partner on `target` to where `expected`
    /// says it belongs.
    fn worst_offset(
        matches: &RimMatches,
        target: &[Vector3<f64>],
        vertices: impl Iterator<Item = usize>,
        expected: impl Fn(usize) -> Vector3<f64>,
    ) -> f64 {
        vertices
            .map(|v| (matches.partners[v].blend(target) - expected(v)).norm())
            .fold(0.0, f64::max)
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
        let rim_vertices = matches.rim.iter().map(|&v| v as usize);
        let rim = worst_offset(&matches, &target, rim_vertices, |v| target[new_of(v)]);
        let worst = worst_offset(&matches, &target, 0..n, |v| target[new_of(v)]);
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
        let rim_vertices = matches.rim.iter().map(|&v| v as usize);
        let worst = worst_offset(&matches, &target, rim_vertices, |v| {
            case.apply(&nalgebra::Point3::from(source[v]), width).coords
        });
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
        let worst = worst_offset(&matches, &target, 0..points.len(), |v| target[v]);
        // a wrong one of the eight would be off by the sheet's size
        assert!(worst < 0.1 * 0.8 / 16.0, "{worst}");
    }

    /// Each rim's turning spread by its own vertex spacing (16 bins for 64 rim vertices, 5 for
    /// 192) correlated by 0.77, under [`SAME_RIM`]: a coarse sheet found no rim on a fine copy.
    #[test]
    fn a_coarse_rim_aligns_with_a_fine_copy_of_it() {
        let (coarse, coarse_faces) = sheet_points(21, 13, 0.5, 0.3);
        let (fine, fine_faces) = sheet_points(61, 37, 0.5, 0.3);
        let matches = match_sheets((&coarse, &coarse_faces), (&fine, &fine_faces));
        let worst = worst_offset(&matches, &fine, 0..coarse.len(), |v| coarse[v]);
        assert!(worst < 0.05 * 0.5 / 20.0, "{worst}");
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
