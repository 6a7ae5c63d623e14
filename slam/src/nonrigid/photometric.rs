//! The photometric data term of non-rigid tracking.
//!
//! Depth holds a surface only along its normal: material sliding along the surface leaves the
//! depth as it was, so a wave running along a sheet or a tube twisting about its axis is fitted
//! while its texture slides away. The texture moves with the material, though. Each canonical
//! data point takes the intensity it showed in a recent tracked frame (one taken every few
//! frames, module `reference_frame`), and in each frame after it adds
//!
//! ```text
//! r = I(π(W(v))) − I_ref,   ∂r/∂b = ∇Iᵀ ∂π/∂x ∂W(v)/∂b
//! ```
//!
//! under Tukey's kernel with weight λ (brightness constancy between nearby frames, the
//! photometric error of dense visual odometry, Kerl, Sturm & Cremers 2013, taken through the
//! blended warp instead of one rigid motion). Referencing a recent frame rather than the
//! canonical colour fused so far keeps most shading out of the residual: it changes as the
//! surface bends, slowly from one frame to the next but by much over a sequence.
//!
//! Shading changes between nearby frames too, and on a bending surface by enough to bias
//! the fit (the generated plate's shading moves by up to 2 % of the intensity a frame, a slide of
//! about half a pixel on its texture). Shading multiplies the albedo and varies smoothly over the
//! surface, so the term compares the ratio of the intensity to its local mean,
//! `N = I / Ī − 1` ([`RatioImage`]): the texture stays and the shading, nearly constant over
//! the window, cancels.

use crate::camera::Camera;
use crate::image::{gradients, GrayImage};
use nalgebra::Vector3;
use rayon::prelude::*;

/// The intensity over its local mean, `N = I / Ī − 1` (Ī the mean over a square window, Ī
/// floored at [`DARK`]), with its gradients; buffers kept across frames.
#[derive(Clone, Default)]
pub struct RatioImage {
    /// N.
    pub image: GrayImage,
    /// ∂N/∂u.
    pub gradient_x: GrayImage,
    /// ∂N/∂v.
    pub gradient_y: GrayImage,
    rows: GrayImage,
}

/// The least local mean intensity a ratio is taken over: darker windows hold no texture to
/// speak of, and their ratios would be noise.
pub const DARK: f32 = 0.02;

impl RatioImage {
    /// Computes N from `intensity` over windows of (2 `radius` + 1)² pixels (clipped at the
    /// border), and its central-difference gradients.
    pub fn compute(&mut self, intensity: &GrayImage, radius: usize) {
        let (w, h) = (intensity.width, intensity.height);
        self.rows.resize(w, h, 0.0);
        self.image.resize(w, h, 0.0);
        // row means, then the column means of those, divided into the intensity
        self.rows
            .data
            .par_chunks_mut(w.max(1))
            .zip(intensity.data.par_chunks(w.max(1)))
            .for_each(|(out, line)| window_means(line, radius, out));
        let rows = &self.rows;
        self.image
            .data
            .par_chunks_mut(w.max(1))
            .enumerate()
            .for_each(|(y, out)| {
                let (lo, hi) = (y.saturating_sub(radius), (y + radius).min(h - 1));
                let scale = 1.0 / (hi - lo + 1) as f32;
                for (x, o) in out.iter_mut().enumerate() {
                    let mean = (lo..=hi).map(|r| rows.data[r * w + x]).sum::<f32>() * scale;
                    *o = intensity.data[y * w + x] / mean.max(DARK) - 1.0;
                }
            });
        gradients(&self.image, &mut self.gradient_x, &mut self.gradient_y);
    }

    /// The ratio image as the photometric term samples it, with the intrinsics of its level.
    pub fn live<'a>(&'a self, camera: &'a Camera) -> LiveIntensity<'a> {
        LiveIntensity::of(camera, [&self.image, &self.gradient_x, &self.gradient_y])
    }
}

/// The mean of `line` over the window of ± `radius` about each entry (clipped at the ends).
fn window_means(line: &[f32], radius: usize, out: &mut [f32]) {
    let n = line.len();
    for (x, o) in out.iter_mut().enumerate() {
        let (lo, hi) = (x.saturating_sub(radius), (x + radius).min(n - 1));
        *o = line[lo..=hi].iter().sum::<f32>() / (hi - lo + 1) as f32;
    }
}

/// A live intensity image with its gradients, sampled bilinearly at projected points.
#[derive(Clone, Copy)]
pub struct LiveIntensity<'a> {
    /// Intrinsics of the images.
    pub camera: &'a Camera,
    /// Intensity in [0, 1].
    pub intensity: &'a GrayImage,
    /// ∂I/∂u.
    pub gradient_x: &'a GrayImage,
    /// ∂I/∂v.
    pub gradient_y: &'a GrayImage,
}

impl<'a> LiveIntensity<'a> {
    /// An image with its two gradients, `[I, ∂I/∂u, ∂I/∂v]`, seen through `camera`.
    pub fn of(camera: &'a Camera, [intensity, gradient_x, gradient_y]: [&'a GrayImage; 3]) -> Self {
        Self {
            camera,
            intensity,
            gradient_x,
            gradient_y,
        }
    }

    /// The intensity at the projection of the camera-frame point `p` and its derivative by `p`
    /// (`∇Iᵀ ∂π/∂x`), or `None` behind the camera or within a pixel of the border (where the
    /// gradients are not defined).
    #[inline]
    pub fn sample(&self, p: &Vector3<f64>) -> Option<(f64, Vector3<f64>)> {
        let c = self.camera;
        if p.z <= 0.0 {
            return None;
        }
        let iz = 1.0 / p.z;
        let (u, v) = (c.fx * p.x * iz + c.cx, c.fy * p.y * iz + c.cy);
        let (w, h) = (self.intensity.width, self.intensity.height);
        if !(u >= 1.0 && v >= 1.0 && u < w as f64 - 2.0 && v < h as f64 - 2.0) {
            return None;
        }
        // u, v ≥ 1 here, so truncation is the floor
        let (x0, y0) = (u as usize, v as usize);
        let (fx, fy) = (u - x0 as f64, v - y0 as f64);
        let i = y0 * w + x0;
        let weights = [
            (i, (1.0 - fx) * (1.0 - fy)),
            (i + 1, fx * (1.0 - fy)),
            (i + w, (1.0 - fx) * fy),
            (i + w + 1, fx * fy),
        ];
        let mut out = [0.0; 3];
        for (k, img) in [self.intensity, self.gradient_x, self.gradient_y]
            .into_iter()
            .enumerate()
        {
            out[k] = weights.iter().map(|&(j, a)| a * img.data[j] as f64).sum();
        }
        let [value, gu, gv] = out;
        let derivative = Vector3::new(
            gu * c.fx * iz,
            gv * c.fy * iz,
            -(gu * c.fx * p.x + gv * c.fy * p.y) * iz * iz,
        );
        Some((value, derivative))
    }
}

/// One frame's photometric term: the live intensities and each canonical data point's reference
/// intensity (NaN where it has none: not seen in the frame it was taken from).
#[derive(Clone, Copy)]
pub struct PhotometricTarget<'a> {
    /// The live image.
    pub live: LiveIntensity<'a>,
    /// One reference intensity per data point.
    pub reference: &'a [f32],
}

/// How well the photometric term is met at the end of an optimisation, over the matched points
/// that have a reference: the median |r| against the median |N_ref| (the texture's own
/// contrast, N having zero local mean). A fit that leaves most of the texture unexplained means
/// the material slid, whatever the depth says.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhotometricFit {
    /// Points compared.
    pub rows: usize,
    /// Median |I(π(W(v))) − I_ref|.
    pub residual: f64,
    /// Median |I_ref|.
    pub texture: f64,
}

impl PhotometricFit {
    /// The fit of `target` at the warped points, over those `matched`.
    pub fn measure(
        target: &PhotometricTarget<'_>,
        warped: &[Vector3<f64>],
        matched: impl Iterator<Item = bool>,
    ) -> Self {
        let (mut residuals, mut texture): (Vec<f64>, Vec<f64>) = warped
            .iter()
            .zip(target.reference)
            .zip(matched)
            .filter(|&((_, r), m)| m && r.is_finite())
            .filter_map(|((p, &r), _)| {
                let (value, _) = target.live.sample(p)?;
                Some(((value - r as f64).abs(), (r as f64).abs()))
            })
            .unzip();
        Self {
            rows: residuals.len(),
            residual: median(&mut residuals),
            texture: median(&mut texture),
        }
    }
}

/// The median of `v` (0 when empty); reorders `v`.
fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::image::Image;

    /// A smooth image I(u, v) = sin(0.3u) + 0.5 cos(0.2v) scaled into [0, 1].
    pub(crate) fn image(w: usize, h: usize) -> GrayImage {
        let mut g = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f32, y as f32);
                g.set(x, y, 0.5 + 0.3 * (0.3 * u).sin() + 0.15 * (0.2 * v).cos());
            }
        }
        g
    }

    /// An intensity image with its central-difference gradients, for [`LiveIntensity`].
    pub(crate) struct WithGradients {
        gray: GrayImage,
        gx: GrayImage,
        gy: GrayImage,
    }

    impl WithGradients {
        pub(crate) fn of(gray: GrayImage) -> Self {
            let (mut gx, mut gy) = (GrayImage::new(1, 1), GrayImage::new(1, 1));
            gradients(&gray, &mut gx, &mut gy);
            Self { gray, gx, gy }
        }

        pub(crate) fn live<'a>(&'a self, camera: &'a Camera) -> LiveIntensity<'a> {
            LiveIntensity::of(camera, [&self.gray, &self.gx, &self.gy])
        }
    }

    #[test]
    fn the_derivative_by_the_point_is_the_central_difference_of_the_samples() {
        let camera = Camera::tum_default().level(1);
        let gray = WithGradients::of(image(camera.width, camera.height));
        let live = gray.live(&camera);
        let p = Vector3::new(0.05, -0.03, 0.9);
        let (_, d) = live.sample(&p).expect("inside");
        // the gradient images are central differences of the pixels, so compare with the
        // difference of the samples over a step of about a pixel
        let step = 0.9 / camera.fx;
        for axis in 0..3 {
            let e = Vector3::ith(axis, step);
            let (a, _) = live.sample(&(p + e)).expect("inside");
            let (b, _) = live.sample(&(p - e)).expect("inside");
            let numeric = (a - b) / (2.0 * step);
            assert!(
                (numeric - d[axis]).abs() < 0.05 * d.norm(),
                "axis {axis}: {numeric} against {}",
                d[axis]
            );
        }
    }

    #[test]
    fn the_ratio_image_drops_a_smooth_shading_and_keeps_the_texture() {
        let camera = Camera::tum_default().level(1);
        let texture = image(camera.width, camera.height);
        // the texture under a shading that falls from 1 to 0.6 across the image
        let mut shaded = texture.clone();
        for y in 0..camera.height {
            for x in 0..camera.width {
                let s = 1.0 - 0.4 * x as f32 / camera.width as f32;
                shaded.set(x, y, texture.at(x, y) * s);
            }
        }
        let (mut a, mut b) = (RatioImage::default(), RatioImage::default());
        a.compute(&texture, 4);
        b.compute(&shaded, 4);
        let (mut worst, mut spread) = (0.0f32, 0.0f32);
        for y in 10..camera.height - 10 {
            for x in 10..camera.width - 10 {
                worst = worst.max((a.image.at(x, y) - b.image.at(x, y)).abs());
                spread = spread.max(a.image.at(x, y).abs());
            }
        }
        // the texture's ratios span tenths; the shading moves them by under 1 % of that
        assert!(spread > 0.1, "texture kept: {spread}");
        assert!(worst < 0.01 * spread, "shading left: {worst} of {spread}");
        // a uniform image has ratio 0 everywhere, a black one too (floored mean)
        let mut flat = GrayImage::new(20, 10);
        flat.data.fill(0.4);
        a.compute(&flat, 3);
        assert!(a.image.data.iter().all(|v| v.abs() < 1e-6));
        flat.data.fill(0.0);
        a.compute(&flat, 3);
        assert!(a
            .image
            .data
            .iter()
            .all(|v| (*v + 1.0).abs() < 1e-6 || v.abs() < 1e-6));
    }

    #[test]
    fn points_behind_the_camera_or_at_the_border_have_no_sample() {
        let camera = Camera::tum_default().level(1);
        let gray = WithGradients::of(image(camera.width, camera.height));
        let live = gray.live(&camera);
        assert!(live.sample(&Vector3::new(0.0, 0.0, -1.0)).is_none());
        assert!(live.sample(&Vector3::new(10.0, 0.0, 1.0)).is_none());
        assert!(live.sample(&Vector3::new(0.0, 0.0, 1.0)).is_some());
    }
}
