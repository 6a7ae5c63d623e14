//! Deforming scenes for the non-rigid work: a surface (plane, cylinder, sphere or any mesh) moved by
//! a known smooth field over time, with the ground-truth deformed mesh and per-pixel scene flow.
//!
//! Fields act in the surface's own frame (long axis y, the plane's normal z), with an amplitude
//! that swings as `sin(2π k / period)` over frames k:
//! - bend: the plate curls about an axis parallel to x, curvature κ(k) (1/m);
//! - twist: rotation about y by τ(k)·y radians;
//! - wave: a travelling ripple `a(k) sin(2π (x/λ − k/period)) cos(π y/λ)` along z.

use super::render::{render, Rendering};
use super::scene::{RayMesh, Scene, Shape};
use super::texture::Texture;
use crate::camera::Camera;
use crate::image::Image;
use crate::mesh::Mesh;
use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use std::sync::Arc;

/// The distance of each tracked point `warped` from the truth `truth` (the same order).
pub fn distances(truth: &[Point3<f64>], warped: &[Vector3<f64>]) -> Vec<f64> {
    truth
        .iter()
        .zip(warped)
        .map(|(t, w)| (t.coords - w).norm())
        .collect()
}

/// A smooth deformation field.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Field {
    /// Curl about an axis parallel to x.
    Bend,
    /// Rotation about y, growing along y.
    Twist,
    /// A travelling ripple along z.
    Wave,
}

/// Built-in surfaces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SurfaceKind {
    /// A 1 m × 1 m plate.
    Plane,
    /// An open cylinder, radius 0.25 m, height 0.8 m, axis y.
    Cylinder,
    /// A sphere of radius 0.3 m.
    Sphere,
}

/// Two triangles per cell of a `(cols + 1) × (rows + 1)` vertex grid stored row by row,
/// counter-clockwise when columns run along +x and rows along +y.
pub(crate) fn grid(m: &mut Mesh, cols: usize, rows: usize) {
    let stride = cols as u32 + 1;
    for j in 0..rows as u32 {
        for i in 0..cols as u32 {
            let a = j * stride + i;
            let (b, c, d) = (a + 1, a + stride, a + stride + 1);
            m.faces.push([a, b, d]);
            m.faces.push([a, d, c]);
        }
    }
}

/// Tessellates a built-in surface (counter-clockwise seen from outside / from +z).
pub fn surface(kind: SurfaceKind, resolution: usize) -> Mesh {
    let n = resolution.max(2);
    let mut m = Mesh::default();
    match kind {
        SurfaceKind::Plane => {
            for j in 0..=n {
                for i in 0..=n {
                    m.vertices.push(Point3::new(
                        i as f32 / n as f32 - 0.5,
                        j as f32 / n as f32 - 0.5,
                        0.0,
                    ));
                }
            }
            grid(&mut m, n, n);
        }
        SurfaceKind::Cylinder => {
            let cols = 2 * n;
            for j in 0..=n {
                for i in 0..=cols {
                    let a = std::f32::consts::TAU * i as f32 / cols as f32;
                    m.vertices.push(Point3::new(
                        0.25 * a.cos(),
                        0.8 * (j as f32 / n as f32 - 0.5),
                        -0.25 * a.sin(),
                    ));
                }
            }
            grid(&mut m, cols, n);
        }
        SurfaceKind::Sphere => {
            let cols = 2 * n;
            for j in 0..=n {
                let polar = std::f32::consts::PI * j as f32 / n as f32;
                for i in 0..=cols {
                    let a = std::f32::consts::TAU * i as f32 / cols as f32;
                    m.vertices.push(Point3::new(
                        0.3 * polar.sin() * a.cos(),
                        -0.3 * polar.cos(),
                        -0.3 * polar.sin() * a.sin(),
                    ));
                }
            }
            grid(&mut m, cols, n);
        }
    }
    m.compute_normals();
    m
}

/// A surface deforming over time in front of a camera.
#[derive(Clone, Debug)]
pub struct DeformingScene {
    /// The undeformed surface, in its own frame.
    pub canonical: Mesh,
    /// The field.
    pub field: Field,
    /// Peak amplitude (κ in 1/m for bend, τ in rad/m for twist, metres for wave).
    pub amplitude: f64,
    /// Frames per swing of the amplitude.
    pub period: f64,
    /// Surface-to-world pose.
    pub pose: Isometry3<f64>,
    /// Its texture (fixed to the material, looked up at canonical positions).
    pub texture: Texture,
    /// Static surroundings (may be empty).
    pub background: Scene,
}

impl DeformingScene {
    /// A surface with the default amplitude of its field, 1.5 m in front of a camera at the origin
    /// looking along +z (world = first camera frame).
    pub fn new(canonical: Mesh, field: Field, seed: u64) -> Self {
        let amplitude = match field {
            Field::Bend => 1.5,
            Field::Twist => 1.5,
            Field::Wave => 0.04,
        };
        let pose = Isometry3::from_parts(
            nalgebra::Translation3::new(0.0, 0.0, 1.5),
            UnitQuaternion::from_scaled_axis(Vector3::y() * std::f64::consts::PI),
        );
        Self {
            canonical,
            field,
            amplitude,
            period: 60.0,
            pose,
            texture: Texture::random(seed, 8.0, 40.0),
            background: Scene::default(),
        }
    }

    fn amount(&self, frame: f64) -> f64 {
        self.amplitude * (std::f64::consts::TAU * frame / self.period).sin()
    }

    /// Where the material point at canonical `p` is at `frame` (surface frame).
    pub fn deform(&self, p: &Point3<f64>, frame: f64) -> Point3<f64> {
        let a = self.amount(frame);
        match self.field {
            Field::Bend => {
                if a.abs() < 1e-9 {
                    return *p;
                }
                let r = 1.0 / a - p.z;
                Point3::new(p.x, r * (a * p.y).sin(), 1.0 / a - r * (a * p.y).cos())
            }
            Field::Twist => {
                let q = UnitQuaternion::from_scaled_axis(Vector3::y() * (a * p.y));
                q * p
            }
            Field::Wave => {
                let lambda = 0.5;
                let phase = std::f64::consts::TAU * (p.x / lambda - frame / self.period);
                Point3::new(
                    p.x,
                    p.y,
                    p.z + a * phase.sin() * (std::f64::consts::PI * p.y / lambda).cos(),
                )
            }
        }
    }

    /// Where the material point seen at world position `x` at frame 0 is at `frame` (world
    /// coordinates): the ground truth of a non-rigid tracker whose canonical frame is frame 0.
    pub fn follow(&self, x: &Point3<f64>, frame: f64) -> Point3<f64> {
        self.pose * self.deform(&self.pose.inverse_transform_point(x), frame)
    }

    /// [`Self::follow`] of every canonical point (world positions at frame 0) to `frame`.
    pub fn follow_all(&self, canonical: &[Vector3<f64>], frame: usize) -> Vec<Point3<f64>> {
        let frame = frame as f64;
        canonical
            .iter()
            .map(|p| self.follow(&Point3::from(*p), frame))
            .collect()
    }

    /// Distances between canonical points (world positions at frame 0) carried to `frame` by a
    /// tracker (`warped`) and where their material points truly are then.
    pub fn tracking_errors(
        &self,
        canonical: &[Vector3<f64>],
        warped: &[Vector3<f64>],
        frame: usize,
    ) -> Vec<f64> {
        distances(&self.follow_all(canonical, frame), warped)
    }

    /// Which of the world points `points` (where material points truly are at `frame`) a camera
    /// at `pose` sees: in the image, at a valid depth, and with nothing of the scene (the
    /// deformed surface included) on the ray to it closer than `tolerance` short of it. The
    /// tolerance absorbs a point's own distance from the surface (a tracker's canonical points
    /// lie within its fusion's error of it).
    pub fn visible(
        &self,
        camera: &Camera,
        pose: &Isometry3<f64>,
        frame: usize,
        points: &[Point3<f64>],
        tolerance: f64,
    ) -> Vec<bool> {
        let scene = self.scene_at(frame);
        let prepared = scene.prepare();
        let origin = Point3::from(pose.translation.vector);
        points
            .par_iter()
            .map(|x| {
                let local = pose.inverse_transform_point(x);
                if camera.project_to_pixel(&local).is_none() || !camera.valid_depth(local.z) {
                    return false;
                }
                let ray = x - origin;
                let distance = ray.norm();
                distance > tolerance
                    && !prepared.blocked(&origin, &(ray / distance), distance - tolerance)
            })
            .collect()
    }

    /// What a depth sensor at `pose` delivers at `frame`: raw depth at the camera's depth scale and
    /// colour, through `noise` (seeded by the frame).
    pub fn sensor_frame(
        &self,
        camera: &Camera,
        pose: &Isometry3<f64>,
        frame: usize,
        noise: &super::noise::SensorNoise,
    ) -> (Image<u16>, crate::image::ColorImage) {
        let (depth, color, _) = self.sensor_frame_seen(camera, pose, frame, noise);
        (depth, color)
    }

    /// [`Self::sensor_frame`], and which pixels see the deforming surface (not the background
    /// nor nothing): the object's mask.
    pub fn sensor_frame_seen(
        &self,
        camera: &Camera,
        pose: &Isometry3<f64>,
        frame: usize,
        noise: &super::noise::SensorNoise,
    ) -> (Image<u16>, crate::image::ColorImage, Image<bool>) {
        let scene = self.scene_at(frame);
        let surface = scene.objects.len() - 1;
        let mut r = render(&scene, camera, pose);
        let depth = noise.apply(
            frame as u64,
            &r.depth,
            &r.cos_incidence,
            &mut r.color,
            camera.depth_scale,
        );
        let seen = r
            .hits
            .iter()
            .map(|h| h.as_ref().is_some_and(|h| h.object == surface))
            .collect();
        let mask = Image::from_vec(camera.width, camera.height, seen).expect("one hit per pixel");
        (depth, r.color, mask)
    }

    /// The deformed surface at `frame`, in world coordinates (the ground-truth mesh).
    pub fn mesh_at(&self, frame: usize) -> Mesh {
        let mut m = self.canonical.clone();
        for v in m.vertices.iter_mut() {
            *v = (self.pose * self.deform(&v.cast(), frame as f64)).cast();
        }
        m.compute_normals();
        m
    }

    /// The scene at `frame`: the deformed surface (texture bound to canonical positions) and the
    /// background.
    pub fn scene_at(&self, frame: usize) -> Scene {
        let world = self.mesh_at(frame);
        let coords = self.canonical.vertices.iter().map(|p| p.cast()).collect();
        let mut scene = self.background.clone();
        scene.add(
            Shape::Mesh(Arc::new(RayMesh::with_texture_coords(world, coords))),
            Isometry3::identity(),
            self.texture.clone(),
        );
        scene
    }

    /// Renders `frame` from `camera` at `pose` and the scene flow of every pixel to `frame + 1`
    /// (world-frame displacement of the material point seen there; NaN where the pixel sees no
    /// deforming surface, zero on the static background).
    pub fn render_with_flow(
        &self,
        camera: &Camera,
        pose: &Isometry3<f64>,
        frame: usize,
    ) -> (Rendering, Image<[f32; 3]>) {
        let scene = self.scene_at(frame);
        let surface = scene.objects.len() - 1;
        let r = render(&scene, camera, pose);
        let mut flow = Image::filled(camera.width, camera.height, [f32::NAN; 3]);
        for (i, hit) in r.hits.iter().enumerate() {
            let Some(hit) = hit else { continue };
            if hit.object != surface {
                flow.data[i] = [0.0; 3];
                continue;
            }
            let Some((tri, w)) = hit.triangle else {
                continue;
            };
            let f = self.canonical.faces[tri];
            let mut d = Vector3::zeros();
            for (&vi, wi) in f.iter().zip(w) {
                let c = self.canonical.vertices[vi as usize].cast();
                d += (self.pose * self.deform(&c, frame as f64 + 1.0)
                    - self.pose * self.deform(&c, frame as f64))
                    * wi;
            }
            flow.data[i] = [d.x as f32, d.y as f32, d.z as f32];
        }
        (r, flow)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_are_identity_at_rest_and_isometric_where_they_should_be() {
        for field in [Field::Bend, Field::Twist, Field::Wave] {
            let s = DeformingScene::new(surface(SurfaceKind::Plane, 10), field, 1);
            for v in &s.canonical.vertices {
                let p = v.cast();
                assert!(
                    (s.deform(&p, 0.0) - p).norm() < 1e-12,
                    "{field:?} moves points at frame 0"
                );
            }
        }
        // Bending keeps distances along the surface; twisting keeps them across its axis.
        let bend = DeformingScene::new(surface(SurfaceKind::Plane, 10), Field::Bend, 1);
        let (a, b) = (Point3::new(0.1, 0.2, 0.0), Point3::new(0.1, 0.201, 0.0));
        let d = (bend.deform(&a, 15.0) - bend.deform(&b, 15.0)).norm();
        assert!((d - 0.001).abs() < 1e-6, "bend: {d}");
        let twist = DeformingScene::new(surface(SurfaceKind::Plane, 10), Field::Twist, 1);
        let (a, b) = (Point3::new(0.1, 0.3, 0.0), Point3::new(0.4, 0.3, 0.0));
        let d = (twist.deform(&a, 15.0) - twist.deform(&b, 15.0)).norm();
        assert!((d - 0.3).abs() < 1e-9, "twist: {d}");
        assert!(
            (twist.deform(&a, 15.0) - a).norm() > 0.01,
            "the twist moves points"
        );
    }

    #[test]
    fn a_tube_shows_its_front_and_hides_its_back() {
        let s = DeformingScene::new(surface(SurfaceKind::Cylinder, 40), Field::Bend, 1);
        let cam = Camera::new(200.0, 200.0, 79.5, 59.5, 160, 120);
        let world = s.mesh_at(0);
        let (mut front, mut back): (Vec<Point3<f64>>, Vec<Point3<f64>>) = (vec![], vec![]);
        // faces' centres: a ray through a vertex or along an edge may pass between triangles
        let centres = world.faces.iter().map(|f| {
            let sum: Vector3<f64> = f
                .iter()
                .map(|&i| world.vertices[i as usize].coords.cast())
                .sum();
            Point3::from(sum / 3.0)
        });
        for v in centres {
            // the axis is at z = 1.5; keep away from the rim seen edge-on and the cut ends
            if v.y.abs() < 0.3 && (v.z - 1.5).abs() > 0.15 {
                if v.z < 1.5 { &mut front } else { &mut back }.push(v);
            }
        }
        assert!(front.len() > 50 && back.len() > 50);
        let id = Isometry3::identity();
        let seen = |points: &[Point3<f64>], tolerance| s.visible(&cam, &id, 0, points, tolerance);
        assert!(seen(&front, 0.005).iter().all(|&v| v), "the front is seen");
        assert!(seen(&back, 0.005).iter().all(|&v| !v), "the back is hidden");
        // a point 2 cm inside the tube behind its front: hidden at 1 cm, seen at 3 cm
        let inside: Vec<_> = front
            .iter()
            .map(|p| p + p.coords.normalize() * 0.02)
            .collect();
        assert!(seen(&inside, 0.01).iter().all(|&v| !v));
        assert!(seen(&inside, 0.03).iter().all(|&v| v));
        // out of the image, or behind the camera
        let out = [Point3::new(3.0, 0.0, 1.0), Point3::new(0.0, 0.0, -1.0)];
        assert_eq!(seen(&out, 0.005), [false, false]);
    }

    #[test]
    fn scene_flow_matches_the_mesh_motion() {
        let s = DeformingScene::new(surface(SurfaceKind::Plane, 30), Field::Wave, 2);
        let cam = Camera::new(200.0, 200.0, 79.5, 59.5, 160, 120);
        let (r, flow) = s.render_with_flow(&cam, &Isometry3::identity(), 5);
        let seen = flow.data.iter().filter(|f| f[0].is_finite()).count();
        assert!(seen > 5000, "{seen} pixels see the surface");
        // The flow carries the hit point of frame 5 onto the deformed surface of frame 6.
        let next = s.mesh_at(6);
        let index = crate::eval::SurfaceDistance::new(&next).unwrap();
        let mut worst: f64 = 0.0;
        for (i, hit) in r.hits.iter().enumerate() {
            if let (Some(h), f) = (hit, flow.data[i]) {
                if f[0].is_finite() {
                    let moved = h.point + Vector3::new(f[0] as f64, f[1] as f64, f[2] as f64);
                    worst = worst.max(index.distance(&moved));
                }
            }
        }
        assert!(
            worst < 1e-6,
            "moved points leave the next surface by {worst} m"
        );
    }
}
