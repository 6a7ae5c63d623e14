//! Writing rendered sequences in the TUM RGB-D layout, so every tool that reads TUM reads ours:
//! `rgb/` and `depth/` PNGs (16-bit depth at the camera's depth scale), `rgb.txt`, `depth.txt`,
//! `associations.txt`, `groundtruth.txt` (camera-to-world, at the depth and the colour stamps) and
//! `intrinsics.txt` (`fx fy cx cy depth_scale`, followed by `k1 k2 p1 p2 k3` when the images are
//! distorted). With the [`Sensor::Kinect`] model, colour is captured after depth and each has its
//! own stamps in `rgb.txt` and `depth.txt`, as in TUM's recordings. Deforming sequences add `meshes/NNNNNN.ply` (the ground-truth surface
//! at each frame, world frame) and `flow/NNNNNN.flow` (per-pixel scene flow to the next frame).
//!
//! A `.flow` file is the text line `FLOW3D <width> <height>\n` followed by width × height × 3
//! little-endian f32 (world-frame displacement per pixel, row by row; NaN where unknown).

use super::deform::DeformingScene;
use super::kinect::{pose_at, KinectModel, Recorder};
use super::noise::SensorNoise;
use super::render::{render, Rendering};
use super::scene::Scene;
use crate::camera::Camera;
use crate::distortion::Distortion;
use crate::image::Image;
use crate::io::images::{write_color, write_depth};
use crate::io::trajectory::Trajectory;
use crate::io::{ply, write_atomic, IoError};
use nalgebra::Isometry3;
use std::fmt::Write as _;
use std::path::Path;

/// Encodes a scene-flow image.
pub fn encode_flow(flow: &Image<[f32; 3]>) -> Vec<u8> {
    let mut out = format!("FLOW3D {} {}\n", flow.width, flow.height).into_bytes();
    for px in &flow.data {
        for c in px {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    out
}

/// Reads a scene-flow file written by [`encode_flow`].
pub fn read_flow(path: impl AsRef<Path>) -> Result<Image<[f32; 3]>, IoError> {
    let path = path.as_ref();
    let bytes =
        std::fs::read(path).map_err(|e| IoError::file(path, format!("cannot read: {e}")))?;
    let nl = bytes
        .iter()
        .position(|&b| b == b'\n')
        .ok_or_else(|| IoError::file(path, "no header line"))?;
    let header =
        std::str::from_utf8(&bytes[..nl]).map_err(|_| IoError::file(path, "header is not text"))?;
    let f: Vec<&str> = header.split_whitespace().collect();
    let (w, h) = match f.as_slice() {
        ["FLOW3D", w, h] => (
            w.parse::<usize>()
                .map_err(|_| IoError::line(path, 1, "width is not a number"))?,
            h.parse::<usize>()
                .map_err(|_| IoError::line(path, 1, "height is not a number"))?,
        ),
        _ => return Err(IoError::line(path, 1, "expected 'FLOW3D width height'")),
    };
    let body = &bytes[nl + 1..];
    if body.len() != w * h * 12 {
        return Err(IoError::file(
            path,
            format!(
                "expected {} bytes of flow, found {}",
                w * h * 12,
                body.len()
            ),
        ));
    }
    let data = body
        .chunks_exact(12)
        .map(|c| [0, 4, 8].map(|o| f32::from_le_bytes(c[o..o + 4].try_into().expect("4 bytes"))))
        .collect();
    Ok(Image::from_vec(w, h, data).expect("size checked"))
}

pub(crate) fn stamp_name(stamp: f64) -> String {
    format!("{stamp:.6}")
}

/// Applies the sensor model to a rendering and writes its depth and colour PNGs, named by stamp.
pub(crate) fn write_sensor_frame(
    dir: &Path,
    stamp: f64,
    k: usize,
    r: &mut Rendering,
    noise: &SensorNoise,
    camera: &Camera,
) -> Result<(), IoError> {
    let raw = noise.apply_to(k as u64, r, camera.depth_scale);
    let n = stamp_name(stamp);
    write_depth(dir.join("depth").join(format!("{n}.png")), &raw)?;
    write_color(dir.join("rgb").join(format!("{n}.png")), &r.color)
}

/// The sensor that records a rendered sequence.
#[derive(Clone, Debug, PartialEq)]
pub enum Sensor {
    /// The simple model: the render's own pixels with axial noise, holes at grazing angles, one
    /// stamp for both images, no distortion.
    Ideal(SensorNoise),
    /// The structured-light sensor of [`super::kinect`].
    Kinect(Box<KinectModel>),
}

impl Sensor {
    /// The lens distortion the images carry.
    pub fn distortion(&self) -> Distortion {
        match self {
            Sensor::Ideal(_) => Distortion::default(),
            Sensor::Kinect(m) => m.distortion,
        }
    }
}

/// The stamps of one listed frame: (depth, colour).
pub(crate) type Stamps = (f64, f64);

/// Writes the image lists (the frames at `listed` stamps), the ground truth (all of `trajectory`)
/// and the intrinsics with `distortion`.
pub(crate) fn write_index(
    dir: &Path,
    camera: &Camera,
    distortion: &Distortion,
    listed: &[Stamps],
    trajectory: &Trajectory,
) -> Result<(), IoError> {
    let (mut rgb, mut depth, mut assoc) = (
        String::from("# color images\n# timestamp filename\n"),
        String::from("# depth maps\n# timestamp filename\n"),
        String::new(),
    );
    for (d, c) in listed {
        let (d, c) = (stamp_name(*d), stamp_name(*c));
        let _ = writeln!(rgb, "{c} rgb/{c}.png");
        let _ = writeln!(depth, "{d} depth/{d}.png");
        let _ = writeln!(assoc, "{c} rgb/{c}.png {d} depth/{d}.png");
    }
    write_atomic(dir.join("rgb.txt"), rgb.as_bytes())?;
    write_atomic(dir.join("depth.txt"), depth.as_bytes())?;
    write_atomic(dir.join("associations.txt"), assoc.as_bytes())?;
    trajectory.write_tum(dir.join("groundtruth.txt"))?;
    let mut intr = format!(
        "{:?} {:?} {:?} {:?} {:?}",
        camera.fx, camera.fy, camera.cx, camera.cy, camera.depth_scale
    );
    if !distortion.is_zero() {
        for c in distortion.to_array() {
            let _ = write!(intr, " {c:?}");
        }
    }
    intr.push('\n');
    write_atomic(dir.join("intrinsics.txt"), intr.as_bytes())
}

pub(crate) fn make_dirs(dir: &Path, extra: &[&str]) -> Result<(), IoError> {
    for d in ["rgb", "depth"].iter().chain(extra) {
        std::fs::create_dir_all(dir.join(d))
            .map_err(|e| IoError::file(dir.join(d), format!("cannot create: {e}")))?;
    }
    Ok(())
}

/// Renders `scene` along `trajectory` (poses in the scene's frame given by `to_scene · pose`) and
/// writes a TUM-layout sequence whose ground truth is `trajectory` exactly. `progress` is called
/// after each frame.
pub fn write_rigid(
    dir: &Path,
    scene: &Scene,
    camera: &Camera,
    trajectory: &Trajectory,
    to_scene: &Isometry3<f64>,
    sensor: &Sensor,
    mut progress: impl FnMut(usize),
) -> Result<(), IoError> {
    make_dirs(dir, &[])?;
    let in_scene = Trajectory {
        stamps: trajectory.stamps.clone(),
        poses: trajectory.poses.iter().map(|p| to_scene * p).collect(),
    };
    let listed = match sensor {
        Sensor::Ideal(noise) => record_ideal(dir, scene, camera, &in_scene, noise, &mut progress)?,
        Sensor::Kinect(model) => record_kinect(
            dir,
            scene,
            &model.recorder(camera),
            &in_scene,
            &mut progress,
        )?,
    };
    // the truth at the colour stamps too, so that an evaluation keyed to either image matches
    let mut truth: Vec<(f64, Isometry3<f64>)> = trajectory
        .stamps
        .iter()
        .copied()
        .zip(trajectory.poses.iter().copied())
        .collect();
    for &(d, c) in &listed {
        if c != d {
            truth.push((c, pose_at(trajectory, c)));
        }
    }
    truth.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut gt = Trajectory::default();
    for (s, p) in truth {
        gt.push(s, p);
    }
    write_index(dir, camera, &sensor.distortion(), &listed, &gt)
}

/// Records every frame of `trajectory` (camera-to-scene) with the ideal sensor.
fn record_ideal(
    dir: &Path,
    scene: &Scene,
    camera: &Camera,
    trajectory: &Trajectory,
    noise: &SensorNoise,
    progress: &mut impl FnMut(usize),
) -> Result<Vec<Stamps>, IoError> {
    let mut listed = Vec::with_capacity(trajectory.len());
    for (k, (stamp, pose)) in trajectory.stamps.iter().zip(&trajectory.poses).enumerate() {
        let mut r = render(scene, camera, pose);
        write_sensor_frame(dir, *stamp, k, &mut r, noise, camera)?;
        listed.push((*stamp, *stamp));
        progress(k);
    }
    Ok(listed)
}

/// Records every frame of `trajectory` (camera-to-scene) with the Kinect model: depth at the
/// trajectory's stamps, colour at its own.
fn record_kinect(
    dir: &Path,
    scene: &Scene,
    recorder: &Recorder,
    trajectory: &Trajectory,
    progress: &mut impl FnMut(usize),
) -> Result<Vec<Stamps>, IoError> {
    let mut listed = Vec::with_capacity(trajectory.len());
    for (k, stamp) in trajectory.stamps.iter().enumerate() {
        let f = recorder.capture(scene, trajectory, k);
        let (d, c) = (stamp_name(*stamp), stamp_name(f.color_stamp));
        write_depth(dir.join("depth").join(format!("{d}.png")), &f.depth)?;
        write_color(dir.join("rgb").join(format!("{c}.png")), &f.color)?;
        listed.push((*stamp, f.color_stamp));
        progress(k);
    }
    Ok(listed)
}

/// Renders a deforming scene seen from `trajectory` and writes a TUM-layout sequence plus the
/// ground-truth meshes and scene flow.
pub fn write_deforming(
    dir: &Path,
    scene: &DeformingScene,
    camera: &Camera,
    trajectory: &Trajectory,
    noise: &SensorNoise,
    mut progress: impl FnMut(usize),
) -> Result<(), IoError> {
    make_dirs(dir, &["meshes", "flow"])?;
    for (k, (stamp, pose)) in trajectory.stamps.iter().zip(&trajectory.poses).enumerate() {
        let (mut r, flow) = scene.render_with_flow(camera, pose, k);
        write_sensor_frame(dir, *stamp, k, &mut r, noise, camera)?;
        ply::write(
            dir.join("meshes").join(format!("{k:06}.ply")),
            &scene.mesh_at(k),
        )?;
        write_atomic(
            dir.join("flow").join(format!("{k:06}.flow")),
            &encode_flow(&flow),
        )?;
        progress(k);
    }
    let listed: Vec<Stamps> = trajectory.stamps.iter().map(|&s| (s, s)).collect();
    write_index(dir, camera, &Distortion::default(), &listed, trajectory)
}

/// A static camera 1.5 m from the deforming surface (world = camera frame), `frames` poses.
pub fn static_camera(frames: usize, fps: f64) -> Trajectory {
    let mut t = Trajectory::default();
    for k in 0..frames {
        t.push(k as f64 / fps, Isometry3::identity());
    }
    t
}
