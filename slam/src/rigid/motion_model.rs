//! Constant-velocity extrapolation of the camera from its recent tracked poses: where to start
//! tracking the next frame, and where the camera was when a frame's colour was exposed.
//!
//! With T₁, T₂ the poses at times s₁ < s₂ and Δ = T₁⁻¹ T₂ their relative motion, the pose a time
//! τ after s₂ is T₂ Δ^(τ / (s₂ − s₁)): the rotation's angle scaled along its axis (slerp), the
//! translation scaled linearly. T₂ is the last tracked pose; for the next frame's start T₁ is
//! the one before it.
//!
//! For the colour's instant T₁ lies further back. An error e in the last pose reaches the
//! colour's shift as e τ / (s₂ − s₁), and the shifted colour pulls the next pose the other
//! way, so that the loop swings: with the colour half a frame late (TUM's Kinect at 30 Hz) and
//! one frame interval between T₁ and T₂, every other frame's pose swung ±7 mm along the motion.
//! T₁ is therefore the newest pose at least [`SPAN_PER_DELAY`] τ before T₂, which feeds back at
//! most a third of an error; at 30 Hz and τ = 17 ms that is two frame intervals, at 15 Hz one.

use nalgebra::Isometry3;
use std::collections::VecDeque;

/// The colour's shift over a delay τ takes the velocity over at least this many times τ (where
/// the recent frames span it): a pose's error feeds back into the next frame's colour by at
/// most its inverse.
pub(crate) const SPAN_PER_DELAY: f64 = 3.0;

/// How far back, in the stamps' unit (seconds where frames are timed), the recent poses are
/// kept: [`SPAN_PER_DELAY`] times a colour delay of up to 80 ms.
const HISTORY: f64 = 0.25;

/// The most poses kept, whatever the stamps (a clock that stops or runs backwards keeps no
/// pose [`HISTORY`] old): 0.25 s at 60 Hz.
const MAX_RECENT: usize = 16;

/// How far two stamps may differ and still count as the same (TUM's stamps give microseconds).
const STAMP_PRECISION: f64 = 1e-6;

/// The recent tracked (time, pose) pairs, and the fastest motion between two tracked frames.
#[derive(Clone, Debug, Default)]
pub(crate) struct MotionModel {
    /// Oldest first: the first is the newest one at least [`HISTORY`] before the last, when
    /// the frames reach back that far.
    recent: VecDeque<(f64, Isometry3<f64>)>,
    fastest: (f64, f64),
    /// The velocity the last [`Self::reset`] forgot: the relative motion over the recent poses
    /// and the time it took.
    held: Option<(Isometry3<f64>, f64)>,
}

impl MotionModel {
    /// Records a tracked frame.
    pub(crate) fn push(&mut self, time: f64, pose: Isometry3<f64>) {
        if let Some(&(s1, t1)) = self.recent.back() {
            let span = time - s1;
            if span > 0.0 && span.is_finite() {
                let d = t1.inverse() * pose;
                let (v, w) = &mut self.fastest;
                *v = v.max(d.translation.vector.norm() / span);
                *w = w.max(d.rotation.angle() / span);
            }
        }
        self.recent.push_back((time, pose));
        // keep one pose at least the history before the last, and none older
        while self.recent.len() > MAX_RECENT
            || (self.recent.len() > 2 && self.recent[1].0 <= time - HISTORY)
        {
            self.recent.pop_front();
        }
    }

    /// The fastest translation (metres per unit of time) and rotation (radians per unit) between
    /// two consecutive tracked frames so far, [`Self::reset`] or not.
    pub(crate) fn fastest(&self) -> (f64, f64) {
        self.fastest
    }

    /// Forgets the motion (after a frame that was not tracked: what came before says nothing
    /// reliable about the next frame's start). The velocity is held for [`Self::coast`]: after
    /// a break it is the best guess of where the camera went.
    pub fn reset(&mut self) {
        if let Some(v) = self.velocity() {
            self.held = Some(v);
        }
        self.recent.clear();
    }

    /// The relative motion T₁⁻¹ T₂ from the oldest pose kept to the newest, and the time it
    /// took: the velocity over up to [`HISTORY`], steadier than over the last interval.
    fn velocity(&self) -> Option<(Isometry3<f64>, f64)> {
        let ((s1, t1), (s2, t2)) = (self.recent.front()?, self.recent.back()?);
        let span = s2 - s1;
        (span > 0.0 && span.is_finite()).then(|| (t1.inverse() * t2, span))
    }

    /// The camera's motion over `tau` after the last tracked frame at the velocity it had
    /// before the track broke off (or now, if it has not): Δ^(τ / span), Δ the relative motion
    /// over the recent poses. Where the stream skipped a stretch, a camera carried on a walk
    /// is about there; `None` without a velocity or a finite `tau`.
    pub(crate) fn coast(&self, tau: f64) -> Option<Isometry3<f64>> {
        let (rel, span) = self.velocity().or(self.held)?;
        extrapolate((0.0, Isometry3::identity()), (span, rel), tau)
    }

    /// The camera's motion over `tau` seconds after the last tracked frame, as T(s₂)⁻¹ T(s₂ + τ),
    /// at the velocity between the last two tracked frames; `None` without two tracked frames a
    /// positive time apart.
    pub(crate) fn step(&self, tau: f64) -> Option<Isometry3<f64>> {
        let n = self.recent.len();
        extrapolate(
            *self.recent.get(n.checked_sub(2)?)?,
            *self.recent.back()?,
            tau,
        )
    }

    /// [`Self::step`] for the colour's instant `tau` after the last tracked frame, at the
    /// velocity over at least [`SPAN_PER_DELAY`] |τ| (to the microsecond TUM's stamps give; over
    /// the oldest pose kept where the frames do not reach back that far), so that the colour's
    /// shift feeds back at most a third of a pose's error (see the module's documentation).
    pub(crate) fn colour_step(&self, tau: f64) -> Option<Isometry3<f64>> {
        let last = *self.recent.back()?;
        let reach = last.0 - SPAN_PER_DELAY * tau.abs() + STAMP_PRECISION;
        let first = self.recent.iter().rev().skip(1).find(|p| p.0 <= reach);
        extrapolate(*first.or(self.recent.front())?, last, tau)
    }

    /// The time of the last tracked frame.
    pub(crate) fn last_time(&self) -> Option<f64> {
        self.recent.back().map(|l| l.0)
    }
}

/// The motion over `tau` after (s₂, T₂) at the constant velocity from (s₁, T₁): Δ^(τ / (s₂ −
/// s₁)) with Δ = T₁⁻¹ T₂; `None` unless s₂ − s₁ is positive and τ finite.
fn extrapolate(
    (s1, t1): (f64, Isometry3<f64>),
    (s2, t2): (f64, Isometry3<f64>),
    tau: f64,
) -> Option<Isometry3<f64>> {
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

    /// The coast outlives a reset: a camera screwing along x at 0.5 m/s and 0.2 rad/s, lost,
    /// is carried 0.75 m and 0.3 rad over 1.5 s at the velocity over the recent poses; a newer
    /// track's velocity replaces it.
    #[test]
    fn a_reset_holds_the_velocity_for_the_coast() {
        let at = |t: f64| Isometry3::new(Vector3::new(0.5 * t, 0.0, 0.0), Vector3::x() * 0.2 * t);
        let mut m = MotionModel::default();
        assert!(m.coast(1.0).is_none());
        for k in 0..10 {
            m.push(k as f64 / 30.0, at(k as f64 / 30.0));
        }
        m.reset();
        assert!(m.step(1.5).is_none());
        let c = m.coast(1.5).unwrap();
        let truth = at(9.0 / 30.0).inverse() * at(9.0 / 30.0 + 1.5);
        assert!((c.translation.vector - truth.translation.vector).norm() < 1e-9);
        assert!(c.rotation.angle_to(&truth.rotation) < 1e-9);
        // a reset with fewer than two poses keeps the velocity held
        m.push(5.0, at(5.0));
        m.reset();
        assert!(m
            .coast(1.5)
            .is_some_and(|d| (d.rotation.angle() - 0.3).abs() < 1e-9));
        // a new track's velocity is the one carried
        m.push(6.0, Isometry3::identity());
        m.push(7.0, Isometry3::translation(0.0, 0.0, 0.1));
        let d = m.coast(2.0).unwrap();
        assert!((d.translation.vector - Vector3::new(0.0, 0.0, 0.2)).norm() < 1e-12);
        assert!(d.rotation.angle() < 1e-12);
    }

    #[test]
    fn the_colours_velocity_spans_three_delays_and_one_error_counts_less() {
        // 30 Hz along x at 0.45 m/s; one frame tracked 6 mm ahead; colour 17 ms late
        let dt = 1.0 / 30.0;
        let tau = 0.017;
        let at = |k: usize| Isometry3::translation(0.45 * dt * k as f64, 0.0, 0.0);
        let mut m = MotionModel::default();
        for k in 0..10 {
            m.push(k as f64 * dt, at(k));
        }
        // a steady motion is extrapolated exactly over either span
        for s in [m.step(tau).unwrap(), m.colour_step(tau).unwrap()] {
            assert!((s.translation.x - 0.45 * tau).abs() < 1e-12);
        }
        let ahead = Isometry3::translation(0.006, 0.0, 0.0) * at(10);
        m.push(10.0 * dt, ahead);
        // over one interval the error is read as 0.006 / dt = 0.18 m/s too fast; over the
        // colour's span of 3 τ = 51 ms, two intervals, half that
        let v = |s: Option<Isometry3<f64>>| s.unwrap().translation.x / tau;
        assert!((v(m.step(tau)) - (0.45 + 0.006 / dt)).abs() < 1e-9);
        assert!((v(m.colour_step(tau)) - (0.45 + 0.006 / (2.0 * dt))).abs() < 1e-9);
        // a delay that asks for more than the history kept uses the oldest pose kept
        let oldest = m.recent.front().unwrap().0;
        assert!(10.0 * dt - oldest >= HISTORY && 10.0 * dt - oldest < HISTORY + dt);
        let far = m.colour_step(0.2).unwrap().translation.x / 0.2;
        assert!((far - (0.45 + 0.006 / (10.0 * dt - oldest))).abs() < 1e-9);
        // at 15 Hz the colour's span is one interval, as the next frame's start
        let mut n = MotionModel::default();
        for k in 0..5 {
            n.push(k as f64 * 2.0 * dt, at(2 * k));
        }
        let (a, b) = (n.step(tau).unwrap(), n.colour_step(tau).unwrap());
        assert!((a.translation.x - b.translation.x).abs() < 1e-15);
        // the fastest motion is between consecutive frames
        assert!((m.fastest().0 - (0.45 + 0.006 / dt)).abs() < 1e-9);
        // a stopped clock keeps a bounded history and no velocity
        let mut stuck = MotionModel::default();
        for k in 0..100 {
            stuck.push(1.0, at(k));
        }
        assert_eq!(stuck.recent.len(), MAX_RECENT);
        assert!(stuck.step(tau).is_none() && stuck.colour_step(tau).is_none());
    }
}
