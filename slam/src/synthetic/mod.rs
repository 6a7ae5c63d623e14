//! The project's own RGB-D sequences with ground truth, so that tests need no downloads.
//!
//! - [`scene`]: primitives (planes, boxes, spheres, cylinders) and triangle meshes (through a
//!   [`bvh`]), with procedural [`texture`] so the photometric term has gradients;
//! - [`layouts`]: the room, a bare room without texture on its walls, a random office;
//! - [`render`]: a ray caster producing depth, colour and normals at any resolution, and the
//!   simple Kinect-like [`noise`] model;
//! - [`kinect`]: a structured-light sensor as hard as a real one (quantised disparity, shadows,
//!   flying pixels, motion blur, exposure drift, distortion, colour captured after depth);
//! - [`motion`]: camera trajectories, procedural (orbit, shake, fast rotation) or from a TUM file;
//! - [`deform`]: surfaces deformed over time by known smooth fields (bend, twist, wave), with
//!   per-pixel scene flow and the deformed mesh per frame;
//! - [`frame_pair`]: two frames of a deforming surface from cameras apart, before a wall or
//!   not, with the true scene flow (frame-to-frame registration);
//! - [`plate`]: the thesis' flat 21 × 13 grid and its five target deformations (Table 4.1);
//! - [`sheet`]: plain sheets bent, rolled, folded, twisted and saddled (issue 26), at any size;
//! - [`sequence`]: writing everything in the TUM layout;
//! - [`surface_error`]: how far a reconstructed mesh lies from the scene (a wall fused twice);
//! - [`view_cone`]: the objects a camera's rays may meet, so that the others are not tested;
//! - [`faults`]: a sequence with dropped, corrupt and blank frames, a jump and a textureless
//!   stretch, for reliability tests.
//!
//! Everything is seeded and deterministic.

/// The most pixels a frame to render may have (4096 × 4096): the Kinect model keeps some 100
/// bytes a pixel (rays, noise images, colour planes), about 1.7 GB at this size; a frame of
/// 100 000² aborted on its allocation. The applications and the Python bindings refuse larger
/// frames.
pub const MAX_PIXELS: usize = 4096 * 4096;

/// The most frames a sequence to render may have: a million, over nine hours at 30 Hz; a
/// trajectory of 10¹² poses was killed for memory before its first frame.
pub const MAX_FRAMES: usize = 1_000_000;

pub mod bvh;
pub mod deform;
pub mod faults;
pub mod frame_pair;
pub mod kinect;
pub mod layouts;
pub mod motion;
pub mod noise;
pub mod plate;
pub mod render;
pub mod rings;
pub mod scene;
pub mod sequence;
pub mod sheet;
pub mod surface_error;
pub mod texture;
pub mod view_cone;
