//! A global affine map (or rigid motion) of one surface onto another, and whether it explains
//! the pair as closely as a non-rigid registration does.
//!
//! A featureless shape stretched lies on its target under many warps, and the field's
//! regulariser picks one that need not be the stretch (NOTES 187–188). The affine map nearest
//! the start that lays the source on the target is the stretch itself. It is fitted as
//! iterative closest point with an affine model (Besl and McKay, "A method for registration of
//! 3-D shapes", PAMI 1992), each round pairing every moved source point with its nearest target
//! point and every target point with its nearest moved source point, and taking one
//! Gauss-Newton step of the point-to-plane distances over the pairs (Chen and Medioni, "Object
//! modelling by registration of multiple range images", 1992), each moved point p with its
//! target point y and that point's normal n:
//!
//! `min Σ (n · (δA (p − d) + t − (y − p)))² + μ |ξ|²`,  then A ← (I + δA) A, d ← d + t
//!
//! over ξ = (δA, t) (for a rigid motion, δA (p − d) = ω × (p − d) and A ← exp(ω) A), with d
//! where the map sends the source's centroid and μ a millionth of the normal equations' mean
//! diagonal, which only fixes the directions the pairs leave free. Point-to-point steps, the
//! first form (NOTES 195), crawl along a smooth surface: on a bumpy ellipsoid turned 14° they
//! stalled 9° short, which NOTES 196 took for local minima; point-to-plane steps reach it, and
//! a stretch of 1.3 turned 45° with it (NOTES 197).

use super::extent::{centroid, finite};
use super::slippage::rigid_row;
use crate::eval::umeyama;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, SMatrix, SVector, Vector3};
use rayon::prelude::*;

/// Rounds of pairing and solving at most. Point-to-plane steps reach an exact fit in far
/// fewer, and a pair that no map fits (the camel's poses) runs them all in each of its eleven
/// fits (module `global_maps`): at 100 rounds, the 30 camel maps took 73.7 s against 58.1 s at
/// 30, every verdict, placement and error on three sets of shapes and on those maps the same
/// (NOTES 198).
const ROUNDS: usize = 30;
/// A round that moves the map by less than this share of the source's extent ends the fit.
const CONVERGED: f64 = 1e-10;
/// Points of each side the fit pairs at most, taken evenly through them: twelve unknowns are
/// fixed as well by two thousand points as by all of a 5,000-vertex mesh's, at less cost.
const MAX_POINTS: usize = 2048;
/// The damping of each step, as a share of the normal equations' mean diagonal (module docs).
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

    /// The rigid motion of `source` nearest `placed` (an answer in the source's order) over the
    /// pairs where both are finite, by Horn's closed form (`umeyama` without scale); `None` with
    /// fewer than three such pairs or where they fix no motion.
    pub fn nearest_rigid(source: &[Vector3<f64>], placed: &[Vector3<f64>]) -> Option<Self> {
        let (from, to): (Vec<Point3<f64>>, Vec<Point3<f64>>) = (source.iter().zip(placed))
            .filter(|(p, q)| finite(p) && finite(q))
            .map(|(p, q)| (Point3::from(*p), Point3::from(*q)))
            .unzip();
        Some(Self::of_motion(&umeyama(&from, &to, false)?.isometry))
    }

    /// The rigid motion `motion` as a map.
    pub fn of_motion(motion: &Isometry3<f64>) -> Self {
        Self {
            linear: motion.rotation.to_rotation_matrix().into_inner(),
            centre: Vector3::zeros(),
            moved_centre: motion.translation.vector,
        }
    }

    /// The root mean square distance between where this map and `other` carry the finite ones
    /// of `points`; 0 without any.
    pub fn rms_apart(&self, other: &Self, points: &[Vector3<f64>]) -> f64 {
        let (sum, count) =
            (points.iter().filter(|p| finite(p))).fold((0.0, 0usize), |(sum, count), p| {
                (
                    sum + (self.apply(p) - other.apply(p)).norm_squared(),
                    count + 1,
                )
            });
        (sum / count.max(1) as f64).sqrt()
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

/// The affine map that lays `source` on `target` (module docs; `normals` the target's, by
/// vertex), fitted to at most about 2,048 finite points of each (`MAX_POINTS`) and started at
/// `start`, or else at the translation between their centroids; `None` without finite points
/// on either side or where a round's system cannot be solved. A box has discrete affine maps
/// onto itself (its faces exchanged, each stretched onto the other), and a start far from the
/// right map can end on one of them exactly (NOTES 198).
pub fn fit_affine(
    source: &[Vector3<f64>],
    (target, normals): (&[Vector3<f64>], &[Vector3<f64>]),
    start: Option<&AffineMap>,
) -> Option<AffineMap> {
    fit(source, (target, normals), Model::Affine, start)
}

/// The rigid motion that lays `source` on `target` by the same rounds with a rigid step, from
/// `start` (a rigid motion) or else the centroids; `None` as for [`fit_affine`].
pub fn fit_rigid(
    source: &[Vector3<f64>],
    (target, normals): (&[Vector3<f64>], &[Vector3<f64>]),
    start: Option<&AffineMap>,
) -> Option<AffineMap> {
    fit(source, (target, normals), Model::Rigid, start)
}

/// The affine map that lays `source` on `target` by the same rounds with point-to-point steps
/// (each pair's distance along all three axes), from `start`; `None` as for [`fit_affine`].
/// Within a flat sheet's plane point-to-plane steps see nothing; point-to-point steps pull each
/// point onto its nearest target point, and from a start within a fraction of the sheet of the
/// map they reach it (module `global_maps`, NOTES 199).
pub fn fit_affine_points(
    source: &[Vector3<f64>],
    target: (&[Vector3<f64>], &[Vector3<f64>]),
    start: &AffineMap,
) -> Option<AffineMap> {
    fit(source, target, Model::AffinePoints, Some(start))
}

/// The maps a fit may take, and how its pairs are measured.
#[derive(Clone, Copy, PartialEq)]
enum Model {
    Rigid,
    Affine,
    /// Affine, point to point.
    AffinePoints,
}

/// [`fit_affine`] or [`fit_rigid`]: rounds of pairing and stepping from `start`, or else from
/// the translation between the sampled points' centroids.
fn fit(
    source: &[Vector3<f64>],
    target: (&[Vector3<f64>], &[Vector3<f64>]),
    model: Model,
    start: Option<&AffineMap>,
) -> Option<AffineMap> {
    let source: Vec<Vector3<f64>> = evenly(source, &[]).into_iter().map(|(p, _)| p).collect();
    let (target, normals): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) =
        evenly(target.0, target.1).into_iter().unzip();
    if source.is_empty() || target.is_empty() {
        return None;
    }
    let centre = centroid(&source);
    let mut map = start.map_or(
        AffineMap {
            linear: Matrix3::identity(),
            centre,
            moved_centre: centroid(&target),
        },
        // the same map about the sampled centroid
        |s| AffineMap {
            linear: s.linear,
            centre,
            moved_centre: s.apply(&centre),
        },
    );
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
        let pairs = (moved.iter().zip(&partners.0))
            .map(|(p, &k)| (p, k))
            .chain(partners.1.iter().enumerate().map(|(k, &i)| (&moved[i], k)))
            .map(|(p, k)| (Vector3::from(*p), target[k], normals[k]));
        let next = match model {
            Model::Affine => affine_step(pairs, &map)?,
            Model::AffinePoints => affine_step(
                pairs.flat_map(|(p, y, _)| {
                    [Vector3::x(), Vector3::y(), Vector3::z()].map(|e| (p, y, e))
                }),
                &map,
            )?,
            Model::Rigid => rigid_step(pairs, &map)?,
        };
        let change = (next.linear - map.linear).norm() * extent
            + (next.moved_centre - map.moved_centre).norm();
        map = next;
        if change <= CONVERGED * extent.max(f64::MIN_POSITIVE) {
            break;
        }
    }
    Some(map)
}

/// The damped Gauss-Newton step of the point-to-plane distances over `pairs` (moved point p,
/// target point y, its normal n), each with the row `row(p − d, n)` of N unknowns (module docs),
/// summed in the pairs' order; `None` where the system cannot be solved.
fn step<const N: usize>(
    pairs: impl Iterator<Item = (Vector3<f64>, Vector3<f64>, Vector3<f64>)>,
    d: Vector3<f64>,
    row: impl Fn(&Vector3<f64>, &Vector3<f64>) -> SVector<f64, N>,
) -> Option<SVector<f64, N>> {
    let (mut h, mut g) = (SMatrix::<f64, N, N>::zeros(), SVector::<f64, N>::zeros());
    for (p, y, n) in pairs {
        let j = row(&(p - d), &n);
        h += j * j.transpose();
        g += j * n.dot(&(y - p));
    }
    let mu = TIKHONOV * h.trace() / N as f64;
    for k in 0..N {
        h[(k, k)] += mu;
    }
    let x = h.cholesky()?.solve(&g);
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// r = (n₁ qᵀ, n₂ qᵀ, n₃ qᵀ, nᵀ): what a point-to-plane term at q with normal n measures of an
/// affine motion δA q + t, ξ = (δA row by row, t), n · (δA q + t) = r · ξ.
pub(super) fn affine_row(q: &Vector3<f64>, n: &Vector3<f64>) -> SVector<f64, 12> {
    let mut r = SVector::<f64, 12>::zeros();
    for i in 0..3 {
        r.fixed_rows_mut::<3>(3 * i).copy_from(&(n[i] * q));
    }
    r.fixed_rows_mut::<3>(9).copy_from(n);
    r
}

/// One affine step, rows [`affine_row`] at q = p − d.
fn affine_step(
    pairs: impl Iterator<Item = (Vector3<f64>, Vector3<f64>, Vector3<f64>)>,
    map: &AffineMap,
) -> Option<AffineMap> {
    let x = step(pairs, map.moved_centre, affine_row)?;
    let grow = Matrix3::identity() + Matrix3::from_row_slice(&x.as_slice()[..9]);
    Some(AffineMap {
        linear: grow * map.linear,
        centre: map.centre,
        moved_centre: map.moved_centre + x.fixed_rows::<3>(9),
    })
}

/// One rigid step, rows [`rigid_row`] (q × n, n) for ω × q + t at q = p − d; the rotation
/// taken exactly.
fn rigid_step(
    pairs: impl Iterator<Item = (Vector3<f64>, Vector3<f64>, Vector3<f64>)>,
    map: &AffineMap,
) -> Option<AffineMap> {
    let x = step(pairs, map.moved_centre, rigid_row)?;
    let turn = Rotation3::new(x.fixed_rows::<3>(0).into_owned());
    Some(AffineMap {
        linear: turn.matrix() * map.linear,
        centre: map.centre,
        moved_centre: map.moved_centre + x.fixed_rows::<3>(3),
    })
}

/// The finite points of `points` with their `normals` (zero where missing or not finite), at
/// most about [`MAX_POINTS`], taken evenly through them.
fn evenly(points: &[Vector3<f64>], normals: &[Vector3<f64>]) -> Vec<(Vector3<f64>, Vector3<f64>)> {
    let normal = |k: usize| {
        (normals.get(k).filter(|n| finite(n)))
            .and_then(|n| n.try_normalize(0.0))
            .unwrap_or_else(Vector3::zeros)
    };
    let kept: Vec<(Vector3<f64>, Vector3<f64>)> = (points.iter().enumerate())
        .filter(|(_, p)| finite(p))
        .map(|(k, p)| (*p, normal(k)))
        .collect();
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

    /// The largest absolute coordinate of the set's points (0 without any).
    pub fn largest_coordinate(&self) -> f64 {
        (self.coords.iter().flatten()).fold(0.0, |m: f64, x| m.max(x.abs()))
    }

    /// The median of every point's distance to the nearest point of the other set, both ways
    /// (`points` to this set, this set to `points`): how closely two point sets lie on each
    /// other, whichever of them is larger. Infinite where either has no finite point.
    pub fn two_way_median(&self, points: &[Vector3<f64>]) -> f64 {
        self.two_way_quantile(points, 0.5)
    }

    /// As [`Self::two_way_median`], the distance that `share` (in [0, 1]) of the distances do
    /// not exceed, where the median is 0.5 and the largest 1.
    pub fn two_way_quantile(&self, points: &[Vector3<f64>], share: f64) -> f64 {
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
        let rank = ((share.clamp(0.0, 1.0) * all.len() as f64) as usize).min(all.len() - 1);
        *all.select_nth_unstable_by(rank, f64::total_cmp).1
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
    use crate::nonrigid::orientation::tests::{bumps, cube, sphere};
    use crate::nonrigid::slippage::tests::normals;
    use nalgebra::Unit;

    /// An egg (a sphere mesh with axes 1, 0.7, 0.45), its radius modulated by bumps of a
    /// fifth of it at most, or plain; with its faces.
    fn egg(bumpy: bool) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let (unit, faces) = sphere(1.0, Vector3::zeros(), 24);
        let points = (unit.iter())
            .map(|p| {
                (if bumpy { bumps(p) } else { 1.0 } * p)
                    .component_mul(&Vector3::new(1.0, 0.7, 0.45))
            })
            .collect();
        (points, faces)
    }

    /// `points` carried by `linear` about their centroid and moved by `shift`.
    fn carried(
        points: &[Vector3<f64>],
        linear: Matrix3<f64>,
        shift: Vector3<f64>,
    ) -> Vec<Vector3<f64>> {
        let c = centroid(points);
        points
            .iter()
            .map(|p| linear * (p - c) + c + shift)
            .collect()
    }

    /// The largest distance of `map`'s image of `source` from `target`, point by point.
    fn worst(map: &AffineMap, source: &[Vector3<f64>], target: &[Vector3<f64>]) -> f64 {
        (source.iter().zip(target))
            .map(|(p, q)| (map.apply(p) - q).norm())
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_bumpy_egg_stretched_and_turned_45_degrees_is_laid_back_by_its_affine_map() {
        let (source, faces) = egg(true);
        let axis = Unit::new_normalize(Vector3::new(0.6, 0.3, -0.2));
        let stretch = Matrix3::identity() + 0.3 * axis.as_ref() * axis.transpose();
        let turn = Rotation3::from_axis_angle(
            &Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8)),
            std::f64::consts::FRAC_PI_4,
        );
        let target = carried(
            &source,
            turn.matrix() * stretch,
            Vector3::new(0.1, -0.05, 0.02),
        );
        let map = fit_affine(&source, (&target, &normals(&target, &faces)), None).unwrap();
        let off = worst(&map, &source, &target);
        assert!(off < 1e-6, "{off} {map:?}");
        assert!(map.is_moderate());
        let moved: Vec<Vector3<f64>> = source.iter().map(|p| map.apply(p)).collect();
        assert!(PointSet::new(&target).two_way_median(&moved) < 1e-6);
        // a vertex normal (summed face normals) of the carried surface is A⁻ᵀ n
        let m = map.normal_transform().unwrap() * normals(&source, &faces)[100];
        let carried_normal = normals(&moved, &faces)[100];
        assert!((m.normalize() - carried_normal).norm() < 1e-9, "{m:?}");
    }

    #[test]
    fn a_plain_ellipsoid_is_laid_on_its_stretch_by_some_affine_map() {
        // an ellipsoid has a family of such maps (module `affine_slippage`); the fit lays it
        // on the target, which of them it is the surface cannot tell
        let (source, faces) = egg(false);
        let axis = Unit::new_normalize(Vector3::new(0.2, 0.9, 0.1));
        let stretch = Matrix3::identity() + 0.25 * axis.as_ref() * axis.transpose();
        let target = carried(&source, stretch, Vector3::new(2.0, -1.0, 0.5));
        let map = fit_affine(&source, (&target, &normals(&target, &faces)), None).unwrap();
        let moved: Vec<Vector3<f64>> = source.iter().map(|p| map.apply(p)).collect();
        let median = PointSet::new(&target).two_way_median(&moved);
        assert!(median < 0.01, "{median} {map:?}");
    }

    #[test]
    fn a_flat_sheet_keeps_the_identity_where_its_pairs_see_nothing_and_a_flattening_map_is_not_moderate(
    ) {
        let sheet: Vec<Vector3<f64>> = (0..400)
            .map(|k| Vector3::new((k % 20) as f64 * 0.05, (k / 20) as f64 * 0.03, 0.0))
            .collect();
        let up = vec![Vector3::z(); sheet.len()];
        let target = carried(
            &sheet,
            Matrix3::from_diagonal(&Vector3::new(1.3, 1.0, 1.0)),
            Vector3::zeros(),
        );
        let map = fit_affine(&sheet, (&target, &up), None).unwrap();
        // point-to-plane pairs see only the normal direction: within the plane and along the
        // normal the map keeps the identity (why open meshes are not judged by it,
        // `surface::Closeness::explained_by`)
        assert!((map.linear - Matrix3::identity()).norm() < 1e-6, "{map:?}");
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
    fn a_turned_bumpy_egg_is_laid_back_by_its_rigid_motion() {
        let (source, faces) = egg(true);
        let axis = Unit::new_normalize(Vector3::new(-0.4, 0.7, 0.2));
        let turns = [
            Rotation3::from_euler_angles(0.2, -0.1, 0.25),
            Rotation3::from_axis_angle(&axis, 0.7),
        ];
        for turn in turns {
            let target = carried(&source, turn.into_inner(), Vector3::new(0.1, -0.05, 0.02));
            let map = fit_rigid(&source, (&target, &normals(&target, &faces)), None).unwrap();
            let off = worst(&map, &source, &target);
            assert!(off < 1e-6, "{off} {map:?}");
            assert!((map.linear.determinant() - 1.0).abs() < 1e-9);
            // the motion nearest an answer is that answer's where the answer is rigid
            let near = AffineMap::nearest_rigid(&source, &target).unwrap();
            assert!((near.linear - turn.into_inner()).norm() < 1e-9, "{near:?}");
            assert!(worst(&near, &source, &target) < 1e-9);
        }
    }

    /// A box has discrete affine maps onto itself: a cube stretched along x lies exactly on its
    /// target under the stretch after each quarter turn about x (its faces exchanged). Started
    /// near one of them, the fit ends on it; the one nearest the start is the one it finds
    /// (NOTES 198).
    #[test]
    fn a_stretched_cube_is_laid_exactly_by_the_stretch_after_a_quarter_turn_too() {
        let (points, faces) = cube(6);
        let stretch = Matrix3::from_diagonal(&Vector3::new(1.3, 1.0, 1.0));
        let target = carried(&points, stretch, Vector3::new(0.1, 0.0, -0.05));
        let normals = normals(&target, &faces);
        let about_x = |a: f64| *Rotation3::from_axis_angle(&Vector3::x_axis(), a).matrix();
        let from = |turn: f64| {
            let start = AffineMap {
                linear: about_x(turn),
                centre: centroid(&points),
                moved_centre: centroid(&target),
            };
            fit_affine(&points, (&target, &normals), Some(&start)).unwrap()
        };
        let right = from(0.3);
        assert!(worst(&right, &points, &target) < 1e-6, "{right:?}");
        let quarter = from(1.3);
        let expected = stretch * about_x(std::f64::consts::FRAC_PI_2);
        assert!((quarter.linear - expected).norm() < 1e-6, "{quarter:?}");
        assert!(quarter.is_moderate());
        let moved: Vec<Vector3<f64>> = points.iter().map(|p| quarter.apply(p)).collect();
        assert!(PointSet::new(&target).two_way_median(&moved) < 1e-9);
        // a quarter turn carries a point of the cube by 0.8–1.8 of its half side
        let apart = right.rms_apart(&quarter, &points);
        assert!(apart > 0.8, "{apart}");
        assert_eq!(right.rms_apart(&right, &points), 0.0);
    }

    #[test]
    fn no_finite_point_gives_no_map_and_an_infinite_median() {
        let (e, faces) = egg(false);
        let n = normals(&e, &faces);
        let nan = [Vector3::repeat(f64::NAN)];
        assert!(fit_affine(&nan, (&e, &n), None).is_none());
        assert!(fit_affine(&e, (&[], &[]), None).is_none());
        assert!(fit_rigid(&e, (&nan, &n), None).is_none());
        // without the target's normals the pairs see nothing, and no map is made up
        assert!(fit_affine(&e, (&e, &[]), None).is_none());
        assert!(fit_rigid(&e, (&e, &vec![Vector3::zeros(); e.len()]), None).is_none());
        assert_eq!(PointSet::new(&e).two_way_median(&nan), f64::INFINITY);
        assert_eq!(PointSet::new(&nan).two_way_median(&e), f64::INFINITY);
    }
}
