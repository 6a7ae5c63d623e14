//! The live frame's brightness against the model's: an exposure gain and the lens' vignetting.
//!
//! A sensor records l = g (1 − v ρ²) I at a pixel whose squared distance from the principal point
//! (cx, cy) is ρ² (cx² + cy²): g its exposure gain, v the darkening towards the corners
//! (vignetting, the r² term of the radial falloff; Goldman, *Vignette and exposure calibration
//! and compensation*, PAMI 2010, and the photometric model of Engel et al., *A photometrically
//! calibrated benchmark for monocular visual odometry*, 2016). The model's colours are averages
//! over many views, in which a surface point sat at every place of the image, so its own
//! vignetting is nearly flat. The ratio live / model is then p + q ρ², a line in ρ², and the
//! live intensity is carried onto the model's by l / (p + q ρ²). A lens' falloff does not change
//! from frame to frame, so the tracker averages the frames' fits of v and fits each frame's gain
//! with the average (`rigid::tracker`).
//!
//! Why it matters: a smoothly textured wall holds the motion along itself only through its
//! texture, and an uncorrected falloff of 30 % in the corners is a brightness gradient fixed to
//! the image, which the photometric term reads as a slide of the camera (NOTES 87).

/// Samples at least, for a fit of anything.
const MIN_SAMPLES: usize = 100;
/// ρ² is split into this many bins of equal width over [0, 1] (the last takes the corners
/// beyond 1).
const BINS: usize = 8;
/// A bin with fewer samples takes no part in the line.
const MIN_BIN_SAMPLES: usize = 15;
/// Vignetting fitted outside this range is taken as a failed fit (no lens darkens its
/// corners by more than 70 %; brighter corners than centre beyond 30 % are not a lens).
const VIGNETTING_RANGE: (f64, f64) = (-0.3, 0.7);
/// The falloff is taken no lower than this (a fifth of the centre's brightness).
const MIN_FALLOFF: f64 = 0.2;
/// Gains outside this range are implausible (the exposure fit of NOTES 60).
const GAIN_RANGE: (f64, f64) = (0.5, 2.0);

/// How the live intensities are carried onto the model's: l ↦ l · gain / (1 − vignetting ρ²).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Exposure {
    /// Model over live at the principal point (1/p).
    pub gain: f64,
    /// v of the live frame's falloff 1 − v ρ² relative to the model's (−q/p).
    pub vignetting: f64,
}

impl Default for Exposure {
    fn default() -> Self {
        Self::NEUTRAL
    }
}

impl Exposure {
    /// The live intensities as they are.
    pub const NEUTRAL: Exposure = Exposure {
        gain: 1.0,
        vignetting: 0.0,
    };

    /// The gain over the whole image: the factor at ρ² = 1/3, the mean of ρ² over the image's
    /// rectangle about the principal point ((cx²/3 + cy²/3) / (cx² + cy²)), which is what one
    /// gain fitted without the falloff measures.
    pub fn image_gain(&self) -> f64 {
        self.factor(1.0 / 3.0)
    }

    /// The factor that carries a live intensity at normalised squared radius `rho2` onto the
    /// model's.
    #[inline]
    pub fn factor(&self, rho2: f64) -> f64 {
        self.gain / falloff(self.vignetting, rho2)
    }

    /// The falloff v seen in `samples` of (ρ², live / model): per bin of ρ² the median ratio (a
    /// ratio is blind to contrast, and the median to speculars, occlusions and the model's
    /// uncoloured edges; NOTES 60), then the line p + q ρ² through the bins' medians by least
    /// squares weighted by their counts, v = −q/p. `None` when there are too few samples, when
    /// the bins do not span enough of the image to show a falloff, or when the line's is
    /// implausible. Reorders `samples`.
    pub fn fit_vignetting(samples: &mut [(f32, f32)]) -> Option<f64> {
        if samples.len() < MIN_SAMPLES {
            return None;
        }
        let (p, q) = fit_line(samples)?;
        let v = -q / p;
        (v.is_finite() && (VIGNETTING_RANGE.0..=VIGNETTING_RANGE.1).contains(&v)).then_some(v)
    }

    /// The exposure of falloff `vignetting` whose gain is the median of the `samples`' ratios
    /// with that falloff taken out; neutral when there are too few samples or the gain is
    /// implausible. Reorders `samples`.
    pub fn with_vignetting(samples: &mut [(f32, f32)], vignetting: f64) -> Exposure {
        if samples.len() < MIN_SAMPLES {
            return Self::NEUTRAL;
        }
        for s in samples.iter_mut() {
            s.1 /= falloff(vignetting, s.0 as f64) as f32;
        }
        let gain = 1.0 / median_ratio(samples) as f64;
        if (GAIN_RANGE.0..=GAIN_RANGE.1).contains(&gain) {
            Exposure { gain, vignetting }
        } else {
            Self::NEUTRAL
        }
    }
}

/// 1 − v ρ², kept above [`MIN_FALLOFF`] where a principal point far from the image's centre
/// puts corners at ρ² well beyond 1.
#[inline]
fn falloff(vignetting: f64, rho2: f64) -> f64 {
    (1.0 - vignetting * rho2).max(MIN_FALLOFF)
}

/// The line p + q x through the bins' median ratios (weighted by count), if at least three bins
/// spanning at least a third of [0, 1] have enough samples.
fn fit_line(samples: &mut [(f32, f32)]) -> Option<(f64, f64)> {
    let bin = |x: f32| ((x.max(0.0) * BINS as f32) as usize).min(BINS - 1);
    samples.sort_unstable_by_key(|s| bin(s.0));
    let (mut sw, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let (mut lo, mut hi, mut bins) = (f64::INFINITY, f64::NEG_INFINITY, 0);
    for chunk in samples.chunk_by_mut(|a, b| bin(a.0) == bin(b.0)) {
        if chunk.len() < MIN_BIN_SAMPLES {
            continue;
        }
        let w = chunk.len() as f64;
        let x = chunk.iter().map(|s| s.0 as f64).sum::<f64>() / w;
        let y = median_ratio(chunk) as f64;
        (sw, sx, sy, sxx, sxy) = (
            sw + w,
            sx + w * x,
            sy + w * y,
            sxx + w * x * x,
            sxy + w * x * y,
        );
        (lo, hi, bins) = (lo.min(x), hi.max(x), bins + 1);
    }
    let det = sw * sxx - sx * sx;
    if bins < 3 || hi - lo < 1.0 / 3.0 || det <= 0.0 {
        return None;
    }
    let q = (sw * sxy - sx * sy) / det;
    let p = (sy - q * sx) / sw;
    (p > 0.0).then_some((p, q))
}

/// The median ratio of the samples (the upper one of an even count), found in place.
fn median_ratio(samples: &mut [(f32, f32)]) -> f32 {
    let n = samples.len();
    let (_, m, _) = samples.select_nth_unstable_by(n / 2, |a, b| a.1.total_cmp(&b.1));
    m.1
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Samples spread over the image of a live frame with gain `g` and vignetting `v` against a
    /// flat model, ratios with 3 % noise and a tenth of them wild.
    fn samples(g: f64, v: f64, n: usize, seed: u64) -> Vec<(f32, f32)> {
        samples_within(1.0, g, v, n, seed)
    }

    /// [`samples`] at ρ² up to `reach`.
    fn samples_within(reach: f64, g: f64, v: f64, n: usize, seed: u64) -> Vec<(f32, f32)> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                let rho2: f64 = rng.random_range(0.0..reach);
                let mut ratio = g * (1.0 - v * rho2) * (1.0 + 0.03 * rng.random_range(-1.0..1.0));
                if rng.random_range(0.0..1.0) < 0.1 {
                    ratio *= rng.random_range(0.2..3.0);
                }
                (rho2 as f32, ratio as f32)
            })
            .collect()
    }

    /// The fit of the falloff, then of the gain with it.
    fn fit(samples: &mut [(f32, f32)]) -> Exposure {
        let v = Exposure::fit_vignetting(samples).unwrap_or(0.0);
        Exposure::with_vignetting(samples, v)
    }

    #[test]
    fn gain_and_vignetting_are_recovered_among_outliers() {
        for (g, v) in [(1.0, 0.3), (0.8, 0.0), (1.2, 0.5), (1.0, -0.1)] {
            let e = fit(&mut samples(g, v, 2000, 3));
            assert!((e.gain - 1.0 / g).abs() < 0.02, "gain {} for {g}", e.gain);
            assert!(
                (e.vignetting - v).abs() < 0.03,
                "vignetting {} for {v}",
                e.vignetting
            );
            // the factor carries the live intensity onto the model's at every radius
            for rho2 in [0.0, 0.5, 1.0] {
                let live = g * (1.0 - v * rho2);
                assert!((live * e.factor(rho2) - 1.0).abs() < 0.03);
            }
        }
    }

    #[test]
    fn without_a_spread_of_radii_no_falloff_is_fitted() {
        // every sample near the centre (ρ² < 0.2): too little of the falloff to fit it
        assert_eq!(
            Exposure::fit_vignetting(&mut samples_within(0.2, 0.9, 0.3, 500, 5)),
            None
        );
        // the gain alone is then the median ratio, 0.9 (1 − 0.3 · 0.1)
        let e = Exposure::with_vignetting(&mut samples_within(0.2, 0.9, 0.3, 500, 5), 0.0);
        assert!((e.gain - 1.0 / 0.873).abs() < 0.03, "gain {}", e.gain);
        // with the falloff given, the gain is the centre's
        let e = Exposure::with_vignetting(&mut samples_within(0.2, 0.9, 0.3, 500, 5), 0.3);
        assert!((e.gain - 1.0 / 0.9).abs() < 0.03, "gain {}", e.gain);
    }

    #[test]
    fn too_few_samples_or_an_implausible_fit_are_refused() {
        assert_eq!(
            Exposure::fit_vignetting(&mut samples(1.0, 0.3, 50, 1)),
            None
        );
        assert_eq!(
            Exposure::with_vignetting(&mut samples(1.0, 0.3, 50, 1), 0.3),
            Exposure::NEUTRAL
        );
        assert_eq!(
            Exposure::with_vignetting(&mut samples(3.0, 0.0, 2000, 1), 0.0),
            Exposure::NEUTRAL
        );
        // a falloff no lens has
        assert_eq!(
            Exposure::fit_vignetting(&mut samples(1.0, 0.95, 2000, 1)),
            None
        );
        // corners far beyond ρ² = 1 (a principal point near the image's edge) stay finite
        let e = Exposure {
            gain: 1.0,
            vignetting: 0.5,
        };
        assert!(e.factor(10.0).is_finite() && e.factor(10.0) <= 1.0 / MIN_FALLOFF);
    }
}
