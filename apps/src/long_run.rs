//! A long rigid run for memory: renders frames on the fly (no files) along a slowly wandering orbit of
//! the room and tracks them with a small TSDF block budget, so that far blocks are evicted over and
//! over; logs the resident memory (from /proc/self/statm), the block count and the evictions.
//!
//! ```text
//! cargo run --release --example long_run -- [--frames 10000] [--width 160 --height 120]
//!                                            [--max-blocks 10000] [--csv memory.csv] [--plot memory.png]
//! ```
//! Prints one JSON line last: frames, failures, ATE, resident MiB after warm-up and at the end, the
//! largest block count, the evictions, and the MiB the estimated trajectory holds (the one thing
//! that grows with the run, 64 bytes a frame, in steps as its vectors double).

use crate::cli;
use crate::flag_checks;
use crate::preview;

use anyhow::{Context, Result};
use clap::Parser;
use cli::Session;
use dynamap_slam::camera::Camera;
use dynamap_slam::eval::{ate, Alignment, MAX_STAMP_DIFFERENCE};
use dynamap_slam::io::trajectory::Trajectory;
use dynamap_slam::rigid::keyframes::Keyframe;
use dynamap_slam::rigid::{RigidSlam, SlamParams};
use dynamap_slam::synthetic::motion::{look_at, TARGET};
use dynamap_slam::synthetic::noise::SensorNoise;
use dynamap_slam::synthetic::render::render;
use dynamap_slam::synthetic::scene::Scene;
use nalgebra::{Isometry3, Point3, Vector3};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

/// A long rendered rigid run that logs resident memory and the TSDF's blocks.
#[derive(Parser, Debug)]
#[command(about, long_about = None)]
struct Args {
    /// Frames to render and track.
    #[arg(long, default_value_t = 10_000)]
    frames: usize,
    /// Image width (the TUM intrinsics scaled).
    #[arg(long, default_value_t = 160)]
    width: usize,
    /// Image height.
    #[arg(long, default_value_t = 120)]
    height: usize,
    /// The TSDF's block budget (small, so that eviction runs all the time).
    #[arg(long, default_value_t = 10_000)]
    max_blocks: usize,
    /// Sample memory every this many frames.
    #[arg(long, default_value_t = 100)]
    every: usize,
    /// Frames before the "after warm-up" sample.
    #[arg(long, default_value_t = 1000)]
    warm_up: usize,
    /// Where to write the samples (frame, resident MiB, blocks, evicted).
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Where to draw the memory curve (PNG).
    #[arg(long)]
    plot: Option<PathBuf>,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

/// Resident memory of this process, MiB (Linux's /proc/self/statm).
fn resident_mib() -> Result<f64> {
    let statm = std::fs::read_to_string("/proc/self/statm").context("reading /proc/self/statm")?;
    let pages: f64 = statm
        .split_whitespace()
        .nth(1)
        .and_then(|p| p.parse().ok())
        .context("/proc/self/statm: no resident field")?;
    Ok(pages * 4096.0 / (1 << 20) as f64)
}

/// The camera at frame `k`: circling the table at 0.8° per frame, its radius and height wandering
/// slowly (1.3-2.1 m, 1.1-1.7 m), so the view keeps meeting parts of the room the budget dropped.
fn pose(k: usize) -> Isometry3<f64> {
    let f = k as f64;
    let a = (0.8 * f).to_radians();
    let r = 1.7 + 0.4 * (f / 290.0).sin();
    let h = 1.4 + 0.3 * (f / 170.0).sin();
    look_at(
        &Point3::new(r * a.cos(), r * a.sin(), h),
        &TARGET,
        &Vector3::z(),
    )
}

/// A memory sample: frame, resident MiB, blocks held, blocks evicted, trajectory MiB, keyframe
/// MiB.
type Sample = (usize, f64, usize, usize, f64, f64);

/// `--csv`: the samples as a table.
fn write_csv(path: &Path, samples: &[Sample]) -> Result<()> {
    let mut text = String::from("frame,resident_mib,blocks,evicted,trajectory_mib,keyframe_mib\n");
    for (f, m, b, e, t, k) in samples {
        let _ = writeln!(text, "{f},{m:.2},{b},{e},{t:.3},{k:.3}");
    }
    dynamap_slam::io::write_atomic(path, text.as_bytes())?;
    Ok(())
}

/// `--plot`: resident memory and the TSDF's voxels against the frame.
fn write_plot(path: &Path, args: &Args, samples: &[Sample]) -> Result<()> {
    let mib: Vec<(f64, f64)> = samples.iter().map(|s| (s.0 as f64, s.1)).collect();
    let blocks: Vec<(f64, f64)> = samples
        .iter()
        .map(|s| (s.0 as f64, s.2 as f64 * 512.0 * 11.0 / (1 << 20) as f64))
        .collect();
    preview::line_plot(
        path,
        &format!(
            "{} frames at {}x{}, budget {} blocks",
            args.frames, args.width, args.height, args.max_blocks
        ),
        ("frame", "MiB"),
        &[
            ("resident memory", mib),
            ("TSDF voxels (blocks x 5.5 KiB)", blocks),
        ],
    )
}

/// The estimate's ATE against [`pose`] at the same frames (recomputed rather than kept).
fn ate_against_truth(frames: usize, estimate: &Trajectory) -> Option<f64> {
    let mut truth = Trajectory::default();
    for k in 0..frames {
        truth.push(k as f64 / 30.0, pose(k));
    }
    ate(&truth, estimate, Alignment::Se3, MAX_STAMP_DIFFERENCE)
        .ok()
        .map(|a| a.stats.rmse)
}

/// What the relocaliser's keyframes hold (each bounded, [`Keyframe::bytes`]), MiB: the
/// other thing that grows, up to [`dynamap_slam::rigid::keyframes::KeyframeParams::max_keyframes`].
fn keyframe_mib(slam: &RigidSlam) -> f64 {
    let bytes: usize = slam.keyframes().frames().iter().map(Keyframe::bytes).sum();
    bytes as f64 / (1 << 20) as f64
}

/// Resident memory at the first sample at or after frame `warm_up`, its peak from there on, and
/// at the end, MiB.
fn memory_after(samples: &[Sample], warm_up: usize) -> (f64, f64, f64) {
    let peak = samples
        .iter()
        .filter(|s| s.0 >= warm_up)
        .map(|s| s.1)
        .fold(0.0, f64::max);
    let (warm, end) = (at_warm_up(samples, warm_up), samples.last());
    (warm.map_or(0.0, |s| s.1), peak, end.map_or(0.0, |s| s.1))
}

/// The first sample at or after the warm-up (the last if none is).
fn at_warm_up(samples: &[Sample], warm_up: usize) -> Option<&Sample> {
    samples.iter().find(|s| s.0 >= warm_up).or(samples.last())
}

pub fn main() -> ExitCode {
    cli::run(run)
}

/// Refuses a frame too small to track or too large to render, and counts of zero.
fn check_flags(args: &Args) -> Result<()> {
    if args.width < 32 || args.height < 24 || args.frames == 0 || args.every == 0 {
        return Err(cli::bad_input(
            "--width at least 32, --height at least 24, --frames and --every at least 1",
        ));
    }
    flag_checks::frame_size(args.width, args.height)?;
    flag_checks::frame_count("--frames", args.frames)?;
    if args.max_blocks == 0 {
        return Err(cli::bad_input("--max-blocks must be at least 1"));
    }
    Ok(())
}

fn run(args: Args, session: &Session) -> Result<()> {
    check_flags(&args)?;
    let camera = Camera::scaled_default(args.width, args.height);
    let mut params = SlamParams::default();
    params.tsdf.max_blocks = args.max_blocks;
    let scene = Scene::room(1);
    let noise = SensorNoise::default();
    let mut slam = RigidSlam::new(camera, params, pose(0));
    // the estimate is the one thing that must grow (64 bytes a frame); the ground truth is
    // recomputed from `pose` at the end rather than kept
    let mut estimate = Trajectory::default();
    let mut samples: Vec<Sample> = Vec::new();
    let trajectory_mib = |t: &Trajectory| {
        (t.stamps.capacity() * std::mem::size_of::<f64>()
            + t.poses.capacity() * std::mem::size_of::<Isometry3<f64>>()) as f64
            / (1 << 20) as f64
    };
    let (mut failures, mut max_blocks) = (0usize, 0usize);
    let bar = session.progress(args.frames as u64, "frames");
    let start = Instant::now();
    for k in 0..args.frames {
        let p = pose(k);
        let mut r = render(&scene, &camera, &p);
        let raw = noise.apply_to(k as u64, &mut r, camera.depth_scale);
        let report = slam.process(&raw, Some(&r.color));
        let stamp = k as f64 / 30.0;
        match report.failure() {
            Some(why) => {
                failures += 1;
                tracing::warn!("frame {k}: not tracked: {why}");
            }
            None => estimate.push(stamp, report.pose),
        }
        let blocks = slam.volume().num_blocks();
        max_blocks = max_blocks.max(blocks);
        if blocks > args.max_blocks {
            anyhow::bail!(
                "frame {k}: {blocks} blocks, over the budget of {}",
                args.max_blocks
            );
        }
        if (k + 1) % args.every == 0 || k + 1 == args.frames {
            samples.push((
                k + 1,
                resident_mib()?,
                blocks,
                slam.volume().evicted_blocks(),
                trajectory_mib(&estimate),
                keyframe_mib(&slam),
            ));
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let seconds = start.elapsed().as_secs_f64();
    let (warm, peak_after_warm_up, end) = memory_after(&samples, args.warm_up);
    let keyframes_at_warm_up = at_warm_up(&samples, args.warm_up).map_or(0.0, |s| s.5);
    if let Some(path) = &args.csv {
        write_csv(path, &samples)?;
    }
    if let Some(path) = &args.plot {
        write_plot(path, &args, &samples)?;
    }
    let ate_rmse = ate_against_truth(args.frames, &estimate);
    println!(
        "{}",
        serde_json::json!({
            "frames": args.frames, "seconds": seconds, "fps": args.frames as f64 / seconds,
            "failures": failures, "ate_rmse": ate_rmse, "max_blocks": max_blocks,
            "budget": args.max_blocks, "evicted": slam.volume().evicted_blocks(),
            "resident_mib_after_warm_up": warm, "resident_mib_peak_after_warm_up": peak_after_warm_up,
            "resident_mib_end": end, "trajectory_mib": trajectory_mib(&estimate),
            "keyframes": slam.keyframes().frames().len(), "loops": slam.keyframe_graph().loop_count(),
            "keyframe_mib_after_warm_up": keyframes_at_warm_up, "keyframe_mib_end": keyframe_mib(&slam),
        })
    );
    Ok(())
}
