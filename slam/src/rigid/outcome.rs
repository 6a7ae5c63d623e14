//! What happened to a frame, as types: [`FrameOutcome`] says whether it was fused and how its
//! pose was found, [`TrackFailure`] why a frame was not tracked.

use crate::tsdf::TsdfError;

/// Why a frame was not tracked (and so not fused).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TrackFailure {
    /// The frame's images are not the camera's size.
    #[error("image size {got_width}x{got_height} does not match the camera's {width}x{height}")]
    ImageSize {
        /// The frame's size.
        got_width: usize,
        /// The frame's size.
        got_height: usize,
        /// The camera's size.
        width: usize,
        /// The camera's size.
        height: usize,
    },
    /// The first frames have too little depth in the fusion range to start the map.
    #[error(
        "only {valid} depth pixels within the fusion range (0, {max_depth} m] to start the map"
    )]
    TooLittleDepthToStart {
        /// Pixels with depth in range.
        valid: usize,
        /// The fusion range's far end, metres.
        max_depth: f32,
    },
    /// The frame has almost no depth to track on: fewer points with a normal on the pyramid's
    /// coarsest level than a pose has degrees of freedom (a blank frame, or a view beyond the
    /// sensor's range).
    #[error(
        "no depth to track on: {points} points with a normal on the coarsest level (a blank frame, or a view beyond the sensor's range?)"
    )]
    NoDepth {
        /// Points with a normal on the coarsest level.
        points: usize,
    },
    /// Geometry and texture leave motions that no start pose can fix (a plain wall).
    #[error(
        "degenerate: geometry conditioning {conditioning:.1e} and texture {texture:.2} per radian (a plain wall?)"
    )]
    Degenerate {
        /// λ_min / λ_max of the depth-scaled point-to-plane covariance.
        conditioning: f64,
        /// RMS intensity gradient, intensity per radian of view.
        texture: f64,
    },
    /// No live point found a model point (blank depth, or a view the model has not seen).
    #[error("no associations with the model (blank depth, or a view the model has not seen)")]
    NoAssociations,
    /// The normal equations of the data are singular at the result (degenerate geometry).
    #[error("singular system (degenerate geometry)")]
    Singular,
    /// Too few of the valid pixels are inliers at the finest level.
    #[error("too few inliers: {inliers} of {valid_pixels} valid pixels")]
    TooFewInliers {
        /// Inlier associations.
        inliers: usize,
        /// Valid live pixels on the tracking grid.
        valid_pixels: usize,
    },
    /// The motion from the start pose is larger than a frame interval allows.
    #[error("implausible motion: {metres:.3} m, {degrees:.1}°")]
    ImplausibleMotion {
        /// Translation from the start, metres.
        metres: f64,
        /// Rotation from the start, degrees.
        degrees: f64,
    },
    /// The solve produced a non-finite pose.
    #[error("non-finite pose")]
    NonFinite,
    /// The track's texture matches the model far worse than the recent frames' did: the pose
    /// is likely wrong, though the geometry fits.
    #[error("the texture does not match the model: correlation {correlation:.2} below {floor:.2}, half the recent frames'")]
    TextureMismatch {
        /// The correlation of the live intensities with the model's at the tracked pose.
        correlation: f64,
        /// The floor: half the recent frames' median correlation.
        floor: f64,
    },
    /// Tracking was lost and no start pose of the relocaliser passed its tests.
    #[error("lost, and no start pose relocalised the frame")]
    NotRelocalised,
    /// The tracked frame could not be fused.
    #[error("fusion failed: {0}")]
    Fusion(#[from] TsdfError),
}

/// How a frame ended.
#[derive(Clone, Debug, PartialEq)]
pub enum FrameOutcome {
    /// The first fused frame: it started the map at the initial pose.
    Started,
    /// Tracked from the predicted pose and fused.
    Tracked,
    /// Tracking from the predicted pose failed or the track was lost; the relocaliser found the
    /// pose, and the frame was fused.
    Relocalised,
    /// Tracking was lost for good ([`super::RelocaliseParams::new_map_after`] frames not
    /// relocalised): the frame started a new map fragment at the last good pose. Its pose and
    /// those of the frames tracked after it are in the fragment's own frame until a loop places
    /// the fragment in the map: [`super::FrameReport::placed`] says so frame by frame, and
    /// [`super::loops::KeyframeGraph::corrected`] carries them to the graph's solution once
    /// placed. A caller that keeps per-frame poses without the graph should set
    /// `new_map_after` to 0.
    NewMap,
    /// Not tracked and not fused; the pose stays the last good one.
    NotTracked(TrackFailure),
    /// The frame was not given to the pipeline (an application's outcome: its files could not
    /// be read); the reason names the file.
    Skipped(String),
}

impl FrameOutcome {
    /// The frame was fused into the map (started it or a new fragment, tracked or relocalised).
    pub fn is_fused(&self) -> bool {
        matches!(
            self,
            Self::Started | Self::NewMap | Self::Tracked | Self::Relocalised
        )
    }

    /// Why the frame was not tracked, if that is what happened.
    pub fn failure(&self) -> Option<&TrackFailure> {
        match self {
            Self::NotTracked(why) => Some(why),
            _ => None,
        }
    }
}
