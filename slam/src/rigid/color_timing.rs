//! Colour exposed at another instant than depth, brought to the depth's instant.
//!
//! A sensor whose colour is captured τ seconds after its depth (TUM's Kinect: 10–20 ms) sees the
//! scene from the pose T_c = T_d S, with S the camera's motion over τ. A point X of the depth
//! camera's frame appears in the colour image at π(S⁻¹ X); sampling the colour there for every
//! pixel with depth gives the colour the depth camera would have seen. Pixels without depth take
//! the depth around them along their row. S comes from the constant-velocity [`super::motion_model::MotionModel`].

use crate::camera::Camera;
use crate::image::{blend4, ColorImage, Image};
use nalgebra::Isometry3;
use rayon::prelude::*;
use wide::{f32x8, i32x8};

/// Writes into `out` the colour registered to the depth's instant: for each pixel with depth
/// (raw units at the camera's depth scale), the colour at π(S⁻¹ X), `step` = S.
pub(crate) fn register(
    depth_raw: &Image<u16>,
    color: &ColorImage,
    camera: &Camera,
    step: &Isometry3<f64>,
    out: &mut ColorImage,
) {
    let (w, h) = (color.width, color.height);
    if (out.width, out.height) != (w, h) {
        *out = Image::filled(w, h, [0, 0, 0]);
    }
    let to_color = Warp::new(&step.inverse(), camera);
    out.data
        .par_chunks_mut(w)
        .enumerate()
        .for_each_init(Vec::new, |filled, (v, row)| {
            fill_row(&depth_raw.data[v * w..(v + 1) * w], filled);
            row.copy_from_slice(&color.data[v * w..(v + 1) * w]);
            register_row(&to_color, color, v, filled, row);
        });
}

/// Row `v` of [`register`]: each pixel of `row` (the colour as recorded) with depth in `filled`
/// (holes filled) takes the colour where the warp puts it, eight pixels' projections at a time.
fn register_row(
    to_color: &Warp,
    color: &ColorImage,
    v: usize,
    filled: &[u16],
    row: &mut [[u8; 3]],
) {
    const LANES: usize = 8;
    let ray = to_color.row(v as f32);
    let offsets = f32x8::from([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]);
    let limit = [(color.width - 1) as f32, (color.height - 1) as f32];
    for (chunk, (px, depths)) in row.chunks_mut(LANES).zip(filled.chunks(LANES)).enumerate() {
        let mut d = [0.0f32; LANES];
        for (d, &raw) in d.iter_mut().zip(depths) {
            *d = raw as f32;
        }
        let u = f32x8::splat((chunk * LANES) as f32) + offsets;
        let (x, y, inside) = to_color.apply8(&ray, u, f32x8::from(d), limit);
        if inside.none() {
            continue;
        }
        bilinear8(color, x, y, inside.to_bitmask(), px);
    }
}

/// [`bilinear_inside`] at eight points at once, written into `px` where their bit of `inside`
/// is set: the corners' indices and weights in SIMD lanes, then each colour's [`blend4`]. The
/// same arithmetic, so the same bits.
#[inline]
fn bilinear8(img: &ColorImage, x: f32x8, y: f32x8, inside: u32, px: &mut [[u8; 3]]) {
    let (x0, y0) = (x.trunc_int(), y.trunc_int());
    let full = i32x8::splat(256);
    let ax = ((x - x0.round_float()) * f32x8::splat(256.0)).trunc_int();
    let ay = ((y - y0.round_float()) * f32x8::splat(256.0)).trunc_int();
    let weights = [
        ((full - ax) * (full - ay)).to_array(),
        (ax * (full - ay)).to_array(),
        ((full - ax) * ay).to_array(),
        (ax * ay).to_array(),
    ];
    let width = img.width as i32;
    let x1 = (x0 + i32x8::ONE).min(i32x8::splat(width - 1));
    let y1 = (y0 + i32x8::ONE).min(i32x8::splat(img.height as i32 - 1));
    let (row0, row1) = (y0 * i32x8::splat(width), y1 * i32x8::splat(width));
    let corners = [
        (row0 + x0).to_array(),
        (row0 + x1).to_array(),
        (row1 + x0).to_array(),
        (row1 + x1).to_array(),
    ];
    for (k, px) in px.iter_mut().enumerate() {
        if inside & (1 << k) == 0 {
            continue;
        }
        let p = corners.map(|index| img.data[index[k] as usize]);
        *px = blend4(p, weights.map(|w| w[k] as u32));
    }
}

/// Pixel (u, v) at raw depth d, back-projected, moved by a rigid motion and projected again
/// (eqs. 2.1, 2.2), in `f32` with the camera's constants folded in. Along a row the moved point
/// is z (b + u a) + t, with a = R K⁻¹ [1, 0, 0]ᵀ and b = R K⁻¹ [0, v, 1]ᵀ ([`Warp::row`]).
struct Warp {
    rotation: [[f32; 3]; 3],
    translation: [f32; 3],
    inv_f: [f32; 2],
    f: [f32; 2],
    c: [f32; 2],
    scale: f32,
}

/// A row's rotated rays: at u = 0 and the step per pixel.
struct RowRays {
    base: [f32; 3],
    step: [f32; 3],
}

impl Warp {
    fn new(motion: &Isometry3<f64>, camera: &Camera) -> Self {
        let r = motion.rotation.to_rotation_matrix();
        let t = motion.translation.vector;
        Self {
            rotation: std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)] as f32)),
            translation: std::array::from_fn(|i| t[i] as f32),
            inv_f: [1.0 / camera.fx as f32, 1.0 / camera.fy as f32],
            f: [camera.fx as f32, camera.fy as f32],
            c: [camera.cx as f32, camera.cy as f32],
            scale: 1.0 / camera.depth_scale as f32,
        }
    }

    /// The rotated rays of row `v`.
    fn row(&self, v: f32) -> RowRays {
        let ray = [
            -self.c[0] * self.inv_f[0],
            (v - self.c[1]) * self.inv_f[1],
            1.0,
        ];
        let r = &self.rotation;
        RowRays {
            base: std::array::from_fn(|i| r[i][0] * ray[0] + r[i][1] * ray[1] + r[i][2]),
            step: std::array::from_fn(|i| r[i][0] * self.inv_f[0]),
        }
    }

    /// The pixel where (u, v) at raw depth `d` lands, `row` being row v's rays; `None` behind
    /// the camera. (The pixel-by-pixel reference of [`Self::apply8`].)
    #[cfg(test)]
    fn apply(&self, row: &RowRays, u: f32, d: f32) -> Option<(f32, f32)> {
        let z = d * self.scale;
        let p: [f32; 3] =
            std::array::from_fn(|i| z * (row.base[i] + u * row.step[i]) + self.translation[i]);
        (p[2] > 0.0).then(|| {
            let inv = 1.0 / p[2];
            (
                self.f[0] * p[0] * inv + self.c[0],
                self.f[1] * p[1] * inv + self.c[1],
            )
        })
    }

    /// [`Self::apply`] for eight pixels of a row at once (`u` their columns, `d` their raw
    /// depths, 0 where missing), in the same arithmetic: their (x, y) in the colour image and
    /// which of them land within `limit` = (width − 1, height − 1) with depth and in front.
    #[inline]
    fn apply8(&self, row: &RowRays, u: f32x8, d: f32x8, limit: [f32; 2]) -> (f32x8, f32x8, f32x8) {
        let zero = f32x8::ZERO;
        let z = d * f32x8::splat(self.scale);
        let p: [f32x8; 3] = std::array::from_fn(|i| {
            z * (f32x8::splat(row.base[i]) + u * f32x8::splat(row.step[i]))
                + f32x8::splat(self.translation[i])
        });
        let inv = f32x8::ONE / p[2];
        let x = f32x8::splat(self.f[0]) * p[0] * inv + f32x8::splat(self.c[0]);
        let y = f32x8::splat(self.f[1]) * p[1] * inv + f32x8::splat(self.c[1]);
        let inside = d.simd_gt(zero)
            & p[2].simd_gt(zero)
            & x.simd_ge(zero)
            & y.simd_ge(zero)
            & x.simd_le(f32x8::splat(limit[0]))
            & y.simd_le(f32x8::splat(limit[1]));
        (x, y, inside)
    }
}

/// Writes into `filled` the row's depth with each hole given the farther of the nearest
/// measurements left and right of it (holes are mostly shadows cast on the far surface): the
/// colour then moves with its surroundings instead of staying put between shifted neighbours. An
/// empty row stays empty. Two passes, O(width).
fn fill_row(row: &[u16], filled: &mut Vec<u16>) {
    filled.clear();
    let mut left = 0;
    filled.extend(row.iter().map(|&d| {
        if d > 0 {
            left = d;
        }
        left
    }));
    let mut right = 0;
    for (f, &d) in filled.iter_mut().zip(row).rev() {
        if d > 0 {
            right = d;
        } else {
            *f = (*f).max(right);
        }
    }
}

/// [`bilinear_inside`] where (x, y) lies within the image, `None` outside (the reference's
/// test of the bounds, pixel by pixel).
#[cfg(test)]
fn bilinear(img: &ColorImage, x: f32, y: f32) -> Option<[u8; 3]> {
    let inside =
        x >= 0.0 && y >= 0.0 && x <= (img.width - 1) as f32 && y <= (img.height - 1) as f32;
    inside.then(|| bilinear_inside(img, x, y))
}

/// The colour at (x, y), a point known to lie within the image, interpolated between the four
/// pixels around it in fixed point (the weights in 1/256ths of a pixel, a rounding of at most
/// one level).
#[cfg(test)]
fn bilinear_inside(img: &ColorImage, x: f32, y: f32) -> [u8; 3] {
    let (x0, y0) = (x as usize, y as usize);
    let (x1, y1) = ((x0 + 1).min(img.width - 1), (y0 + 1).min(img.height - 1));
    let ax = ((x - x0 as f32) * 256.0) as u32;
    let ay = ((y - y0 as f32) * 256.0) as u32;
    let w = crate::image::bilinear_weights(ax, ay);
    let at = |x: usize, y: usize| img.data[y * img.width + x];
    let p = [at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1)];
    std::array::from_fn(|c| {
        let sum: u32 = (0..4).map(|k| p[k][c] as u32 * w[k]).sum();
        ((sum + (1 << 15)) >> 16) as u8
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn holes_take_the_farther_of_their_nearest_measurements() {
        let mut filled = Vec::new();
        fill_row(&[0, 0, 5, 0, 0, 9, 0, 3, 0], &mut filled);
        assert_eq!(filled, [5, 5, 5, 9, 9, 9, 9, 3, 3]);
        fill_row(&[0, 0, 0], &mut filled);
        assert_eq!(filled, [0, 0, 0]);
    }

    /// [`register`] pixel by pixel through [`Warp::apply`] and [`bilinear`], as it was before
    /// its projections were computed eight at a time (the blend itself is shared).
    fn register_one_by_one(
        depth_raw: &Image<u16>,
        color: &ColorImage,
        camera: &Camera,
        step: &Isometry3<f64>,
    ) -> ColorImage {
        let w = color.width;
        let to_color = Warp::new(&step.inverse(), camera);
        let mut out = color.clone();
        let mut filled = Vec::new();
        for (v, row) in out.data.chunks_mut(w).enumerate() {
            fill_row(&depth_raw.data[v * w..(v + 1) * w], &mut filled);
            let ray = to_color.row(v as f32);
            for (u, (px, &d)) in row.iter_mut().zip(&filled).enumerate() {
                let moved = (d > 0)
                    .then(|| to_color.apply(&ray, u as f32, d as f32))
                    .flatten()
                    .and_then(|(x, y)| bilinear(color, x, y));
                if let Some(c) = moved {
                    *px = c;
                }
            }
        }
        out
    }

    #[test]
    fn eight_at_a_time_registers_as_pixel_by_pixel() {
        // a width that is no multiple of eight, holes, depths near and far, colour everywhere,
        // and motions that move pixels out of the image and points behind the camera
        let (w, h) = (61, 23);
        let cam = Camera::new(40.0, 42.0, 30.2, 11.7, w, h);
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        let depth = Image::from_vec(
            w,
            h,
            (0..w * h)
                .map(|_| match next() % 5 {
                    0 => 0,
                    _ => 500 + (next() % 30_000) as u16,
                })
                .collect(),
        )
        .unwrap();
        let color: ColorImage = Image::from_vec(
            w,
            h,
            (0..w * h)
                .map(|_| next().to_le_bytes()[..3].try_into().unwrap())
                .collect(),
        )
        .unwrap();
        let motions = [
            Isometry3::new(
                Vector3::new(0.01, -0.004, 0.002),
                Vector3::new(0.003, 0.02, -0.01),
            ),
            Isometry3::new(Vector3::new(-0.3, 0.2, 0.5), Vector3::new(0.2, -0.1, 0.05)),
            Isometry3::new(Vector3::new(0.0, 0.0, 3.0), Vector3::new(0.0, 0.0, 0.4)),
        ];
        for step in motions {
            let mut out = ColorImage::new(0, 0);
            register(&depth, &color, &cam, &step, &mut out);
            assert_eq!(
                out,
                register_one_by_one(&depth, &color, &cam, &step),
                "{step}"
            );
        }
    }

    #[test]
    fn a_shifted_colour_image_is_brought_back_over_its_depth() {
        // a plane at 2 m; the colour camera moved 2 cm right: the scene shifts f·0.02/2 = 5 px left
        let cam = Camera::new(500.0, 500.0, 49.5, 39.5, 100, 80);
        let depth = Image::filled(100, 80, 10_000u16); // 2 m at scale 5000
        let pattern = |u: usize| [(u * 2) as u8, 0, 0];
        let mut color: ColorImage = Image::filled(100, 80, [0, 0, 0]);
        for v in 0..80 {
            for u in 0..100 {
                color.data[v * 100 + u] = pattern((u + 5).min(99));
            }
        }
        let step = Isometry3::translation(0.02, 0.0, 0.0);
        let mut out = ColorImage::new(0, 0);
        register(&depth, &color, &cam, &step, &mut out);
        for u in 10..90 {
            assert_eq!(out.data[40 * 100 + u], pattern(u), "u {u}");
        }
    }
}

#[cfg(test)]
mod rendered {
    use super::*;
    use crate::distortion::Distortion;
    use crate::synthetic::kinect::{pose_at, KinectModel};
    use crate::synthetic::motion::{procedural, Motion};
    use crate::synthetic::scene::Scene;

    /// Mean absolute difference of the colour over pixels with depth.
    fn diff(a: &ColorImage, b: &ColorImage, depth: &Image<u16>) -> f64 {
        let (mut sum, mut n) = (0.0, 0usize);
        for i in 0..a.data.len() {
            if depth.data[i] > 0 {
                for c in 0..3 {
                    sum += (a.data[i][c] as f64 - b.data[i][c] as f64).abs();
                }
                n += 3;
            }
        }
        sum / n as f64
    }

    #[test]
    fn registered_colour_matches_the_colour_at_the_depths_instant() {
        let camera = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
        let clean = KinectModel {
            disparity_sigma: 0.0,
            disparity_sigma_correlated: 0.0,
            jitter: 0.0,
            jitter_correlated: 0.0,
            exposure: 0.0,
            gain_drift: 0.0,
            vignetting: 0.0,
            color_noise: (0.0, 0.0),
            optics_blur: 0.0,
            distortion: Distortion::default(),
            color_delay: (0.016, 0.016),
            ..KinectModel::default()
        };
        let at_depth = KinectModel {
            color_delay: (0.0, 0.0),
            ..clean.clone()
        };
        let scene = Scene::room(2);
        let traj = procedural(Motion::Sweep, 12, 30.0);
        let k = 10;
        let late = clean.recorder(&camera).capture(&scene, &traj, k);
        let truth = at_depth.recorder(&camera).capture(&scene, &traj, k);
        let delay = late.color_stamp - traj.stamps[k];
        let step = traj.poses[k].inverse() * pose_at(&traj, traj.stamps[k] + delay);
        let mut out = ColorImage::new(0, 0);
        register(&late.depth, &late.color, &camera, &step, &mut out);
        let (before, after) = (
            diff(&late.color, &truth.color, &late.depth),
            diff(&out, &truth.color, &late.depth),
        );
        assert!(
            after < 0.5 * before,
            "mean |colour − truth| {before} before, {after} after"
        );
    }
}
