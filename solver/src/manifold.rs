//! Manifolds: the spaces variables live on.
//!
//! A variable is stored in its *ambient* coordinates (a quaternion has 4) and moved in its *tangent*
//! space (a rotation has 3 degrees of freedom) through `plus(x, δ) = x ⊞ δ`; `minus(y, x) = y ⊟ x` is
//! its inverse (Hertzberg et al., *Integrating generic sensor fusion algorithms with sound state
//! representations through encapsulation of manifolds*, 2013). The Lie groups use the right
//! perturbation `X ⊞ δ = X Exp(δ)`; see [`crate::lie`] for their tangent orders.

use crate::lie::{se2, se3, so2, so3};
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3, Vector6};
use std::fmt::Debug;

/// A smooth manifold with a retraction `plus` and its local inverse `minus`.
///
/// Laws (property-tested for every manifold here): `plus(x, 0) = x`, `minus(plus(x, δ), x) = δ` for
/// small δ, and `plus_jacobian` is the derivative of `plus(x, δ)` at δ = 0.
pub trait Manifold: Send + Sync + Debug {
    /// Number of stored (ambient) coordinates.
    fn ambient_dim(&self) -> usize;
    /// Number of degrees of freedom (tangent dimension).
    fn tangent_dim(&self) -> usize;
    /// `out = x ⊞ delta`.
    fn plus(&self, x: &[f64], delta: &[f64], out: &mut [f64]);
    /// `out = y ⊟ x`, the tangent vector δ with `x ⊞ δ = y`.
    fn minus(&self, y: &[f64], x: &[f64], out: &mut [f64]);
    /// `∂(x ⊞ δ)/∂δ` at δ = 0, ambient × tangent, column-major.
    fn plus_jacobian(&self, x: &[f64], out: &mut [f64]);
    /// True when `plus` is plain addition (the plus Jacobian is the identity).
    fn is_euclidean(&self) -> bool {
        false
    }
    /// Returns a checked, normalised copy of a value given in ambient coordinates (unit quaternions
    /// are normalised), or a message saying why it is not a point of the manifold.
    fn validate(&self, x: &[f64]) -> Result<Vec<f64>, String> {
        if x.len() != self.ambient_dim() {
            return Err(format!(
                "expected {} coordinates, got {}",
                self.ambient_dim(),
                x.len()
            ));
        }
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            return Err(format!("coordinate {i} is not finite ({})", x[i]));
        }
        Ok(x.to_vec())
    }
}

/// Rⁿ with a size known at compile time.
#[derive(Clone, Copy, Debug, Default)]
pub struct Euclidean<const N: usize>;

/// Rⁿ with a size chosen at run time.
#[derive(Clone, Copy, Debug)]
pub struct EuclideanDyn(pub usize);

fn identity_into(n: usize, out: &mut [f64]) {
    out[..n * n].fill(0.0);
    for i in 0..n {
        out[i * n + i] = 1.0;
    }
}

/// The size of a Euclidean space, known statically or at run time.
trait Size {
    fn size(&self) -> usize;
}
impl<const N: usize> Size for Euclidean<N> {
    fn size(&self) -> usize {
        N
    }
}
impl Size for EuclideanDyn {
    fn size(&self) -> usize {
        self.0
    }
}

impl<E: Size + Send + Sync + Debug> Manifold for E {
    fn ambient_dim(&self) -> usize {
        self.size()
    }
    fn tangent_dim(&self) -> usize {
        self.size()
    }
    fn plus(&self, x: &[f64], delta: &[f64], out: &mut [f64]) {
        for i in 0..self.size() {
            out[i] = x[i] + delta[i];
        }
    }
    fn minus(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        for i in 0..self.size() {
            out[i] = y[i] - x[i];
        }
    }
    fn plus_jacobian(&self, _x: &[f64], out: &mut [f64]) {
        identity_into(self.size(), out);
    }
    fn is_euclidean(&self) -> bool {
        true
    }
}

/// SO(2) stored as an angle θ; `θ ⊞ δ = wrap(θ + δ)`.
#[derive(Clone, Copy, Debug, Default)]
pub struct SO2;

impl Manifold for SO2 {
    fn ambient_dim(&self) -> usize {
        1
    }
    fn tangent_dim(&self) -> usize {
        1
    }
    fn plus(&self, x: &[f64], delta: &[f64], out: &mut [f64]) {
        out[0] = so2::wrap(x[0] + delta[0]);
    }
    fn minus(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        out[0] = so2::wrap(y[0] - x[0]);
    }
    fn plus_jacobian(&self, _x: &[f64], out: &mut [f64]) {
        out[0] = 1.0;
    }
}

/// SE(2) stored as `[x, y, θ]`, tangent `[v_x, v_y, ω]`, `X ⊞ δ = X Exp(δ)`.
#[derive(Clone, Copy, Debug, Default)]
pub struct SE2;

impl SE2 {
    /// (ambient, tangent) sizes, for [`crate::Residual::variable_size`].
    pub const SIZE: (usize, usize) = (3, 3);
}

impl Manifold for SE2 {
    fn ambient_dim(&self) -> usize {
        Self::SIZE.0
    }
    fn tangent_dim(&self) -> usize {
        Self::SIZE.1
    }
    fn plus(&self, x: &[f64], delta: &[f64], out: &mut [f64]) {
        let t = se2::from_coordinates(x) * se2::exp(&Vector3::new(delta[0], delta[1], delta[2]));
        out[..3].copy_from_slice(se2::coordinates(&t).as_slice());
    }
    fn minus(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        let d = se2::log(&(se2::from_coordinates(x).inverse() * se2::from_coordinates(y)));
        out[..3].copy_from_slice(d.as_slice());
    }
    fn plus_jacobian(&self, x: &[f64], out: &mut [f64]) {
        // d(t + R V(ω) v, θ + ω)/d(v, ω) at 0 = [[R, 0], [0, 1]]
        let (s, c) = x[2].sin_cos();
        out[..9].copy_from_slice(&[c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0]);
    }
    fn validate(&self, x: &[f64]) -> Result<Vec<f64>, String> {
        let mut v = Euclidean::<3>.validate(x)?;
        v[2] = so2::wrap(v[2]);
        Ok(v)
    }
}

/// Writes ∂(q ⊗ Exp(δ))/∂δ at δ = 0 (4 × 3, column-major, rows x, y, z, w) into `out` at `row0` of a
/// column-major matrix with `rows` rows.
fn quaternion_plus_jacobian(q: &[f64], out: &mut [f64], rows: usize, row0: usize, col0: usize) {
    let (x, y, z, w) = (q[0], q[1], q[2], q[3]);
    // ½ [w I + [q_v]×; -q_vᵀ], column by column
    let cols = [[w, z, -y, -x], [-z, w, x, -y], [y, -x, w, -z]];
    for (k, col) in cols.iter().enumerate() {
        for (i, v) in col.iter().enumerate() {
            out[(col0 + k) * rows + row0 + i] = 0.5 * v;
        }
    }
}

fn quaternion_from(x: &[f64]) -> UnitQuaternion<f64> {
    UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(x[3], x[0], x[1], x[2]))
}

fn validate_quaternion(x: &[f64], at: usize) -> Result<(), String> {
    let n = x[at..at + 4].iter().map(|v| v * v).sum::<f64>().sqrt();
    if n.is_nan() || n <= 1e-9 {
        return Err(format!("quaternion has norm {n}, not a rotation"));
    }
    Ok(())
}

fn normalise_quaternion(v: &mut [f64]) {
    let n = v.iter().map(|a| a * a).sum::<f64>().sqrt();
    for a in v.iter_mut() {
        *a /= n;
    }
}

/// Unit quaternions stored as `[x, y, z, w]`, tangent the rotation vector, `q ⊞ δ = q ⊗ Exp(δ)`.
#[derive(Clone, Copy, Debug, Default)]
pub struct UnitQuaternionManifold;

impl Manifold for UnitQuaternionManifold {
    fn ambient_dim(&self) -> usize {
        4
    }
    fn tangent_dim(&self) -> usize {
        3
    }
    fn plus(&self, x: &[f64], delta: &[f64], out: &mut [f64]) {
        let q = quaternion_from(x) * so3::exp(&Vector3::new(delta[0], delta[1], delta[2]));
        out[..4].copy_from_slice(q.coords.as_slice());
    }
    fn minus(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        let d = so3::log(&(quaternion_from(x).inverse() * quaternion_from(y)));
        out[..3].copy_from_slice(d.as_slice());
    }
    fn plus_jacobian(&self, x: &[f64], out: &mut [f64]) {
        quaternion_plus_jacobian(x, out, 4, 0, 0);
    }
    fn validate(&self, x: &[f64]) -> Result<Vec<f64>, String> {
        let mut v = Euclidean::<4>.validate(x)?;
        validate_quaternion(&v, 0)?;
        normalise_quaternion(&mut v);
        Ok(v)
    }
}

/// SO(3) stored as a column-major rotation matrix (9 numbers), `R ⊞ δ = R Exp(δ)`.
#[derive(Clone, Copy, Debug, Default)]
pub struct SO3;

impl Manifold for SO3 {
    fn ambient_dim(&self) -> usize {
        9
    }
    fn tangent_dim(&self) -> usize {
        3
    }
    fn plus(&self, x: &[f64], delta: &[f64], out: &mut [f64]) {
        let r = Matrix3::from_column_slice(x);
        let e = so3::exp(&Vector3::new(delta[0], delta[1], delta[2])).to_rotation_matrix();
        out[..9].copy_from_slice((r * e.matrix()).as_slice());
    }
    fn minus(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        let r = Matrix3::from_column_slice(x).transpose() * Matrix3::from_column_slice(y);
        let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
        out[..3].copy_from_slice(so3::log(&q).as_slice());
    }
    fn plus_jacobian(&self, x: &[f64], out: &mut [f64]) {
        // ∂(R Exp(δ))/∂δ_k = R [e_k]×
        let r = Matrix3::from_column_slice(x);
        for k in 0..3 {
            let d = r * so3::hat(&Vector3::ith(k, 1.0));
            out[k * 9..k * 9 + 9].copy_from_slice(d.as_slice());
        }
    }
    fn validate(&self, x: &[f64]) -> Result<Vec<f64>, String> {
        let v = Euclidean::<9>.validate(x)?;
        let m = Matrix3::from_column_slice(&v);
        if (m.transpose() * m - Matrix3::identity()).abs().max() > 1e-6 || m.determinant() < 0.0 {
            return Err("matrix is not a rotation".into());
        }
        Ok(so3::project(&m).as_slice().to_vec())
    }
}

/// SE(3) stored as `[tx, ty, tz, qx, qy, qz, qw]`, tangent `[ω; v]`, `X ⊞ δ = X Exp(δ)`.
#[derive(Clone, Copy, Debug, Default)]
pub struct SE3;

impl SE3 {
    /// (ambient, tangent) sizes, for [`crate::Residual::variable_size`].
    pub const SIZE: (usize, usize) = (7, 6);
}

impl Manifold for SE3 {
    fn ambient_dim(&self) -> usize {
        Self::SIZE.0
    }
    fn tangent_dim(&self) -> usize {
        Self::SIZE.1
    }
    fn plus(&self, x: &[f64], delta: &[f64], out: &mut [f64]) {
        let t = se3::from_slice(x) * se3::exp(&Vector6::from_column_slice(&delta[..6]));
        se3::to_slice(&t, out);
    }
    fn minus(&self, y: &[f64], x: &[f64], out: &mut [f64]) {
        let d = se3::log(&(se3::from_slice(x).inverse() * se3::from_slice(y)));
        out[..6].copy_from_slice(d.as_slice());
    }
    fn plus_jacobian(&self, x: &[f64], out: &mut [f64]) {
        // translation t + R Jl(ω) v: ∂/∂v = R, ∂/∂ω = 0; rotation q ⊗ Exp(ω).
        out[..42].fill(0.0);
        let r = quaternion_from(&x[3..7]).to_rotation_matrix().into_inner();
        for c in 0..3 {
            for rr in 0..3 {
                out[(3 + c) * 7 + rr] = r[(rr, c)];
            }
        }
        quaternion_plus_jacobian(&x[3..7], out, 7, 3, 0);
    }
    fn validate(&self, x: &[f64]) -> Result<Vec<f64>, String> {
        let mut v = Euclidean::<7>.validate(x)?;
        validate_quaternion(&v, 3)?;
        normalise_quaternion(&mut v[3..7]);
        Ok(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A random point of each manifold, and a random tangent vector.
    fn sample(m: &dyn Manifold, seed: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let origin = match m.ambient_dim() {
            4 => vec![0.0, 0.0, 0.0, 1.0],
            7 => vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            9 if m.tangent_dim() == 3 => Matrix3::<f64>::identity().as_slice().to_vec(),
            n => vec![0.0; n],
        };
        let t = m.tangent_dim();
        let mut x = vec![0.0; m.ambient_dim()];
        m.plus(
            &origin,
            &seed[..t].iter().map(|v| v * 2.0).collect::<Vec<_>>(),
            &mut x,
        );
        (x, seed[t..2 * t].iter().map(|v| v * 0.5).collect())
    }

    fn manifolds() -> Vec<Box<dyn Manifold>> {
        vec![
            Box::new(Euclidean::<3>),
            Box::new(EuclideanDyn(5)),
            Box::new(SO2),
            Box::new(SE2),
            Box::new(UnitQuaternionManifold),
            Box::new(SO3),
            Box::new(SE3),
        ]
    }

    proptest! {
        #[test]
        fn plus_minus_round_trip(seed in prop::collection::vec(-1.0f64..1.0, 12)) {
            for m in manifolds() {
                let (x, d) = sample(m.as_ref(), &seed);
                let mut y = vec![0.0; m.ambient_dim()];
                m.plus(&x, &d, &mut y);
                let mut back = vec![0.0; m.tangent_dim()];
                m.minus(&y, &x, &mut back);
                for (a, b) in back.iter().zip(&d) {
                    prop_assert!((a - b).abs() < 1e-10, "{m:?}: {back:?} vs {d:?}");
                }
                let zero = vec![0.0; m.tangent_dim()];
                m.plus(&x, &zero, &mut y);
                for (a, b) in y.iter().zip(&x) {
                    prop_assert!((a - b).abs() < 1e-12, "{m:?}: plus(x, 0) != x");
                }
                m.minus(&x, &x, &mut back);
                prop_assert!(back.iter().all(|v| v.abs() < 1e-12));
            }
        }

        #[test]
        fn plus_jacobian_matches_central_differences(seed in prop::collection::vec(-1.0f64..1.0, 12)) {
            for m in manifolds() {
                let (x, _) = sample(m.as_ref(), &seed);
                let (a, t) = (m.ambient_dim(), m.tangent_dim());
                let mut j = vec![0.0; a * t];
                m.plus_jacobian(&x, &mut j);
                let h = 1e-6;
                let (mut p, mut q) = (vec![0.0; a], vec![0.0; a]);
                for k in 0..t {
                    let mut d = vec![0.0; t];
                    d[k] = h;
                    m.plus(&x, &d, &mut p);
                    d[k] = -h;
                    m.plus(&x, &d, &mut q);
                    for r in 0..a {
                        let num = (p[r] - q[r]) / (2.0 * h);
                        prop_assert!((num - j[k * a + r]).abs() < 1e-7, "{m:?} ({r},{k}): {num} vs {}", j[k * a + r]);
                    }
                }
            }
        }
    }

    #[test]
    fn validation_rejects_non_points() {
        assert!(UnitQuaternionManifold
            .validate(&[0.0, 0.0, 0.0, 0.0])
            .is_err());
        assert!(SE3
            .validate(&[0.0, 0.0, f64::NAN, 0.0, 0.0, 0.0, 1.0])
            .is_err());
        assert!(SO3
            .validate(&[2.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])
            .is_err());
        let q = UnitQuaternionManifold
            .validate(&[0.0, 0.0, 0.0, 2.0])
            .unwrap();
        assert_eq!(q, vec![0.0, 0.0, 0.0, 1.0]);
        assert!(Euclidean::<2>.validate(&[1.0]).is_err());
    }
}
