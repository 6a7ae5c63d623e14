//! The per-frame front end: raw depth (and colour) in, a pyramid of filtered depth, vertices,
//! normals, intensity and gradients out, ready for coarse-to-fine tracking (thesis sec. 3.1).
//!
//! A [`Preprocessor`] keeps its buffers, so processing a frame allocates nothing once the first frame
//! of a size has been seen.

use crate::camera::Camera;
use crate::image::{
    bilateral_filter, depth_to_metres, downsample_depth, downsample_gray, gradients, intensity,
    normal_map, vertex_map, BilateralParams, ColorImage, DepthImage, GrayImage, Image, NormalMap,
    VertexMap,
};

/// One level of the pyramid.
#[derive(Clone, Debug)]
pub struct Level {
    /// Intrinsics of this level.
    pub camera: Camera,
    /// Depth in metres (filtered at level 0, down-sampled above).
    pub depth: DepthImage,
    /// Points in the camera frame.
    pub vertices: VertexMap,
    /// Normals facing the camera.
    pub normals: NormalMap,
    /// Intensity in [0, 1] (empty without colour).
    pub intensity: GrayImage,
    /// ∂I/∂u.
    pub gradient_x: GrayImage,
    /// ∂I/∂v.
    pub gradient_y: GrayImage,
}

impl Level {
    fn empty(camera: Camera) -> Self {
        Self {
            camera,
            depth: Image::new(0, 0),
            vertices: Image::filled(0, 0, [0.0; 3]),
            normals: Image::filled(0, 0, [0.0; 3]),
            intensity: Image::new(0, 0),
            gradient_x: Image::new(0, 0),
            gradient_y: Image::new(0, 0),
        }
    }
}

/// Settings of the front end.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PreprocessParams {
    /// Number of pyramid levels (default 3).
    pub levels: usize,
    /// Bilateral filter on level 0.
    pub bilateral: BilateralParams,
}

impl Default for PreprocessParams {
    fn default() -> Self {
        Self {
            levels: 3,
            bilateral: BilateralParams::default(),
        }
    }
}

/// Turns raw frames into pyramids, reusing its buffers.
#[derive(Clone, Debug)]
pub struct Preprocessor {
    /// The settings.
    pub params: PreprocessParams,
    camera: Camera,
    raw: DepthImage,
    /// The pyramid of the last frame processed (level 0 is full resolution).
    pub levels: Vec<Level>,
}

impl Preprocessor {
    /// A front end for images from `camera`.
    pub fn new(camera: Camera, params: PreprocessParams) -> Self {
        let levels = (0..params.levels.max(1))
            .map(|l| Level::empty(camera.level(l)))
            .collect();
        Self {
            params,
            camera,
            raw: Image::new(0, 0),
            levels,
        }
    }

    /// Processes one frame: `depth_raw` in sensor units (divided by the camera's depth scale), and
    /// optionally its colour.
    pub fn process(&mut self, depth_raw: &Image<u16>, color: Option<&ColorImage>) -> &[Level] {
        depth_to_metres(depth_raw, &self.camera, &mut self.raw);
        self.process_metres_inner(color)
    }

    /// Processes a frame whose depth is already in metres (0 where missing).
    pub fn process_metres(&mut self, depth: &DepthImage, color: Option<&ColorImage>) -> &[Level] {
        self.raw.reset(depth.width, depth.height, 0.0);
        self.raw.data.copy_from_slice(&depth.data);
        self.process_metres_inner(color)
    }

    fn process_metres_inner(&mut self, color: Option<&ColorImage>) -> &[Level] {
        let sigma_range = self.params.bilateral.sigma_range;
        bilateral_filter(&self.raw, &self.params.bilateral, &mut self.levels[0].depth);
        for l in 1..self.levels.len() {
            let (lower, upper) = self.levels.split_at_mut(l);
            downsample_depth(&lower[l - 1].depth, sigma_range, &mut upper[0].depth);
        }
        if let Some(c) = color {
            intensity(c, &mut self.levels[0].intensity);
            for l in 1..self.levels.len() {
                let (lower, upper) = self.levels.split_at_mut(l);
                downsample_gray(&lower[l - 1].intensity, &mut upper[0].intensity);
            }
        } else {
            // a frame without colour has no intensity: the last frame's, left in the buffers,
            // entered its tracking as if it were its own (NOTES 124); emptied, keeping their memory
            for level in self.levels.iter_mut() {
                level.intensity.reset(0, 0, 0.0);
                level.gradient_x.reset(0, 0, 0.0);
                level.gradient_y.reset(0, 0, 0.0);
            }
        }
        for level in self.levels.iter_mut() {
            vertex_map(&level.depth, &level.camera, &mut level.vertices);
            normal_map(&level.vertices, &level.camera, &mut level.normals);
            if color.is_some() {
                gradients(
                    &level.intensity,
                    &mut level.gradient_x,
                    &mut level.gradient_y,
                );
            }
        }
        &self.levels
    }
}
