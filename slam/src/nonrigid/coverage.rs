//! Coverage matches: closest point from the target back to the warped source, for a whole shape
//! registered onto a whole shape.
//!
//! Closest point from the source alone lets a limb slide along itself: a leg that ends short of
//! the target's foot has every point on the target's leg, so nothing pulls it down, and the foot
//! stays uncovered (the camel's hind legs, 7 → 1, ended 0.1 of the diagonal up their legs). The
//! reverse direction of a symmetric (two-sided) ICP sees it: a target sample whose nearest warped
//! source point lies farther than the coverage distance is uncovered, and that source point is
//! given the nearest such sample as its partner instead of its own closest point (one partner per
//! point keeps the data term as it is). Round after round the limb is drawn towards its end, as
//! far as the regulariser and the other points' matches let it (on 7 → 1 not all the way, NOTES
//! 101). The same gates as forward matching apply: the distance gate and the normals' angle; a
//! sample farther than the data terms' Tukey c gets no weight.

use kiddo::traits::DistanceMetric;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;
use rayon::prelude::*;

/// A match: target point and unit normal.
type Match = (Vector3<f64>, Vector3<f64>);

/// The gates of a coverage round.
#[derive(Clone, Copy, Debug)]
pub(crate) struct CoverageGates {
    /// A target sample is uncovered when its nearest warped point is farther than this.
    pub cover: f64,
    /// … and no partner is taken farther than this (the forward matches' gate).
    pub max_distance: f64,
    /// The cosine of the largest angle between the two normals.
    pub min_cos: f64,
}

/// Reusable buffers of the coverage rounds.
#[derive(Default)]
pub(crate) struct Coverage {
    coords: Vec<[f64; 3]>,
    /// Per target sample: the nearest warped point and the squared distance, if uncovered.
    nearest: Vec<Option<(u32, f64)>>,
    /// Per warped point: the nearest uncovered sample that chose it, and the squared distance.
    chosen: Vec<Option<(u32, f64)>>,
    /// Per target sample: the warped point found nearest it when it was last searched for
    /// (`u32::MAX` for none). While that point stays within the coverage distance the sample
    /// is covered, whichever point is nearest now, and is not searched for again.
    last: Vec<u32>,
    /// Per target sample: whether this round searches for its nearest warped point.
    search: Vec<bool>,
}

impl Coverage {
    /// Forgets the samples' last nearest points: the next round searches for every one (a new
    /// optimisation, whose points or target may differ).
    pub fn forget(&mut self) {
        self.last.clear();
    }

    /// Gives each warped point that is the nearest of some uncovered target sample (within the
    /// gates) the nearest such sample as its partner in `matches`. Returns how many points were
    /// given one.
    pub fn pull(
        &mut self,
        warped: (&[Vector3<f64>], &[Vector3<f64>]),
        samples: (&[Vector3<f64>], &[Vector3<f64>]),
        gates: CoverageGates,
        matches: &mut [Option<Match>],
    ) -> usize {
        let (points, normals) = warped;
        if points.is_empty() {
            return 0;
        }
        let (cover2, gate2) = (gates.cover * gates.cover, gates.max_distance.powi(2));
        self.mark_searches(points, samples, cover2);
        self.nearest.clear();
        self.nearest.resize(samples.0.len(), None);
        if self.search.iter().any(|&s| s) {
            self.coords.clear();
            self.coords
                .extend(points.iter().map(|p| <[f64; 3]>::from(*p)));
            let tree = ImmutableKdTree::<f64, 3>::new_from_slice(&self.coords);
            self.nearest
                .par_iter_mut()
                .zip(self.last.par_iter_mut())
                .zip(self.search.par_iter())
                .zip(samples.0.par_iter().zip(samples.1.par_iter()))
                .filter(|(((_, _), search), _)| **search)
                .for_each(|(((out, last), _), (q, n))| {
                    let near = tree.nearest_one::<SquaredEuclidean>(&(*q).into());
                    let i = near.item as usize;
                    *last = near.item as u32;
                    if near.distance > cover2
                        && near.distance <= gate2
                        && normals[i].dot(n) >= gates.min_cos
                    {
                        *out = Some((i as u32, near.distance));
                    }
                });
        }
        self.give_partners(points.len(), samples, matches)
    }

    /// Marks the samples to search for this round: those with a finite point and normal whose
    /// last nearest warped point is not within the coverage distance (squared: `cover2`) of
    /// them now.
    fn mark_searches(
        &mut self,
        points: &[Vector3<f64>],
        (samples, normals): (&[Vector3<f64>], &[Vector3<f64>]),
        cover2: f64,
    ) {
        self.last.resize(samples.len(), u32::MAX);
        self.search.clear();
        self.search.resize(samples.len(), false);
        self.search
            .par_iter_mut()
            .zip(self.last.par_iter())
            .zip(samples.par_iter().zip(normals.par_iter()))
            .for_each(|((search, &last), (q, n))| {
                let covered = points.get(last as usize).is_some_and(|w| {
                    let (q, w): ([f64; 3], [f64; 3]) = ((*q).into(), (*w).into());
                    <SquaredEuclidean as DistanceMetric<f64, 3>>::dist(&q, &w) <= cover2
                });
                *search = !covered && q.iter().chain(n.iter()).all(|v| v.is_finite());
            });
    }

    /// Gives each warped point (of `count`) the nearest uncovered sample that chose it.
    fn give_partners(
        &mut self,
        count: usize,
        samples: (&[Vector3<f64>], &[Vector3<f64>]),
        matches: &mut [Option<Match>],
    ) -> usize {
        self.chosen.clear();
        self.chosen.resize(count, None);
        for (s, found) in self.nearest.iter().enumerate() {
            if let Some((i, d2)) = *found {
                let slot = &mut self.chosen[i as usize];
                if slot.is_none_or(|(_, best)| d2 < best) {
                    *slot = Some((s as u32, d2));
                }
            }
        }
        let mut pulled = 0;
        for (m, c) in matches.iter_mut().zip(&self.chosen) {
            if let Some((s, _)) = *c {
                *m = Some((samples.0[s as usize], samples.1[s as usize]));
                pulled += 1;
            }
        }
        pulled
    }
}

/// The squared distance from each of `coords` (the points of `tree`) to its `k`-th nearest other
/// point (k ≥ 1), 0 where it has fewer others (or another point lies on it and k = 1).
pub(crate) fn neighbour_distances2(
    tree: &ImmutableKdTree<f64, 3>,
    coords: &[[f64; 3]],
    k: usize,
) -> Vec<f64> {
    let n = std::num::NonZero::new(k + 1).expect("k + 1 is not 0");
    // the first of a point's own coordinates' nearest is itself (or a point on it), so its k-th
    // other is the (k + 1)-th found
    coords
        .par_iter()
        .map(|q| {
            let near = tree.nearest_n::<SquaredEuclidean>(q, n);
            near.get(k).map_or(0.0, |m| m.distance)
        })
        .collect()
}

/// The median distance from a point to its nearest neighbour: the points' sampling (a mesh's
/// edge length), 0 for fewer than two.
pub(crate) fn sampling_spacing(points: &[Vector3<f64>]) -> f64 {
    median_neighbour_distance(points, 1)
}

/// The median distance from a point to its [`GAP_NEIGHBOUR`]-th nearest neighbour: the
/// points' widest sampling gap. On a mesh of long, thin triangles the nearest neighbour lies
/// along the short edges and understates how far a point of the surface can be from every
/// vertex; the fourth lies across the long ones (on an even mesh it is about as near as the
/// first). 0 for too few points.
pub(crate) fn sampling_gap(points: &[Vector3<f64>]) -> f64 {
    median_neighbour_distance(points, GAP_NEIGHBOUR)
}

/// Which neighbour [`sampling_gap`] measures.
const GAP_NEIGHBOUR: usize = 4;

/// The median over the finite `points` of the distance to the `k`-th nearest other point, 0
/// for `k` or fewer points.
fn median_neighbour_distance(points: &[Vector3<f64>], k: usize) -> f64 {
    let coords: Vec<[f64; 3]> = points
        .iter()
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .map(|p| (*p).into())
        .collect();
    if coords.len() <= k {
        return 0.0;
    }
    let tree = ImmutableKdTree::<f64, 3>::new_from_slice(&coords);
    let mut d = neighbour_distances2(&tree, &coords, k);
    let mid = d.len() / 2;
    d.select_nth_unstable_by(mid, f64::total_cmp).1.sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A row of points along x at spacing 1, normals +z.
    fn row(from: f64, count: usize) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let p = (0..count)
            .map(|k| Vector3::new(from + k as f64, 0.0, 0.0))
            .collect();
        (p, vec![Vector3::z(); count])
    }

    #[test]
    fn the_end_of_a_short_limb_is_given_the_nearest_uncovered_sample() {
        // source 0..5, target 0..8: samples 6, 7 and 8 are uncovered and all nearest to point 5
        let (src, sn) = row(0.0, 6);
        let (tgt, tn) = row(0.0, 9);
        let mut matches: Vec<Option<Match>> =
            src.iter().map(|p| Some((*p, Vector3::z()))).collect();
        let gates = CoverageGates {
            cover: 0.5,
            max_distance: 10.0,
            min_cos: 0.5,
        };
        let mut c = Coverage::default();
        let pulled = c.pull((&src, &sn), (&tgt, &tn), gates, &mut matches);
        assert_eq!(pulled, 1);
        assert_eq!(
            matches[5].unwrap().0,
            tgt[6],
            "the nearest uncovered sample"
        );
        assert!(
            (0..5).all(|i| matches[i].unwrap().0 == src[i]),
            "the rest as they were"
        );
        // beyond the distance gate, or with normals apart, nothing is pulled
        let mut again = matches.clone();
        let far = CoverageGates {
            max_distance: 0.9,
            ..gates
        };
        assert_eq!(c.pull((&src, &sn), (&tgt, &tn), far, &mut again), 0);
        let flipped = vec![-Vector3::z(); tgt.len()];
        assert_eq!(c.pull((&src, &sn), (&tgt, &flipped), gates, &mut again), 0);
        // a covered target, non-finite samples and an empty source pull nothing
        let (same, sn2) = row(0.0, 6);
        assert_eq!(c.pull((&src, &sn), (&same, &sn2), gates, &mut again), 0);
        let nan = vec![Vector3::repeat(f64::NAN); 3];
        assert_eq!(c.pull((&src, &sn), (&nan, &nan), gates, &mut again), 0);
        assert_eq!(c.pull((&[], &[]), (&tgt, &tn), gates, &mut []), 0);
    }

    /// A grid of `nx` × `ny` points `dx` and `dy` apart.
    fn grid(nx: usize, ny: usize, dx: f64, dy: f64) -> Vec<Vector3<f64>> {
        (0..nx * ny)
            .map(|k| Vector3::new((k % nx) as f64 * dx, (k / nx) as f64 * dy, 0.0))
            .collect()
    }

    /// On an even grid the gap is the spacing; on a grid four times as long one way as the other
    /// the spacing is the short side and the gap twice it (the fourth neighbour, two rows over);
    /// too few points give 0.
    #[test]
    fn the_gap_of_long_thin_cells_is_wider_than_their_spacing() {
        let even = grid(30, 30, 0.01, 0.01);
        assert!((sampling_spacing(&even) - 0.01).abs() < 1e-12);
        assert!((sampling_gap(&even) - 0.01).abs() < 1e-12);
        let long = grid(30, 30, 0.04, 0.01);
        assert!((sampling_spacing(&long) - 0.01).abs() < 1e-12);
        assert!((sampling_gap(&long) - 0.02).abs() < 1e-12);
        assert_eq!(sampling_gap(&long[..4]), 0.0);
        assert!(sampling_gap(&long[..5]) > 0.0);
    }
}
