//! What the recent frames looked like, to tell a frame that does not fit them: the inlier
//! fraction, the agreement with the model ([`super::TrackOutcome::agreement`], the share of the
//! points landing on the model that agree with it) and the correlation of the texture with the
//! model's over those points ([`super::TrackOutcome::correlation`]) of the last fused frames,
//! and the intervals between their stamps.
//!
//! A track that converges at a wrong pose after a jump of the camera still finds the large
//! planes, so it passes the tracker's absolute tests; what gives it away is an inlier fraction
//! below the recent frames' (on a there-and-back orbit with a 75 cm jump: 0.34–0.38 at the wrong
//! poses against 0.48 before). The fraction also falls where the camera sees what the model has
//! not (after a stretch that was not fused: 0.35 at the right pose against 0.45 before the
//! break), while the agreement stays (0.57 against 0.55); so a pose that sparse features support
//! is held to the agreement only ([`super::relocalise`]). Both numbers are geometry's: beside a
//! wall and the floor a view slid 0.64 m along the wall kept a fraction of 0.97 and an agreement
//! of 0.97, and only the texture gave it away (correlation 0.27 against 0.99 before the gap). A
//! gap in the stamps says the same before any tracking: the prediction is not to be trusted.

use std::collections::VecDeque;

/// Fused frames remembered.
const WINDOW: usize = 15;
/// Fewer remembered frames and there is no expectation.
const MIN_FRAMES: usize = 5;

/// A floor on the correlation at least this high makes it a test of its own
/// ([`Fit::telling`]); below it the texture is too weak or too noisy to tell poses apart.
const TELLING_CORRELATION: f64 = 0.5;

/// How well a tracked frame fits the model.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Fit {
    /// Inliers over valid pixels.
    pub fraction: f64,
    /// Of the points landing on the model, the share that agree with it.
    pub agreement: f64,
    /// … and the share near it, whatever the normals' angle
    /// ([`super::TrackOutcome::proximity`]).
    pub proximity: f64,
    /// Over those points, the correlation of the live intensities with the model's (0 without
    /// colour; [`super::TrackOutcome::correlation`]).
    pub correlation: f64,
}

impl Fit {
    /// Each scaled by `r`.
    pub fn scaled(self, r: f64) -> Self {
        Self {
            fraction: r * self.fraction,
            agreement: r * self.agreement,
            proximity: r * self.proximity,
            correlation: r * self.correlation,
        }
    }

    /// Whether the correlation can tell a right pose from a wrong one: at least
    /// [`TELLING_CORRELATION`] (the recent frames' texture matched the model well).
    pub fn telling(&self) -> bool {
        self.correlation >= TELLING_CORRELATION
    }
}

/// The recent frames' fits and stamp intervals.
#[derive(Clone, Debug, Default)]
pub(crate) struct Health {
    fractions: VecDeque<f64>,
    agreements: VecDeque<f64>,
    proximities: VecDeque<f64>,
    correlations: VecDeque<f64>,
    intervals: VecDeque<f64>,
    last_stamp: Option<f64>,
    anchor: Option<Fit>,
}

impl Health {
    /// Records a fused frame taken at `stamp` with its fit (`None` for the first frame, which
    /// was not tracked).
    pub fn push(&mut self, stamp: f64, fit: Option<Fit>) {
        if let Some(f) = fit {
            push_bounded(&mut self.fractions, f.fraction);
            push_bounded(&mut self.agreements, f.agreement);
            push_bounded(&mut self.proximities, f.proximity);
            push_bounded(&mut self.correlations, f.correlation);
        }
        if let Some(last) = self.last_stamp.filter(|&l| stamp > l) {
            push_bounded(&mut self.intervals, stamp - last);
        }
        self.last_stamp = Some(stamp);
    }

    /// Starts the fits again from a relocalised frame's (the recent frames saw another view):
    /// until a few frames are fused, that one is the expectation.
    pub(crate) fn restart(&mut self, fit: Fit) {
        self.forget_fits();
        self.anchor = Some(fit);
    }

    /// Forgets the fits (a new map fragment starts with no model to fit), keeping the stamps.
    pub(crate) fn forget_fits(&mut self) {
        self.fractions.clear();
        self.agreements.clear();
        self.proximities.clear();
        self.correlations.clear();
        self.anchor = None;
    }

    /// The median fit of the recent fused frames once there are a few; before, the relocalised
    /// frame's, if any.
    pub fn expected(&self) -> Option<Fit> {
        let medians = (
            median(&self.fractions),
            median(&self.agreements),
            median(&self.proximities),
            median(&self.correlations),
        );
        match medians {
            (Some(fraction), Some(agreement), Some(proximity), Some(correlation)) => Some(Fit {
                fraction,
                agreement,
                proximity,
                correlation,
            }),
            _ => self.anchor,
        }
    }

    /// The stamp of the last fused frame.
    pub(crate) fn last_stamp(&self) -> Option<f64> {
        self.last_stamp
    }

    /// Whether more than `factor` typical frame intervals passed since the last fused frame
    /// (frames dropped from the stream, or a stretch that could not be tracked).
    pub(crate) fn is_gap(&self, stamp: f64, factor: f64) -> bool {
        match (self.last_stamp, median(&self.intervals)) {
            (Some(last), Some(interval)) => stamp - last > factor * interval,
            _ => false,
        }
    }
}

fn push_bounded(q: &mut VecDeque<f64>, x: f64) {
    if q.len() == WINDOW {
        q.pop_front();
    }
    q.push_back(x);
}

fn median(q: &VecDeque<f64>) -> Option<f64> {
    if q.len() < MIN_FRAMES {
        return None;
    }
    // at most WINDOW values: sorted on the stack
    let mut v = [0.0; WINDOW];
    let v = &mut v[..q.len()];
    for (slot, x) in v.iter_mut().zip(q) {
        *slot = *x;
    }
    let mid = v.len() / 2;
    Some(*v.select_nth_unstable_by(mid, f64::total_cmp).1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fit(x: f64) -> Fit {
        Fit {
            fraction: x,
            agreement: x + 0.2,
            proximity: x + 0.3,
            correlation: x + 0.4,
        }
    }

    #[test]
    fn the_expectation_is_the_recent_median_and_a_gap_is_measured_in_intervals() {
        let mut h = Health::default();
        h.push(0.0, None);
        for k in 1..4 {
            h.push(k as f64 / 30.0, Some(fit(0.5)));
        }
        assert_eq!(h.expected(), None, "too few frames");
        assert!(
            !h.is_gap(10.0, 3.0),
            "no gap before the intervals are known"
        );
        for k in 4..40 {
            h.push(
                k as f64 / 30.0,
                Some(fit(if k % 7 == 0 { 0.1 } else { 0.45 })),
            );
        }
        assert_eq!(h.expected(), Some(fit(0.45)));
        let last = 39.0 / 30.0;
        assert!(!h.is_gap(last + 2.0 / 30.0, 3.0));
        assert!(h.is_gap(last + 0.5, 3.0));
        h.restart(fit(0.3));
        assert_eq!(h.expected(), Some(fit(0.3)), "the relocalised frame's");
        for k in 40..45 {
            h.push(k as f64 / 30.0, Some(fit(0.35)));
        }
        assert_eq!(h.expected(), Some(fit(0.35)), "the new frames'");
    }
}
