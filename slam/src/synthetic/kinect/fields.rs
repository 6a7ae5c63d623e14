//! Seeded random images for the sensor model: white Gaussian noise and spatially correlated
//! Gaussian noise (white noise smoothed by a Gaussian kernel and rescaled to unit variance), filled
//! row by row in parallel from per-row streams, so an image is the same whatever the thread count.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

/// SplitMix64's finaliser: decorrelates seeds that differ in a few bits.
pub(crate) fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The generator of row `row` of the stream `(seed, stream)`.
pub(crate) fn row_rng(seed: u64, stream: u64, row: usize) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(mix(mix(seed ^ mix(stream)) ^ row as u64))
}

/// A `width` × `height` image of independent standard normal samples.
pub(crate) fn white(width: usize, height: usize, seed: u64, stream: u64) -> Vec<f32> {
    let mut out = vec![0f32; width * height];
    out.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(v, row)| {
            let mut rng = row_rng(seed, stream, v);
            for x in row.iter_mut() {
                *x = StandardNormal.sample(&mut rng);
            }
        });
    out
}

/// Standard normal noise correlated over about `sigma` pixels: white noise convolved with a
/// Gaussian of standard deviation `sigma` (separable, radius ⌈2.5 σ⌉) and divided by the kernel's
/// ‖k‖², so each pixel still has unit variance. `sigma` ≤ 0.3 gives white noise.
pub(crate) fn correlated(
    width: usize,
    height: usize,
    sigma: f64,
    seed: u64,
    stream: u64,
) -> Vec<f32> {
    let mut noise = white(width, height, seed, stream);
    if sigma <= 0.3 {
        return noise;
    }
    let energy = blur(&mut noise, width, height, sigma);
    noise.par_iter_mut().for_each(|x| *x /= energy); // separable: variance energy², std energy
    noise
}

/// Convolves the image in place with a normalised Gaussian of standard deviation `sigma` pixels
/// (separable, radius ⌈2.5 σ⌉, clamped at the borders); returns the 1-D kernel's Σ k².
pub(crate) fn blur(image: &mut [f32], width: usize, height: usize, sigma: f64) -> f32 {
    if sigma <= 0.0 || image.is_empty() {
        return 1.0;
    }
    let r = (2.5 * sigma).ceil() as isize;
    let mut k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let sum: f32 = k.iter().sum();
    k.iter_mut().for_each(|x| *x /= sum);
    let blur_rows = convolve_rows(image, width, &k);
    let t = transpose(&blur_rows, width, height);
    let blur_cols = convolve_rows(&t, height, &k);
    image.copy_from_slice(&transpose(&blur_cols, height, width));
    k.iter().map(|x| x * x).sum()
}

/// Convolves every row (length `width`) with the odd kernel `k`, clamping at the ends. Pixels
/// whose window lies inside the row read it as one slice; the others clamp each tap. Both sum the
/// taps in the kernel's order, so every pixel gets the same bits either way.
fn convolve_rows(src: &[f32], width: usize, k: &[f32]) -> Vec<f32> {
    let r = k.len() / 2;
    let mut out = vec![0f32; src.len()];
    out.par_chunks_mut(width)
        .zip(src.par_chunks(width))
        .for_each(|(o, s)| {
            let clamped = |x: usize| {
                k.iter().enumerate().fold(0.0, |acc, (j, w)| {
                    let xi = (x + j).saturating_sub(r).min(width - 1);
                    acc + w * s[xi]
                })
            };
            let lo = r.min(width);
            let inside = lo..width.saturating_sub(r).max(lo);
            for x in (0..width).filter(|x| !inside.contains(x)) {
                o[x] = clamped(x);
            }
            let (o, n) = (&mut o[inside], k.len());
            // eight pixels at a time, each its own sum: independent additions in flight
            let done = o.len() / LANES * LANES;
            for (b, dst) in o.chunks_exact_mut(LANES).enumerate() {
                let mut acc = [0f32; LANES];
                for (j, w) in k.iter().enumerate() {
                    let src = &s[b * LANES + j..][..LANES];
                    for (a, v) in acc.iter_mut().zip(src) {
                        *a += w * v;
                    }
                }
                dst.copy_from_slice(&acc);
            }
            for (dst, window) in o[done..].iter_mut().zip(s[done..].windows(n)) {
                *dst = k.iter().zip(window).fold(0.0, |acc, (w, v)| acc + w * v);
            }
        });
    out
}

/// Pixels convolved side by side in [`convolve_rows`].
const LANES: usize = 8;

/// The `width` × `height` image transposed, in tiles that stay in cache.
fn transpose(src: &[f32], width: usize, height: usize) -> Vec<f32> {
    const TILE: usize = 32;
    let mut out = vec![0f32; src.len()];
    out.par_chunks_mut(height * TILE)
        .enumerate()
        .for_each(|(band, cols)| {
            let x0 = band * TILE;
            for y0 in (0..height).step_by(TILE) {
                for (dx, col) in cols.chunks_mut(height).enumerate() {
                    let x = x0 + dx;
                    for y in y0..(y0 + TILE).min(height) {
                        col[y] = src[y * width + x];
                    }
                }
            }
        });
    out
}

/// The value that a fraction `p` of `field` exceeds (an order statistic; `p` in (0, 1)).
pub(crate) fn upper_quantile(field: &[f32], p: f64) -> f32 {
    if field.is_empty() {
        return f32::INFINITY;
    }
    let mut v = field.to_vec();
    let k = (((1.0 - p) * v.len() as f64) as usize).min(v.len() - 1);
    *v.select_nth_unstable_by(k, f32::total_cmp).1
}

#[cfg(test)]
mod tests {
    use super::*;

    fn moments(x: &[f32]) -> (f64, f64) {
        let n = x.len() as f64;
        let m = x.iter().map(|&v| v as f64).sum::<f64>() / n;
        let v = x.iter().map(|&v| (v as f64 - m).powi(2)).sum::<f64>() / n;
        (m, v)
    }

    #[test]
    fn correlated_noise_has_unit_variance_and_neighbours_agree() {
        let (w, h) = (200, 150);
        let f = correlated(w, h, 2.0, 7, 1);
        let (m, v) = moments(&f);
        assert!(m.abs() < 0.15 && (v - 1.0).abs() < 0.2, "mean {m} var {v}");
        // the correlation of horizontal neighbours of a Gaussian-smoothed field is exp(-1/(4σ²))
        let mut c = 0.0;
        for y in 0..h {
            for x in 0..w - 1 {
                c += (f[y * w + x] * f[y * w + x + 1]) as f64;
            }
        }
        let rho = c / (h * (w - 1)) as f64 / v;
        let expected = (-1.0f64 / 16.0).exp();
        assert!((rho - expected).abs() < 0.05, "rho {rho} vs {expected}");
        assert_eq!(f, correlated(w, h, 2.0, 7, 1), "deterministic");
        assert_ne!(f, correlated(w, h, 2.0, 8, 1), "seeded");
    }

    /// Every tap clamped to the row, in the kernel's order.
    fn convolve_rows_clamping_every_tap(src: &[f32], width: usize, k: &[f32]) -> Vec<f32> {
        let r = (k.len() / 2) as isize;
        let mut out = vec![0f32; src.len()];
        for (o, s) in out.chunks_mut(width).zip(src.chunks(width)) {
            for (x, dst) in o.iter_mut().enumerate() {
                let mut acc = 0.0;
                for (j, w) in k.iter().enumerate() {
                    let xi = (x as isize + j as isize - r).clamp(0, width as isize - 1);
                    acc += w * s[xi as usize];
                }
                *dst = acc;
            }
        }
        out
    }

    #[test]
    fn rows_convolved_through_slices_are_the_clamped_convolution_to_the_bit() {
        let k = [0.05f32, 0.2, 0.5, 0.2, 0.05, 0.0, 0.001];
        // rows narrower than the kernel, as wide, and wider; kernels of one to seven taps
        for (width, height) in [(1, 3), (3, 2), (6, 4), (7, 5), (40, 9), (97, 33)] {
            let src = white(width, height, 5, width as u64);
            for taps in [1, 3, 5, 7] {
                let k = &k[..taps];
                let fast = convolve_rows(&src, width, k);
                let reference = convolve_rows_clamping_every_tap(&src, width, k);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(
                    bits(&fast),
                    bits(&reference),
                    "{width} x {height}, {taps} taps"
                );
            }
            let t = transpose(&src, width, height);
            for (y, x) in (0..height).flat_map(|y| (0..width).map(move |x| (y, x))) {
                assert_eq!(t[x * height + y], src[y * width + x]);
            }
            assert_eq!(transpose(&t, height, width), src, "{width} x {height}");
        }
    }

    #[test]
    fn the_upper_quantile_leaves_the_wanted_fraction_above() {
        let f = white(100, 100, 3, 0);
        let t = upper_quantile(&f, 0.02);
        let above = f.iter().filter(|&&x| x > t).count();
        assert!((195..=200).contains(&above), "{above}");
    }
}
