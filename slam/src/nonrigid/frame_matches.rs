//! The feature matches of a frame pair as the warp's correspondences (NOTES 95): the rigid fit's
//! inliers grown by local agreement, tied to the source's points, the warp fitted to them before
//! the depth is looked at, and held through the dense optimisation.
//!
//! RANSAC keeps the matches one rigid motion explains; on a deforming object those are one part
//! of it (on a cylinder twisted end against end, the middle's, 76–103 of about 190 matches), and
//! the dense terms cannot carry the rest, whose partners lie beyond their kernel. Grown region by
//! region, each match judged by the motion of the accepted matches around it, the set covers the
//! object; fitted first (point to point, a kernel as wide as the matches are far), the warp starts
//! near every match instead of near the rigid start.

use super::graph::{Binding, DeformationGraph};
use super::register::{
    RegisterError, RegisterParams, RegisterSummary, Seeds, Target, WarpOptimiser,
};
use crate::camera::Camera;
use crate::eval::umeyama;
use crate::features::FrameMatches;
use crate::image::{valid, NormalMap};
use nalgebra::{Isometry3, Point3, Vector3};

/// A pair of matched points: source (its camera's frame) and target (its camera's frame).
pub type MatchPair = (Vector3<f64>, Vector3<f64>);

/// Grows `inliers` by `candidates` that agree locally: a candidate joins when the rigid motion
/// fitted (Umeyama) to the accepted matches within `radius` of its source point, at least three,
/// carries that point within `tolerance` of its partner; repeated until none joins. Returns the
/// candidates that joined, in the order they did.
pub fn grow_matches(
    inliers: &[MatchPair],
    candidates: &[MatchPair],
    radius: f64,
    tolerance: f64,
) -> Vec<MatchPair> {
    let mut accepted = inliers.to_vec();
    let mut left = candidates.to_vec();
    let first = accepted.len();
    let mut near = (Vec::new(), Vec::new());
    loop {
        let before = accepted.len();
        let mut k = 0;
        while k < left.len() {
            if agrees(&accepted, &left[k], (radius, tolerance), &mut near) {
                accepted.push(left.swap_remove(k));
            } else {
                k += 1;
            }
        }
        if accepted.len() == before {
            return accepted.split_off(first);
        }
    }
}

/// Whether the rigid motion of the accepted matches within `radius` of `m`'s source point (at
/// least three) carries it within `tolerance` of its partner; `near` holds those matches' two
/// sides (buffers reused across calls).
fn agrees(
    accepted: &[MatchPair],
    m: &MatchPair,
    (radius, tolerance): (f64, f64),
    near: &mut (Vec<Point3<f64>>, Vec<Point3<f64>>),
) -> bool {
    let (a, b) = near;
    a.clear();
    b.clear();
    for (s, t) in accepted.iter().filter(|(s, _)| (s - m.0).norm() <= radius) {
        a.push(Point3::from(*s));
        b.push(Point3::from(*t));
    }
    if a.len() < 3 {
        return false;
    }
    umeyama(a, b, false)
        .is_some_and(|f| (f.isometry * Point3::from(m.0) - Point3::from(m.1)).norm() <= tolerance)
}

/// A feature match tied to the source's points: the point's index, its partner in the target
/// and the target's normal there.
#[derive(Clone, Copy, Debug)]
pub(super) struct TiedMatch {
    point: usize,
    target: Vector3<f64>,
    normal: Vector3<f64>,
}

/// The frames' cameras, the target's normals and the source points' pixels: what ties a match
/// to a source point and a target normal.
pub(super) struct MatchFrames<'a> {
    pub(super) source: &'a Camera,
    pub(super) target: &'a Camera,
    pub(super) target_normals: &'a NormalMap,
    /// The pixel (row-major index) of each source point.
    pub(super) pixels: &'a [usize],
}

/// The matches RANSAC kept, grown by the ones it rejected ([`grow_matches`] over two node
/// spacings, to RANSAC's own `tolerance`), tied to the source's points.
pub(super) fn grown_and_tied(
    matches: &FrameMatches,
    frames: &MatchFrames<'_>,
    spacing: f64,
    tolerance: f64,
) -> Vec<TiedMatch> {
    let mut pairs: Vec<MatchPair> = (matches.source.iter().copied())
        .zip(matches.target.iter().copied())
        .collect();
    let grown = grow_matches(&pairs, &matches.rejected, 2.0 * spacing, tolerance);
    pairs.extend(grown);
    tie_matches(&pairs, frames)
}

/// Ties each pair to the source point at its pixel and the target's normal at its partner's;
/// pairs without either are left out.
fn tie_matches(pairs: &[MatchPair], frames: &MatchFrames<'_>) -> Vec<TiedMatch> {
    let w = frames.source.width;
    let mut point_of = vec![u32::MAX; w * frames.source.height];
    for (k, &i) in frames.pixels.iter().enumerate() {
        point_of[i] = k as u32;
    }
    let pixel = |camera: &Camera, p: &Vector3<f64>| camera.project_to_pixel(&Point3::from(*p));
    pairs
        .iter()
        .filter_map(|(s, t)| {
            let (u, v) = pixel(frames.source, s)?;
            let (tu, tv) = pixel(frames.target, t)?;
            let n = frames.target_normals.data[tv * frames.target.width + tu];
            let k = point_of[v * w + u];
            (k != u32::MAX && valid(&n)).then(|| TiedMatch {
                point: k as usize,
                target: *t,
                normal: Vector3::new(n[0] as f64, n[1] as f64, n[2] as f64),
            })
        })
        .collect()
}

/// The matches as correspondences held through every stage ([`Seeds::pinned`]): each match's
/// source point joins `data` (if it is not in it) and is pinned to its partner. Depth constrains
/// a smooth surface only along its normal; the matches hold it along itself. `None` without
/// matches.
pub(super) fn held_seeds(
    held: &[TiedMatch],
    normals: &[Vector3<f64>],
    data: &mut Vec<usize>,
) -> Option<Seeds> {
    if held.is_empty() {
        return None;
    }
    let mut data_of = vec![u32::MAX; normals.len()];
    for (j, &k) in data.iter().enumerate() {
        data_of[k] = j as u32;
    }
    let mut pinned = Vec::with_capacity(held.len());
    for m in held {
        if data_of[m.point] == u32::MAX {
            data_of[m.point] = data.len() as u32;
            data.push(m.point);
        }
        pinned.push(data_of[m.point]);
    }
    let mut matches: Vec<(Vector3<f64>, Vector3<f64>)> = data
        .iter()
        .map(|&k| (Vector3::zeros(), normals[k]))
        .collect();
    for (m, &j) in held.iter().zip(&pinned) {
        matches[j as usize] = (m.target, m.normal);
    }
    Some(Seeds {
        matches,
        stages: 0,
        tukey_scale: 1.0,
        // no stage is seeded: the pinned matches are weighed as the frames' own matches
        point_weight: 0.0,
        replace_all: false,
        iterations: 0,
        pinned,
    })
}

/// The source's points, their normals and their bindings to the graph.
pub(super) struct Bound<'a> {
    pub(super) points: &'a [Vector3<f64>],
    pub(super) normals: &'a [Vector3<f64>],
    pub(super) bindings: &'a [Binding],
}

/// A target that offers no partner: only the pinned matches act.
struct MatchesOnly;

impl Target for MatchesOnly {
    fn associate(&self, _: &Vector3<f64>) -> Option<(Vector3<f64>, Vector3<f64>)> {
        None
    }
}

/// Fits the warp to the matches alone from the rigid motion `start`: the matched points pinned to
/// their partners point to point, under Tukey's c twice the farthest partner from the start (so
/// that none is rejected; the matches were verified), the regulariser's schedule as `params`', no
/// stay prior. What the optimiser did; `None` (and the graph untouched) without matches.
pub(super) fn fit_to_matches(
    graph: &mut DeformationGraph,
    held: &[TiedMatch],
    bound: &Bound<'_>,
    params: &RegisterParams,
    start: &Isometry3<f64>,
) -> Result<Option<RegisterSummary>, RegisterError> {
    let mut data = Vec::new();
    let Some(seeds) = held_seeds(held, bound.normals, &mut data) else {
        return Ok(None);
    };
    let farthest = held
        .iter()
        .map(|m| (start * Point3::from(bound.points[m.point]) - Point3::from(m.target)).norm())
        .fold(0.0, f64::max);
    let fit = RegisterParams {
        rigid_iterations: 0,
        point_weight: 1.0,
        tukey: (2.0 * farthest).max(params.max_distance),
        stay_weight: 0.0,
        ..params.clone()
    };
    let pick = |v: &[Vector3<f64>]| -> Vec<Vector3<f64>> { data.iter().map(|&k| v[k]).collect() };
    let bindings: Vec<Binding> = data.iter().map(|&k| bound.bindings[k]).collect();
    let summary = WarpOptimiser::new(fit).optimise_from(
        graph,
        &pick(bound.points),
        &pick(bound.normals),
        &bindings,
        &MatchesOnly,
        &[*start],
        Some(&seeds),
    )?;
    Ok(Some(summary))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    /// Points along a 1 m bar bent by 60° end to end (each point turned about z by 60° × its
    /// position along the bar), the middle fifth given as inliers: every other point joins by
    /// its neighbours' motion, none of five matches sent 20 cm astray does.
    #[test]
    fn matches_grow_along_a_bend_and_strays_stay_out() {
        let bend = |x: f64| {
            let turn = UnitQuaternion::from_scaled_axis(Vector3::z() * (x * 60f64.to_radians()));
            turn * Vector3::new(x, 0.0, 1.0) + Vector3::new(0.05, 0.0, 0.0)
        };
        let pairs: Vec<MatchPair> = (0..101)
            .map(|i| {
                let x = (i as f64 - 50.0) / 100.0;
                let s = Vector3::new(x, 0.01 * (i % 3) as f64, 1.0 + 0.01 * (i % 2) as f64);
                (s, bend(x) + (s - Vector3::new(x, 0.0, 1.0)))
            })
            .collect();
        let (inliers, rest): (Vec<_>, Vec<_>) = pairs.iter().partition(|(s, _)| s.x.abs() <= 0.1);
        let mut candidates = rest.clone();
        for k in 0..5 {
            let (s, t) = candidates[k * 15];
            candidates.push((s, t + Vector3::new(0.0, 0.2, 0.0)));
        }
        let grown = grow_matches(&inliers, &candidates, 0.1, 0.03);
        assert_eq!(grown.len(), rest.len(), "{} of {}", grown.len(), rest.len());
        assert!(grown.iter().all(|g| rest.contains(g)));
    }
}
