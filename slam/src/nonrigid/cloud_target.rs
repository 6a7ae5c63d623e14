//! A point cloud with normals (a mesh's vertices) as a registration's target: each warped point's
//! partner is its closest target point.
//!
//! Between rounds most points move by a fraction of the target's spacing, so most keep their
//! partner. That is told without a search: if the target point k's nearest other target point
//! lies `s_k` from it, every other target point j does at least, and for a query p with
//! `|p − t_k| < s_k / 2` the triangle inequality gives
//! `|p − t_j| ≥ |t_j − t_k| − |p − t_k| > s_k / 2 > |p − t_k|`: k is still the unique nearest,
//! the answer the KD-tree would give. Otherwise the tree is searched.

use super::coverage::neighbour_distances2;
use super::register::{Samples, Target};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;

/// A point cloud with normals, associated by closest point through a KD-tree.
pub struct CloudTarget {
    points: Vec<Vector3<f64>>,
    normals: Vec<Vector3<f64>>,
    tree: ImmutableKdTree<f64, 3>,
    /// Per point, the squared radius `(s_k / 2)²` (slightly less) of the ball round it within
    /// which it is the nearest target point; 0 where another point lies on it.
    keep: Vec<f64>,
}

impl CloudTarget {
    /// A target from points and their unit normals (non-finite points are left out).
    pub fn new(points: &[Vector3<f64>], normals: &[Vector3<f64>]) -> Self {
        let (points, normals): (Vec<_>, Vec<_>) = points
            .iter()
            .zip(normals)
            .filter(|(p, n)| p.iter().chain(n.iter()).all(|v| v.is_finite()))
            .map(|(p, n)| (*p, *n))
            .unzip();
        let coords: Vec<[f64; 3]> = points.iter().map(|p| (*p).into()).collect();
        let tree = ImmutableKdTree::new_from_slice(&coords);
        // half the distance, squared; a margin of 10⁻⁹ keeps rounding from deciding
        let mut keep = neighbour_distances2(&tree, &coords, 1);
        keep.iter_mut().for_each(|d| *d *= 0.25 * (1.0 - 1e-9));
        Self {
            tree,
            points,
            normals,
            keep,
        }
    }

    /// The index of the target point nearest `p` (the target is not empty).
    fn nearest(&self, p: &Vector3<f64>) -> usize {
        self.tree.nearest_one::<SquaredEuclidean>(&(*p).into()).item as usize
    }
}

impl Target for CloudTarget {
    fn associate(&self, p: &Vector3<f64>) -> Option<(Vector3<f64>, Vector3<f64>)> {
        if self.points.is_empty() {
            return None;
        }
        let k = self.nearest(p);
        Some((self.points[k], self.normals[k]))
    }

    fn associate_from(
        &self,
        p: &Vector3<f64>,
        last: &mut u32,
    ) -> Option<(Vector3<f64>, Vector3<f64>)> {
        if self.points.is_empty() {
            return None;
        }
        let k = *last as usize;
        let k = if k < self.points.len() && (p - self.points[k]).norm_squared() < self.keep[k] {
            k
        } else {
            let k = self.nearest(p);
            *last = k as u32;
            k
        };
        Some((self.points[k], self.normals[k]))
    }

    fn samples(&self) -> Option<Samples<'_>> {
        Some((&self.points, &self.normals))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A jittered grid of points on a wavy sheet, normals +z.
    fn sheet(rng: &mut ChaCha8Rng) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let mut points = Vec::new();
        for i in 0..30 {
            for j in 0..30 {
                let (x, y) = (
                    i as f64 + rng.random_range(-0.3..0.3),
                    j as f64 + rng.random_range(-0.3..0.3),
                );
                points.push(Vector3::new(x, y, (0.3 * x).sin()) * 0.01);
            }
        }
        let normals = vec![Vector3::z(); points.len()];
        (points, normals)
    }

    #[test]
    fn a_kept_partner_is_the_one_the_search_finds() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (points, normals) = sheet(&mut rng);
        let target = CloudTarget::new(&points, &normals);
        // query points drifting in small steps, as warped points do between rounds, and jumps
        let jitter = |rng: &mut ChaCha8Rng, size: f64| {
            Vector3::from_fn(|_, _| rng.random_range(-0.5..0.5) * size)
        };
        let mut queries: Vec<Vector3<f64>> = (0..500)
            .map(|k| points[k % points.len()] + jitter(&mut rng, 0.01))
            .collect();
        let mut last = vec![u32::MAX; queries.len()];
        let (mut kept, mut total) = (0, 0);
        for round in 0..20 {
            let step = if round % 7 == 6 { 0.05 } else { 0.001 };
            for (q, l) in queries.iter_mut().zip(&mut last) {
                *q += jitter(&mut rng, step);
                let before = *l;
                let found = target.associate_from(q, l);
                assert_eq!(found, target.associate(q), "round {round}");
                kept += usize::from(before != u32::MAX && *l == before);
                total += 1;
            }
        }
        // the test above is not vacuous: most small steps keep their partner without a search
        assert!(kept > total / 3, "{kept} of {total}");
        // a stale or foreign index is searched, not trusted
        let mut foreign = 10_000_u32;
        assert_eq!(
            target.associate_from(&queries[0], &mut foreign),
            target.associate(&queries[0])
        );
        let mut wrong = 0_u32;
        let far = points[899];
        assert_eq!(
            target.associate_from(&far, &mut wrong),
            Some((far, Vector3::z()))
        );
        assert_eq!(wrong, 899);
    }

    #[test]
    fn points_on_one_another_are_always_searched() {
        let p = vec![Vector3::zeros(), Vector3::zeros(), Vector3::x()];
        let target = CloudTarget::new(&p, &[Vector3::z(); 3]);
        assert_eq!(target.keep[0], 0.0);
        assert_eq!(target.keep[1], 0.0);
        let mut last = 0;
        assert!(target
            .associate_from(&Vector3::new(1e-9, 0.0, 0.0), &mut last)
            .is_some());
        let empty = CloudTarget::new(&[], &[]);
        assert_eq!(empty.associate_from(&Vector3::zeros(), &mut last), None);
    }
}
