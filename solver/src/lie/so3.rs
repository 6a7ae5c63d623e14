//! SO(3): exponential and logarithm through unit quaternions, right Jacobians (Barfoot, *State
//! Estimation for Robotics*, 2017, eq. 7.77 and 7.78; Solà et al. 2018, eq. 143-146).

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

/// Below this angle the closed forms are replaced by their Taylor series.
const SMALL: f64 = 1e-2;

/// The skew-symmetric matrix `[w]×` with `[w]× u = w × u`.
#[inline]
pub fn hat(w: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}

/// Exp: the rotation by angle |w| about w / |w|, as a unit quaternion.
#[inline]
pub fn exp(w: &Vector3<f64>) -> UnitQuaternion<f64> {
    let t2 = w.norm_squared();
    let t = t2.sqrt();
    let (s, c) = if t < SMALL {
        // sin(t/2)/t and cos(t/2) by their series.
        (
            0.5 - t2 / 48.0 + t2 * t2 / 3840.0,
            1.0 - t2 / 8.0 + t2 * t2 / 384.0,
        )
    } else {
        ((0.5 * t).sin() / t, (0.5 * t).cos())
    };
    UnitQuaternion::new_unchecked(Quaternion::new(c, s * w.x, s * w.y, s * w.z))
}

/// Log: the rotation vector of `q`, angle in [0, π], exact for tiny angles.
#[inline]
pub fn log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let q = q.quaternion();
    let (mut w, mut v) = (q.w, q.vector().into_owned());
    if w < 0.0 {
        w = -w;
        v = -v;
    }
    let n = v.norm();
    // angle = 2 atan2(n, w); factor = angle / n
    let factor = if n < 1e-8 {
        2.0 / w * (1.0 - n * n / (3.0 * w * w))
    } else {
        2.0 * n.atan2(w) / n
    };
    v * factor
}

/// Coefficients (a, b) with Jr(w) = I - a [w]× + b [w]×², a = (1 - cos t)/t², b = (t - sin t)/t³.
#[inline]
fn jr_coefficients(t2: f64) -> (f64, f64) {
    let t = t2.sqrt();
    if t < SMALL {
        (
            0.5 - t2 / 24.0 + t2 * t2 / 720.0,
            1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0,
        )
    } else {
        ((1.0 - t.cos()) / t2, (t - t.sin()) / (t2 * t))
    }
}

/// The right Jacobian Jr(w): Exp(w + δ) ≈ Exp(w) Exp(Jr(w) δ).
pub fn right_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let (a, b) = jr_coefficients(w.norm_squared());
    let h = hat(w);
    Matrix3::identity() - h * a + h * h * b
}

/// The inverse right Jacobian Jr⁻¹(w) = I + ½\[w\]× + (1/t² - (1 + cos t)/(2 t sin t)) \[w\]×².
pub fn right_jacobian_inv(w: &Vector3<f64>) -> Matrix3<f64> {
    let t2 = w.norm_squared();
    let t = t2.sqrt();
    let c = if t < SMALL {
        1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0
    } else {
        1.0 / t2 - (1.0 + t.cos()) / (2.0 * t * t.sin())
    };
    let h = hat(w);
    Matrix3::identity() + h * 0.5 + h * h * c
}

/// The left Jacobian Jl(w) = Jr(-w), which maps the rotation vector to the translation factor of SE(3)'s Exp.
pub fn left_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    right_jacobian(&-w)
}

/// The inverse left Jacobian Jl⁻¹(w) = Jr⁻¹(-w).
pub fn left_jacobian_inv(w: &Vector3<f64>) -> Matrix3<f64> {
    right_jacobian_inv(&-w)
}

/// Projects a 3x3 matrix onto the nearest rotation in the Frobenius norm (SVD, determinant fixed to +1).
pub fn project(m: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u.unwrap(), svd.v_t.unwrap());
    let d = (u * vt).determinant().signum();
    u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * vt
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;
    use proptest::prelude::*;

    fn vec3(max: f64) -> impl Strategy<Value = Vector3<f64>> {
        (-max..max, -max..max, -max..max).prop_map(|(a, b, c)| Vector3::new(a, b, c))
    }

    proptest! {
        #[test]
        fn exp_log_round_trip(w in vec3(1.8)) {
            assert_relative_eq!(log(&exp(&w)), w, epsilon = 1e-12);
        }

        #[test]
        fn exp_log_round_trip_tiny(w in vec3(1e-7)) {
            assert_relative_eq!(log(&exp(&w)), w, epsilon = 1e-20, max_relative = 1e-9);
        }

        #[test]
        fn exp_matches_nalgebra(w in vec3(3.0)) {
            let a = exp(&w);
            let b = UnitQuaternion::from_scaled_axis(w);
            prop_assert!(a.angle_to(&b) < 1e-12);
        }

        #[test]
        fn right_jacobian_is_the_derivative_of_exp(w in vec3(2.5), d in vec3(1.0)) {
            let h = 1e-6;
            let jr = right_jacobian(&w);
            // Exp(w)^-1 Exp(w + h d) = Exp(h Jr d) + O(h^2)
            let lhs = log(&(exp(&w).inverse() * exp(&(w + d * h)))) / h;
            assert_relative_eq!(lhs, jr * d, epsilon = 1e-5);
            assert_relative_eq!(right_jacobian_inv(&w) * jr, Matrix3::identity(), epsilon = 1e-10);
        }

        #[test]
        fn jacobian_series_agree_across_the_threshold(d in vec3(1.0)) {
            prop_assume!(d.norm() > 1e-3);
            let d = d.normalize();
            let below = right_jacobian_inv(&(d * (SMALL * (1.0 - 1e-9))));
            let above = right_jacobian_inv(&(d * (SMALL * (1.0 + 1e-9))));
            assert_relative_eq!(below, above, epsilon = 1e-9);
            let below = right_jacobian(&(d * (SMALL * (1.0 - 1e-9))));
            let above = right_jacobian(&(d * (SMALL * (1.0 + 1e-9))));
            assert_relative_eq!(below, above, epsilon = 1e-9);
        }

        #[test]
        fn projection_of_a_perturbed_rotation_is_a_rotation(w in vec3(3.0), e in vec3(0.1)) {
            let r = exp(&w).to_rotation_matrix().into_inner();
            let m = r + hat(&e);
            let p = project(&m);
            assert_relative_eq!(p.transpose() * p, Matrix3::identity(), epsilon = 1e-12);
            prop_assert!((p.determinant() - 1.0).abs() < 1e-12);
            assert_relative_eq!(project(&r), r, epsilon = 1e-12);
        }
    }
}
