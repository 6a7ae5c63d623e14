//! Benchmark of the map's two per-frame stages at 640×480: fusing a frame into the voxel-hashed
//! TSDF (thesis eq. 3.23-3.25) and raycasting the model (thesis sec. 2.6), on a rendered room seen
//! along an orbit with sensor noise.
//!
//! ```text
//! cargo run --release --example tsdf_bench [-- --frames 300 --threads 2]
//! ```
//! The map is first built from 30 frames; then each timed call fuses (or raycasts) the next frame
//! of a 40-view orbit, cycled, so the work is that of a steady run. Prints medians and one JSON
//! line last.

use crate::bench;
use crate::cli;

use anyhow::Result;
use clap::Parser;
use cli::Session;
use dynamap_slam::camera::Camera;
use dynamap_slam::image::Image;
use dynamap_slam::preprocess::{PreprocessParams, Preprocessor};
use dynamap_slam::synthetic::motion::{self, Motion};
use dynamap_slam::synthetic::noise::SensorNoise;
use dynamap_slam::synthetic::render::render;
use dynamap_slam::synthetic::scene::Scene;
use dynamap_slam::tsdf::{RaycastMaps, TsdfParams, TsdfVolume};
use std::process::ExitCode;
use std::time::Instant;

/// TSDF benchmark.
#[derive(Parser, Debug)]
#[command(long_about = None)]
struct Args {
    #[command(flatten)]
    timing: bench::Timing,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

pub fn main() -> ExitCode {
    cli::run(run)
}

/// A rendered, noisy frame: its filtered depth, normals and colour, and the depth of the pyramid
/// level the model is raycast at (the raycast's hint).
struct Frame {
    depth: Image<f32>,
    normals: Image<[f32; 3]>,
    color: Image<[u8; 3]>,
    hint: Image<f32>,
}

/// The pyramid level the model is raycast at: 160×120 for a 640×480 sensor.
const RAYCAST_LEVEL: usize = 2;

fn run(args: Args, session: &Session) -> Result<()> {
    args.timing.setup()?;
    let cam = Camera::tum_default();
    let scene = Scene::room(1);
    // a short orbit, frames cycled: enough distinct views that the map is a steady one
    let views = 40;
    let trajectory = motion::procedural(Motion::Orbit, views, 30.0);
    let mut pre = Preprocessor::new(cam, PreprocessParams::default());
    let frames: Vec<Frame> = trajectory
        .poses
        .iter()
        .enumerate()
        .map(|(k, pose)| {
            let mut r = render(&scene, &cam, pose);
            let raw = SensorNoise::default().apply(
                k as u64,
                &r.depth,
                &r.cos_incidence,
                &mut r.color,
                cam.depth_scale,
            );
            let levels = pre.process(&raw, Some(&r.color));
            Frame {
                depth: levels[0].depth.clone(),
                normals: levels[0].normals.clone(),
                color: r.color,
                hint: levels[RAYCAST_LEVEL].depth.clone(),
            }
        })
        .collect();
    let mut volume = TsdfVolume::new(TsdfParams::default());
    let fuse = |k: usize, volume: &mut TsdfVolume| -> Result<usize> {
        let f = &frames[k % views];
        let stats = volume.integrate(
            &f.depth,
            &f.normals,
            Some(&f.color),
            &cam,
            &trajectory.poses[k % views],
        )?;
        Ok(stats.updated_blocks)
    };
    for k in 0..30 {
        fuse(k, &mut volume)?;
    }
    let (mut integrate, mut updated) = (Vec::new(), 0);
    for k in 0..args.timing.frames {
        let t = Instant::now();
        updated += fuse(30 + k, &mut volume)?;
        integrate.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let mut maps = RaycastMaps::new();
    let mut raycast = Vec::new();
    for k in 0..args.timing.frames {
        let t = Instant::now();
        volume.raycast_with_hint(
            &cam.level(RAYCAST_LEVEL),
            &trajectory.poses[k % views],
            Some(&frames[k % views].hint),
            &mut maps,
        );
        raycast.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let updated = updated as f64 / args.timing.frames as f64;
    let (integrate, raycast) = (bench::median(&mut integrate), bench::median(&mut raycast));
    let threads = rayon::current_num_threads();
    if !session.quiet {
        println!(
            "640x480 room orbit on {threads} threads, {} frames each, map of {} blocks:",
            args.timing.frames,
            volume.blocks().len()
        );
        println!(
            "  integrate        median {integrate:.3} ms ({updated:.0} blocks updated, {:.1} ns per voxel)",
            integrate * 1e6 / (updated * 512.0)
        );
        println!("  raycast 160x120  median {raycast:.3} ms");
    }
    println!(
        "{}",
        serde_json::json!({"threads": threads, "frames": args.timing.frames, "blocks": volume.blocks().len(),
            "updated_blocks": updated, "integrate_ms": integrate, "raycast_ms": raycast})
    );
    Ok(())
}
