//! Non-rigid terms (thesis ch. 4, after DynamicFusion, Newcombe et al. 2015, and embedded
//! deformation, Sumner et al. 2007): a point warped by dual-quaternion linear blending of its K
//! nearest deformation nodes (Kavan et al. 2008; thesis eq. 2.23, 4.2-4.3), the point-to-plane data
//! term on it (eq. 4.4), and the as-rigid-as-possible regulariser between graph neighbours
//! (eq. 4.5-4.6).
//!
//! Every node is an SE(3) variable `A_k` (camera/world frame, acting on canonical points) perturbed on
//! the right, `A_k Exp(δ_k)`, δ = `[ω; v]`, like [`dynamap_solver::SE3`]. Jacobians are exact: the
//! blend `b = Σ_k s_k w_k q_k` is linear in the node dual quaternions `q_k`, the warped point is a
//! rational function of `b` (differentiated in closed form by [`transform_point_jacobian`]), and
//! `∂(q_k ⊗ e(δ))/∂δ` at δ = 0 is [`right_perturbation`].

use crate::write_scaled;
use dynamap_solver::lie::se3;
use dynamap_solver::{Jacobians, Residual, Var, SE3};
use nalgebra::{
    DualQuaternion, Isometry3, Matrix3, Quaternion, SMatrix, Translation3, UnitQuaternion, Vector3,
};

/// Most nodes a point is bound to (the thesis' K).
pub const MAX_NEIGHBOURS: usize = 4;

/// ∂p/∂b of a point transformed by a (non-normalised) dual quaternion b, columns ordered
/// `[w, x, y, z]` of the real part then of the dual part.
pub type PointJacobian = SMatrix<f64, 3, 8>;

/// ∂q/∂δ of a node's dual quaternion under the right perturbation `A Exp(δ)`.
pub type NodeJacobian = SMatrix<f64, 8, 6>;

/// The unit dual quaternion of a rigid motion: real part the rotation q, dual part `½ t q`.
pub fn dual_quaternion(t: &Isometry3<f64>) -> DualQuaternion<f64> {
    let real = *t.rotation.quaternion();
    let tq = Quaternion::from_imag(t.translation.vector);
    DualQuaternion::from_real_and_dual(real, tq * real * 0.5)
}

/// The rigid motion of a (possibly non-normalised) dual quaternion b: the rotation of `b_r/|b_r|`
/// and the translation `2 vec(b_d b_r*) / |b_r|²` (the scalar part of `b_d b_r*`, which a unit dual
/// quaternion has zero, is dropped: Kavan et al.'s projection).
pub fn rigid_motion(b: &DualQuaternion<f64>) -> Isometry3<f64> {
    let n = b.real.norm_squared();
    let t = (b.dual * b.real.conjugate()).imag() * (2.0 / n);
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::new_normalize(b.real))
}

/// Dual-quaternion linear blending (Kavan et al. 2008): `Σ_k s_k w_k q_k`, each `q_k` taken with the
/// sign `s_k` that puts its real part in the hemisphere of the first node's (antipodal quaternions
/// are the same rotation). The result is not normalised; [`transform_point`] divides by its norm.
/// Returns the blend and the signs.
pub fn blend(
    nodes: &[DualQuaternion<f64>],
    weights: &[f64],
) -> (DualQuaternion<f64>, [f64; MAX_NEIGHBOURS]) {
    let mut signs = [1.0; MAX_NEIGHBOURS];
    let mut real = Quaternion::new(0.0, 0.0, 0.0, 0.0);
    let mut dual = real;
    for (k, (q, &w)) in nodes.iter().zip(weights).enumerate() {
        let s = if q.real.dot(&nodes[0].real) < 0.0 {
            -1.0
        } else {
            1.0
        };
        signs[k] = s;
        real += q.real * (s * w);
        dual += q.dual * (s * w);
    }
    (DualQuaternion::from_real_and_dual(real, dual), signs)
}

/// A point v moved by the blend b: `p = vec(b_r v b_r* + 2 b_d b_r*) / |b_r|²` (a unit dual
/// quaternion's `R v + t` after normalisation).
#[inline]
pub fn transform_point(b: &DualQuaternion<f64>, v: &Vector3<f64>) -> Vector3<f64> {
    transform_vector(b, v) + (b.dual * b.real.conjugate()).imag() * (2.0 / b.real.norm_squared())
}

/// A direction (normal) turned by the blend's rotation: `vec(b_r n b_r*) / |b_r|²`.
#[inline]
pub fn transform_vector(b: &DualQuaternion<f64>, n: &Vector3<f64>) -> Vector3<f64> {
    let (w, a) = (b.real.w, b.real.imag());
    let s = (w * w - a.dot(&a)) * n + 2.0 * a.dot(n) * a + 2.0 * w * a.cross(n);
    s / b.real.norm_squared()
}

/// [`transform_point`] and its Jacobian with respect to the eight coordinates of b.
///
/// With `S = (w² − a·a) v + 2(a·v) a + 2w a×v + 2(w a_d − w_d a + a×a_d)` and `N = w² + a·a`,
/// `p = S/N` and `∂p/∂b = (∂S/∂b − p ∂N/∂b) / N`.
pub fn transform_point_jacobian(
    b: &DualQuaternion<f64>,
    v: &Vector3<f64>,
) -> (Vector3<f64>, PointJacobian) {
    let (w, a) = (b.real.w, b.real.imag());
    let (wd, ad) = (b.dual.w, b.dual.imag());
    let n = w * w + a.dot(&a);
    let s = (w * w - a.dot(&a)) * v
        + 2.0 * a.dot(v) * a
        + 2.0 * w * a.cross(v)
        + 2.0 * (w * ad - wd * a + a.cross(&ad));
    let p = s / n;
    let mut j = PointJacobian::zeros();
    // ∂S/∂w − p ∂N/∂w
    let dw = 2.0 * w * v + 2.0 * a.cross(v) + 2.0 * ad - 2.0 * w * p;
    j.fixed_view_mut::<3, 1>(0, 0).copy_from(&(dw / n));
    // ∂S/∂a − p ∂N/∂a
    let da =
        -2.0 * v * a.transpose() + 2.0 * a.dot(v) * Matrix3::identity() + 2.0 * a * v.transpose()
            - 2.0 * w * v.cross_matrix()
            - 2.0 * wd * Matrix3::identity()
            - 2.0 * ad.cross_matrix()
            - 2.0 * p * a.transpose();
    j.fixed_view_mut::<3, 3>(0, 1).copy_from(&(da / n));
    j.fixed_view_mut::<3, 1>(0, 4).copy_from(&(-2.0 * a / n));
    j.fixed_view_mut::<3, 3>(0, 5)
        .copy_from(&((2.0 * w * Matrix3::identity() + 2.0 * a.cross_matrix()) / n));
    (p, j)
}

/// `∂(q ⊗ e(δ))/∂δ` at δ = 0, where `e(δ) = (1 + ½ω, ½ v) + O(|δ|²)` is the dual quaternion of
/// `Exp(δ)`: `∂q_r/∂ω = ½ q_r ⊗ (0, e_i)`, `∂q_d/∂ω = ½ q_d ⊗ (0, e_i)`, `∂q_d/∂v = ½ q_r ⊗ (0, e_i)`,
/// and for `q = (w, a)`, `q ⊗ (0, u) = (−a·u, w u + a × u)`.
pub fn right_perturbation(q: &DualQuaternion<f64>) -> NodeJacobian {
    let mut j = NodeJacobian::zeros();
    let mut put = |row: usize, col: usize, p: &Quaternion<f64>| {
        let (w, a) = (p.w, p.imag());
        for c in 0..3 {
            j[(row, col + c)] = -0.5 * a[c];
        }
        let m = 0.5 * (w * Matrix3::identity() + a.cross_matrix());
        j.fixed_view_mut::<3, 3>(row + 1, col).copy_from(&m);
    };
    put(0, 0, &q.real);
    put(4, 0, &q.dual);
    put(4, 3, &q.real);
    j
}

/// `∂r/∂δ_k = s_k w_k (∂r/∂b) ∂q_k/∂δ_k` for every node, from `g = ∂r/∂b` (R×8), written
/// column-major into `jac[k]`.
fn chain_to_nodes<const R: usize, J: AsMut<[f64]>>(
    nodes: &[DualQuaternion<f64>],
    weights: &[f64],
    signs: &[f64],
    g: &SMatrix<f64, R, 8>,
    jac: &mut [J],
) {
    for (k, node) in nodes.iter().enumerate() {
        let jk = g * right_perturbation(node) * (signs[k] * weights[k]);
        jac[k].as_mut().copy_from_slice(jk.as_slice());
    }
}

/// Point-to-plane under the warp (thesis eq. 4.4): `r = nᵀ(W(v) − q)` for a canonical point v bound
/// to `nodes` with normalised `weights`, against a target point q with unit normal n. Writes
/// `∂r/∂δ_k` into `jac[k]` and returns r.
pub fn warped_point_to_plane(
    nodes: &[DualQuaternion<f64>],
    weights: &[f64],
    v: &Vector3<f64>,
    q: &Vector3<f64>,
    n: &Vector3<f64>,
    jac: &mut [[f64; 6]],
) -> f64 {
    let (b, signs) = blend(nodes, weights);
    let (p, dp) = transform_point_jacobian(&b, v);
    chain_to_nodes(nodes, weights, &signs, &(n.transpose() * dp), jac);
    n.dot(&(p - q))
}

/// Point-to-point under the warp: `r = W(v) − q`. Writes `∂r/∂δ_k` (3×6, column-major) into
/// `jac[k]` and returns r.
pub fn warped_point_to_point(
    nodes: &[DualQuaternion<f64>],
    weights: &[f64],
    v: &Vector3<f64>,
    q: &Vector3<f64>,
    jac: &mut [[f64; 18]],
) -> Vector3<f64> {
    let (b, signs) = blend(nodes, weights);
    let (p, dp) = transform_point_jacobian(&b, v);
    chain_to_nodes(nodes, weights, &signs, &dp, jac);
    p - q
}

/// As-rigid-as-possible between graph neighbours i and j (thesis eq. 4.5; Sumner et al.'s
/// regulariser): `r = A_i g_j − A_j g_j`, node i's motion applied to node j's position against node
/// j's own. Returns r, `∂r/∂δ_i = [−R_i [g_j]×, R_i]` and `∂r/∂δ_j = −[−R_j [g_j]×, R_j]`.
pub fn as_rigid_as_possible(
    ti: &Isometry3<f64>,
    tj: &Isometry3<f64>,
    gj: &Vector3<f64>,
) -> (Vector3<f64>, SMatrix<f64, 3, 6>, SMatrix<f64, 3, 6>) {
    let r = ti * nalgebra::Point3::from(*gj) - tj * nalgebra::Point3::from(*gj);
    let jac = |t: &Isometry3<f64>, sign: f64| {
        let rot = t.rotation.to_rotation_matrix().into_inner();
        let mut j = SMatrix::<f64, 3, 6>::zeros();
        j.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&(-sign * rot * gj.cross_matrix()));
        j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(sign * rot));
        j
    };
    (r, jac(ti, 1.0), jac(tj, -1.0))
}

/// [`warped_point_to_plane`] as a residual on the point's K node variables (SE(3)), scaled by
/// `scale` (√ of the term's weight; 0 switches it off without changing the problem's structure).
#[derive(Clone, Debug, PartialEq)]
pub struct WarpedPointToPlane {
    /// Canonical point.
    pub point: Vector3<f64>,
    /// Normalised blending weights, one per node variable.
    pub weights: [f64; MAX_NEIGHBOURS],
    /// Target point.
    pub target: Vector3<f64>,
    /// Target normal (unit).
    pub normal: Vector3<f64>,
    /// Multiplies residual and Jacobian.
    pub scale: f64,
}

/// The dual quaternions of the node variables of a residual (at most [`MAX_NEIGHBOURS`]).
fn node_dqs(vars: &[Var<'_>]) -> [DualQuaternion<f64>; MAX_NEIGHBOURS] {
    let mut out = [DualQuaternion::identity(); MAX_NEIGHBOURS];
    for (o, v) in out.iter_mut().zip(vars) {
        *o = dual_quaternion(&se3::from_slice(v.value));
    }
    out
}

impl Residual for WarpedPointToPlane {
    fn dim(&self) -> usize {
        1
    }
    fn variable_size(&self, _k: usize) -> Option<(usize, usize)> {
        Some(SE3::SIZE)
    }
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) {
        let k = vars.len().min(MAX_NEIGHBOURS);
        let nodes = node_dqs(vars);
        if jacobians.is_none() {
            // a cost evaluation: the warped point alone, no Jacobian chain
            let p = transform_point(&blend(&nodes[..k], &self.weights[..k]).0, &self.point);
            let r = self.normal.dot(&(p - self.target));
            write_scaled::<0>(self.scale, &[r], &[], residual, None);
            return;
        }
        let mut jac = [[0.0; 6]; MAX_NEIGHBOURS];
        let r = warped_point_to_plane(
            &nodes[..k],
            &self.weights[..k],
            &self.point,
            &self.target,
            &self.normal,
            &mut jac,
        );
        write_scaled(self.scale, &[r], &jac[..k], residual, jacobians);
    }
}

/// [`warped_point_to_point`] as a residual on the point's K node variables, scaled by `scale`.
#[derive(Clone, Debug, PartialEq)]
pub struct WarpedPointToPoint {
    /// Canonical point.
    pub point: Vector3<f64>,
    /// Normalised blending weights, one per node variable.
    pub weights: [f64; MAX_NEIGHBOURS],
    /// Target point.
    pub target: Vector3<f64>,
    /// Multiplies residual and Jacobian.
    pub scale: f64,
}

impl Residual for WarpedPointToPoint {
    fn dim(&self) -> usize {
        3
    }
    fn variable_size(&self, _k: usize) -> Option<(usize, usize)> {
        Some(SE3::SIZE)
    }
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) {
        let k = vars.len().min(MAX_NEIGHBOURS);
        let nodes = node_dqs(vars);
        if jacobians.is_none() {
            let p = transform_point(&blend(&nodes[..k], &self.weights[..k]).0, &self.point);
            write_scaled::<0>(
                self.scale,
                (p - self.target).as_slice(),
                &[],
                residual,
                None,
            );
            return;
        }
        let mut jac = [[0.0; 18]; MAX_NEIGHBOURS];
        let r = warped_point_to_point(
            &nodes[..k],
            &self.weights[..k],
            &self.point,
            &self.target,
            &mut jac,
        );
        write_scaled(self.scale, r.as_slice(), &jac[..k], residual, jacobians);
    }
}

/// [`as_rigid_as_possible`] as a residual on the node variables (i, j), scaled by `scale`
/// (√(λ φ_ij), the regulariser weight times the edge weight of eq. 4.7).
#[derive(Clone, Debug, PartialEq)]
pub struct AsRigidAsPossible {
    /// Position g_j of the second node, canonical frame.
    pub position: Vector3<f64>,
    /// Multiplies residual and Jacobians.
    pub scale: f64,
}

impl Residual for AsRigidAsPossible {
    fn dim(&self) -> usize {
        3
    }
    fn arity(&self) -> Option<usize> {
        Some(2)
    }
    fn variable_size(&self, _k: usize) -> Option<(usize, usize)> {
        Some(SE3::SIZE)
    }
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) {
        let (r, ji, jj) = as_rigid_as_possible(
            &se3::from_slice(vars[0].value),
            &se3::from_slice(vars[1].value),
            &self.position,
        );
        let blocks = [ji, jj].map(|m| {
            let mut b = [0.0; 18];
            b.copy_from_slice(m.as_slice());
            b
        });
        write_scaled(self.scale, r.as_slice(), &blocks, residual, jacobians);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynamap_solver::{check_jacobians, Manifold, SE3};
    use nalgebra::{Point3, Vector6};
    use proptest::prelude::*;

    fn pose(a: &[f64], rot: f64, trans: f64) -> Isometry3<f64> {
        se3::exp(&Vector6::new(
            a[0] * rot,
            a[1] * rot,
            a[2] * rot,
            a[3] * trans,
            a[4] * trans,
            a[5] * trans,
        ))
    }

    fn vars<'a>(xs: &'a [[f64; 7]]) -> Vec<Var<'a>> {
        xs.iter()
            .map(|x| Var {
                value: x,
                manifold: &SE3 as &dyn Manifold,
            })
            .collect()
    }

    /// K poses near a common one (nearby nodes of a smooth field), their ambient coordinates,
    /// and normalised weights.
    fn nodes(a: &[f64], k: usize) -> (Vec<[f64; 7]>, [f64; MAX_NEIGHBOURS]) {
        let base = pose(a, 1.5, 1.0);
        let mut xs = Vec::new();
        let mut w = [0.0; MAX_NEIGHBOURS];
        for i in 0..k {
            let t = base * pose(&a[6 + 6 * i..], 0.3, 0.1);
            let mut x = [0.0; 7];
            se3::to_slice(&t, &mut x);
            xs.push(x);
            w[i] = 0.1 + a[30 + i].abs();
        }
        let s: f64 = w.iter().sum();
        w.iter_mut().for_each(|v| *v /= s);
        (xs, w)
    }

    #[test]
    fn one_node_blends_to_its_own_motion() {
        let t = pose(&[0.3, -0.2, 0.5, 0.1, 0.4, -0.3], 1.0, 1.0);
        let q = dual_quaternion(&t);
        let (b, _) = blend(&[q], &[1.0]);
        let v = Vector3::new(0.2, -0.7, 1.3);
        let expect = t * Point3::from(v);
        assert!((transform_point(&b, &v) - expect.coords).norm() < 1e-12);
        let back = rigid_motion(&b);
        assert!((back.to_homogeneous() - t.to_homogeneous()).norm() < 1e-12);
    }

    #[test]
    fn agreeing_nodes_blend_rigidly_whatever_the_weights_and_signs() {
        let t = pose(&[-0.9, 0.4, 0.2, 0.3, 0.0, 0.8], 2.0, 1.0);
        let q = dual_quaternion(&t);
        let flipped = DualQuaternion::from_real_and_dual(-q.real, -q.dual);
        let (b, signs) = blend(&[q, flipped, q, flipped], &[0.1, 0.2, 0.3, 0.4]);
        assert_eq!(signs, [1.0, -1.0, 1.0, -1.0]);
        for v in [Vector3::new(1.0, 2.0, 3.0), Vector3::new(-0.5, 0.1, 0.0)] {
            let expect = t * Point3::from(v);
            assert!((transform_point(&b, &v) - expect.coords).norm() < 1e-12);
            let n = Vector3::new(0.0, 0.6, 0.8);
            assert!((transform_vector(&b, &n) - t.rotation * n).norm() < 1e-12);
        }
    }

    proptest! {
        #[test]
        fn transform_point_jacobian_matches_differences(a in prop::collection::vec(-1.0f64..1.0, 11)) {
            let b = DualQuaternion::from_real_and_dual(
                Quaternion::new(1.0 + a[0] * 0.5, a[1], a[2], a[3]),
                Quaternion::new(a[4], a[5], a[6], a[7]),
            );
            let v = Vector3::new(a[8], a[9], a[10]);
            let (_, j) = transform_point_jacobian(&b, &v);
            let h = 1e-6;
            for c in 0..8 {
                let shift = |d: f64| {
                    let mut x = [b.real.w, b.real.i, b.real.j, b.real.k, b.dual.w, b.dual.i, b.dual.j, b.dual.k];
                    x[c] += d;
                    DualQuaternion::from_real_and_dual(
                        Quaternion::new(x[0], x[1], x[2], x[3]),
                        Quaternion::new(x[4], x[5], x[6], x[7]),
                    )
                };
                let num = (transform_point(&shift(h), &v) - transform_point(&shift(-h), &v)) / (2.0 * h);
                for r in 0..3 {
                    prop_assert!((num[r] - j[(r, c)]).abs() < 1e-6 * (1.0 + num[r].abs()), "{c} {r} {num} {j}");
                }
            }
        }

        #[test]
        fn warped_point_to_plane_jacobian(a in prop::collection::vec(-1.0f64..1.0, 40), k in 1usize..=4) {
            let (xs, weights) = nodes(&a, k);
            let r = WarpedPointToPlane {
                point: Vector3::new(a[34], a[35], a[36]),
                weights,
                target: Vector3::new(a[37], a[38], a[39]),
                normal: Vector3::new(a[36], a[35] + 2.0, a[34]).normalize(),
                scale: 0.7,
            };
            let c = check_jacobians(&r, &vars(&xs));
            prop_assert!(c.passes(1e-6), "{c:?}");
        }

        #[test]
        fn warped_point_to_point_jacobian(a in prop::collection::vec(-1.0f64..1.0, 40), k in 1usize..=4) {
            let (xs, weights) = nodes(&a, k);
            let r = WarpedPointToPoint {
                point: Vector3::new(a[34], a[35], a[36]),
                weights,
                target: Vector3::new(a[37], a[38], a[39]),
                scale: 1.3,
            };
            let c = check_jacobians(&r, &vars(&xs));
            prop_assert!(c.passes(1e-6), "{c:?}");
        }

        #[test]
        fn as_rigid_as_possible_jacobian(a in prop::collection::vec(-1.0f64..1.0, 15)) {
            let mut xs = [[0.0; 7]; 2];
            se3::to_slice(&pose(&a, 2.0, 1.0), &mut xs[0]);
            se3::to_slice(&pose(&a[6..], 2.0, 1.0), &mut xs[1]);
            let r = AsRigidAsPossible { position: Vector3::new(a[12], a[13], a[14]), scale: 0.5 };
            let c = check_jacobians(&r, &vars(&xs));
            prop_assert!(c.passes(1e-7), "{c:?}");
        }
    }
}
