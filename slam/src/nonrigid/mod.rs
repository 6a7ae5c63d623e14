//! Non-rigid registration (thesis ch. 4, after DynamicFusion and embedded deformation):
//!
//! - [`graph`]: the deformation graph: nodes sampled over the canonical surface, K-nearest-node
//!   binding through a KD-tree, dual-quaternion blending of points and normals, growth where new
//!   surface appears.
//! - [`register`]: the warp-field optimiser: rigid pre-alignment, then point-to-plane data and
//!   as-rigid-as-possible regularisation under a decreasing weight, solved on the solver's
//!   block-sparse Cholesky from normal equations assembled in the blend's coordinates (`system`).
//! - [`photometric`]: the photometric data term of tracking: each data point's intensity (over its
//!   local mean) in a recent tracked frame ([`reference_frame`]) against the live image, for
//!   motion along the surface that depth cannot see.
//! - [`chroma`]: the chromaticity term of tracking and frame registration: colour that shading
//!   and exposure leave as it is, compared with what each point showed when first seen.
//! - [`fusion`]: the DynamicFusion-style pipeline: a canonical TSDF fused through the warp (each
//!   voxel's nodes cached across frames, `voxel_bindings`), the field tracked frame to frame
//!   against live depth, the graph grown with the surface.
//! - [`surface`]: one whole surface registered onto another (meshes, clouds), and meshes far
//!   apart in pose in further passes seeded by [`descriptors`]: geodesic descriptors that tell
//!   apart parts closest point confuses, and meshes with a rim (sheets) from the rim's shape
//!   ([`boundary`]; the rim itself in `rim`, laid corner to corner in `rim_map`), whose matches
//!   land between the target's vertices ([`mesh_point`]); [`surface_fit`]: whether the result
//!   lies on the target and covers it (registered or not).
//! - [`frames`]: one RGB-D frame registered onto another (feature-matched rigid start, or
//!   [`outline_start`]'s placement by the object's outline where no feature match agrees; dense
//!   non-rigid refinement), with per-pixel scene flow; [`frame_surface`]: a frame's object from a
//!   graph's nodes, and the median distance from a registered source to the target's surface;
//!   [`colour_check`]: whether the colour agrees with a frame registration, patch by patch.

pub mod affine_fit;
pub mod affine_slippage;
mod band;
pub mod boundary;
mod cell_nearest;
pub mod chroma;
mod cloud_target;
pub mod colour_check;
pub mod colour_drift;
mod coverage;
pub mod descriptors;
mod extent;
mod extremities;
pub mod frame_matches;
pub mod frame_surface;
pub mod frame_target;
pub mod frames;
pub mod fusion;
pub mod global_maps;
pub mod graph;
pub mod linear_steps;
pub mod mesh_point;
pub mod mesh_target;
pub mod orientation;
pub mod outline_check;
pub mod outline_start;
pub mod photometric;
mod point_terms;
pub mod principal_axes;
mod prior_index;
pub mod reference_frame;
pub mod register;
mod rim;
mod rim_map;
pub mod round_trip;
pub mod slippage;
pub mod surface;
pub mod surface_area;
pub mod surface_fit;
mod system;
mod voxel_bindings;
mod weld;

pub use affine_slippage::{AffineSlide, MAX_AFFINE_SLIPPAGE};
pub use boundary::{rim_matches, RimMatches};
pub use chroma::{chromaticity, ChromaImage, ChromaReferences};
pub use cloud_target::CloudTarget;
pub use colour_check::ColourCheck;
pub use colour_drift::{ColourDrift, ColourDrifted};
pub use descriptors::{descriptor_matches, DescriptorError, DescriptorPair, MeshRef};
pub use frame_surface::{frame_points, mask_near_nodes, median_distance};
pub use frame_target::SeenThroughTarget;
pub use frames::{
    frame_verdict, register_frames, FrameError, FrameRegistration, FrameSettings, FrameStart,
    FrameVerdict, FrameView, COLOUR_TOLERANCE, MAX_OFF_FRACTION, MIN_MATCHED_FRACTION,
};
pub use fusion::{FusionFailure, FusionParams, FusionReport, FusionTimes, NonRigidFusion};
pub use graph::{Binding, DeformationGraph, GraphError, GraphParams, Node};
pub use linear_steps::{LinearEffort, LinearSteps, LinearStepsError};
pub use mesh_point::MeshPoint;
pub use mesh_target::MeshTarget;
pub use outline_check::{OutlineCheck, MAX_FLUSH_FRACTION};
pub use photometric::{LiveIntensity, PhotometricFit, PhotometricTarget, RatioImage};
pub use principal_axes::principal_axes_guesses;
pub use reference_frame::ReferenceFrame;
pub use register::{
    DepthTarget, RegisterError, RegisterParams, RegisterSummary, RegisterTimes, Samples, Seeds,
    Target, TexturedDepthTarget, WarpOptimiser,
};
pub use round_trip::{RoundTrip, MAX_ROUND_TRIP};
pub use slippage::{Slippage, MAX_SLIPPAGE};
pub use surface::{
    bounding_diagonal, clean_surface_settings, mesh_points, register_mesh_or_cloud,
    register_mesh_pair, register_meshes, register_surfaces, surface_diagonal, MeshRole, Seeding,
    SurfaceError, SurfaceMesh, SurfaceRegistration,
};
pub use surface_fit::{SurfaceFit, SurfaceVerdict, AREA_FACTOR, MIN_FACING, MIN_SHARE};
