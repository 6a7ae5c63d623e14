//! The TSDF map on rendered scenes with known geometry.

use dynamap::slam::camera::Camera;
use dynamap::slam::image::{normal_map, vertex_map, Image, NormalMap};
use dynamap::slam::synthetic::motion::look_at;
use dynamap::slam::synthetic::render::{render, Rendering};
use dynamap::slam::synthetic::scene::{Scene, Shape};
use dynamap::slam::synthetic::texture::Texture;
use dynamap::slam::tsdf::{RaycastMaps, TsdfParams, TsdfVolume};
use nalgebra::{Isometry3, Point3, Vector3};
use std::collections::HashMap;

const RADIUS: f64 = 0.3;

fn sphere_scene() -> Scene {
    let mut s = Scene::default();
    s.add(
        Shape::Sphere { radius: RADIUS },
        Isometry3::identity(),
        Texture::random(5, 5.0, 20.0),
    );
    s
}

/// Cameras on a sphere of radius 1.2 m around the origin: 3 latitudes × 8 longitudes plus the poles.
fn views() -> Vec<Isometry3<f64>> {
    let mut v = Vec::new();
    for lat in [-50.0f64, 0.0, 50.0] {
        for k in 0..8 {
            let lon = (k as f64 * 45.0 + lat).to_radians();
            let (la, lo) = (lat.to_radians(), lon);
            let eye = Point3::new(la.cos() * lo.cos(), la.cos() * lo.sin(), la.sin()) * 1.2;
            v.push(look_at(&eye, &Point3::origin(), &Vector3::z()));
        }
    }
    v.push(look_at(
        &Point3::new(0.0, 0.0, 1.2),
        &Point3::origin(),
        &Vector3::y(),
    ));
    v.push(look_at(
        &Point3::new(0.0, 0.0, -1.2),
        &Point3::origin(),
        &Vector3::y(),
    ));
    v
}

/// A rendering and the normals computed from its depth, as the pipeline would fuse them.
fn render_with_normals(
    scene: &Scene,
    cam: &Camera,
    pose: &Isometry3<f64>,
) -> (Rendering, NormalMap) {
    let r = render(scene, cam, pose);
    let (mut v, mut n) = (
        Image::filled(0, 0, [0.0f32; 3]),
        Image::filled(0, 0, [0.0f32; 3]),
    );
    vertex_map(&r.depth, cam, &mut v);
    normal_map(&v, cam, &mut n);
    (r, n)
}

/// The volume of these tests: 1 cm voxels, the other settings default.
fn params() -> TsdfParams {
    TsdfParams {
        voxel_size: 0.01,
        ..TsdfParams::default()
    }
}

/// `scene` rendered from `poses` at 320×240 and fused into a volume with [`params`].
fn fuse(scene: &Scene, poses: &[Isometry3<f64>]) -> TsdfVolume {
    let cam = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
    let mut vol = TsdfVolume::new(params());
    for pose in poses {
        let (r, n) = render_with_normals(scene, &cam, pose);
        vol.integrate(&r.depth, &n, Some(&r.color), &cam, pose)
            .unwrap();
    }
    vol
}

#[test]
fn a_fused_sphere_has_its_zero_crossing_at_the_true_radius() {
    let vol = fuse(&sphere_scene(), &views());
    // Along 200 directions, find where the interpolated distance crosses zero.
    let mut worst: f64 = 0.0;
    for k in 0..200 {
        let (a, b) = (
            k as f64 * 2.399963,
            (1.0 - 2.0 * (k as f64 + 0.5) / 200.0).acos(),
        );
        let dir = Vector3::new(b.sin() * a.cos(), b.sin() * a.sin(), b.cos()).cast::<f32>();
        let mut prev: Option<(f32, f32)> = None;
        let mut r = 0.2f32;
        let mut found = None;
        while r < 0.4 {
            if let Some(d) = vol.sdf(&Point3::from(dir * r)) {
                if let Some((rp, dp)) = prev {
                    if dp <= 0.0 && d > 0.0 {
                        found = Some(rp + (r - rp) * (-dp) / (d - dp));
                        break;
                    }
                }
                prev = Some((r, d));
            }
            r += 0.001;
        }
        let f = found.unwrap_or_else(|| panic!("no zero crossing along direction {k}")) as f64;
        worst = worst.max((f - RADIUS).abs());
    }
    assert!(
        worst < 0.5 * params().voxel_size as f64,
        "zero crossing up to {worst} m from the radius"
    );
}

#[test]
fn marching_cubes_of_a_sphere_is_watertight_with_the_right_area() {
    let vol = fuse(&sphere_scene(), &views());
    let mesh = vol.extract_mesh();
    assert!(mesh.faces.len() > 5000);
    // Watertight: every edge is shared by exactly two triangles, in opposite directions.
    // per undirected edge: (triangles using it, uses a→b minus uses b→a with a < b)
    let mut edges: HashMap<(u32, u32), (usize, i32)> = HashMap::new();
    for f in &mesh.faces {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            let e = edges.entry((a.min(b), a.max(b))).or_insert((0, 0));
            e.0 += 1;
            e.1 += if a < b { 1 } else { -1 };
        }
    }
    let open = edges.values().filter(|e| e.0 != 2).count();
    assert_eq!(open, 0, "{open} edges not shared by exactly two triangles");
    assert!(edges.values().all(|e| e.1 == 0), "inconsistent orientation");
    let area = mesh.area();
    let truth = 4.0 * std::f64::consts::PI * RADIUS * RADIUS;
    assert!((area / truth - 1.0).abs() < 0.02, "area {area} vs {truth}");
    // Faces point outwards.
    let outward = mesh
        .faces
        .iter()
        .filter(|f| {
            let [a, b, c] = f.map(|i| mesh.vertices[i as usize].coords);
            (b - a).cross(&(c - a)).dot(&a) > 0.0
        })
        .count();
    assert!(outward as f64 > 0.99 * mesh.faces.len() as f64);
}

#[test]
fn raycasting_the_model_reproduces_the_rendered_depth() {
    let vol = fuse(&sphere_scene(), &views());
    let cam = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
    let pose = look_at(
        &Point3::new(0.9, 0.5, 0.5),
        &Point3::origin(),
        &Vector3::z(),
    );
    let truth = render(&sphere_scene(), &cam, &pose);
    let mut maps = RaycastMaps::new();
    vol.raycast(&cam, &pose, &mut maps);
    let mut errors = Vec::new();
    for i in 0..truth.depth.data.len() {
        let (a, b) = (truth.depth.data[i], maps.depth.data[i]);
        if a > 0.0 && b > 0.0 {
            errors.push((a - b).abs());
        }
    }
    let hit = truth.depth.data.iter().filter(|d| **d > 0.0).count();
    assert!(
        errors.len() as f64 > 0.95 * hit as f64,
        "{} of {hit} pixels hit the model",
        errors.len()
    );
    errors.sort_by(f32::total_cmp);
    assert!(
        errors[errors.len() / 2] < 0.002,
        "median depth error {}",
        errors[errors.len() / 2]
    );
    let ok = maps
        .normals
        .data
        .iter()
        .zip(&truth.normals.data)
        .filter(|(m, t)| m[0].is_finite() && t[0].is_finite())
        .all(|(m, t)| {
            // model normals are world-frame; truth normals camera-frame
            let mw = Vector3::new(m[0], m[1], m[2]).cast::<f64>();
            let tw = pose.rotation * Vector3::new(t[0], t[1], t[2]).cast::<f64>();
            mw.dot(&tw) > 0.9
        });
    assert!(ok, "model normals disagree with the rendered ones");
}

/// A hint with runs of holes (a band across the sphere's edge, a patch inside it): the rays
/// there are marched on a stride and the skipped ones found from their neighbours. The holes see
/// as many sphere pixels as with every ray marched, and away from the limb (where a grazing
/// ray's crossing depends on where its search starts, with or without the stride) each at the
/// same depth.
#[test]
fn runs_of_holes_in_the_hint_are_marched_on_a_stride_and_filled_between() {
    let mut vol = fuse(&sphere_scene(), &views());
    let cam = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
    let pose = look_at(
        &Point3::new(0.9, 0.5, 0.5),
        &Point3::origin(),
        &Vector3::z(),
    );
    let mut full = RaycastMaps::new();
    vol.raycast(&cam, &pose, &mut full);
    let hole = |x: usize, y: usize| (60..180).contains(&y) && (x < 140 || (180..200).contains(&x));
    let mut hint = full.depth.clone();
    for (i, z) in hint.data.iter_mut().enumerate() {
        if hole(i % 320, i / 320) {
            *z = 0.0;
        }
    }
    let mut cast = |stride: usize| {
        vol.params.hole_stride = stride;
        let mut maps = RaycastMaps::new();
        vol.raycast_with_hint(&cam, &pose, Some(&hint), &mut maps);
        maps.depth
    };
    let (every, strided) = (cast(1), cast(4));
    let seen = |x: usize, y: usize| every.data[y * 320 + x] > 0.0;
    // within 6 pixels of the sphere's outline along the row
    let limb = |x: usize, y: usize| {
        (x.saturating_sub(6)..(x + 7).min(320)).any(|u| seen(u, y) != seen(x, y))
    };
    let (mut hits, mut judged, mut wrong) = ([0, 0], 0, Vec::new());
    for y in 0..240 {
        for x in (0..320).filter(|&x| hole(x, y)) {
            let (a, b) = (every.data[y * 320 + x], strided.data[y * 320 + x]);
            hits[0] += usize::from(a > 0.0);
            hits[1] += usize::from(b > 0.0);
            if !limb(x, y) {
                judged += usize::from(a > 0.0);
                if (a > 0.0) != (b > 0.0) || (a - b).abs() > 1e-4 {
                    wrong.push((x, y, a, b));
                }
            }
        }
    }
    // a stride without the filling loses one to three pixels where each row's run meets the
    // sphere, about 200 here
    assert!(
        hits[0] > 3000 && hits[1].abs_diff(hits[0]) <= 10,
        "sphere pixels {hits:?}"
    );
    assert!(judged > 3000, "{judged} pixels of the holes judged");
    let shown = &wrong[..wrong.len().min(8)];
    assert!(wrong.is_empty(), "{} pixels differ: {shown:?}", wrong.len());
}

#[test]
fn memory_follows_the_surface_area() {
    // Spheres of radius 0.15 and 0.3 seen from the same relative distance: 4× the area should need
    // about 4× the blocks.
    let mut counts = Vec::new();
    for (r, scale) in [(0.15, 0.5), (0.3, 1.0)] {
        let mut s = Scene::default();
        s.add(
            Shape::Sphere { radius: r },
            Isometry3::identity(),
            Texture::random(1, 5.0, 20.0),
        );
        let poses: Vec<Isometry3<f64>> = views()
            .into_iter()
            .map(|p| Isometry3::from_parts((p.translation.vector * scale).into(), p.rotation))
            .collect();
        let vol = fuse(&s, &poses);
        counts.push(vol.num_blocks() as f64);
        // per voxel: distance and weight (4 + 4 bytes), colour (RGB and a pad byte)
        assert_eq!(
            vol.memory_bytes(),
            vol.num_blocks() * (512 * 12 + std::mem::size_of::<dynamap::slam::tsdf::Block>())
        );
    }
    let ratio = counts[1] / counts[0];
    assert!(
        (2.8..5.0).contains(&ratio),
        "blocks {counts:?}: ratio {ratio} for 4x the area"
    );
}

/// The sphere seen from 1.2 m along +x at 320×240: camera, pose, rendering and normals.
fn sphere_from_the_side() -> (Camera, Isometry3<f64>, Rendering, NormalMap) {
    let cam = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
    let pose = look_at(
        &Point3::new(1.2, 0.0, 0.0),
        &Point3::origin(),
        &Vector3::z(),
    );
    let (r, n) = render_with_normals(&sphere_scene(), &cam, &pose);
    (cam, pose, r, n)
}

#[test]
fn the_block_budget_is_a_clear_error() {
    let (cam, pose, r, n) = sphere_from_the_side();
    let mut vol = TsdfVolume::new(TsdfParams {
        max_blocks: 10,
        ..TsdfParams::default()
    });
    let e = vol.integrate(&r.depth, &n, None, &cam, &pose).unwrap_err();
    assert!(e.to_string().contains("budget is exhausted"), "{e}");
    assert_eq!(vol.num_blocks(), 0, "nothing half-allocated");
}

/// A ray arriving from free space finds a one-sided wall whatever the phase and direction of its
/// long steps through free space (once, some phases landed behind the surface's thin band and
/// missed it, which drew arcs of holes in model views): free space is crossed cell face to cell
/// face, so the ray enters the wall's blocks at their faces.
#[test]
fn rays_from_free_space_find_a_thin_wall_at_every_step_phase() {
    let cam = Camera::new(131.25, 131.25, 79.5, 59.5, 160, 120);
    let depth: Image<f32> = Image::filled(160, 120, 1.0);
    let (mut v, mut n) = (
        Image::filled(0, 0, [0.0f32; 3]),
        Image::filled(0, 0, [0.0f32; 3]),
    );
    vertex_map(&depth, &cam, &mut v);
    normal_map(&v, &cam, &mut n);
    let mut vol = TsdfVolume::new(params());
    vol.integrate(&depth, &n, None, &cam, &Isometry3::identity())
        .unwrap();
    let mut missed = Vec::new();
    for k in 0..64 {
        let t_min = 0.2 + k as f32 * 0.00125; // a block (8 cm) of start phases
                                              // and directions up to 22° off the wall's normal, about two axes
        let (a, b) = ((k % 8) as f32 * 0.05, (k / 8) as f32 * 0.02);
        let dir = Vector3::new(a.sin() * b.cos(), b.sin(), a.cos() * b.cos());
        let wall = 1.0 / dir.z;
        match vol.cast_ray(&Point3::origin(), &dir, t_min, 2.0) {
            Some((_, _, _, t)) if (t - wall).abs() < 0.005 * wall => {}
            other => missed.push((t_min, dir, other.map(|h| h.3))),
        }
    }
    assert!(
        missed.is_empty(),
        "rays that missed the wall at 1 m: {missed:?}"
    );
}

/// Two spheres 5 m apart: fusing the second under a budget smaller than both evicts the first
/// (farthest from the camera) and keeps every block of the current view; without eviction the
/// frame fails instead.
#[test]
fn a_full_budget_evicts_the_blocks_farthest_from_the_camera() {
    let cam = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
    let mut scene = sphere_scene();
    let far = Vector3::new(5.0, 0.0, 0.0);
    scene.add(
        Shape::Sphere { radius: RADIUS },
        Isometry3::translation(far.x, far.y, far.z),
        Texture::random(6, 5.0, 20.0),
    );
    let at = |centre: Vector3<f64>, side: f64| {
        look_at(
            &(Point3::from(centre) + Vector3::new(0.0, side * 1.2, 0.0)),
            &Point3::from(centre),
            &Vector3::z(),
        )
    };
    let first = [at(Vector3::zeros(), 1.0), at(Vector3::zeros(), -1.0)];
    let second = [at(far, 1.0), at(far, -1.0)];
    let mut one = TsdfVolume::new(params());
    for pose in &first {
        let (r, n) = render_with_normals(&scene, &cam, pose);
        one.integrate(&r.depth, &n, None, &cam, pose).unwrap();
    }
    let budget = one.num_blocks() + one.num_blocks() / 2;
    let mut vol = TsdfVolume::new(TsdfParams {
        max_blocks: budget,
        ..params()
    });
    let mut strict = TsdfVolume::new(TsdfParams {
        max_blocks: budget,
        evict: false,
        ..params()
    });
    let mut failed = 0;
    for pose in first.iter().chain(&second) {
        let (r, n) = render_with_normals(&scene, &cam, pose);
        vol.integrate(&r.depth, &n, None, &cam, pose).unwrap();
        assert!(vol.num_blocks() <= budget);
        failed += strict.integrate(&r.depth, &n, None, &cam, pose).is_err() as usize;
    }
    assert!(failed > 0, "without eviction the budget must stop a frame");
    assert!(vol.evicted_blocks() > 0);
    // the second sphere is whole: its surface is found where the two views saw it (facing ±y)
    for k in 0..22 {
        let side = if k < 11 { 90.0 } else { -90.0 };
        let a = (side + 10.0 * (k % 11) as f64 - 50.0f64).to_radians();
        let p = far + Vector3::new(a.cos(), a.sin(), 0.0) * RADIUS;
        let d = vol.sdf(&Point3::from(p.cast::<f32>()));
        assert!(
            d.is_some_and(|d| d.abs() < 0.3),
            "second sphere at angle {k}: {d:?}"
        );
    }
    // what was dropped is the first sphere's
    let kept_near_first = vol.blocks().iter().filter(|b| b.coord[0] < 20).count();
    let first_blocks = one.num_blocks();
    assert!(
        kept_near_first < first_blocks,
        "{kept_near_first} of the first sphere's {first_blocks} blocks kept"
    );
}

/// Depth maps from a user may hold NaN, infinities and negative values: they are not surface, and
/// fusing them changes nothing that a map with those pixels at 0 would not.
#[test]
fn nan_inf_and_negative_depth_are_ignored() {
    let (cam, pose, r, n) = sphere_from_the_side();
    let (mut bad, mut zeroed) = (r.depth.clone(), r.depth.clone());
    for (i, v) in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -1.0]
        .iter()
        .cycle()
        .take(2000)
        .enumerate()
    {
        let k = (i * 37) % bad.data.len();
        bad.data[k] = *v;
        zeroed.data[k] = 0.0;
    }
    let mut a = TsdfVolume::new(params());
    let mut b = TsdfVolume::new(params());
    a.integrate(&bad, &n, Some(&r.color), &cam, &pose).unwrap();
    b.integrate(&zeroed, &n, Some(&r.color), &cam, &pose)
        .unwrap();
    assert_eq!(a.num_blocks(), b.num_blocks());
    for (x, y) in a.blocks().iter().zip(b.blocks()) {
        assert_eq!(x.coord, y.coord);
        for (u, v) in x.voxels.iter().zip(y.voxels.iter()) {
            assert!(u.tsdf.is_finite() && u.weight.is_finite());
            assert_eq!(u, v);
        }
    }
    let mut maps = RaycastMaps::new();
    a.raycast(&cam, &pose, &mut maps);
}

/// Two flat frames seen straight on, about 1.00 m away in one colour and 1.03 m in another: each voxel
/// on the optical axis holds the weighted running average of the truncated distances (eq.
/// 3.23-3.25) under the sensor-noise weights cos θ · (σ(1 m)/σ(z))², and the colour average
/// under the same weights (to one unit of rounding).
#[test]
fn fusion_averages_distance_and_colour_under_the_sensor_weights() {
    let cam = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
    let pose = Isometry3::identity();
    let normals: NormalMap = Image::filled(320, 240, [0.0, 0.0, -1.0]);
    // depths off the voxel grid, so that no voxel sits on the edge of a band
    let frames = [(1.004f32, [200u8, 100, 40]), (1.033, [40, 180, 250])];
    let mut vol = TsdfVolume::new(params());
    for (d, rgb) in frames {
        let depth = Image::filled(320, 240, d);
        let color = Image::filled(320, 240, rgb);
        vol.integrate(&depth, &normals, Some(&color), &cam, &pose)
            .unwrap();
    }
    // the voxel column x = y = 0 projects to pixel (160, 120)
    let (rx, ry) = (0.5 / 262.5f32, 0.5 / 262.5f32);
    let cos = 1.0 / (rx * rx + ry * ry + 1.0).sqrt();
    let sigma = |z: f32| 0.0012 + 0.0019 * (z - 0.4) * (z - 0.4);
    let weight = |z: f32| cos * (sigma(1.0) / sigma(z)).powi(2);
    let mu = params().truncation();
    let mut checked = 0;
    // the blocks the two bands touch: z from 0.96 to 1.11 m
    for k in 96..=111 {
        let z = vol.voxel_center([0, 0, k]).z;
        let (mut t, mut w, mut c) = (1.0f32, 0.0f32, [0.0f32; 3]);
        for (d, rgb) in frames {
            let sdf = d - z;
            if sdf < -mu {
                continue;
            }
            let wi = weight(d);
            t = (t * w + (sdf / mu).min(1.0) * wi) / (w + wi);
            for j in 0..3 {
                c[j] = (c[j] * w + rgb[j] as f32 * wi) / (w + wi);
            }
            w += wi;
        }
        let (tsdf, weight_stored) = vol.voxel([0, 0, k]).expect("allocated");
        assert!(
            (weight_stored - w).abs() < 1e-5,
            "z {z}: weight {weight_stored} vs {w}"
        );
        if w == 0.0 {
            continue;
        }
        assert!((tsdf - t).abs() < 1e-5, "z {z}: tsdf {tsdf} vs {t}");
        let block = vol.block(&[0, 0, k.div_euclid(8)]).unwrap();
        let stored = block.color[(k.rem_euclid(8) * 64) as usize];
        for j in 0..3 {
            assert!(
                (stored[j] as f32 - c[j]).abs() <= 1.0,
                "z {z}: colour {stored:?} vs {c:?}"
            );
        }
        checked += 1;
    }
    assert!(checked >= 10, "{checked} voxels in the band");
}

/// A ray far from the origin, where a hundredth of a voxel is below the precision of its
/// distance, still crosses free space and ends (each step moves it by at least a few units in
/// the last place).
#[test]
fn a_ray_far_out_ends() {
    // on its own thread, so that a march that never ends fails the test instead of hanging it
    let (done, ended) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let vol = TsdfVolume::new(params());
        for far in [2.0e4f32, 3.3e4, 1.0e5] {
            for dir in [Vector3::x(), -Vector3::x(), Vector3::new(-0.6, -0.8, 0.0)] {
                let origin = Point3::from(-dir * far);
                let hit = vol.cast_ray(&origin, &dir, far - 2.0, far + 2.0);
                done.send(hit.is_none()).unwrap();
            }
        }
    });
    for k in 0..9 {
        let missed = ended.recv_timeout(std::time::Duration::from_secs(20));
        assert_eq!(missed, Ok(true), "ray {k} of 9 through empty space");
    }
}
