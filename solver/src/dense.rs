//! The dense path: one variable with many small independent terms (pixels of an image, points of a
//! cloud), reduced straight into the N×N normal equations without storing a Jacobian.
//!
//! Terms are evaluated in parallel over fixed chunks; each chunk accumulates `Σ w JJᵀ`, `Σ w r J` and
//! the cost, and the chunks are summed in order, so results do not depend on thread timing. Robust
//! kernels enter as iteratively reweighted least squares, w = ρ'(r²) (the first-order part of the
//! Triggs correction, exact for Huber inside its threshold). Steps are exact on the manifold,
//! `x ← x ⊞ δ` (for SE(3), `X Exp(δ)`; no small-angle approximation).

use crate::manifold::Manifold;
use crate::robust::RobustKernel;
use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;

/// Terms per parallel chunk (fixed, so the reduction order is too).
const CHUNK: usize = 2048;

/// Many scalar terms of one variable with tangent dimension N.
pub trait DenseTerms<const N: usize>: Sync {
    /// What the terms need of the current point, computed once per linearisation (a pose's rotation
    /// matrix, say).
    type Point: Sync;
    /// Number of terms.
    fn len(&self) -> usize;
    /// True when there are no terms.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Prepares the point `x` (ambient coordinates) for evaluation.
    fn prepare(&self, x: &[f64]) -> Self::Point;
    /// Evaluates term `i` at the prepared point, calling `emit(r, J, group)` for each residual row it
    /// contributes (none when the term is rejected); `group` selects the robust kernel and weight in
    /// [`DenseOptions::groups`].
    fn evaluate<E: FnMut(f64, &[f64; N], usize)>(
        &self,
        i: usize,
        point: &Self::Point,
        emit: &mut E,
    );
}

/// A term group's weight and kernel.
#[derive(Clone, Copy)]
pub struct Group<'a> {
    /// Weight λ multiplying the group's squared residuals.
    pub weight: f64,
    /// Robust kernel of the group (None: least squares).
    pub kernel: Option<&'a dyn RobustKernel>,
}

impl std::fmt::Debug for Group<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Group")
            .field("weight", &self.weight)
            .field("kernel", &self.kernel)
            .finish()
    }
}

/// Settings of a dense solve.
#[derive(Clone, Debug)]
pub struct DenseOptions<'a> {
    /// Per-group weights and kernels (group 0 must exist).
    pub groups: &'a [Group<'a>],
    /// Iterations at most.
    pub max_iterations: usize,
    /// Stop when ‖δ‖ falls below this.
    pub step_tolerance: f64,
    /// Levenberg-Marquardt damping added as μ·diag(H) (0: Gauss-Newton).
    pub damping: f64,
}

/// The reduced normal equations of one linearisation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reduced<const N: usize> {
    /// Σ w J Jᵀ.
    pub h: SMatrix<f64, N, N>,
    /// Σ w r J.
    pub g: SVector<f64, N>,
    /// ½ Σ λ ρ(r²).
    pub cost: f64,
    /// Number of residual rows.
    pub rows: usize,
    /// Rows per group (the first [`MAX_GROUPS`] groups).
    pub group_rows: [usize; MAX_GROUPS],
}

/// Groups whose rows are counted separately in [`Reduced::group_rows`].
pub const MAX_GROUPS: usize = 4;

impl<const N: usize> Reduced<N> {
    fn zero() -> Self {
        Self {
            h: SMatrix::zeros(),
            g: SVector::zeros(),
            cost: 0.0,
            rows: 0,
            group_rows: [0; MAX_GROUPS],
        }
    }
    fn add(&mut self, o: &Self) {
        self.h += o.h;
        self.g += o.g;
        self.cost += o.cost;
        self.rows += o.rows;
        for (a, b) in self.group_rows.iter_mut().zip(o.group_rows) {
            *a += b;
        }
    }
}

/// Linearises all terms at `x`: `H = Σ w JJᵀ`, `g = Σ w r J` (upper triangle accumulated, then
/// mirrored), in parallel with a fixed reduction order.
pub fn reduce<const N: usize, T: DenseTerms<N>>(
    terms: &T,
    x: &[f64],
    groups: &[Group<'_>],
    partials: &mut Vec<Reduced<N>>,
) -> Reduced<N> {
    let chunks = terms.len().div_ceil(CHUNK);
    let point = terms.prepare(x);
    let x = &point;
    partials.clear();
    partials.resize(chunks, Reduced::zero());
    partials.par_iter_mut().enumerate().for_each(|(c, acc)| {
        let mut h = [[0.0f64; N]; N];
        let mut g = [0.0f64; N];
        let (mut cost, mut rows) = (0.0, 0usize);
        let mut group_rows = [0usize; MAX_GROUPS];
        let end = ((c + 1) * CHUNK).min(terms.len());
        for i in c * CHUNK..end {
            terms.evaluate(i, x, &mut |r: f64, j: &[f64; N], group: usize| {
                let gr = groups[group];
                let s = r * r;
                let (rho, w) = match gr.kernel {
                    Some(k) => {
                        let [rho, d1, _] = k.evaluate(s);
                        (rho, d1)
                    }
                    None => (s, 1.0),
                };
                let w = w * gr.weight;
                cost += 0.5 * gr.weight * rho;
                rows += 1;
                if group < MAX_GROUPS {
                    group_rows[group] += 1;
                }
                for a in 0..N {
                    let wa = w * j[a];
                    g[a] += wa * r;
                    for b in a..N {
                        h[a][b] += wa * j[b];
                    }
                }
            });
        }
        let mut hm = SMatrix::<f64, N, N>::zeros();
        for a in 0..N {
            for b in a..N {
                hm[(a, b)] = h[a][b];
                hm[(b, a)] = h[a][b];
            }
        }
        *acc = Reduced {
            h: hm,
            g: SVector::from(g),
            cost,
            rows,
            group_rows,
        };
    });
    let mut total = Reduced::zero();
    for p in partials.iter() {
        total.add(p);
    }
    total
}

/// Why a dense solve stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DenseStop {
    /// The step fell below the tolerance.
    Converged,
    /// The iteration limit was reached.
    MaxIterations,
    /// H was not positive definite (too few or degenerate terms).
    Singular,
    /// No term contributed.
    NoTerms,
}

/// The outcome of [`solve`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DenseSummary<const N: usize> {
    /// Iterations done.
    pub iterations: usize,
    /// Why it stopped.
    pub stop: DenseStop,
    /// The last linearisation (at the point before the last step).
    pub last: Reduced<N>,
    /// Cost at the first linearisation.
    pub initial_cost: f64,
}

/// Reusable buffers of the dense path.
#[derive(Clone, Debug, Default)]
pub struct DenseWorkspace<const N: usize> {
    partials: Vec<Reduced<N>>,
    next: Vec<f64>,
}

/// Gauss-Newton (or damped) iterations on `x`, re-evaluating the terms (and so re-associating, for
/// trackers) at every iteration.
pub fn solve<const N: usize, T: DenseTerms<N>>(
    terms: &T,
    manifold: &dyn Manifold,
    x: &mut [f64],
    options: &DenseOptions<'_>,
    ws: &mut DenseWorkspace<N>,
) -> DenseSummary<N> {
    assert_eq!(
        manifold.tangent_dim(),
        N,
        "the manifold's tangent dimension must be N"
    );
    let mut summary = DenseSummary {
        iterations: 0,
        stop: DenseStop::MaxIterations,
        last: Reduced::zero(),
        initial_cost: 0.0,
    };
    ws.next.resize(x.len(), 0.0);
    for it in 0..options.max_iterations {
        let red = reduce(terms, x, options.groups, &mut ws.partials);
        if it == 0 {
            summary.initial_cost = red.cost;
        }
        summary.last = red;
        if red.rows < N {
            summary.stop = DenseStop::NoTerms;
            break;
        }
        let mut h = red.h;
        if options.damping > 0.0 {
            for a in 0..N {
                h[(a, a)] *= 1.0 + options.damping;
            }
        }
        let Some(chol) = h.cholesky() else {
            summary.stop = DenseStop::Singular;
            break;
        };
        let delta = -chol.solve(&red.g);
        if !delta.iter().all(|v| v.is_finite()) {
            summary.stop = DenseStop::Singular;
            break;
        }
        manifold.plus(x, delta.as_slice(), &mut ws.next);
        x.copy_from_slice(&ws.next);
        summary.iterations = it + 1;
        if delta.norm() < options.step_tolerance {
            summary.stop = DenseStop::Converged;
            break;
        }
    }
    summary
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lie::se3;
    use crate::manifold::SE3;
    use crate::robust::Huber;
    use nalgebra::{Isometry3, Point3, Vector3, Vector6};

    /// Point-to-plane alignment of points onto three planes (an exactly determined pose).
    struct Planes {
        points: Vec<(Vector3<f64>, Vector3<f64>, f64)>, // (source point, plane normal, plane offset)
    }
    impl DenseTerms<6> for Planes {
        type Point = Isometry3<f64>;
        fn len(&self) -> usize {
            self.points.len()
        }
        fn prepare(&self, x: &[f64]) -> Isometry3<f64> {
            se3::from_slice(x)
        }
        fn evaluate<E: FnMut(f64, &[f64; 6], usize)>(
            &self,
            i: usize,
            t: &Isometry3<f64>,
            emit: &mut E,
        ) {
            let (p, n, d) = self.points[i];
            let q = t * Point3::from(p);
            let r = n.dot(&q.coords) - d;
            let nc = t.rotation.inverse() * n;
            let w = p.cross(&nc);
            emit(r, &[w.x, w.y, w.z, nc.x, nc.y, nc.z], 0);
        }
    }

    #[test]
    fn dense_gauss_newton_recovers_a_pose_from_planes() {
        let truth = se3::exp(&Vector6::new(0.2, -0.1, 0.3, 0.5, -0.4, 0.2));
        let normals = [
            Vector3::x(),
            Vector3::y(),
            Vector3::z(),
            Vector3::new(1.0, 1.0, 1.0).normalize(),
        ];
        let mut points = Vec::new();
        for k in 0..2000 {
            let f = k as f64;
            let p = Vector3::new((f * 0.37).sin(), (f * 0.73).cos(), (f * 0.11).sin()) * 2.0;
            let n = normals[k % 4];
            // plane through truth·p with normal n
            let d = n.dot(&(truth * Point3::from(p)).coords);
            points.push((p, n, d));
        }
        let terms = Planes { points };
        let mut x = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        let huber = Huber(0.5);
        let options = DenseOptions {
            groups: &[Group {
                weight: 1.0,
                kernel: Some(&huber),
            }],
            max_iterations: 20,
            step_tolerance: 1e-12,
            damping: 0.0,
        };
        let summary = solve(
            &terms,
            &SE3,
            &mut x,
            &options,
            &mut DenseWorkspace::default(),
        );
        assert_eq!(summary.stop, DenseStop::Converged);
        let err = se3::log(&(truth.inverse() * se3::from_slice(&x))).norm();
        assert!(err < 1e-10, "pose error {err}");
    }

    #[test]
    fn the_reduction_does_not_depend_on_the_thread_count() {
        let terms = Planes {
            points: (0..10_000)
                .map(|k| {
                    let f = k as f64;
                    (
                        Vector3::new(f.sin(), f.cos(), (f * 0.3).sin()),
                        Vector3::new(0.3, 0.4, (f * 0.1).cos()).normalize(),
                        f.sin() * 0.1,
                    )
                })
                .collect(),
        };
        let x = [0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 1.0];
        let groups = [Group {
            weight: 1.0,
            kernel: None,
        }];
        let a = reduce(&terms, &x, &groups, &mut Vec::new());
        let b = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| reduce(&terms, &x, &groups, &mut Vec::new()));
        assert_eq!(a, b);
    }
}
