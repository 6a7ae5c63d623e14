//! How far the tracked motion between two keyframes may be off along motions the geometry
//! barely fixed, for the odometry edge of the keyframe graph ([`super::loops`]).
//!
//! Each tracked frame k comes with its pose's covariance Σ_k from the point-to-plane term
//! ([`super::tracker::TrackOutcome::covariance`]): small where the scene's shape pins the
//! camera, large along a plain wall the camera slides over. Frame-to-model tracking does not
//! add up independent errors frame after frame: where a motion is weakly fixed, the model
//! follows the camera, and the frames' errors along it persist and add up like a bias. The spread
//! therefore adds the frames' deviations, not their variances:
//!
//!   L = Σ_k Ad(T_k) Σ_k^{1/2},   Σ_spread = Ad(T_b⁻¹) L Lᵀ Ad(T_b⁻¹)ᵀ,
//!
//! with the frames' right perturbations T_k·Exp(δ) carried to the world by the adjoint and back
//! to keyframe b's, in which the graph's between residual Log(Z⁻¹ X_a⁻¹ X_b) is expressed. Where
//! the geometry pins every motion the spread is far below the graph's drift model and changes
//! nothing; along a slide it lets a loop move the keyframes the slide displaced.

use dynamap_solver::lie::se3;
use nalgebra::{Isometry3, Matrix6};

/// The frames' deviations summed since the last keyframe.
#[derive(Clone, Debug)]
pub(crate) struct OdometrySpread {
    /// Σ_k Ad(T_k) Σ_k^{1/2}.
    sum: Matrix6<f64>,
    /// Frames added since the last keyframe.
    frames: usize,
}

impl Default for OdometrySpread {
    fn default() -> Self {
        Self {
            sum: Matrix6::zeros(),
            frames: 0,
        }
    }
}

impl OdometrySpread {
    /// Adds a frame tracked at `pose` with this covariance of its right perturbation; a
    /// covariance that is not symmetric positive semi-definite and finite is left out.
    pub(crate) fn push(&mut self, pose: &Isometry3<f64>, covariance: &Matrix6<f64>) {
        if let Some(root) = square_root(covariance) {
            self.sum += se3::adjoint(pose) * root;
            self.frames += 1;
        }
    }

    /// The spread's covariance in the tangent of the keyframe at `pose` (`[ω; v]`), and a fresh
    /// start for the next span; `None` when no frame was added.
    pub(crate) fn take(&mut self, pose: &Isometry3<f64>) -> Option<Matrix6<f64>> {
        let taken = std::mem::take(self);
        if taken.frames == 0 {
            return None;
        }
        let local = se3::adjoint(&pose.inverse()) * taken.sum;
        Some(local * local.transpose())
    }
}

/// The symmetric square root of a symmetric positive semi-definite matrix (negative
/// eigenvalues from rounding clamped to 0); `None` when it is not finite.
fn square_root(c: &Matrix6<f64>) -> Option<Matrix6<f64>> {
    if !c.iter().all(|v| v.is_finite()) {
        return None;
    }
    let eig = c.symmetric_eigen();
    let roots = eig.eigenvalues.map(|l| l.max(0.0).sqrt());
    Some(eig.eigenvectors * Matrix6::from_diagonal(&roots) * eig.eigenvectors.transpose())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Vector3, Vector6};

    fn slide_covariance(deviation: f64) -> Matrix6<f64> {
        // tight everywhere except the camera's x translation
        let mut d = Vector6::repeat(1e-10);
        d[3] = deviation * deviation;
        Matrix6::from_diagonal(&d)
    }

    #[test]
    fn deviations_add_up_along_a_slide_and_follow_the_keyframe() {
        let mut s = OdometrySpread::default();
        assert!(s.take(&Isometry3::identity()).is_none());
        let turned = Isometry3::new(Vector3::new(0.3, -0.2, 1.0), Vector3::y() * 0.4);
        for _ in 0..10 {
            s.push(&turned, &slide_covariance(0.002));
        }
        // ten frames of 2 mm each, fully correlated: 2 cm, not 2 mm · √10
        let at_frame = s.clone().take(&turned).unwrap();
        assert!((at_frame[(3, 3)].sqrt() - 0.02).abs() < 1e-9, "{at_frame}");
        assert!(at_frame[(4, 4)] < 2e-8 && at_frame[(5, 5)] < 2e-8);
        // seen from a keyframe turned a quarter about the camera's y axis, the slide is along z
        let quarter = turned * Isometry3::rotation(Vector3::y() * std::f64::consts::FRAC_PI_2);
        let at_quarter = s.take(&quarter).unwrap();
        assert!(
            (at_quarter[(5, 5)].sqrt() - 0.02).abs() < 1e-6,
            "{at_quarter}"
        );
        assert!(at_quarter[(3, 3)] < 2e-8);
        // the next span starts empty
        assert!(s.take(&quarter).is_none());
    }

    #[test]
    fn a_covariance_that_is_not_finite_is_left_out() {
        let mut s = OdometrySpread::default();
        let mut c = slide_covariance(0.01);
        c[(0, 0)] = f64::NAN;
        s.push(&Isometry3::identity(), &c);
        assert!(s.take(&Isometry3::identity()).is_none());
    }
}
