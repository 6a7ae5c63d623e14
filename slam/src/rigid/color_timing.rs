//! Colour exposed at another instant than depth, brought to the depth's instant.
//!
//! A sensor whose colour is captured τ seconds after its depth (TUM's Kinect: 10–20 ms) sees the
//! scene from the pose T_c = T_d S, with S the camera's motion over τ. A point X of the depth
//! camera's frame appears in the colour image at π(S⁻¹ X); sampling the colour there for every
//! pixel with depth gives the colour the depth camera would have seen. Pixels without depth take
//! the depth around them along their row. S comes from the constant-velocity [`super::motion_model::MotionModel`].

use crate::camera::Camera;
use crate::image::{ColorImage, Image};
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;

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
    let to_color = step.inverse();
    let scale = 1.0 / camera.depth_scale;
    out.data.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        let depth = &depth_raw.data[v * w..(v + 1) * w];
        for (u, px) in row.iter_mut().enumerate() {
            *px = color.data[v * w + u];
            let Some(d) = depth_at(depth, u) else {
                continue;
            };
            let x = camera.back_project(u as f64, v as f64, d as f64 * scale);
            let p: Point3<f64> = to_color * x;
            if let Some((cu, cv)) = camera.project(&p) {
                if let Some(c) = bilinear(color, cu, cv) {
                    *px = c;
                }
            }
        }
    });
}

/// The row's depth at u or, in a hole, the farther of the nearest measurements left and right of
/// it (holes are mostly shadows cast on the far surface): the colour then moves with its
/// surroundings instead of staying put between shifted neighbours. `None` for an empty row.
fn depth_at(row: &[u16], u: usize) -> Option<u16> {
    if row[u] > 0 {
        return Some(row[u]);
    }
    let left = row[..u].iter().rev().find(|&&d| d > 0);
    let right = row[u + 1..].iter().find(|&&d| d > 0);
    left.into_iter().chain(right).max().copied()
}

/// The colour at (x, y) interpolated between the four pixels around it; `None` outside.
fn bilinear(img: &ColorImage, x: f64, y: f64) -> Option<[u8; 3]> {
    if !(x >= 0.0 && y >= 0.0 && x <= (img.width - 1) as f64 && y <= (img.height - 1) as f64) {
        return None;
    }
    let (x0, y0) = (x as usize, y as usize);
    let (x1, y1) = ((x0 + 1).min(img.width - 1), (y0 + 1).min(img.height - 1));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let at = |x: usize, y: usize| img.data[y * img.width + x];
    let mut out = [0u8; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let top = at(x0, y0)[c] as f64 * (1.0 - fx) + at(x1, y0)[c] as f64 * fx;
        let bottom = at(x0, y1)[c] as f64 * (1.0 - fx) + at(x1, y1)[c] as f64 * fx;
        *o = (top * (1.0 - fy) + bottom * fy).round() as u8;
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

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
