//! One interface over the RGB-D sequences on disk, told apart by their files:
//! - a TUM RGB-D folder (`rgb.txt`, `depth.txt`, optional `groundtruth.txt` and
//!   `intrinsics.txt`), which is also what `generate` writes;
//! - an ICL-NUIM folder (`pose.txt`, `color/`, `depth/`, frames numbered from 1);
//! - a plain folder of numbered colour and depth frames (Open3D's layout, [`FolderSequence`]).

use super::folder::FolderSequence;
use super::iclnuim::IclNuimSequence;
use super::trajectory::Trajectory;
use super::tum::{LeftOut, Pairing, RgbdFrame, TumSequence, MAX_DIFFERENCE};
use super::IoError;
use crate::camera::Camera;
use crate::distortion::Distortion;
use std::path::{Path, PathBuf};

/// How [`Sequence::open`] reads a folder.
#[derive(Clone, Debug, PartialEq)]
pub struct OpenOptions {
    /// TUM: the largest stamp difference at which a depth and a colour frame are paired,
    /// seconds (default 0.02, `associate.py`'s), where they are paired by their stamps.
    pub max_difference: f64,
    /// TUM: whether a folder's `associations.txt` pairs its frames (the default) or their
    /// stamps do.
    pub pairing: Pairing,
    /// TUM: a calibration (intrinsics and lens distortion) replacing the folder's own.
    pub calibration: Option<(Camera, Distortion)>,
    /// Plain folder: depth units per metre when it has no `intrinsics.txt` (default: its own).
    pub depth_scale: Option<f64>,
}

impl Default for OpenOptions {
    fn default() -> Self {
        Self {
            max_difference: MAX_DIFFERENCE,
            pairing: Pairing::default(),
            calibration: None,
            depth_scale: None,
        }
    }
}

/// An RGB-D sequence of any of the layouts above.
#[derive(Clone, Debug)]
pub enum Sequence {
    /// A TUM RGB-D folder.
    Tum(TumSequence),
    /// An ICL-NUIM folder, with its poses as a trajectory (30 Hz stamps).
    IclNuim(IclNuimSequence, Trajectory),
    /// A plain folder of frames.
    Folder(FolderSequence),
}

/// What [`Sequence::open`] takes, for the message when a folder is none of them.
const LAYOUTS: &str = "a sequence is a folder in TUM's layout (rgb.txt, depth.txt), ICL-NUIM's \
    (pose.txt, depth/, color/) or a plain one (depth/ and color/ with intrinsics.txt or an \
    Open3D camera_*.json)";

impl Sequence {
    /// Opens `root`, telling its layout by its files; a calibration is refused for a layout other
    /// than TUM's.
    pub fn open(root: impl AsRef<Path>, options: &OpenOptions) -> Result<Self, IoError> {
        let root = root.as_ref();
        if !root.is_dir() {
            let what = if root.exists() {
                "is not a folder"
            } else {
                "does not exist"
            };
            return Err(IoError::file(root, format!("{what}: {LAYOUTS}")));
        }
        if root.join("rgb.txt").exists() || root.join("depth.txt").exists() {
            let seq = TumSequence::open_with(root, options.max_difference, options.pairing)?;
            return Ok(Self::Tum(match &options.calibration {
                Some((camera, distortion)) => seq.with_calibration(*camera, distortion)?,
                None => seq,
            }));
        }
        if options.calibration.is_some() {
            return Err(IoError::file(
                root,
                "a calibration applies to TUM-layout folders (rgb.txt, depth.txt)",
            ));
        }
        if root.join("pose.txt").exists() {
            let seq = IclNuimSequence::open(root)?;
            let poses = seq.poses.clone();
            let stamps = (0..poses.len()).map(|i| i as f64 / 30.0).collect();
            return Ok(Self::IclNuim(seq, Trajectory { stamps, poses }));
        }
        if !root.join("depth").is_dir() {
            return Err(IoError::file(
                root,
                format!("no sequence layout: {LAYOUTS}"),
            ));
        }
        Ok(Self::Folder(FolderSequence::open(
            root,
            options.depth_scale,
        )?))
    }

    /// The layout's name: "tum", "icl-nuim" or "folder".
    pub fn format(&self) -> &'static str {
        match self {
            Self::Tum(_) => "tum",
            Self::IclNuim(..) => "icl-nuim",
            Self::Folder(_) => "folder",
        }
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        match self {
            Self::Tum(s) => s.len(),
            Self::IclNuim(s, _) => s.len(),
            Self::Folder(s) => s.len(),
        }
    }

    /// True when the sequence has no frame.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Loads frame `i`; an error names the file and the frame.
    pub fn load(&self, i: usize) -> Result<RgbdFrame, IoError> {
        match self {
            Self::Tum(s) => s.load(i),
            Self::IclNuim(s, _) => s.load(i),
            Self::Folder(s) => s.load(i),
        }
    }

    /// The intrinsics of the frames [`Self::load`] delivers.
    pub fn camera(&self) -> &Camera {
        match self {
            Self::Tum(s) => &s.camera,
            Self::IclNuim(s, _) => &s.camera,
            Self::Folder(s) => &s.camera,
        }
    }

    /// Where a TUM folder's intrinsics come from (`None` for the other layouts, whose folders
    /// give theirs).
    pub fn intrinsics_source(&self) -> Option<super::tum::IntrinsicsSource> {
        match self {
            Self::Tum(s) => Some(s.intrinsics),
            _ => None,
        }
    }

    /// The intrinsics, to be set where the folder does not give them.
    pub fn camera_mut(&mut self) -> &mut Camera {
        match self {
            Self::Tum(s) => &mut s.camera,
            Self::IclNuim(s, _) => &mut s.camera,
            Self::Folder(s) => &mut s.camera,
        }
    }

    /// The ground truth, when the folder has one.
    pub fn groundtruth(&self) -> Option<&Trajectory> {
        match self {
            Self::Tum(s) => s.groundtruth.as_ref(),
            Self::IclNuim(_, t) => Some(t),
            Self::Folder(_) => None,
        }
    }

    /// The depth image of frame `i` (a file name that per-frame side files, such as masks, are
    /// named after); `None` past the last frame.
    pub fn depth_path(&self, i: usize) -> Option<PathBuf> {
        match self {
            Self::Tum(s) => s.frames.get(i).map(|f| f.depth.clone()),
            Self::IclNuim(s, _) => {
                (i < s.len()).then(|| s.root.join("depth").join(format!("{}.png", i + 1)))
            }
            Self::Folder(s) => s.frames.get(i).map(|f| f.0.clone()),
        }
    }

    /// Where a TUM folder's `associations.txt` paired its frames, the lines it left out;
    /// `None` where their stamps paired them, and in the other layouts.
    pub fn listed_pairing(&self) -> Option<LeftOut> {
        match self {
            Self::Tum(s) => s.listed,
            Self::IclNuim(..) | Self::Folder(_) => None,
        }
    }

    /// Depth frames the layout lists but that are not delivered: in the TUM layout those
    /// without a colour frame (in `associations.txt`, or within the stamp limit
    /// [`OpenOptions::max_difference`]); 0 in the others.
    pub fn unpaired_depth(&self) -> usize {
        match self {
            Self::Tum(s) => s.unpaired_depth,
            Self::IclNuim(..) | Self::Folder(_) => 0,
        }
    }

    /// TUM: paired frames left out because an earlier frame has their depth stamp
    /// ([`TumSequence::repeated_stamps`]); 0 for the other layouts, whose frames are numbered.
    pub fn repeated_stamps(&self) -> usize {
        match self {
            Self::Tum(s) => s.repeated_stamps,
            Self::IclNuim(..) | Self::Folder(_) => 0,
        }
    }

    /// The first frame's stamp, seconds (0 where the layout has no stamps).
    pub fn first_stamp(&self) -> f64 {
        match self {
            Self::Tum(s) => s.frames.first().map_or(0.0, |f| f.timestamp),
            Self::IclNuim(..) | Self::Folder(_) => 0.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::distortion::TumSensor;
    use crate::image::Image;

    fn write_frames(dir: &Path, color: &str, depth: &str, names: &[&str]) {
        std::fs::create_dir_all(dir.join(color)).unwrap();
        std::fs::create_dir_all(dir.join(depth)).unwrap();
        for name in names {
            let d: Image<u16> = Image {
                width: 4,
                height: 3,
                data: vec![5000; 12],
            };
            crate::io::images::write_depth(dir.join(depth).join(name), &d).unwrap();
            let c = Image {
                width: 4,
                height: 3,
                data: vec![[10u8, 20, 30]; 12],
            };
            crate::io::images::write_color(dir.join(color).join(name), &c).unwrap();
        }
    }

    #[test]
    fn each_layout_is_recognised_and_read_and_a_calibration_is_refused_off_tum() {
        let root = std::env::temp_dir().join(format!("dynamap-sequence-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        // TUM
        let tum = root.join("tum");
        write_frames(&tum, "rgb", "depth", &["0.000000.png", "0.033333.png"]);
        let list = |dir: &str| {
            format!("# {dir}\n0.000000 {dir}/0.000000.png\n0.033333 {dir}/0.033333.png\n")
        };
        std::fs::write(tum.join("rgb.txt"), list("rgb")).unwrap();
        std::fs::write(tum.join("depth.txt"), list("depth")).unwrap();
        std::fs::write(
            tum.join("groundtruth.txt"),
            "0.0 0 0 0 0 0 0 1\n0.0333 0.1 0 0 0 0 0 1\n",
        )
        .unwrap();
        // ICL-NUIM
        let icl = root.join("icl");
        write_frames(&icl, "color", "depth", &["1.png", "2.png", "3.png"]);
        std::fs::write(
            icl.join("pose.txt"),
            "0 0 0 0 0 0 1\n0 0 0.1 0 0 0 1\n0 0 0.2 0 0 0 1\n",
        )
        .unwrap();
        // plain folder
        let plain = root.join("plain");
        write_frames(&plain, "color", "depth", &["000000.png"]);
        std::fs::write(plain.join("intrinsics.txt"), "2 2 1.5 1 5000\n").unwrap();
        let open = |p: &Path| Sequence::open(p, &OpenOptions::default()).unwrap();
        let (t, i, f) = (open(&tum), open(&icl), open(&plain));
        assert_eq!((t.format(), t.len()), ("tum", 2));
        assert_eq!((i.format(), i.len()), ("icl-nuim", 3));
        assert_eq!((f.format(), f.len()), ("folder", 1));
        assert_eq!(t.groundtruth().map(|g| g.len()), Some(2));
        assert_eq!(i.groundtruth().map(|g| g.poses[2].translation.z), Some(0.2));
        assert!(f.groundtruth().is_none());
        // each frame's depth file, as masks and other per-frame files are named after it
        assert_eq!(t.depth_path(1), Some(tum.join("depth/0.033333.png")));
        assert_eq!(i.depth_path(2), Some(icl.join("depth/3.png")));
        assert_eq!(f.depth_path(0), Some(plain.join("depth/000000.png")));
        for s in [&t, &i, &f] {
            assert!(s.depth_path(s.len()).is_none());
            assert_eq!(s.load(0).unwrap().depth.width, 4);
            assert!(
                s.load(s.len()).is_err(),
                "{}: a frame past the end",
                s.format()
            );
        }
        let calibrated = OpenOptions {
            calibration: Some(TumSensor::Freiburg1.calibration()),
            ..OpenOptions::default()
        };
        let err = Sequence::open(&plain, &calibrated).unwrap_err();
        assert!(err.to_string().contains("TUM-layout"), "{err}");
        // fr1's calibration is for 640x480 frames, these are 4x3
        assert!(Sequence::open(&tum, &calibrated).is_err());
        // a file, a missing path and a folder of no layout are named as such, with the layouts
        let file = tum.join("rgb.txt");
        let (missing, bare) = (root.join("missing"), root.join("bare"));
        std::fs::create_dir_all(bare.join("color")).unwrap();
        for (path, says) in [
            (&file, "is not a folder"),
            (&missing, "does not exist"),
            (&bare, "no sequence layout"),
        ] {
            let e = Sequence::open(path, &OpenOptions::default()).unwrap_err();
            let e = e.to_string();
            assert!(e.contains(says) && e.contains("rgb.txt, depth.txt"), "{e}");
        }
        std::fs::remove_dir_all(&root).unwrap();
    }
}
