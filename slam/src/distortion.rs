//! Brown–Conrady lens distortion (Brown 1966; OpenCV's and ROS' `plumb_bob`) and the precomputed
//! remap that undistorts whole images.
//!
//! For normalised image coordinates (x, y) = ((u − cx)/fx, (v − cy)/fy) and r² = x² + y²,
//!
//! ```text
//! x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²)
//! y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y
//! ```
//!
//! The sensor records the distorted point. [`Undistorter`] stores, once per camera, where each
//! pixel of the ideal (pinhole) image falls in the recorded one, so that undistorting a frame is a
//! lookup and an interpolation per pixel, with no equation solved per pixel.

use crate::camera::Camera;
use crate::image::{bilinear_weights, blend4, ColorImage, Image};
use rayon::prelude::*;

/// Brown–Conrady coefficients, in OpenCV's order (k1, k2, p1, p2, k3).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Distortion {
    /// Radial, r².
    pub k1: f64,
    /// Radial, r⁴.
    pub k2: f64,
    /// Tangential.
    pub p1: f64,
    /// Tangential.
    pub p2: f64,
    /// Radial, r⁶.
    pub k3: f64,
}

impl Distortion {
    /// The coefficients in OpenCV's order `[k1, k2, p1, p2, k3]`.
    pub fn from_array(c: [f64; 5]) -> Self {
        Self {
            k1: c[0],
            k2: c[1],
            p1: c[2],
            p2: c[3],
            k3: c[4],
        }
    }

    /// `[k1, k2, p1, p2, k3]`.
    pub fn to_array(&self) -> [f64; 5] {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
    }

    /// No distortion at all.
    pub fn is_zero(&self) -> bool {
        self.to_array().iter().all(|&c| c == 0.0)
    }

    /// The recorded (distorted) normalised coordinates of the ideal point (x, y).
    #[inline]
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = self.radial(r2);
        (
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// The ideal point whose distortion is (xd, yd), by Newton's method on the 2 × 2 system
    /// (converges in a few steps over the field of view of a real lens); `None` where it does not
    /// converge (outside the region where the model is invertible).
    pub fn undistort(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..30 {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex.abs() < 1e-13 && ey.abs() < 1e-13 {
                return Some((x, y));
            }
            let j = self.jacobian(x, y);
            let det = j[0] * j[3] - j[1] * j[2];
            if det.abs() < 1e-12 {
                return None;
            }
            x -= (j[3] * ex - j[1] * ey) / det;
            y -= (-j[2] * ex + j[0] * ey) / det;
        }
        let (fx, fy) = self.distort(x, y);
        ((fx - xd).abs() < 1e-9 && (fy - yd).abs() < 1e-9).then_some((x, y))
    }

    /// The first pixel of `camera`'s image (row by row) where the model folds the image over, if
    /// any: a pixel of the ideal image whose recorded point lies inside the recorded image although
    /// the map is not one-to-one there. That is where ∂(x_d, y_d)/∂(x, y) has a determinant ≤ 0 (a
    /// neighbourhood is mirrored or squashed) or the radial factor 1 + k1 r² + k2 r⁴ + k3 r⁶ is
    /// ≤ 0 (the point is sent through the centre to the other side). Either way two points of the
    /// scene would be recorded at one pixel, and the undistorted frame would hold copies of parts
    /// of the recorded one. TUM's calibrations keep both positive over their images; a coefficient
    /// of the wrong sign, order or units may not.
    pub fn fold_in(&self, camera: &Camera) -> Option<(usize, usize)> {
        let w = camera.width;
        (0..w * camera.height)
            .map(|i| (i % w, i / w))
            .find(|&(u, v)| {
                let ((x, y), recorded) = self.recorded_pixel(camera, u, v);
                let [a, b, c, d] = self.jacobian(x, y);
                recorded.is_some() && (self.radial(x * x + y * y) <= 0.0 || a * d - b * c <= 0.0)
            })
    }

    /// Ideal pixel (u, v) of `camera`: its normalised coordinates, and where the lens records it,
    /// if that falls inside the image (within half a pixel of its border pixels' centres).
    fn recorded_pixel(
        &self,
        camera: &Camera,
        u: usize,
        v: usize,
    ) -> ((f64, f64), Option<(f64, f64)>) {
        let x = (u as f64 - camera.cx) / camera.fx;
        let y = (v as f64 - camera.cy) / camera.fy;
        let (xd, yd) = self.distort(x, y);
        let (us, vs) = (camera.fx * xd + camera.cx, camera.fy * yd + camera.cy);
        let (w, h) = (camera.width as f64, camera.height as f64);
        let inside = us > -0.5 && vs > -0.5 && us < w - 0.5 && vs < h - 0.5;
        ((x, y), inside.then_some((us, vs)))
    }

    /// The radial factor 1 + k1 r² + k2 r⁴ + k3 r⁶ at r² = `r2`.
    #[inline]
    fn radial(&self, r2: f64) -> f64 {
        1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
    }

    /// ∂(x_d, y_d)/∂(x, y), row-major.
    fn jacobian(&self, x: f64, y: f64) -> [f64; 4] {
        let r2 = x * x + y * y;
        let radial = self.radial(r2);
        // d radial / d r²
        let dr = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        [
            radial + 2.0 * x * x * dr + 2.0 * self.p1 * y + 6.0 * self.p2 * x,
            2.0 * x * y * dr + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
            2.0 * x * y * dr + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
            radial + 2.0 * y * y * dr + 6.0 * self.p1 * y + 2.0 * self.p2 * x,
        ]
    }
}

/// Where every pixel of the ideal image lies in the recorded one, for one camera: computed once,
/// applied to every frame.
#[derive(Clone, Debug)]
pub struct Undistorter {
    width: usize,
    height: usize,
    /// Source pixel coordinates (u, v) per ideal pixel, row-major; NaN where it falls outside.
    map: Vec<[f32; 2]>,
    /// Per ideal pixel, the recorded pixel nearest its source point ([`OUTSIDE`] where none).
    nearest: Vec<u32>,
    /// Per ideal pixel, the four recorded pixels around its source point and their weights.
    taps: Vec<Tap>,
}

/// An ideal pixel with no source in the recorded image.
const OUTSIDE: u32 = u32::MAX;

/// Where bilinear interpolation reads an ideal pixel: the index of the upper left of the four
/// recorded pixels around its source point ([`OUTSIDE`] where none), and the weights of the
/// right and the lower ones in 1/256ths of a pixel (0..=256). The upper left is kept one pixel
/// inside the right and bottom borders (weight 256 on the far side), so the other three are
/// always one step right, one row down and both (for images at least 2 × 2).
#[derive(Clone, Copy, Debug)]
struct Tap {
    index: u32,
    right: u16,
    down: u16,
}

impl Undistorter {
    /// The remap of `camera` (its intrinsics and image size) with `distortion`: the ideal image
    /// has the same intrinsics, without distortion.
    pub fn new(camera: &Camera, distortion: &Distortion) -> Self {
        let (w, h) = (camera.width, camera.height);
        let mut map = vec![[f32::NAN; 2]; w * h];
        map.par_chunks_mut(w.max(1))
            .enumerate()
            .for_each(|(v, row)| {
                for (u, m) in row.iter_mut().enumerate() {
                    if let (_, Some((us, vs))) = distortion.recorded_pixel(camera, u, v) {
                        *m = [us as f32, vs as f32];
                    }
                }
            });
        let nearest = map
            .par_iter()
            .map(|&[x, y]| {
                if x.is_nan() {
                    return OUTSIDE;
                }
                let (u, v) = (
                    ((x + 0.5) as usize).min(w - 1),
                    ((y + 0.5) as usize).min(h - 1),
                );
                (v * w + u) as u32
            })
            .collect();
        let taps = map.par_iter().map(|m| Tap::of(*m, w, h)).collect();
        Self {
            width: w,
            height: h,
            map,
            nearest,
            taps,
        }
    }

    /// Image size the remap was made for.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Undistorts a raw depth image by nearest neighbour (depth is not interpolated across a
    /// discontinuity); pixels that fall outside the recorded image get 0 (no measurement).
    /// Panics if the size differs from the camera's (a caller's bug: frames are checked on load).
    pub fn depth(&self, src: &Image<u16>, out: &mut Image<u16>) {
        assert_eq!((src.width, src.height), self.size(), "depth size");
        self.remap(out, &self.nearest, |&i| {
            (i != OUTSIDE).then(|| src.data[i as usize])
        });
    }

    /// Undistorts a colour image by bilinear interpolation, in fixed point (weights in 1/256ths
    /// of a pixel: at most 1.5 levels from the exact value where neighbours differ by the full
    /// range); pixels that fall outside get black.
    pub fn color(&self, src: &ColorImage, out: &mut ColorImage) {
        assert_eq!((src.width, src.height), self.size(), "colour size");
        // the neighbours' steps (none along an axis one pixel long)
        let (dx, dy) = (
            usize::from(self.width > 1),
            self.width * usize::from(self.height > 1),
        );
        self.remap(out, &self.taps, |t| {
            if t.index == OUTSIDE {
                return None;
            }
            let i = t.index as usize;
            let p = [
                src.data[i],
                src.data[i + dx],
                src.data[i + dy],
                src.data[i + dx + dy],
            ];
            Some(blend4(
                p,
                bilinear_weights(u32::from(t.right), u32::from(t.down)),
            ))
        });
    }

    /// `out` at the remap's size, each ideal pixel set to `sample` of its entry in `table` (one
    /// per ideal pixel, row-major), or left at the default where that gives none; rows in
    /// parallel.
    fn remap<T: Copy + Default + Send + Sync, E: Sync>(
        &self,
        out: &mut Image<T>,
        table: &[E],
        sample: impl Fn(&E) -> Option<T> + Sync,
    ) {
        out.reset(self.width, self.height, T::default());
        let w = self.width.max(1);
        out.data
            .par_chunks_mut(w)
            .zip(table.par_chunks(w))
            .for_each(|(row, entries)| {
                for (o, e) in row.iter_mut().zip(entries) {
                    if let Some(value) = sample(e) {
                        *o = value;
                    }
                }
            });
    }

    /// The source coordinates of ideal pixel (u, v), if it falls inside the recorded image.
    pub fn source_of(&self, u: usize, v: usize) -> Option<(f32, f32)> {
        let m = self.map[v * self.width + u];
        (!m[0].is_nan()).then_some((m[0], m[1]))
    }
}

impl Tap {
    /// The tap of source point (x, y) (NaN: none) in a `w` × `h` image, clamped into it.
    fn of([x, y]: [f32; 2], w: usize, h: usize) -> Self {
        if x.is_nan() {
            return Self {
                index: OUTSIDE,
                right: 0,
                down: 0,
            };
        }
        let corner = |p: f32, n: usize| {
            let p = p.clamp(0.0, (n - 1) as f32);
            let p0 = (p as usize).min(n.saturating_sub(2));
            (p0, ((p - p0 as f32) * 256.0).round() as u16)
        };
        let ((x0, right), (y0, down)) = (corner(x, w), corner(y, h));
        Self {
            index: (y0 * w + x0) as u32,
            right,
            down,
        }
    }
}

/// The sensors of the TUM RGB-D benchmark (Sturm et al. 2012).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TumSensor {
    /// freiburg1 (a Kinect).
    Freiburg1,
    /// freiburg2 (a Kinect).
    Freiburg2,
    /// freiburg3 (an Asus Xtion; its images are published undistorted).
    Freiburg3,
}

impl TumSensor {
    /// The sensor named `fr1`, `fr2`, `fr3` (or `freiburg1` ...).
    pub fn from_name(name: &str) -> Option<Self> {
        match name.to_ascii_lowercase().as_str() {
            "fr1" | "freiburg1" => Some(Self::Freiburg1),
            "fr2" | "freiburg2" => Some(Self::Freiburg2),
            "fr3" | "freiburg3" => Some(Self::Freiburg3),
            _ => None,
        }
    }

    /// The colour camera's published calibration at 640×480: intrinsics and Brown–Conrady
    /// coefficients, depth scale 5000.
    pub fn calibration(self) -> (Camera, Distortion) {
        let (k, d) = match self {
            Self::Freiburg1 => (
                [517.3, 516.5, 318.6, 255.3],
                [0.2624, -0.9531, -0.0054, 0.0026, 1.1633],
            ),
            Self::Freiburg2 => (
                [520.9, 521.0, 325.1, 249.7],
                [0.2312, -0.7849, -0.0033, -0.0001, 0.9172],
            ),
            Self::Freiburg3 => ([535.4, 539.2, 320.1, 247.6], [0.0; 5]),
        };
        (
            Camera::new(k[0], k[1], k[2], k[3], 640, 480),
            Distortion::from_array(d),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn fr1() -> Distortion {
        TumSensor::Freiburg1.calibration().1
    }

    proptest! {
        #[test]
        fn undistort_inverts_distort(x in -0.6f64..0.6, y in -0.45f64..0.45) {
            for d in [fr1(), TumSensor::Freiburg2.calibration().1,
                      Distortion::from_array([-0.3, 0.1, 0.001, -0.002, 0.0])] {
                let (xd, yd) = d.distort(x, y);
                let (bx, by) = d.undistort(xd, yd).expect("converges");
                prop_assert!((bx - x).abs() < 1e-10 && (by - y).abs() < 1e-10);
            }
        }

        #[test]
        fn the_jacobian_matches_central_differences(x in -0.6f64..0.6, y in -0.45f64..0.45) {
            let d = fr1();
            let j = d.jacobian(x, y);
            let h = 1e-6;
            let (px, py) = d.distort(x + h, y);
            let (mx, my) = d.distort(x - h, y);
            let (qx, qy) = d.distort(x, y + h);
            let (nx, ny) = d.distort(x, y - h);
            let numeric = [(px - mx) / (2.0 * h), (qx - nx) / (2.0 * h), (py - my) / (2.0 * h), (qy - ny) / (2.0 * h)];
            for k in 0..4 {
                prop_assert!((j[k] - numeric[k]).abs() < 1e-6, "{k}: {} vs {}", j[k], numeric[k]);
            }
        }
    }

    /// `fold_in` finds a fold where the map turns back or is far too skewed, and none in the
    /// calibrations in use or in a steep model that stays one-to-one.
    #[test]
    fn a_lens_model_that_folds_the_image_over_is_found() {
        // TUM's three calibrations and the generator's at 320×240 keep the map one-to-one
        for sensor in [
            TumSensor::Freiburg1,
            TumSensor::Freiburg2,
            TumSensor::Freiburg3,
        ] {
            let (camera, d) = sensor.calibration();
            assert_eq!(d.fold_in(&camera), None, "{sensor:?}");
        }
        let (fr1, d) = TumSensor::Freiburg1.calibration();
        let half = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
        assert_eq!(d.fold_in(&half), None);
        // strong but monotonic: most of the ideal image falls outside, nothing is folded
        let steep = Distortion::from_array([100.0, 100.0, 0.0, 0.0, 100.0]);
        assert_eq!(steep.fold_in(&fr1), None);
        // r (1 − 5 r²) turns back at r = 0.26 (about 130 px from the centre at f = 517): a pixel
        // past it whose recorded point is inside the image is found, and the map's determinant
        // is negative there
        let folded = Distortion::from_array([-5.0, 0.0, 0.0, 0.0, 0.0]);
        let (u, v) = folded.fold_in(&fr1).expect("a fold");
        let (x, y) = ((u as f64 - fr1.cx) / fr1.fx, (v as f64 - fr1.cy) / fr1.fy);
        assert!(x.hypot(y) > 0.25, "({u}, {v})");
        let [a, b, c, e] = folded.jacobian(x, y);
        let radial = 1.0 - 5.0 * (x * x + y * y);
        assert!(a * e - b * c <= 0.0 || radial <= 0.0);
        // a tangential term far too large folds it too
        let skewed = Distortion::from_array([0.0, 0.0, 3.0, 0.0, 0.0]);
        assert!(skewed.fold_in(&fr1).is_some());
    }

    /// A distorted render of an image whose values are its own ideal coordinates, undistorted by
    /// the remap, gives back each pixel's coordinates to a fraction of a pixel.
    #[test]
    fn undistorting_a_distorted_render_recovers_the_ideal_geometry() {
        let (camera, d) = TumSensor::Freiburg1.calibration();
        let (w, h) = (camera.width, camera.height);
        // the recorded images: each pixel holds the ideal u (resp. v) of what it sees, scaled to u8
        // range in two channels (u / 4, v / 4), computed by inverting the distortion per pixel
        let mut recorded = ColorImage::new(w, h);
        let mut depth = Image::<u16>::new(w, h);
        for v in 0..h {
            for u in 0..w {
                let xd = (u as f64 - camera.cx) / camera.fx;
                let yd = (v as f64 - camera.cy) / camera.fy;
                let (x, y) = d.undistort(xd, yd).unwrap();
                let (ui, vi) = (camera.fx * x + camera.cx, camera.fy * y + camera.cy);
                recorded.set(
                    u,
                    v,
                    [(ui / 4.0).round() as u8, (vi / 4.0).round() as u8, 0],
                );
                // depth: a code of the ideal pixel, exact in u16
                depth.set(
                    u,
                    v,
                    (ui.round().clamp(0.0, 639.0) as u16) * 100 + (vi / 5.0) as u16,
                );
            }
        }
        let undistorter = Undistorter::new(&camera, &d);
        let mut ideal = ColorImage::new(w, h);
        undistorter.color(&recorded, &mut ideal);
        let mut ideal_depth = Image::<u16>::new(w, h);
        undistorter.depth(&depth, &mut ideal_depth);
        let (mut worst, mut covered, mut worst_depth) = (0.0f64, 0, 0i64);
        for v in 8..h - 8 {
            for u in 8..w - 8 {
                if undistorter.source_of(u, v).is_none() {
                    continue;
                }
                covered += 1;
                let p = ideal.at(u, v);
                // the u8 channels quantise to 4 px (±2), interpolation adds little
                worst = worst
                    .max((4.0 * p[0] as f64 - u as f64).abs())
                    .max((4.0 * p[1] as f64 - v as f64).abs());
                let code = ideal_depth.at(u, v) as i64;
                worst_depth = worst_depth.max((code / 100 - u as i64).abs());
            }
        }
        assert!(covered > w * h / 2, "{covered} pixels covered");
        assert!(worst <= 2.5, "colour geometry off by {worst} px");
        // nearest neighbour: the recorded pixel nearest the source point sees an ideal point within
        // a pixel of this one
        assert!(worst_depth <= 1, "depth geometry off by {worst_depth} px");
    }

    /// The fixed-point interpolation is within 1.5 levels of the exact bilinear value at each
    /// pixel's source point (half a level of rounding, and weights within 1/512 on each axis
    /// against a full contrast of 255) on a noise image, the hardest case, borders included;
    /// outside pixels are black.
    #[test]
    fn the_fixed_point_colour_is_within_a_level_and_a_half_of_the_exact_interpolation() {
        let (camera, d) = TumSensor::Freiburg1.calibration();
        let (w, h) = (camera.width, camera.height);
        let mut src = ColorImage::new(w, h);
        let mut state = 12345u64;
        for p in src.data.iter_mut() {
            *p = std::array::from_fn(|_| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (state >> 56) as u8
            });
        }
        let undistorter = Undistorter::new(&camera, &d);
        let mut out = ColorImage::new(0, 0);
        undistorter.color(&src, &mut out);
        let mut outside = 0;
        for v in 0..h {
            for u in 0..w {
                let Some((x, y)) = undistorter.source_of(u, v) else {
                    assert_eq!(out.at(u, v), [0; 3]);
                    outside += 1;
                    continue;
                };
                let (x, y) = (x.clamp(0.0, (w - 1) as f32), y.clamp(0.0, (h - 1) as f32));
                let (x0, y0) = (x as usize, y as usize);
                let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
                let (ax, ay) = ((x - x0 as f32) as f64, (y - y0 as f32) as f64);
                for c in 0..3 {
                    let at = |xx: usize, yy: usize| src.at(xx, yy)[c] as f64;
                    let top = at(x0, y0) * (1.0 - ax) + at(x1, y0) * ax;
                    let bottom = at(x0, y1) * (1.0 - ax) + at(x1, y1) * ax;
                    let exact = top * (1.0 - ay) + bottom * ay;
                    let got = out.at(u, v)[c] as f64;
                    assert!(
                        (got - exact).abs() <= 1.5,
                        "({u}, {v}): {got} against {exact}"
                    );
                }
            }
        }
        assert!(
            outside > 0,
            "fr1's distortion leaves some corners without a source"
        );
    }

    #[test]
    fn precise_remap_lands_within_a_hundredth_of_a_pixel() {
        // The remap itself, against the per-point inverse, everywhere it is defined.
        let (camera, d) = TumSensor::Freiburg2.calibration();
        let undistorter = Undistorter::new(&camera, &d);
        let mut worst = 0.0f64;
        for v in (0..camera.height).step_by(7) {
            for u in (0..camera.width).step_by(7) {
                let Some((us, vs)) = undistorter.source_of(u, v) else {
                    continue;
                };
                let xd = (us as f64 - camera.cx) / camera.fx;
                let yd = (vs as f64 - camera.cy) / camera.fy;
                let (x, y) = d.undistort(xd, yd).unwrap();
                let (ui, vi) = (camera.fx * x + camera.cx, camera.fy * y + camera.cy);
                worst = worst.max((ui - u as f64).abs()).max((vi - v as f64).abs());
            }
        }
        assert!(worst < 0.01, "remap off by {worst} px");
    }

    #[test]
    fn no_distortion_is_the_identity() {
        let c = Camera::tum_default();
        let u = Undistorter::new(&c, &Distortion::default());
        assert_eq!(u.source_of(10, 20), Some((10.0, 20.0)));
        assert!(Distortion::default().is_zero() && !fr1().is_zero());
        assert_eq!(TumSensor::from_name("FR2"), Some(TumSensor::Freiburg2));
        assert_eq!(TumSensor::from_name("fr4"), None);
    }
}
