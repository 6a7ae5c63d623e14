//! Constant-velocity extrapolation of the camera from its last two tracked poses: where to start
//! tracking the next frame, and where the camera was when a frame's colour was exposed.
//!
//! With T₁, T₂ the poses at times s₁ < s₂ and Δ = T₁⁻¹ T₂ their relative motion, the pose a time
//! τ after s₂ is T₂ Δ^(τ / (s₂ − s₁)): the rotation's angle scaled along its axis (slerp), the
//! translation scaled linearly.

use nalgebra::Isometry3;

/// The last two tracked (time, pose) pairs, and the fastest motion between two tracked frames.
#[derive(Clone, Debug, Default)]
pub(crate) struct MotionModel {
    last: Option<(f64, Isometry3<f64>)>,
    before: Option<(f64, Isometry3<f64>)>,
    fastest: (f64, f64),
}

impl MotionModel {
    /// Records a tracked frame.
    pub(crate) fn push(&mut self, time: f64, pose: Isometry3<f64>) {
        self.before = self.last.replace((time, pose));
        if let (Some((s1, t1)), Some((s2, t2))) = (self.before, self.last) {
            let span = s2 - s1;
            if span > 0.0 && span.is_finite() {
                let d = t1.inverse() * t2;
                let (v, w) = &mut self.fastest;
                *v = v.max(d.translation.vector.norm() / span);
                *w = w.max(d.rotation.angle() / span);
            }
        }
    }

    /// The fastest translation (metres per unit of time) and rotation (radians per unit) between
    /// two consecutive tracked frames so far, [`Self::reset`] or not.
    pub(crate) fn fastest(&self) -> (f64, f64) {
        self.fastest
    }

    /// Forgets the motion (after a frame that was not tracked: what came before says nothing
    /// reliable about what follows).
    pub fn reset(&mut self) {
        self.last = None;
        self.before = None;
    }

    /// The camera's motion over `tau` seconds after the last tracked frame, as T(s₂)⁻¹ T(s₂ + τ);
    /// `None` without two tracked frames a positive time apart.
    pub(crate) fn step(&self, tau: f64) -> Option<Isometry3<f64>> {
        let ((s1, t1), (s2, t2)) = (self.before?, self.last?);
        let span = s2 - s1;
        if span.is_nan() || span <= 0.0 || !tau.is_finite() {
            return None;
        }
        let a = tau / span;
        let rel = t1.inverse() * t2;
        Some(Isometry3::from_parts(
            (rel.translation.vector * a).into(),
            rel.rotation.powf(a),
        ))
    }

    /// The time of the last tracked frame.
    pub(crate) fn last_time(&self) -> Option<f64> {
        self.last.map(|l| l.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn a_steady_motion_is_extrapolated_exactly() {
        // the same motion in the camera's frame every second
        let delta = Isometry3::new(Vector3::new(0.1, 0.0, 0.02), Vector3::y() * 0.05);
        let mut m = MotionModel::default();
        assert!(m.step(1.0).is_none());
        m.push(0.0, Isometry3::identity());
        assert!(m.step(1.0).is_none());
        m.push(1.0, delta);
        let predicted = delta * m.step(1.0).unwrap();
        let truth = delta * delta;
        assert!(predicted.rotation.angle_to(&truth.rotation) < 1e-12);
        assert!((predicted.translation.vector - truth.translation.vector).norm() < 1e-12);
        let half = m.step(0.5).unwrap();
        assert!((half.rotation.angle() - 0.025).abs() < 1e-12);
        assert!((half.translation.vector - delta.translation.vector * 0.5).norm() < 1e-12);
        m.reset();
        assert!(m.step(1.0).is_none());
    }
}
