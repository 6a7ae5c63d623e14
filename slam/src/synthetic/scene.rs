//! Scenes of textured primitives and meshes, and ray intersection with them.

use super::bvh::Bvh;
use super::texture::Texture;
use super::view_cone::ViewCone;
use crate::mesh::Mesh;
use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};
use std::sync::Arc;

/// A triangle mesh ready for ray casting.
#[derive(Clone, Debug)]
pub struct RayMesh {
    /// The mesh (in the object's frame).
    pub mesh: Mesh,
    /// Its hierarchy.
    pub bvh: Bvh,
    /// Where each vertex's texture is looked up (the undeformed positions for deforming surfaces).
    pub texture_coords: Vec<Point3<f64>>,
    /// The largest distance of a vertex from the mesh's origin (its bounding sphere's radius).
    pub radius: f64,
}

impl RayMesh {
    /// Indexes a mesh; texture is looked up at the vertices' own positions.
    pub fn new(mesh: Mesh) -> Self {
        let texture_coords = mesh.vertices.iter().map(|p| p.cast()).collect();
        Self::with_texture_coords(mesh, texture_coords)
    }
    /// Indexes a mesh with separate texture-lookup positions (one per vertex).
    pub(crate) fn with_texture_coords(mesh: Mesh, texture_coords: Vec<Point3<f64>>) -> Self {
        let v: Vec<Point3<f64>> = mesh.vertices.iter().map(|p| p.cast()).collect();
        Self {
            bvh: Bvh::new(&v, &mesh.faces),
            radius: v.iter().map(|p| p.coords.norm()).fold(0.0, f64::max),
            mesh,
            texture_coords,
        }
    }
}

/// A shape in its own frame.
#[derive(Clone, Debug)]
pub enum Shape {
    /// The rectangle |x| ≤ hx, |y| ≤ hy of the plane z = 0 (seen from both sides).
    Plane {
        /// Half-size along x.
        hx: f64,
        /// Half-size along y.
        hy: f64,
    },
    /// The box |x| ≤ h.x, |y| ≤ h.y, |z| ≤ h.z.
    Cuboid {
        /// Half-sizes.
        half: Vector3<f64>,
    },
    /// The sphere of this radius about the origin.
    Sphere {
        /// Radius.
        radius: f64,
    },
    /// The capped cylinder x² + y² ≤ r², |z| ≤ h.
    Cylinder {
        /// Radius.
        radius: f64,
        /// Half-height.
        half_height: f64,
    },
    /// A triangle mesh.
    Mesh(Arc<RayMesh>),
}

impl Shape {
    /// The squared radius of a sphere about the shape's origin that holds all of it.
    pub(crate) fn bounding_radius_squared(&self) -> f64 {
        match self {
            Shape::Plane { hx, hy } => hx * hx + hy * hy,
            Shape::Cuboid { half } => half.norm_squared(),
            Shape::Sphere { radius } => radius * radius,
            Shape::Cylinder {
                radius,
                half_height,
            } => radius * radius + half_height * half_height,
            Shape::Mesh(m) => m.radius * m.radius,
        }
    }
}

/// A shape placed in the world with a texture.
#[derive(Clone, Debug)]
pub struct Object {
    /// The shape.
    pub shape: Shape,
    /// Object-to-world pose.
    pub pose: Isometry3<f64>,
    /// Its texture (looked up in the object's frame).
    pub texture: Texture,
}

/// A ray's nearest hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the unit ray.
    pub t: f64,
    /// World point.
    pub point: Point3<f64>,
    /// World unit normal, facing the ray.
    pub normal: Vector3<f64>,
    /// Albedo in [0, 1]³.
    pub albedo: [f64; 3],
    /// Object index.
    pub object: usize,
    /// For meshes: triangle and barycentric weights of its vertices.
    pub triangle: Option<(usize, [f64; 3])>,
}

/// The ray (origin, direction) in the frame of an object at `pose`.
#[inline]
fn to_local(
    pose: &Isometry3<f64>,
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
) -> (Vector3<f64>, Vector3<f64>) {
    let inv = pose.inverse();
    ((inv * origin).coords, inv.rotation * dir)
}

/// A [`Scene`] ready for casting many rays (see [`Scene::prepare`]); it borrows the scene, so the
/// scene cannot change under it.
#[derive(Clone, Debug)]
pub struct PreparedScene<'a> {
    scene: &'a Scene,
    /// Every object's world-to-object transform, shared by the views [`Self::within`] makes.
    to_object: Arc<[(Matrix3<f64>, Vector3<f64>)]>,
    /// The objects rays are tested against, in the scene's order (all, or those a
    /// [`ViewCone`] may meet).
    order: Vec<usize>,
    /// For a view made by [`Self::within`]: what each of `order`'s objects makes of rays from the
    /// cone's apex, worked out once for all of them.
    eye: Option<Eye>,
}

/// The parts of a ray's tests against an object that depend only on the ray's origin, for rays
/// from one point (a camera's centre): the same operations on the same numbers as per ray, so the
/// same bits.
#[derive(Clone, Debug)]
struct Eye {
    origin: Point3<f64>,
    /// One per object of the view's order.
    parts: Vec<EyePart>,
}

/// What rays from an [`Eye`] share for one object.
#[derive(Clone, Copy, Debug)]
struct EyePart {
    /// The object's centre less the eye.
    to_centre: Vector3<f64>,
    /// Its squared norm.
    to_centre2: f64,
    /// The squared radius of the object's bounding sphere.
    radius2: f64,
    /// The eye in the object's frame.
    local_origin: Vector3<f64>,
}

impl PreparedScene<'_> {
    /// The same scene for the rays of `cone` only: the objects none of them can meet are left
    /// out, the others tested in the same order, so every answer for such a ray is the same.
    /// Rays from the cone's apex (see [`ViewCone::apex`]) reuse the parts of their tests that
    /// depend on the origin alone.
    pub fn within(&self, cone: &ViewCone) -> Self {
        let objects = &self.scene.objects;
        let order: Vec<usize> = (self.order.iter().copied())
            .filter(|&k| {
                let o = &objects[k];
                cone.may_meet(
                    &Point3::from(o.pose.translation.vector),
                    o.shape.bounding_radius_squared(),
                )
            })
            .collect();
        let origin = cone.apex();
        let parts = (order.iter())
            .map(|&k| {
                let obj = &objects[k];
                let to_centre = obj.pose.translation.vector - origin.coords;
                let (r, t) = &self.to_object[k];
                EyePart {
                    to_centre,
                    to_centre2: to_centre.norm_squared(),
                    radius2: obj.shape.bounding_radius_squared(),
                    local_origin: r * origin.coords + t,
                }
            })
            .collect();
        Self {
            scene: self.scene,
            to_object: Arc::clone(&self.to_object),
            order,
            eye: Some(Eye { origin, parts }),
        }
    }

    /// How many objects rays are tested against.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// Whether rays meet nothing.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    #[inline]
    fn local(
        &self,
        k: usize,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
    ) -> (Vector3<f64>, Vector3<f64>) {
        let (r, t) = &self.to_object[k];
        (r * origin.coords + t, r * dir)
    }

    /// As [`Scene::surface`].
    pub fn surface(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
    ) -> Option<(f64, Point3<f64>, Vector3<f64>)> {
        let n = self.nearest(origin, dir)?;
        Some((n.t, self.scene.objects[n.object].pose * n.local, n.normal))
    }

    /// As [`Scene::intersect`].
    pub(crate) fn intersect(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        let n = self.nearest(origin, dir)?;
        Some(self.scene.textured(n))
    }

    /// The nearest hit among the view's objects: from the eye by its parts, else object by object.
    fn nearest(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Nearest> {
        let (order, scene) = (&self.order, self.scene);
        match &self.eye {
            Some(eye) if eye.origin == *origin => {
                scene.nearest_with(order.len(), dir, |i, t_max| {
                    let (p, k) = (&eye.parts[i], order[i]);
                    may_hit_from(&p.to_centre, p.to_centre2, p.radius2, dir, t_max)
                        .then(|| (k, (p.local_origin, self.to_object[k].0 * dir)))
                })
            }
            _ => scene.nearest_with(order.len(), dir, |i, t_max| {
                let k = order[i];
                may_hit(&scene.objects[k], origin, dir, t_max)
                    .then(|| (k, self.local(k, origin, dir)))
            }),
        }
    }

    /// As [`Scene::blocked`].
    pub fn blocked(&self, origin: &Point3<f64>, dir: &Vector3<f64>, t_max: f64) -> bool {
        self.order.iter().any(|&k| {
            let obj = &self.scene.objects[k];
            may_hit(obj, origin, dir, t_max) && {
                let (o, d) = self.local(k, origin, dir);
                intersect_local(&obj.shape, &o, &d, t_max).is_some()
            }
        })
    }
}

/// The nearest hit before its texture is looked up.
struct Nearest {
    object: usize,
    t: f64,
    /// Local until [`Scene::nearest`] turns it into the world normal facing the ray.
    normal: Vector3<f64>,
    triangle: Option<(usize, [f64; 3])>,
    /// The hit in the object's frame.
    local: Point3<f64>,
}

/// A set of objects.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// The objects.
    pub objects: Vec<Object>,
}

/// Whether the ray may meet the object before `t_max`: a test against its bounding sphere in the
/// world frame, cheaper than moving the ray into the object's frame.
#[inline]
fn may_hit(obj: &Object, origin: &Point3<f64>, dir: &Vector3<f64>, t_max: f64) -> bool {
    let oc = obj.pose.translation.vector - origin.coords;
    let r2 = obj.shape.bounding_radius_squared();
    may_hit_from(&oc, oc.norm_squared(), r2, dir, t_max)
}

/// [`may_hit`] from the object's centre less the ray's origin, `oc`, its squared norm and the
/// bounding sphere's squared radius `r2`.
#[inline]
fn may_hit_from(oc: &Vector3<f64>, oc2: f64, r2: f64, dir: &Vector3<f64>, t_max: f64) -> bool {
    let along = oc.dot(dir);
    let off2 = oc2 - along * along;
    if off2 > r2 * (1.0 + 1e-9) + 1e-12 {
        return false;
    }
    // within the sphere's extent along the ray: (along - t)² ≤ r² for some t in (0, t_max)
    let before = along - t_max;
    (along > 0.0 || along * along <= r2) && (before < 0.0 || before * before <= r2)
}

/// Ray–shape intersection in the shape's frame: (t, local normal, triangle).
#[allow(clippy::type_complexity)]
fn intersect_local(
    shape: &Shape,
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    t_max: f64,
) -> Option<(f64, Vector3<f64>, Option<(usize, [f64; 3])>)> {
    const EPS: f64 = 1e-9;
    match shape {
        Shape::Plane { hx, hy } => {
            if d.z.abs() < 1e-15 {
                return None;
            }
            let t = -o.z / d.z;
            let p = o + d * t;
            (t > EPS && t < t_max && p.x.abs() <= *hx && p.y.abs() <= *hy)
                .then(|| (t, Vector3::z(), None))
        }
        Shape::Sphere { radius } => {
            let b = o.dot(d);
            let c = o.norm_squared() - radius * radius;
            let disc = b * b - c;
            if disc < 0.0 {
                return None;
            }
            let s = disc.sqrt();
            let t = if -b - s > EPS { -b - s } else { -b + s };
            (t > EPS && t < t_max).then(|| (t, (o + d * t) / *radius, None))
        }
        Shape::Cuboid { half } => hit_cuboid(half, o, d, t_max).map(|(t, n)| (t, n, None)),
        Shape::Cylinder {
            radius,
            half_height,
        } => hit_cylinder(*radius, *half_height, o, d, t_max).map(|(t, n)| (t, n, None)),
        Shape::Mesh(m) => {
            let h = m.bvh.intersect(o, d, t_max)?;
            let f = m.mesh.faces[h.triangle];
            let [a, b, c] = f.map(|i| m.mesh.vertices[i as usize].coords.cast::<f64>());
            let n = (b - a).cross(&(c - a)).try_normalize(1e-20)?;
            Some((h.t, n, Some((h.triangle, [1.0 - h.u - h.v, h.u, h.v]))))
        }
    }
}

/// Smallest EPS < t < t_max where the ray o + t d meets the axis-aligned box of half-sizes
/// `half` about the origin (slabs), with the face's outward normal.
fn hit_cuboid(
    half: &Vector3<f64>,
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    t_max: f64,
) -> Option<(f64, Vector3<f64>)> {
    const EPS: f64 = 1e-9;
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    let (mut n0, mut n1) = (Vector3::zeros(), Vector3::zeros());
    for a in 0..3 {
        if d[a].abs() < 1e-15 {
            if o[a].abs() > half[a] {
                return None;
            }
            continue;
        }
        let (mut near, mut far) = ((-half[a] - o[a]) / d[a], (half[a] - o[a]) / d[a]);
        let mut sign = -1.0;
        if near > far {
            std::mem::swap(&mut near, &mut far);
            sign = 1.0;
        }
        if near > t0 {
            t0 = near;
            n0 = Vector3::ith(a, sign);
        }
        if far < t1 {
            t1 = far;
            n1 = Vector3::ith(a, -sign);
        }
    }
    if t0 > t1 {
        return None;
    }
    if t0 > EPS && t0 < t_max {
        Some((t0, n0))
    } else if t1 > EPS && t1 < t_max {
        Some((t1, n1))
    } else {
        None
    }
}

/// Smallest EPS < t < t_max where the ray o + t d meets the cylinder of `radius` about the z
/// axis, |z| ≤ `half_height`, side or caps, with the outward normal.
fn hit_cylinder(
    radius: f64,
    half_height: f64,
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    t_max: f64,
) -> Option<(f64, Vector3<f64>)> {
    const EPS: f64 = 1e-9;
    let mut best: Option<(f64, Vector3<f64>)> = None;
    let a = d.x * d.x + d.y * d.y;
    if a > 1e-15 {
        let b = o.x * d.x + o.y * d.y;
        let c = o.x * o.x + o.y * o.y - radius * radius;
        let disc = b * b - a * c;
        if disc >= 0.0 {
            for t in [(-b - disc.sqrt()) / a, (-b + disc.sqrt()) / a] {
                let p = o + d * t;
                if t > EPS && t < t_max && p.z.abs() <= half_height && best.is_none_or(|b| t < b.0)
                {
                    best = Some((t, Vector3::new(p.x, p.y, 0.0) / radius));
                }
            }
        }
    }
    if d.z.abs() > 1e-15 {
        for cap in [-half_height, half_height] {
            let t = (cap - o.z) / d.z;
            let p = o + d * t;
            if t > EPS
                && t < t_max
                && p.x * p.x + p.y * p.y <= radius * radius
                && best.is_none_or(|b| t < b.0)
            {
                best = Some((t, Vector3::new(0.0, 0.0, cap.signum())));
            }
        }
    }
    best
}

impl Scene {
    /// Adds an object.
    pub fn add(&mut self, shape: Shape, pose: Isometry3<f64>, texture: Texture) -> usize {
        self.objects.push(Object {
            shape,
            pose,
            texture,
        });
        self.objects.len() - 1
    }

    /// The nearest hit of the ray from `origin` along the unit `dir` (world frame).
    pub fn intersect(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        Some(self.textured(self.nearest(origin, dir)?))
    }

    /// The hit with its texture looked up.
    fn textured(&self, n: Nearest) -> Hit {
        let obj = &self.objects[n.object];
        let tex_point = match (&obj.shape, n.triangle) {
            (Shape::Mesh(m), Some((ti, w))) => {
                let f = m.mesh.faces[ti];
                Point3::from(
                    f.iter()
                        .zip(w)
                        .map(|(&i, wi)| m.texture_coords[i as usize].coords * wi)
                        .sum::<Vector3<f64>>(),
                )
            }
            _ => n.local,
        };
        Hit {
            t: n.t,
            point: obj.pose * n.local,
            normal: n.normal,
            albedo: obj.texture.color(&tex_point),
            object: n.object,
            triangle: n.triangle,
        }
    }

    /// The nearest hit's geometry only, (t, world point, world unit normal facing the ray): no
    /// texture looked up.
    pub fn surface(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
    ) -> Option<(f64, Point3<f64>, Vector3<f64>)> {
        let n = self.nearest(origin, dir)?;
        Some((n.t, self.objects[n.object].pose * n.local, n.normal))
    }

    fn nearest(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Nearest> {
        self.nearest_with(self.objects.len(), dir, |k, t_max| {
            let obj = &self.objects[k];
            may_hit(obj, origin, dir, t_max).then(|| (k, to_local(&obj.pose, origin, dir)))
        })
    }

    /// The nearest hit along the unit `dir` among `count` candidates: `candidate(i, t_max)`
    /// gives the i-th's object and the ray in its frame, or `None` where the ray cannot meet it
    /// before `t_max`. Candidates are tried in order; a later one replaces a hit only nearer.
    fn nearest_with(
        &self,
        count: usize,
        dir: &Vector3<f64>,
        candidate: impl Fn(usize, f64) -> Option<(usize, (Vector3<f64>, Vector3<f64>))>,
    ) -> Option<Nearest> {
        let mut best: Option<Nearest> = None;
        for i in 0..count {
            let t_max = best.as_ref().map_or(f64::INFINITY, |b| b.t);
            let Some((k, (o, d))) = candidate(i, t_max) else {
                continue;
            };
            let obj = &self.objects[k];
            if let Some((t, normal, triangle)) = intersect_local(&obj.shape, &o, &d, t_max) {
                best = Some(Nearest {
                    object: k,
                    t,
                    normal,
                    triangle,
                    local: Point3::from(o + d * t),
                });
            }
        }
        let mut n = best?;
        n.normal = self.objects[n.object].pose.rotation * n.normal;
        if n.normal.dot(dir) > 0.0 {
            n.normal = -n.normal;
        }
        Some(n)
    }

    /// Whether anything lies on the ray from `origin` along the unit `dir` before `t_max` (a
    /// shadow ray: stops at the first hit, looks up no texture).
    pub fn blocked(&self, origin: &Point3<f64>, dir: &Vector3<f64>, t_max: f64) -> bool {
        self.objects.iter().any(|obj| {
            may_hit(obj, origin, dir, t_max) && {
                let (o, d) = to_local(&obj.pose, origin, dir);
                intersect_local(&obj.shape, &o, &d, t_max).is_some()
            }
        })
    }

    /// The scene with every object's world-to-object transform computed once, for casting many
    /// rays: the same answers as the scene's own methods, faster.
    pub fn prepare(&self) -> PreparedScene<'_> {
        PreparedScene {
            scene: self,
            to_object: self
                .objects
                .iter()
                .map(|o| {
                    let inv = o.pose.inverse();
                    (
                        inv.rotation.to_rotation_matrix().into_inner(),
                        inv.translation.vector,
                    )
                })
                .collect(),
            order: (0..self.objects.len()).collect(),
            eye: None,
        }
    }

    /// A furnished room around the origin (z up): floor, walls, a table and objects on and around it,
    /// all textured; `seed` varies textures. About 6 × 5 × 3 m.
    pub fn room(seed: u64) -> Self {
        let mut s = Scene::default();
        s.add_room_shell(seed);
        s.add_room_furniture(seed);
        s
    }

    /// The room's floor, ceiling and four walls.
    fn add_room_shell(&mut self, seed: u64) {
        let s = self;
        s.add(
            Shape::Plane { hx: 3.0, hy: 2.5 },
            place(0.0, 0.0, 0.0),
            room_texture(seed, 1, 3.0, 20.0),
        );
        s.add(
            Shape::Plane { hx: 3.0, hy: 2.5 },
            place(0.0, 0.0, 3.0),
            room_texture(seed, 2, 2.0, 10.0),
        );
        s.add(
            Shape::Plane { hx: 3.0, hy: 1.5 },
            turned(0.0, 2.5, 1.5, Vector3::x(), std::f64::consts::FRAC_PI_2),
            room_texture(seed, 3, 2.0, 15.0),
        );
        s.add(
            Shape::Plane { hx: 3.0, hy: 1.5 },
            turned(0.0, -2.5, 1.5, Vector3::x(), std::f64::consts::FRAC_PI_2),
            room_texture(seed, 4, 2.0, 15.0),
        );
        s.add(
            Shape::Plane { hx: 1.5, hy: 2.5 },
            turned(3.0, 0.0, 1.5, Vector3::y(), std::f64::consts::FRAC_PI_2),
            room_texture(seed, 5, 2.0, 15.0),
        );
        s.add(
            Shape::Plane { hx: 1.5, hy: 2.5 },
            turned(-3.0, 0.0, 1.5, Vector3::y(), std::f64::consts::FRAC_PI_2),
            room_texture(seed, 6, 2.0, 15.0),
        );
    }

    /// The room's table, the objects on it and the furniture around it.
    fn add_room_furniture(&mut self, seed: u64) {
        let s = self;
        s.add(
            Shape::Cuboid {
                half: Vector3::new(0.6, 0.4, 0.03),
            },
            place(0.0, 0.0, 0.72),
            room_texture(seed, 7, 5.0, 30.0),
        );
        s.add(
            Shape::Cuboid {
                half: Vector3::new(0.05, 0.05, 0.35),
            },
            place(0.5, 0.3, 0.35),
            room_texture(seed, 8, 5.0, 30.0),
        );
        s.add(
            Shape::Cuboid {
                half: Vector3::new(0.05, 0.05, 0.35),
            },
            place(-0.5, -0.3, 0.35),
            room_texture(seed, 9, 5.0, 30.0),
        );
        s.add(
            Shape::Sphere { radius: 0.15 },
            place(0.2, 0.1, 0.9),
            room_texture(seed, 10, 8.0, 40.0),
        );
        s.add(
            Shape::Cylinder {
                radius: 0.08,
                half_height: 0.12,
            },
            place(-0.25, -0.1, 0.87),
            room_texture(seed, 11, 8.0, 40.0),
        );
        s.add(
            Shape::Cuboid {
                half: Vector3::new(0.1, 0.15, 0.08),
            },
            turned(-0.1, 0.25, 0.83, Vector3::z(), 0.4),
            room_texture(seed, 12, 8.0, 40.0),
        );
        s.add(
            Shape::Cuboid {
                half: Vector3::new(0.4, 0.3, 0.45),
            },
            turned(1.8, -1.5, 0.45, Vector3::z(), 0.3),
            room_texture(seed, 13, 4.0, 25.0),
        );
        s.add(
            Shape::Cylinder {
                radius: 0.25,
                half_height: 0.5,
            },
            place(-1.8, 1.4, 0.5),
            room_texture(seed, 14, 4.0, 25.0),
        );
        s.add(
            Shape::Sphere { radius: 0.35 },
            place(1.5, 1.6, 0.35),
            room_texture(seed, 15, 4.0, 25.0),
        );
    }
}

/// The texture of the room's surface `k`: its seed from the room's.
fn room_texture(seed: u64, k: u64, lo: f64, hi: f64) -> Texture {
    Texture::random(seed.wrapping_mul(1000).wrapping_add(k), lo, hi)
}

/// A pose at (x, y, z), unrotated.
fn place(x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::translation(x, y, z)
}

/// A pose at (x, y, z), turned by `angle` about `axis`.
fn turned(x: f64, y: f64, z: f64, axis: Vector3<f64>, angle: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_scaled_axis(axis * angle),
    )
}
