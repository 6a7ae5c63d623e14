//! Rigid tracking terms (thesis eq. 3.2 and 3.14-3.20): point-to-plane distance and photometric
//! difference, as functions of the camera pose T (camera-to-world) under right perturbations
//! `T Exp(δ)`, δ = `[ω; v]` (the SE(3) tangent order of [`dynamap_solver::lie`]).
//!
//! Each comes twice from one formula: a plain function giving (r, ∂r/∂δ) for the tracker's dense
//! path, and a [`Residual`] wrapping it, so its Jacobian is property-tested with
//! [`dynamap_solver::check_jacobians`].

use dynamap_solver::lie::se3;
use dynamap_solver::{Jacobians, Residual, Var, SE3};
use nalgebra::{Isometry3, Matrix3, Vector3};

/// A rigid motion with its rotation as a matrix (and its transpose), for per-pixel use: applying it
/// costs 9 multiply-adds instead of a quaternion rotation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigidMotion {
    /// Rotation.
    pub r: Matrix3<f64>,
    /// Rᵀ.
    pub rt: Matrix3<f64>,
    /// Translation.
    pub t: Vector3<f64>,
}

impl RigidMotion {
    /// From an isometry.
    pub fn new(iso: &Isometry3<f64>) -> Self {
        let r = iso.rotation.to_rotation_matrix().into_inner();
        Self {
            r,
            rt: r.transpose(),
            t: iso.translation.vector,
        }
    }
    /// R p + t.
    #[inline]
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.r * p + self.t
    }
}

/// Point-to-plane: `r = nᵀ (T p − q)` for a source point p (camera frame) and a target point q with
/// normal n (world frame). Returns r and ∂r/∂δ = `[(p × Rᵀn)ᵀ, (Rᵀn)ᵀ]`.
#[inline]
pub fn point_to_plane(
    t: &RigidMotion,
    p: &Vector3<f64>,
    q: &Vector3<f64>,
    n: &Vector3<f64>,
) -> (f64, [f64; 6]) {
    let pw = t.apply(p);
    let r = n.dot(&(pw - q));
    let nc = t.rt * n;
    let w = p.cross(&nc);
    (r, [w.x, w.y, w.z, nc.x, nc.y, nc.z])
}

/// [`point_to_plane`] as a residual on one SE(3) variable.
#[derive(Clone, Debug)]
pub struct PointToPlane {
    /// Source point, camera frame.
    pub source: Vector3<f64>,
    /// Target point, world frame.
    pub target: Vector3<f64>,
    /// Target normal, world frame (unit).
    pub normal: Vector3<f64>,
}

impl Residual for PointToPlane {
    fn dim(&self) -> usize {
        1
    }
    fn arity(&self) -> Option<usize> {
        Some(1)
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
        let term = point_to_plane(
            &RigidMotion::new(&se3::from_slice(vars[0].value)),
            &self.source,
            &self.target,
            &self.normal,
        );
        write_scalar(Some(term), residual, jacobians);
    }
}

/// An image of intensities that can be sampled with its gradient at continuous pixel coordinates.
pub trait IntensityField: Sync {
    /// Intensity and `[∂I/∂u, ∂I/∂v]` at (u, v), or `None` outside the valid region.
    fn sample(&self, u: f64, v: f64) -> Option<(f64, [f64; 2])>;
}

/// Pinhole intrinsics of the reference image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    /// Focal length x.
    pub fx: f64,
    /// Focal length y.
    pub fy: f64,
    /// Principal point x.
    pub cx: f64,
    /// Principal point y.
    pub cy: f64,
}

/// A point in the reference camera's frame, `x = T_ref⁻¹ T p`, with its projection
/// `(u, v) = (fx x/z + cx, fy y/z + cy)` (eq. 2.1) and `1/z`: computed once per pixel and shared by
/// data association and [`photometric_at`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projected {
    /// The point, reference camera frame.
    pub x: Vector3<f64>,
    /// 1 / x.z.
    pub iz: f64,
    /// Column, pixels.
    pub u: f64,
    /// Row, pixels.
    pub v: f64,
}

impl Projected {
    /// Projects `x` (reference camera frame); `None` behind or at the camera.
    #[inline]
    pub fn new(x: Vector3<f64>, k: &Intrinsics) -> Option<Self> {
        if x.z <= 1e-6 {
            return None;
        }
        let iz = 1.0 / x.z;
        Some(Self {
            x,
            iz,
            u: k.fx * x.x * iz + k.cx,
            v: k.fy * x.y * iz + k.cy,
        })
    }
}

/// Photometric: `r = I_ref(π(T_ref⁻¹ T p)) − i` for a live point p (camera frame) of intensity i,
/// against a reference image taken at `T_ref` (thesis eq. 3.14). Returns r and
/// ∂r/∂δ = ∇I · ∂π/∂x · R_ref⁻¹ R [−\[p\]×, I], or `None` when p projects behind the reference
/// camera or outside its valid image.
#[inline]
pub fn photometric<F: IntensityField + ?Sized>(
    t: &RigidMotion,
    t_ref_inv: &RigidMotion,
    k: &Intrinsics,
    field: &F,
    p: &Vector3<f64>,
    intensity: f64,
) -> Option<(f64, [f64; 6])> {
    let x = Projected::new(t_ref_inv.apply(&t.apply(p)), k)?;
    photometric_at(&x, &(t.rt * t_ref_inv.rt), k, field, p, intensity)
}

/// [`photometric`] from the already projected point `x` and `R_relᵀ = Rᵀ R_ref` (the transpose of
/// the live-to-reference rotation), for callers that project once per pixel.
#[inline]
pub fn photometric_at<F: IntensityField + ?Sized>(
    x: &Projected,
    rel_rt: &Matrix3<f64>,
    k: &Intrinsics,
    field: &F,
    p: &Vector3<f64>,
    intensity: f64,
) -> Option<(f64, [f64; 6])> {
    let (value, [gu, gv]) = field.sample(x.u, x.v)?;
    let iz = x.iz;
    // ∇I · ∂π/∂x
    let a = Vector3::new(
        gu * k.fx * iz,
        gv * k.fy * iz,
        -(gu * k.fx * x.x.x + gv * k.fy * x.x.y) * iz * iz,
    );
    // ∂x/∂δ = R_rel [−[p]×, I] with R_rel = R_ref⁻¹ R; aᵀ R_rel [−[p]×, I] = [(p × b)ᵀ, bᵀ], b = R_relᵀ a
    let b = rel_rt * a;
    let w = p.cross(&b);
    Some((value - intensity, [w.x, w.y, w.z, b.x, b.y, b.z]))
}

/// [`photometric`] as a residual on one SE(3) variable.
pub struct Photometric<'a> {
    /// Live point, camera frame.
    pub point: Vector3<f64>,
    /// Live intensity.
    pub intensity: f64,
    /// Inverse of the reference camera's pose.
    pub t_ref_inv: Isometry3<f64>,
    /// Reference intrinsics.
    pub intrinsics: Intrinsics,
    /// Reference intensities.
    pub field: &'a dyn IntensityField,
}

impl Residual for Photometric<'_> {
    fn dim(&self) -> usize {
        1
    }
    fn arity(&self) -> Option<usize> {
        Some(1)
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
        let t = RigidMotion::new(&se3::from_slice(vars[0].value));
        let term = photometric(
            &t,
            &RigidMotion::new(&self.t_ref_inv),
            &self.intrinsics,
            self.field,
            &self.point,
            self.intensity,
        );
        write_scalar(term, residual, jacobians);
    }
}

/// Writes a scalar term on one SE(3) variable into a [`Residual`]'s outputs: NaN and a zero
/// Jacobian where the term is undefined (`None`).
fn write_scalar(
    term: Option<(f64, [f64; 6])>,
    residual: &mut [f64],
    jacobians: Option<&mut Jacobians<'_>>,
) {
    let (r, j) = term.unwrap_or((f64::NAN, [0.0; 6]));
    crate::write_scaled(1.0, &[r], &[j], residual, jacobians);
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynamap_solver::{check_jacobians, Manifold, SE3};
    use nalgebra::Vector6;
    use proptest::prelude::*;

    /// A smooth analytic image: I = sin(0.05 u) + cos(0.07 v) + 0.001 u v.
    struct Waves;
    impl IntensityField for Waves {
        fn sample(&self, u: f64, v: f64) -> Option<(f64, [f64; 2])> {
            Some((
                (0.05 * u).sin() + (0.07 * v).cos() + 0.001 * u * v,
                [
                    0.05 * (0.05 * u).cos() + 0.001 * v,
                    -0.07 * (0.07 * v).sin() + 0.001 * u,
                ],
            ))
        }
    }

    fn pose(a: &[f64]) -> Isometry3<f64> {
        se3::exp(&Vector6::new(
            a[0] * 0.3,
            a[1] * 0.3,
            a[2] * 0.3,
            a[3] * 0.2,
            a[4] * 0.2,
            a[5] * 0.2,
        ))
    }

    proptest! {
        #[test]
        fn point_to_plane_jacobian(a in prop::collection::vec(-1.0f64..1.0, 15)) {
            let t = pose(&a);
            let mut x = [0.0; 7];
            se3::to_slice(&t, &mut x);
            let r = PointToPlane {
                source: Vector3::new(a[6], a[7], 2.0 + a[8]),
                target: Vector3::new(a[9], a[10], a[11]),
                normal: Vector3::new(a[12], a[13], a[14] + 2.0).normalize(),
            };
            let c = check_jacobians(&r, &[Var { value: &x, manifold: &SE3 as &dyn Manifold }]);
            prop_assert!(c.passes(1e-7), "{c:?}");
        }

        #[test]
        fn photometric_jacobian(a in prop::collection::vec(-1.0f64..1.0, 15)) {
            let t = pose(&a);
            let t_ref = pose(&a[6..12]);
            let mut x = [0.0; 7];
            se3::to_slice(&t, &mut x);
            let r = Photometric {
                point: Vector3::new(a[12] * 0.5, a[13] * 0.5, 2.0 + a[14] * 0.3),
                intensity: 0.3,
                t_ref_inv: t_ref.inverse(),
                intrinsics: Intrinsics { fx: 525.0, fy: -480.0, cx: 319.5, cy: 239.5 },
                field: &Waves,
            };
            let c = check_jacobians(&r, &[Var { value: &x, manifold: &SE3 as &dyn Manifold }]);
            prop_assert!(c.passes(1e-6), "{c:?}");
        }
    }
}
