//! Sub-maps (Kähler, Prisacariu & Murray, *Real-time large-scale dense 3D reconstruction with
//! loop closure*, ECCV 2016): the map is a sequence of TSDF volumes, each anchored to a keyframe.
//! Frames are tracked against the active sub-map only, so the odometry drifts freely instead of
//! snapping to older parts of the map that drifted differently; a loop measured against an older
//! sub-map ([`super::pipeline`]) moves the keyframes in the pose graph ([`super::loops`]), and
//! each sub-map moves rigidly with its anchor: a voxel at x in the tracking frame lies at
//! X*_a X_a⁻¹ x in the corrected one, X_a being the anchor's tracked pose and X*_a its optimum.
//!
//! A new sub-map starts at the first keyframe after the active one has fused
//! [`SubmapParams::frames`] frames. For [`SubmapParams::overlap`] frames both are fused and the
//! old one is tracked against; then the new one takes over and the old one is frozen.

use crate::mesh::Mesh;
use crate::tsdf::{TsdfParams, TsdfVolume};
use nalgebra::Isometry3;
use std::sync::Arc;

/// When sub-maps start and hand over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SubmapParams {
    /// A new sub-map starts at the first keyframe once the active one has fused this many
    /// frames (default 300, 10 s at 30 Hz).
    pub frames: usize,
    /// Frames fused into both the old and the new sub-map before tracking switches to the new
    /// one (default 30), so that the new one is tracked against only once it holds a surface.
    pub overlap: usize,
}

impl Default for SubmapParams {
    fn default() -> Self {
        Self {
            frames: 300,
            overlap: 30,
        }
    }
}

/// A frozen sub-map: its volume (in the tracking frame), its anchor keyframe and the frames it
/// fused.
#[derive(Debug)]
pub struct Submap {
    /// The TSDF, in the frame the poses were tracked in. Nothing writes a frozen volume again;
    /// it is shared with the loop search running off the tracking thread (the pipeline's
    /// `loop_search` module).
    pub volume: Arc<TsdfVolume>,
    /// The anchor keyframe's frame index.
    pub anchor: usize,
    /// The first and last frame fused.
    pub frames: (usize, usize),
}

/// The active sub-map's anchor and the frames it fused so far.
#[derive(Clone, Copy, Debug)]
struct Active {
    anchor: Option<usize>,
    first: usize,
    last: usize,
    fused: usize,
}

/// The sub-maps other than the active one (whose volume the pipeline holds).
#[derive(Debug)]
pub struct Submaps {
    /// Settings.
    pub params: SubmapParams,
    frozen: Vec<Submap>,
    active: Active,
    /// The sub-map being started, with the frames fused into it.
    next: Option<(Starting, usize)>,
}

/// A sub-map being filled beside the active one: its volume, its anchor keyframe and the first
/// and last frame fused.
#[derive(Debug)]
struct Starting {
    volume: TsdfVolume,
    anchor: usize,
    frames: (usize, usize),
}

impl Submaps {
    /// One active sub-map, nothing frozen.
    pub fn new(params: SubmapParams) -> Self {
        Self {
            params,
            frozen: Vec::new(),
            active: Active {
                anchor: None,
                first: 0,
                last: 0,
                fused: 0,
            },
            next: None,
        }
    }

    /// The map so far as one active sub-map anchored at keyframe `anchor` that fused frames
    /// `first..=last` (a single volume split when its track is lost for good, see
    /// [`super::RelocaliseParams::new_map_after`]).
    pub fn single(params: SubmapParams, anchor: usize, first: usize, last: usize) -> Self {
        let mut s = Self::new(params);
        s.active = Active {
            anchor: Some(anchor),
            first,
            last,
            fused: (last + 1).saturating_sub(first),
        };
        s
    }

    /// The frozen sub-maps, oldest first.
    pub fn frozen(&self) -> &[Submap] {
        &self.frozen
    }

    /// The newest frozen sub-map that fused `frame`.
    pub(crate) fn containing(&self, frame: usize) -> Option<&Submap> {
        self.frozen
            .iter()
            .rev()
            .find(|s| (s.frames.0..=s.frames.1).contains(&frame))
    }

    /// The last frame any frozen sub-map fused.
    pub(crate) fn frozen_until(&self) -> Option<usize> {
        self.frozen.last().map(|s| s.frames.1)
    }

    /// Whether a keyframe taken now should anchor a new sub-map (the first keyframe anchors the
    /// first one).
    pub(crate) fn wants_anchor(&self) -> bool {
        self.active.anchor.is_none()
            || (self.next.is_none() && self.active.fused >= self.params.frames)
    }

    /// Anchors a sub-map at keyframe `frame`: the first one, or a new one to be filled beside
    /// the active one.
    pub fn anchor(&mut self, frame: usize, tsdf: TsdfParams) {
        if self.active.anchor.is_none() {
            self.active.anchor = Some(frame);
            return;
        }
        let new = Starting {
            volume: TsdfVolume::new(tsdf),
            anchor: frame,
            frames: (frame, frame),
        };
        self.next = Some((new, 0));
    }

    /// The sub-map being started, to fuse the frame into as well.
    pub(crate) fn next_volume(&mut self) -> Option<&mut TsdfVolume> {
        self.next.as_mut().map(|(s, _)| &mut s.volume)
    }

    /// Counts frame `frame` as fused (into `active`, and into the next sub-map if one is being
    /// started); once the next one has [`SubmapParams::overlap`] frames it becomes the active
    /// one (swapped into `active`) and the old one is frozen.
    pub fn fused(&mut self, frame: usize, active: &mut TsdfVolume) {
        if self.active.fused == 0 {
            self.active.first = frame;
        }
        self.active.fused += 1;
        self.active.last = frame;
        let Some((next, count)) = self.next.as_mut() else {
            return;
        };
        *count += 1;
        next.frames.1 = frame;
        if *count < self.params.overlap {
            return;
        }
        let (mut next, count) = self.next.take().expect("checked above");
        std::mem::swap(&mut next.volume, active);
        // `next` now holds the old active volume
        let old = Submap {
            volume: Arc::new(next.volume),
            anchor: self.active.anchor.unwrap_or(self.active.first),
            frames: (self.active.first, frame),
        };
        self.frozen.push(old);
        self.active = Active {
            anchor: Some(next.anchor),
            first: next.frames.0,
            last: frame,
            fused: count,
        };
    }

    /// Starts a new map fragment at keyframe `frame`: the active sub-map is frozen as it is (a
    /// sub-map being started is dropped, as the active one holds its frames too) and `active`
    /// becomes an empty volume anchored at `frame`.
    pub fn restart(&mut self, frame: usize, tsdf: TsdfParams, active: &mut TsdfVolume) {
        self.next = None;
        let old = std::mem::replace(active, TsdfVolume::new(tsdf));
        if self.active.fused > 0 {
            self.frozen.push(Submap {
                volume: Arc::new(old),
                anchor: self.active.anchor.unwrap_or(self.active.first),
                frames: (self.active.first, self.active.last),
            });
        }
        self.active = Active {
            anchor: Some(frame),
            first: frame,
            last: frame,
            fused: 0,
        };
    }

    /// The active sub-map's anchor keyframe.
    pub fn active_anchor(&self) -> Option<usize> {
        self.active.anchor
    }

    /// Bytes held by the frozen sub-maps and the one being started.
    pub fn memory_bytes(&self) -> usize {
        let next = self
            .next
            .as_ref()
            .map_or(0, |(s, _)| s.volume.memory_bytes());
        next + self
            .frozen
            .iter()
            .map(|s| s.volume.memory_bytes())
            .sum::<usize>()
    }

    /// The whole map as one mesh: each frozen sub-map's and `active`'s surface moved by
    /// `correction(anchor)` (X*_a X_a⁻¹, see the module's documentation); a sub-map whose
    /// correction is `None` (a map fragment no loop placed) is left out.
    pub fn mesh(
        &self,
        active: &TsdfVolume,
        correction: impl Fn(usize) -> Option<Isometry3<f64>>,
    ) -> Mesh {
        let mut out = Mesh::default();
        let parts = self
            .frozen
            .iter()
            .map(|s| (&*s.volume, Some(s.anchor)))
            .chain(std::iter::once((active, self.active.anchor)));
        for (volume, anchor) in parts {
            let Some(c) = anchor.map_or(Some(Isometry3::identity()), &correction) else {
                continue;
            };
            append(&mut out, volume.extract_mesh(), &c.cast::<f32>());
        }
        out
    }
}

/// Appends `part` moved by `c` to `out`.
fn append(out: &mut Mesh, part: Mesh, c: &Isometry3<f32>) {
    let base = out.vertices.len() as u32;
    let normals = part.normals.len() == part.vertices.len();
    let colors = part.colors.len() == part.vertices.len();
    if !normals {
        out.normals.clear();
    }
    if !colors {
        out.colors.clear();
    }
    let keep_normals = normals && out.normals.len() == out.vertices.len();
    let keep_colors = colors && out.colors.len() == out.vertices.len();
    out.vertices.extend(part.vertices.iter().map(|v| c * v));
    if keep_normals {
        out.normals
            .extend(part.normals.iter().map(|n| c.rotation * n));
    }
    if keep_colors {
        out.colors.extend(part.colors);
    }
    out.faces
        .extend(part.faces.iter().map(|f| f.map(|i| i + base)));
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Vector3};

    #[test]
    fn a_new_submap_takes_over_after_its_overlap_and_the_old_one_is_frozen() {
        let params = SubmapParams {
            frames: 5,
            overlap: 3,
        };
        let mut s = Submaps::new(params);
        let mut active = TsdfVolume::new(TsdfParams::default());
        assert!(s.wants_anchor());
        s.anchor(1, TsdfParams::default());
        assert_eq!(s.active_anchor(), Some(1));
        for f in 1..=5 {
            assert!(s.next_volume().is_none());
            s.fused(f, &mut active);
        }
        // frame 6 is a keyframe: it anchors the next sub-map, fused beside the active one
        s.fused(6, &mut active);
        assert!(s.wants_anchor());
        s.anchor(6, TsdfParams::default());
        assert!(!s.wants_anchor() && s.next_volume().is_some());
        for f in 7..=8 {
            s.fused(f, &mut active);
            assert!(s.frozen().is_empty(), "frame {f}");
        }
        s.fused(9, &mut active);
        assert_eq!(s.frozen().len(), 1);
        assert_eq!(s.frozen()[0].anchor, 1);
        assert_eq!(s.frozen()[0].frames, (1, 9));
        assert_eq!(s.active_anchor(), Some(6));
        assert_eq!(s.containing(3).map(|m| m.anchor), Some(1));
        assert!(s.containing(10).is_none());
        assert_eq!(s.frozen_until(), Some(9));
    }

    #[test]
    fn appended_parts_are_moved_and_their_faces_renumbered() {
        let part = Mesh {
            vertices: vec![
                Point3::origin(),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(0.0, 1.0, 0.0),
            ],
            normals: vec![Vector3::z(); 3],
            colors: vec![[1, 2, 3]; 3],
            faces: vec![[0, 1, 2]],
        };
        let mut out = Mesh::default();
        append(&mut out, part.clone(), &Isometry3::identity());
        let turn = Isometry3::new(
            Vector3::new(0.0, 0.0, 2.0),
            Vector3::x() * std::f32::consts::PI,
        );
        append(&mut out, part, &turn);
        assert_eq!(out.vertices.len(), 6);
        assert_eq!(out.faces, vec![[0, 1, 2], [3, 4, 5]]);
        assert!((out.vertices[5] - Point3::new(0.0, -1.0, 2.0)).norm() < 1e-6);
        assert!((out.normals[5] + Vector3::z()).norm() < 1e-6);
        assert_eq!(out.colors.len(), 6);
    }
}
