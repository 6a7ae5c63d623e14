//! A dense scene flow scored against its ground truth (DeepDeform's `.sflow` files, Božič et
//! al., CVPR 2020): EPE 3D on the object and over every pixel with a ground truth, and the score
//! of doing nothing (zero flow).

use super::{epe3d, EpeResult};
use crate::image::Image;
use nalgebra::Vector3;

/// The scores of one flow image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlowScores {
    /// On the object: inside the source mask (where there is one), over the pixels with both a
    /// ground truth and a flow; `None` when there is no such pixel (nothing to score, not a
    /// zero error).
    pub object: Option<EpeResult>,
    /// Pixels scored for `object`.
    pub object_pixels: usize,
    /// The share of the object's ground-truth pixels that were given a flow.
    pub coverage: f64,
    /// Over every ground-truth pixel, a missing flow taken as zero.
    pub all: EpeResult,
    /// Pixels scored for `all`.
    pub all_pixels: usize,
    /// Zero flow over every ground-truth pixel.
    pub zero_flow: EpeResult,
}

/// Scores `flow` against `gt` (the same size) over the pixels where the ground truth is finite;
/// `mask` marks the object in the source frame. `None` when no pixel has a finite ground truth.
pub fn flow_scores(
    flow: &Image<[f32; 3]>,
    gt: &Image<[f32; 3]>,
    mask: Option<&Image<bool>>,
) -> Option<FlowScores> {
    let v = |p: &[f32; 3]| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
    let finite = |p: &[f32; 3]| p.iter().all(|c| c.is_finite());
    let (mut ours, mut truth, mut all_ours, mut all_truth) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut object = 0;
    for (i, (f, g)) in flow.data.iter().zip(&gt.data).enumerate() {
        if !finite(g) {
            continue;
        }
        all_truth.push(v(g));
        all_ours.push(if finite(f) { v(f) } else { Vector3::zeros() });
        if mask.is_none_or(|m| m.data[i]) {
            object += 1;
            if finite(f) {
                ours.push(v(f));
                truth.push(v(g));
            }
        }
    }
    if all_truth.is_empty() {
        return None;
    }
    let zeros = vec![Vector3::zeros(); all_truth.len()];
    Some(FlowScores {
        object: (!ours.is_empty()).then(|| epe3d(&ours, &truth, None)),
        object_pixels: ours.len(),
        coverage: ours.len() as f64 / object.max(1) as f64,
        all: epe3d(&all_ours, &all_truth, None),
        all_pixels: all_truth.len(),
        zero_flow: epe3d(&zeros, &all_truth, None),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scores_count_the_object_the_whole_frame_and_zero_flow() {
        let image = |data: Vec<[f32; 3]>| Image {
            width: data.len(),
            height: 1,
            data,
        };
        let nan = [f32::NAN; 3];
        // ground truth: 0.1 m along x everywhere but the last pixel (no ground truth)
        let gt = image(vec![[0.1, 0.0, 0.0], [0.1, 0.0, 0.0], [0.1, 0.0, 0.0], nan]);
        // ours: exact, 3 cm off, missing, and a flow where there is no ground truth
        let flow = image(vec![[0.1, 0.0, 0.0], [0.1, 0.03, 0.0], nan, [0.0; 3]]);
        let mask = Image {
            width: 4,
            height: 1,
            data: vec![true, true, true, false],
        };
        let s = flow_scores(&flow, &gt, Some(&mask)).unwrap();
        assert_eq!((s.object_pixels, s.all_pixels), (2, 3));
        assert!((s.coverage - 2.0 / 3.0).abs() < 1e-12);
        assert!((s.object.unwrap().stats.mean - 0.015).abs() < 1e-6);
        assert!(
            (s.all.stats.max - 0.1).abs() < 1e-6,
            "the missing flow counts as zero"
        );
        assert!((s.zero_flow.stats.mean - 0.1).abs() < 1e-6);
        assert_eq!(s.zero_flow.within_10cm, 0.0);
        // no flow on the object: nothing scored there, not a zero error
        let none = image(vec![nan; 4]);
        let s = flow_scores(&none, &gt, Some(&mask)).unwrap();
        assert_eq!((s.object, s.object_pixels, s.coverage), (None, 0, 0.0));
        // no ground truth at all: no score
        assert!(flow_scores(&flow, &image(vec![nan; 4]), None).is_none());
    }
}
