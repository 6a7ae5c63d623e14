//! The flags of a frame-to-frame registration, shared by `frames` and `pairs`.

use crate::cli::{bad_input, InputError};
use crate::warp_flags::WarpFlags;
use anyhow::Result;
use dynamap_slam::nonrigid::FrameSettings;

/// How two frames are registered: the graph and optimiser, and the two ways the target holds
/// the source beyond projective association (NOTES 95).
#[derive(clap::Args, Debug)]
pub(super) struct FrameFlags {
    /// Where the target is seen through a warped point (no depth there, or depth beyond the
    /// association gate behind it), the point takes the nearest target point within this
    /// distance, metres; 0 leaves it to projective association [default: 0.05]
    #[arg(long, value_name = "METRES")]
    nearest_within: Option<f64>,
    /// The feature matches only start the fit (rigidly) instead of also shaping the warp (grown
    /// by local agreement, fitted first, held throughout).
    #[arg(long)]
    matches_start_only: bool,
    /// Where no feature match agrees, start where the source is instead of searching the
    /// target's depth for the object's outline
    #[arg(long)]
    no_outline_start: bool,
    /// No colour feature matches: the rigid start comes from the outline search (or the
    /// source's own place), as for a plain object
    #[arg(long)]
    no_features: bool,
    /// Weight of the chromaticity term, (R − B)/(R + G + B) of the source pixel against the
    /// target's where the warp carries it (0: none; both frames need colour) [default: 0.3]
    #[arg(long, value_name = "WEIGHT")]
    chroma_weight: Option<f64>,
    /// Graph and optimiser settings.
    #[command(flatten)]
    warp: WarpFlags,
}

impl FrameFlags {
    /// The defaults with these flags applied; a bad value is bad input.
    pub(super) fn settings(&self) -> Result<FrameSettings> {
        let mut settings = FrameSettings::default();
        self.warp
            .apply(&mut settings.graph, &mut settings.register)
            .bad_input()?;
        if let Some(within) = self.nearest_within {
            if !(within >= 0.0 && within.is_finite()) {
                return Err(bad_input(format!(
                    "--nearest-within must be a finite distance of 0 or more, not {within}"
                )));
            }
            settings.nearest_within = within;
        }
        settings.hold_matches = !self.matches_start_only;
        settings.outline_start = !self.no_outline_start;
        if self.no_features {
            settings.features = None;
        }
        if let Some(w) = self.chroma_weight {
            if !(w >= 0.0 && w.is_finite()) {
                return Err(bad_input(format!(
                    "--chroma-weight must be a finite weight of 0 or more, not {w}"
                )));
            }
            settings.register.chroma_weight = w;
        }
        Ok(settings)
    }
}
