//! Dense non-rigid RGB-D SLAM of one deforming object (DynamicFusion-style).
//!
//! ```text
//! cargo run --release --example nonrigid_slam                  # a generated bending plate, error vs ground truth
//! cargo run --release --example nonrigid_slam -- --field wave --surface cylinder --max-frames 100
//! cargo run --release --example nonrigid_slam -- --field wave --sensor kinect  # the structured-light sensor model
//! cargo run --release --example nonrigid_slam -- DIR [--masks MASKS] [--output OUT]
//! ```
//! DIR is a TUM-layout, ICL-NUIM or plain folder of frames, told apart by its files
//! (`slam::io::sequence::Sequence`; intrinsics from DIR/intrinsics.txt, else the layout's); MASKS
//! holds one object mask per depth image, with the depth image's file name. OUT receives the
//! canonical mesh (`canonical.ply`), the live mesh of every frame (`live/NNNNNN.ply`) and the warp
//! field (`warp.txt`: one node per line, position, radius and unit dual quaternion
//! `w x y z` real then dual). One JSON line last: frames, seconds, fps, failures (frames not
//! fused), skipped (frames that could not be read), nodes, per-stage
//! seconds per frame, the block-Jacobi linear steps (`linear_steps`: how many, their mean
//! conjugate-gradient iterations, and how many stopped at their cap short of the tolerance)
//! and, for the generated sequence, the tracking error: over every canonical
//! sample, over the samples the camera sees, and the worst seen error of a frame reported tracked
//! (NOTES 132). A run that fused no frame at all exits with code 1 after its outputs and JSON line
//! (2 when no frame could be read).

use crate::cli;
use crate::flag_checks;
use crate::preview;
use crate::rerun_log;
use crate::unread_frames;
use crate::warp_flags;

use crate::deform_flags::{DeformMotion, SurfaceArg};
use anyhow::{Context, Result};
use clap::Parser;
use cli::{InputError, Session};
use dynamap_slam::camera::Camera;
use dynamap_slam::distortion::Distortion;
use dynamap_slam::eval::Stats;
use dynamap_slam::image::Image;
use dynamap_slam::io::images::read_mask;
use dynamap_slam::io::sequence::{OpenOptions, Sequence};
use dynamap_slam::io::trajectory::Trajectory;
use dynamap_slam::io::{ply, write_atomic};
use dynamap_slam::mesh::Mesh;
use dynamap_slam::nonrigid::{
    FusionParams, FusionTimes, LinearEffort, NonRigidFusion, RegisterTimes,
};
use dynamap_slam::synthetic::deform::{distances, surface, DeformingScene};
use dynamap_slam::synthetic::kinect::KinectModel;
use dynamap_slam::synthetic::noise::SensorNoise;
use dynamap_slam::synthetic::sequence::static_camera;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;
use warp_flags::WarpFlags;

/// Dense non-rigid RGB-D SLAM.
#[derive(Parser, Debug)]
#[command(long_about = None)]
struct Args {
    /// A TUM-layout, ICL-NUIM or plain folder of frames. Without it, a bending plate is rendered
    /// and tracked.
    dir: Option<PathBuf>,
    /// A folder of object masks named like the depth images.
    #[arg(long)]
    masks: Option<PathBuf>,
    /// A folder for the canonical mesh, the live meshes and the warp field.
    #[arg(long)]
    output: Option<PathBuf>,
    /// Frames to process at most [default: all; 30 for the generated sequence].
    #[arg(long)]
    max_frames: Option<usize>,
    /// Without DIR: the field that deforms the generated surface.
    #[arg(long, value_enum, default_value_t = DeformMotion::Bend)]
    field: DeformMotion,
    /// Without DIR: the generated surface.
    #[arg(long, value_enum, default_value_t = SurfaceArg::Plane)]
    surface: SurfaceArg,
    /// Without DIR: the seed of the surface's texture and of the sensor noise [default: 3 for
    /// the texture, 0 for the noise].
    #[arg(long)]
    seed: Option<u64>,
    /// Without DIR: the sensor. `simple`: depth noise growing with depth and incidence, colour
    /// as rendered. `kinect`: the structured-light model of `generate --sensor kinect`
    /// (quantised disparity, correlated noise, holes, flying pixels, colour noise, blur,
    /// vignetting and auto-exposure), its lens distortion left out as the pipeline takes
    /// undistorted images; the colour is exposed on the same surface as the depth.
    #[arg(long, value_enum, default_value_t = SensorKind::Simple)]
    sensor: SensorKind,
    /// A folder for pictures: the canonical model shaded from three viewpoints and, for the
    /// generated sequence, the tracking error per frame.
    #[arg(long, value_name = "DIR")]
    preview: Option<PathBuf>,
    #[command(flatten)]
    rerun: rerun_log::RerunFlags,
    /// With --rerun: log the live (warped) mesh every this many frames.
    #[arg(long, default_value_t = 1)]
    rerun_mesh_every: usize,
    /// Voxel size, metres.
    #[arg(long, default_value_t = FusionParams::default().tsdf.voxel_size)]
    voxel_size: f32,
    /// Canonical data points are thinned to one per cube of this edge, metres.
    #[arg(long, default_value_t = FusionParams::default().data_spacing)]
    data_spacing: f64,
    #[command(flatten)]
    warp: WarpFlags,
    /// The pyramid level of the data term's depth (0: full resolution).
    #[arg(long, default_value_t = FusionParams::default().data_level)]
    data_level: usize,
    /// Weight of the photometric term beside the depth terms (0: none; used when the frames
    /// have colour).
    #[arg(long, default_value_t = FusionParams::default().register.photometric_weight)]
    photometric_weight: f64,
    /// Tukey's c of the photometric term, in units of intensity over its local mean.
    #[arg(long, default_value_t = FusionParams::default().register.photometric_tukey)]
    photometric_tukey: f64,
    /// The photometric term compares intensities over their mean in windows of ± this many
    /// pixels of the data level.
    #[arg(long, default_value_t = FusionParams::default().photometric_window)]
    photometric_window: usize,
    /// The photometric references are taken from a tracked frame every this many frames.
    #[arg(long, default_value_t = FusionParams::default().photometric_keyframe_every)]
    photometric_keyframe_every: usize,
    /// Weight of the chromaticity term, (R − B)/(R + G + B) against the canonical model's (0:
    /// none; used when the frames have colour).
    #[arg(long, default_value_t = FusionParams::default().register.chroma_weight)]
    chroma_weight: f64,
    /// Tukey's c of the chromaticity term.
    #[arg(long, default_value_t = FusionParams::default().register.chroma_tukey)]
    chroma_tukey: f64,
    /// A frame whose median chromaticity residual exceeds this many times its floor (the first
    /// tracked frames', or one 8-bit level of the chromaticity where larger) has slid along the
    /// surface and is not fused (0: never judged).
    #[arg(long, default_value_t = FusionParams::default().colour_drift_ratio)]
    colour_drift_ratio: f64,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

fn params(args: &Args) -> Result<FusionParams> {
    let mut p = FusionParams::default();
    args.warp.apply(&mut p.graph, &mut p.register).bad_input()?;
    p.tsdf.voxel_size = args.voxel_size;
    p.data_spacing = args.data_spacing;
    p.data_level = args.data_level;
    p.register.photometric_weight = args.photometric_weight;
    p.register.photometric_tukey = args.photometric_tukey;
    p.photometric_window = args.photometric_window;
    p.photometric_keyframe_every = args.photometric_keyframe_every;
    p.register.chroma_weight = args.chroma_weight;
    p.register.chroma_tukey = args.chroma_tukey;
    p.colour_drift_ratio = args.colour_drift_ratio;
    flag_checks::non_negative("--colour-drift-ratio", p.colour_drift_ratio)?;
    let r = &p.register;
    flag_checks::non_negative("--photometric-weight", r.photometric_weight)?;
    flag_checks::positive("--photometric-tukey", r.photometric_tukey)?;
    flag_checks::non_negative("--chroma-weight", r.chroma_weight)?;
    flag_checks::positive("--chroma-tukey", r.chroma_tukey)?;
    if p.photometric_window == 0 || p.photometric_keyframe_every == 0 {
        return Err(cli::bad_input(
            "--photometric-window and --photometric-keyframe-every must be at least 1",
        ));
    }
    flag_checks::voxel("--voxel-size", p.tsdf.voxel_size)?;
    flag_checks::positive("--data-spacing", p.data_spacing)?;
    let coarsest = p.preprocess.levels.saturating_sub(1);
    if p.data_level > coarsest {
        return Err(cli::bad_input(format!(
            "--data-level must be at most {coarsest} (the front end's pyramid has {} levels), not {}",
            p.preprocess.levels, p.data_level
        )));
    }
    Ok(p)
}

/// The generated sequence's sensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum SensorKind {
    Simple,
    Kinect,
}

/// One frame as the pipeline takes it.
struct Frame {
    depth: Image<u16>,
    color: Option<dynamap_slam::image::ColorImage>,
    mask: Option<Image<bool>>,
}

/// Where frames come from: the generator (with its ground truth) or a folder.
enum Source {
    Generated {
        scene: DeformingScene,
        camera: Camera,
        noise: SensorNoise,
        /// The structured-light sensor instead of `noise`, with the static camera's stamps.
        kinect: Option<Box<(KinectModel, Trajectory)>>,
        frames: usize,
    },
    Folder {
        seq: Sequence,
        masks: Option<PathBuf>,
    },
}

impl Source {
    fn camera(&self) -> Camera {
        match self {
            Source::Generated { camera, .. } => *camera,
            Source::Folder { seq, .. } => *seq.camera(),
        }
    }

    fn len(&self) -> usize {
        match self {
            Source::Generated { frames, .. } => *frames,
            Source::Folder { seq, .. } => seq.len(),
        }
    }

    fn load(&self, i: usize) -> Result<Frame> {
        match self {
            Source::Generated {
                scene,
                camera,
                noise,
                kinect,
                ..
            } => {
                let (depth, color) = match kinect {
                    None => scene.sensor_frame(camera, &Isometry3::identity(), i, noise),
                    Some(k) => {
                        let (model, stamps) = &**k;
                        let f = model
                            .recorder(camera)
                            .capture(&scene.scene_at(i), stamps, i);
                        (f.depth, f.color)
                    }
                };
                Ok(Frame {
                    depth,
                    color: Some(color),
                    mask: None,
                })
            }
            Source::Folder { seq, masks } => {
                let f = seq.load(i)?;
                let mask = match masks {
                    None => None,
                    Some(dir) => {
                        let depth = seq.depth_path(i).with_context(|| format!("no frame {i}"))?;
                        let name = depth.file_name().with_context(|| {
                            format!("frame {i}: depth image without a file name")
                        })?;
                        Some(read_mask(dir.join(name))?)
                    }
                };
                Ok(Frame {
                    depth: f.depth,
                    color: f.color,
                    mask,
                })
            }
        }
    }
}

/// The warp field as text: `x y z radius w x y z w' x' y' z'` per node.
fn warp_text(slam: &NonRigidFusion) -> String {
    let mut out = String::from("# position(3) radius real(w x y z) dual(w x y z)\n");
    if let Some(g) = slam.graph() {
        for n in &g.nodes {
            let (r, d) = (n.motion.real, n.motion.dual);
            let _ = writeln!(
                out,
                "{} {} {} {} {} {} {} {} {} {} {} {}",
                n.position.x,
                n.position.y,
                n.position.z,
                n.radius,
                r.w,
                r.i,
                r.j,
                r.k,
                d.w,
                d.i,
                d.j,
                d.k
            );
        }
    }
    out
}

/// A frame's tracking error on a generated sequence.
#[derive(Clone, Copy, Debug)]
struct FrameError {
    frame: usize,
    /// Mean distance between the warped canonical samples and where their material points truly
    /// are.
    all: f64,
    /// The same over the samples whose material points the camera sees in the frame (NaN if it
    /// sees none): what the frame's data can hold. The rest are carried by the field's
    /// regulariser alone, out of view or behind the surface.
    seen: f64,
    /// Whether the frame was fused (reported tracked).
    fused: bool,
}

/// Frame `frame`'s tracking error; the camera sees points within three voxels of the surface
/// its ray meets (the canonical samples lie within the fusion's error of the true surface).
fn tracking_error(
    slam: &NonRigidFusion,
    scene: &DeformingScene,
    camera: &Camera,
    frame: usize,
) -> (f64, f64) {
    let points = slam.data_points();
    let truth = scene.follow_all(points, frame);
    let errors = distances(&truth, &slam.warp_points(points));
    let tolerance = 3.0 * f64::from(slam.params.tsdf.voxel_size);
    let seen = scene.visible(camera, &Isometry3::identity(), frame, &truth, tolerance);
    let seen: Vec<f64> = errors
        .iter()
        .zip(&seen)
        .filter(|s| *s.1)
        .map(|s| *s.0)
        .collect();
    let mean_seen = if seen.is_empty() {
        f64::NAN
    } else {
        Stats::of(&seen).mean
    };
    (Stats::of(&errors).mean, mean_seen)
}

/// Logs one frame: the camera and its images, the deformation graph warped into the live frame
/// (nodes and edges), the live mesh when given, and the stage times.
fn record(
    rec: &rerun_log::Recorder,
    i: usize,
    frame: &Frame,
    slam: &NonRigidFusion,
    camera: &Camera,
    times: &FusionTimes,
    live_mesh: Option<&Mesh>,
) -> Result<()> {
    rec.at("frame", i);
    rec.camera("world/camera", camera, &Isometry3::identity())?;
    if let Some(c) = &frame.color {
        rec.color("world/camera/rgb", c)?;
    }
    rec.depth("world/camera/depth", &frame.depth, camera.depth_scale)?;
    if let Some(g) = slam.graph() {
        let canonical: Vec<Vector3<f64>> = g.nodes.iter().map(|n| n.position).collect();
        let live: Vec<nalgebra::Point3<f64>> = slam
            .warp_points(&canonical)
            .into_iter()
            .map(Into::into)
            .collect();
        let edges: Vec<(usize, usize)> = g
            .edges
            .iter()
            .enumerate()
            .flat_map(|(a, list)| list.iter().map(move |&b| (a, b as usize)))
            .filter(|&(a, b)| a < b)
            .collect();
        rec.graph("world/graph", &live, &edges)?;
        rec.scalar("tracking/nodes", g.nodes.len() as f64)?;
    }
    if let Some(mesh) = live_mesh {
        rec.mesh("world/live_mesh", mesh)?;
    }
    rec.scalar("tracking/ms/optimise", 1e3 * times.optimise)?;
    rec.scalar("tracking/ms/fuse", 1e3 * times.fuse)
}

pub fn main() -> ExitCode {
    let defaults = FusionParams::default();
    cli::run_with(
        |cmd| WarpFlags::show_defaults(cmd, &defaults.graph, &defaults.register),
        run,
    )
}

/// The canonical volume seen from the camera and from two sides, turned ±35° about the vertical
/// axis through the object's data points.
fn canonical_views(slam: &NonRigidFusion) -> Vec<Isometry3<f64>> {
    let points = slam.data_points();
    let centre = points.iter().sum::<Vector3<f64>>() / points.len().max(1) as f64;
    [0.0f64, 35.0, -35.0]
        .iter()
        .map(|deg| {
            // a camera at the origin, turned about the centre: x -> R (x - c) + c
            let r = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), deg.to_radians());
            Isometry3::from_parts(Translation3::from(centre - r * centre), r)
        })
        .collect()
}

fn run(args: Args, session: &Session) -> Result<()> {
    let params = params(&args)?;
    let folders = [
        ("--output", args.output.as_deref()),
        ("--preview", args.preview.as_deref()),
    ];
    cli::check_outputs(&[], &folders)?;
    let source = open_source(&args)?;
    let n = args.max_frames.unwrap_or(source.len()).min(source.len());
    if let Some(out) = &args.output {
        std::fs::create_dir_all(out.join("live"))
            .with_context(|| format!("cannot create {}", out.join("live").display()))?;
    }
    let camera = source.camera();
    let mut slam = NonRigidFusion::new(camera, params);
    let rec = rerun_log::Recorder::open(&args.rerun, "dynamap nonrigid_slam")?;
    // a failed recording is reported after the outputs are written, so the run is not lost
    let mut logged: Result<()> = Ok(());
    let bar = session.progress(n as u64, "frames");
    let mut tally = Tally::default();
    let start = Instant::now();
    for i in 0..n {
        let frame = match source.load(i) {
            Ok(f) => f,
            Err(e) => {
                tally.skipped += 1;
                tracing::warn!("frame {i} skipped: {e:#}");
                tally
                    .first_unreadable
                    .get_or_insert_with(|| format!("{e:#}"));
                continue;
            }
        };
        let times = process_frame(&source, &mut slam, &mut tally, i, &frame);
        // the live mesh, built once when the output or the recording needs it this frame
        let log_mesh = rec.enabled() && args.rerun_mesh_every > 0 && i % args.rerun_mesh_every == 0;
        let live =
            (args.output.is_some() || log_mesh).then(|| slam.warp_mesh(&slam.canonical_mesh()));
        if rec.enabled() && logged.is_ok() {
            let mesh = live.as_ref().filter(|_| log_mesh);
            logged = record(&rec, i, &frame, &slam, &camera, &times, mesh);
        }
        if let (Some(out), Some(live)) = (&args.output, &live) {
            ply::write(out.join("live").join(format!("{i:06}.ply")), live)?;
        }
        bar.inc(1);
    }
    let seconds = start.elapsed().as_secs_f64();
    bar.finish_and_clear();
    if let Some(out) = &args.output {
        ply::write(out.join("canonical.ply"), &slam.canonical_mesh())?;
        write_atomic(out.join("warp.txt"), warp_text(&slam).as_bytes())?;
    }
    let logged = logged.and_then(|()| rec.flush());
    if let Some(dir) = &args.preview {
        write_preview(dir, &slam, &camera, &tally.errors)?;
    }
    println!("{}", result_line(n, seconds, &tally, &slam));
    let counts = cli::FrameCounts {
        taken: n,
        unreadable: tally.skipped,
        first_unreadable: tally.first_unreadable,
        kept: tally.processed - tally.failures,
    };
    let name =
        (args.dir.as_ref()).map_or("the generated sequence".into(), |d| d.display().to_string());
    counts.check(name, "fused")?;
    logged
}

/// The generated bending plate, or the folder of `DIR` with its masks.
fn open_source(args: &Args) -> Result<Source> {
    // the generated sequence's length
    let frames = args.max_frames.unwrap_or(30);
    if args.dir.is_none() {
        flag_checks::frame_count("--max-frames", frames)?;
    }
    Ok(match &args.dir {
        None => Source::Generated {
            scene: DeformingScene::new(
                surface(args.surface.into(), 60),
                args.field.into(),
                args.seed.unwrap_or(3),
            ),
            camera: Camera::tum_default(),
            noise: SensorNoise {
                seed: args.seed.unwrap_or(0),
                ..SensorNoise::default()
            },
            kinect: (args.sensor == SensorKind::Kinect).then(|| {
                let model = KinectModel {
                    seed: args.seed.unwrap_or(0),
                    distortion: Distortion::default(),
                    ..KinectModel::default()
                };
                Box::new((model, static_camera(frames, 30.0)))
            }),
            frames,
        },
        Some(d) => {
            let options = OpenOptions::default();
            let seq = Sequence::open(d, &options).bad_input()?;
            unread_frames::warn(d, &seq, options.max_difference);
            cli::check_tum_intrinsics(d, &seq, None)?;
            Source::Folder {
                seq,
                masks: args.masks.clone(),
            }
        }
    })
}

/// What the frame loop counts and keeps.
#[derive(Default)]
struct Tally {
    /// Stage times summed over the frames, and the optimiser's over the frames it ran on.
    totals: FusionTimes,
    stages: RegisterTimes,
    /// The optimiser's block-Jacobi steps over the frames it ran on.
    linear: LinearEffort,
    /// Frames the optimiser ran on.
    optimised: usize,
    /// Frames not fused, frames that could not be read, frames processed.
    failures: usize,
    skipped: usize,
    processed: usize,
    /// Why the first frame that could not be read could not be.
    first_unreadable: Option<String>,
    /// Time in `process`, seconds.
    processing: f64,
    /// Each frame's tracking error on a generated sequence.
    errors: Vec<FrameError>,
}

/// Processes frame `i`, counts it, logs its figures; gives its stage times.
fn process_frame(
    source: &Source,
    slam: &mut NonRigidFusion,
    tally: &mut Tally,
    i: usize,
    frame: &Frame,
) -> FusionTimes {
    let t = Instant::now();
    let report = slam.process(&frame.depth, frame.color.as_ref(), frame.mask.as_ref());
    tally.processing += t.elapsed().as_secs_f64();
    tally.processed += 1;
    tally.totals.add(&report.times);
    if let Some(s) = &report.summary {
        tally.stages.add(&s.times);
        tally.linear.add(&s.linear);
        tally.optimised += 1;
    }
    if let Some(why) = &report.failure {
        tally.failures += 1;
        tracing::warn!("frame {i}: not fused: {why}");
    }
    let error = match source {
        Source::Generated { scene, camera, .. } if slam.graph().is_some() => {
            Some(tracking_error(slam, scene, camera, i))
        }
        _ => None,
    };
    tally.errors.extend(error.map(|(all, seen)| FrameError {
        frame: i,
        all,
        seen,
        fused: report.failure.is_none(),
    }));
    let s = report.summary.as_ref();
    tracing::debug!(
        "frame {i}: nodes {} (+{}), matched {}, data cost per match {:.3e}, iterations {}, photometric residual {:.4} of texture {:.4}, chromaticity residual {:.4} of {:.4} (step {:.4}), error {:.2} mm ({:.2} mm seen), optimise {:.1} ms, fuse {:.1} ms, surface {:.1} ms",
        report.nodes,
        report.added_nodes,
        s.map_or(0, |s| s.matched),
        s.map_or(f64::NAN, |s| s.data_cost / s.matched.max(1) as f64),
        s.map_or(0, |s| s.iterations),
        s.and_then(|s| s.photometric).map_or(f64::NAN, |p| p.residual),
        s.and_then(|s| s.photometric).map_or(f64::NAN, |p| p.texture),
        s.and_then(|s| s.chroma).map_or(f64::NAN, |p| p.residual),
        s.and_then(|s| s.chroma).map_or(f64::NAN, |p| p.texture),
        slam.colour_step(),
        error.map_or(f64::NAN, |e| e.0) * 1e3,
        error.map_or(f64::NAN, |e| e.1) * 1e3,
        report.times.optimise * 1e3,
        report.times.fuse * 1e3,
        report.times.surface * 1e3
    );
    report.times
}

/// `--preview`: views of the canonical model and, on a generated sequence, the error per frame.
fn write_preview(
    dir: &Path,
    slam: &NonRigidFusion,
    camera: &Camera,
    errors: &[FrameError],
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let views = canonical_views(slam);
    preview::model_views(dir, slam.volume(), camera, 1.0, &views)?;
    if !errors.is_empty() {
        let mm = |f: fn(&FrameError) -> f64| {
            let points = errors.iter().map(|e| (e.frame as f64, 1e3 * f(e)));
            points.filter(|p| p.1.is_finite()).collect()
        };
        preview::line_plot(
            &dir.join("error.png"),
            "mean distance of the warped samples from their true positions",
            ("frame", "error (mm)"),
            &[
                ("every sample", mm(|e| e.all)),
                ("samples the camera sees", mm(|e| e.seen)),
            ],
        )?;
    }
    Ok(())
}

/// The JSON line's error fields: over every sample (`error_mean`, `error_max_frame`: the mean of
/// the frames' means and the worst frame's), over the samples seen (`error_seen_mean`,
/// `error_seen_max_frame`), and the worst seen error of a frame reported tracked
/// (`error_seen_max_fused`: one over a centimetre is a wrong frame reported as right); null where
/// no frame counts (no sample seen, no frame fused).
fn error_fields(errors: &[FrameError]) -> String {
    // a statistic over no frame is null, not a zero that would read as no error
    let stats = |f: &dyn Fn(&FrameError) -> Option<f64>| {
        let v: Vec<f64> = errors
            .iter()
            .filter_map(f)
            .filter(|e| e.is_finite())
            .collect();
        let s = Stats::of(&v);
        let json = |x: f64| format!("{x:.6}");
        match v.is_empty() {
            true => ["null".to_string(), "null".to_string()],
            false => [json(s.mean), json(s.max)],
        }
    };
    let [mean, max] = stats(&|e| Some(e.all));
    let [seen_mean, seen_max] = stats(&|e| Some(e.seen));
    let [_, fused_max] = stats(&|e| e.fused.then_some(e.seen));
    format!(
        ", \"error_mean\": {mean}, \"error_max_frame\": {max}, \"error_seen_mean\": {seen_mean}, \"error_seen_max_frame\": {seen_max}, \"error_seen_max_fused\": {fused_max}"
    )
}

/// The block-Jacobi steps as JSON: their count, mean conjugate-gradient iterations (null
/// without a step) and how many were truncated at their cap.
fn linear_json(e: &LinearEffort) -> String {
    let mean = match e.steps {
        0 => "null".to_string(),
        n => format!("{:.2}", e.iterations as f64 / n as f64),
    };
    format!(
        "{{\"steps\": {}, \"iterations_per_step\": {mean}, \"truncated\": {}}}",
        e.steps, e.truncated
    )
}

/// The JSON line printed last.
fn result_line(n: usize, seconds: f64, tally: &Tally, slam: &NonRigidFusion) -> String {
    let per_frame = |s: f64| s / tally.processed.max(1) as f64;
    let error = (!tally.errors.is_empty()).then(|| error_fields(&tally.errors));
    let ms = |s: f64| 1e3 * s / tally.optimised.max(1) as f64;
    let st = &tally.stages;
    let stages = format!(
        "{{\"prealign\": {:.2}, \"associate\": {:.2}, \"update\": {:.2}, \"evaluate\": {:.2}, \"linear\": {:.2}}}",
        ms(st.prealign),
        ms(st.associate),
        ms(st.update),
        ms(st.evaluate),
        ms(st.linear)
    );
    let totals = &tally.totals;
    let linear = linear_json(&tally.linear);
    format!(
        "{{\"frames\": {n}, \"seconds\": {seconds:.3}, \"fps\": {:.2}, \"failures\": {}, \"skipped\": {}, \"nodes\": {}, \"preprocess\": {:.4}, \"optimise\": {:.4}, \"fuse\": {:.4}, \"surface\": {:.4}, \"optimise_ms\": {stages}, \"linear_steps\": {linear}{}}}",
        if tally.processing > 0.0 {
            tally.processed as f64 / tally.processing
        } else {
            0.0
        },
        tally.failures,
        tally.skipped,
        slam.graph().map_or(0, |g| g.nodes.len()),
        per_frame(totals.preprocess),
        per_frame(totals.optimise),
        per_frame(totals.fuse),
        per_frame(totals.surface),
        error.unwrap_or_default()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The linear steps' JSON: their mean iterations, null without a step (never a zero that
    /// would read as steps that cost nothing), and the truncated ones counted.
    #[test]
    fn linear_steps_are_counted_and_a_run_without_any_gives_no_mean() {
        let parse = |e: &LinearEffort| serde_json::from_str::<serde_json::Value>(&linear_json(e));
        let none = parse(&LinearEffort::default()).unwrap();
        assert_eq!(none["steps"], 0);
        assert!(none["iterations_per_step"].is_null());
        let some = LinearEffort {
            steps: 4,
            iterations: 50,
            truncated: 1,
        };
        let some = parse(&some).unwrap();
        assert_eq!(some["iterations_per_step"].as_f64(), Some(12.5));
        assert_eq!(some["truncated"], 1);
    }

    /// Frames the camera saw nothing of, or none fused: those statistics are null, never a zero
    /// that would read as no error; the others are over the frames that count.
    #[test]
    fn error_fields_are_null_where_no_frame_counts() {
        let frame = |frame, all, seen, fused| FrameError {
            frame,
            all,
            seen,
            fused,
        };
        let unseen = [
            frame(0, 0.002, f64::NAN, false),
            frame(1, 0.004, f64::NAN, false),
        ];
        let line = format!("{{\"x\": 0{}}}", error_fields(&unseen));
        let v: serde_json::Value = serde_json::from_str(&line).expect(&line);
        assert_eq!(v["error_mean"].as_f64(), Some(0.003), "{line}");
        assert_eq!(v["error_max_frame"].as_f64(), Some(0.004), "{line}");
        for key in [
            "error_seen_mean",
            "error_seen_max_frame",
            "error_seen_max_fused",
        ] {
            assert!(v[key].is_null(), "{key}: {line}");
        }
        let seen = [frame(0, 0.002, 0.001, true), frame(1, 0.03, 0.02, false)];
        let v: serde_json::Value =
            serde_json::from_str(&format!("{{\"x\": 0{}}}", error_fields(&seen))).unwrap();
        assert_eq!(v["error_seen_max_frame"].as_f64(), Some(0.02));
        assert_eq!(v["error_seen_max_fused"].as_f64(), Some(0.001));
    }
}
