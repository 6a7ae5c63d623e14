//! Slippage: the rigid motion under which a surface moves least off itself, and whether a
//! registration onto or from it can tell where its points lie along that motion.
//!
//! After Gelfand, Ikemoto, Rusinkiewicz & Levoy, *Geometrically stable sampling for the ICP
//! algorithm* (3DIM 2003), and Gelfand & Guibas, *Shape segmentation using local slippage
//! analysis* (SGP 2004). A small rigid motion, the twist ξ = (ω, t), moves a surface point p by
//! u = ω × p + t. Point-to-plane data terms see only its normal part, n · u = r · ξ with
//! r = (p × n, n), so over the surface (vertex k of area a_k, total area A)
//!
//! ```text
//! C = Σ_k (a_k / A) r_k r_kᵀ,        r_k = (p_k × n_k, n_k)
//! B = Σ_k (a_k / A) J_kᵀ J_k,        J_k = ( −skew(p_k) | I ),  u_k = J_k ξ
//! ```
//!
//! C is what the data terms can measure of ξ, and ξᵀ B ξ is the motion's mean squared
//! displacement. The least eigenvalue of C ξ = λ B ξ is the share of a motion's (mean squared)
//! displacement that leaves the surface: 0 along a continuous symmetry (a sphere turned about
//! any axis, a cylinder, cone or torus about its own, a tube slid along itself), where a
//! registration's data terms cannot tell one answer from another, so its points may lie
//! anywhere along the motion while it fits its target exactly. The measure is unit-free and
//! does not depend on the surface's size.
//!
//! An open surface is also held by its boundary: a boundary edge of length ℓ and outward
//! direction m (in the surface, across the edge) adds (ℓ h / A) (q × m, m)(q × m, m)ᵀ to C at its
//! midpoint q, the boundary counted as a band of width h (the deformation graph's node spacing,
//! as the registration's rim matches see it). A flat sheet thus slides nowhere, while a disc
//! still turns about its normal.

use super::extent::finite;
use super::orientation::{boundary_edges, vertex_areas};
use nalgebra::{Matrix3, Matrix3x6, Matrix6, SMatrix, Vector3, Vector6};

/// Below this share of a motion's displacement leaving the surface, the surface slides along
/// itself. Measured (NOTES 179): Open3D's exactly symmetric primitives 2·10⁻⁷–8·10⁻⁵; of 42
/// random symmetric shapes (`bench/symmetric_shapes.py`) all but one 6.5·10⁻⁸–5.4·10⁻⁴, the one a
/// 16-sided cone of two rings at 1.9·10⁻³ (its quads' diagonals twist the vertex normals);
/// asymmetric shapes 3.5·10⁻³ (a bumpy sphere) and over, primitives with 1 % bumps 2.8·10⁻³ and
/// over, boxes 0.07–0.13, flat sheets 0.06–0.1, the camel's poses 0.15 and over.
pub const MAX_SLIPPAGE: f64 = 1e-3;

/// The rigid motion that moves a surface least off itself.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Slippage {
    /// The share of the motion's mean squared displacement that is normal to the surface (or
    /// across its boundary): 0 for a motion along a symmetry, up to about 1.
    pub ratio: f64,
    /// The motion's rotation (radians per unit of the motion) about the surface's centroid.
    pub rotation: Vector3<f64>,
    /// Its translation at the centroid, in units of the surface's bounding-box diagonal; the
    /// motion is scaled so that it moves the surface's points by 1 diagonal, root mean square.
    pub translation: Vector3<f64>,
}

impl Slippage {
    /// Whether the surface slides along itself ([`MAX_SLIPPAGE`]).
    pub fn is_free(&self) -> bool {
        self.ratio < MAX_SLIPPAGE
    }
}

/// The least-constrained rigid motion of the mesh `faces` over `points` with the vertex
/// `normals`, its boundary counted as a band `band` wide (module docs). `None` where the mesh
/// has no area or its points span less than a plane's worth of motions (all on one line).
/// Faces that refer past `points` or touch a non-finite point are left out, and so are normals
/// that are missing, zero or not finite.
pub fn slippage(
    points: &[Vector3<f64>],
    normals: &[Vector3<f64>],
    faces: &[[u32; 3]],
    band: f64,
) -> Option<Slippage> {
    let (c, b) = Samples::new(points, normals, faces, band)?.sums(constraint, displacement);
    least_motion(c, b)
}

/// A mesh's vertices and boundary crossings as the measures of slippage weigh them: points
/// about the area-weighted centroid in units of the surface's diagonal, each vertex with its
/// share of the area (and its unit normal where it has a usable one), each boundary edge's
/// midpoint with its outward direction and the band's share `ℓ h / A` (module docs).
pub(super) struct Samples {
    /// (p, n, a_k / A) per vertex of positive area.
    pub surface: Vec<(Vector3<f64>, Option<Vector3<f64>>, f64)>,
    /// (q, m, ℓ h / A) per boundary edge.
    pub rim: Vec<(Vector3<f64>, Vector3<f64>, f64)>,
}

impl Samples {
    /// The samples of the mesh `faces` over `points` with the vertex `normals` and a boundary
    /// band `band` wide; `None` where the mesh has no area. Faces that refer past `points` or
    /// touch a non-finite point are left out, and so are normals that are missing, zero or
    /// not finite.
    pub fn new(
        points: &[Vector3<f64>],
        normals: &[Vector3<f64>],
        faces: &[[u32; 3]],
        band: f64,
    ) -> Option<Self> {
        let usable: Vec<[u32; 3]> = faces
            .iter()
            .filter(|f| {
                f.iter()
                    .all(|&v| points.get(v as usize).is_some_and(finite))
            })
            .copied()
            .collect();
        let areas = vertex_areas(points, &usable);
        let total: f64 = areas.iter().sum();
        if total.is_nan() || total <= 0.0 {
            return None;
        }
        // the area-weighted centroid: each vertex once, by its third of its faces' area
        let centre = (areas.iter().zip(points))
            .filter(|(&a, _)| a > 0.0)
            .map(|(&a, p)| a * p)
            .sum::<Vector3<f64>>()
            / total;
        let scale = super::extent::surface_diagonal(points, &usable);
        let at = |p: &Vector3<f64>| (p - centre) / scale;
        let surface = (areas.iter().enumerate())
            .filter(|(_, &a)| a > 0.0)
            .map(|(k, a)| {
                let normal = normals.get(k).filter(|n| finite(n));
                let n = normal.and_then(|n| n.try_normalize(0.0));
                (at(&points[k]), n, a / total)
            })
            .collect();
        let rim = (boundary_crossings(points, &usable).into_iter())
            .map(|(q, m, length)| (at(&q), m, length * band / total))
            .collect();
        Some(Self { surface, rim })
    }

    /// C = Σ w `constraint`(p, n) over the vertices with a normal and the boundary crossings,
    /// and B = Σ w `displacement`(p) over the vertices (module docs), for motions of N unknowns.
    pub fn sums<const N: usize>(
        &self,
        constraint: impl Fn(&Vector3<f64>, &Vector3<f64>) -> SMatrix<f64, N, N>,
        displacement: impl Fn(&Vector3<f64>) -> SMatrix<f64, N, N>,
    ) -> (SMatrix<f64, N, N>, SMatrix<f64, N, N>) {
        let (mut c, mut b) = (SMatrix::zeros(), SMatrix::zeros());
        for (p, n, w) in &self.surface {
            b += *w * displacement(p);
            if let Some(n) = n {
                c += *w * constraint(p, n);
            }
        }
        for (q, m, w) in &self.rim {
            c += *w * constraint(q, m);
        }
        (c, b)
    }
}

/// r = (p × n, n): what a point-to-plane term at p with normal n measures of a twist ξ = (ω, t),
/// n · (ω × p + t) = r · ξ.
pub(super) fn rigid_row(p: &Vector3<f64>, n: &Vector3<f64>) -> Vector6<f64> {
    Vector6::from_iterator(p.cross(n).iter().chain(n.iter()).copied())
}

/// r rᵀ, r = [`rigid_row`]: what a point-to-plane term measures of a twist, squared.
fn constraint(p: &Vector3<f64>, n: &Vector3<f64>) -> Matrix6<f64> {
    let r = rigid_row(p, n);
    r * r.transpose()
}

/// Jᵀ J, J = (−skew(p) | I): a twist's squared displacement of p.
fn displacement(p: &Vector3<f64>) -> Matrix6<f64> {
    let mut j = Matrix3x6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-p.cross_matrix()));
    j.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    j.transpose() * j
}

/// The midpoint, outward direction (in the face's plane, across the edge) and length of each
/// edge that one face alone has.
fn boundary_crossings(
    points: &[Vector3<f64>],
    faces: &[[u32; 3]],
) -> Vec<(Vector3<f64>, Vector3<f64>, f64)> {
    (boundary_edges(faces).into_iter())
        .filter_map(|((a, b), i)| {
            let [p, q, r] = faces[i].map(|v| points[v as usize]);
            let normal = (q - p).cross(&(r - p));
            let (from, to) = (points[a as usize], points[b as usize]);
            let across = (to - from).cross(&normal).try_normalize(0.0)?;
            Some(((from + to) / 2.0, across, (to - from).norm()))
        })
        .collect()
}

/// The least eigenvalue of C ξ = λ B ξ and its ξ scaled to ξᵀ B ξ = 1 (B = L Lᵀ, the symmetric
/// problem L⁻¹ C L⁻ᵀ y = λ y, ξ = L⁻ᵀ y).
fn least_motion(c: Matrix6<f64>, b: Matrix6<f64>) -> Option<Slippage> {
    let l = b.cholesky()?.l();
    let l_inv = l.try_inverse()?;
    let m = l_inv * c * l_inv.transpose();
    let eigen = (0.5 * (m + m.transpose())).symmetric_eigen();
    let (k, &ratio) = eigen
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let xi = l_inv.transpose() * eigen.eigenvectors.column(k);
    ratio.is_finite().then(|| Slippage {
        ratio: ratio.max(0.0),
        rotation: xi.fixed_rows::<3>(0).into(),
        translation: xi.fixed_rows::<3>(3).into(),
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::nonrigid::orientation::tests::sphere;

    /// Outward unit normals of a mesh: its vertices' summed face normals.
    pub(crate) fn normals(points: &[Vector3<f64>], faces: &[[u32; 3]]) -> Vec<Vector3<f64>> {
        let mut n = vec![Vector3::zeros(); points.len()];
        for f in faces {
            let [a, b, c] = f.map(|v| points[v as usize]);
            let face = (b - a).cross(&(c - a));
            f.iter().for_each(|&v| n[v as usize] += face);
        }
        n.iter().map(|n| n.normalize()).collect()
    }

    /// A grid of `nx` × `ny` vertices over [0, sx] × [0, sy] at z = 0, mapped by `f`.
    fn sheet(
        (nx, ny): (u32, u32),
        (sx, sy): (f64, f64),
        f: impl Fn(f64, f64) -> Vector3<f64>,
    ) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let points = (0..ny)
            .flat_map(|j| (0..nx).map(move |i| (i, j)))
            .map(|(i, j)| {
                f(
                    sx * i as f64 / (nx - 1) as f64,
                    sy * j as f64 / (ny - 1) as f64,
                )
            })
            .collect();
        let faces = (0..ny - 1)
            .flat_map(|j| (0..nx - 1).map(move |i| j * nx + i))
            .flat_map(|a| [[a, a + 1, a + nx + 1], [a, a + nx + 1, a + nx]])
            .collect();
        (points, faces)
    }

    fn measure(mesh: &(Vec<Vector3<f64>>, Vec<[u32; 3]>), band: f64) -> Slippage {
        let n = normals(&mesh.0, &mesh.1);
        slippage(&mesh.0, &n, &mesh.1, band).expect("a mesh with area")
    }

    /// A closed tube of `sides` around the z axis, radius 0.15 and 0.8 long (its ends' rims
    /// joined to their centres), scaled by `s`.
    fn capped_tube(sides: u32, s: f64) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let (mut points, mut faces) = sheet((sides + 1, 9), (1.0, 0.8), |u, z| {
            let a = std::f64::consts::TAU * u;
            s * Vector3::new(0.15 * a.cos(), 0.15 * a.sin(), z)
        });
        // the seam: column `sides` is column 0
        for f in &mut faces {
            f.iter_mut()
                .filter(|v| **v % (sides + 1) == sides)
                .for_each(|v| *v -= sides);
        }
        for (row, z, turn) in [(0, 0.0, true), (8, 0.8, false)] {
            let centre = points.len() as u32;
            points.push(s * Vector3::new(0.0, 0.0, z));
            for i in 0..sides {
                let (a, b) = (row * (sides + 1) + i, row * (sides + 1) + (i + 1) % sides);
                faces.push(if turn { [centre, b, a] } else { [centre, a, b] });
            }
        }
        (points, faces)
    }

    #[test]
    fn symmetric_surfaces_slide_about_their_symmetry_and_others_do_not() {
        let ball = measure(&sphere(0.3, Vector3::new(1.0, 2.0, 3.0), 24), 0.03);
        assert!(ball.ratio < 1e-4 && ball.is_free(), "{ball:?}");
        // it turns about an axis through its centre, which is the centroid it is reported about
        assert!(ball.translation.norm() < 0.01, "{ball:?}");
        let tube = measure(&capped_tube(32, 1.0), 0.03);
        assert!(tube.is_free(), "{tube:?}");
        // the free motion is the turn about the tube's own axis
        let axis = tube.rotation.normalize();
        assert!(axis.z.abs() > 0.999, "{tube:?}");
        assert!(tube.translation.norm() < 0.05, "{tube:?}");
        // an ellipsoid of three different axes has no symmetry
        let (mut e, f) = sphere(1.0, Vector3::zeros(), 24);
        e.iter_mut()
            .for_each(|p| *p = p.component_mul(&Vector3::new(1.0, 0.6, 0.35)));
        let egg = measure(&(e, f), 0.03);
        assert!(egg.ratio > 30.0 * MAX_SLIPPAGE, "{egg:?}");
    }

    #[test]
    fn a_flat_sheet_is_held_by_its_boundary_and_a_disc_is_not() {
        let strip = sheet((41, 5), (2.0, 0.1), |x, y| Vector3::new(x, y, 0.0));
        let held = measure(&strip, 0.06);
        assert!(held.ratio > 10.0 * MAX_SLIPPAGE, "{held:?}");
        // without its boundary, a plane slides along itself
        let loose = measure(&strip, 0.0);
        assert!(loose.is_free(), "{loose:?}");
        // a disc (a polar grid) turns about its normal whatever its boundary
        let disc = sheet((65, 12), (1.0, 1.0), |u, r| {
            let a = std::f64::consts::TAU * u;
            Vector3::new((0.05 + r) * a.cos(), (0.05 + r) * a.sin(), 0.0)
        });
        let mut faces = disc.1.clone();
        faces
            .iter_mut()
            .flatten()
            .filter(|v| **v % 65 == 64)
            .for_each(|v| *v -= 64);
        let turned = measure(&(disc.0, faces), 0.06);
        assert!(turned.is_free(), "{turned:?}");
        assert!(turned.rotation.normalize().z.abs() > 0.999, "{turned:?}");
    }

    #[test]
    fn the_measure_does_not_depend_on_size_and_bad_meshes_give_none() {
        let (small, large) = (capped_tube(8, 0.01), capped_tube(8, 100.0));
        let (a, b) = (measure(&small, 0.0), measure(&large, 0.0));
        assert!(
            (a.ratio - b.ratio).abs() <= 1e-9 * a.ratio.max(1e-12),
            "{a:?} {b:?}"
        );
        // no area, a face past the points, a non-finite point
        let line = vec![Vector3::zeros(), Vector3::x(), 2.0 * Vector3::x()];
        let n = vec![Vector3::z(); 3];
        assert_eq!(slippage(&line, &n, &[[0, 1, 2]], 0.1), None);
        assert_eq!(slippage(&line, &n, &[[0, 1, 7]], 0.1), None);
        let (mut p, f) = sphere(1.0, Vector3::zeros(), 12);
        let good = measure(&(p.clone(), f.clone()), 0.1);
        p[5] = Vector3::new(f64::NAN, 0.0, 0.0);
        let n = normals(&p, &f);
        let holed = slippage(&p, &n, &f, 0.1).expect("the rest has area");
        assert!(
            holed.ratio.is_finite() && holed.ratio >= 0.0,
            "{holed:?} {good:?}"
        );
    }
}
