//! Which way a closed mesh's normals point, out of its inside or into it, so that a target whose
//! normals point the other way from the source's (a mesh wound the other way round, as some
//! exporters and reconstructions write them) can be registered with its normals turned over.
//!
//! By the divergence theorem, ∮ n·(p − c) dA = 3V over a closed surface with outward normals n,
//! for any point c: positive. Summed over the vertices, F = Σᵢ Aᵢ nᵢ·(pᵢ − c) with Aᵢ a third of
//! the area of the triangles at vertex i and c the centroid, its sign says which way the normals
//! the registration uses point (those given, which need not follow the winding). An open surface
//! has no inside: a sheet bent up or bent down changes the sign with no change of its
//! orientation, so only closed meshes count, those whose boundary (the edges of one triangle) is
//! shorter than [`HOLES`] times the square root of their area, so that the small holes of a scan
//! are let through. Normals pointing both ways (|F| below [`CONSISTENCY`] of Σᵢ Aᵢ |nᵢ·(pᵢ − c)|)
//! say neither.

use super::extent::centroid;
use super::weld::weld;
use nalgebra::Vector3;
use rustc_hash::FxHashMap;

/// A closed mesh's boundary may be at most this many times the square root of its area long.
pub const HOLES: f64 = 0.1;
/// |F| must be at least this share of the sum of its terms' magnitudes.
pub const CONSISTENCY: f64 = 0.1;

/// A mesh's vertex positions, unit vertex normals and triangles.
pub type Oriented<'a> = (&'a [Vector3<f64>], &'a [Vector3<f64>], &'a [[u32; 3]]);

/// The way a closed mesh's normals point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Facing {
    /// Out of the inside: the flux F is positive.
    Outward,
    /// Into it.
    Inward,
}

/// The way `mesh`'s normals point, or `None` when it is open (module docs) or its normals point
/// both ways. A triangle soup is welded first, so that its triangles share their edges.
pub fn facing(mesh: Oriented<'_>) -> Option<Facing> {
    let welded = weld(mesh.0, mesh.1, mesh.2);
    let (points, normals, faces) = match &welded {
        Some(w) => (&w.points[..], &w.normals[..], &w.faces[..]),
        None => mesh,
    };
    if normals.len() != points.len() || faces.is_empty() {
        return None;
    }
    let boundary = boundary_length(points, faces)?;
    let vertex_area = vertex_areas(points, faces);
    let area: f64 = vertex_area.iter().sum();
    if !(area > 0.0 && area.is_finite() && boundary <= HOLES * area.sqrt()) {
        return None;
    }
    let c = centroid(points);
    let terms =
        (points.iter().zip(normals).zip(&vertex_area)).map(|((p, n), a)| a * n.dot(&(p - c)));
    let (flux, magnitude) = terms.fold((0.0, 0.0), |(f, m), t| (f + t, m + t.abs()));
    if !(flux.abs() >= CONSISTENCY * magnitude && magnitude > 0.0) {
        return None;
    }
    Some(if flux > 0.0 {
        Facing::Outward
    } else {
        Facing::Inward
    })
}

/// How two meshes' normals point, one against the other.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Relation {
    /// Both closed, their normals pointing the same way (both out, or both in).
    Same,
    /// Both closed, one's normals pointing out and the other's in.
    Opposite,
    /// Either is open, or its normals point both ways ([`facing`] says nothing).
    Unknown,
}

/// How `source`'s and `target`'s normals point, one against the other.
pub fn relation(source: Oriented<'_>, target: Oriented<'_>) -> Relation {
    match (facing(source), facing(target)) {
        (Some(s), Some(t)) if s == t => Relation::Same,
        (Some(_), Some(_)) => Relation::Opposite,
        _ => Relation::Unknown,
    }
}

/// The length of the boundary of `faces` (their edges that one face alone has), or `None` when
/// a face refers past `points` or the length is not finite.
fn boundary_length(points: &[Vector3<f64>], faces: &[[u32; 3]]) -> Option<f64> {
    if faces.iter().flatten().any(|&v| v as usize >= points.len()) {
        return None;
    }
    let boundary: f64 = (boundary_edges(faces).iter())
        .map(|&((a, b), _)| (points[a as usize] - points[b as usize]).norm())
        .sum();
    boundary.is_finite().then_some(boundary)
}

/// The boundary of `faces`: each edge (its two vertices, the lower first) that one face alone
/// has, with that face's index; edges from a vertex to itself are left out.
pub(crate) fn boundary_edges(faces: &[[u32; 3]]) -> Vec<((u32, u32), usize)> {
    let mut uses: FxHashMap<(u32, u32), (u32, usize)> = FxHashMap::default();
    for (i, f) in faces.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            if a != b {
                uses.entry((a.min(b), a.max(b))).or_insert((0, i)).0 += 1;
            }
        }
    }
    (uses.into_iter())
        .filter(|&(_, (count, _))| count == 1)
        .map(|(edge, (_, face))| (edge, face))
        .collect()
}

/// Each vertex's area: a third of the area of each face that has it (every face's vertices
/// must lie in `points`).
pub(crate) fn vertex_areas(points: &[Vector3<f64>], faces: &[[u32; 3]]) -> Vec<f64> {
    let mut areas = vec![0.0; points.len()];
    for f in faces {
        let third = triangle_area(points, f) / 3.0;
        f.iter().for_each(|&v| areas[v as usize] += third);
    }
    areas
}

/// The area of triangle `f`.
fn triangle_area(points: &[Vector3<f64>], f: &[u32; 3]) -> f64 {
    let [a, b, c] = f.map(|v| points[v as usize]);
    (b - a).cross(&(c - a)).norm() / 2.0
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A radius factor for a point `p` of the unit sphere: low bumps of up to a quarter of the
    /// radius, which pin a shape against every rigid and affine slide (modules `slippage`,
    /// `affine_slippage`).
    pub(crate) fn bumps(p: &Vector3<f64>) -> f64 {
        1.0 + 0.15 * (4.0 * p.x + 1.0).sin() + 0.1 * (5.0 * p.y - 2.0 * p.z).sin()
    }

    /// A UV sphere of radius `r` about `o`, `rings` × `2 rings` cells, wound so that its face
    /// normals point out.
    pub(crate) fn sphere(
        r: f64,
        o: Vector3<f64>,
        rings: u32,
    ) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let segments = 2 * rings;
        let mut points = vec![o + Vector3::z() * r, o - Vector3::z() * r];
        for i in 1..rings {
            let theta = std::f64::consts::PI * i as f64 / rings as f64;
            for j in 0..segments {
                let phi = std::f64::consts::TAU * j as f64 / segments as f64;
                let dir = Vector3::new(
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                );
                points.push(o + dir * r);
            }
        }
        let at = |i: u32, j: u32| 2 + (i - 1) * segments + j % segments;
        let mut faces = Vec::new();
        for j in 0..segments {
            faces.push([0, at(1, j), at(1, j + 1)]);
            faces.push([1, at(rings - 1, j + 1), at(rings - 1, j)]);
            for i in 1..rings - 1 {
                faces.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                faces.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
        (points, faces)
    }

    /// The surface of the cube [−1, 1]³, each face an `n` × `n` grid of squares cut in two,
    /// wound so that its face normals point out. Its vertices are the lattice points on the
    /// surface, so every turn of the cube onto itself carries them onto each other.
    pub(crate) fn cube(n: u32) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let mut index = std::collections::HashMap::new();
        let mut points = Vec::new();
        let mut at = |c: [u32; 3]| {
            *index.entry(c).or_insert_with(|| {
                points.push(c.map(|x| 2.0 * x as f64 / n as f64 - 1.0).into());
                points.len() as u32 - 1
            })
        };
        let mut faces = Vec::new();
        for (axis, side) in (0..3).flat_map(|a| [(a, 0), (a, n)]) {
            // (u, v) along the two other axes in cyclic order: u × v along +axis
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for (i, j) in (0..n).flat_map(|i| (0..n).map(move |j| (i, j))) {
                let corner = |di: u32, dj: u32| {
                    let mut c = [side; 3];
                    (c[u], c[v]) = (i + di, j + dj);
                    c
                };
                let [a, b, c, d] = [(0, 0), (1, 0), (1, 1), (0, 1)].map(|(x, y)| at(corner(x, y)));
                if side == n {
                    faces.extend([[a, b, c], [a, c, d]]);
                } else {
                    faces.extend([[a, c, b], [a, d, c]]);
                }
            }
        }
        (points, faces)
    }

    /// The cube's faces point out, and each vertex is on its surface.
    #[test]
    fn the_test_cube_is_closed_and_faces_out() {
        let (p, f) = cube(4);
        assert_eq!(p.len(), 6 * 16 + 2);
        assert!(boundary_edges(&f).is_empty());
        let n = normals_of(&p, &f);
        assert_eq!(facing(mesh(&p, &n, &f)), Some(Facing::Outward));
        assert!(p.iter().all(|q| (q.amax() - 1.0).abs() < 1e-12));
    }

    fn normals_of(points: &[Vector3<f64>], faces: &[[u32; 3]]) -> Vec<Vector3<f64>> {
        let mut n = vec![Vector3::zeros(); points.len()];
        for f in faces {
            let [a, b, c] = f.map(|v| points[v as usize]);
            f.iter()
                .for_each(|&v| n[v as usize] += (b - a).cross(&(c - a)));
        }
        n.iter().map(|v| v.normalize()).collect()
    }

    fn mesh<'a>(p: &'a [Vector3<f64>], n: &'a [Vector3<f64>], f: &'a [[u32; 3]]) -> Oriented<'a> {
        (p, n, f)
    }

    /// A sphere wound outward faces out, wound the other way in, wherever it lies and whatever
    /// its size; the two are opposite, and each is the same as itself.
    #[test]
    fn a_closed_mesh_faces_out_or_in_as_it_is_wound() {
        let (p, f) = sphere(0.3, Vector3::new(40.0, -7.0, 3.0), 12);
        let n = normals_of(&p, &f);
        assert_eq!(facing(mesh(&p, &n, &f)), Some(Facing::Outward));
        let reversed: Vec<[u32; 3]> = f.iter().map(|&[a, b, c]| [a, c, b]).collect();
        let inward = normals_of(&p, &reversed);
        assert_eq!(facing(mesh(&p, &inward, &reversed)), Some(Facing::Inward));
        let (outward, inward) = (mesh(&p, &n, &f), mesh(&p, &inward, &reversed));
        assert_eq!(relation(outward, inward), Relation::Opposite);
        assert_eq!(relation(inward, outward), Relation::Opposite);
        assert_eq!(relation(inward, inward), Relation::Same);
        assert_eq!(relation(outward, outward), Relation::Same);
        // as a triangle soup, the same
        let soup: Vec<Vector3<f64>> = reversed.iter().flatten().map(|&v| p[v as usize]).collect();
        let soup_normals: Vec<Vector3<f64>> = reversed
            .iter()
            .flatten()
            .map(|&v| inward.1[v as usize])
            .collect();
        let soup_faces: Vec<[u32; 3]> = (0..reversed.len() as u32)
            .map(|k| [3 * k, 3 * k + 1, 3 * k + 2])
            .collect();
        assert_eq!(
            facing(mesh(&soup, &soup_normals, &soup_faces)),
            Some(Facing::Inward)
        );
    }

    /// A cap of the sphere (an open surface: bent up or down, a sheet has no inside) and a
    /// closed sphere with half its normals turned say nothing; a small hole is let through.
    #[test]
    fn open_meshes_and_mixed_normals_say_nothing() {
        let (p, f) = sphere(1.0, Vector3::zeros(), 12);
        let n = normals_of(&p, &f);
        let cap: Vec<[u32; 3]> = (f.iter())
            .filter(|t| t.iter().all(|&v| p[v as usize].z > 0.2))
            .copied()
            .collect();
        assert_eq!(facing(mesh(&p, &n, &cap)), None);
        assert_eq!(
            relation(mesh(&p, &n, &f), mesh(&p, &n, &cap)),
            Relation::Unknown
        );
        let mixed: Vec<Vector3<f64>> = (p.iter().zip(&n))
            .map(|(q, m)| if q.x > 0.0 { -m } else { *m })
            .collect();
        assert_eq!(facing(mesh(&p, &mixed, &f)), None);
        // the north pole's fan taken out, a hole 1.6 long against a square root of the area of
        // 3.5, is no small hole; on a finer sphere, one triangle of the fan (0.16) is
        let without_pole: Vec<[u32; 3]> = f.iter().filter(|t| !t.contains(&0)).copied().collect();
        assert_eq!(facing(mesh(&p, &n, &without_pole)), None);
        let finer = sphere(1.0, Vector3::zeros(), 40);
        let fine_normals = normals_of(&finer.0, &finer.1);
        assert_eq!(
            facing(mesh(&finer.0, &fine_normals, &finer.1[1..])),
            Some(Facing::Outward)
        );
    }
}
