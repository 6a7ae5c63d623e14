//! SE(2), rigid motions of the plane, on `nalgebra::Isometry2`. Tangent order `[v_x, v_y, ω]`
//! (Solà et al. 2018, appendix C; GTSAM's Pose2).

use nalgebra::{Isometry2, Matrix2, Matrix3, Vector2, Vector3};

/// The matrix V(θ) with Exp([v, θ]) = (R(θ), V(θ) v).
#[inline]
fn v_matrix(theta: f64) -> Matrix2<f64> {
    let t2 = theta * theta;
    let (a, b) = if theta.abs() < 1e-4 {
        (1.0 - t2 / 6.0, theta / 2.0 - theta * t2 / 24.0)
    } else {
        // 1 − cos θ = 2 sin²(θ/2), which keeps its digits where θ is small.
        let h = (0.5 * theta).sin();
        (theta.sin() / theta, 2.0 * h * h / theta)
    };
    Matrix2::new(a, -b, b, a)
}

/// Builds a pose from its coordinates (x, y, θ).
#[inline]
pub fn from_coordinates(c: &[f64]) -> Isometry2<f64> {
    Isometry2::new(Vector2::new(c[0], c[1]), c[2])
}

/// The coordinates (x, y, θ) of a pose, θ in (-π, π].
#[inline]
pub fn coordinates(t: &Isometry2<f64>) -> Vector3<f64> {
    Vector3::new(t.translation.x, t.translation.y, t.rotation.angle())
}

/// Exp: the pose reached by moving with twist `[v_x, v_y, ω]` for unit time.
pub fn exp(xi: &Vector3<f64>) -> Isometry2<f64> {
    let t = v_matrix(xi.z) * Vector2::new(xi.x, xi.y);
    Isometry2::new(t, xi.z)
}

/// Log: the twist `[v_x, v_y, ω]` with Exp(twist) = T, ω in (-π, π].
pub fn log(t: &Isometry2<f64>) -> Vector3<f64> {
    let theta = t.rotation.angle();
    let v = v_matrix(theta)
        .try_inverse()
        .unwrap_or_else(Matrix2::identity)
        * t.translation.vector;
    Vector3::new(v.x, v.y, theta)
}

/// The adjoint Ad(T), with T Exp(ξ) T⁻¹ = Exp(Ad(T) ξ).
pub fn adjoint(t: &Isometry2<f64>) -> Matrix3<f64> {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let p = t.translation.vector;
    Matrix3::new(
        r[(0, 0)],
        r[(0, 1)],
        p.y,
        r[(1, 0)],
        r[(1, 1)],
        -p.x,
        0.0,
        0.0,
        1.0,
    )
}

/// The inverse right Jacobian Jr⁻¹(τ): Log(Exp(τ) Exp(δ)) ≈ τ + Jr⁻¹(τ) δ (Solà et al. 2018, eq. 163).
pub fn right_jacobian_inv(tau: &Vector3<f64>) -> Matrix3<f64> {
    let (r1, r2, t) = (tau.x, tau.y, tau.z);
    let t2 = t * t;
    // Jr = [[A, b], [0, 1]] with A = [[s/θ, (1−c)/θ], [−(1−c)/θ, s/θ]]
    let (a, c1, d1, d2) = if t.abs() < 1e-4 {
        // s/θ, (1−c)/θ, (θ − s)/θ², (1 − c)/θ²
        (
            1.0 - t2 / 6.0,
            t / 2.0 - t * t2 / 24.0,
            t / 6.0 - t * t2 / 120.0,
            0.5 - t2 / 24.0,
        )
    } else {
        let s = t.sin();
        let h = (0.5 * t).sin();
        let one_minus_c = 2.0 * h * h;
        (s / t, one_minus_c / t, (t - s) / t2, one_minus_c / t2)
    };
    let b = Vector2::new(r1 * d1 - r2 * d2, r1 * d2 + r2 * d1);
    let m = Matrix2::new(a, c1, -c1, a);
    let m_inv = m.try_inverse().unwrap_or_else(Matrix2::identity);
    let top = -(m_inv * b);
    Matrix3::new(
        m_inv[(0, 0)],
        m_inv[(0, 1)],
        top.x,
        m_inv[(1, 0)],
        m_inv[(1, 1)],
        top.y,
        0.0,
        0.0,
        1.0,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use proptest::prelude::*;

    fn twist() -> impl Strategy<Value = Vector3<f64>> {
        (-5.0f64..5.0, -5.0f64..5.0, -3.0f64..3.0).prop_map(|(a, b, c)| Vector3::new(a, b, c))
    }

    proptest! {
        #[test]
        fn exp_log_round_trip(xi in twist()) {
            assert_relative_eq!(log(&exp(&xi)), xi, epsilon = 1e-10);
        }

        #[test]
        fn adjoint_moves_twists_across(xi in twist(), p in twist()) {
            let t = exp(&p);
            let small = xi * 1e-3;
            let lhs = log(&(t * exp(&small) * t.inverse()));
            assert_relative_eq!(lhs, adjoint(&t) * small, epsilon = 1e-9);
        }

        #[test]
        fn right_jacobian_inverse_is_the_derivative_of_log(xi in twist(), d in twist(), tiny in any::<bool>()) {
            let xi = if tiny { xi * 1e-5 } else { xi };
            let h = 1e-6;
            let t = exp(&xi);
            let num = (log(&(t * exp(&(d * h)))) - log(&(t * exp(&(-d * h))))) / (2.0 * h);
            let ana = right_jacobian_inv(&xi) * d;
            prop_assert!((num - ana).norm() < 1e-6 * (1.0 + ana.norm()), "num {num:?} ana {ana:?}");
        }

        #[test]
        fn coordinates_round_trip(xi in twist()) {
            let t = exp(&xi);
            let c = coordinates(&t);
            let back = from_coordinates(c.as_slice());
            assert_relative_eq!(back.to_homogeneous(), t.to_homogeneous(), epsilon = 1e-12);
        }
    }
}
