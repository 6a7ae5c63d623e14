//! Generated frame pairs for frame-to-frame non-rigid registration (DeepDeform's setting, Božič
//! et al. 2020): a textured surface deformed by a known field ([`super::deform`]), seen at frame 0
//! and at a later frame from a moved camera, optionally before a wall, with each source point's
//! true scene flow.

use super::deform::{surface, DeformingScene, Field, SurfaceKind};
use super::noise::SensorNoise;
use super::scene::Shape;
use super::texture::Texture;
use crate::camera::Camera;
use crate::eval::{epe3d, EpeResult};
use crate::image::{depth_to_metres, ColorImage, DepthImage, Image};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// One generated pair: which surface, field and texture, where the second camera is, at which
/// frame, and whether a wall stands behind.
#[derive(Clone, Debug, PartialEq)]
pub struct FramePairCase {
    /// The surface.
    pub kind: SurfaceKind,
    /// Its deformation.
    pub field: Field,
    /// The texture's seed (and the sensor noise's, through the frames).
    pub seed: u64,
    /// The second camera's pose in the first's frame.
    pub moved: Isometry3<f64>,
    /// The second frame (the field swings over 60 frames).
    pub frame: usize,
    /// A textured wall 0.8 m behind the surface, over which its outline moves.
    pub wall: bool,
}

/// The two frames of a [`FramePairCase`], in metres, and what their truth needs.
pub struct FramePair {
    /// Both frames' intrinsics.
    pub camera: Camera,
    /// The first frame's depth (metres) and colour.
    pub source: (DepthImage, ColorImage),
    /// The first frame's pixels that see the surface (the object's mask).
    pub mask: Image<bool>,
    /// The second frame's.
    pub target: (DepthImage, ColorImage),
    scene: DeformingScene,
    moved: Isometry3<f64>,
    frame: usize,
}

impl FramePairCase {
    /// Every surface (plate, cylinder, ball) under every field (bend, twist, wave) for `seeds`
    /// seeds from `first`: the camera moves 6–12 cm across and 0–2 cm up and turns 4–8° about
    /// the vertical, and the second frame is 6–12, each by the seed.
    pub fn set(first: u64, seeds: u64, wall: bool) -> Vec<Self> {
        let mut cases = Vec::new();
        for kind in [
            SurfaceKind::Plane,
            SurfaceKind::Cylinder,
            SurfaceKind::Sphere,
        ] {
            for field in [Field::Bend, Field::Twist, Field::Wave] {
                for seed in first..first + seeds {
                    let s = seed as f64;
                    let moved = Isometry3::from_parts(
                        Translation3::new(0.06 + 0.03 * (s % 3.0), 0.02 * (s % 2.0), 0.0),
                        UnitQuaternion::from_scaled_axis(
                            Vector3::y() * (4.0 + 2.0 * (s % 3.0)).to_radians(),
                        ),
                    );
                    let frame = 6 + (seed as usize % 4) * 2;
                    cases.push(Self {
                        kind,
                        field,
                        seed,
                        moved,
                        frame,
                        wall,
                    });
                }
            }
        }
        cases
    }

    /// NOTES 147's pairs moved far (12–33 cm; 8–16° of turn), for registrations started without
    /// colour features: `set` 0, on which the outline search was shaped (seeds 30–35), or any
    /// other, held out (seeds 40–45, another surface for each of the first three, another motion).
    pub fn far_set(set: u8, wall: bool) -> Vec<Self> {
        use SurfaceKind::{Cylinder, Plane, Sphere};
        let firsts = if set == 0 {
            [
                (Plane, Field::Bend),
                (Cylinder, Field::Wave),
                (Sphere, Field::Twist),
            ]
        } else {
            [
                (Plane, Field::Wave),
                (Cylinder, Field::Twist),
                (Sphere, Field::Bend),
            ]
        };
        let lasts = [
            (Plane, Field::Twist),
            (Cylinder, Field::Bend),
            (Sphere, Field::Wave),
        ];
        (firsts.into_iter().chain(lasts).enumerate())
            .map(|(k, (kind, field))| {
                let s = k as f64;
                let (shift, turn) = if set == 0 {
                    (
                        Vector3::new(0.25 - 0.1 * s, 0.2 - 0.08 * s, 0.05 * s - 0.1),
                        Vector3::new(0.05, 0.1, 0.2 - 0.08 * s),
                    )
                } else {
                    (
                        Vector3::new(0.08 * s - 0.22, 0.12 - 0.06 * s, 0.08 - 0.04 * s),
                        Vector3::new(0.03 * s - 0.08, 0.12 - 0.04 * s, 0.06 * s - 0.15),
                    )
                };
                Self {
                    kind,
                    field,
                    seed: if set == 0 { 30 } else { 40 } + k as u64,
                    moved: Isometry3::from_parts(
                        Translation3::from(shift),
                        UnitQuaternion::from_scaled_axis(turn),
                    ),
                    frame: 8,
                    wall,
                }
            })
            .collect()
    }

    /// `plane-bend-3` and the like.
    pub fn name(&self) -> String {
        format!("{:?}-{:?}-{}", self.kind, self.field, self.seed).to_lowercase()
    }

    /// Renders both frames at 640 × 480 through the simple sensor model.
    pub fn render(&self) -> FramePair {
        let mut scene = DeformingScene::new(surface(self.kind, 60), self.field, self.seed);
        // a finer texture than the default, for corners (wavelengths 3 to 16 cm)
        scene.texture = Texture::random(self.seed, 40.0, 200.0);
        if self.wall {
            let behind = Isometry3::translation(0.0, 0.0, 2.3);
            let shape = Shape::Plane { hx: 3.0, hy: 3.0 };
            scene
                .background
                .add(shape, behind, Texture::random(self.seed + 1000, 8.0, 40.0));
        }
        let camera = Camera::tum_default();
        let noise = SensorNoise::default();
        let metres = |raw: &Image<u16>| {
            let mut out = Image::new(0, 0);
            depth_to_metres(raw, &camera, &mut out);
            out
        };
        let (d0, c0, mask) = scene.sensor_frame_seen(&camera, &Isometry3::identity(), 0, &noise);
        let (d1, c1) = scene.sensor_frame(&camera, &self.moved, self.frame, &noise);
        FramePair {
            source: (metres(&d0), c0),
            mask,
            target: (metres(&d1), c1),
            camera,
            scene,
            moved: self.moved,
            frame: self.frame,
        }
    }
}

impl FramePair {
    /// The true scene flow of `points` of the surface in the first frame (its camera's
    /// coordinates): where each one's material is at the second frame, in the second camera's
    /// coordinates, minus the point.
    pub fn flow(&self, points: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let to_target = self.moved.inverse();
        points
            .iter()
            .map(|p| {
                let x = Point3::from(*p);
                let on_surface = self.scene.follow(&x, self.frame as f64);
                (to_target * on_surface).coords - p
            })
            .collect()
    }

    /// The EPE 3D of a registration that carried the surface's `points` to `warped`, against
    /// [`Self::flow`], and zero flow's: (ours, zero).
    pub fn score(
        &self,
        points: &[Vector3<f64>],
        warped: &[Vector3<f64>],
    ) -> (EpeResult, EpeResult) {
        let truth = self.flow(points);
        let ours: Vec<Vector3<f64>> = warped.iter().zip(points).map(|(q, p)| q - p).collect();
        let zero = epe3d(&vec![Vector3::zeros(); truth.len()], &truth, None);
        (epe3d(&ours, &truth, None), zero)
    }
}
