//! The dense loop search of a new keyframe, run off the tracking thread (issue 24: tracking never
//! waits for the back end).
//!
//! When a keyframe is taken with the map split into sub-maps, the pipeline captures what its
//! search reads in a [`LoopQuery`]: the live pyramid and colour, the candidate keyframes with
//! their frozen sub-maps (shared: nothing writes a frozen volume again), every keyframe's
//! tracked pose, the recent frames' fit and the tracker's learned state. A worker thread with a
//! pool of its own runs [`search`] on each query in turn, and the pipeline adds the loops found
//! to its keyframe graph in the order the keyframes were taken ([`LoopSearch::finished`]). The
//! search reads nothing that changes after its keyframe, so it finds what it would have found
//! on the tracking thread; only the frame at which its loop reaches the graph moves.
//!
//! The search (ElasticFusion's local loops, Whelan et al., RSS 2015, checked as NOTES 94 and
//! 116 describe): each candidate's sub-map is raycast at the candidate's pose and the live frame
//! tracked against it. A track must pass the tracker's tests and the relocaliser's floor on the
//! inlier fraction; one that agrees with the track ([`loop_candidates::agrees_with_track`])
//! needs nothing more and wins over one that does not, which must also reach the floors of the
//! recent frames' fit. The better fit decides between equals. A loop to another map fragment,
//! which nothing else places, also needs the sparse features to agree with it
//! ([`features_agree`]) or, where the recent frames' correlation floor is telling, a correlation
//! reaching it. A loop of the current fragment is tracked again from the new keyframe's tracked
//! pose and kept only if both tracks end in one place ([`loop_candidates::settled_alike`]).

use super::health::Fit;
use super::keyframes::Keyframe;
use super::loop_candidates;
use super::loops::{median_z, LoopCandidate};
use super::relocalise::{LiveFrame, RelocaliseParams, Verifier};
use super::tracker::{ModelPyramid, TrackOutcome, Tracker};
use crate::camera::Camera;
use crate::features::fit_keypoints;
use crate::image::ColorImage;
use crate::preprocess::Level;
use crate::tsdf::TsdfVolume;
use nalgebra::Isometry3;
use std::sync::{mpsc, Arc};

/// Searches waiting or under way at most: a keyframe taken while this many are pending first
/// waits for the oldest (each query holds a copy of the live pyramid).
pub(super) const MAX_PENDING: usize = 2;

/// An older keyframe a loop is tried against.
pub(super) struct LoopTarget {
    /// Its index among the keyframes.
    pub index: usize,
    /// Its frame.
    pub frame: usize,
    /// Its tracked pose.
    pub pose: Isometry3<f64>,
    /// The frozen sub-map that fused it.
    pub map: Arc<TsdfVolume>,
    /// The keyframe itself when it lies in an older map fragment, whose loops need its
    /// features to agree.
    pub keyframe: Option<Keyframe>,
}

/// What the search of one new keyframe reads, captured when the keyframe is taken.
pub(super) struct LoopQuery {
    /// The new keyframe (the live frame): its frame and tracked pose.
    pub frame: usize,
    /// Its tracked pose.
    pub pose: Isometry3<f64>,
    /// The first frame of the current map fragment.
    pub since: usize,
    /// The scene's median depth in the live frame, metres.
    pub depth: f64,
    /// The recent frames' fit scaled by the relocaliser's ratio.
    pub floor: Fit,
    /// The older keyframes to try, in the order they are tried.
    pub targets: Vec<LoopTarget>,
    /// Every keyframe's tracked pose, oldest first, the new one last.
    pub poses: Vec<Isometry3<f64>>,
    /// The new keyframe.
    pub newest: Keyframe,
    /// The live pyramid.
    pub levels: Vec<Level>,
    /// The live colour, if any.
    pub color: Option<ColorImage>,
    /// The sensor.
    pub camera: Camera,
    /// A model pyramid of the pipeline's shape.
    pub model_template: ModelPyramid,
    /// The pipeline's tracker as it was (its learned scales and vignetting).
    pub tracker: Tracker,
    /// The relocaliser's settings (floors, features, loops).
    pub params: RelocaliseParams,
}

/// The loop from the query's keyframe to one of its targets, if one passes every test (see the
/// module's documentation); `verifier` holds the raycast buffers.
pub(super) fn search(q: &mut LoopQuery, verifier: &mut Verifier) -> Option<LoopCandidate> {
    let p = &q.params;
    let live = LiveFrame {
        levels: &q.levels,
        color: q.color.as_ref(),
        camera: &q.camera,
        model_template: &q.model_template,
    };
    let mut best: Option<((bool, f64), LoopCandidate)> = None;
    for t in &q.targets {
        let o = verifier.verify(&mut q.tracker, &t.map, &live, &t.pose);
        let fraction = o.inlier_fraction();
        let same_fragment = t.frame >= q.since;
        let agrees = same_fragment
            && loop_candidates::agrees_with_track(
                &q.poses, t.index, &q.pose, &o.pose, &p.loops, q.depth,
            );
        // a loop the track corroborates needs only the relocaliser's own floor; one it does
        // not must also fit nearly as well as the recent frames
        let floor = &q.floor;
        let fits = fraction >= p.min_inlier_fraction
            && (agrees || (fraction >= floor.fraction && o.agreement >= floor.agreement));
        log_candidate((t.frame, q.frame), &o, fits, agrees);
        let rank = (agrees, fraction);
        if o.failure.is_some() || !fits || best.as_ref().is_some_and(|b| b.0 >= rank) {
            continue;
        }
        // nothing but this loop places another map fragment: the features must agree, or the
        // texture must match as the recent frames' did where that floor can tell (NOTES 94)
        let textured = floor.telling() && o.correlation >= floor.correlation;
        let placed_by_features = || {
            t.keyframe
                .as_ref()
                .is_some_and(|old| features_agree(p, old, &q.newest, &o.pose))
        };
        if !same_fragment && !textured && !placed_by_features() {
            continue;
        }
        // the same fragment's track gives a second start: a registration that ends elsewhere
        // from it depends on where it started (a slide along a corridor)
        if same_fragment {
            let again = verifier.verify(&mut q.tracker, &t.map, &live, &q.pose);
            let alike = loop_candidates::settled_alike(&o.pose, &again.pose, &p.loops, q.depth);
            if again.failure.is_some() || !alike {
                tracing::debug!(from = t.frame, to = q.frame, "loop depends on its start");
                continue;
            }
        }
        let found = LoopCandidate {
            from: t.frame,
            to: q.frame,
            relative: t.pose.inverse() * o.pose,
            inliers: o.inliers,
            depth: q.depth,
        };
        best = Some((rank, found));
    }
    best.map(|(_, found)| found)
}

/// Whether the sparse features of keyframes `old` and `new` match (RANSAC finds a motion with
/// [`crate::features::FeatureParams::min_inliers`]) on a motion that puts `new` within three
/// loop deviations ([`super::loops::LoopParams::loop_deviation`] of the matches' depth) of
/// `dense`, the pose the dense loop found for it in `old`'s frame. Two independent measurements
/// agreeing is what a loop from a look-alike place rarely has: on the room's survey, none of
/// nine false loops between fragments had a feature fit at all, and the true ones agreed within
/// 2.5 cm and 0.5° (with 12–27 inliers, fewer than a feature loop needs).
fn features_agree(
    p: &RelocaliseParams,
    old: &Keyframe,
    new: &Keyframe,
    dense: &Isometry3<f64>,
) -> bool {
    let Some(m) = fit_keypoints(&new.keypoints, &old.keypoints, &p.features) else {
        return false;
    };
    let (sigma_r, sigma_t) = p.loops.loop_deviations(median_z(&m.target));
    let d = (old.pose * m.fit.motion).inverse() * dense;
    d.translation.vector.norm() <= 3.0 * sigma_t && d.rotation.angle() <= 3.0 * sigma_r
}

/// Logs one candidate's track at debug level.
fn log_candidate((from, to): (usize, usize), o: &TrackOutcome, fits: bool, agrees: bool) {
    tracing::debug!(
        from,
        to,
        fraction = o.inlier_fraction(),
        agreement = o.agreement,
        correlation = o.correlation,
        failed = o.failure.is_some(),
        fits,
        agrees,
        "dense loop candidate"
    );
}

/// The worker that runs the searches, started with the first query.
#[derive(Debug)]
struct Worker {
    queries: mpsc::Sender<Box<LoopQuery>>,
    answers: mpsc::Receiver<Option<LoopCandidate>>,
    thread: std::thread::JoinHandle<()>,
}

impl Worker {
    /// Starts the thread. Its searches run on a one-thread pool of their own, so that their
    /// parallel loops do not queue behind the tracking's on the global pool: the two threads
    /// share the cores through the operating system, the search taking what tracking leaves.
    fn start() -> Self {
        let (queries, inbox) = mpsc::channel::<Box<LoopQuery>>();
        let (outbox, answers) = mpsc::channel();
        let thread = std::thread::spawn(move || {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build();
            if let Err(why) = &pool {
                tracing::warn!(%why, "the loop search shares the global thread pool");
            }
            let mut verifier = Verifier::default();
            while let Ok(mut q) = inbox.recv() {
                let found = match &pool {
                    Ok(pool) => pool.install(|| search(&mut q, &mut verifier)),
                    Err(_) => search(&mut q, &mut verifier),
                };
                if outbox.send(found).is_err() {
                    break;
                }
            }
        });
        Self {
            queries,
            answers,
            thread,
        }
    }
}

/// Runs [`search`] on a thread of its own: [`Self::submit`] hands a query over,
/// [`Self::finished`] takes the loops found, in the order the queries were submitted.
#[derive(Debug, Default)]
pub(super) struct LoopSearch {
    worker: Option<Worker>,
    /// Queries submitted and not yet answered.
    pending: usize,
}

impl LoopSearch {
    /// Hands `query` to the worker (started on the first call).
    pub fn submit(&mut self, query: Box<LoopQuery>) {
        let worker = self.worker.get_or_insert_with(Worker::start);
        if worker.queries.send(query).is_ok() {
            self.pending += 1;
        } else {
            tracing::error!(
                "the loop search's worker has stopped: the keyframe's loop is not searched"
            );
        }
    }

    /// The loops found by the searches answered so far, oldest first, after waiting until
    /// fewer than `below` searches are pending (`usize::MAX`: no wait; 1: every search).
    pub fn finished(&mut self, below: usize) -> Vec<LoopCandidate> {
        let mut found = Vec::new();
        let Some(worker) = &self.worker else {
            return found;
        };
        while self.pending > 0 {
            let answer = if self.pending >= below {
                worker.answers.recv().ok()
            } else {
                worker.answers.try_recv().ok()
            };
            let Some(answer) = answer else {
                break;
            };
            self.pending -= 1;
            found.extend(answer);
        }
        if self.pending >= below {
            // the worker ended without answering (it panicked): nothing more will come
            tracing::error!(
                pending = self.pending,
                "the loop search's worker has stopped: keyframes left unsearched"
            );
            self.pending = 0;
        }
        found
    }
}

impl Drop for LoopSearch {
    fn drop(&mut self) {
        if let Some(Worker {
            queries, thread, ..
        }) = self.worker.take()
        {
            // closing the queue ends the worker's loop
            drop(queries);
            let _ = thread.join();
        }
    }
}
