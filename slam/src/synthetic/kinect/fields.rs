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

/// Convolves every row (length `width`) with the odd kernel `k`, clamping at the ends.
fn convolve_rows(src: &[f32], width: usize, k: &[f32]) -> Vec<f32> {
    let r = (k.len() / 2) as isize;
    let mut out = vec![0f32; src.len()];
    out.par_chunks_mut(width)
        .zip(src.par_chunks(width))
        .for_each(|(o, s)| {
            for (x, dst) in o.iter_mut().enumerate() {
                let mut acc = 0.0;
                for (j, w) in k.iter().enumerate() {
                    let xi = (x as isize + j as isize - r).clamp(0, width as isize - 1);
                    acc += w * s[xi as usize];
                }
                *dst = acc;
            }
        });
    out
}

fn transpose(src: &[f32], width: usize, height: usize) -> Vec<f32> {
    let mut out = vec![0f32; src.len()];
    out.par_chunks_mut(height).enumerate().for_each(|(x, col)| {
        for (y, dst) in col.iter_mut().enumerate() {
            *dst = src[y * width + x];
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

    #[test]
    fn the_upper_quantile_leaves_the_wanted_fraction_above() {
        let f = white(100, 100, 3, 0);
        let t = upper_quantile(&f, 0.02);
        let above = f.iter().filter(|&&x| x > t).count();
        assert!((195..=200).contains(&above), "{above}");
    }
}
