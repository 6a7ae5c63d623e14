//! Whether the colour agrees with a registration: the chromaticity of the warped source against
//! the target's, patch by patch.
//!
//! A warp that lays the source on the target's surface can still leave the material slid along
//! it; the depth residual is then small and only the colour shows the slide. The source's
//! chromaticity `c_s` (module `chroma`) is splatted where the warp carries each source pixel
//! into the target image (nearest surface wins, hidden points left out), giving the prediction
//! `P`. On square patches of the target the mean squared difference
//!
//! ```text
//! e(d) = mean_x ( C_t(x + d) − P(x) )²
//! ```
//!
//! is what the check reads. Two references make it relative to the pair itself, with nothing
//! fitted to one sensor:
//! - the *floor* `F`: what a fit leaves where the colour does fit. Each patch is searched for its
//!   best shift within half a patch, `min_d e(d)`, and `F` is the tenth percentile of those over
//!   the patches. It holds the sensors' noise, compression and the colour's small changes between
//!   the frames (DeepDeform seq258's floor is 75 times the noise that Immerkær's estimator finds
//!   in its images: their JPEG chroma is smoothed, and the frames differ by more);
//! - the *signal* `S` of a slide of the tolerance `t` (in pixels at the patch's depth, at least
//!   two): the target's own squared difference under a shift of `t` pixels less that under one
//!   pixel, `mean_x (C_t(x + t) − C_t(x))² − mean_x (C_t(x + 1) − C_t(x))²` over the four
//!   directions (both hold the noise twice; their difference is the texture's).
//!
//! A patch is *textured* when `S > M F`, a slide of the tolerance would stand out of the floor
//! ([`MARGIN`] `= M`), and *off* when `e(0) > M F + S`: more is left than the floor and a slide
//! of the tolerance could leave. Flat patches say nothing either way.
//!
//! The floor is the registration's own, so a registration wrong everywhere (every patch slid
//! farther than half a patch) raises it with its errors and reads every patch flat. The whole
//! judged area is therefore also read at once: the correlation (Pearson's `ρ`) of `P` with
//! `C_t` at zero shift over the predicted pixels of the judged patches, and the source's
//! *contrast*, the variance of `P` over half the mean squared difference of horizontally
//! adjacent predicted pixels (about 1 for noise alone, large for a texture; it does not depend
//! on the registration). Correlation is blind to a colour cast and to the chromaticity's
//! scale. Where the contrast exceeds [`MARGIN`] and `ρ <` [`MIN_CORRELATION`], the source's
//! colour does not follow it to where the registration put it: the colour is *unrelated*.

use crate::camera::Camera;
use crate::correlation::pearson;
use crate::image::{GrayImage, VertexMap};
use nalgebra::Vector3;
use rayon::prelude::*;

/// A patch is judged when at least this fraction of its pixels have a prediction.
const MIN_COVERED: f64 = 0.5;
/// How many times the floor a patch's squared difference must exceed, beyond a slide of the
/// tolerance, to be off.
pub const MARGIN: f64 = 4.0;
/// The floor is this quantile of the patches' best fits.
const FLOOR_QUANTILE: f64 = 0.1;
/// A textured source's colour is unrelated to the target's where the registration put it when
/// their correlation is below this: the source's colour explains less than a ninth of the
/// target's variance (NOTES 152: registrations wrong everywhere −0.04–0.16, right ones on real
/// DeepDeform pairs 0.55–0.65 and on generated pairs 0.90–0.99).
pub const MIN_CORRELATION: f64 = 1.0 / 3.0;

/// What the colour says of a registration.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ColourCheck {
    /// Textured patches where the colour agrees.
    pub aligned: usize,
    /// Textured patches where more is left than a slide of the tolerance could leave.
    pub off: usize,
    /// Patches with a prediction but too little texture to say.
    pub flat: usize,
    /// The floor `F`: the squared difference of chromaticity where the colour fits.
    pub floor: f64,
    /// The correlation of the prediction with the target over the judged patches (0 when
    /// either is constant).
    pub correlation: f64,
    /// The source's contrast over the judged patches: the prediction's variance over its
    /// pixel-to-pixel noise (0 when it cannot be read).
    pub contrast: f64,
}

impl ColourCheck {
    /// The fraction of the textured patches that are off (0 with none).
    pub fn fraction_off(&self) -> f64 {
        self.off as f64 / (self.aligned + self.off).max(1) as f64
    }

    /// Whether the source is textured ([`MARGIN`] times its noise) and its colour is unrelated
    /// to the target's where the registration put it (correlation below [`MIN_CORRELATION`]).
    pub fn unrelated(&self) -> bool {
        self.contrast > MARGIN && self.correlation < MIN_CORRELATION
    }
}

/// The registration to check, in the target camera's frame.
pub struct CheckInput<'a> {
    /// The target camera.
    pub camera: &'a Camera,
    /// The target's chromaticity at full resolution (level 0).
    pub target: &'a GrayImage,
    /// The target's vertex map (for which warped points are hidden).
    pub target_vertices: &'a VertexMap,
    /// Each source point's chromaticity (NaN: too dark).
    pub source: &'a [f32],
    /// Where the warp carries each source point.
    pub warped: &'a [Vector3<f64>],
    /// A warped point hides behind the target's surface when it is farther than this (metres).
    pub gate: f64,
}

/// The colour check of `input` on patches of `patch` pixels with the tolerance `tolerance`
/// (metres); `None` when no patch has a prediction.
pub fn check_colour(input: &CheckInput<'_>, patch: usize, tolerance: f64) -> Option<ColourCheck> {
    let (prediction, depth) = splat(input);
    let (w, h) = (prediction.width, prediction.height);
    let patch = patch.max(4);
    let f = 0.5 * (input.camera.fx + input.camera.fy);
    let tiles: Vec<Tile> = (0..h / patch)
        .flat_map(|j| (0..w / patch).map(move |i| (i * patch, j * patch)))
        .filter_map(|corner| Tile::covered(corner, patch, &depth))
        .collect();
    let costs: Vec<(f64, f64, f64)> = tiles
        .par_iter()
        .map(|tile| {
            let (at_zero, best) = tile.search(&prediction, input.target, patch as i64 / 2);
            let t = (tolerance * f / tile.depth).round().max(2.0) as i64;
            (at_zero, best, tile.texture(input.target, t))
        })
        .collect();
    let mut bests: Vec<f64> = costs
        .iter()
        .map(|c| c.1)
        .filter(|b| b.is_finite())
        .collect();
    if bests.is_empty() {
        return None;
    }
    let k = ((bests.len() - 1) as f64 * FLOOR_QUANTILE).round() as usize;
    let floor = *bests.select_nth_unstable_by(k, f64::total_cmp).1;
    let (correlation, contrast) = Moments::over(&tiles, &prediction, input.target).read();
    let mut check = ColourCheck {
        floor,
        correlation,
        contrast,
        ..ColourCheck::default()
    };
    for &(at_zero, _, signal) in &costs {
        if signal <= MARGIN * floor {
            check.flat += 1;
        } else if at_zero > MARGIN * floor + signal {
            check.off += 1;
        } else {
            check.aligned += 1;
        }
    }
    Some(check)
}

/// The source's chromaticity splatted to the nearest target pixel of each visible warped point
/// (NaN: none), and the depth there.
fn splat(input: &CheckInput<'_>) -> (GrayImage, GrayImage) {
    let (w, h) = (input.target.width, input.target.height);
    let mut value = GrayImage::filled(w, h, f32::NAN);
    let mut depth = GrayImage::filled(w, h, f32::INFINITY);
    for (&c, p) in input.source.iter().zip(input.warped) {
        if !c.is_finite() {
            continue;
        }
        let Some((x, y)) = input.camera.project_to_pixel(&(*p).into()) else {
            continue;
        };
        if x >= w || y >= h {
            continue;
        }
        let seen = input.target_vertices.at(x, y)[2] as f64;
        let visible = seen.is_finite() && seen > 0.0 && p.z <= seen + input.gate;
        if visible && (p.z as f32) < depth.at(x, y) {
            depth.set(x, y, p.z as f32);
            value.set(x, y, c);
        }
    }
    (value, depth)
}

/// Sums over the predicted pixels of the judged patches: `[n, Σp, Σt, Σp², Σt², Σpt]` of the
/// prediction `p` and the target `t`, and the count and sum of the squared differences of
/// horizontally adjacent `p`.
#[derive(Default)]
struct Moments {
    sums: [f64; 6],
    steps: f64,
    step_sq: f64,
}

impl Moments {
    fn over(tiles: &[Tile], prediction: &GrayImage, target: &GrayImage) -> Self {
        let mut m = Self::default();
        for (x, y) in tiles.iter().flat_map(Tile::pixels) {
            let p = prediction.at(x, y) as f64;
            if !p.is_finite() {
                continue;
            }
            let t = target.at(x, y) as f64;
            for (slot, v) in m.sums.iter_mut().zip([1.0, p, t, p * p, t * t, p * t]) {
                *slot += v;
            }
            let next = if x + 1 < prediction.width {
                prediction.at(x + 1, y) as f64
            } else {
                f64::NAN
            };
            if next.is_finite() {
                m.steps += 1.0;
                m.step_sq += (next - p) * (next - p);
            }
        }
        m
    }

    /// Pearson's correlation of `p` with `t` (module `correlation`), and the contrast
    /// `var(p) / (½ mean step²)` (0 when it cannot be read).
    fn read(&self) -> (f64, f64) {
        let [n, sp, _, spp, ..] = self.sums;
        let variance = if n > 0.0 {
            (spp / n - (sp / n).powi(2)).max(0.0)
        } else {
            0.0
        };
        let noise = 0.5 * self.step_sq / self.steps.max(1.0);
        let contrast = if noise > 0.0 { variance / noise } else { 0.0 };
        (pearson(self.sums), contrast)
    }
}

/// A square patch of the target image, with the mean depth of its predicted pixels.
struct Tile {
    corner: (usize, usize),
    size: usize,
    depth: f64,
}

impl Tile {
    /// The patch at `corner`, when at least [`MIN_COVERED`] of it is predicted.
    fn covered(corner: (usize, usize), size: usize, depth: &GrayImage) -> Option<Self> {
        let mut tile = Self {
            corner,
            size,
            depth: 0.0,
        };
        let (sum, n) = tile
            .pixels()
            .map(|(x, y)| depth.at(x, y))
            .filter(|z| z.is_finite())
            .fold((0.0, 0usize), |(s, n), z| (s + z as f64, n + 1));
        tile.depth = sum / n.max(1) as f64;
        (n as f64 >= MIN_COVERED * (size * size) as f64).then_some(tile)
    }

    fn pixels(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        let (x0, y0) = self.corner;
        (y0..y0 + self.size).flat_map(move |y| (x0..x0 + self.size).map(move |x| (x, y)))
    }

    /// The mean squared difference between `reference` (NaN: none) and `image` shifted by
    /// `(dx, dy)` pixels, over the patch's pixels whose shifted position is in the image
    /// (infinite when fewer than [`MIN_COVERED`] of the patch's).
    fn cost(&self, reference: &GrayImage, image: &GrayImage, (dx, dy): (i64, i64)) -> f64 {
        let (w, h) = (image.width as i64, image.height as i64);
        let (mut sum, mut n) = (0.0, 0usize);
        for (x, y) in self.pixels() {
            let p = reference.at(x, y);
            let (tx, ty) = (x as i64 + dx, y as i64 + dy);
            if p.is_finite() && (0..w).contains(&tx) && (0..h).contains(&ty) {
                let d = (image.at(tx as usize, ty as usize) - p) as f64;
                sum += d * d;
                n += 1;
            }
        }
        if (n as f64) < MIN_COVERED * (self.size * self.size) as f64 {
            return f64::INFINITY;
        }
        sum / n as f64
    }

    /// `e(0)` and the least `e(d)` over the shifts within `reach` pixels: every second one, then
    /// the neighbours of the best.
    fn search(&self, prediction: &GrayImage, target: &GrayImage, reach: i64) -> (f64, f64) {
        let at_zero = self.cost(prediction, target, (0, 0));
        let (mut best, mut shift) = (at_zero, (0, 0));
        for dy in (-reach..=reach).step_by(2) {
            for dx in (-reach..=reach).step_by(2) {
                let c = self.cost(prediction, target, (dx, dy));
                if c < best {
                    (best, shift) = (c, (dx, dy));
                }
            }
        }
        let coarse = shift;
        for dy in -1..=1 {
            for dx in -1..=1 {
                best = best.min(self.cost(prediction, target, (coarse.0 + dx, coarse.1 + dy)));
            }
        }
        (at_zero, best)
    }

    /// The signal `S` of a slide of `t` pixels: the target's squared difference with itself
    /// shifted by `t` less that shifted by one pixel, over the four directions (at least 0).
    fn texture(&self, target: &GrayImage, t: i64) -> f64 {
        let at = |d: i64| {
            [(d, 0), (-d, 0), (0, d), (0, -d)]
                .iter()
                .map(|&s| self.cost(target, target, s))
                .sum::<f64>()
                / 4.0
        };
        let s = at(t) - at(1);
        if s.is_finite() {
            s.max(0.0)
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nonrigid::chroma::{chromaticity, ChromaImage};
    use std::f64::consts::PI;

    /// A plane 1.5 m in front of the camera whose colour has a smooth two-dimensional pattern
    /// of chromaticity, seen by the source and by the target, each with its own noise of a few
    /// levels per channel; the target's red channel is scaled by `cast` (a white balance).
    /// The registration under test carries each source point `offset` (metres, in the plane)
    /// from where it truly lands.
    struct Plane {
        camera: Camera,
        target: GrayImage,
        vertices: VertexMap,
        source: Vec<f32>,
        warped: Vec<Vector3<f64>>,
    }

    /// A few levels of noise, fixed by the pixel and the frame.
    fn noise(i: usize, frame: usize) -> f64 {
        let h = (i as u64 ^ (frame as u64) << 40).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        ((h >> 33) % 7) as f64 - 3.0
    }

    fn plane(offset: Vector3<f64>, cast: f64) -> Plane {
        patterned(offset, cast, 1.0)
    }

    /// [`plane`] with the pattern's amplitude scaled by `texture` (0: a plain colour).
    fn patterned(offset: Vector3<f64>, cast: f64, texture: f64) -> Plane {
        let camera = Camera::tum_default();
        let (w, h, z) = (camera.width, camera.height, 1.5);
        let pattern =
            |x: f64, y: f64| texture * (0.15 * (x * 40.0).sin() + 0.12 * (y * 31.0 + 0.3).cos());
        let colour_of = |c: f64, i: usize, frame: usize, red: f64| {
            // R + G + B = 300 and R − B = 300 c, then noise on each channel
            let rgb = [100.0 + 150.0 * c, 100.0, 100.0 - 150.0 * c];
            let mut out = [0u8; 3];
            for (k, (o, v)) in out.iter_mut().zip(rgb).enumerate() {
                let gain = if k == 0 { red } else { 1.0 };
                *o = (gain * v + noise(3 * i + k, frame))
                    .round()
                    .clamp(0.0, 255.0) as u8;
            }
            out
        };
        let mut colour = crate::image::ColorImage::filled(w, h, [0, 0, 0]);
        let mut vertices = VertexMap::filled(w, h, [f32::NAN; 3]);
        let (mut source, mut warped) = (Vec::new(), Vec::new());
        for i in 0..w * h {
            let (px, py) = (i % w, i / w);
            let x = (px as f64 - camera.cx) * z / camera.fx;
            let y = (py as f64 - camera.cy) * z / camera.fy;
            let c = pattern(x, y);
            colour.data[i] = colour_of(c, i, 1, cast);
            vertices.data[i] = [x as f32, y as f32, z as f32];
            // the source point that truly lands at this pixel showed the same colour
            source.push(chromaticity(colour_of(c, i, 0, 1.0)).unwrap_or(f32::NAN));
            warped.push(Vector3::new(x, y, z) + offset);
        }
        let mut target = ChromaImage::default();
        target.compute(&colour, 0);
        Plane {
            camera,
            target: target.image,
            vertices,
            source,
            warped,
        }
    }

    impl Plane {
        fn check(&self, tolerance: f64) -> Option<ColourCheck> {
            let input = CheckInput {
                camera: &self.camera,
                target: &self.target,
                target_vertices: &self.vertices,
                source: &self.source,
                warped: &self.warped,
                gate: 0.05,
            };
            check_colour(&input, 32, tolerance)
        }
    }

    fn check(offset: Vector3<f64>, cast: f64, tolerance: f64) -> ColourCheck {
        plane(offset, cast)
            .check(tolerance)
            .expect("the plane fills the view")
    }

    #[test]
    fn a_slide_longer_than_the_tolerance_is_off_and_a_shorter_one_is_not() {
        let exact = check(Vector3::zeros(), 1.0, 0.01);
        assert!(exact.aligned > 100 && exact.off == 0, "{exact:?}");
        let long = check(Vector3::new(0.025, 0.0, 0.0), 1.0, 0.01);
        assert!(long.fraction_off() > 0.8, "{long:?}");
        let short = check(Vector3::new(0.01, 0.0, 0.0), 1.0, 0.025);
        assert!(short.fraction_off() < 0.05, "{short:?}");
    }

    #[test]
    fn a_colour_cast_between_the_frames_is_not_a_slide() {
        let cast = check(Vector3::zeros(), 1.06, 0.01);
        assert!(cast.aligned > 100 && cast.fraction_off() < 0.05, "{cast:?}");
    }

    /// Slid by half the pattern's period along both axes (7.9 and 10.1 cm, farther than half
    /// a patch, 4.6 cm here), every patch's colour is wrong and the floor rises with them; the
    /// correlation over the whole area tells.
    #[test]
    fn a_colour_wrong_everywhere_is_unrelated_and_a_plain_one_is_not_judged() {
        let half = Vector3::new(PI / 40.0, PI / 31.0, 0.0);
        let slid = check(half, 1.0, 0.01);
        assert!(slid.unrelated(), "{slid:?}");
        let exact = check(Vector3::zeros(), 1.06, 0.01);
        assert!(exact.correlation > 0.9 && !exact.unrelated(), "{exact:?}");
        let plain = patterned(half, 1.0, 0.0).check(0.01).expect("in view");
        assert!(plain.contrast < MARGIN && !plain.unrelated(), "{plain:?}");
    }

    #[test]
    fn nothing_in_view_has_no_check() {
        let mut p = plane(Vector3::zeros(), 1.0);
        for w in &mut p.warped {
            w.z = -1.0;
        }
        assert_eq!(p.check(0.01), None);
    }
}
