//! Dense rigid RGB-D SLAM (voxel-hashed TSDF, frame-to-model tracking).
//!
//! ```text
//! cargo run --release --example rigid_slam                       # renders a sequence, runs, prints ATE
//! cargo run --release --example rigid_slam -- DIR --output traj.txt [--mesh out.ply] [--config slam.toml]
//! ```
//! DIR is a TUM-layout folder (intrinsics from DIR/intrinsics.txt, else --fx/--fy/--cx/--cy/--depth-scale,
//! else TUM's published ones). Prints a progress bar with the fps, and one JSON line last: frames,
//! seconds (the whole per-frame loop, image reading included), fps, failures, and the ATE when the
//! folder has a ground truth.

#[path = "common/report.rs"]
mod report;

use anyhow::{bail, Context, Result};
use clap::Parser;
use dynamap::slam::camera::Camera;
use dynamap::slam::eval::{ate, Alignment, MAX_STAMP_DIFFERENCE};
use dynamap::slam::io::folder::FolderSequence;
use dynamap::slam::io::ply;
use dynamap::slam::io::trajectory::Trajectory;
use dynamap::slam::io::tum::{RgbdFrame, TumSequence};
use dynamap::slam::io::IoError;
use dynamap::slam::rigid::{RigidSlam, SlamParams, StageTimes};
use dynamap::slam::synthetic::{motion, noise::SensorNoise, scene::Scene, sequence};
use dynamap::slam::tsdf::RaycastMaps;
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Isometry3;
use report::report_line;
use serde::Deserialize;
use std::path::PathBuf;
use std::time::Instant;

/// Dense rigid RGB-D SLAM.
#[derive(Parser, Debug)]
#[command(about)]
struct Args {
    /// A TUM-layout sequence. Without it, a 60-frame sequence is rendered and tracked.
    dir: Option<PathBuf>,
    /// Where to write the estimated trajectory (TUM format).
    #[arg(long)]
    output: Option<PathBuf>,
    /// Where to write the fused mesh (binary PLY).
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Where to write a PNG of the fused model raycast from the last pose (shaded by its normals).
    #[arg(long)]
    render: Option<PathBuf>,
    /// Parameters from a TOML file (keys as the flags below, with underscores).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Voxel size, metres.
    #[arg(long)]
    voxel_size: Option<f32>,
    /// Truncation, voxels.
    #[arg(long)]
    truncation: Option<f32>,
    /// Photometric weight λ.
    #[arg(long)]
    lambda: Option<f64>,
    /// Iterations per level, finest first, e.g. 2,3,6.
    #[arg(long, value_delimiter = ',')]
    iterations: Option<Vec<usize>>,
    /// Association distance threshold, metres.
    #[arg(long)]
    max_distance: Option<f64>,
    /// Association normal-angle threshold, degrees.
    #[arg(long)]
    max_angle: Option<f64>,
    /// Intrinsics when DIR has no intrinsics.txt.
    #[arg(long)]
    fx: Option<f64>,
    /// Intrinsics when DIR has no intrinsics.txt.
    #[arg(long)]
    fy: Option<f64>,
    /// Intrinsics when DIR has no intrinsics.txt.
    #[arg(long)]
    cx: Option<f64>,
    /// Intrinsics when DIR has no intrinsics.txt.
    #[arg(long)]
    cy: Option<f64>,
    /// Depth units per metre when DIR has no intrinsics.txt.
    #[arg(long)]
    depth_scale: Option<f64>,
    /// Frames to process at most.
    #[arg(long)]
    max_frames: Option<usize>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// A TUM-layout folder (rgb.txt, depth.txt) or a plain folder of numbered colour/depth frames.
enum Source {
    Tum(TumSequence),
    Folder(FolderSequence, Camera),
}

impl Source {
    fn open(dir: &std::path::Path) -> Result<Self> {
        if dir.join("rgb.txt").exists() {
            Ok(Source::Tum(TumSequence::open(dir)?))
        } else {
            let f = FolderSequence::open(dir, None)?;
            let c = f.camera;
            Ok(Source::Folder(f, c))
        }
    }
    fn len(&self) -> usize {
        match self {
            Source::Tum(t) => t.len(),
            Source::Folder(f, _) => f.len(),
        }
    }
    fn load(&self, i: usize) -> Result<RgbdFrame, IoError> {
        match self {
            Source::Tum(t) => t.load(i),
            Source::Folder(f, _) => f.load(i),
        }
    }
    fn camera_mut(&mut self) -> &mut Camera {
        match self {
            Source::Tum(t) => &mut t.camera,
            Source::Folder(_, c) => c,
        }
    }
    fn groundtruth(&self) -> Option<&Trajectory> {
        match self {
            Source::Tum(t) => t.groundtruth.as_ref(),
            Source::Folder(..) => None,
        }
    }
    fn first_stamp(&self) -> f64 {
        match self {
            Source::Tum(t) => t.frames[0].timestamp,
            Source::Folder(..) => 0.0,
        }
    }
}

/// The TOML form of the parameters.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct Config {
    voxel_size: Option<f32>,
    truncation: Option<f32>,
    lambda: Option<f64>,
    iterations: Option<Vec<usize>>,
    max_distance: Option<f64>,
    max_angle: Option<f64>,
}

fn params(args: &Args) -> Result<SlamParams> {
    let file: Config = match &args.config {
        Some(p) => toml::from_str(
            &std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
        )
        .with_context(|| format!("{}: invalid parameters", p.display()))?,
        None => Config::default(),
    };
    let mut p = SlamParams::default();
    if let Some(v) = args.voxel_size.or(file.voxel_size) {
        p.tsdf.voxel_size = v;
    }
    if let Some(v) = args.truncation.or(file.truncation) {
        p.tsdf.truncation_voxels = v;
    }
    if let Some(v) = args.lambda.or(file.lambda) {
        p.tracker.lambda_photometric = v;
    }
    if let Some(v) = args.iterations.clone().or(file.iterations) {
        p.tracker.iterations = v;
    }
    if let Some(v) = args.max_distance.or(file.max_distance) {
        p.tracker.max_distance = v;
    }
    if let Some(v) = args.max_angle.or(file.max_angle) {
        p.tracker.max_normal_angle_deg = v;
    }
    let positive = p.tsdf.voxel_size.is_finite() && p.tsdf.voxel_size > 0.0;
    if !positive || p.tsdf.truncation_voxels.is_nan() || p.tsdf.truncation_voxels < 1.0 {
        bail!("voxel_size must be positive and truncation at least 1 voxel");
    }
    Ok(p)
}

/// Renders the default sequence (60 frames orbiting the room, 640×480, with noise) into a folder.
fn default_sequence() -> Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("dynamap-rigid-default-{}", std::process::id()));
    let cam = Camera::tum_default();
    let traj = motion::procedural(motion::Motion::Orbit, 60, 30.0);
    eprintln!("rendering a 60-frame sequence into {}", dir.display());
    sequence::write_rigid(
        &dir,
        &Scene::room(1),
        &cam,
        &traj,
        &Isometry3::identity(),
        &SensorNoise::default(),
        |_| {},
    )?;
    Ok(dir)
}

fn main() -> Result<()> {
    let args = Args::parse();
    let params = params(&args)?;
    let (dir, generated) = match &args.dir {
        Some(d) => (d.clone(), false),
        None => (default_sequence()?, true),
    };
    let mut seq = Source::open(&dir)?;
    if !dir.join("intrinsics.txt").exists() {
        let c = seq.camera_mut();
        c.fx = args.fx.unwrap_or(c.fx);
        c.fy = args.fy.unwrap_or(c.fy);
        c.cx = args.cx.unwrap_or(c.cx);
        c.cy = args.cy.unwrap_or(c.cy);
        c.depth_scale = args.depth_scale.unwrap_or(c.depth_scale);
    }
    let n = args.max_frames.unwrap_or(seq.len()).min(seq.len());
    let camera = *seq.camera_mut();
    let start_pose = seq.groundtruth().and_then(|g| {
        // start at the ground truth pose of the first frame when there is one (for comparable ATE
        // plots; ATE aligns anyway)
        let t0 = seq.first_stamp();
        g.stamps
            .iter()
            .position(|s| (s - t0).abs() < MAX_STAMP_DIFFERENCE)
            .map(|i| g.poses[i])
    });
    let mut slam = RigidSlam::new(
        camera,
        params,
        start_pose.unwrap_or_else(Isometry3::identity),
    );
    let bar = if args.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(n as u64)
    };
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} frames {msg}").expect("valid template"),
    );
    let mut trajectory = Trajectory::default();
    let mut totals = StageTimes::default();
    let (mut failures, mut read_seconds) = (0usize, 0.0);
    let start = Instant::now();
    // A reader thread decodes the next frames while this one is processed (as a sensor driver
    // would deliver them); "read" is the time spent waiting for a frame.
    let (sender, frames) = std::sync::mpsc::sync_channel(2);
    std::thread::scope(|scope| {
        let seq = &seq;
        scope.spawn(move || {
            for i in 0..n {
                if sender.send((i, seq.load(i))).is_err() {
                    break;
                }
            }
        });
        loop {
            let t_read = Instant::now();
            let Ok((i, loaded)) = frames.recv() else {
                break;
            };
            read_seconds += t_read.elapsed().as_secs_f64();
            let frame = match loaded {
                Ok(f) => f,
                Err(e) => {
                    failures += 1;
                    report_line(&bar, format!("skipped: {e}"));
                    bar.inc(1);
                    continue;
                }
            };
            let report = slam.process(&frame.depth, frame.color.as_ref());
            totals.add(&report.times);
            if let Some(why) = &report.failure {
                failures += 1;
                report_line(
                    &bar,
                    format!("frame {i} ({:.6}): not fused: {why}", frame.timestamp),
                );
            }
            trajectory.push(frame.timestamp, report.pose);
            bar.inc(1);
            if i % 10 == 9 {
                bar.set_message(format!(
                    "{:.1} fps",
                    (i + 1) as f64 / start.elapsed().as_secs_f64()
                ));
            }
        }
    });
    let seconds = start.elapsed().as_secs_f64();
    bar.finish_and_clear();
    if let Some(out) = &args.output {
        trajectory.write_tum(out)?;
    }
    if let Some(m) = &args.mesh {
        ply::write(m, &slam.volume().extract_mesh())?;
    }
    if let Some(png) = &args.render {
        let mut maps = RaycastMaps::new();
        slam.volume().raycast(&camera, &slam.pose(), &mut maps);
        let light = nalgebra::Vector3::new(0.3f32, -0.5, -1.0).normalize();
        let rot = slam
            .pose()
            .rotation
            .to_rotation_matrix()
            .into_inner()
            .cast::<f32>();
        let data = maps
            .normals
            .data
            .iter()
            .map(|n| {
                if !n[0].is_finite() {
                    return [0, 0, 0];
                }
                // shade in the camera frame: a light from behind the viewer's left shoulder
                let nc = rot.transpose() * nalgebra::Vector3::new(n[0], n[1], n[2]);
                let v = (40.0 + 215.0 * nc.dot(&light).max(0.0)) as u8;
                [v, v, v]
            })
            .collect();
        let img =
            dynamap::slam::image::Image::from_vec(camera.width, camera.height, data).expect("size");
        dynamap::slam::io::images::write_color(png, &img)?;
    }
    let ate_rmse = seq
        .groundtruth()
        .and_then(|gt| ate(gt, &trajectory, Alignment::Se3, MAX_STAMP_DIFFERENCE).ok())
        .map(|a| a.stats.rmse);
    let k = |t: f64| 1e3 * t / n.max(1) as f64;
    eprintln!(
        "per frame: read {:.2} ms, preprocess {:.2} ms, track {:.2} ms, integrate {:.2} ms, raycast {:.2} ms; {} blocks ({:.0} MiB)",
        k(read_seconds),
        k(totals.preprocess),
        k(totals.track),
        k(totals.integrate),
        k(totals.raycast),
        slam.volume().num_blocks(),
        slam.volume().memory_bytes() as f64 / (1 << 20) as f64
    );
    if let Some(a) = ate_rmse {
        eprintln!(
            "ATE (SE(3)-aligned RMSE) against {}: {a:.4} m",
            dir.join("groundtruth.txt").display()
        );
    }
    println!(
        "{}",
        serde_json::json!({
            "frames": n, "seconds": seconds, "fps": n as f64 / seconds, "failures": failures,
            "ate_rmse": ate_rmse, "sequence": dir.display().to_string(),
            "ms_per_frame": {"read": k(read_seconds), "preprocess": k(totals.preprocess), "track": k(totals.track),
                             "integrate": k(totals.integrate), "raycast": k(totals.raycast)},
        })
    );
    if generated {
        let _ = std::fs::remove_dir_all(&dir);
    }
    Ok(())
}
