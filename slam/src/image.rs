//! Images and the per-pixel operations of the sensor front end (thesis ch. 2.2): bilateral filtering
//! of depth (eq. 2.4-2.7), Gaussian smoothing and down-sampling (eq. 2.10), vertex and normal maps
//! (eq. 2.3), intensity and its gradients. Every operation runs over rows in parallel with rayon and
//! writes into a buffer the caller keeps, so a frame loop allocates nothing.

use crate::camera::Camera;
use rayon::prelude::*;

/// A row-major image.
#[derive(Clone, Debug, PartialEq)]
pub struct Image<T> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width × height` pixels, row by row.
    pub data: Vec<T>,
}

/// Depth in metres, 0 where missing.
pub type DepthImage = Image<f32>;
/// Intensity in [0, 1].
pub type GrayImage = Image<f32>;
/// 8-bit RGB.
pub type ColorImage = Image<[u8; 3]>;
/// Points in the camera frame; NaN where invalid.
pub type VertexMap = Image<[f32; 3]>;
/// Unit normals in the camera frame, facing the camera; NaN where invalid.
pub type NormalMap = Image<[f32; 3]>;

/// The invalid vertex or normal.
pub const INVALID: [f32; 3] = [f32::NAN; 3];

impl<T: Copy + Default> Image<T> {
    /// An image filled with `T::default()`.
    pub fn new(width: usize, height: usize) -> Self {
        Self::filled(width, height, T::default())
    }
}

impl<T: Copy> Image<T> {
    /// An image filled with `value`.
    pub fn filled(width: usize, height: usize, value: T) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }
    /// Wraps pixel data; `None` if the length does not match.
    pub fn from_vec(width: usize, height: usize, data: Vec<T>) -> Option<Self> {
        (data.len() == width * height).then_some(Self {
            width,
            height,
            data,
        })
    }
    /// The pixel at column x, row y.
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> T {
        self.data[y * self.width + x]
    }
    /// Sets the pixel at column x, row y.
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, v: T) {
        self.data[y * self.width + x] = v;
    }
    /// Resizes (reallocating only when the size changes) and fills with `value`.
    pub fn reset(&mut self, width: usize, height: usize, value: T) {
        self.width = width;
        self.height = height;
        self.data.clear();
        self.data.resize(width * height, value);
    }
}

/// Whether a vertex or normal is valid.
#[inline]
pub fn valid(p: &[f32; 3]) -> bool {
    p[0].is_finite()
}

/// Bilateral filter settings (eq. 2.4-2.7).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BilateralParams {
    /// Window half-size in pixels.
    pub radius: usize,
    /// Spatial standard deviation, pixels.
    pub sigma_space: f32,
    /// Range (depth) standard deviation, metres.
    pub sigma_range: f32,
}

impl Default for BilateralParams {
    /// A 5×5 window, σ_s = 2 px, σ_r = 3 cm.
    fn default() -> Self {
        Self {
            radius: 2,
            sigma_space: 2.0,
            sigma_range: 0.03,
        }
    }
}

/// Entries of the range-weight table, covering 3 σ_r.
const RANGE_TABLE: usize = 256;

/// Edge-preserving smoothing of depth: `D'(u) = 1/W Σ_q N_σs(‖u − q‖) N_σr(|D(u) − D(q)|) D(q)`
/// over the valid neighbours q (D(q) > 0) within 3 σ_r of D(u); missing depth stays missing and
/// depth does not bleed across edges deeper than 3 σ_r.
pub fn bilateral_filter(input: &DepthImage, params: &BilateralParams, out: &mut DepthImage) {
    let (w, h) = (input.width, input.height);
    out.reset(w, h, 0.0);
    let r = params.radius as isize;
    let side = 2 * params.radius + 1;
    let spatial: Vec<f32> = (0..side * side)
        .map(|i| {
            let (dx, dy) = ((i % side) as f32 - r as f32, (i / side) as f32 - r as f32);
            (-(dx * dx + dy * dy) / (2.0 * params.sigma_space * params.sigma_space)).exp()
        })
        .collect();
    let cutoff = 3.0 * params.sigma_range;
    let scale = (RANGE_TABLE - 1) as f32 / cutoff;
    let range: Vec<f32> = (0..RANGE_TABLE)
        .map(|i| {
            let d = i as f32 / scale;
            (-(d * d) / (2.0 * params.sigma_range * params.sigma_range)).exp()
        })
        .collect();
    out.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let y = y as isize;
        for (x, o) in row.iter_mut().enumerate() {
            let c = input.data[y as usize * w + x];
            if c <= 0.0 {
                continue;
            }
            let (mut sum, mut wsum) = (0.0f32, 0.0f32);
            let x = x as isize;
            for dy in -r..=r {
                let yy = y + dy;
                if yy < 0 || yy >= h as isize {
                    continue;
                }
                let line = &input.data[yy as usize * w..(yy as usize + 1) * w];
                let srow = &spatial[((dy + r) as usize) * side..];
                for dx in -r..=r {
                    let xx = x + dx;
                    if xx < 0 || xx >= w as isize {
                        continue;
                    }
                    let d = line[xx as usize];
                    let diff = (d - c).abs();
                    if d > 0.0 && diff < cutoff {
                        let wt = srow[(dx + r) as usize] * range[(diff * scale) as usize];
                        sum += wt * d;
                        wsum += wt;
                    }
                }
            }
            *o = sum / wsum;
        }
    });
}

/// Halves a depth image with a 5×5 Gaussian (weights [1 4 6 4 1]/16 each way, eq. 2.10), averaging
/// only the valid neighbours within 3 σ_r of the centre depth, as KinectFusion does so that the
/// coarse levels do not blur across edges.
pub fn downsample_depth(input: &DepthImage, sigma_range: f32, out: &mut DepthImage) {
    const K: [f32; 5] = [1.0, 4.0, 6.0, 4.0, 1.0];
    let (w, h) = (input.width, input.height);
    let (ow, oh) = ((w / 2).max(1), (h / 2).max(1));
    out.reset(ow, oh, 0.0);
    let cutoff = 3.0 * sigma_range;
    out.data
        .par_chunks_mut(ow)
        .enumerate()
        .for_each(|(oy, row)| {
            for (ox, o) in row.iter_mut().enumerate() {
                let (cx, cy) = (2 * ox, 2 * oy);
                let c = input.data[cy * w + cx];
                if c <= 0.0 {
                    continue;
                }
                let (mut sum, mut wsum) = (0.0f32, 0.0f32);
                for (j, ky) in K.iter().enumerate() {
                    let yy = cy as isize + j as isize - 2;
                    if yy < 0 || yy >= h as isize {
                        continue;
                    }
                    for (i, kx) in K.iter().enumerate() {
                        let xx = cx as isize + i as isize - 2;
                        if xx < 0 || xx >= w as isize {
                            continue;
                        }
                        let d = input.data[yy as usize * w + xx as usize];
                        if d > 0.0 && (d - c).abs() < cutoff {
                            sum += ky * kx * d;
                            wsum += ky * kx;
                        }
                    }
                }
                *o = sum / wsum;
            }
        });
}

/// Halves an intensity image with the 5×5 Gaussian (eq. 2.10), borders clamped.
pub fn downsample_gray(input: &GrayImage, out: &mut GrayImage) {
    const K: [f32; 5] = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];
    let (w, h) = (input.width, input.height);
    let (ow, oh) = ((w / 2).max(1), (h / 2).max(1));
    out.reset(ow, oh, 0.0);
    out.data
        .par_chunks_mut(ow)
        .enumerate()
        .for_each(|(oy, row)| {
            for (ox, o) in row.iter_mut().enumerate() {
                let mut sum = 0.0;
                for (j, ky) in K.iter().enumerate() {
                    let yy = (2 * oy + j).saturating_sub(2).min(h - 1);
                    for (i, kx) in K.iter().enumerate() {
                        let xx = (2 * ox + i).saturating_sub(2).min(w - 1);
                        sum += ky * kx * input.data[yy * w + xx];
                    }
                }
                *o = sum;
            }
        });
}

/// Back-projects every valid depth (eq. 2.2): `V(u) = D(u) K⁻¹ [u, 1]ᵀ`; NaN where depth is missing
/// or outside the camera's range.
pub fn vertex_map(depth: &DepthImage, camera: &Camera, out: &mut VertexMap) {
    let w = depth.width;
    out.reset(w, depth.height, INVALID);
    let (fx, fy, cx, cy) = (
        camera.fx as f32,
        camera.fy as f32,
        camera.cx as f32,
        camera.cy as f32,
    );
    let (lo, hi) = (camera.depth_min as f32, camera.depth_max as f32);
    out.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let z = depth.data[y * w + x];
            if z >= lo && z <= hi {
                *o = [(x as f32 - cx) / fx * z, (y as f32 - cy) / fy * z, z];
            }
        }
    });
}

/// Normals from neighbour differences (eq. 2.3): `n = ±(V(x+1, y) − V(x, y)) × (V(x, y+1) − V(x, y))`,
/// normalised, with the sign chosen by the camera's handedness so that normals face the camera;
/// NaN where a neighbour is missing.
pub fn normal_map(vertices: &VertexMap, camera: &Camera, out: &mut NormalMap) {
    let (w, h) = (vertices.width, vertices.height);
    out.reset(w, h, INVALID);
    // x × y = +z (away from the camera) for a right-handed image; flip to face the camera.
    let sign = -camera.handedness() as f32;
    out.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        if y + 1 >= h {
            return;
        }
        for (x, o) in row.iter_mut().enumerate().take(w.saturating_sub(1)) {
            let p = vertices.data[y * w + x];
            let px = vertices.data[y * w + x + 1];
            let py = vertices.data[(y + 1) * w + x];
            if !(valid(&p) && valid(&px) && valid(&py)) {
                continue;
            }
            let a = [px[0] - p[0], px[1] - p[1], px[2] - p[2]];
            let b = [py[0] - p[0], py[1] - p[1], py[2] - p[2]];
            let n = [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ];
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if len > 0.0 {
                let s = sign / len;
                *o = [n[0] * s, n[1] * s, n[2] * s];
            }
        }
    });
}

/// Intensity I = (0.299 R + 0.587 G + 0.114 B) / 255 (ITU-R BT.601 luma).
pub fn intensity(color: &ColorImage, out: &mut GrayImage) {
    let w = color.width;
    out.reset(w, color.height, 0.0);
    out.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let [r, g, b] = color.data[y * w + x];
            *o = (0.299 * r as f32 + 0.587 * g as f32 + 0.114 * b as f32) / 255.0;
        }
    });
}

/// Intensity gradients by central differences, ∂I/∂u ≈ (I(u+1) − I(u−1))/2; zero on the border.
pub fn gradients(gray: &GrayImage, gx: &mut GrayImage, gy: &mut GrayImage) {
    let (w, h) = (gray.width, gray.height);
    gx.reset(w, h, 0.0);
    gy.reset(w, h, 0.0);
    gx.data
        .par_chunks_mut(w)
        .zip(gy.data.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (rx, ry))| {
            if y == 0 || y + 1 >= h {
                return;
            }
            for x in 1..w.saturating_sub(1) {
                let i = y * w + x;
                rx[x] = 0.5 * (gray.data[i + 1] - gray.data[i - 1]);
                ry[x] = 0.5 * (gray.data[i + w] - gray.data[i - w]);
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn std_dev(v: &[f32]) -> f32 {
        let m = v.iter().sum::<f32>() / v.len() as f32;
        (v.iter().map(|x| (x - m) * (x - m)).sum::<f32>() / v.len() as f32).sqrt()
    }

    #[test]
    fn bilateral_filter_reduces_noise_keeps_a_step_and_ignores_holes() {
        let (w, h) = (80, 60);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0f32, 0.005).unwrap();
        let truth = |x: usize| if x < 40 { 1.0f32 } else { 1.5f32 };
        let mut d = DepthImage::new(w, h);
        for y in 0..h {
            for x in 0..w {
                d.set(x, y, truth(x) + noise.sample(&mut rng));
            }
        }
        d.set(10, 10, 0.0);
        let mut f = DepthImage::new(1, 1);
        bilateral_filter(&d, &BilateralParams::default(), &mut f);
        assert_eq!(f.at(10, 10), 0.0, "a hole stays a hole");
        assert!(
            f.at(11, 10) > 0.9,
            "a hole's neighbours do not average in the 0"
        );
        // Noise on the flat halves (away from the step) drops.
        let inner = |img: &DepthImage, x0: usize, x1: usize| -> Vec<f32> {
            (5..h - 5)
                .flat_map(|y| (x0..x1).map(move |x| (x, y)))
                .map(|(x, y)| img.at(x, y))
                .filter(|v| *v > 0.0)
                .collect()
        };
        let (before, after) = (std_dev(&inner(&d, 5, 35)), std_dev(&inner(&f, 5, 35)));
        assert!(after < 0.5 * before, "sigma {before} -> {after}");
        // The step survives: no pixel next to it is pulled towards the other side.
        for y in 0..h {
            assert!(
                (f.at(39, y) - 1.0).abs() < 0.02 && (f.at(40, y) - 1.5).abs() < 0.02,
                "row {y}: {} {}",
                f.at(39, y),
                f.at(40, y)
            );
        }
    }

    #[test]
    fn downsampling_halves_and_respects_edges() {
        let mut d = DepthImage::new(8, 8);
        for y in 0..8 {
            for x in 0..8 {
                d.set(x, y, if x < 4 { 1.0 } else { 3.0 });
            }
        }
        let mut o = DepthImage::new(1, 1);
        downsample_depth(&d, 0.03, &mut o);
        assert_eq!((o.width, o.height), (4, 4));
        assert!(
            o.data.iter().all(|v| *v == 1.0 || *v == 3.0),
            "{:?}",
            o.data
        );
        let g = GrayImage::filled(9, 7, 0.25);
        let mut go = GrayImage::new(1, 1);
        downsample_gray(&g, &mut go);
        assert_eq!((go.width, go.height), (4, 3));
        assert!(go.data.iter().all(|v| (v - 0.25).abs() < 1e-6));
    }

    #[test]
    fn gradients_of_a_ramp() {
        let mut g = GrayImage::new(10, 10);
        for y in 0..10 {
            for x in 0..10 {
                g.set(x, y, 0.1 * x as f32 + 0.02 * y as f32);
            }
        }
        let (mut gx, mut gy) = (GrayImage::new(1, 1), GrayImage::new(1, 1));
        gradients(&g, &mut gx, &mut gy);
        assert!((gx.at(5, 5) - 0.1).abs() < 1e-6 && (gy.at(5, 5) - 0.02).abs() < 1e-6);
        assert_eq!(gx.at(0, 5), 0.0);
    }
}
