//! Images and the per-pixel operations of the sensor front end (thesis ch. 2.2): bilateral filtering
//! of depth (eq. 2.4-2.7), Gaussian smoothing and down-sampling (eq. 2.10), vertex and normal maps
//! (eq. 2.3), intensity and its gradients. Every operation runs over rows in parallel with rayon and
//! writes into a buffer the caller keeps, so a frame loop allocates nothing.

use crate::camera::Camera;
use rayon::prelude::*;

/// The blend of four colours with integer weights `w` summing to 2¹⁶ (bilinear interpolation in
/// fixed point, the weights in 1/256ths of a pixel along each axis), rounded to the nearest level:
/// Σₖ wₖ pₖ / 2¹⁶ per channel. Red and blue share one 64-bit product, one in each half: every
/// product and sum stays below 2²⁴, so the halves never carry into each other.
#[inline]
pub fn blend4(p: [[u8; 3]; 4], w: [u32; 4]) -> [u8; 3] {
    let (mut rb, mut g) = (0u64, 0u32);
    for ([r, gr, b], w) in p.into_iter().zip(w) {
        rb += (u64::from(r) | u64::from(b) << 32) * u64::from(w);
        g += u32::from(gr) * w;
    }
    let round = |sum: u64| ((sum + (1 << 15)) >> 16) as u8;
    [
        round(rb & 0xffff_ffff),
        round(u64::from(g)),
        round(rb >> 32),
    ]
}

/// The weights [`blend4`] takes for a point `right` and `down` 256ths of a pixel past the upper
/// left of its four pixels (each in 0..=256): upper left, upper right, lower left, lower right.
#[inline]
pub fn bilinear_weights(right: u32, down: u32) -> [u32; 4] {
    let (left, up) = (256 - right, 256 - down);
    [left * up, right * up, left * down, right * down]
}

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

impl<T: Copy + Default> Default for Image<T> {
    /// An empty image.
    fn default() -> Self {
        Self::new(0, 0)
    }
}

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
    /// Resizes for a kernel that writes every pixel: memory is reused and, when the size is
    /// unchanged, not touched.
    pub fn resize(&mut self, width: usize, height: usize, value: T) {
        if self.width != width || self.height != height || self.data.len() != width * height {
            self.reset(width, height, value);
        }
    }
}

/// Runs `f(y, row)` over the rows of a `width`-wide buffer in parallel, a block of rows per task
/// (a task per row would cost more in scheduling than the rows' work).
fn par_rows<T: Send>(data: &mut [T], width: usize, f: impl Fn(usize, &mut [T]) + Sync) {
    if width == 0 {
        return;
    }
    let rows = data.len() / width;
    let per_task = (rows / (4 * rayon::current_num_threads())).clamp(1, 64);
    data.par_chunks_mut(width * per_task)
        .enumerate()
        .for_each(|(b, block)| {
            for (k, row) in block.chunks_mut(width).enumerate() {
                f(b * per_task + k, row);
            }
        });
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

/// e^x for x ≤ 0 in a form the compiler vectorises: x = n ln 2 + f, 2^f by a degree-5 polynomial
/// (relative error below 5e-6 on [−87, 0]), 2^n through the exponent bits.
/// Below −87 the result is garbage (but never a trap): callers discard it there.
#[inline(always)]
fn exp_neg(x: f32) -> f32 {
    let t = x * std::f32::consts::LOG2_E;
    // round to nearest without `floor` (SSE2 has no vector floor): the 1.5·2^23 trick
    let shifted = t + 12_582_912.0;
    let n = shifted - 12_582_912.0;
    let f = t - n; // in [−0.5, 0.5]
    let p = 1.0
        + f * (std::f32::consts::LN_2
            + f * (0.240_226_5 + f * (0.055_504_11 + f * (0.009_618_13 + f * 0.001_333_55))));
    // the low mantissa bits of `shifted` hold n in two's complement: no float-to-int conversion
    let ni = (shifted.to_bits() as i32).wrapping_sub(0x4B40_0000);
    p * f32::from_bits((ni.wrapping_add(127) << 23) as u32)
}

/// The weight of neighbour depth `d` for centre `c`: `ws · exp(−a (d − c)²)`, zero for a missing
/// neighbour or one beyond the range cutoff (`(d − c)² ≥ cut2`). Branch-free.
#[inline(always)]
fn bilateral_weight(c: f32, d: f32, ws: f32, a: f32, cut2: f32) -> f32 {
    let diff = d - c;
    let d2 = diff * diff;
    let inside = (d > 0.0) & (d2 < cut2);
    // Beyond the cutoff the exponential may be garbage; the select below discards it.
    let wt = ws * exp_neg(-a * d2);
    if inside {
        wt
    } else {
        0.0
    }
}

/// `sum += w·d`, `wsum += w` for one tap over a row (all slices of one length).
#[inline(always)]
fn taps_generic(
    sum: &mut [f32],
    wsum: &mut [f32],
    center: &[f32],
    src: &[f32],
    ws: f32,
    a: f32,
    cut2: f32,
) {
    let n = center.len();
    let (sum, wsum, src) = (&mut sum[..n], &mut wsum[..n], &src[..n]);
    for i in 0..n {
        let d = src[i];
        let wt = bilateral_weight(center[i], d, ws, a, cut2);
        sum[i] += wt * d;
        wsum[i] += wt;
    }
}

/// Defines `fn $name(args)` running `$generic(args)`, compiled a second time for AVX2 and FMA (8
/// lanes, fused multiply-adds) and dispatched to that copy when the CPU has them.
macro_rules! avx2_dispatch {
    ($(#[$meta:meta])* fn $name:ident => $generic:ident($($arg:ident: $ty:ty),* $(,)?)) => {
        $(#[$meta])*
        fn $name($($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2,fma")]
                unsafe fn wide($($arg: $ty),*) {
                    $generic($($arg),*)
                }
                if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                    // SAFETY: the CPU has just been checked for the features `wide` is compiled with.
                    return unsafe { wide($($arg),*) };
                }
            }
            $generic($($arg),*)
        }
    };
}

avx2_dispatch! {
    /// One tap of the bilateral filter over a row, on the widest vector unit the CPU has.
    fn accumulate_taps => taps_generic(sum: &mut [f32], wsum: &mut [f32], center: &[f32], src: &[f32], ws: f32, a: f32, cut2: f32)
}

thread_local! {
    /// Per-thread row accumulators of the bilateral filter (Σ w·D and Σ w).
    static ROW_SCRATCH: std::cell::RefCell<(Vec<f32>, Vec<f32>)> = const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

/// Runs `f(Σ w·D, Σ w)` with this thread's row accumulators, zeroed and `n` long (no allocation
/// once a thread has seen a row that long).
fn with_row_scratch<R>(n: usize, f: impl FnOnce(&mut [f32], &mut [f32]) -> R) -> R {
    ROW_SCRATCH.with(|cell| {
        let (sum, wsum) = &mut *cell.borrow_mut();
        sum.clear();
        sum.resize(n, 0.0);
        wsum.clear();
        wsum.resize(n, 0.0);
        f(sum, wsum)
    })
}

/// Edge-preserving smoothing of depth: `D'(u) = 1/W Σ_q N_σs(‖u − q‖) N_σr(|D(u) − D(q)|) D(q)`
/// over the valid neighbours q (D(q) > 0) within 3 σ_r of D(u); missing depth stays missing and
/// depth does not bleed across edges deeper than 3 σ_r.
///
/// Interior rows run tap by tap over the whole row, branch-free, so the compiler vectorises them;
/// the border frame of `radius` pixels takes the checked path.
pub fn bilateral_filter(input: &DepthImage, params: &BilateralParams, out: &mut DepthImage) {
    let (w, h) = (input.width, input.height);
    out.resize(w, h, 0.0);
    let r = params.radius;
    let side = 2 * r + 1;
    let inv_2ss = 1.0 / (2.0 * params.sigma_space * params.sigma_space);
    let spatial: Vec<f32> = (0..side * side)
        .map(|i| {
            let (dx, dy) = ((i % side) as f32 - r as f32, (i / side) as f32 - r as f32);
            (-(dx * dx + dy * dy) * inv_2ss).exp()
        })
        .collect();
    let cut2 = (3.0 * params.sigma_range).powi(2);
    let a = 1.0 / (2.0 * params.sigma_range * params.sigma_range);
    let data = &input.data;
    let tap = |c: f32, d: f32, ws: f32| bilateral_weight(c, d, ws, a, cut2);
    // The checked path, for pixels within `r` of the border.
    let slow = |x: usize, y: usize| -> f32 {
        let c = data[y * w + x];
        if c <= 0.0 {
            return 0.0;
        }
        let (mut sum, mut wsum) = (0.0f32, 0.0f32);
        for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
            for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                let d = data[yy * w + xx];
                let wt = tap(c, d, spatial[(yy + r - y) * side + xx + r - x]);
                sum += wt * d;
                wsum += wt;
            }
        }
        sum / wsum
    };
    par_rows(&mut out.data, w, |y, row| {
        if y < r || y + r >= h || w <= 2 * r {
            for (x, o) in row.iter_mut().enumerate() {
                *o = slow(x, y);
            }
            return;
        }
        let n = w - 2 * r;
        with_row_scratch(n, |sum, wsum| {
            let center = &data[y * w + r..y * w + r + n];
            for dy in 0..side {
                let line = &data[(y + dy - r) * w..(y + dy - r + 1) * w];
                for dx in 0..side {
                    let ws = spatial[dy * side + dx];
                    accumulate_taps(
                        &mut sum[..n],
                        &mut wsum[..n],
                        center,
                        &line[dx..dx + n],
                        ws,
                        a,
                        cut2,
                    );
                }
            }
            for (x, o) in row.iter_mut().enumerate() {
                *o = if x < r || x >= r + n {
                    slow(x, y)
                } else if center[x - r] > 0.0 {
                    sum[x - r] / wsum[x - r]
                } else {
                    0.0
                };
            }
        });
    });
}

/// Halves a depth image with a 5×5 Gaussian (weights [1 4 6 4 1]/16 each way, eq. 2.10), averaging
/// only the valid neighbours within 3 σ_r of the centre depth, as KinectFusion does so that the
/// coarse levels do not blur across edges.
pub fn downsample_depth(input: &DepthImage, sigma_range: f32, out: &mut DepthImage) {
    const K: [f32; 5] = [1.0, 4.0, 6.0, 4.0, 1.0];
    let (w, h) = (input.width, input.height);
    let (ow, oh) = ((w / 2).max(1), (h / 2).max(1));
    out.resize(ow, oh, 0.0);
    let cutoff = 3.0 * sigma_range;
    let data = &input.data;
    // The checked path, for outputs whose 5×5 window leaves the image.
    let slow = |ox: usize, oy: usize| -> f32 {
        let (cx, cy) = (2 * ox, 2 * oy);
        let c = data[cy * w + cx];
        if c <= 0.0 {
            return 0.0;
        }
        let (mut sum, mut wsum) = (0.0f32, 0.0f32);
        for yy in cy.saturating_sub(2)..(cy + 3).min(h) {
            for xx in cx.saturating_sub(2)..(cx + 3).min(w) {
                let d = data[yy * w + xx];
                let ok = (d > 0.0) & ((d - c).abs() < cutoff);
                let wt = if ok {
                    K[yy + 2 - cy] * K[xx + 2 - cx]
                } else {
                    0.0
                };
                sum += wt * d;
                wsum += wt;
            }
        }
        sum / wsum
    };
    // Interior outputs ox in [1, n], whose windows span input columns 2·ox − 2 .. 2·ox + 2 and
    // whose five taps each read 2n columns from their own offset (at most 4 + 2n ≤ w): on an odd
    // width the last output whose window fits takes the checked path, which sums the same taps
    // in the same order.
    let n = w.saturating_sub(4) / 2;
    par_rows(&mut out.data, ow, |oy, row| {
        let cy = 2 * oy;
        if cy < 2 || cy + 2 >= h || n == 0 {
            for (ox, o) in row.iter_mut().enumerate() {
                *o = slow(ox, oy);
            }
            return;
        }
        with_row_scratch(n, |sum, wsum| {
            // centres at input columns 2, 4, …, 2n
            let center = &data[cy * w + 2..cy * w + 2 + 2 * n];
            for (j, ky) in K.iter().enumerate() {
                let line = &data[(cy + j - 2) * w..(cy + j - 1) * w];
                for (i, kx) in K.iter().enumerate() {
                    accumulate_pyramid(
                        &mut sum[..n],
                        &mut wsum[..n],
                        center,
                        &line[i..i + 2 * n],
                        ky * kx,
                        cutoff,
                    );
                }
            }
            for (ox, o) in row.iter_mut().enumerate() {
                *o = if ox >= 1 && ox <= n {
                    if center[2 * (ox - 1)] > 0.0 {
                        sum[ox - 1] / wsum[ox - 1]
                    } else {
                        0.0
                    }
                } else {
                    slow(ox, oy)
                };
            }
        });
    });
}

/// One tap of the depth pyramid's 5×5 over an output row: inputs at even offsets of `src` and
/// `center`, accumulated where the depth is valid and within `cutoff` of the centre.
#[inline(always)]
fn pyramid_generic(
    sum: &mut [f32],
    wsum: &mut [f32],
    center: &[f32],
    src: &[f32],
    k: f32,
    cutoff: f32,
) {
    let n = sum.len();
    let (wsum, center, src) = (&mut wsum[..n], &center[..2 * n], &src[..2 * n]);
    for i in 0..n {
        let (d, c) = (src[2 * i], center[2 * i]);
        let ok = (d > 0.0) & ((d - c).abs() < cutoff);
        let wt = if ok { k } else { 0.0 };
        sum[i] += wt * d;
        wsum[i] += wt;
    }
}

avx2_dispatch! {
    /// One tap of the depth pyramid over an output row, on the widest vector unit the CPU has.
    fn accumulate_pyramid => pyramid_generic(sum: &mut [f32], wsum: &mut [f32], center: &[f32], src: &[f32], k: f32, cutoff: f32)
}

/// Halves an intensity image with the 5×5 Gaussian (eq. 2.10), borders clamped.
pub fn downsample_gray(input: &GrayImage, out: &mut GrayImage) {
    const K: [f32; 5] = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];
    let (w, h) = (input.width, input.height);
    let (ow, oh) = ((w / 2).max(1), (h / 2).max(1));
    out.resize(ow, oh, 0.0);
    par_rows(&mut out.data, ow, |oy, row| {
        for (ox, o) in row.iter_mut().enumerate() {
            let mut sum = 0.0;
            for (j, ky) in K.iter().enumerate() {
                let line = &input.data[(2 * oy + j).saturating_sub(2).min(h - 1) * w..][..w];
                for (i, kx) in K.iter().enumerate() {
                    sum += ky * kx * line[(2 * ox + i).saturating_sub(2).min(w - 1)];
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
    out.resize(w, depth.height, INVALID);
    let (ifx, ify) = (1.0 / camera.fx as f32, 1.0 / camera.fy as f32);
    let (cx, cy) = (camera.cx as f32, camera.cy as f32);
    let (lo, hi) = (camera.depth_min as f32, camera.depth_max as f32);
    par_rows(&mut out.data, w, |y, row| {
        let ry = (y as f32 - cy) * ify;
        for (x, (o, &z)) in row
            .iter_mut()
            .zip(&depth.data[y * w..(y + 1) * w])
            .enumerate()
        {
            *o = if z >= lo && z <= hi {
                [(x as f32 - cx) * ifx * z, ry * z, z]
            } else {
                INVALID
            };
        }
    });
}

/// Normals from central differences (eq. 2.3, centred):
/// `n = ±(V(x+1, y) − V(x−1, y)) × (V(x, y+1) − V(x, y−1))`, normalised, with the sign chosen by the
/// camera's handedness so that normals face the camera; NaN where a neighbour is missing and on the
/// image border. Centred differences give the normal at the pixel itself; forward differences
/// (KinectFusion's) give it half a pixel down and right, a bias that a surface free to slide along
/// itself (non-rigid tracking of a smooth sheet) turns into a steady drift.
pub fn normal_map(vertices: &VertexMap, camera: &Camera, out: &mut NormalMap) {
    let (w, h) = (vertices.width, vertices.height);
    out.resize(w, h, INVALID);
    // x × y = +z (away from the camera) for a right-handed image; flip to face the camera.
    let sign = -camera.handedness() as f32;
    par_rows(&mut out.data, w, |y, row| {
        if y == 0 || y + 1 >= h || w < 3 {
            row.fill(INVALID);
            return;
        }
        let (above, line, below) = (
            &vertices.data[(y - 1) * w..y * w],
            &vertices.data[y * w..(y + 1) * w],
            &vertices.data[(y + 1) * w..(y + 2) * w],
        );
        row[0] = INVALID;
        for x in 1..w - 1 {
            let (l, r, u, d) = (line[x - 1], line[x + 1], above[x], below[x]);
            // Branch-free: a missing neighbour is NaN and makes the normal NaN (invalid); so does a
            // degenerate cross product (0 · ∞).
            let a = [r[0] - l[0], r[1] - l[1], r[2] - l[2]];
            let b = [d[0] - u[0], d[1] - u[1], d[2] - u[2]];
            let n = [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ];
            let len2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
            let s = if len2 > 0.0 {
                sign / len2.sqrt()
            } else {
                f32::NAN
            };
            row[x] = [n[0] * s, n[1] * s, n[2] * s];
        }
        row[w - 1] = INVALID;
    });
}

/// Raw sensor depth to metres: `d / depth_scale`, 0 outside the camera's valid range
/// [`Camera::depth_min`, `Camera::depth_max`] (and where the sensor gave 0).
pub fn depth_to_metres(raw: &Image<u16>, camera: &Camera, out: &mut DepthImage) {
    let scale = 1.0 / camera.depth_scale as f32;
    let (lo, hi) = (camera.depth_min as f32, camera.depth_max as f32);
    out.reset(raw.width, raw.height, 0.0);
    out.data
        .par_iter_mut()
        .zip(raw.data.par_iter())
        .with_min_len(4096)
        .for_each(|(o, &d)| {
            let z = d as f32 * scale;
            *o = if z >= lo && z <= hi { z } else { 0.0 };
        });
}

/// Intensity I = (0.299 R + 0.587 G + 0.114 B) / 255 (ITU-R BT.601 luma).
pub fn intensity(color: &ColorImage, out: &mut GrayImage) {
    let w = color.width;
    out.resize(w, color.height, 0.0);
    par_rows(&mut out.data, w, |y, row| {
        for (o, &[r, g, b]) in row.iter_mut().zip(&color.data[y * w..(y + 1) * w]) {
            *o = (0.299 / 255.0) * r as f32
                + (0.587 / 255.0) * g as f32
                + (0.114 / 255.0) * b as f32;
        }
    });
}

/// Intensity gradients by central differences, ∂I/∂u ≈ (I(u+1) − I(u−1))/2; zero on the border.
pub fn gradients(gray: &GrayImage, gx: &mut GrayImage, gy: &mut GrayImage) {
    let (w, h) = (gray.width, gray.height);
    gx.resize(w, h, 0.0);
    gy.resize(w, h, 0.0);
    par_rows(&mut gx.data, w, |y, rx| {
        rx.fill(0.0);
        if y == 0 || y + 1 >= h || w < 3 {
            return;
        }
        let line = &gray.data[y * w..(y + 1) * w];
        for (x, o) in rx.iter_mut().enumerate().take(w - 1).skip(1) {
            *o = 0.5 * (line[x + 1] - line[x - 1]);
        }
    });
    par_rows(&mut gy.data, w, |y, ry| {
        ry.fill(0.0);
        if y == 0 || y + 1 >= h || w < 3 {
            return;
        }
        let (above, below) = (
            &gray.data[(y - 1) * w..y * w],
            &gray.data[(y + 1) * w..(y + 2) * w],
        );
        for x in 1..w - 1 {
            ry[x] = 0.5 * (below[x] - above[x]);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn a_blend_of_four_colours_is_each_channels_rounded_weighted_mean() {
        // every channel alone: Σ wₖ pₖ / 2¹⁶ rounded, at the extremes and at random
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let one_channel = |p: &[[u8; 3]; 4], w: &[u32; 4], c: usize| {
            let sum: u64 = (0..4).map(|k| u64::from(p[k][c]) * u64::from(w[k])).sum();
            ((sum + (1 << 15)) >> 16) as u8
        };
        let mut cases = vec![
            ([[255; 3]; 4], [65536, 0, 0, 0]),
            ([[255; 3]; 4], [16384; 4]),
            (
                [[255, 0, 255], [0, 255, 0], [255, 255, 255], [0, 0, 0]],
                [0, 256, 65024, 256],
            ),
        ];
        for _ in 0..10_000 {
            let (ax, ay) = (rng.random_range(0..=256u32), rng.random_range(0..=256u32));
            cases.push((
                std::array::from_fn(|_| rng.random()),
                bilinear_weights(ax, ay),
            ));
        }
        for (p, w) in cases {
            let expected: [u8; 3] = std::array::from_fn(|c| one_channel(&p, &w, c));
            assert_eq!(blend4(p, w), expected, "{p:?} {w:?}");
        }
    }

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
    fn fast_exponential_is_accurate() {
        for i in 0..2000 {
            let x = -(i as f32) * 0.02;
            let (a, b) = (exp_neg(x), x.exp());
            assert!((a - b).abs() <= 5e-6 * b + 1e-30, "{x}: {a} vs {b}");
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

    /// Eq. 2.10 for one output, pixel by pixel: the 5×5 binomial taps in row-major order over
    /// the valid inputs within `cutoff` of the centre.
    fn halved_at(input: &DepthImage, cutoff: f32, ox: usize, oy: usize) -> f32 {
        const K: [f32; 5] = [1.0, 4.0, 6.0, 4.0, 1.0];
        let (w, h) = (input.width as isize, input.height as isize);
        let (cx, cy) = (2 * ox as isize, 2 * oy as isize);
        let c = input.at(cx as usize, cy as usize);
        if c <= 0.0 {
            return 0.0;
        }
        let (mut sum, mut wsum) = (0.0f32, 0.0f32);
        for (j, ky) in K.iter().enumerate() {
            for (i, kx) in K.iter().enumerate() {
                let (x, y) = (cx + i as isize - 2, cy + j as isize - 2);
                if x < 0 || y < 0 || x >= w || y >= h {
                    continue;
                }
                let d = input.at(x as usize, y as usize);
                let wt = if d > 0.0 && (d - c).abs() < cutoff {
                    ky * kx
                } else {
                    0.0
                };
                sum += wt * d;
                wsum += wt;
            }
        }
        sum / wsum
    }

    #[test]
    fn the_depth_pyramid_halves_every_size_as_eq_2_10_pixel_by_pixel() {
        // odd and even widths and heights from 1 up, holes and steps deeper than the cutoff:
        // every output has the bits of the pixel-by-pixel sum (the vectorised interior once read
        // past the row on odd widths and panicked)
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for w in 1..=21 {
            for h in 1..=9 {
                let mut d = DepthImage::new(w, h);
                for v in d.data.iter_mut() {
                    *v = match rng.random_range(0..6) {
                        0 => 0.0,
                        1 => 2.0 + rng.random_range(0.0..0.01),
                        _ => 1.0 + rng.random_range(0.0..0.05),
                    };
                }
                let mut o = DepthImage::new(1, 1);
                downsample_depth(&d, 0.03, &mut o);
                assert_eq!((o.width, o.height), ((w / 2).max(1), (h / 2).max(1)));
                for oy in 0..o.height {
                    for ox in 0..o.width {
                        let want = halved_at(&d, 3.0 * 0.03f32, ox, oy);
                        assert_eq!(
                            o.at(ox, oy).to_bits(),
                            want.to_bits(),
                            "{w}x{h} ({ox}, {oy})"
                        );
                    }
                }
            }
        }
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
