//! SE(3), rigid motions of space, on `nalgebra::Isometry3`. Tangent order `[ω; v]`, as GTSAM's Pose3
//! (Barfoot 2017, sec. 7.1.5; Solà et al. 2018, appendix D).

use super::so3;
use nalgebra::{
    Isometry3, Matrix3, Matrix6, Quaternion, Translation3, UnitQuaternion, Vector3, Vector6,
};

/// Builds a pose from the stored layout `[tx, ty, tz, qx, qy, qz, qw]` (g2o's and TUM's order).
/// The quaternion is normalised.
#[inline]
pub fn from_slice(c: &[f64]) -> Isometry3<f64> {
    let q = UnitQuaternion::from_quaternion(Quaternion::new(c[6], c[3], c[4], c[5]));
    Isometry3::from_parts(Translation3::new(c[0], c[1], c[2]), q)
}

/// Writes a pose in the stored layout `[tx, ty, tz, qx, qy, qz, qw]`.
#[inline]
pub fn to_slice(t: &Isometry3<f64>, out: &mut [f64]) {
    let q = t.rotation.quaternion();
    out[..7].copy_from_slice(&[
        t.translation.x,
        t.translation.y,
        t.translation.z,
        q.i,
        q.j,
        q.k,
        q.w,
    ]);
}

/// Exp([ω; v]) = (Exp(ω), Jl(ω) v).
pub fn exp(xi: &Vector6<f64>) -> Isometry3<f64> {
    let w = xi.fixed_rows::<3>(0).into_owned();
    let v = xi.fixed_rows::<3>(3).into_owned();
    let t = so3::left_jacobian(&w) * v;
    Isometry3::from_parts(Translation3::from(t), so3::exp(&w))
}

/// Log(T) = [ω; Jl⁻¹(ω) t] with ω = Log(R).
pub fn log(t: &Isometry3<f64>) -> Vector6<f64> {
    let w = so3::log(&t.rotation);
    let v = so3::left_jacobian_inv(&w) * t.translation.vector;
    Vector6::new(w.x, w.y, w.z, v.x, v.y, v.z)
}

/// The adjoint Ad(T) = [[R, 0], [\[t\]× R, R]] for the `[ω; v]` order.
pub fn adjoint(t: &Isometry3<f64>) -> Matrix6<f64> {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let mut a = Matrix6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    a.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    a.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(so3::hat(&t.translation.vector) * r));
    a
}

/// Barfoot's Q(ρ, φ) (2017, eq. 7.86), the translation-rotation block of SE(3)'s left Jacobian.
fn q_block(rho: &Vector3<f64>, phi: &Vector3<f64>) -> Matrix3<f64> {
    let t2 = phi.norm_squared();
    let t = t2.sqrt();
    let (a, b, c) = if t < 1e-2 {
        (
            1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0,
            1.0 / 24.0 - t2 / 720.0 + t2 * t2 / 40320.0,
            1.0 / 120.0 - t2 / 2520.0,
        )
    } else {
        let (s, co) = t.sin_cos();
        (
            (t - s) / (t2 * t),
            (t2 + 2.0 * co - 2.0) / (2.0 * t2 * t2),
            (2.0 * t - 3.0 * s + t * co) / (2.0 * t2 * t2 * t),
        )
    };
    let r = so3::hat(rho);
    let p = so3::hat(phi);
    let pr = p * r;
    let rp = r * p;
    let prp = pr * p;
    r * 0.5 + (pr + rp + prp) * a + (p * pr + rp * p - prp * 3.0) * b + (prp * p + p * prp) * c
}

/// The inverse right Jacobian Jr⁻¹(ξ): Log(Exp(ξ) Exp(δ)) ≈ ξ + Jr⁻¹(ξ) δ.
pub fn right_jacobian_inv(xi: &Vector6<f64>) -> Matrix6<f64> {
    // Jr(ξ) = Jl(-ξ) = [[J, 0], [Q, J]] with J = Jl(-ω) and Q = Q(-v, -ω); invert the block triangle.
    let w = -xi.fixed_rows::<3>(0).into_owned();
    let v = -xi.fixed_rows::<3>(3).into_owned();
    let j_inv = so3::left_jacobian_inv(&w);
    let q = q_block(&v, &w);
    let mut out = Matrix6::zeros();
    out.fixed_view_mut::<3, 3>(0, 0).copy_from(&j_inv);
    out.fixed_view_mut::<3, 3>(3, 3).copy_from(&j_inv);
    out.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(-j_inv * q * j_inv));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use proptest::prelude::*;

    fn twist(rot: f64) -> impl Strategy<Value = Vector6<f64>> {
        prop::array::uniform6(-1.0f64..1.0).prop_map(move |a| {
            Vector6::new(
                a[0] * rot,
                a[1] * rot,
                a[2] * rot,
                a[3] * 3.0,
                a[4] * 3.0,
                a[5] * 3.0,
            )
        })
    }

    proptest! {
        #[test]
        fn exp_log_round_trip(xi in twist(1.7)) {
            assert_relative_eq!(log(&exp(&xi)), xi, epsilon = 1e-10);
        }

        #[test]
        fn exp_log_round_trip_small(xi in twist(1e-6)) {
            assert_relative_eq!(log(&exp(&xi)), xi, epsilon = 1e-12);
        }

        #[test]
        fn adjoint_moves_twists_across(xi in twist(1.0), p in twist(2.0)) {
            let t = exp(&p);
            let small = xi * 1e-4;
            let lhs = log(&(t * exp(&small) * t.inverse()));
            assert_relative_eq!(lhs, adjoint(&t) * small, epsilon = 1e-10);
        }

        #[test]
        fn right_jacobian_inverse_is_the_derivative_of_log(xi in twist(2.5), d in twist(1.0), tiny in any::<bool>()) {
            let xi = if tiny { xi * 1e-3 } else { xi };
            // Log is the inverse of Exp only for rotation angles below π.
            prop_assume!(xi.fixed_rows::<3>(0).norm() < 3.0);
            let h = 1e-6;
            let t = exp(&xi);
            let num = (log(&(t * exp(&(d * h)))) - log(&(t * exp(&(-d * h))))) / (2.0 * h);
            let ana = right_jacobian_inv(&xi) * d;
            prop_assert!((num - ana).norm() < 1e-6, "xi {xi:?}\nnum {num:?}\nana {ana:?}");
        }

        #[test]
        fn slice_round_trip(xi in twist(3.0)) {
            let t = exp(&xi);
            let mut s = [0.0; 7];
            to_slice(&t, &mut s);
            assert_relative_eq!(from_slice(&s).to_homogeneous(), t.to_homogeneous(), epsilon = 1e-14);
        }
    }
}
