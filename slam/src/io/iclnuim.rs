//! The ICL-NUIM layout as distributed with slambook2 (Handa et al., ICRA 2014): `color/N.png`,
//! `depth/N.png` numbered from 1, and `pose.txt` with one camera-to-world pose per frame
//! (`tx ty tz qx qy qz qw`). Its intrinsics have a negative fy (fx 481.2, fy −480, cx 319.5, cy 239.5).

use super::images::{read_color, read_depth};
use super::tum::RgbdFrame;
use super::{data_lines, number, read_text, IoError};
use crate::camera::Camera;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::path::{Path, PathBuf};

/// ICL-NUIM's intrinsics (negative fy: the image's y axis points up in the camera frame).
pub fn camera() -> Camera {
    Camera::new(481.2, -480.0, 319.5, 239.5, 640, 480)
}

/// An ICL-NUIM sequence on disk.
#[derive(Clone, Debug)]
pub struct IclNuimSequence {
    /// Its folder.
    pub root: PathBuf,
    /// Intrinsics.
    pub camera: Camera,
    /// Ground-truth camera-to-world pose of each frame.
    pub poses: Vec<Isometry3<f64>>,
}

impl IclNuimSequence {
    /// Opens a folder with `pose.txt`, `color/` and `depth/`.
    pub fn open(root: impl AsRef<Path>) -> Result<Self, IoError> {
        let root = root.as_ref().to_path_buf();
        let path = root.join("pose.txt");
        let text = read_text(&path)?;
        let names = ["tx", "ty", "tz", "qx", "qy", "qz", "qw"];
        let mut poses = Vec::new();
        for (line, f) in data_lines(&text) {
            if f.len() != 7 {
                return Err(IoError::line(
                    &path,
                    line,
                    format!(
                        "expected 7 fields (tx ty tz qx qy qz qw), found {}",
                        f.len()
                    ),
                ));
            }
            let v: Vec<f64> = (0..7)
                .map(|k| number(&path, line, &f, k, names[k]))
                .collect::<Result<_, _>>()?;
            let q = Quaternion::new(v[6], v[3], v[4], v[5]);
            if q.norm() < 1e-9 {
                return Err(IoError::line(
                    &path,
                    line,
                    "fields qx qy qz qw: the quaternion is zero",
                ));
            }
            poses.push(Isometry3::from_parts(
                Translation3::new(v[0], v[1], v[2]),
                UnitQuaternion::from_quaternion(q),
            ));
        }
        if poses.is_empty() {
            return Err(IoError::file(&path, "no poses"));
        }
        Ok(Self {
            root,
            camera: camera(),
            poses,
        })
    }

    /// Number of frames (poses).
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Loads frame `i` (0-based; files are numbered from 1).
    pub fn load(&self, i: usize) -> Result<RgbdFrame, IoError> {
        if i >= self.poses.len() {
            return Err(IoError::no_frame(&self.root, i, self.poses.len()));
        }
        let frame_err = |e: IoError| e.in_frame(i);
        let depth = read_depth(self.root.join("depth").join(format!("{}.png", i + 1)))
            .map_err(frame_err)?;
        let color = read_color(self.root.join("color").join(format!("{}.png", i + 1)))
            .map_err(frame_err)?;
        Ok(RgbdFrame {
            index: i,
            timestamp: i as f64 / 30.0,
            color_timestamp: i as f64 / 30.0,
            depth,
            color: Some(color),
        })
    }
}
