//! Benchmark of the per-frame front end at 640×480: bilateral filter, 3-level pyramid, vertex and
//! normal maps, intensity and gradients (thesis sec. 3.1). Target: under 5 ms on 2 cores.
//!
//! ```text
//! cargo run --release --example preprocess_bench [-- --frames 300 --threads 2]
//! ```
//! Prints the median and mean per frame (after 20 warm-up frames), a per-stage breakdown, and one
//! JSON line last.

use crate::bench;
use crate::cli;

use anyhow::Result;
use clap::Parser;
use cli::Session;
use dynamap_slam::camera::Camera;
use dynamap_slam::image::{
    bilateral_filter, downsample_depth, gradients, intensity, normal_map, vertex_map, Image,
};
use dynamap_slam::preprocess::{PreprocessParams, Preprocessor};
use dynamap_slam::synthetic::motion::{self, Motion};
use dynamap_slam::synthetic::noise::SensorNoise;
use dynamap_slam::synthetic::render::render;
use dynamap_slam::synthetic::scene::Scene;
use std::process::ExitCode;
use std::time::Instant;

/// Front-end benchmark.
#[derive(Parser, Debug)]
#[command(long_about = None)]
struct Args {
    #[command(flatten)]
    timing: bench::Timing,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

fn time<F: FnMut()>(frames: usize, mut f: F) -> (f64, f64) {
    for _ in 0..20 {
        f();
    }
    let mut t: Vec<f64> = (0..frames)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    let mean = t.iter().sum::<f64>() / t.len() as f64;
    (bench::median(&mut t), mean)
}

pub fn main() -> ExitCode {
    cli::run(run)
}

fn run(args: Args, session: &Session) -> Result<()> {
    args.timing.setup()?;
    let cam = Camera::tum_default();
    let pose = motion::procedural(Motion::Orbit, 1, 30.0).poses[0];
    let mut r = render(&Scene::room(1), &cam, &pose);
    let raw =
        SensorNoise::default().apply(0, &r.depth, &r.cos_incidence, &mut r.color, cam.depth_scale);
    let mut pre = Preprocessor::new(cam, PreprocessParams::default());
    let (total_median, total_mean) = time(args.timing.frames, || {
        pre.process(&raw, Some(&r.color));
    });
    let (depth_median, depth_mean) = time(args.timing.frames, || {
        pre.process(&raw, None);
    });
    // Stage by stage, on the same inputs.
    let params = PreprocessParams::default();
    let depth: Image<f32> = Image::from_vec(
        640,
        480,
        raw.data.iter().map(|&d| d as f32 / 5000.0).collect(),
    )
    .expect("size");
    let mut filtered = Image::new(0, 0);
    let (bilateral, _) = time(args.timing.frames, || {
        bilateral_filter(&depth, &params.bilateral, &mut filtered)
    });
    let (mut d1, mut d2) = (Image::new(0, 0), Image::new(0, 0));
    let (pyramid, _) = time(args.timing.frames, || {
        downsample_depth(&filtered, 0.03, &mut d1);
        downsample_depth(&d1, 0.03, &mut d2);
    });
    let (mut v, mut n) = (
        Image::filled(0, 0, [0.0f32; 3]),
        Image::filled(0, 0, [0.0f32; 3]),
    );
    let (maps, _) = time(args.timing.frames, || {
        vertex_map(&filtered, &cam, &mut v);
        normal_map(&v, &cam, &mut n);
    });
    let (mut g, mut gx, mut gy) = (Image::new(0, 0), Image::new(0, 0), Image::new(0, 0));
    let (gray, _) = time(args.timing.frames, || {
        intensity(&r.color, &mut g);
        gradients(&g, &mut gx, &mut gy);
    });
    let threads = rayon::current_num_threads();
    if !session.quiet {
        println!(
            "640x480 preprocessing on {threads} threads, {} frames each:",
            args.timing.frames
        );
        println!("  depth only (filter + 3-level pyramid + vertex/normal maps): median {depth_median:.3} ms, mean {depth_mean:.3} ms");
        println!("  with colour (+ intensity pyramid and gradients):           median {total_median:.3} ms, mean {total_mean:.3} ms");
        println!("stages, median:");
        println!("  bilateral filter (5x5)          {bilateral:.3} ms");
        println!("  depth pyramid (2 halvings)      {pyramid:.3} ms");
        println!("  vertex + normal map (level 0)   {maps:.3} ms");
        println!("  intensity + gradients (level 0) {gray:.3} ms");
    }
    println!(
        "{}",
        serde_json::json!({"threads": threads, "frames": args.timing.frames, "depth_median_ms": depth_median, "depth_mean_ms": depth_mean,
            "median_ms": total_median, "mean_ms": total_mean,
            "bilateral_ms": bilateral, "pyramid_ms": pyramid, "maps_level0_ms": maps, "intensity_level0_ms": gray})
    );
    Ok(())
}
