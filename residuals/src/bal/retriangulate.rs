//! Points restarted from their rays once a solve has converged.
//!
//! With the cameras held, a point's cost ½ Σₖ ρ(‖rₖ‖²) over its own observations depends on that
//! point alone, so every point can be restarted on its own without touching the others. A point
//! that a solve carried far out along its rays (where a robust kernel's gradient is small) stays
//! there: the solve's steps near convergence are too short to bring it back. Each point is
//! therefore started again from the point nearest its observations' rays (the midpoint method;
//! Hartley & Sturm, *Triangulation*, CVIU 1997), refined by Levenberg-Marquardt
//! on its three coordinates with the kernel's weights ρ'(s) (iteratively re-weighted least
//! squares), and moved only where that lowers its cost. The total cost therefore never rises.
//! Re-triangulating after bundle adjustment is what incremental structure from motion does
//! (Schönberger & Frahm, *Structure-from-Motion Revisited*, CVPR 2016).

use super::{camera_centre, reprojection, rotate, BalProblem, BalSolve};
use dynamap_solver::robust::{NamedKernel, RobustKernel};
use dynamap_solver::{ProblemError, SolveError, Solver, Summary};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Levenberg-Marquardt steps of one point's refinement, at most.
const REFINE_STEPS: usize = 30;

/// What [`retriangulate`] did: the points it moved and the cost ½ Σ ρ before and after.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Retriangulation {
    /// Points moved to a position of lower cost.
    pub points_moved: usize,
    /// The cost over every observation before.
    pub cost_before: f64,
    /// The cost over every observation after (never above `cost_before`).
    pub cost_after: f64,
}

impl Retriangulation {
    /// The cost decrease relative to the cost before (0 when the cost was 0).
    pub fn relative_gain(&self) -> f64 {
        if self.cost_before > 0.0 {
            (self.cost_before - self.cost_after) / self.cost_before
        } else {
            0.0
        }
    }
}

/// Restarts every point with two or more observations from its rays and keeps the result where it
/// lowers that point's cost under `kernel` (plain least squares without one); the cameras are
/// held. See the module's documentation.
pub fn retriangulate(problem: &mut BalProblem, kernel: Option<NamedKernel>) -> Retriangulation {
    let (ptr, by_point) = observations_by_point(problem);
    let BalProblem {
        cameras,
        points,
        observations,
    } = problem;
    let (cameras, observations) = (&*cameras, &*observations);
    let outcomes: Vec<(f64, f64, bool)> = points
        .par_iter_mut()
        .enumerate()
        .map_init(Vec::new, |seen, (i, point)| {
            seen.clear();
            seen.extend(by_point[ptr[i]..ptr[i + 1]].iter().map(|&k| Sight {
                camera: &cameras[observations[k].camera],
                uv: observations[k].uv,
            }));
            restart(point, seen, kernel)
        })
        .collect();
    Retriangulation {
        points_moved: outcomes.iter().filter(|o| o.2).count(),
        cost_before: outcomes.iter().map(|o| o.0).sum(),
        cost_after: outcomes.iter().map(|o| o.1).sum(),
    }
}

/// What the restarts of [`solve_with_restarts`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Restarts {
    /// Re-triangulations that lowered the cost enough to resume the solve.
    pub rounds: usize,
    /// Points moved over all of them.
    pub points: usize,
    /// Seconds spent re-triangulating (included in the summary's total).
    pub seconds: f64,
}

/// Why [`solve_with_restarts`] failed.
#[derive(Debug, thiserror::Error)]
pub enum RestartError {
    /// A solve failed.
    #[error(transparent)]
    Solve(#[from] SolveError),
    /// A re-triangulated point was refused by the problem.
    #[error(transparent)]
    Problem(#[from] ProblemError),
}

/// Solves `solve` with `solver`; then, while the solve converged before the iteration limit,
/// re-triangulates the points with the cameras held ([`retriangulate`]) and, where that lowered
/// the cost by more than the function tolerance (relative), resumes with the iterations left.
/// `on_restart` hears of every re-triangulation that resumed the solve. The summary covers every
/// solve ([`Summary::resume`]), its total time the re-triangulations' included; `data` holds the
/// last re-triangulated points (call [`BalProblem::update_from`] for the solved values).
pub fn solve_with_restarts(
    solver: &mut Solver,
    data: &mut BalProblem,
    solve: &mut BalSolve,
    kernel: Option<NamedKernel>,
    mut on_restart: impl FnMut(&Retriangulation),
) -> Result<(Summary, Restarts), RestartError> {
    let limit = solver.options.max_iterations;
    let mut summary = solver.solve(&mut solve.problem)?;
    let mut restarts = Restarts::default();
    while summary.termination.converged() && summary.num_iterations() < limit {
        let clock = std::time::Instant::now();
        data.update_from(solve);
        let moved = retriangulate(data, kernel);
        let seconds = clock.elapsed().as_secs_f64();
        restarts.seconds += seconds;
        summary.total_seconds += seconds;
        if moved.relative_gain() <= solver.options.function_tolerance {
            break;
        }
        for (&v, p) in solve.points.iter().zip(&data.points) {
            solve.problem.set_value(v, p)?;
        }
        on_restart(&moved);
        restarts.rounds += 1;
        restarts.points += moved.points_moved;
        solver.options.max_iterations = limit - summary.num_iterations();
        let next = solver.solve(&mut solve.problem);
        solver.options.max_iterations = limit;
        let next = next?;
        // a resumed solve that stops at its start point ends the restarts
        let moved_on = next.num_iterations() > 0;
        summary.resume(next);
        if !moved_on {
            break;
        }
    }
    Ok((summary, restarts))
}

/// The indices of each point's observations in compressed rows: point i's are
/// `indices[ptr[i]..ptr[i + 1]]`.
fn observations_by_point(problem: &BalProblem) -> (Vec<usize>, Vec<usize>) {
    let n = problem.points.len();
    let mut ptr = vec![0usize; n + 1];
    for o in &problem.observations {
        ptr[o.point + 1] += 1;
    }
    for i in 0..n {
        ptr[i + 1] += ptr[i];
    }
    let mut fill = ptr.clone();
    let mut indices = vec![0; problem.observations.len()];
    for (k, o) in problem.observations.iter().enumerate() {
        indices[fill[o.point]] = k;
        fill[o.point] += 1;
    }
    (ptr, indices)
}

/// One observation of a point: the camera and the measured pixel.
struct Sight<'a> {
    camera: &'a [f64; 9],
    uv: [f64; 2],
}

/// The point's cost before and after, and whether it moved.
fn restart(point: &mut [f64; 3], seen: &[Sight], kernel: Option<NamedKernel>) -> (f64, f64, bool) {
    let before = cost(seen, point, kernel);
    if seen.len() < 2 || !before.is_finite() {
        return (before, before, false);
    }
    let Some(start) = nearest_to_rays(seen) else {
        return (before, before, false);
    };
    let (candidate, after) = refine(seen, start, kernel);
    if after < before {
        *point = candidate;
        (before, after, true)
    } else {
        (before, before, false)
    }
}

/// ½ Σ ρ(‖r‖²) over the point's observations.
fn cost(seen: &[Sight], point: &[f64; 3], kernel: Option<NamedKernel>) -> f64 {
    seen.iter()
        .map(|s| {
            let r = reprojection(s.camera, point, s.uv, None);
            0.5 * rho(kernel, r[0] * r[0] + r[1] * r[1])[0]
        })
        .sum()
}

/// `[ρ(s), ρ'(s)]`; ρ(s) = s without a kernel.
fn rho(kernel: Option<NamedKernel>, s: f64) -> [f64; 2] {
    match kernel {
        Some(k) => {
            let r = k.evaluate(s);
            [r[0], r[1]]
        }
        None => [s, 1.0],
    }
}

/// The point nearest (in the least-squares sense) to every observation's ray: with each ray's
/// centre C and unit direction n, Σ (I − n nᵀ) X = Σ (I − n nᵀ) C. None when fewer than two rays
/// can be undistorted or the rays are parallel.
fn nearest_to_rays(seen: &[Sight]) -> Option<[f64; 3]> {
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    let mut rays = 0;
    for s in seen {
        let Some((centre, n)) = ray(s) else { continue };
        let p = Matrix3::identity() - n * n.transpose();
        a += p;
        b += p * centre;
        rays += 1;
    }
    if rays < 2 {
        return None;
    }
    let x = a.cholesky()?.solve(&b);
    x.iter().all(|v| v.is_finite()).then(|| [x[0], x[1], x[2]])
}

/// The world ray through an observation: the camera's centre C = −Rᵀt and the unit direction
/// Rᵀ(x, y, −1) of the undistorted image point (the camera looks down −z).
fn ray(s: &Sight) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let c = s.camera;
    let [x, y] = undistort(c[6], c[7], c[8], s.uv)?;
    let w = -Vector3::new(c[0], c[1], c[2]);
    let direction = rotate(&w, &Vector3::new(x, y, -1.0)).normalize();
    Some((camera_centre(c), direction))
}

/// The normalised image point p with f (1 + k₁‖p‖² + k₂‖p‖⁴) p = uv: the radius ρ solves
/// ρ + k₁ρ³ + k₂ρ⁵ = ‖uv‖/f by Newton's method from ρ = ‖uv‖/f, and p keeps uv's direction. None
/// where the distortion is not invertible along the way (its derivative not positive) or Newton's
/// method does not settle.
fn undistort(f: f64, k1: f64, k2: f64, uv: [f64; 2]) -> Option<[f64; 2]> {
    if f.abs() <= f64::EPSILON || !f.is_finite() {
        return None;
    }
    let q = [uv[0] / f, uv[1] / f];
    let target = q[0].hypot(q[1]);
    if target == 0.0 {
        return Some(q);
    }
    let mut r = target;
    for _ in 0..50 {
        let r2 = r * r;
        let g = r * (1.0 + r2 * (k1 + k2 * r2)) - target;
        let dg = 1.0 + r2 * (3.0 * k1 + 5.0 * k2 * r2);
        if dg.is_nan() || dg <= 0.0 {
            return None;
        }
        let step = g / dg;
        r -= step;
        if r.is_nan() || r <= 0.0 {
            return None;
        }
        if step.abs() <= 1e-14 * r {
            let scale = r / target;
            return Some([q[0] * scale, q[1] * scale]);
        }
    }
    None
}

/// Levenberg-Marquardt on the point alone, with the kernel's weights ρ'(s) on each observation's
/// normal equations; returns the point reached and its cost.
fn refine(seen: &[Sight], start: [f64; 3], kernel: Option<NamedKernel>) -> ([f64; 3], f64) {
    let mut x = start;
    let mut c = cost(seen, &x, kernel);
    let mut mu = 1e-4;
    for _ in 0..REFINE_STEPS {
        if !c.is_finite() {
            break;
        }
        let (h, g) = normal_equations(seen, &x, kernel);
        let damped = h + Matrix3::from_diagonal(&(h.diagonal() * mu));
        let Some(chol) = damped.cholesky() else { break };
        let delta = chol.solve(&-g);
        let trial = [x[0] + delta[0], x[1] + delta[1], x[2] + delta[2]];
        let ct = cost(seen, &trial, kernel);
        if ct < c {
            let settled = c - ct <= 1e-12 * c;
            (x, c) = (trial, ct);
            mu = (mu / 10.0).max(1e-12);
            if settled {
                break;
            }
        } else {
            mu *= 10.0;
            if mu > 1e8 {
                break;
            }
        }
    }
    (x, c)
}

/// H = Σ ρ'(s) JᵀJ and g = Σ ρ'(s) Jᵀr over the point's observations, J = ∂r/∂X.
fn normal_equations(
    seen: &[Sight],
    x: &[f64; 3],
    kernel: Option<NamedKernel>,
) -> (Matrix3<f64>, Vector3<f64>) {
    let mut h = Matrix3::zeros();
    let mut g = Vector3::zeros();
    let mut jc = [0.0; 18];
    let mut jx = [0.0; 6];
    for s in seen {
        let r = reprojection(s.camera, x, s.uv, Some((&mut jc, &mut jx)));
        let weight = rho(kernel, r[0] * r[0] + r[1] * r[1])[1];
        let j = nalgebra::Matrix2x3::from_column_slice(&jx);
        let rv = nalgebra::Vector2::new(r[0], r[1]);
        h += j.transpose() * j * weight;
        g += j.transpose() * rv * weight;
    }
    (h, g)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bal::synthetic::{self, SyntheticOptions};

    /// A point carried far out along one camera's ray comes back to where its observations
    /// meet; the others, already at their optimum, do not move, and the cost falls by the moved
    /// point's cost.
    #[test]
    fn a_point_carried_along_its_ray_is_brought_back() {
        let truth = synthetic::generate(&SyntheticOptions::default()).truth;
        let mut problem = truth.clone();
        let i = problem.observations[0].point;
        let cam = problem.observations[0].camera;
        // the centre of the camera that sees it, and the point moved 40× farther along that ray
        let centre = camera_centre(&problem.cameras[cam]);
        let x = Vector3::from(problem.points[i]);
        let far = centre + (x - centre) * 40.0;
        problem.points[i] = [far.x, far.y, far.z];
        let kernel = Some(NamedKernel::Huber(1.0));
        let outcome = retriangulate(&mut problem, kernel);
        assert_eq!(outcome.points_moved, 1, "{outcome:?}");
        assert!(outcome.cost_after < 1e-12, "{outcome:?}");
        for (p, q) in problem.points.iter().zip(&truth.points) {
            let d = (Vector3::from(*p) - Vector3::from(*q)).norm();
            assert!(d < 1e-6, "{p:?} against {q:?}");
        }
    }

    /// Undistortion inverts BAL's radial distortion.
    #[test]
    fn undistortion_inverts_the_distortion() {
        let (f, k1, k2) = (500.0, -0.2, 0.05);
        for p in [[0.3, -0.2], [0.0, 0.0], [-0.45, 0.1], [1e-9, 0.0]] {
            let r2 = p[0] * p[0] + p[1] * p[1];
            let d = 1.0 + r2 * (k1 + k2 * r2);
            let uv = [f * d * p[0], f * d * p[1]];
            let q = undistort(f, k1, k2, uv).expect("invertible here");
            assert!((q[0] - p[0]).abs() < 1e-12 && (q[1] - p[1]).abs() < 1e-12);
        }
        assert_eq!(undistort(0.0, 0.0, 0.0, [1.0, 1.0]), None);
    }

    /// The cost never rises, on noisy observations with outliers where most points are already at
    /// their optimum.
    #[test]
    fn the_cost_never_rises() {
        let generated = synthetic::generate(&SyntheticOptions::default());
        let mut problem = generated.start;
        let before = problem.cost();
        let outcome = retriangulate(&mut problem, None);
        assert!(outcome.cost_after <= outcome.cost_before);
        assert!((outcome.cost_before - before).abs() <= 1e-9 * before.max(1.0));
        assert!((problem.cost() - outcome.cost_after).abs() <= 1e-9 * before.max(1.0));
    }
}
