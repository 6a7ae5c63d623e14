//! The depth image of a structured-light sensor, registered to the colour camera.
//!
//! For each recorded pixel, the sample point is jittered laterally (independent plus correlated
//! parts), its ray is traced through the distorted lens, and the hit becomes a measurement only if
//! the projector lights it and the IR camera sees it (shadow rays to both), the incidence is not
//! grazing and the depth is in range. The disparity in 1/8-pixel steps is
//!
//! ```text
//! d = kq / z + σ_i n_i + σ_c n_c(u, v),   kq = 8 f_ir b,   z_measured = kq / round(d)
//! ```
//!
//! then rounded to whole millimetres (OpenNI's unit) and written at the camera's depth scale. Random
//! blob holes and a dead border are added; holes at a discontinuity narrower than the matching
//! window are filled with the foreground's depth (edge fattening), and flying pixels appear at
//! discontinuities.

use super::fields::{correlated, mix, row_rng, upper_quantile};
use super::{KinectModel, Recorder};
use crate::image::Image;
use crate::synthetic::scene::PreparedScene;
use nalgebra::{Isometry3, Point3, Vector3};
use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

/// Streams of the frame's random images.
const JITTER_U: u64 = 1;
const JITTER_V: u64 = 2;
const DISPARITY: u64 = 3;
const HOLES: u64 = 4;
const PIXEL: u64 = 5;
const FLYING: u64 = 6;
const GRAZING: u64 = 7;

/// The frame's noise images.
struct Noise {
    ju: Vec<f32>,
    jv: Vec<f32>,
    disparity: Vec<f32>,
    holes: Vec<f32>,
    hole_threshold: f32,
    /// Where in the grazing band each pixel's measurement fails (uniform in (0, 1), smooth over
    /// a few pixels, so a steep surface is lost in patches rather than speckled).
    grazing: Vec<f32>,
}

impl Noise {
    fn new(model: &KinectModel, w: usize, h: usize, seed: u64) -> Self {
        let s = KinectModel::pixel_scale(w);
        let holes = correlated(w, h, 1.5 * s, seed, HOLES);
        let hole_threshold = if model.hole_fraction > 0.0 {
            upper_quantile(&holes, model.hole_fraction)
        } else {
            f32::INFINITY
        };
        Self {
            ju: correlated(w, h, 2.0 * s, seed, JITTER_U),
            jv: correlated(w, h, 2.0 * s, seed, JITTER_V),
            disparity: correlated(w, h, model.disparity_correlation * s, seed, DISPARITY),
            holes,
            hole_threshold,
            grazing: correlated(w, h, 3.0 * s, seed, GRAZING)
                .into_iter()
                .map(normal_cdf)
                .collect(),
        }
    }
}

/// Captures the raw depth of `scene` seen from `pose` (camera-to-scene) as frame `frame`.
pub fn capture(
    rec: &Recorder,
    scene: &PreparedScene,
    pose: &Isometry3<f64>,
    frame: usize,
) -> Image<u16> {
    let (model, camera) = (rec.model, &rec.camera);
    let (w, h) = (camera.width, camera.height);
    let seed = mix(model.seed ^ mix(frame as u64 ^ 0xD0));
    let noise = Noise::new(model, w, h, seed);
    // the shadow rays run to the projector and the infrared camera
    let eyes = model
        .ir_offset
        .abs()
        .max((model.ir_offset + model.baseline).abs());
    let scene = &scene.within(&rec.rays.cone(pose, eyes));
    let mut z = vec![0f32; w * h];
    z.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        let mut rng = row_rng(seed, PIXEL, v);
        for (u, out) in row.iter_mut().enumerate() {
            *out = measure(rec, scene, pose, &noise, (u, v), &mut rng).unwrap_or(0.0);
        }
    });
    let s = KinectModel::pixel_scale(w);
    z.par_chunks_mut(w)
        .for_each(|row| fill_narrow_holes(model, row, model.window_fill * s));
    let z = add_flying_pixels(model, &z, w, h, seed);
    let mut raw = Image::new(w, h);
    for (r, &d) in raw.data.iter_mut().zip(&z) {
        let q = (d as f64 * camera.depth_scale).round();
        if q >= 1.0 && q <= u16::MAX as f64 {
            *r = q as u16;
        }
    }
    raw
}

/// The depth measured at pixel (u, v), or `None` for a hole.
fn measure<R: rand::Rng>(
    rec: &Recorder,
    scene: &PreparedScene,
    pose: &Isometry3<f64>,
    noise: &Noise,
    (u, v): (usize, usize),
    rng: &mut R,
) -> Option<f32> {
    let (model, camera) = (rec.model, &rec.camera);
    let (w, h) = (camera.width, camera.height);
    let s = KinectModel::pixel_scale(w);
    let [left, right, top, bottom] = model.dead_border.map(|b| b * s);
    let (uf, vf) = (u as f64, v as f64);
    if uf < left || uf >= w as f64 - right || vf < top || vf >= h as f64 - bottom {
        return None;
    }
    let i = v * w + u;
    if noise.holes[i] > noise.hole_threshold {
        return None;
    }
    let pu = uf + s * (model.jitter * gauss(rng) + model.jitter_correlated * noise.ju[i] as f64);
    let pv = vf + s * (model.jitter * gauss(rng) + model.jitter_correlated * noise.jv[i] as f64);
    let ray = rec.rays.at(pu, pv)?;
    let dir = pose.rotation * ray.normalize();
    let origin = Point3::from(pose.translation.vector);
    let (_, point, normal) = scene.surface(&origin, &dir)?;
    let z = (pose.inverse() * point).z;
    let fade = (z - model.range.1) / (model.range_limit - model.range.1);
    if z < model.range.0 || z >= model.range_limit || (fade > 0.0 && rng.random::<f64>() < fade) {
        return None;
    }
    let angle = (-normal.dot(&dir)).clamp(-1.0, 1.0).acos().to_degrees();
    let (g0, g1) = model.grazing;
    if angle > g0 + (g1 - g0) * noise.grazing[i] as f64 {
        return None;
    }
    let ir = pose * Point3::new(model.ir_offset, 0.0, 0.0);
    let projector = pose * Point3::new(model.ir_offset + model.baseline, 0.0, 0.0);
    if !visible(scene, &point, &normal, &projector) || !visible(scene, &point, &normal, &ir) {
        return None;
    }
    let kq = model.kq();
    let d = kq / z
        + model.disparity_sigma * gauss(rng)
        + model.disparity_sigma_correlated * noise.disparity[i] as f64;
    let steps = d.round();
    if steps < 1.0 {
        return None;
    }
    let mut zq = kq / steps;
    if model.millimetres {
        zq = (zq * 1000.0).round() / 1000.0;
    }
    Some(zq as f32)
}

/// The standard normal distribution function, by the logistic approximation Φ(x) ≈ 1 / (1 +
/// e^(−1.702 x)) (within 0.01 everywhere; Bowling et al., J. Ind. Eng. Manag. 2009).
fn normal_cdf(x: f32) -> f32 {
    1.0 / (1.0 + (-1.702 * x).exp())
}

/// A standard normal sample.
fn gauss<R: rand::Rng + ?Sized>(rng: &mut R) -> f64 {
    StandardNormal.sample(rng)
}

/// Whether nothing stands between the hit and `eye`, and the surface faces it.
fn visible(
    scene: &PreparedScene,
    point: &Point3<f64>,
    normal: &Vector3<f64>,
    eye: &Point3<f64>,
) -> bool {
    let to = eye - point;
    let dist = to.norm();
    let d = to / dist;
    if normal.dot(&d) <= 0.0 {
        return false;
    }
    let from = point + normal * 1e-6;
    !scene.blocked(&from, &d, dist - 1e-6)
}

/// Fills every run of holes shorter than `width` pixels between two measurements on either side
/// of a depth discontinuity with the nearer of the two (the block-matching window spans the
/// projector's shadow and reports the foreground: edge fattening). Holes inside one surface
/// (grazing incidence, random blobs) stay: there is no second surface whose pattern the window
/// could lock onto, and filling them would lay steep surfaces out as staircases.
fn fill_narrow_holes(model: &KinectModel, row: &mut [f32], width: f64) {
    let mut u = 0;
    while u < row.len() {
        if row[u] > 0.0 {
            u += 1;
            continue;
        }
        let start = u;
        while u < row.len() && row[u] <= 0.0 {
            u += 1;
        }
        if start == 0 || u == row.len() || ((u - start) as f64) >= width {
            continue;
        }
        let (near, far) = (row[start - 1].min(row[u]), row[start - 1].max(row[u]));
        if is_jump(model, near as f64, far as f64) {
            row[start..u].fill(near);
        }
    }
}

/// Pixels on the far side of a depth discontinuity take, with the model's probability, a depth
/// between the two sides (the mixed return of a pixel that straddles the edge).
fn add_flying_pixels(model: &KinectModel, z: &[f32], w: usize, h: usize, seed: u64) -> Vec<f32> {
    let mut out = z.to_vec();
    if model.flying_probability <= 0.0 {
        return out;
    }
    out.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        let mut rng = row_rng(seed, FLYING, v);
        for (u, px) in row.iter_mut().enumerate() {
            let here = z[v * w + u];
            if here <= 0.0 {
                continue;
            }
            let near = neighbours(u, v, w, h)
                .map(|j| z[j])
                .filter(|&n| n > 0.0 && is_jump(model, n as f64, here as f64))
                .fold(f32::INFINITY, f32::min);
            if near.is_finite() && rng.random::<f64>() < model.flying_probability {
                let a = rng.random_range(0.2f32..0.8);
                *px = here + a * (near - here);
            }
        }
    });
    out
}

/// The 4-neighbours of (u, v) inside the image, as indices.
fn neighbours(u: usize, v: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    let (u, v) = (u as isize, v as isize);
    [(u - 1, v), (u + 1, v), (u, v - 1), (u, v + 1)]
        .into_iter()
        .filter(move |&(x, y)| x >= 0 && y >= 0 && x < w as isize && y < h as isize)
        .map(move |(x, y)| y as usize * w + x as usize)
}

/// A neighbour at `near` is in front of `here` by a discontinuity: more than 5 % and more than
/// three quantisation steps.
fn is_jump(model: &KinectModel, near: f64, here: f64) -> bool {
    let gap = here - near;
    gap > 0.05 * here && gap > 3.0 * model.depth_step(here)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_narrow_holes_at_a_discontinuity_take_the_nearer_depth() {
        let m = KinectModel::default();
        // a 3-pixel shadow between a near (1 m) and a far (2 m) surface, then a 3-pixel hole
        // inside the far surface, then a 5-pixel shadow (wider than the 4-pixel window)
        let mut row = vec![
            1.0, 1.0, 0.0, 0.0, 0.0, 2.0, 2.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0,
        ];
        row.extend([0.0, 0.0, 0.0, 1.0, 1.0]);
        let before = row.clone();
        fill_narrow_holes(&m, &mut row, 4.0);
        assert_eq!(&row[2..5], &[1.0; 3], "the shadow at the jump is fattened");
        assert_eq!(&row[7..10], &[0.0; 3], "the hole inside one surface stays");
        assert_eq!(
            &row[11..16],
            &before[11..16],
            "a shadow wider than the window stays"
        );
    }
}
