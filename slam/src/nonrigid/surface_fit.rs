//! Whether a whole-surface registration registered. The optimiser always returns a field: from a
//! start too far off, onto another shape, or folded onto part of the target, that field is
//! reported with its costs like any other. What can be measured without ground truth is how
//! well the two surfaces lie on each other at the end:
//!
//! - `on_target`: the share of warped source points within a tolerance of the target (its
//!   surface for a mesh target, its points for a cloud);
//! - `covered`: the share of target points within the tolerance of a warped source point: a
//!   source gathered onto part of the target leaves the rest bare;
//! - `facing`: of the source points on the target, the share whose warped normal points the way
//!   the target's does there (a positive dot product): a source laid on the target inside out,
//!   or onto a target whose normals point the other way (a mesh wound the other way round), lies
//!   on it as closely as a right one, and faces it (NOTES 140);
//! - for a mesh onto a mesh, `source_area_ratio` and `area_ratio`: the source's area before and
//!   after the warp over the target's, measured so that the vertices' noise does not count
//!   ([`SurfaceFit::add_areas`], NOTES 107). Bending keeps area, so a whole shape and the whole
//!   of another pose of it keep both near 1 (the camel's 30 maps and 38 chained pairs 0.97–1.09
//!   after, 0.93–1.08 before; onto a copy with noise of 0.5 % of its diagonal at most 1.17);
//!   onto part of the target, the source folds (the camel onto its own half: 2.41 after and
//!   2.14 before, though 99 % of it then lies on the half and covers 81 %) or shrinks (the
//!   source's area at rest is then a multiple of the target's: a tube onto the first third of
//!   its bent copy, in `surface`'s tests).
//!
//! The tolerance is the graph's node spacing: the warp's resolution, relative to the source's
//! size as every setting of [`clean_surface_settings`](super::clean_surface_settings) is.
//! A registration is *registered* when most of the source lies on the target and most of the
//! target is covered ([`MIN_SHARE`] each, the plain meaning of "most", as for frames, NOTES 68),
//! nearly all of it faces the target's way ([`MIN_FACING`]), and, for meshes, the areas agree
//! within [`AREA_FACTOR`]. The camel's 30 maps end with
//! 99.8–100 % on the target and 85–100 % covered. Necessary, not sufficient: a symmetric shape
//! turned over fits as closely as the right way up, a shape that slides along itself fits in
//! every place along the slide (module `slippage`), and a featureless shape stretched fits with
//! its points anywhere along it (module `round_trip`);
//! [`SurfaceRegistration::verdict`](super::SurfaceRegistration::verdict) adds those checks.

use super::affine_slippage::AffineSlide;
use super::global_maps::MapsApart;
use super::graph::DeformationGraph;
use super::register::Target;
use super::round_trip::RoundTrip;
use super::slippage::Slippage;
use super::surface_area::{area, denoised_area, Denoiser};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;
use rayon::prelude::*;

/// The share of the source on the target, and of the target covered, that a registration needs.
pub const MIN_SHARE: f64 = 0.5;
/// The share of the source on the target that must face the way the target does. Registrations
/// that are right face it nearly everywhere (the camel's 30 maps 0.971–1, the sheets' 120 cases
/// 1, a tube onto a copy with noise of an edge's length 0.98); the camel 1 → 3 onto a cloud whose
/// normals point in ended 10.6 % off with 0.57 facing (NOTES 140).
pub const MIN_FACING: f64 = 0.8;
/// A mesh registration's source, before and after the warp, may differ in area from the target
/// by at most this factor (half as much again, or a third less).
pub const AREA_FACTOR: f64 = 1.5;

/// How closely a registration's result and its target lie on each other (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceFit {
    /// Share of the warped source's points within `tolerance` of the target.
    pub on_target: f64,
    /// Share of the target's points within `tolerance` of a warped source point.
    pub covered: f64,
    /// Of the warped source's points within `tolerance` of the target, the share whose warped
    /// normal has a positive dot product with the target's normal there (0 when none is within).
    pub facing: f64,
    /// Median distance from a warped source point to the target.
    pub median_distance: f64,
    /// The distance within which a point counts as on the other surface (the node spacing).
    pub tolerance: f64,
    /// For a mesh onto a mesh, the warped source's area over the target's
    /// ([`SurfaceFit::add_areas`]); `None` for clouds.
    pub area_ratio: Option<f64>,
    /// … and the source's area at rest over the target's.
    pub source_area_ratio: Option<f64>,
}

/// Whether a surface registration can be trusted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SurfaceVerdict {
    /// Most of the source lies on the target facing its way, most of the target is covered,
    /// and (meshes) their areas agree.
    Registered,
    /// One of those failed; the fit says which.
    NotRegistered(SurfaceFit),
    /// The fit registered, but the source or the target slides along itself (the freer one's
    /// motion, module `slippage`): the points may lie anywhere along that motion, and nothing in
    /// the surfaces tells where.
    Ambiguous(Slippage),
    /// The fit registered, but the target registered back onto the source does not bring the
    /// source's points back where they started (module `round_trip`): the surfaces do not fix
    /// where the points go, and the two directions chose differently.
    Inconsistent(RoundTrip),
    /// The fit registered and neither surface slides rigidly, but one of them slides along
    /// itself under a stretch or shear (module `affine_slippage`: an ellipsoid, a stretched
    /// torus) and the answer is not rigid: the same answer composed with that motion fits as
    /// well, and only the regulariser chose among them.
    AffineAmbiguous(AffineSlide),
    /// The fit registered, and two rigid motions, or two moderate affine maps, fitted from
    /// different starts each lay the source on the target as closely as the warp, but carry it
    /// to different places (a box or an ellipsoid after a half turn, a box's faces exchanged by
    /// a stretch; module `global_maps`): the surfaces fit both, and nothing tells which is
    /// right.
    MapsDisagree(MapsApart),
}

impl SurfaceFit {
    /// Measures a registration's result `warped` (points and normals) against the `target` it
    /// was registered onto (`target_points` its points), with the optimised `graph`, all in one
    /// unit of length. Non-finite points count as off the other surface (source) or are left out
    /// (target). Either side without a finite point gives shares of 0 and an infinite median
    /// distance.
    pub fn measure(
        warped: (&[Vector3<f64>], &[Vector3<f64>]),
        target: &dyn Target,
        target_points: &[Vector3<f64>],
        graph: &DeformationGraph,
    ) -> Self {
        let tolerance = graph.params.spacing;
        let finite = |p: &&Vector3<f64>| p.iter().all(|x| x.is_finite());
        // each finite point's distance to the target, and whether its normal faces the target's
        let (mut to_target, facing): (Vec<f64>, Vec<bool>) = warped
            .0
            .par_iter()
            .zip(warped.1)
            .filter(|(p, _)| finite(p))
            .filter_map(|(p, n)| {
                let (q, nq) = target.associate(p)?;
                Some(((p - q).norm(), n.dot(&nq) > 0.0))
            })
            .unzip();
        let warped = warped.0;
        let coords: Vec<[f64; 3]> = warped.iter().filter(finite).map(|&p| p.into()).collect();
        let target_points: Vec<&Vector3<f64>> = target_points.iter().filter(finite).collect();
        let mut fit = Self {
            on_target: 0.0,
            covered: 0.0,
            facing: 0.0,
            median_distance: f64::INFINITY,
            tolerance,
            area_ratio: None,
            source_area_ratio: None,
        };
        if to_target.is_empty() || coords.is_empty() || target_points.is_empty() {
            return fit;
        }
        let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&coords);
        let near = target_points
            .par_iter()
            .filter(|q| {
                let d = tree
                    .nearest_one::<SquaredEuclidean>(&(***q).into())
                    .distance;
                d <= tolerance * tolerance
            })
            .count();
        let close = to_target.iter().filter(|&&d| d <= tolerance).count();
        let faces = (to_target.iter().zip(&facing)).filter(|(&d, &f)| d <= tolerance && f);
        fit.on_target = close as f64 / warped.len() as f64;
        fit.facing = faces.count() as f64 / close.max(1) as f64;
        fit.covered = near as f64 / target_points.len() as f64;
        let mid = to_target.len() / 2;
        fit.median_distance = *to_target.select_nth_unstable_by(mid, f64::total_cmp).1;
        fit
    }

    /// Sets [`Self::area_ratio`] and [`Self::source_area_ratio`]: the area of the triangles
    /// `faces` over the source's points `at_rest` and `warped` against the target's
    /// (`target.1` over `target.0`). The source at rest and the target are measured without
    /// their vertices' noise ([`denoised_area`]): noise of 0.5 % of the camel's diagonal on the
    /// target's vertices had made a right registration's ratios 0.54 (NOTES 107). The warped
    /// source is measured both ways, smoothed (the warp lays it on the target's noise) and as
    /// the ratio at rest times the warp's raw change of area (which keeps a fold's crease), and
    /// the one farther from 1 is kept: a fold is not let through by the smoothing. Left `None`
    /// when the target's area is 0.
    pub fn add_areas(
        &mut self,
        at_rest: &[Vector3<f64>],
        warped: &[Vector3<f64>],
        faces: &[[u32; 3]],
        target: (&[Vector3<f64>], &[[u32; 3]]),
    ) {
        let whole = denoised_area(target.0, target.1);
        if whole > 0.0 {
            let source = Denoiser::new(at_rest.len(), faces);
            let rest_ratio = source.area(at_rest) / whole;
            let smoothed = source.area(warped) / whole;
            // the warp's own change of the raw area keeps a fold's crease and its crumples,
            // which the smoothing rounds away (the camel onto half its target: 1.62 smoothed,
            // 2.41 so); the verdict takes whichever lies farther from 1
            let own = area(at_rest, faces);
            let stretched = rest_ratio * area(warped, faces) / own;
            let off = |r: f64| {
                if r.is_finite() && r > 0.0 {
                    r.ln().abs()
                } else {
                    f64::INFINITY
                }
            };
            let warped_ratio = if own > 0.0 && off(stretched) > off(smoothed) {
                stretched
            } else {
                smoothed
            };
            self.area_ratio = Some(warped_ratio);
            self.source_area_ratio = Some(rest_ratio);
        }
    }

    /// [`SurfaceVerdict::Registered`] when the source lies on the target and covers it
    /// ([`MIN_SHARE`] each), faces its way ([`MIN_FACING`]) and, for meshes, the areas agree
    /// within [`AREA_FACTOR`].
    pub fn verdict(&self) -> SurfaceVerdict {
        let agrees =
            |r: Option<f64>| r.is_none_or(|r| (1.0 / AREA_FACTOR..=AREA_FACTOR).contains(&r));
        let areas_agree = agrees(self.area_ratio) && agrees(self.source_area_ratio);
        let shares = self.on_target >= MIN_SHARE && self.covered >= MIN_SHARE;
        if shares && self.facing >= MIN_FACING && areas_agree {
            SurfaceVerdict::Registered
        } else {
            SurfaceVerdict::NotRegistered(*self)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nonrigid::cloud_target::CloudTarget;
    use crate::nonrigid::graph::GraphParams;

    /// A flat 1 × 1 square of 41 × 41 points in z = 0, normals +z.
    fn square() -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let points: Vec<Vector3<f64>> = (0..41 * 41)
            .map(|k| Vector3::new((k % 41) as f64 / 40.0, (k / 41) as f64 / 40.0, 0.0))
            .collect();
        let normals = vec![Vector3::z(); points.len()];
        (points, normals)
    }

    /// Normals +z for every one of `points`.
    fn up(points: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        vec![Vector3::z(); points.len()]
    }

    fn graph(points: &[Vector3<f64>]) -> DeformationGraph {
        let params = GraphParams {
            spacing: 0.1,
            ..GraphParams::default()
        };
        DeformationGraph::sample(points, params).unwrap()
    }

    #[test]
    fn a_source_on_its_target_registered() {
        let (points, normals) = square();
        let target = CloudTarget::new(&points, &normals);
        let fit = SurfaceFit::measure((&points, &up(&points)), &target, &points, &graph(&points));
        assert_eq!((fit.on_target, fit.covered, fit.facing), (1.0, 1.0, 1.0));
        assert_eq!(fit.median_distance, 0.0);
        assert_eq!(fit.tolerance, 0.1);
        assert_eq!(fit.verdict(), SurfaceVerdict::Registered);
    }

    /// The square on itself with its normals turned over (as a mesh wound the other way round
    /// has them) lies on it as closely and faces it the wrong way; with one in ten turned over
    /// it faces it nearly everywhere, with one in three not.
    #[test]
    fn a_source_on_its_target_facing_the_other_way_is_not_registered() {
        let (points, normals) = square();
        let target = CloudTarget::new(&points, &normals);
        let turned = |every: usize| -> Vec<Vector3<f64>> {
            (0..points.len())
                .map(|k| {
                    if k % every == 0 {
                        -Vector3::z()
                    } else {
                        Vector3::z()
                    }
                })
                .collect()
        };
        let measure = |normals: &[Vector3<f64>]| {
            SurfaceFit::measure((&points, normals), &target, &points, &graph(&points))
        };
        let fit = measure(&turned(1));
        assert_eq!((fit.on_target, fit.covered, fit.facing), (1.0, 1.0, 0.0));
        assert_eq!(fit.verdict(), SurfaceVerdict::NotRegistered(fit));
        let fit = measure(&turned(3));
        assert!((fit.facing - 1120.0 / 1681.0).abs() < 1e-12, "{fit:?}");
        assert_eq!(fit.verdict(), SurfaceVerdict::NotRegistered(fit));
        let fit = measure(&turned(10));
        assert!((fit.facing - 1512.0 / 1681.0).abs() < 1e-12, "{fit:?}");
        assert_eq!(fit.verdict(), SurfaceVerdict::Registered);
    }

    #[test]
    fn a_source_left_beside_its_target_is_not_registered() {
        let (points, normals) = square();
        let target = CloudTarget::new(&points, &normals);
        // 1.5 node spacings above the target
        let left: Vec<Vector3<f64>> = points.iter().map(|p| p + Vector3::z() * 0.15).collect();
        let fit = SurfaceFit::measure((&left, &up(&left)), &target, &points, &graph(&points));
        assert_eq!((fit.on_target, fit.covered), (0.0, 0.0));
        assert!((fit.median_distance - 0.15).abs() < 1e-12);
        assert_eq!(fit.verdict(), SurfaceVerdict::NotRegistered(fit));
    }

    /// The target is the square's left quarter: the whole source cannot lie on it (only about
    /// a quarter does), though the target is covered.
    #[test]
    fn a_source_larger_than_its_target_is_not_registered() {
        let (points, normals) = square();
        let (part, part_normals): (Vec<_>, Vec<_>) = points
            .iter()
            .zip(&normals)
            .filter(|(p, _)| p.x <= 0.25)
            .unzip();
        let target = CloudTarget::new(&part, &part_normals);
        let fit = SurfaceFit::measure((&points, &up(&points)), &target, &part, &graph(&points));
        assert_eq!(fit.covered, 1.0);
        // within a node spacing of x ≤ 0.25: x ≤ 0.35, 15 of 41 columns
        assert!((fit.on_target - 15.0 / 41.0).abs() < 1e-12, "{fit:?}");
        assert!(matches!(fit.verdict(), SurfaceVerdict::NotRegistered(_)));
        // and the other way round, the part onto the whole: on it, but most of it bare
        let whole = CloudTarget::new(&points, &normals);
        let fit = SurfaceFit::measure((&part, &up(&part)), &whole, &points, &graph(&part));
        assert_eq!(fit.on_target, 1.0);
        assert!((fit.covered - 15.0 / 41.0).abs() < 1e-12, "{fit:?}");
        assert!(matches!(fit.verdict(), SurfaceVerdict::NotRegistered(_)));
    }

    /// The square's 40 × 40 cells as triangles.
    fn square_faces() -> Vec<[u32; 3]> {
        let mut faces = Vec::new();
        for j in 0..40u32 {
            for i in 0..40u32 {
                let v = j * 41 + i;
                faces.push([v, v + 1, v + 42]);
                faces.push([v, v + 42, v + 41]);
            }
        }
        faces
    }

    /// The square's right half folded over onto its left: every point lies on the left half
    /// and covers it, but the area laid on it is twice its own.
    #[test]
    fn a_source_folded_onto_half_its_target_is_not_registered() {
        let (points, normals) = square();
        let faces = square_faces();
        let left: Vec<[u32; 3]> = faces
            .iter()
            .filter(|f| f.iter().all(|&v| points[v as usize].x <= 0.5))
            .copied()
            .collect();
        let folded: Vec<Vector3<f64>> = points
            .iter()
            .map(|p| Vector3::new(p.x.min(1.0 - p.x), p.y, 0.0))
            .collect();
        let target = CloudTarget::new(&points, &normals);
        let mut fit =
            SurfaceFit::measure((&folded, &up(&folded)), &target, &points, &graph(&points));
        fit.add_areas(&points, &folded, &faces, (&points, &left));
        assert_eq!(fit.on_target, 1.0);
        let ratio = fit.area_ratio.unwrap();
        assert!((ratio - 2.0).abs() < 1e-9, "{ratio}");
        assert!(matches!(fit.verdict(), SurfaceVerdict::NotRegistered(_)));
        // shrunk onto it instead, the source's own area still says it is twice the target
        let shrunk: Vec<Vector3<f64>> = points
            .iter()
            .map(|p| Vector3::new(p.x / 2.0, p.y, 0.0))
            .collect();
        fit.add_areas(&points, &shrunk, &faces, (&points, &left));
        assert!((fit.area_ratio.unwrap() - 1.0).abs() < 1e-9, "{fit:?}");
        assert!(
            (fit.source_area_ratio.unwrap() - 2.0).abs() < 1e-9,
            "{fit:?}"
        );
        assert!(matches!(fit.verdict(), SurfaceVerdict::NotRegistered(_)));
        // laid flat, the same source and the whole square agree
        fit.add_areas(&points, &points, &faces, (&points, &faces));
        assert_eq!(
            (fit.area_ratio, fit.source_area_ratio),
            (Some(1.0), Some(1.0))
        );
        assert_eq!(fit.verdict(), SurfaceVerdict::Registered);
    }

    #[test]
    fn nothing_finite_to_measure_is_not_registered() {
        let (points, normals) = square();
        let target = CloudTarget::new(&points, &normals);
        let lost = vec![Vector3::repeat(f64::NAN); points.len()];
        let fit = SurfaceFit::measure((&lost, &up(&lost)), &target, &points, &graph(&points));
        assert_eq!((fit.on_target, fit.covered), (0.0, 0.0));
        assert_eq!(fit.median_distance, f64::INFINITY);
        assert!(matches!(fit.verdict(), SurfaceVerdict::NotRegistered(_)));
    }
}
