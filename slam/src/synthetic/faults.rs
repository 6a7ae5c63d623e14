//! A rigid sequence with the faults a real stream has, for testing that a run survives them: frames
//! the driver dropped (absent from the lists), image files that are corrupt, depth frames that are
//! blank, a sudden jump of the camera, and a stretch looking at a wall without texture (a plane, so
//! three of the six motions are unobservable, and nothing the model has seen).
//!
//! The camera orbits the room's table ([`motion::Motion::Orbit`]); the ground truth holds every
//! frame, the jump and the wall stretch included, so the error of whatever a run reports as
//! tracked can be measured.

use super::motion::{self, look_at, Motion};
use super::noise::SensorNoise;
use super::render::render;
use super::scene::{Scene, Shape};
use super::sequence::{make_dirs, stamp_name, write_index, write_sensor_frame};
use super::texture::Texture;
use crate::camera::Camera;
use crate::io::trajectory::Trajectory;
use crate::io::IoError;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::ops::Range;
use std::path::Path;

/// How a corrupt frame is broken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Corruption {
    /// The depth PNG cut after its first 100 bytes.
    TruncatedDepth,
    /// The colour PNG cut after its first 100 bytes.
    TruncatedColor,
    /// The depth file replaced by bytes that are not an image.
    GarbageDepth,
    /// The depth file empty.
    EmptyDepth,
}

/// Which frames of the orbit carry which fault (indices into the rendered orbit).
#[derive(Clone, Debug, PartialEq)]
pub struct FaultPlan {
    /// Frames of the orbit.
    pub frames: usize,
    /// Frames rendered but left out of the lists (the driver dropped them).
    pub dropped: Vec<usize>,
    /// Frames whose files are broken.
    pub corrupt: Vec<(usize, Corruption)>,
    /// Frames whose depth is all zeros.
    pub blank: Vec<usize>,
    /// From this frame on, the camera is displaced by `jump` (world frame, metres).
    pub jump_at: Option<usize>,
    /// The displacement of the jump.
    pub jump: Vector3<f64>,
    /// Frames that look at the plain wall instead of the table.
    pub wall: Range<usize>,
}

impl FaultPlan {
    /// The plan of the reliability issue over a 180-frame orbit: 10 dropped frames, 5 corrupt
    /// files, 3 blank depth frames, a 30 cm jump at frame 80 and 20 frames at a plain wall from
    /// frame 140.
    pub fn standard() -> Self {
        Self {
            frames: 180,
            dropped: vec![12, 13, 27, 36, 37, 38, 66, 95, 118, 171],
            corrupt: vec![
                (20, Corruption::TruncatedDepth),
                (42, Corruption::TruncatedColor),
                (58, Corruption::GarbageDepth),
                (101, Corruption::EmptyDepth),
                (125, Corruption::TruncatedDepth),
            ],
            blank: vec![48, 49, 110],
            jump_at: Some(80),
            jump: Vector3::new(2.0, -1.0, 1.0).normalize() * 0.3,
            wall: 140..160,
        }
    }

    /// The same orbit with no faults at all (the reference run).
    pub fn clean(frames: usize) -> Self {
        Self {
            frames,
            dropped: Vec::new(),
            corrupt: Vec::new(),
            blank: Vec::new(),
            jump_at: None,
            jump: Vector3::zeros(),
            wall: 0..0,
        }
    }

    /// The ground-truth trajectory: the orbit, displaced after the jump, with the wall stretch.
    pub fn trajectory(&self) -> Trajectory {
        let orbit = motion::procedural(Motion::Orbit, self.frames, 30.0);
        let mut t = Trajectory::default();
        let n = self.wall.len().max(1) as f64;
        for (k, (stamp, pose)) in orbit.stamps.iter().zip(&orbit.poses).enumerate() {
            let mut pose = *pose;
            if self.wall.contains(&k) {
                // 0.7 m from the panel, sliding along it
                let s = (k - self.wall.start) as f64 / n;
                let eye = Point3::new(-1.2 + 0.6 * s, PANEL_Y - 0.7, 1.4);
                pose = look_at(&eye, &(eye + Vector3::y()), &Vector3::z());
            }
            if self.jump_at.is_some_and(|j| k >= j) {
                pose = Translation3::from(self.jump) * pose;
            }
            t.push(*stamp, pose);
        }
        t
    }
}

/// Where the plain panel stands: in front of the room's +y wall.
const PANEL_Y: f64 = 2.45;

/// The room with a plain grey panel (2.6 × 2.2 m) in front of its +y wall.
pub fn scene() -> Scene {
    let mut s = Scene::room(1);
    s.add(
        Shape::Plane { hx: 1.3, hy: 1.1 },
        Isometry3::from_parts(
            Translation3::new(-0.9, PANEL_Y, 1.5),
            UnitQuaternion::from_scaled_axis(Vector3::x() * std::f64::consts::FRAC_PI_2),
        ),
        Texture::plain([0.6, 0.6, 0.6]),
    );
    s
}

/// What a faulty sequence holds, for checking a run against.
#[derive(Clone, Debug, PartialEq)]
pub struct FaultManifest {
    /// Frames in the lists (orbit indices), in order.
    pub listed: Vec<usize>,
    /// The ground truth of every orbit frame.
    pub groundtruth: Trajectory,
}

/// Renders the plan's orbit with `camera` and writes a TUM-layout folder with its faults.
pub fn write_faulty(
    dir: &Path,
    plan: &FaultPlan,
    camera: &Camera,
    noise: &SensorNoise,
) -> Result<FaultManifest, IoError> {
    make_dirs(dir, &[])?;
    let scene = scene();
    let truth = plan.trajectory();
    let mut listed = Vec::new();
    for (k, (stamp, pose)) in truth.stamps.iter().zip(&truth.poses).enumerate() {
        if plan.dropped.contains(&k) {
            continue;
        }
        let mut r = render(&scene, camera, pose);
        if plan.blank.contains(&k) {
            r.depth.data.fill(0.0);
        }
        write_sensor_frame(dir, *stamp, k, &mut r, noise, camera)?;
        let name = stamp_name(*stamp);
        let depth = dir.join("depth").join(format!("{name}.png"));
        let color = dir.join("rgb").join(format!("{name}.png"));
        if let Some((_, how)) = plan.corrupt.iter().find(|c| c.0 == k) {
            let cut = |path: &Path| -> Result<(), IoError> {
                let bytes = std::fs::read(path)
                    .map_err(|e| IoError::file(path, format!("cannot read: {e}")))?;
                std::fs::write(path, &bytes[..bytes.len().min(100)])
                    .map_err(|e| IoError::file(path, format!("cannot write: {e}")))
            };
            let put = |path: &Path, bytes: &[u8]| {
                std::fs::write(path, bytes)
                    .map_err(|e| IoError::file(path, format!("cannot write: {e}")))
            };
            match how {
                Corruption::TruncatedDepth => cut(&depth)?,
                Corruption::TruncatedColor => cut(&color)?,
                Corruption::GarbageDepth => put(&depth, b"not a PNG at all")?,
                Corruption::EmptyDepth => put(&depth, b"")?,
            }
        }
        listed.push(k);
    }
    let stamps: Vec<(f64, f64)> = listed
        .iter()
        .map(|&k| (truth.stamps[k], truth.stamps[k]))
        .collect();
    write_index(dir, camera, &Default::default(), &stamps, &truth)?;
    Ok(FaultManifest {
        listed,
        groundtruth: truth,
    })
}
