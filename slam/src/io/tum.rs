//! The TUM RGB-D layout (Sturm et al., IROS 2012): `rgb.txt` and `depth.txt` list
//! `timestamp filename`, frames are paired by the folder's `associations.txt` where it has one (as
//! ORB-SLAM2 reads them), else by nearest timestamp as TUM's `associate.py` does (at most 0.02 s
//! apart), depth PNGs are 16-bit with 5000 units per metre, `groundtruth.txt` is a TUM
//! trajectory. An `intrinsics.txt` (`fx fy cx cy depth_scale`, as the project's generator writes)
//! overrides the intrinsics known for freiburg1/2/3 sequences, and so does a `calibration.txt`
//! (`fx fy cx cy`, the ETH3D SLAM benchmark's, whose depth is at TUM's 5000 units per metre); the
//! folder's [`IntrinsicsSource`] says which was used. ETH3D's `associated.txt` pairs frames as
//! `associations.txt` does.

use super::images::{read_color, read_depth};
use super::trajectory::Trajectory;
use super::{data_lines, number, read_text, IoError};
use crate::camera::{usable_focal_length, Camera};
use crate::distortion::{Distortion, Undistorter};
use crate::image::{ColorImage, Image};
use std::path::{Path, PathBuf};

/// TUM's default maximum timestamp difference for associating colour and depth.
pub const MAX_DIFFERENCE: f64 = 0.02;

/// How a TUM folder's depth and colour frames are paired.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Pairing {
    /// As the folder's `associations.txt` lists them, where it has one (ORB-SLAM2 reads them so;
    /// the project's generator writes each capture's own pair there), else by their stamps.
    #[default]
    Listed,
    /// By their stamps alone ([`associate`]), whatever the folder has.
    Stamps,
}

/// One RGB-D frame as loaded.
#[derive(Clone, Debug)]
pub struct RgbdFrame {
    /// Index in its sequence.
    pub index: usize,
    /// Seconds (the depth image's stamp).
    pub timestamp: f64,
    /// Seconds: the colour image's own stamp (equal to `timestamp` where the source has one stamp
    /// for both).
    pub color_timestamp: f64,
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
    /// Colour timestamp, seconds.
    pub color_timestamp: f64,
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
    /// Intrinsics of the frames [`Self::load`] delivers (undistorted where the sequence's
    /// calibration has lens distortion).
    pub camera: Camera,
    /// Associated frames in time order.
    pub frames: Vec<FrameFiles>,
    /// The ground truth, when `groundtruth.txt` exists.
    pub groundtruth: Option<Trajectory>,
    /// The remap applied to every frame when `intrinsics.txt` gives lens distortion.
    pub undistorter: Option<Undistorter>,
    /// Depth frames of `depth.txt` left out for want of a colour frame (within the stamp limit,
    /// as `associate.py` leaves them out, or in `associations.txt`).
    pub unpaired_depth: usize,
    /// Paired frames left out because an earlier frame has the same depth stamp (a trajectory
    /// has one pose per stamp; the first frame listed at it is read).
    pub repeated_stamps: usize,
    /// Where `associations.txt` paired the frames, the lines it left out (`None` where the
    /// stamps paired them).
    pub listed: Option<LeftOut>,
    /// Where [`Self::camera`]'s intrinsics come from.
    pub intrinsics: IntrinsicsSource,
}

/// Where a TUM-layout folder's intrinsics come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IntrinsicsSource {
    /// The folder's `intrinsics.txt`.
    File,
    /// The folder's `calibration.txt` (ETH3D's `fx fy cx cy`).
    Eth3d,
    /// A calibration given when the folder was opened (`with_calibration`).
    Given,
    /// The intrinsics TUM publishes for the sensor the folder's name names (`freiburg1`, `2`,
    /// `3`), for its 640 × 480 images.
    Published,
    /// None given: TUM's default Kinect intrinsics (fx = fy = 525 at 640 × 480) are assumed.
    Assumed,
}

impl IntrinsicsSource {
    /// Whether the intrinsics were not read from the folder or given, but taken from TUM's
    /// published 640 × 480 ones: they fit no other image size.
    pub fn is_tums(self) -> bool {
        matches!(self, Self::Published | Self::Assumed)
    }
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
    one_to_one(
        candidates.into_iter().map(|c| (c.3, c.4)),
        first,
        second.len(),
    )
}

/// Index pairs into `first` (stamps) and a second list of `second_len` entries, taken from
/// `candidates` (best first) as long as neither side is used yet; sorted by the first stamp.
fn one_to_one(
    candidates: impl IntoIterator<Item = (usize, usize)>,
    first: &[f64],
    second_len: usize,
) -> Vec<(usize, usize)> {
    let (mut used_a, mut used_b) = (vec![false; first.len()], vec![false; second_len]);
    let mut out = Vec::new();
    for (i, j) in candidates {
        if !used_a[i] && !used_b[j] {
            (used_a[i], used_b[j]) = (true, true);
            out.push((i, j));
        }
    }
    out.sort_by(|x, y| first[x.0].total_cmp(&first[y.0]));
    out
}

/// The pairs `associations.txt` gives.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Associations {
    /// (depth, colour) indices into the lists, sorted by the depth stamp.
    pub pairs: Vec<(usize, usize)>,
    /// The lines that pair no frames.
    pub left_out: LeftOut,
}

/// Lines of `associations.txt` left out, by cause.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LeftOut {
    /// Lines naming a file that neither `rgb.txt` nor `depth.txt` lists.
    pub unlisted: usize,
    /// Lines whose two stamps are more than `limit` seconds apart.
    pub far_apart: usize,
    /// The largest gap between a listed pair's stamps: see [`listed_pair_limit`].
    pub limit: f64,
    /// Lines pairing a frame that another line pairs nearer in time (each frame keeps its nearest
    /// partner, as in [`associate`]); a line repeated word for word is not counted.
    pub contested: usize,
    /// The paired lines whose stamps are not the lists' (the lists' are used).
    pub restamped: Restamped,
}

/// Lines of `associations.txt` whose stamps differ from those `rgb.txt` and `depth.txt` give their
/// files by more than [`STAMP_AGREEMENT`]: the lists were written apart from the associations
/// (re-stamped, or another capture's), and the lists' stamps are the ones used.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Restamped {
    /// How many lines.
    pub count: usize,
    /// The largest difference between a line's stamp and its list's, seconds.
    pub largest: f64,
}

/// How far a stamp in `associations.txt` may lie from its list's for the same file, seconds:
/// `associate.py` copies the lists' stamps as printed (TUM prints microseconds), so anything
/// past printing's rounding, and well under a frame interval, says the files disagree.
pub const STAMP_AGREEMENT: f64 = 1e-3;

/// The largest gap, in seconds, between the stamps of a pair that `associations.txt` lists:
/// one frame interval of the depth stream (the median gap between its stamps), and at least
/// `associate.py`'s default [`MAX_DIFFERENCE`]. A colour frame further from its depth frame than
/// that is nearer another capture than its own: its colour would not show the depth's scene.
pub fn listed_pair_limit(depth_stamps: &[f64]) -> f64 {
    let mut gaps: Vec<f64> = depth_stamps
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|g| *g > 0.0)
        .collect();
    if gaps.is_empty() {
        return MAX_DIFFERENCE;
    }
    let mid = gaps.len() / 2;
    let (_, median, _) = gaps.select_nth_unstable_by(mid, f64::total_cmp);
    median.max(MAX_DIFFERENCE)
}

/// Parses `associations.txt` (`path` names it in errors) as `associate.py` writes it and ORB-SLAM2
/// reads it: `timestamp file timestamp file` per line, one file a colour frame of `rgb` and the
/// other a depth frame of `depth` (in either order; the lists' stamps are the frames'). A frame
/// named on two lines keeps its partner nearest in time (the other line's frames stay unpaired),
/// as in [`associate`]; such lines are counted ([`LeftOut::contested`]), and so are lines whose
/// stamps are not the lists' ([`LeftOut::restamped`]). A line naming a file that neither list
/// has is left out and counted:
/// the lists say which frames the sequence has (a frame taken out of them is gone, whatever
/// `associations.txt` still says). So is a line whose stamps are further apart than
/// [`listed_pair_limit`] of the depth stamps.
pub fn parse_associations<'a>(
    text: &str,
    path: &Path,
    rgb: &'a [(f64, String)],
    depth: &'a [(f64, String)],
) -> Result<Associations, IoError> {
    let index = |list: &'a [(f64, String)]| -> std::collections::HashMap<&'a str, usize> {
        list.iter()
            .enumerate()
            .map(|(i, (_, f))| (f.as_str(), i))
            .collect()
    };
    let (by_rgb, by_depth) = (index(rgb), index(depth));
    let (mut candidates, mut unlisted) = (Vec::new(), 0);
    let mut restamped = Restamped::default();
    for (line, f) in data_lines(text) {
        if f.len() != 4 {
            return Err(IoError::line(
                path,
                line,
                format!(
                    "expected 'timestamp file timestamp file', found {} fields",
                    f.len()
                ),
            ));
        }
        let (sa, sb) = (
            number(path, line, &f, 0, "timestamp")?,
            number(path, line, &f, 2, "timestamp")?,
        );
        let (a, b) = (f[1], f[3]);
        let listed = |f: &str| by_rgb.contains_key(f) || by_depth.contains_key(f);
        let pair = match (
            by_depth.get(a),
            by_rgb.get(b),
            by_rgb.get(a),
            by_depth.get(b),
        ) {
            (Some(&d), Some(&r), _, _) => Some((d, r, sa, sb)),
            (_, _, Some(&r), Some(&d)) => Some((d, r, sb, sa)),
            _ => None,
        };
        match pair {
            Some((d, r, sd, sr)) => {
                let off = (depth[d].0 - sd).abs().max((rgb[r].0 - sr).abs());
                if off > STAMP_AGREEMENT {
                    restamped.count += 1;
                    restamped.largest = restamped.largest.max(off);
                }
                candidates.push((d, r));
            }
            None if !listed(a) || !listed(b) => unlisted += 1,
            _ => {
                return Err(IoError::line(
                    path,
                    line,
                    format!("'{a}' and '{b}' are not a frame of rgb.txt and one of depth.txt"),
                ))
            }
        }
    }
    let stamps: Vec<f64> = depth.iter().map(|d| d.0).collect();
    let limit = listed_pair_limit(&stamps);
    let gap = |&(d, r): &(usize, usize)| (depth[d].0 - rgb[r].0).abs();
    let listed = candidates.len();
    candidates.retain(|c| gap(c) <= limit);
    let far_apart = listed - candidates.len();
    candidates.sort_by(|x, y| gap(x).total_cmp(&gap(y)).then(x.cmp(y)));
    // a line repeated word for word pairs nothing new and loses nothing
    candidates.dedup();
    let distinct = candidates.len();
    let pairs = one_to_one(candidates, &stamps, rgb.len());
    Ok(Associations {
        left_out: LeftOut {
            unlisted,
            far_apart,
            limit,
            contested: distinct - pairs.len(),
            restamped,
        },
        pairs,
    })
}

/// Reads `intrinsics.txt`: `fx fy cx cy depth_scale` on one line; the image size comes from `width`,
/// `height`. A file that also gives distortion coefficients is refused here: read it with
/// [`read_calibration`], which returns them.
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
    let (camera, distortion) = parse_calibration(text, path, width, height)?;
    if !distortion.is_zero() {
        return Err(IoError::file(
            path,
            "the file gives lens distortion; read it as a calibration (parse_calibration)",
        ));
    }
    Ok(camera)
}

/// The form of a calibration file's one line of numbers.
struct NumbersLine {
    /// What the line holds, and its fields as written, for the messages.
    what: &'static str,
    fields: &'static str,
    /// The numbers' names, in order.
    names: &'static [&'static str],
    /// How many numbers the line may hold, and the same in words.
    counts: &'static [usize],
    counts_text: &'static str,
}

/// `intrinsics.txt`: `fx fy cx cy depth_scale [k1 k2 p1 p2 k3]`.
const INTRINSICS_LINE: NumbersLine = NumbersLine {
    what: "intrinsics",
    fields: "fx fy cx cy depth_scale [k1 k2 p1 p2 k3]",
    names: &[
        "fx",
        "fy",
        "cx",
        "cy",
        "depth_scale",
        "k1",
        "k2",
        "p1",
        "p2",
        "k3",
    ],
    counts: &[5, 10],
    counts_text: "5 (fx fy cx cy depth_scale) or 10 (and k1 k2 p1 p2 k3)",
};

/// ETH3D's `calibration.txt`: `fx fy cx cy`.
const ETH3D_LINE: NumbersLine = NumbersLine {
    what: "calibration",
    fields: "fx fy cx cy",
    names: &["fx", "fy", "cx", "cy"],
    counts: &[4],
    counts_text: "4 (fx fy cx cy)",
};

/// The first data line of `text` (`path` names it in errors) read as `form` says: its line
/// number and its numbers.
fn numbers_line(text: &str, path: &Path, form: &NumbersLine) -> Result<(usize, Vec<f64>), IoError> {
    let (line, f) = data_lines(text).next().ok_or_else(|| {
        let (what, fields) = (form.what, form.fields);
        IoError::file(path, format!("no {what} line (expected '{fields}')"))
    })?;
    if !form.counts.contains(&f.len()) {
        let message = format!("{} numbers; expected {}", f.len(), form.counts_text);
        return Err(IoError::line(path, line, message));
    }
    let v = (0..f.len())
        .map(|k| number(path, line, &f, k, form.names[k]))
        .collect::<Result<_, _>>()?;
    Ok((line, v))
}

/// Reads `intrinsics.txt` with optional Brown–Conrady coefficients:
/// `fx fy cx cy depth_scale [k1 k2 p1 p2 k3]` on one line (OpenCV's order).
pub fn read_calibration(
    path: &Path,
    width: usize,
    height: usize,
) -> Result<(Camera, Distortion), IoError> {
    parse_calibration(&read_text(path)?, path, width, height)
}

/// Parses the text of an intrinsics file (see [`read_calibration`]); `path` names it in errors.
pub(crate) fn parse_calibration(
    text: &str,
    path: &Path,
    width: usize,
    height: usize,
) -> Result<(Camera, Distortion), IoError> {
    let (line, v) = numbers_line(text, path, &INTRINSICS_LINE)?;
    if !usable_focal_length(v[0]) || !usable_focal_length(v[1]) || v[4] <= 0.0 {
        return Err(IoError::line(
            path,
            line,
            "focal lengths must be non-zero and depth_scale positive",
        ));
    }
    let mut c = Camera::new(v[0], v[1], v[2], v[3], width, height);
    c.depth_scale = v[4];
    let d = match v.get(5..10) {
        Some(k) => Distortion::from_array([k[0], k[1], k[2], k[3], k[4]]),
        None => Distortion::default(),
    };
    if let Some((pu, pv)) = d.fold_in(&c) {
        return Err(IoError::line(
            path,
            line,
            format!(
                "the lens distortion (k1 k2 p1 p2 k3) folds the {width}x{height} image over at \
                 pixel ({pu}, {pv}): two points would be recorded at one pixel; check the \
                 coefficients' signs, order (OpenCV's k1 k2 p1 p2 k3) and units"
            ),
        ));
    }
    Ok((c, d))
}

/// The intrinsics TUM publishes for its three sensors, chosen by the folder name, and whether
/// the name chose them (else TUM's default Kinect ones).
pub(crate) fn known_intrinsics(root: &Path) -> (Camera, IntrinsicsSource) {
    let name = root.to_string_lossy();
    let named = [
        ("freiburg1", (517.3, 516.5, 318.6, 255.3)),
        ("freiburg2", (520.9, 521.0, 325.1, 249.7)),
        ("freiburg3", (535.4, 539.2, 320.1, 247.6)),
    ];
    let (source, (fx, fy, cx, cy)) = match named.iter().find(|(n, _)| name.contains(n)) {
        Some((_, k)) => (IntrinsicsSource::Published, *k),
        None => (IntrinsicsSource::Assumed, (525.0, 525.0, 319.5, 239.5)),
    };
    (Camera::new(fx, fy, cx, cy, 640, 480), source)
}

/// The intrinsics of a TUM-layout folder whose images are `width` × `height`: its
/// `intrinsics.txt`, else its `calibration.txt` (ETH3D: `fx fy cx cy`, depth at 5000 units per
/// metre), else TUM's published ones ([`known_intrinsics`]; the image size set, not scaled).
fn folder_intrinsics(
    root: &Path,
    width: usize,
    height: usize,
) -> Result<(Camera, Distortion, IntrinsicsSource), IoError> {
    let intr = root.join("intrinsics.txt");
    if intr.exists() {
        let (c, d) = read_calibration(&intr, width, height)?;
        return Ok((c, d, IntrinsicsSource::File));
    }
    let eth = root.join("calibration.txt");
    if eth.exists() {
        let c = parse_eth3d_calibration(&read_text(&eth)?, &eth, width, height)?;
        return Ok((c, Distortion::default(), IntrinsicsSource::Eth3d));
    }
    let (known, source) = known_intrinsics(root);
    let c = Camera {
        width,
        height,
        ..known
    };
    Ok((c, Distortion::default(), source))
}

/// Parses ETH3D's `calibration.txt`: `fx fy cx cy` on one line (the depth scale is TUM's 5000
/// units per metre, as ETH3D's depth PNGs have); `path` names it in errors.
fn parse_eth3d_calibration(
    text: &str,
    path: &Path,
    width: usize,
    height: usize,
) -> Result<Camera, IoError> {
    let (line, v) = numbers_line(text, path, &ETH3D_LINE)?;
    if !usable_focal_length(v[0]) || !usable_focal_length(v[1]) {
        return Err(IoError::line(path, line, "focal lengths must be non-zero"));
    }
    Ok(Camera::new(v[0], v[1], v[2], v[3], width, height))
}

/// The frames of the lists paired as [`TumSequence::open_with`] pairs them, and whether
/// `root`'s `associations.txt` did it; an error when nothing pairs.
fn pair_frames(
    root: &Path,
    rgb: &[(f64, String)],
    depth: &[(f64, String)],
    max_difference: f64,
    pairing: Pairing,
) -> Result<(Associations, bool), IoError> {
    // ETH3D's folders call the same list `associated.txt`
    let listed = (pairing == Pairing::Listed)
        .then(|| ["associations.txt", "associated.txt"].map(|n| root.join(n)))
        .and_then(|names| names.into_iter().find(|p| p.exists()));
    let paired = if let Some(listed) = &listed {
        parse_associations(&read_text(listed)?, listed, rgb, depth)?
    } else {
        Associations {
            pairs: associate(
                &depth.iter().map(|d| d.0).collect::<Vec<_>>(),
                &rgb.iter().map(|r| r.0).collect::<Vec<_>>(),
                max_difference,
            ),
            left_out: LeftOut::default(),
        }
    };
    if paired.pairs.is_empty() {
        return Err(match listed {
            Some(listed) => IoError::file(listed, "pairs no frames"),
            None => IoError::file(
                root.join("depth.txt"),
                format!("no depth frame has a colour frame within {max_difference} s"),
            ),
        });
    }
    Ok((paired, listed.is_some()))
}

impl TumSequence {
    /// Opens a sequence folder: reads the lists, associates colour and depth (as
    /// `associations.txt` lists them where the folder has one), the ground truth and the
    /// intrinsics (the size is taken from the first depth image).
    pub fn open(root: impl AsRef<Path>) -> Result<Self, IoError> {
        Self::open_with(root, MAX_DIFFERENCE, Pairing::Listed)
    }

    /// As [`Self::open`]: with [`Pairing::Listed`], frames are paired as the folder's
    /// `associations.txt` lists them where it has one; otherwise (or without the file) a depth
    /// and a colour frame are paired when their stamps are less than `max_difference` seconds
    /// apart (`associate.py --max_difference`).
    pub(crate) fn open_with(
        root: impl AsRef<Path>,
        max_difference: f64,
        pairing: Pairing,
    ) -> Result<Self, IoError> {
        let root = root.as_ref().to_path_buf();
        let rgb = read_list(&root.join("rgb.txt"))?;
        let depth = read_list(&root.join("depth.txt"))?;
        let (Associations { pairs, left_out }, listed) =
            pair_frames(&root, &rgb, &depth, max_difference, pairing)?;
        let mut frames: Vec<FrameFiles> = pairs
            .iter()
            .map(|&(d, r)| FrameFiles {
                timestamp: depth[d].0,
                color_timestamp: rgb[r].0,
                depth: root.join(&depth[d].1),
                rgb: root.join(&rgb[r].1),
            })
            .collect();
        // two depth frames at one instant would give the trajectory two poses for one stamp
        let paired = frames.len();
        frames.dedup_by(|later, first| later.timestamp == first.timestamp);
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
        let (camera, distortion, intrinsics) = folder_intrinsics(&root, first.width, first.height)?;
        Ok(Self {
            root,
            camera,
            unpaired_depth: depth.len() - paired,
            repeated_stamps: paired - frames.len(),
            listed: listed.then_some(left_out),
            frames,
            groundtruth,
            undistorter: undistorter_for(&camera, &distortion),
            intrinsics,
        })
    }

    /// The sequence read through another calibration (for example a [`TumSensor`]'s published
    /// one): its frames are undistorted with `distortion` and delivered with `camera`'s
    /// intrinsics; the depth scale stays the sequence's. Refused when the image sizes differ.
    ///
    /// [`TumSensor`]: crate::distortion::TumSensor
    pub(crate) fn with_calibration(
        mut self,
        camera: Camera,
        distortion: &Distortion,
    ) -> Result<Self, IoError> {
        if (camera.width, camera.height) != (self.camera.width, self.camera.height) {
            return Err(IoError::file(
                &self.root,
                format!(
                    "the calibration is for {}x{} images, the sequence's are {}x{}",
                    camera.width, camera.height, self.camera.width, self.camera.height
                ),
            ));
        }
        self.camera = Camera {
            depth_scale: self.camera.depth_scale,
            ..camera
        };
        self.undistorter = undistorter_for(&self.camera, distortion);
        self.intrinsics = IntrinsicsSource::Given;
        Ok(self)
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
        check_size(
            i,
            &self.camera,
            "depth",
            (depth.width, depth.height),
            &f.depth,
        )?;
        check_size(
            i,
            &self.camera,
            "colour",
            (color.width, color.height),
            &f.rgb,
        )?;
        Ok(undistorted(
            RgbdFrame {
                index: i,
                timestamp: f.timestamp,
                color_timestamp: f.color_timestamp,
                depth,
                color: Some(color),
            },
            self.undistorter.as_ref(),
        ))
    }
}

/// An error naming frame `i`'s file when its image is not the sequence's size.
pub(crate) fn check_size(
    i: usize,
    camera: &Camera,
    what: &str,
    (w, h): (usize, usize),
    path: &Path,
) -> Result<(), IoError> {
    if (w, h) == (camera.width, camera.height) {
        return Ok(());
    }
    Err(IoError::file(
        path,
        format!(
            "frame {i}: {what} is {w}x{h}, the sequence is {}x{}",
            camera.width, camera.height
        ),
    ))
}

/// The remap for a camera whose calibration has lens distortion, `None` without.
pub(crate) fn undistorter_for(camera: &Camera, distortion: &Distortion) -> Option<Undistorter> {
    (!distortion.is_zero()).then(|| Undistorter::new(camera, distortion))
}

/// `frame` with both images undistorted by `undistorter`, if any.
pub(crate) fn undistorted(mut frame: RgbdFrame, undistorter: Option<&Undistorter>) -> RgbdFrame {
    if let Some(u) = undistorter {
        let mut depth = Image::new(0, 0);
        u.depth(&frame.depth, &mut depth);
        frame.depth = depth;
        if let Some(color) = &frame.color {
            let mut out = ColorImage::new(0, 0);
            u.color(color, &mut out);
            frame.color = Some(out);
        }
    }
    frame
}

#[cfg(test)]
mod tests {
    use super::*;

    fn list(entries: &[(f64, &str)]) -> Vec<(f64, String)> {
        entries.iter().map(|&(t, f)| (t, f.to_string())).collect()
    }

    #[test]
    fn listed_associations_pair_frames_the_stamps_would_not() {
        let p = Path::new("associations.txt");
        let rgb = list(&[
            (0.025, "rgb/a.png"),
            (0.058, "rgb/b.png"),
            (0.091, "rgb/c.png"),
        ]);
        let depth = list(&[
            (0.0, "depth/a.png"),
            (0.033, "depth/b.png"),
            (0.066, "depth/c.png"),
        ]);
        // colour 25 ms after its depth: associate.py's 0.02 s pairs none of them with its own
        // capture (b's colour would go with c's depth), the listed pairs do, in either column
        // order, comments and blank lines aside
        let text = "# rgb depth\n0.025 rgb/a.png 0.0 depth/a.png\n\n\
                    0.033 depth/b.png 0.058 rgb/b.png\n0.091 rgb/c.png 0.066 depth/c.png\n";
        let pairs = parse_associations(text, p, &rgb, &depth).unwrap().pairs;
        assert_eq!(pairs, [(0, 0), (1, 1), (2, 2)]);
        let stamps = |l: &[(f64, String)]| l.iter().map(|e| e.0).collect::<Vec<_>>();
        assert_ne!(
            associate(&stamps(&depth), &stamps(&rgb), MAX_DIFFERENCE),
            pairs
        );
        // a frame named twice keeps its nearest partner; the other line's frames stay unpaired
        let twice = "0.025 rgb/a.png 0.0 depth/a.png\n0.058 rgb/b.png 0.0 depth/a.png\n";
        assert_eq!(
            parse_associations(twice, p, &rgb, &depth).unwrap().pairs,
            [(0, 0)]
        );
        // (rgb/a is 8 ms from depth/b, 25 ms from depth/a: the line left is counted; a line
        // repeated word for word loses nothing, and is not)
        let contested = "0.025 rgb/a.png 0.0 depth/a.png\n0.025 rgb/a.png 0.033 depth/b.png\n";
        let a = parse_associations(contested, p, &rgb, &depth).unwrap();
        assert_eq!((a.pairs, a.left_out.contested), (vec![(1, 0)], 1));
        let repeated = "0.025 rgb/a.png 0.0 depth/a.png\n0.025 rgb/a.png 0.0 depth/a.png\n";
        let a = parse_associations(repeated, p, &rgb, &depth).unwrap();
        assert_eq!((a.pairs, a.left_out.contested), (vec![(0, 0)], 0));
        assert_eq!(a.left_out.restamped, Restamped::default());
        // stamps that are not the lists' are counted, with the largest difference; the lists'
        // stamps pair the frames (rgb/b's line stamps it 0.5 s late, depth/c's 1 µs off)
        let restamped = "0.025 rgb/a.png 0.0 depth/a.png\n0.558 rgb/b.png 0.033 depth/b.png\n\
                         0.091 rgb/c.png 0.066001 depth/c.png\n";
        let a = parse_associations(restamped, p, &rgb, &depth).unwrap();
        assert_eq!(
            (a.pairs, a.left_out.far_apart),
            (vec![(0, 0), (1, 1), (2, 2)], 0)
        );
        assert_eq!(a.left_out.restamped.count, 1);
        assert!((a.left_out.restamped.largest - 0.5).abs() < 1e-9);
        // a frame taken out of the lists is gone, though associations.txt still names it
        let stale = "0.025 rgb/a.png 0.0 depth/a.png\n0.058 rgb/b.png 0.033 depth/gone.png\n";
        let a = parse_associations(stale, p, &rgb, &depth).unwrap();
        assert_eq!((a.pairs, a.left_out.unlisted), (vec![(0, 0)], 1));
        // a colour frame more than a frame interval (33 ms) from its depth frame is nearer
        // another capture: the line is left out and counted, not paired
        let far = "0.025 rgb/a.png 0.0 depth/a.png\n0.091 rgb/c.png 0.033 depth/b.png\n";
        let a = parse_associations(far, p, &rgb, &depth).unwrap();
        assert_eq!((a.pairs, a.left_out.far_apart), (vec![(0, 0)], 1));
        assert!((a.left_out.limit - 0.033).abs() < 1e-12);
    }

    #[test]
    fn a_bad_associations_line_is_named() {
        let p = Path::new("associations.txt");
        let rgb = list(&[(0.0, "rgb/a.png")]);
        let depth = list(&[(0.0, "depth/a.png")]);
        for (text, line, says) in [
            ("0.0 rgb/a.png 0.0\n", 1, "found 3 fields"),
            ("# header\n0.0 rgb/a.png x depth/a.png\n", 2, "timestamp"),
            (
                "0.0 rgb/a.png 0.0 rgb/a.png\n",
                1,
                "not a frame of rgb.txt and one of depth.txt",
            ),
        ] {
            let e = parse_associations(text, p, &rgb, &depth)
                .unwrap_err()
                .to_string();
            assert!(e.contains(&format!("associations.txt:{line}:")), "{e}");
            assert!(e.contains(says), "{e}");
        }
    }

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

    #[test]
    fn calibration_files_carry_distortion_or_are_refused() {
        use crate::distortion::TumSensor;
        let p = Path::new("intrinsics.txt");
        let fr1 = "517.3 516.5 318.6 255.3 5000 0.2624 -0.9531 -0.0054 0.0026 1.1633\n";
        let (c, d) = parse_calibration(fr1, p, 640, 480).unwrap();
        assert_eq!(d, TumSensor::Freiburg1.calibration().1);
        assert_eq!((c.fx, c.cy, c.depth_scale), (517.3, 255.3, 5000.0));
        let (_, none) = parse_calibration("525 525 319.5 239.5 5000", p, 640, 480).unwrap();
        assert!(none.is_zero());
        let e = parse_calibration("525 525 319.5 239.5 5000 0.1 0.2", p, 640, 480)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("intrinsics.txt:1") && e.contains("7 numbers"),
            "{e}"
        );
        // the camera-only reader does not drop coefficients silently
        assert!(parse_intrinsics(fr1, p, 640, 480).is_err());
        // k1 of the wrong sign and scale folds the image over: refused, naming a pixel
        let folded = "517.3 516.5 318.6 255.3 5000 -5 0 0 0 0\n";
        let e = parse_calibration(folded, p, 640, 480)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("intrinsics.txt:1") && e.contains("folds the 640x480 image over at pixel ("),
            "{e}"
        );
    }

    /// A folder whose lists and calibration a Windows editor saved: each text file begins with
    /// a byte-order mark (which hid the first line's `#`, or made its stamp not a number: the
    /// folder was refused) and ends its lines in CRLF. It is the same sequence.
    #[test]
    fn text_files_with_a_byte_order_mark_and_crlf_read_as_without() {
        use super::super::images::{write_color, write_depth};
        let write = |dir: &Path, mark: &str, end: &str| {
            for sub in ["rgb", "depth"] {
                std::fs::create_dir_all(dir.join(sub)).unwrap();
            }
            for k in 0..2 {
                let depth = Image::filled(64, 48, 5000u16);
                write_depth(dir.join(format!("depth/{k}.png")), &depth).unwrap();
                let color = ColorImage::filled(64, 48, [90, 120, 200]);
                write_color(dir.join(format!("rgb/{k}.png")), &color).unwrap();
            }
            let files = [
                ("rgb.txt", "# colour\n0.004 rgb/0.png\n0.037 rgb/1.png\n"),
                ("depth.txt", "0.000 depth/0.png\n0.033 depth/1.png\n"),
                ("associations.txt", "0.004 rgb/0.png 0.000 depth/0.png\n"),
                ("groundtruth.txt", "0.0 1 2 3 0 0 0 1\n0.1 1 2 4 0 0 0 1\n"),
                ("intrinsics.txt", "52.5 52.5 31.5 23.5 5000\n"),
            ];
            for (name, text) in files {
                let text = format!("{mark}{}", text.replace('\n', end));
                std::fs::write(dir.join(name), text).unwrap();
            }
        };
        let root = std::env::temp_dir().join(format!("dynamap-bom-{}", std::process::id()));
        let (plain, marked) = (root.join("plain"), root.join("marked"));
        write(&plain, "", "\n");
        write(&marked, "\u{feff}", "\r\n");
        let (a, b) = (
            TumSequence::open(&plain).unwrap(),
            TumSequence::open(&marked).unwrap(),
        );
        std::fs::remove_dir_all(&root).unwrap();
        assert_eq!(b.camera, a.camera);
        assert_eq!(b.frames.len(), 1);
        assert_eq!(b.frames[0].timestamp, a.frames[0].timestamp);
        assert_eq!(b.frames[0].depth.file_name(), a.frames[0].depth.file_name());
        let gt = |s: &TumSequence| s.groundtruth.as_ref().map(|t| t.poses.len());
        assert_eq!((gt(&a), gt(&b)), (Some(2), Some(2)));
    }

    /// `dir` with `rgb/` and `depth/` holding one plain 8 × 6 image each, listed as
    /// [`one_image_each`] lists them.
    fn plain_8x6_frames(dir: &Path) {
        std::fs::create_dir_all(dir.join("rgb")).unwrap();
        std::fs::create_dir_all(dir.join("depth")).unwrap();
        one_image_each(
            dir,
            &Image::filled(8, 6, 5000),
            &ColorImage::filled(8, 6, [1, 2, 3]),
        );
    }

    /// Writes `depth` and `color` into `dir` (whose `rgb` and `depth` folders exist), listed as
    /// depth at 0 and 0.1 s (the same image) and colour at 0.004 s.
    fn one_image_each(dir: &Path, depth: &Image<u16>, color: &ColorImage) {
        use super::super::images::{write_color, write_depth};
        write_depth(dir.join("depth/0.png"), depth).unwrap();
        write_color(dir.join("rgb/0.png"), color).unwrap();
        let depth_list = "0.000 depth/0.png\n0.100 depth/0.png\n";
        std::fs::write(dir.join("depth.txt"), depth_list).unwrap();
        std::fs::write(dir.join("rgb.txt"), "0.004 rgb/0.png\n").unwrap();
    }

    /// Two depth frames listed at one stamp would give the trajectory two poses for it: the
    /// first is read, the other counted. Frames at distinct stamps are all read.
    #[test]
    fn a_depth_stamp_listed_twice_is_read_once_and_counted() {
        let dir = std::env::temp_dir().join(format!("dynamap-twice-{}", std::process::id()));
        plain_8x6_frames(&dir);
        std::fs::write(dir.join("intrinsics.txt"), "7 7 3.5 2.5 5000\n").unwrap();
        let depth = "0.000 depth/0.png\n0.100 depth/0.png\n0.100 depth/0.png\n0.200 depth/0.png\n";
        std::fs::write(dir.join("depth.txt"), depth).unwrap();
        let rgb = "0.004 rgb/0.png\n0.104 rgb/0.png\n0.105 rgb/0.png\n0.204 rgb/0.png\n";
        std::fs::write(dir.join("rgb.txt"), rgb).unwrap();
        let seq = TumSequence::open(&dir).unwrap();
        let stamps: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
        assert_eq!(stamps, [0.0, 0.1, 0.2]);
        assert_eq!((seq.repeated_stamps, seq.unpaired_depth), (1, 0));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_sequence_with_distortion_delivers_undistorted_frames() {
        let dir = std::env::temp_dir().join(format!("dynamap-undistort-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("rgb")).unwrap();
        std::fs::create_dir_all(dir.join("depth")).unwrap();
        let (w, h) = (64, 48);
        // depth encodes its own pixel: 100 u + v
        let depth = Image::from_vec(
            w,
            h,
            (0..w * h).map(|k| (100 * (k % w) + k / w) as u16).collect(),
        )
        .unwrap();
        // a second depth frame with no colour near it is left out, and counted
        one_image_each(&dir, &depth, &ColorImage::filled(w, h, [90, 120, 200]));
        std::fs::write(
            dir.join("intrinsics.txt"),
            "52.5 52.5 31.5 23.5 5000 -0.25 0.05 0.001 0.0 0.0\n",
        )
        .unwrap();
        let seq = TumSequence::open(&dir).unwrap();
        assert_eq!((seq.len(), seq.unpaired_depth), (1, 1));
        let u = seq.undistorter.as_ref().expect("a remap");
        let frame = seq.load(0).unwrap();
        // every ideal pixel holds the recorded pixel nearest its source point
        for (x, y) in [(5, 5), (31, 23), (60, 40), (10, 44)] {
            let Some((us, vs)) = u.source_of(x, y) else {
                continue;
            };
            let code = frame.depth.at(x, y) as f32;
            let (ru, rv) = ((code / 100.0).floor(), code % 100.0);
            assert!(
                (ru - us).abs() <= 0.5 + 1e-4 && (rv - vs).abs() <= 0.5 + 1e-4,
                "({x}, {y})"
            );
        }
        // barrel distortion pulls the corners in: the ideal corner has no recorded source
        assert!(u.source_of(0, 0).is_none() || u.source_of(0, 0) != Some((0.0, 0.0)));
        assert_eq!(frame.color.unwrap().at(31, 23), [90, 120, 200]);
        // an associations.txt pairs what it lists, even beyond the stamps' limit, unless the
        // stamps are asked for
        std::fs::write(
            dir.join("associations.txt"),
            "0.004 rgb/0.png 0.100 depth/0.png\n",
        )
        .unwrap();
        let listed = TumSequence::open(&dir).unwrap();
        assert!(listed.listed.is_some());
        assert_eq!((listed.len(), listed.unpaired_depth), (1, 1));
        assert_eq!(
            (listed.frames[0].timestamp, listed.frames[0].color_timestamp),
            (0.1, 0.004)
        );
        let by_stamps = TumSequence::open_with(&dir, MAX_DIFFERENCE, Pairing::Stamps).unwrap();
        assert!(by_stamps.listed.is_none());
        assert_eq!(by_stamps.frames[0].timestamp, 0.0);
        std::fs::remove_file(dir.join("associations.txt")).unwrap();
        // a stricter association than the stamps allow finds no pair, and says so
        let e = TumSequence::open_with(&dir, 0.001, Pairing::Stamps)
            .unwrap_err()
            .to_string();
        assert!(e.contains("within 0.001 s"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// ETH3D's layout (`calibration.txt`, `associated.txt`) reads with its intrinsics and
    /// pairing, a bad calibration line is named, and without any file the intrinsics are TUM's,
    /// marked as such (published for a freiburg name, else assumed).
    #[test]
    fn eth3d_calibration_and_associated_list_are_read_and_tums_are_marked() {
        let base = std::env::temp_dir().join(format!("dynamap-eth3d-{}", std::process::id()));
        let dir = base.join("rgbd_dataset_freiburg2_desk");
        // the stamps would pair colour with the depth at 0; the list pairs it with the one at 0.1
        plain_8x6_frames(&dir);
        std::fs::write(
            dir.join("associated.txt"),
            "0.004 rgb/0.png 0.100 depth/0.png\n",
        )
        .unwrap();
        let published = TumSequence::open(&dir).unwrap();
        assert_eq!(published.intrinsics, IntrinsicsSource::Published);
        assert!(published.intrinsics.is_tums() && published.listed.is_some());
        assert_eq!(published.frames[0].timestamp, 0.1);
        assert_eq!((published.camera.fx, published.camera.width), (520.9, 8));
        std::fs::write(
            dir.join("calibration.txt"),
            "# fx fy cx cy\n7 7.5 3.5 2.5\n",
        )
        .unwrap();
        let eth = TumSequence::open(&dir).unwrap();
        assert_eq!(eth.intrinsics, IntrinsicsSource::Eth3d);
        let c = eth.camera;
        assert_eq!(
            (c.fx, c.fy, c.cx, c.cy, c.depth_scale),
            (7.0, 7.5, 3.5, 2.5, 5000.0)
        );
        assert_eq!(eth.load(0).unwrap().depth.at(3, 3), 5000);
        std::fs::write(dir.join("calibration.txt"), "7 7.5 3.5\n").unwrap();
        let e = TumSequence::open(&dir).unwrap_err().to_string();
        assert!(
            e.contains("calibration.txt:1") && e.contains("expected 4"),
            "{e}"
        );
        // intrinsics.txt wins over calibration.txt
        std::fs::write(dir.join("intrinsics.txt"), "9 9 4 3 1000\n").unwrap();
        let file = TumSequence::open(&dir).unwrap();
        assert_eq!(
            (file.intrinsics, file.camera.fx),
            (IntrinsicsSource::File, 9.0)
        );
        // no file, no sensor in the name: assumed
        let plain = base.join("desk");
        std::fs::rename(&dir, &plain).unwrap();
        for f in ["intrinsics.txt", "calibration.txt"] {
            std::fs::remove_file(plain.join(f)).unwrap();
        }
        let assumed = TumSequence::open(&plain).unwrap();
        assert_eq!(
            (assumed.intrinsics, assumed.camera.fx),
            (IntrinsicsSource::Assumed, 525.0)
        );
        std::fs::remove_dir_all(&base).unwrap();
    }

    proptest::proptest! {
        #[test]
        fn association_respects_the_maximum_difference(
            a in proptest::collection::vec(0.0f64..2.0, 0..40),
            b in proptest::collection::vec(0.0f64..2.0, 0..40),
            max in 0.0f64..0.05,
        ) {
            let pairs = associate(&a, &b, max);
            let (mut used_a, mut used_b) = (vec![false; a.len()], vec![false; b.len()]);
            for &(i, j) in &pairs {
                proptest::prop_assert!((a[i] - b[j]).abs() < max, "{} and {} paired", a[i], b[j]);
                proptest::prop_assert!(!used_a[i] && !used_b[j], "a frame used twice");
                used_a[i] = true;
                used_b[j] = true;
            }
            // maximal: no two frames left unpaired are within the limit of each other
            for (i, &x) in a.iter().enumerate().filter(|&(i, _)| !used_a[i]) {
                for (j, &y) in b.iter().enumerate().filter(|&(j, _)| !used_b[j]) {
                    proptest::prop_assert!((x - y).abs() >= max, "{i} and {j} left apart");
                }
            }
        }
    }
}
