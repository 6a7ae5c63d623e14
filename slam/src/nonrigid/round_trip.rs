//! Whether a surface registration comes back: the forward–backward ("round trip") check.
//!
//! A registration of the source onto the target moves each source point `p` to `f(p)`. The
//! registration of the target back onto the source gives a warp `b` over the target. Where the
//! surfaces fix the correspondence themselves, `b(f(p)) ≈ p`. Where they leave it open, each
//! direction settles where its own regulariser is cheapest, and the two disagree. A featureless
//! shape stretched, or bent so that no isometry carries one surface onto the other, is such a
//! case: it lies on its target as closely as a right registration does (NOTES 187).
//!
//! The measure, over the source points whose `f(p)` lies within the node spacing of a target
//! point:
//!
//! `e = mean |b(f(p)) − p|` against `m = mean |f(p) − p|`,
//!
//! the error of the round trip against the displacement the registration claims. It is the
//! forward–backward check of optical flow (Sundaram, Brox and Keutzer, "Dense point trajectories
//! by GPU-accelerated large displacement optical flow", ECCV 2010), applied to whole surfaces.
//! The registration *holds* when `e ≤ MAX_ROUND_TRIP · m`, or when `e` is under a floor that
//! no ratio can judge below: [`ROUND_TRIP_FLOOR`] of the node spacing, or [`NOISE_FLOOR`] times
//! the fit's median distance, where the target's noise is larger. A pair that barely moves, or
//! a target that differs from the source by its noise alone, moves by about what each way's fit
//! to the noise adds to the trip.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;
use rayon::prelude::*;
use std::num::NonZero;

/// The target points whose backward displacements carry a point back.
pub const NEIGHBOURS: usize = 4;

/// The largest round-trip error a registration may have, as a share of the mean displacement
/// it claims. Chosen on the 30 camel maps (right answers, 0.29–2.64 % mean error: 0.040–0.194)
/// and five wrong answers among `bench/symmetric_shapes.py`'s asymmetric shapes of seed 7, bent
/// or stretched (0.63–1.79, 0.9–5 % of the diagonal off), at about the geometric mean of the
/// two sides (NOTES 188).
pub const MAX_ROUND_TRIP: f64 = 0.35;

/// A round-trip error below this share of the node spacing (the warp's resolution) holds
/// whatever the ratio: the ratio of two small numbers says nothing. At 0.1 an ellipsoid bent by
/// under a third of the spacing, 33 % of its displacement off, came back 0.49 of it off and
/// passed; the right answers of the same sets came back within 0.05 of their displacement
/// (NOTES 188).
pub const ROUND_TRIP_FLOOR: f64 = 0.05;

/// A round-trip error below this multiple of the fit's median distance holds whatever the
/// ratio. A target with noise is fitted by each way to its noise: a vertex off by σ along the
/// normal lies a median 0.67 σ off, and two such fits put the trip some √2 · 1.5 ≈ 2 medians
/// off. The camel onto a copy of itself with noise of 0.5 % of its diagonal came back 0.24 node
/// spacings off, 1.2 times what it moved, at a median of 0.155 spacings (NOTES 188).
pub const NOISE_FLOOR: f64 = 2.0;

/// The round trip of a registration (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoundTrip {
    /// Mean distance from a source point to where the round trip brings it back, `e`.
    pub mean: f64,
    /// Mean distance the forward registration moved the same points, `m`.
    pub moved: f64,
    /// The points measured: those that landed near the target.
    pub points: usize,
    /// The larger of [`ROUND_TRIP_FLOOR`] of the tolerance (the node spacing) and
    /// [`NOISE_FLOOR`] times the fit's median distance.
    pub floor: f64,
}

impl RoundTrip {
    /// The round trip of `source` (at rest) moved to `forward` (in its order) and brought back
    /// by the registration that moved `target` (at rest) to `backward` (in its order), all in
    /// one unit of length. The way back at a point is the backward displacement of its
    /// [`NEIGHBOURS`] nearest target points, weighted by their inverse distances: the backward
    /// registration's result as it stands, whatever binding of points to nodes it used. Only
    /// points within `tolerance` of a target point count; `None` when none is (nothing came
    /// near the target, which the fit reports). `median` is the forward fit's median distance
    /// to the target (for the floor; ignored when not finite).
    pub fn measure(
        source: &[Vector3<f64>],
        forward: &[Vector3<f64>],
        (target, backward): (&[Vector3<f64>], &[Vector3<f64>]),
        (tolerance, median): (f64, f64),
    ) -> Option<Self> {
        let blend = Blend::over(target, tolerance);
        let finite = |q: &Vector3<f64>| q.iter().all(|x| x.is_finite());
        let (back, moved, points) = source
            .par_iter()
            .zip(forward)
            .filter(|(_, q)| finite(q))
            .filter_map(|(p, q)| {
                let ([sum], weights) = blend.sums(q, |i| [backward[i] - target[i]])?;
                let returned = q + sum / weights;
                Some(((returned - p).norm(), (q - p).norm(), 1usize))
            })
            .reduce(|| (0.0, 0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2));
        (points > 0).then(|| Self {
            mean: back / points as f64,
            moved: moved / points as f64,
            points,
            floor: if median.is_finite() {
                (ROUND_TRIP_FLOOR * tolerance).max(NOISE_FLOOR * median)
            } else {
                ROUND_TRIP_FLOOR * tolerance
            },
        })
    }

    /// `e / m`: the round trip's error as a share of the displacement claimed (infinite when
    /// nothing moved and the trip did not come back).
    pub fn ratio(&self) -> f64 {
        if self.mean == 0.0 {
            0.0
        } else {
            self.mean / self.moved
        }
    }

    /// Whether the registration comes back (module docs).
    pub fn holds(&self) -> bool {
        self.mean <= self.floor || self.ratio() <= MAX_ROUND_TRIP
    }
}

/// Inverse-distance blending over a set of points: the [`NEIGHBOURS`] nearest a query, each
/// weighed `1 / (d + 10⁻⁹ tolerance)` (finite where the query lies on a point, as a vertex of
/// the same meshing does, and never so large that a sum of weighted coordinates overflows),
/// where the nearest lies within `tolerance`.
struct Blend {
    tree: ImmutableKdTree<f64, 3>,
    neighbours: Option<NonZero<usize>>,
    tolerance: f64,
}

impl Blend {
    fn over(points: &[Vector3<f64>], tolerance: f64) -> Self {
        let coords: Vec<[f64; 3]> = points.iter().map(|&p| p.into()).collect();
        Self {
            tree: ImmutableKdTree::new_from_slice(&coords),
            neighbours: NonZero::new(NEIGHBOURS.min(points.len())),
            tolerance,
        }
    }

    /// `Σ w_i f(i)` for each of the `N` quantities `f` gives, and `Σ w_i`, over the neighbours
    /// of `q`; `None` where there are no points or the nearest lies farther than the tolerance.
    fn sums<const N: usize>(
        &self,
        q: &Vector3<f64>,
        f: impl Fn(usize) -> [Vector3<f64>; N],
    ) -> Option<([Vector3<f64>; N], f64)> {
        let near = self
            .tree
            .nearest_n::<SquaredEuclidean>(&(*q).into(), self.neighbours?);
        if near.first()?.distance > self.tolerance * self.tolerance {
            return None;
        }
        let (mut sums, mut weights) = ([Vector3::zeros(); N], 0.0);
        for n in &near {
            let w = 1.0 / (n.distance.sqrt() + 1e-9 * self.tolerance);
            for (sum, x) in sums.iter_mut().zip(f(n.item as usize)) {
                *sum += w * x;
            }
            weights += w;
        }
        Some((sums, weights))
    }
}

/// Where the way back places each of `source`'s points: `backward` holds the target's points
/// (`target.0`, normals `target.1`) warped onto the source, so a source point takes the target
/// positions and normals of the [`NEIGHBOURS`] warped points nearest it, blended by inverse
/// distance. `None` where the nearest lies farther than `tolerance` (the way back did not reach
/// there) or `backward` holds no point.
pub fn placed_back(
    source: &[Vector3<f64>],
    target: (&[Vector3<f64>], &[Vector3<f64>]),
    backward: &[Vector3<f64>],
    tolerance: f64,
) -> Vec<Option<(Vector3<f64>, Vector3<f64>)>> {
    let blend = Blend::over(backward, tolerance);
    source
        .par_iter()
        .map(|p| {
            let ([at, normal], weights) = blend.sums(p, |i| [target.0[i], target.1[i]])?;
            Some((at / weights, normal.try_normalize(0.0).unwrap_or(normal)))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 21 × 21 grid of points 0.05 apart in the plane z = 0.
    fn grid() -> Vec<Vector3<f64>> {
        (0..21 * 21)
            .map(|k| Vector3::new((k % 21) as f64, (k / 21) as f64, 0.0) * 0.05)
            .collect()
    }

    fn shifted(points: &[Vector3<f64>], by: Vector3<f64>) -> Vec<Vector3<f64>> {
        points.iter().map(|p| p + by).collect()
    }

    /// The source moved by `t` onto a target that is that move, and brought back by the target's
    /// move `back`: the trip's error is |t + back| at every point.
    fn trip(t: Vector3<f64>, back: Vector3<f64>, tolerance: f64) -> RoundTrip {
        let source = grid();
        let forward = shifted(&source, t);
        let backward = shifted(&forward, back);
        RoundTrip::measure(&source, &forward, (&forward, &backward), (tolerance, 0.0)).unwrap()
    }

    #[test]
    fn a_trip_that_comes_back_holds() {
        let t = Vector3::new(0.1, 0.05, 0.02);
        let r = trip(t, -t, 0.05);
        assert!(r.mean < 1e-12, "{r:?}");
        assert!((r.moved - t.norm()).abs() < 1e-12);
        assert_eq!(r.points, 441);
        assert!(r.holds());
    }

    /// Brought back a quarter of the way off, the trip holds; half the way off, it does not.
    #[test]
    fn a_trip_that_comes_back_elsewhere_does_not_hold() {
        let t = Vector3::new(0.2, 0.0, 0.0);
        let slid = |share: f64| trip(t, -t + Vector3::new(0.0, share * 0.2, 0.0), 0.05);
        let (near, far) = (slid(0.25), slid(0.5));
        assert!((near.ratio() - 0.25).abs() < 1e-9, "{near:?}");
        assert!(near.holds());
        assert!((far.ratio() - 0.5).abs() < 1e-9, "{far:?}");
        assert!(!far.holds());
    }

    /// A pair that barely moved is judged by the floor, not the ratio.
    #[test]
    fn a_trip_within_the_floor_holds_whatever_the_ratio() {
        let t = Vector3::new(1e-4, 0.0, 0.0);
        let off = |e: f64| trip(t, -t + Vector3::new(0.0, e, 0.0), 0.05);
        // the floor is a twentieth of the tolerance, 2.5e-3
        let (inside, outside) = (off(2e-3), off(3e-3));
        assert!(inside.ratio() > 10.0 && inside.holds(), "{inside:?}");
        assert!(!outside.holds(), "{outside:?}");
    }

    /// A fit whose median distance is its target's noise raises the floor to twice it.
    #[test]
    fn a_noisy_fit_raises_the_floor() {
        let source = grid();
        let t = Vector3::new(1e-4, 0.0, 0.0);
        let forward = shifted(&source, t);
        let backward = shifted(&forward, -t + Vector3::new(0.0, 6e-3, 0.0));
        let trip = |median: f64| {
            RoundTrip::measure(&source, &forward, (&forward, &backward), (0.05, median)).unwrap()
        };
        assert!(!trip(0.0).holds());
        assert!(!trip(f64::INFINITY).holds());
        let noisy = trip(3.5e-3);
        assert!(
            (noisy.floor - 7e-3).abs() < 1e-15 && noisy.holds(),
            "{noisy:?}"
        );
    }

    /// A way back that undoes the move places each source point where the move took it, with the
    /// target's normal; source points the way back does not reach are left unplaced.
    #[test]
    fn the_way_back_places_the_points_where_it_reached() {
        let source = grid();
        let t = Vector3::new(0.3, -0.1, 0.2);
        let target = shifted(&source, t);
        let normals = vec![Vector3::z(); target.len()];
        let mut backward = shifted(&target, -t);
        backward[0].z += 1.0;
        let placed = placed_back(&source, (&target, &normals), &backward, 0.01);
        assert!(placed[0].is_none());
        for (p, q) in source.iter().zip(&placed).skip(1) {
            let (q, n) = q.unwrap();
            assert!(
                (q - (p + t)).norm() < 1e-9 && n == Vector3::z(),
                "{p} {q} {n}"
            );
        }
        assert!(placed_back(&source, (&[], &[]), &[], 0.01)
            .iter()
            .all(Option::is_none));
    }

    /// Points that land farther than the tolerance from every target point are not measured;
    /// when none lands near, there is no trip.
    #[test]
    fn points_off_the_target_are_not_counted() {
        let source = grid();
        let mut forward = source.clone();
        for p in forward.iter_mut().skip(200) {
            p.z += 1.0;
        }
        forward[0].x = f64::NAN;
        let r = RoundTrip::measure(&source, &forward, (&source, &source), (0.05, 0.0)).unwrap();
        assert_eq!(r.points, 199);
        let far = shifted(&source, Vector3::z());
        assert!(RoundTrip::measure(&source, &far, (&source, &source), (0.05, 0.0)).is_none());
        assert!(RoundTrip::measure(&source, &source, (&[], &[]), (0.05, 0.0)).is_none());
    }
}
