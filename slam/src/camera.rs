//! The pinhole camera (thesis eq. 2.1-2.2 and 2.9): projection, back-projection, depth scale and range,
//! and intrinsics per pyramid level.
//!
//! Camera frame: x right, y down, z forward. A pixel (u, v) covers [u − ½, u + ½] × [v − ½, v + ½]
//! around its centre. A negative focal length (ICL-NUIM's fy = −480, an image y axis pointing up in the
//! camera frame) is carried through every formula unchanged; only what depends on the handedness of
//! the image (the orientation of normals from image-space cross products) checks its sign.

use nalgebra::{Point3, Vector3};

/// Pinhole intrinsics with the image size, depth scale and valid depth range.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Focal length along x, pixels (may be negative).
    pub fx: f64,
    /// Focal length along y, pixels (may be negative).
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Raw depth units per metre (5000 for TUM and ICL-NUIM PNGs, 1000 for millimetres).
    pub depth_scale: f64,
    /// Nearest valid depth, metres.
    pub depth_min: f64,
    /// Farthest valid depth, metres.
    pub depth_max: f64,
}

/// Whether `f` can be a focal length, pixels: finite and not zero (a negative one mirrors its
/// axis, as above).
pub fn usable_focal_length(f: f64) -> bool {
    f.is_finite() && f != 0.0
}

impl Camera {
    /// A camera with the default depth scale 5000 and range 0.1–10 m.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64, width: usize, height: usize) -> Self {
        Self {
            fx,
            fy,
            cx,
            cy,
            width,
            height,
            depth_scale: 5000.0,
            depth_min: 0.1,
            depth_max: 10.0,
        }
    }

    /// The TUM RGB-D "ROS default" intrinsics (525, 525, 319.5, 239.5) at 640×480, scale 5000.
    pub fn tum_default() -> Self {
        Self::new(525.0, 525.0, 319.5, 239.5, 640, 480)
    }

    /// TUM's default focal length (525 px at 640 wide) scaled to a `width` × `height` image, the
    /// principal point at its centre: the camera of the project's rendered sequences.
    pub fn scaled_default(width: usize, height: usize) -> Self {
        let f = 525.0 * width as f64 / 640.0;
        Self::new(
            f,
            f,
            (width as f64 - 1.0) / 2.0,
            (height as f64 - 1.0) / 2.0,
            width,
            height,
        )
    }

    /// Projects a point in the camera frame to continuous pixel coordinates (u, v) (eq. 2.1);
    /// `None` behind the camera (z ≤ 0).
    #[inline]
    pub fn project(&self, p: &Point3<f64>) -> Option<(f64, f64)> {
        if p.z <= 0.0 {
            return None;
        }
        Some((self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }

    /// Projects and rounds to the nearest pixel, `None` outside the image.
    #[inline]
    pub fn project_to_pixel(&self, p: &Point3<f64>) -> Option<(usize, usize)> {
        let (u, v) = self.project(p)?;
        // round half up; truncation equals floor once negatives are excluded (and no libm call)
        let (u, v) = (u + 0.5, v + 0.5);
        if u.is_nan() || v.is_nan() || u < 0.0 || v < 0.0 {
            return None;
        }
        let (ur, vr) = (u as usize, v as usize);
        (ur < self.width && vr < self.height).then_some((ur, vr))
    }

    /// Back-projects pixel (u, v) at depth z (metres along the optical axis) to the camera frame
    /// (eq. 2.2).
    #[inline]
    pub fn back_project(&self, u: f64, v: f64, z: f64) -> Point3<f64> {
        Point3::new((u - self.cx) / self.fx * z, (v - self.cy) / self.fy * z, z)
    }

    /// The unit ray direction through pixel (u, v).
    #[inline]
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        self.back_project(u, v, 1.0).coords.normalize()
    }

    /// Whether a depth in metres lies in the valid range.
    #[inline]
    pub fn valid_depth(&self, z: f64) -> bool {
        z >= self.depth_min && z <= self.depth_max
    }

    /// The intrinsics of pyramid level `level` (each level halves the resolution; eq. 2.9):
    /// f' = f / 2^l and c' = (c + ½) / 2^l − ½, so that pixel centres keep their geometry.
    pub fn level(&self, level: usize) -> Self {
        let s = 1.0 / (1u64 << level) as f64;
        Self {
            fx: self.fx * s,
            fy: self.fy * s,
            cx: (self.cx + 0.5) * s - 0.5,
            cy: (self.cy + 0.5) * s - 0.5,
            width: (self.width >> level).max(1),
            height: (self.height >> level).max(1),
            ..*self
        }
    }

    /// +1 when the image axes (u right, v down) form a right-handed frame with the viewing direction
    /// (fx·fy > 0), −1 when one axis is mirrored (e.g. ICL-NUIM's negative fy).
    #[inline]
    pub(crate) fn handedness(&self) -> f64 {
        (self.fx * self.fy).signum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn cameras() -> [Camera; 2] {
        [
            Camera::tum_default(),
            Camera::new(481.2, -480.0, 319.5, 239.5, 640, 480),
        ]
    }

    proptest! {
        #[test]
        fn projection_round_trips(u in 0.0f64..640.0, v in 0.0f64..480.0, z in 0.2f64..8.0) {
            for cam in cameras() {
                let p = cam.back_project(u, v, z);
                let (pu, pv) = cam.project(&p).unwrap();
                prop_assert!((pu - u).abs() < 1e-9 && (pv - v).abs() < 1e-9);
                prop_assert!((p.z - z).abs() < 1e-12);
                let r = cam.ray(u, v);
                prop_assert!((r.norm() - 1.0).abs() < 1e-12 && r.z > 0.0);
            }
        }

        #[test]
        fn pyramid_levels_keep_pixel_geometry(x in -1.0f64..1.0, y in -1.0f64..1.0, z in 0.5f64..5.0, l in 1usize..4) {
            // A point seen at (u, v) on level 0 is seen at ((u + ½)/2^l − ½, (v + ½)/2^l − ½) on level l.
            for cam in cameras() {
                let p = Point3::new(x, y, z);
                let (u, v) = cam.project(&p).unwrap();
                let (ul, vl) = cam.level(l).project(&p).unwrap();
                let s = (1u64 << l) as f64;
                prop_assert!((ul - ((u + 0.5) / s - 0.5)).abs() < 1e-9);
                prop_assert!((vl - ((v + 0.5) / s - 0.5)).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn pyramid_intrinsics() {
        let c = Camera::tum_default().level(1);
        assert_eq!(
            (c.fx, c.fy, c.cx, c.cy, c.width, c.height),
            (262.5, 262.5, 159.5, 119.5, 320, 240)
        );
        let c = Camera::tum_default().level(2);
        assert_eq!((c.fx, c.cx, c.width, c.height), (131.25, 79.5, 160, 120));
        let icl = Camera::new(481.2, -480.0, 319.5, 239.5, 640, 480);
        assert_eq!(icl.level(1).fy, -240.0);
        assert_eq!(icl.handedness(), -1.0);
    }

    #[test]
    fn points_behind_or_outside_are_rejected() {
        let c = Camera::tum_default();
        assert!(c.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
        assert!(c.project_to_pixel(&Point3::new(10.0, 0.0, 1.0)).is_none());
        assert_eq!(
            c.project_to_pixel(&Point3::new(0.0, 0.0, 1.0)),
            Some((320, 240))
        );
    }
}
