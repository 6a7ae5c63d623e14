//! A plain folder of numbered frames: `color/` and `depth/` with matching sorted file names, and the
//! intrinsics in `intrinsics.txt` (`fx fy cx cy depth_scale`) or in an Open3D camera JSON
//! (`camera_*.json`: `width`, `height`, column-major `intrinsic_matrix`; depth in millimetres).

use super::images::{read_color, read_depth};
use super::tum::{check_size, read_calibration, undistorted, undistorter_for, RgbdFrame};
use super::{read_text, IoError};
use crate::camera::Camera;
use crate::distortion::{Distortion, Undistorter};
use std::path::{Path, PathBuf};

/// A folder sequence on disk.
#[derive(Clone, Debug)]
pub struct FolderSequence {
    /// Its folder.
    pub root: PathBuf,
    /// Intrinsics of the frames [`Self::load`] delivers (undistorted where `intrinsics.txt`
    /// gives lens distortion).
    pub camera: Camera,
    /// (depth, colour) file pairs in name order.
    pub frames: Vec<(PathBuf, PathBuf)>,
    /// The remap applied to every frame when `intrinsics.txt` gives lens distortion.
    pub undistorter: Option<Undistorter>,
}

fn sorted_files(dir: &Path) -> Result<Vec<PathBuf>, IoError> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| IoError::file(dir, format!("cannot list: {e}")))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    v.sort();
    Ok(v)
}

/// Reads an Open3D `PinholeCameraIntrinsic` JSON (depth scale 1000: millimetres).
pub fn read_open3d_camera(path: &Path) -> Result<Camera, IoError> {
    parse_open3d_camera(&read_text(path)?, path)
}

/// Parses the text of an Open3D intrinsics JSON (see [`read_open3d_camera`]); `path` names it in
/// errors.
pub fn parse_open3d_camera(text: &str, path: &Path) -> Result<Camera, IoError> {
    let j: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| IoError::line(path, e.line(), format!("invalid JSON: {e}")))?;
    let field = |k: &str| {
        j.get(k)
            .ok_or_else(|| IoError::file(path, format!("missing field {k}")))
    };
    let width = field("width")?
        .as_u64()
        .ok_or_else(|| IoError::file(path, "field width: not an integer"))?
        as usize;
    let height = field("height")?
        .as_u64()
        .ok_or_else(|| IoError::file(path, "field height: not an integer"))?
        as usize;
    let m: Vec<f64> = field("intrinsic_matrix")?
        .as_array()
        .filter(|a| a.len() == 9)
        .ok_or_else(|| IoError::file(path, "field intrinsic_matrix: expected 9 numbers"))?
        .iter()
        .map(|v| {
            v.as_f64()
                .ok_or_else(|| IoError::file(path, "field intrinsic_matrix: not a number"))
        })
        .collect::<Result<_, _>>()?;
    // column-major: [fx, 0, 0, 0, fy, 0, cx, cy, 1]
    if m[0] == 0.0 || m[4] == 0.0 {
        // a zero focal length puts every pixel on one ray: every frame would be lost
        return Err(IoError::file(
            path,
            "field intrinsic_matrix: focal lengths (entries 0 and 4) must be non-zero",
        ));
    }
    let mut c = Camera::new(m[0], m[4], m[6], m[7], width, height);
    c.depth_scale = 1000.0;
    Ok(c)
}

impl FolderSequence {
    /// Opens a folder; `depth_scale` overrides the intrinsics file's.
    pub fn open(root: impl AsRef<Path>, depth_scale: Option<f64>) -> Result<Self, IoError> {
        let root = root.as_ref().to_path_buf();
        let depth = sorted_files(&root.join("depth"))?;
        let color = sorted_files(&root.join("color"))?;
        if depth.is_empty() {
            return Err(IoError::file(root.join("depth"), "no depth images"));
        }
        if depth.len() != color.len() {
            return Err(IoError::file(
                &root,
                format!(
                    "{} depth images but {} colour images",
                    depth.len(),
                    color.len()
                ),
            ));
        }
        let first = read_depth(&depth[0])?;
        let txt = root.join("intrinsics.txt");
        let json = std::fs::read_dir(&root)
            .map_err(|e| IoError::file(&root, format!("cannot list: {e}")))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .find(|p| {
                p.extension().is_some_and(|x| x == "json")
                    && p.file_name()
                        .is_some_and(|n| n.to_string_lossy().starts_with("camera"))
            });
        let (mut camera, distortion) = if txt.exists() {
            read_calibration(&txt, first.width, first.height)?
        } else if let Some(j) = json {
            (read_open3d_camera(&j)?, Distortion::default())
        } else {
            return Err(IoError::file(&root, "no intrinsics.txt or camera_*.json"));
        };
        if (camera.width, camera.height) != (first.width, first.height) {
            return Err(IoError::file(
                &depth[0],
                format!(
                    "image is {}x{}, the intrinsics say {}x{}",
                    first.width, first.height, camera.width, camera.height
                ),
            ));
        }
        if let Some(s) = depth_scale {
            camera.depth_scale = s;
        }
        Ok(Self {
            root,
            undistorter: undistorter_for(&camera, &distortion),
            camera,
            frames: depth.into_iter().zip(color).collect(),
        })
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Loads frame `i`.
    pub fn load(&self, i: usize) -> Result<RgbdFrame, IoError> {
        let (d, c) = self
            .frames
            .get(i)
            .ok_or_else(|| IoError::no_frame(&self.root, i, self.frames.len()))?;
        let frame_err = |e: IoError| e.in_frame(i);
        let frame = RgbdFrame {
            index: i,
            timestamp: i as f64 / 30.0,
            color_timestamp: i as f64 / 30.0,
            depth: read_depth(d).map_err(frame_err)?,
            color: Some(read_color(c).map_err(frame_err)?),
        };
        check_size(
            i,
            &self.camera,
            "depth",
            (frame.depth.width, frame.depth.height),
            d,
        )?;
        if let Some(color) = &frame.color {
            check_size(i, &self.camera, "colour", (color.width, color.height), c)?;
        }
        Ok(undistorted(frame, self.undistorter.as_ref()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_open3d_camera_is_read_column_major_and_a_zero_focal_length_is_refused() {
        let p = Path::new("camera_intrinsic.json");
        let json = |fx: f64| {
            format!(
                "{{\"width\": 640, \"height\": 480, \
                 \"intrinsic_matrix\": [{fx}, 0, 0, 0, 520.5, 0, 319.5, 241.0, 1]}}"
            )
        };
        let c = parse_open3d_camera(&json(525.0), p).unwrap();
        assert_eq!((c.fx, c.fy, c.cx, c.cy), (525.0, 520.5, 319.5, 241.0));
        assert_eq!((c.width, c.height, c.depth_scale), (640, 480, 1000.0));
        let e = parse_open3d_camera(&json(0.0), p).unwrap_err().to_string();
        assert!(
            e.contains("camera_intrinsic.json") && e.contains("focal lengths"),
            "{e}"
        );
        let short = r#"{"width": 640, "height": 480, "intrinsic_matrix": [525, 0, 0]}"#;
        assert!(parse_open3d_camera(short, p).is_err());
    }
}
