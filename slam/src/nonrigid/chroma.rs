//! The chromaticity term of non-rigid tracking: colour that neither shading nor exposure moves.
//!
//! The photometric term (module `photometric`) compares each point's intensity over its local
//! mean with a recent tracked frame. That ratio is a high-pass filter: it cancels shading, which
//! is smooth over its window, but also the texture's long waves, and every new reference frame
//! adds its tracking error to the references, so a slide that one frame leaves uncorrected stays.
//!
//! Under white light, shading, the exposure gain and the lens' vignetting multiply the three
//! channels alike, `(R, G, B) = s (ρ_R, ρ_G, ρ_B)`, and cancel at every scale in the
//! chromaticity
//!
//! ```text
//! c = (R − B) / (R + G + B)
//! ```
//!
//! (the red–blue opponent axis of the normalised rgb space of illumination-invariant colour
//! tracking; with gamma-encoded channels `s^γ` factors out all the same). So a point's `c` can
//! be kept from the frame it was first seen in, with no reference frame to walk
//! ([`ChromaReferences`]):
//!
//! ```text
//! r = c(π(W(v))) − c_first(v)
//! ```
//!
//! The first frame's chromaticities are exact for the first frame's surface; a part that comes
//! into view later takes them from the first tracked frame that matches it, with that frame's
//! error once. (The colour fused into the canonical volume was tried as the reference: blurred
//! by the voxels and by every frame's error, it tracked the bending plate to 4.0 mm mean against
//! 1.9 without the term.)
//!
//! A grey surface has `c = 0` everywhere and gives the term nothing; the intensity ratio then
//! still holds what it can.

use super::photometric::LiveIntensity;
use crate::camera::Camera;
use crate::image::{downsample_gray, gradients, ColorImage, GrayImage};
use nalgebra::Vector3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use std::collections::hash_map::Entry;

/// Channel sums (of 765) below which a colour is too dark for its chromaticity to mean anything:
/// the same floor as the ratio's [`super::photometric::DARK`], on the sum of the channels.
const DARK_SUM: f32 = 3.0 * 255.0 * super::photometric::DARK;

/// The chromaticity `(R − B) / (R + G + B)` of a colour, or `None` when it is too dark.
#[inline]
pub fn chromaticity([r, g, b]: [u8; 3]) -> Option<f32> {
    let sum = r as f32 + g as f32 + b as f32;
    (sum >= DARK_SUM).then(|| (r as f32 - b as f32) / sum)
}

/// The live chromaticity at a pyramid level with its gradients; buffers kept across frames.
#[derive(Clone, Default)]
pub struct ChromaImage {
    /// c at the level (0 where the colour is too dark).
    pub image: GrayImage,
    /// ∂c/∂u.
    pub gradient_x: GrayImage,
    /// ∂c/∂v.
    pub gradient_y: GrayImage,
    /// One 8-bit level of the chromaticity at the frame's brightness: 1 / the mean channel sum
    /// `R + G + B` of the pixels bright enough to have a chromaticity (0 when none are). A
    /// residual below it is the colour's quantisation, not a slide.
    pub step: f64,
    spare: GrayImage,
}

impl ChromaImage {
    /// Computes c from `color` at full resolution and halves it `level` times with the
    /// pyramid's 5-tap filter (as the intensity pyramid is), then its gradients, and
    /// [`Self::step`] (whose channel sums are whole numbers, so their sum is exact in any order).
    pub fn compute(&mut self, color: &ColorImage, level: usize) {
        let w = color.width.max(1);
        self.image.resize(color.width, color.height, 0.0);
        // the chromaticity and, in the same pass, the bright pixels' channel sums for `step`
        let (sum, count) = self
            .image
            .data
            .par_chunks_mut(w)
            .zip(color.data.par_chunks(w))
            .map(|(out, line)| {
                let (mut sum, mut count) = (0.0f64, 0usize);
                for (o, &rgb) in out.iter_mut().zip(line) {
                    *o = chromaticity(rgb).unwrap_or(0.0);
                    let s = rgb.iter().map(|&v| v as f32).sum::<f32>();
                    if s >= DARK_SUM {
                        sum += s as f64;
                        count += 1;
                    }
                }
                (sum, count)
            })
            .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        self.step = if count > 0 { count as f64 / sum } else { 0.0 };
        for _ in 0..level {
            downsample_gray(&self.image, &mut self.spare);
            std::mem::swap(&mut self.image, &mut self.spare);
        }
        gradients(&self.image, &mut self.gradient_x, &mut self.gradient_y);
    }

    /// The image as the term samples it, with the intrinsics of its level.
    pub fn live<'a>(&'a self, camera: &'a Camera) -> LiveIntensity<'a> {
        LiveIntensity::of(camera, [&self.image, &self.gradient_x, &self.gradient_y])
    }
}

/// The cube of edge `cell` that holds the canonical point `p`: data points are thinned to one
/// per cube, and a cube keeps its reference across re-samplings.
pub fn cell_key(p: &Vector3<f64>, cell: f64) -> (i64, i64, i64) {
    let k = p.map(|v| (v / cell).floor() as i64);
    (k.x, k.y, k.z)
}

/// The chromaticity each canonical cube was first seen with, and the canonical point it was seen
/// at.
///
/// The data points are re-thinned from the canonical surface as fusion refines it
/// ([`Self::thin`]); the point a cube keeps must be the one its reference was taken at, or the
/// comparison `c(π(W(v))) − c_first` reads the texture up to a cube's diagonal away from where
/// `c_first` was seen: a slide that the references themselves put in (NOTES 135).
#[derive(Clone, Debug, Default)]
pub struct ChromaReferences {
    by_cell: FxHashMap<(i64, i64, i64), Reference>,
}

/// A cube's reference: the chromaticity and where, in the canonical frame, it was seen.
#[derive(Clone, Copy, Debug)]
struct Reference {
    chromaticity: f32,
    at: Vector3<f64>,
}

impl ChromaReferences {
    /// Forgets every reference.
    pub fn clear(&mut self) {
        self.by_cell.clear();
    }

    /// Each canonical point's reference (NaN where its cube has none yet), into `out`.
    pub fn assign(&self, points: &[Vector3<f64>], cell: f64, out: &mut Vec<f32>) {
        out.clear();
        out.extend(points.iter().map(|p| {
            self.by_cell
                .get(&cell_key(p, cell))
                .map_or(f32::NAN, |r| r.chromaticity)
        }));
    }

    /// Thins `surface` (canonical points and normals) to one point per cube of edge `cell`, into
    /// `points` and `normals`: in a cube with a reference, the point nearest where the
    /// reference was seen; elsewhere the first.
    pub fn thin(
        &self,
        (surface, surface_normals): (&[Vector3<f64>], &[Vector3<f64>]),
        cell: f64,
        (points, normals): (&mut Vec<Vector3<f64>>, &mut Vec<Vector3<f64>>),
    ) {
        // per cube: the kept point's index, and where its reference was seen (looked up once)
        let mut kept = FxHashMap::default();
        points.clear();
        normals.clear();
        for (p, n) in surface.iter().zip(surface_normals) {
            let key = cell_key(p, cell);
            match kept.entry(key) {
                Entry::Vacant(e) => {
                    e.insert((points.len(), self.by_cell.get(&key).map(|r| r.at)));
                    points.push(*p);
                    normals.push(*n);
                }
                Entry::Occupied(e) => {
                    let (i, at) = *e.get();
                    if at
                        .is_some_and(|at| (p - at).norm_squared() < (points[i] - at).norm_squared())
                    {
                        points[i] = *p;
                        normals[i] = *n;
                    }
                }
            }
        }
    }

    /// Points without a reference that were `seen` (index and position in the live camera
    /// frame) take the live chromaticity there; `references` (one per point) is updated too.
    pub fn learn(
        &mut self,
        points: &[Vector3<f64>],
        cell: f64,
        seen: impl Iterator<Item = (usize, Vector3<f64>)>,
        live: &LiveIntensity<'_>,
        references: &mut [f32],
    ) {
        for (i, p) in seen {
            if i >= points.len() || references[i].is_finite() {
                continue;
            }
            if let Some((c, _)) = live.sample(&p) {
                references[i] = c as f32;
                let reference = Reference {
                    chromaticity: c as f32,
                    at: points[i],
                };
                self.by_cell.insert(cell_key(&points[i], cell), reference);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;

    #[test]
    fn the_quantisation_step_is_one_level_at_the_bright_pixels_mean_sum() {
        // half the pixels (100, 100, 100), a quarter (200, 200, 200), a quarter too dark to count
        let mut color = Image::filled(8, 4, [100u8, 100, 100]);
        color.data[16..24].fill([200, 200, 200]);
        color.data[24..].fill([1, 1, 1]);
        let mut chroma = ChromaImage::default();
        chroma.compute(&color, 0);
        let mean_sum = (2.0 * 300.0 + 600.0) / 3.0;
        assert!(
            (chroma.step - 1.0 / mean_sum).abs() < 1e-12,
            "{}",
            chroma.step
        );
        chroma.compute(&Image::filled(8, 4, [0u8, 0, 0]), 0);
        assert_eq!(chroma.step, 0.0, "no bright pixel, no step");
    }

    #[test]
    fn a_shading_or_an_exposure_leaves_the_chromaticity_as_it_was() {
        let albedo = [200u8, 120, 60];
        let c = chromaticity(albedo).expect("bright");
        for s in [0.3f32, 0.55, 0.9, 1.2] {
            let shaded = albedo.map(|v| (v as f32 * s).round().min(255.0) as u8);
            let cs = chromaticity(shaded).expect("bright enough");
            // rounding to 8 bits moves it by at most a level of the darkest channel
            assert!((cs - c).abs() < 0.01, "shade {s}: {cs} against {c}");
        }
        assert_eq!(chromaticity([128, 128, 128]), Some(0.0));
        assert!(chromaticity([3, 2, 1]).is_none());
    }

    #[test]
    fn the_image_at_a_level_is_the_pyramid_of_the_chromaticity() {
        // red to blue across the image, under a shading that falls from top to bottom
        let (w, h) = (64, 48);
        let mut color = Image::new(w, h);
        for y in 0..h {
            let s = 1.0 - 0.5 * y as f32 / h as f32;
            for x in 0..w {
                let t = x as f32 / (w - 1) as f32;
                let rgb = [200.0 * (1.0 - t) + 40.0, 100.0, 200.0 * t + 40.0];
                color.set(x, y, rgb.map(|v| (v * s) as u8));
            }
        }
        let mut chroma = ChromaImage::default();
        chroma.compute(&color, 1);
        assert_eq!((chroma.image.width, chroma.image.height), (32, 24));
        for y in 2..22 {
            // the shading changed nothing down a column; red-to-blue falls along a row
            let (a, b) = (chroma.image.at(10, 2), chroma.image.at(10, y));
            assert!((a - b).abs() < 0.02, "row {y}: {b} against {a}");
            assert!(chroma.image.at(20, y) < chroma.image.at(10, y));
            assert!(chroma.gradient_x.at(15, y) < 0.0);
        }
    }

    #[test]
    fn a_cube_keeps_the_chromaticity_it_was_first_seen_with() {
        let camera = crate::camera::Camera::tum_default().level(1);
        let mut image = GrayImage::new(camera.width, camera.height);
        image.data.fill(0.25);
        let mut chroma = ChromaImage {
            image,
            ..ChromaImage::default()
        };
        gradients(
            &chroma.image,
            &mut chroma.gradient_x,
            &mut chroma.gradient_y,
        );
        let cell = 0.01;
        let points = [Vector3::new(0.0, 0.0, 1.0), Vector3::new(0.1, 0.0, 1.0)];
        let mut refs = Vec::new();
        let mut book = ChromaReferences::default();
        book.assign(&points, cell, &mut refs);
        assert!(refs.iter().all(|r| r.is_nan()));
        // only the first point is seen; the second stays without a reference
        book.learn(
            &points,
            cell,
            [(0, points[0])].into_iter(),
            &chroma.live(&camera),
            &mut refs,
        );
        assert_eq!(refs[0], 0.25);
        assert!(refs[1].is_nan());
        // a later frame with another colour does not overwrite it, and a re-sampled point
        // in the same cube finds it
        chroma.image.data.fill(0.5);
        book.learn(
            &points,
            cell,
            [(0, points[0]), (1, points[1])].into_iter(),
            &chroma.live(&camera),
            &mut refs,
        );
        assert_eq!((refs[0], refs[1]), (0.25, 0.5));
        let moved = [
            points[0] + Vector3::new(0.002, 0.003, 0.001),
            points[1],
            Vector3::new(0.5, 0.0, 1.0),
        ];
        book.assign(&moved, cell, &mut refs);
        assert_eq!(refs[..2], [0.25, 0.5]);
        assert!(refs[2].is_nan(), "a cube never seen has no reference");
    }

    #[test]
    fn thinning_keeps_the_point_where_a_cubes_reference_was_seen() {
        let cell = 0.01;
        let a = Vector3::new(0.001, 0.001, 0.0);
        let b = Vector3::new(0.008, 0.007, 0.0);
        let c = Vector3::new(0.005, 0.004, 0.0);
        let next = Vector3::new(0.015, 0.001, 0.0);
        let normals = [Vector3::z(); 4];
        let mut book = ChromaReferences::default();
        let (mut points, mut kept_normals) = (Vec::new(), Vec::new());
        // without a reference, each cube keeps its first point
        book.thin(
            (&[a, b, next], &normals[..3]),
            cell,
            (&mut points, &mut kept_normals),
        );
        assert_eq!(points, [a, next]);
        // with one seen at b, the cube keeps b (or, without b, the point nearest it) wherever
        // it comes in the surface
        let reference = Reference {
            chromaticity: 0.2,
            at: b,
        };
        book.by_cell.insert(cell_key(&b, cell), reference);
        for (surface, kept) in [
            (vec![a, b, next], b),
            (vec![next, b, a], b),
            (vec![a, c, next], c),
            (vec![c, a, next], c),
        ] {
            book.thin(
                (&surface, &normals[..3]),
                cell,
                (&mut points, &mut kept_normals),
            );
            assert_eq!(points.len(), 2);
            assert!(
                points.contains(&kept) && points.contains(&next),
                "{points:?}"
            );
            assert_eq!(kept_normals.len(), 2);
        }
        let mut references = Vec::new();
        book.assign(&points, cell, &mut references);
        let at = |p: &Vector3<f64>| points.iter().position(|q| q == p).unwrap();
        assert_eq!(references[at(&c)], 0.2);
        assert!(references[at(&next)].is_nan());
    }
}
