//! The Snavely reprojection error of Bundle Adjustment in the Large.

use dynamap_solver::lie::so3;
use dynamap_solver::{Jacobians, Residual, Var};
use nalgebra::{Matrix2, Matrix2x3, Matrix3, Vector3};

/// Reprojection error of one observation under BAL's camera model (Agarwal et al., *Bundle
/// Adjustment in the Large*, ECCV 2010; the BAL page's camera model):
///
/// ```text
/// P  = R(ω) X + t                       ω angle-axis (Rodrigues), t translation
/// p  = −(P_x, P_y) / P_z                the camera looks down −z
/// r  = f (1 + k₁‖p‖² + k₂‖p‖⁴) p − (u, v)
/// ```
///
/// Variables: the camera `[ω, t, f, k₁, k₂]` (9, Euclidean) and the point X (3, Euclidean).
/// Analytic Jacobians: ∂P/∂ω = −R \[X\]× J_r(ω) with J_r the right Jacobian of SO(3) (Barfoot 2017,
/// eq. 7.77), ∂P/∂X = R, ∂P/∂t = I, chained through the projection and the distortion.
#[derive(Clone, Copy, Debug)]
pub struct SnavelyReprojection {
    /// The observed image point (u, v) in pixels, origin at the image centre.
    pub observed: [f64; 2],
}

impl SnavelyReprojection {
    /// The residual of an observation (u, v).
    pub fn new(u: f64, v: f64) -> Self {
        Self { observed: [u, v] }
    }
}

/// R(ω) X by Rodrigues' formula, with its first-order form below machine epsilon (as Ceres'
/// `AngleAxisRotatePoint`).
pub fn rotate(w: &Vector3<f64>, x: &Vector3<f64>) -> Vector3<f64> {
    let t2 = w.norm_squared();
    if t2 > f64::EPSILON {
        let t = t2.sqrt();
        let (s, c) = t.sin_cos();
        let k = w / t;
        x * c + k.cross(x) * s + k * (k.dot(x) * (1.0 - c))
    } else {
        x + w.cross(x)
    }
}

/// R(ω) by Rodrigues' formula and the right Jacobian J_r(ω) = I − a[ω]× + b[ω]×² with
/// a = (1 − cos θ)/θ², b = (θ − sin θ)/θ³ (Barfoot 2017, eq. 7.77), sharing one sine and cosine;
/// small angles go through [`so3`]'s series.
fn rotation_and_right_jacobian(w: &Vector3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let t2 = w.norm_squared();
    if t2 < 1e-4 {
        return (
            so3::exp(w).to_rotation_matrix().into_inner(),
            so3::right_jacobian(w),
        );
    }
    let t = t2.sqrt();
    let (s, c) = t.sin_cos();
    let k = so3::hat(w);
    let k2 = k * k;
    let rot = Matrix3::identity() + k * (s / t) + k2 * ((1.0 - c) / t2);
    let jr = Matrix3::identity() - k * ((1.0 - c) / t2) + k2 * ((t - s) / (t2 * t));
    (rot, jr)
}

/// The residual r and, when asked, ∂r/∂camera (2×9) and ∂r/∂X (2×3), column-major.
pub fn reprojection(
    camera: &[f64],
    point: &[f64],
    observed: [f64; 2],
    jacobians: Option<(&mut [f64], &mut [f64])>,
) -> [f64; 2] {
    let w = Vector3::new(camera[0], camera[1], camera[2]);
    let t = Vector3::new(camera[3], camera[4], camera[5]);
    let (f, k1, k2) = (camera[6], camera[7], camera[8]);
    let x = Vector3::new(point[0], point[1], point[2]);
    // R(ω) and, for the Jacobian, J_r(ω) from one sine and cosine.
    let (rot, jr) = if jacobians.is_some() {
        let (rot, jr) = rotation_and_right_jacobian(&w);
        (Some(rot), Some(jr))
    } else {
        (None, None)
    };
    let p = match &rot {
        Some(r) => r * x + t,
        None => rotate(&w, &x) + t,
    };
    let (xp, yp) = (-p.x / p.z, -p.y / p.z);
    let r2 = xp * xp + yp * yp;
    let d = 1.0 + r2 * (k1 + k2 * r2);
    let r = [f * d * xp - observed[0], f * d * yp - observed[1]];
    if let Some((jc, jx)) = jacobians {
        let dd = k1 + 2.0 * k2 * r2;
        // ∂r/∂(xp, yp)
        let a = Matrix2::new(
            f * (d + 2.0 * xp * xp * dd),
            f * 2.0 * xp * yp * dd,
            f * 2.0 * xp * yp * dd,
            f * (d + 2.0 * yp * yp * dd),
        );
        // ∂(xp, yp)/∂P
        let inv_z = 1.0 / p.z;
        let b = Matrix2x3::new(
            -inv_z,
            0.0,
            p.x * inv_z * inv_z,
            0.0,
            -inv_z,
            p.y * inv_z * inv_z,
        );
        let ab = a * b;
        let (rot, jr) = (rot.unwrap_or_default(), jr.unwrap_or_default());
        // ∂r/∂X = A B R, and ∂r/∂ω = −A B R [X]× J_r(ω)
        let abr = ab * rot;
        let d_rot = -(abr * so3::hat(&x)) * jr;
        jc[..6].copy_from_slice(d_rot.as_slice());
        jc[6..12].copy_from_slice(ab.as_slice());
        jc[12] = d * xp;
        jc[13] = d * yp;
        jc[14] = f * r2 * xp;
        jc[15] = f * r2 * yp;
        jc[16] = f * r2 * r2 * xp;
        jc[17] = f * r2 * r2 * yp;
        jx.copy_from_slice(abr.as_slice());
    }
    r
}

impl Residual for SnavelyReprojection {
    fn dim(&self) -> usize {
        2
    }
    fn arity(&self) -> Option<usize> {
        Some(2)
    }
    fn variable_size(&self, k: usize) -> Option<(usize, usize)> {
        Some(if k == 0 { (9, 9) } else { (3, 3) })
    }
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) {
        let r = match jacobians {
            Some(j) => {
                let mut jc = [0.0; 18];
                let mut jx = [0.0; 6];
                let r = reprojection(
                    vars[0].value,
                    vars[1].value,
                    self.observed,
                    Some((&mut jc, &mut jx)),
                );
                j.block(0).copy_from_slice(&jc);
                j.block(1).copy_from_slice(&jx);
                r
            }
            None => reprojection(vars[0].value, vars[1].value, self.observed, None),
        };
        residual.copy_from_slice(&r);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynamap_solver::{check_jacobians, Euclidean};
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn jacobians_match_central_differences(
            w in prop::array::uniform3(-1.5f64..1.5),
            tiny in any::<bool>(),
            t in prop::array::uniform3(-1.0f64..1.0),
            f in 300.0f64..900.0,
            k1 in -0.3f64..0.3,
            k2 in -0.1f64..0.1,
            x in prop::array::uniform2(-2.0f64..2.0),
            depth in 3.0f64..12.0,
        ) {
            let w = if tiny { [w[0] * 1e-9, w[1] * 1e-9, w[2] * 1e-9] } else { w };
            let camera = [w[0], w[1], w[2], t[0], t[1], t[2], f, k1, k2];
            // a point in front of the camera (P_z < 0), mapped back to world coordinates
            let p_cam = Vector3::new(x[0], x[1], -depth) - Vector3::from(t);
            let point = rotate(&-Vector3::from(w), &p_cam);
            let residual = SnavelyReprojection::new(12.0, -7.0);
            let vars = [
                Var { value: &camera, manifold: &Euclidean::<9> },
                Var { value: point.as_slice(), manifold: &Euclidean::<3> },
            ];
            let check = check_jacobians(&residual, &vars);
            prop_assert!(check.passes(1e-6), "{check:?}");
        }
    }

    #[test]
    fn rodrigues_matches_the_rotation_matrix() {
        let w = Vector3::new(0.3, -0.2, 0.9);
        let x = Vector3::new(1.0, 2.0, -3.0);
        let r = so3::exp(&w).to_rotation_matrix() * x;
        assert!((rotate(&w, &x) - r).norm() < 1e-14);
    }
}
