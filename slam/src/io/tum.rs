//! The TUM RGB-D layout (Sturm et al., IROS 2012): `rgb.txt` and `depth.txt` list
//! `timestamp filename`, frames are paired by nearest timestamp as TUM's `associate.py` does (at most
//! 0.02 s apart), depth PNGs are 16-bit with 5000 units per metre, `groundtruth.txt` is a TUM
//! trajectory. An `intrinsics.txt` (`fx fy cx cy depth_scale`, as the project's generator writes)
//! overrides the intrinsics known for freiburg1/2/3 sequences.

use super::images::{read_color, read_depth};
use super::trajectory::Trajectory;
use super::{data_lines, number, read_text, IoError};
use crate::camera::Camera;
use crate::image::{ColorImage, Image};
use std::path::{Path, PathBuf};

/// TUM's default maximum timestamp difference for associating colour and depth.
pub const MAX_DIFFERENCE: f64 = 0.02;

/// One RGB-D frame as loaded.
#[derive(Clone, Debug)]
pub struct RgbdFrame {
    /// Index in its sequence.
    pub index: usize,
    /// Seconds (the depth image's stamp).
    pub timestamp: f64,
    /// Raw depth (sensor units).
    pub depth: Image<u16>,
    /// Colour, when the sequence has it.
    pub color: Option<ColorImage>,
}

/// The files of one associated frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameFiles {
    /// Depth timestamp, seconds.
    pub timestamp: f64,
    /// Depth image.
    pub depth: PathBuf,
    /// Colour image.
    pub rgb: PathBuf,
}

/// A TUM RGB-D sequence on disk.
#[derive(Clone, Debug)]
pub struct TumSequence {
    /// Its folder.
    pub root: PathBuf,
    /// Intrinsics.
    pub camera: Camera,
    /// Associated frames in time order.
    pub frames: Vec<FrameFiles>,
    /// The ground truth, when `groundtruth.txt` exists.
    pub groundtruth: Option<Trajectory>,
}

/// Reads `rgb.txt` or `depth.txt`: `timestamp filename` per line.
pub fn read_list(path: &Path) -> Result<Vec<(f64, String)>, IoError> {
    parse_list(&read_text(path)?, path)
}

/// Parses the text of an image list (see [`read_list`]); `path` names it in errors.
pub fn parse_list(text: &str, path: &Path) -> Result<Vec<(f64, String)>, IoError> {
    data_lines(text)
        .map(|(line, f)| {
            if f.len() != 2 {
                return Err(IoError::line(
                    path,
                    line,
                    format!("expected 'timestamp filename', found {} fields", f.len()),
                ));
            }
            Ok((number(path, line, &f, 0, "timestamp")?, f[1].to_string()))
        })
        .collect()
}

/// TUM's `associate.py`: every pair closer than `max_difference` is a candidate; candidates are taken
/// in order of increasing difference (ties by the first, then the second stamp) as long as neither
/// side is used yet. Returns index pairs sorted by the first stamp.
pub fn associate(first: &[f64], second: &[f64], max_difference: f64) -> Vec<(usize, usize)> {
    let mut order: Vec<usize> = (0..second.len()).collect();
    order.sort_by(|&a, &b| second[a].total_cmp(&second[b]));
    let sorted: Vec<f64> = order.iter().map(|&i| second[i]).collect();
    let mut candidates = Vec::new();
    for (i, &a) in first.iter().enumerate() {
        let start = sorted.partition_point(|&b| b <= a - max_difference);
        for (k, &b) in sorted.iter().enumerate().skip(start) {
            if b >= a + max_difference {
                break;
            }
            if (a - b).abs() < max_difference {
                candidates.push(((a - b).abs(), a, b, i, order[k]));
            }
        }
    }
    candidates.sort_by(|x, y| {
        x.0.total_cmp(&y.0)
            .then(x.1.total_cmp(&y.1))
            .then(x.2.total_cmp(&y.2))
    });
    let (mut used_a, mut used_b) = (vec![false; first.len()], vec![false; second.len()]);
    let mut out = Vec::new();
    for (_, _, _, i, j) in candidates {
        if !used_a[i] && !used_b[j] {
            used_a[i] = true;
            used_b[j] = true;
            out.push((i, j));
        }
    }
    out.sort_by(|x, y| first[x.0].total_cmp(&first[y.0]));
    out
}

/// Reads `intrinsics.txt`: `fx fy cx cy depth_scale` on one line; the image size comes from `width`,
/// `height`.
pub fn read_intrinsics(path: &Path, width: usize, height: usize) -> Result<Camera, IoError> {
    parse_intrinsics(&read_text(path)?, path, width, height)
}

/// Parses the text of an intrinsics file (see [`read_intrinsics`]); `path` names it in errors.
pub fn parse_intrinsics(
    text: &str,
    path: &Path,
    width: usize,
    height: usize,
) -> Result<Camera, IoError> {
    let (line, f) = data_lines(text).next().ok_or_else(|| {
        IoError::file(
            path,
            "no intrinsics line (expected 'fx fy cx cy depth_scale')",
        )
    })?;
    let names = ["fx", "fy", "cx", "cy", "depth_scale"];
    let v: Vec<f64> = (0..5)
        .map(|k| number(path, line, &f, k, names[k]))
        .collect::<Result<_, _>>()?;
    if v[0] == 0.0 || v[1] == 0.0 || v[4] <= 0.0 {
        return Err(IoError::line(
            path,
            line,
            "focal lengths must be non-zero and depth_scale positive",
        ));
    }
    let mut c = Camera::new(v[0], v[1], v[2], v[3], width, height);
    c.depth_scale = v[4];
    Ok(c)
}

/// The intrinsics TUM publishes for its three sensors, chosen by the folder name.
pub fn known_intrinsics(root: &Path) -> Camera {
    let name = root.to_string_lossy();
    let (fx, fy, cx, cy) = if name.contains("freiburg1") {
        (517.3, 516.5, 318.6, 255.3)
    } else if name.contains("freiburg2") {
        (520.9, 521.0, 325.1, 249.7)
    } else if name.contains("freiburg3") {
        (535.4, 539.2, 320.1, 247.6)
    } else {
        (525.0, 525.0, 319.5, 239.5)
    };
    Camera::new(fx, fy, cx, cy, 640, 480)
}

impl TumSequence {
    /// Opens a sequence folder: reads the lists, associates colour and depth, the ground truth and the
    /// intrinsics (the size is taken from the first depth image).
    pub fn open(root: impl AsRef<Path>) -> Result<Self, IoError> {
        let root = root.as_ref().to_path_buf();
        let rgb = read_list(&root.join("rgb.txt"))?;
        let depth = read_list(&root.join("depth.txt"))?;
        let pairs = associate(
            &depth.iter().map(|d| d.0).collect::<Vec<_>>(),
            &rgb.iter().map(|r| r.0).collect::<Vec<_>>(),
            MAX_DIFFERENCE,
        );
        if pairs.is_empty() {
            return Err(IoError::file(
                root.join("depth.txt"),
                "no depth frame has a colour frame within 0.02 s",
            ));
        }
        let frames: Vec<FrameFiles> = pairs
            .iter()
            .map(|&(d, r)| FrameFiles {
                timestamp: depth[d].0,
                depth: root.join(&depth[d].1),
                rgb: root.join(&rgb[r].1),
            })
            .collect();
        let gt_path = root.join("groundtruth.txt");
        let groundtruth = if gt_path.exists() {
            Some(Trajectory::read_tum(&gt_path)?)
        } else {
            None
        };
        // the image size from the first depth image that reads (a broken one is the frame's
        // problem, reported when it is loaded, not the sequence's)
        let mut first_error = None;
        let first = frames
            .iter()
            .find_map(|f| match read_depth(&f.depth) {
                Ok(d) => Some(d),
                Err(e) => {
                    first_error.get_or_insert(e);
                    None
                }
            })
            .ok_or_else(|| {
                let e = first_error.expect("at least one frame was tried");
                IoError::file(&root, format!("no depth image can be read; the first: {e}"))
            })?;
        let intr = root.join("intrinsics.txt");
        let camera = if intr.exists() {
            read_intrinsics(&intr, first.width, first.height)?
        } else {
            Camera {
                width: first.width,
                height: first.height,
                ..known_intrinsics(&root)
            }
        };
        Ok(Self {
            root,
            camera,
            frames,
            groundtruth,
        })
    }

    /// Number of associated frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// True when there are no frames.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Loads frame `i`; an unreadable or mis-sized image is an error naming the frame and file.
    pub fn load(&self, i: usize) -> Result<RgbdFrame, IoError> {
        let f = self
            .frames
            .get(i)
            .ok_or_else(|| IoError::no_frame(&self.root, i, self.frames.len()))?;
        let frame_err = |e: IoError| e.in_frame(i);
        let depth = read_depth(&f.depth).map_err(frame_err)?;
        let color = read_color(&f.rgb).map_err(frame_err)?;
        for (what, w, h, path) in [
            ("depth", depth.width, depth.height, &f.depth),
            ("colour", color.width, color.height, &f.rgb),
        ] {
            if (w, h) != (self.camera.width, self.camera.height) {
                return Err(IoError::file(
                    path,
                    format!(
                        "frame {i}: {what} is {w}x{h}, the sequence is {}x{}",
                        self.camera.width, self.camera.height
                    ),
                ));
            }
        }
        Ok(RgbdFrame {
            index: i,
            timestamp: f.timestamp,
            depth,
            color: Some(color),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn association_matches_a_hand_checked_case() {
        // depth stamps vs rgb stamps; by hand: 1.000↔1.004 (0.004), 1.033↔1.030 (0.003),
        // 1.066↔1.070 (0.004; 1.060 is 0.006 away), 1.100 has nothing within 0.02 (1.125 is 0.025),
        // 1.130↔1.125 (0.005).
        let depth = [1.000, 1.033, 1.066, 1.100, 1.130];
        let rgb = [0.970, 1.004, 1.030, 1.060, 1.070, 1.125];
        // 1.100: 1.070 is 0.030 and 1.125 is 0.025 away -> unmatched.
        assert_eq!(
            associate(&depth, &rgb, 0.02),
            vec![(0, 1), (1, 2), (2, 4), (4, 5)]
        );
        // Greedy by difference: 1.062 could take 1.060 (0.002) or 1.070 (0.008); 1.066 then gets 1.070.
        assert_eq!(
            associate(&[1.062, 1.066], &[1.060, 1.070], 0.02),
            vec![(0, 0), (1, 1)]
        );
        assert_eq!(
            associate(&[1.066, 1.062], &[1.060, 1.070], 0.02),
            vec![(1, 0), (0, 1)]
        );
    }
}
