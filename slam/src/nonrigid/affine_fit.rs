//! A global affine map of one surface onto another, and whether it explains the pair as closely
//! as a non-rigid registration does.
//!
//! A featureless shape stretched lies on its target under many warps, and the field's
//! regulariser picks one that need not be the stretch (NOTES 187–188). The affine map nearest
//! the identity that lays the source on the target is the stretch itself. It is fitted as
//! iterative closest point with an affine model (Besl and McKay, "A method for registration of
//! 3-D shapes", PAMI 1992; the affine step as in Amberg, Romdhani and Vetter, "Optimal step
//! nonrigid ICP algorithms for surface registration", CVPR 2007, at infinite stiffness): each
//! round pairs every source point with its nearest target point and every target point with its
//! nearest moved source point, and solves
//!
//! `min Σ |A (x − c) + d − y|² + μ ‖A − I‖²_F`
//!
//! over the pairs (x, y), c the source's centroid. μ is a millionth of the pairs' spread, so it
//! only fixes directions the pairs leave free (a flat sheet's normal), where A keeps the
//! identity.

use super::extent::{centroid, finite};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, Matrix4, Matrix4x3, Vector3, Vector4};
use rayon::prelude::*;

/// Rounds of pairing and solving at most.
const ROUNDS: usize = 100;
/// A round that moves the map by less than this share of the source's extent ends the fit.
const CONVERGED: f64 = 1e-12;
/// Points of each side the fit pairs at most, taken evenly through them: twelve unknowns are
/// fixed as well by two thousand points as by all of a 5,000-vertex mesh's, at less cost.
const MAX_POINTS: usize = 2048;
/// The pull towards the identity, as a share of the pairs' spread (module docs).
const TIKHONOV: f64 = 1e-6;
/// An affine map whose singular values all lie within this factor of 1 (and that does not
/// mirror) is a stretch a registration may take; beyond it, the map flattens or blows up a
/// direction the pairs barely fix (a sheet onto a curved target), and is not taken.
pub const MAX_AFFINE_STRETCH: f64 = 2.0;

/// `x ↦ A (x − c) + d`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AffineMap {
    /// A.
    pub linear: Matrix3<f64>,
    /// The source's centroid c.
    pub centre: Vector3<f64>,
    /// Where c goes, d.
    pub moved_centre: Vector3<f64>,
}

impl AffineMap {
    /// The map applied to a point.
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.linear * (p - self.centre) + self.moved_centre
    }

    /// `A⁻ᵀ`, which carries normals (each to be normalised after); `None` where A is singular.
    pub fn normal_transform(&self) -> Option<Matrix3<f64>> {
        Some(self.linear.try_inverse()?.transpose())
    }

    /// Whether the map keeps orientation and stretches no direction by more than
    /// [`MAX_AFFINE_STRETCH`] either way.
    pub fn is_moderate(&self) -> bool {
        let s = self.linear.singular_values();
        self.linear.determinant() > 0.0
            && s.iter()
                .all(|&v| (1.0 / MAX_AFFINE_STRETCH..=MAX_AFFINE_STRETCH).contains(&v))
    }
}

/// The affine map that lays `source` on `target` (module docs), fitted to at most about
/// 2,048 finite points of each (`MAX_POINTS`) and started at the translation between their
/// centroids; `None` without finite points on either side or where a round's system cannot be
/// solved.
pub fn fit_affine(source: &[Vector3<f64>], target: &[Vector3<f64>]) -> Option<AffineMap> {
    let source = evenly(source);
    let target = evenly(target);
    if source.is_empty() || target.is_empty() {
        return None;
    }
    let centre = centroid(&source);
    let mut map = AffineMap {
        linear: Matrix3::identity(),
        centre,
        moved_centre: centroid(&target),
    };
    let extent = source
        .iter()
        .map(|p| (p - centre).norm())
        .fold(0.0, f64::max);
    let target_set = PointSet::new(&target);
    let mut moved = vec![[0.0; 3]; source.len()];
    let mut partners = (vec![0; source.len()], vec![0; target.len()]);
    for _ in 0..ROUNDS {
        moved
            .par_iter_mut()
            .zip(&source)
            .for_each(|(m, p)| *m = map.apply(p).into());
        pair(&target, (&target_set.tree, &moved), &mut partners);
        let next = solve_round(&source, &target, &partners, centre)?;
        let change = (next.linear - map.linear).norm() * extent
            + (next.moved_centre - map.moved_centre).norm();
        map = next;
        if change <= CONVERGED * extent.max(f64::MIN_POSITIVE) {
            break;
        }
    }
    Some(map)
}

/// The finite points of `points`, at most about [`MAX_POINTS`], taken evenly through them.
fn evenly(points: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let kept: Vec<Vector3<f64>> = points.iter().filter(|p| finite(p)).copied().collect();
    let step = kept.len().div_ceil(MAX_POINTS).max(1);
    kept.into_iter().step_by(step).collect()
}

/// Each moved source point's nearest target point (`partners.0`) and each target point's
/// nearest moved source point (`partners.1`), found in parallel into the buffers.
fn pair(
    target: &[Vector3<f64>],
    (tree, moved): (&ImmutableKdTree<f64, 3>, &[[f64; 3]]),
    partners: &mut (Vec<usize>, Vec<usize>),
) {
    let nearest = |t: &ImmutableKdTree<f64, 3>, q: &[f64; 3]| {
        t.nearest_one::<SquaredEuclidean>(q).item as usize
    };
    let moved_tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(moved);
    (partners.0.par_iter_mut().zip(moved)).for_each(|(k, q)| *k = nearest(tree, q));
    (partners.1.par_iter_mut().zip(target))
        .for_each(|(i, t)| *i = nearest(&moved_tree, &(*t).into()));
}

/// The map that fits the pairs of [`pair`] best, summed in their order (the bits do not hang
/// on the schedule that found them).
fn solve_round(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
    (forward, backward): &(Vec<usize>, Vec<usize>),
    centre: Vector3<f64>,
) -> Option<AffineMap> {
    let pairs = (source.iter().zip(forward.iter().map(|&k| &target[k])))
        .chain(backward.iter().map(|&i| &source[i]).zip(target));
    let (mut m, mut c) = (Matrix4::zeros(), Matrix4x3::zeros());
    for (x, y) in pairs {
        let u = Vector4::new(x.x - centre.x, x.y - centre.y, x.z - centre.z, 1.0);
        m += u * u.transpose();
        c += u * y.transpose();
    }
    let mu = TIKHONOV * (m[(0, 0)] + m[(1, 1)] + m[(2, 2)]);
    for k in 0..3 {
        m[(k, k)] += mu;
        c[(k, k)] += mu;
    }
    let w = m.cholesky()?.solve(&c);
    Some(AffineMap {
        linear: w.fixed_view::<3, 3>(0, 0).transpose(),
        centre,
        moved_centre: w.row(3).transpose(),
    })
}

/// The finite points of a set with a tree over them, for [`Self::two_way_median`]s against
/// other sets.
pub struct PointSet {
    coords: Vec<[f64; 3]>,
    tree: ImmutableKdTree<f64, 3>,
}

impl PointSet {
    /// The finite ones of `points`.
    pub fn new(points: &[Vector3<f64>]) -> Self {
        let coords: Vec<[f64; 3]> = finite_coords(points);
        let tree = ImmutableKdTree::new_from_slice(&coords);
        Self { coords, tree }
    }

    /// The median of every point's distance to the nearest point of the other set, both ways
    /// (`points` to this set, this set to `points`): how closely two point sets lie on each
    /// other, whichever of them is larger. Infinite where either has no finite point.
    pub fn two_way_median(&self, points: &[Vector3<f64>]) -> f64 {
        let points = finite_coords(points);
        if points.is_empty() || self.coords.is_empty() {
            return f64::INFINITY;
        }
        let distances = |from: &[[f64; 3]], tree: &ImmutableKdTree<f64, 3>| {
            from.par_iter()
                .map(|q| tree.nearest_one::<SquaredEuclidean>(q).distance.sqrt())
                .collect::<Vec<f64>>()
        };
        let mut all = distances(&points, &self.tree);
        all.extend(distances(
            &self.coords,
            &ImmutableKdTree::new_from_slice(&points),
        ));
        let mid = all.len() / 2;
        *all.select_nth_unstable_by(mid, f64::total_cmp).1
    }
}

/// The finite points of `points` as coordinates.
fn finite_coords(points: &[Vector3<f64>]) -> Vec<[f64; 3]> {
    points
        .iter()
        .filter(|p| finite(p))
        .map(|&p| p.into())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Unit};

    /// An ellipsoid's points (axes 1, 0.7, 0.45), a lattice over its parameters.
    fn ellipsoid() -> Vec<Vector3<f64>> {
        let mut out = Vec::new();
        for i in 1..30 {
            let theta = std::f64::consts::PI * i as f64 / 30.0;
            for j in 0..60 {
                let phi = std::f64::consts::TAU * j as f64 / 60.0;
                let d = Vector3::new(
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                );
                out.push(Vector3::new(d.x, 0.7 * d.y, 0.45 * d.z));
            }
        }
        out
    }

    /// `points` stretched by `1 + s` along `axis` through their centroid.
    fn stretched(points: &[Vector3<f64>], axis: &Unit<Vector3<f64>>, s: f64) -> Vec<Vector3<f64>> {
        let c = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
        points
            .iter()
            .map(|p| p + axis.as_ref() * (s * (p - c).dot(axis)))
            .collect()
    }

    #[test]
    fn a_stretched_ellipsoid_is_laid_back_by_its_stretch() {
        let turn = Rotation3::from_euler_angles(0.3, -0.5, 0.9);
        let source: Vec<Vector3<f64>> = ellipsoid()
            .iter()
            .map(|p| turn * p + Vector3::new(2.0, -1.0, 0.5))
            .collect();
        let axis = Unit::new_normalize(turn * Vector3::x());
        let target = stretched(&source, &axis, 0.2);
        let map = fit_affine(&source, &target).unwrap();
        let worst = source
            .iter()
            .zip(&target)
            .map(|(p, q)| (map.apply(p) - q).norm())
            .fold(0.0, f64::max);
        assert!(worst < 1e-6, "{worst} {map:?}");
        assert!(map.is_moderate());
        let moved: Vec<Vector3<f64>> = source.iter().map(|p| map.apply(p)).collect();
        assert!(PointSet::new(&target).two_way_median(&moved) < 1e-6);
        // a normal of the stretched surface is A⁻ᵀ n: orthogonal to the stretched tangents
        let (p, q) = (source[100], source[101]);
        let n = (p - source[160]).cross(&(q - p)).normalize();
        let m = map.normal_transform().unwrap() * n;
        assert!(m.dot(&(map.apply(&q) - map.apply(&p))).abs() < 1e-9);
    }

    #[test]
    fn a_flat_sheet_keeps_its_normal_direction_and_a_flattening_map_is_not_moderate() {
        let sheet: Vec<Vector3<f64>> = (0..400)
            .map(|k| Vector3::new((k % 20) as f64 * 0.05, (k / 20) as f64 * 0.03, 0.0))
            .collect();
        let axis = Unit::new_normalize(Vector3::x());
        let map = fit_affine(&sheet, &stretched(&sheet, &axis, 0.3)).unwrap();
        // the pairs leave the normal direction free: the identity keeps it
        assert!((map.linear[(2, 2)] - 1.0).abs() < 1e-6, "{map:?}");
        assert!(
            map.linear[(0, 2)].abs() + map.linear[(2, 0)].abs() < 1e-6,
            "{map:?}"
        );
        // within the plane the pairs snap to the lattice and the stretch stalls short of 1.3
        // (why open meshes are not judged by it, `surface::explains_as_closely`)
        assert!(
            map.linear[(0, 0)] > 1.05 && map.linear[(0, 0)] < 1.3,
            "{map:?}"
        );
        let flat = AffineMap {
            linear: Matrix3::from_diagonal(&Vector3::new(1.2, 1.0, 0.3)),
            ..map
        };
        assert!(!flat.is_moderate());
        let mirrored = AffineMap {
            linear: Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0)),
            ..map
        };
        assert!(!mirrored.is_moderate());
    }

    #[test]
    fn no_finite_point_gives_no_map_and_an_infinite_median() {
        let nan = [Vector3::repeat(f64::NAN)];
        assert!(fit_affine(&nan, &ellipsoid()).is_none());
        assert!(fit_affine(&ellipsoid(), &[]).is_none());
        assert_eq!(
            PointSet::new(&ellipsoid()).two_way_median(&nan),
            f64::INFINITY
        );
        assert_eq!(
            PointSet::new(&nan).two_way_median(&ellipsoid()),
            f64::INFINITY
        );
    }
}
