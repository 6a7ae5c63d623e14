//! Dense rigid RGB-D SLAM (voxel-hashed TSDF, frame-to-model tracking).
//!
//! ```text
//! cargo run --release --example rigid_slam                       # renders a sequence, runs, prints ATE
//! cargo run --release --example rigid_slam -- DIR --output traj.txt [--mesh out.ply] [--config slam.toml]
//! ```
//! DIR is a TUM-layout folder (intrinsics from DIR/intrinsics.txt, else --fx/--fy/--cx/--cy/
//! --depth-scale, else TUM's published ones), an ICL-NUIM folder or a plain folder of frames
//! (`slam::io::sequence::Sequence` tells them apart). Prints a progress bar with the fps, and one
//! JSON line last: frames, seconds (the whole per-frame loop, image reading included), fps,
//! failures (frames read but not tracked), skipped (frames whose files could not be read),
//! relocalised, new_maps and unplaced_frames (maps started after the track was lost for good, and
//! the tracked frames left out because no loop placed their map), held_apart (joins of maps that
//! later loops contradicted, undone), unpaired_depth (TUM-layout depth frames without a colour
//! frame in `associations.txt`, or within `--max-difference` where the folder has none; not
//! read, and a warning names them too), repeated_stamps (TUM-layout frames at the depth stamp of
//! an earlier one: not read, warned of), the loop_events (each loop's keyframes by frame number
//! counted from 1 and by depth stamp, its inliers and DCS weight, null for a loop between maps
//! held apart, which is not solved) and the ATE when the folder has a ground truth. The
//! trajectory holds the tracked frames only.
//!
//! A frame that cannot be read or tracked is logged with its reason and left out; the run goes on.
//! A run that tracked no frame at all exits with code 1 after its outputs and JSON line (2 when
//! no frame could be read).
//! Ctrl-C stops after the current frame, writes the outputs so far and exits with code 130.

use crate::cli;
use crate::flag_checks;
use crate::preview;
use crate::rerun_log;
use crate::unread_frames;

use anyhow::{bail, Context, Result};
use clap::Parser;
use cli::{InputError, Session};
use dynamap_residuals::pose_graph::Pose;
use dynamap_slam::camera::Camera;
use dynamap_slam::distortion::TumSensor;
use dynamap_slam::eval::{ate, Alignment, AteResult, MAX_STAMP_DIFFERENCE};
use dynamap_slam::io::ply;
use dynamap_slam::io::sequence::{OpenOptions, Sequence};
use dynamap_slam::io::trajectory::Trajectory;
use dynamap_slam::io::tum::{Pairing, RgbdFrame};
use dynamap_slam::rigid::loops::{KeyframeGraph, Optimised};
use dynamap_slam::rigid::submaps::SubmapParams;
use dynamap_slam::rigid::{
    FrameOutcome, FrameReport, FrameStamps, PhotometricWeight, RigidSlam, SlamParams, StageTimes,
};
use dynamap_slam::synthetic::{motion, scene::Scene, sequence};
use dynamap_slam::tsdf::RaycastMaps;
use indicatif::ProgressBar;
use nalgebra::Isometry3;
use rerun_log::Recorder;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

/// Dense rigid RGB-D SLAM: frame-to-model tracking into a voxel-hashed TSDF.
#[derive(Parser, Debug)]
#[command(about, long_about = None)]
struct Args {
    /// A TUM-layout sequence (rgb.txt, depth.txt), an ICL-NUIM folder (pose.txt, color/, depth/)
    /// or a folder of numbered colour/depth frames.
    /// Without it, a 60-frame sequence is rendered and tracked.
    dir: Option<PathBuf>,
    /// Where to write the estimated trajectory (TUM format). With --submaps (or once a lost
    /// track split one volume into new maps), each frame's tracked pose is carried with its
    /// keyframe to the keyframe graph's solution when loops were found, and frames of new maps
    /// that no loop placed are left out (the JSON line's `ate_rmse` is this trajectory's,
    /// `ate_tracked` the poses' as tracked).
    #[arg(long)]
    output: Option<PathBuf>,
    /// Where to write the fused mesh (binary PLY).
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Where to write the keyframes' pose graph (g2o text: odometry and the loops found, the
    /// vertices at the graph's optimum, loops under DCS), solved after the run. A vertex's id is
    /// its keyframe's frame number counted from 1.
    #[arg(long)]
    graph: Option<PathBuf>,
    /// Where to write a PNG of the fused model raycast from the last pose (shaded by its normals).
    #[arg(long)]
    render: Option<PathBuf>,
    /// A folder for pictures of the run: the model shaded from three of the estimated poses, the
    /// trajectory from above over the ground truth, the per-frame error.
    #[arg(long, value_name = "DIR")]
    preview: Option<PathBuf>,
    #[command(flatten)]
    rerun: rerun_log::RerunFlags,
    /// With --rerun: log the fused mesh every this many frames (and after the last).
    #[arg(long, default_value_t = 50)]
    rerun_mesh_every: usize,
    /// Voxel size, metres.
    #[arg(long, default_value_t = SlamParams::default().tsdf.voxel_size)]
    voxel_size: f32,
    /// Truncation band, voxels.
    #[arg(long, default_value_t = SlamParams::default().tsdf.truncation_voxels)]
    truncation: f32,
    /// Cap on a voxel's fused weight.
    #[arg(long, default_value_t = SlamParams::default().tsdf.max_weight)]
    max_weight: f32,
    /// Block budget of the TSDF (blocks of 8³ voxels).
    #[arg(long, default_value_t = SlamParams::default().tsdf.max_blocks)]
    max_blocks: usize,
    /// A fixed photometric weight λ of E_geo + λ E_pho (0 leaves colour out of tracking);
    /// without it, λ is balanced by the residuals' scales (`--photometric-balance`).
    #[arg(long, conflicts_with = "photometric_balance")]
    lambda: Option<f64>,
    /// κ of the balanced photometric weight λ = κ (σ_geo / σ_pho)², measured per pyramid level
    /// (default 0.5; 1 weighs each term by the inverse of its noise variance).
    #[arg(long)]
    photometric_balance: Option<f64>,
    /// Gauss-Newton iterations per pyramid level, finest first.
    #[arg(long, value_delimiter = ',', default_values_t = SlamParams::default().tracker.iterations)]
    iterations: Vec<usize>,
    /// Pixel stride of the tracking grid per pyramid level, finest first.
    #[arg(long, value_delimiter = ',', default_values_t = SlamParams::default().tracker.strides)]
    strides: Vec<usize>,
    /// Association distance threshold, metres.
    #[arg(long, default_value_t = SlamParams::default().tracker.max_distance)]
    max_distance: f64,
    /// Association normal-angle threshold, degrees.
    #[arg(long, default_value_t = SlamParams::default().tracker.max_normal_angle_deg)]
    max_angle: f64,
    /// Weigh point-to-plane residuals by (mean depth / depth)^k (0: off; 2 follows a
    /// structured-light sensor's noise).
    #[arg(long, default_value_t = SlamParams::default().tracker.depth_weight_power)]
    depth_weight_power: i32,
    /// Weight of the prior holding each frame's pose to the constant-velocity prediction, relative
    /// to the frame's points (TrackerParams::motion_prior; 0 turns it off).
    #[arg(long, default_value_t = SlamParams::default().tracker.motion_prior)]
    motion_prior: f64,
    /// A frame whose geometry fixes its pose worse than this (λ_min / λ_max of its point-to-plane
    /// information, TrackerParams::min_conditioning) and whose texture cannot hold it is
    /// reported degenerate, not tracked.
    #[arg(long, default_value_t = SlamParams::default().tracker.min_conditioning)]
    min_conditioning: f64,
    /// Focal length x, pixels (negative for a mirrored axis), when DIR has no intrinsics.txt
    /// [default: TUM fr1's].
    #[arg(long, allow_negative_numbers = true)]
    fx: Option<f64>,
    /// Focal length y, pixels (negative for a mirrored axis, as ICL-NUIM's −480), when DIR has
    /// no intrinsics.txt [default: TUM fr1's].
    #[arg(long, allow_negative_numbers = true)]
    fy: Option<f64>,
    /// Principal point x, pixels, when DIR has no intrinsics.txt [default: TUM fr1's].
    #[arg(long, allow_negative_numbers = true)]
    cx: Option<f64>,
    /// Principal point y, pixels, when DIR has no intrinsics.txt [default: TUM fr1's].
    #[arg(long, allow_negative_numbers = true)]
    cy: Option<f64>,
    /// Depth units per metre when DIR has no intrinsics.txt [default: 5000, TUM's].
    #[arg(long)]
    depth_scale: Option<f64>,
    /// Split the map into sub-maps anchored to keyframes, track against the newest only and
    /// close loops densely against the older ones; --mesh then writes the sub-maps moved with
    /// their keyframes to the pose graph's solution.
    #[arg(long)]
    submaps: bool,
    /// With --submaps: frames a sub-map fuses before the next keyframe starts a new one.
    #[arg(long, default_value_t = SubmapParams::default().frames)]
    submap_frames: usize,
    /// With --submaps: frames fused into both the old and the new sub-map before tracking
    /// switches to the new one.
    #[arg(long, default_value_t = SubmapParams::default().overlap)]
    submap_overlap: usize,
    /// A loop's deviation as a fraction of the scene's median depth (and radians), in the
    /// keyframe graph (LoopParams::loop_deviation).
    #[arg(long, default_value_t = SlamParams::default().relocalise.loops.loop_deviation)]
    loop_deviation: f64,
    /// The odometry's deviation per metre and per radian between keyframes, in the keyframe
    /// graph (LoopParams::odometry_drift).
    #[arg(long, default_value_t = SlamParams::default().relocalise.loops.odometry_drift)]
    odometry_drift: f64,
    /// Weigh the keyframe graph's odometry by the drift model alone, without the tracking's own
    /// spread along weakly fixed motions (LoopParams::tracking_spread).
    #[arg(long)]
    no_tracking_spread: bool,
    /// Do not relocalise after losing track (frames then fail until tracking from the last good
    /// pose works again).
    #[arg(long)]
    no_relocalise: bool,
    /// Frames to process at most [default: all].
    #[arg(long)]
    max_frames: Option<usize>,
    /// Do not fit the live exposure to the model's (TrackerParams::fit_gain).
    #[arg(long)]
    no_exposure_fit: bool,
    /// Start each frame's tracking from the last pose, not from the constant-velocity prediction.
    #[arg(long)]
    no_motion_prediction: bool,
    /// Use the colour as it is, not brought to the depth's instant (when their stamps differ).
    #[arg(long)]
    no_color_registration: bool,
    /// TUM layout: read the frames through TUM's published calibration of this sensor (fr1, fr2
    /// or fr3: intrinsics and lens distortion; the frames are undistorted) instead of the
    /// folder's intrinsics.
    #[arg(long, value_name = "fr1|fr2|fr3")]
    calibration: Option<String>,
    /// TUM layout: pair a depth and a colour frame only when their stamps are less than this many
    /// seconds apart (associate.py's --max_difference), where the frames are paired by stamps
    /// (no associations.txt, or --no-associations).
    #[arg(long, default_value_t = dynamap_slam::io::tum::MAX_DIFFERENCE)]
    max_difference: f64,
    /// TUM layout: pair the frames by their stamps even where the folder has an associations.txt
    /// (which otherwise pairs them, as ORB-SLAM2 reads it).
    #[arg(long)]
    no_associations: bool,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

/// The SLAM parameters the flags set, checked.
fn params(args: &Args) -> Result<SlamParams> {
    check_flags(args)?;
    let mut p = SlamParams::default();
    p.tsdf.voxel_size = args.voxel_size;
    p.tsdf.truncation_voxels = args.truncation;
    p.tsdf.max_weight = args.max_weight;
    p.tsdf.max_blocks = args.max_blocks;
    if let Some(lambda) = args.lambda {
        p.tracker.photometric_weight = PhotometricWeight::Fixed(lambda);
    }
    if let Some(kappa) = args.photometric_balance {
        p.tracker.photometric_weight = PhotometricWeight::Balanced(kappa);
    }
    p.tracker.iterations = args.iterations.clone();
    p.tracker.strides = args.strides.clone();
    p.tracker.fit_gain = !args.no_exposure_fit;
    p.predict_motion = !args.no_motion_prediction;
    p.register_color = !args.no_color_registration;
    p.tracker.max_distance = args.max_distance;
    p.tracker.max_normal_angle_deg = args.max_angle;
    p.tracker.depth_weight_power = args.depth_weight_power;
    p.tracker.motion_prior = args.motion_prior;
    p.tracker.min_conditioning = args.min_conditioning;
    p.relocalise.enabled = !args.no_relocalise;
    p.relocalise.loops.loop_deviation = args.loop_deviation;
    p.relocalise.loops.odometry_drift = args.odometry_drift;
    p.relocalise.loops.tracking_spread = !args.no_tracking_spread;
    if args.submaps {
        if args.no_relocalise || args.submap_frames == 0 {
            return Err(cli::bad_input(
                "--submaps needs relocalisation (its keyframes anchor the sub-maps) and --submap-frames at least 1",
            ));
        }
        p.submaps = Some(SubmapParams {
            frames: args.submap_frames,
            overlap: args.submap_overlap,
        });
    }
    Ok(p)
}

/// Refuses flag values outside what their settings mean ([`flag_checks`]): the map's, the
/// tracker's, the keyframe graph's and the intrinsics'; and output paths that could not be
/// written ([`cli::check_outputs`]).
fn check_flags(args: &Args) -> Result<()> {
    use flag_checks::{angle, iterations, non_negative, positive, voxel, within};
    let tsdf = SlamParams::default().tsdf;
    voxel("--voxel-size", args.voxel_size)?;
    // a band (truncation × voxel) wider than the depth range fused is no band
    let widest = f64::from(tsdf.max_depth) / f64::from(args.voxel_size);
    let band = (1.0, widest.floor());
    within("--truncation", args.truncation, band, " voxels")?;
    if !(args.max_weight.is_finite() && args.max_weight >= 1.0) || args.max_blocks == 0 {
        return Err(cli::bad_input(format!(
            "--max-weight must be a number of at least 1 (not {}) and --max-blocks at least 1",
            args.max_weight
        )));
    }
    if args.iterations.is_empty() {
        return Err(cli::bad_input("--iterations needs a level"));
    }
    iterations("--iterations", &args.iterations, true)?;
    if args.strides.contains(&0) {
        return Err(cli::bad_input(
            "--strides must be at least 1 on every level",
        ));
    }
    positive("--max-distance", args.max_distance)?;
    angle("--max-angle", args.max_angle)?;
    non_negative("--motion-prior", args.motion_prior)?;
    if let Some(lambda) = args.lambda {
        non_negative("--lambda", lambda)?;
    }
    if let Some(kappa) = args.photometric_balance {
        non_negative("--photometric-balance", kappa)?;
    }
    if !(0.0..1.0).contains(&args.min_conditioning) {
        return Err(cli::bad_input(
            "--min-conditioning is a ratio of eigenvalues: at least 0 and below 1",
        ));
    }
    positive("--loop-deviation", args.loop_deviation)?;
    positive("--odometry-drift", args.odometry_drift)?;
    check_intrinsics_flags(args)?;
    let files = [
        ("--output", args.output.as_deref()),
        ("--mesh", args.mesh.as_deref()),
        ("--graph", args.graph.as_deref()),
        ("--render", args.render.as_deref()),
    ];
    cli::check_outputs(&files, &[("--preview", args.preview.as_deref())])
}

/// Refuses intrinsics flags that no camera has (a focal length or depth scale of zero or less,
/// a principal point at infinity), whether or not the folder's `intrinsics.txt` overrides them.
fn check_intrinsics_flags(args: &Args) -> Result<()> {
    flag_checks::intrinsics([
        ("--fx", args.fx),
        ("--fy", args.fy),
        ("--cx", args.cx),
        ("--cy", args.cy),
    ])?;
    args.depth_scale
        .map_or(Ok(()), |v| flag_checks::positive("--depth-scale", v))
}

/// Renders the default sequence (60 frames orbiting the room, 640×480, recorded by the
/// structured-light sensor model with lens distortion) into a folder.
fn default_sequence() -> Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("dynamap-rigid-default-{}", std::process::id()));
    let cam = Camera::tum_default();
    let traj = motion::procedural(motion::Motion::Orbit, 60, 30.0);
    tracing::info!("rendering a 60-frame sequence into {}", dir.display());
    sequence::write_rigid(
        &dir,
        &Scene::room(1),
        &cam,
        &traj,
        &Isometry3::identity(),
        &sequence::Sensor::Kinect(Box::default()),
        |_| {},
    )?;
    Ok(dir)
}

/// Logs one frame to the recording: camera, images, the model view, the trajectory so far,
/// tracking figures, and the mesh every `--rerun-mesh-every` frames.
fn record(
    rec: &Recorder,
    args: &Args,
    i: usize,
    frame: &RgbdFrame,
    report: &FrameReport,
    slam: &RigidSlam,
    trajectory: &Trajectory,
) -> Result<()> {
    let camera = slam.camera();
    rec.at("frame", i);
    rec.camera("world/camera", &camera, &report.pose)?;
    if let Some(c) = &frame.color {
        rec.color("world/camera/rgb", c)?;
    }
    rec.depth("world/camera/depth", &frame.depth, camera.depth_scale)?;
    rec.color(
        "model_view",
        &preview::shade(slam.model_maps(), &report.pose),
    )?;
    rec.path(
        "world/trajectory/estimate",
        &trajectory.poses,
        [220, 40, 40],
    )?;
    rec.scalar("tracking/inliers", report.inliers as f64)?;
    rec.scalar("tracking/failed", report.failure().is_some() as u8 as f64)?;
    rec.scalar("tracking/placed", report.placed as u8 as f64)?;
    let t = &report.times;
    for (name, s) in [
        ("preprocess", t.preprocess),
        ("track", t.track),
        ("integrate", t.integrate),
        ("raycast", t.raycast),
    ] {
        rec.scalar(&format!("tracking/ms/{name}"), 1e3 * s)?;
    }
    if args.rerun_mesh_every > 0 && i % args.rerun_mesh_every == args.rerun_mesh_every - 1 {
        rec.mesh("world/mesh", &slam.volume().extract_mesh())?;
    }
    Ok(())
}

/// Logs the loops found since the last call (`logged` of them were logged before), each as a
/// segment between its keyframes' tracked poses, and the count so far.
fn log_loops(rec: &Recorder, graph: &KeyframeGraph, logged: &mut usize) -> Result<()> {
    let vertices = &graph.graph().vertices;
    let pose = |id| match vertices.get(&id) {
        Some(Pose::Se3(x)) => Some(*x),
        _ => None,
    };
    for (k, l) in graph.loops().iter().enumerate().skip(*logged) {
        if let (Some(from), Some(to)) = (pose(l.from), pose(l.to)) {
            rec.path(&format!("world/loops/{k}"), &[from, to], [40, 200, 40])?;
        }
    }
    if graph.loop_count() > *logged {
        *logged = graph.loop_count();
        rec.scalar("tracking/loops", *logged as f64)?;
    }
    Ok(())
}

pub fn main() -> ExitCode {
    cli::run(run)
}

fn run(args: Args, session: &Session) -> Result<()> {
    let params = params(&args)?;
    let (dir, generated) = match &args.dir {
        Some(d) => (d.clone(), false),
        None => (default_sequence()?, true),
    };
    let seq = open_sequence(&args, &dir)?;
    let n = args.max_frames.unwrap_or(seq.len()).min(seq.len());
    let mut slam = RigidSlam::new(*seq.camera(), params, start_pose(&seq));
    let bar = session.progress(n as u64, "frames");
    let rec = Recorder::open(&args.rerun, "dynamap rigid_slam")?;
    if let Some(gt) = seq.groundtruth() {
        rec.at("frame", 0);
        rec.path("world/trajectory/ground_truth", &gt.poses, [90, 90, 90])?;
    }
    let interrupt = cli::interrupt_flag()?;
    let start = Instant::now();
    let mut tally = Tally::default();
    let logged = track_frames(
        &args, &seq, n, &mut slam, &mut tally, &bar, &rec, &interrupt,
    );
    let interrupted = interrupt.load(std::sync::atomic::Ordering::SeqCst);
    // a failed recording is reported after the outputs are written, so the run is not lost
    let logged = logged.and_then(|()| {
        if rec.enabled() {
            rec.mesh("world/mesh", &slam.volume().extract_mesh())?;
        }
        rec.flush()
    });
    let seconds = start.elapsed().as_secs_f64();
    bar.finish_and_clear();
    // the keyframe graph, solved once more from the background solver's newest solution; the
    // frames follow their keyframes to it
    let warm = slam.finish_graph()?.cloned();
    let solved = solve_graph(slam.keyframe_graph(), warm.as_ref(), args.graph.is_some())?;
    let unplaced = leave_out_unplaced(&mut tally, slam.keyframe_graph());
    let tracked = tally.trajectory.clone();
    // one volume cannot follow a loop: its poses stay as tracked (NOTES 59), unless a lost track
    // split it into sub-maps (NOTES 81)
    if let Some(o) = solved.as_ref().filter(|_| slam.submaps().is_some()) {
        correct(
            &mut tally.trajectory,
            &tally.anchors,
            slam.keyframe_graph(),
            &o.poses,
        );
    }
    write_outputs(&args, &slam, &tally.trajectory, solved.as_ref())?;
    let ate_result = ate_against(&seq, &tally.trajectory);
    if let Some(out) = &args.preview {
        write_preview(out, &slam, &seq, &tally.trajectory, ate_result.as_ref())?;
    }
    let ate_tracked = ate_against(&seq, &tracked).map(|a| a.stats.rmse);
    let ate_rmse = ate_result.as_ref().map(|a| a.stats.rmse);
    log_summary(&tally, &slam, ate_rmse, &dir);
    let graph = slam.keyframe_graph();
    let [read, preprocess, track, integrate, raycast] = tally.ms_per_frame();
    println!(
        "{}",
        serde_json::json!({
            "frames": tally.processed, "seconds": seconds, "fps": tally.processed as f64 / seconds,
            "failures": tally.failures, "skipped": tally.skipped, "tracked": tally.trajectory.len(),
            "relocalised": tally.relocalised, "new_maps": tally.new_maps, "held_apart": graph.held_apart(),
            "unplaced_frames": unplaced, "unpaired_depth": seq.unpaired_depth(),
            "repeated_stamps": seq.repeated_stamps(),
            "keyframes": graph.graph().vertices.len(), "loops": graph.loop_count(),
            "loop_events": loop_events(graph, solved.as_ref(), &tally.given), "ate_tracked": ate_tracked,
            "graph_converged": solved.as_ref().map(|o| o.converged),
            "interrupted": interrupted, "ate_rmse": ate_rmse, "sequence": dir.display().to_string(),
            "ms_per_frame": {"read": read, "preprocess": preprocess, "track": track,
                             "integrate": integrate, "raycast": raycast},
        })
    );
    if generated {
        let _ = std::fs::remove_dir_all(&dir);
    }
    if interrupted {
        return Err(cli::Interrupted.into());
    }
    tally.counts().check(dir.display(), "tracked")?;
    logged
}

/// The SE(3)-aligned ATE of `trajectory` against the sequence's ground truth, where it has one
/// and they share stamps.
fn ate_against(seq: &Sequence, trajectory: &Trajectory) -> Option<AteResult> {
    let gt = seq.groundtruth()?;
    ate(gt, trajectory, Alignment::Se3, MAX_STAMP_DIFFERENCE).ok()
}

/// Opens the sequence in `dir` with the command line's stamp limit, TUM calibration and (without
/// an `intrinsics.txt`) intrinsics.
fn open_sequence(args: &Args, dir: &Path) -> Result<Sequence> {
    if !(args.max_difference >= 0.0 && args.max_difference.is_finite()) {
        return Err(cli::bad_input(format!(
            "--max-difference must be a finite non-negative number of seconds, got {}",
            args.max_difference
        )));
    }
    let sensor = match &args.calibration {
        Some(name) => Some(TumSensor::from_name(name).ok_or_else(|| {
            cli::bad_input(format!(
                "--calibration {name}: not a TUM sensor (fr1, fr2 or fr3)"
            ))
        })?),
        None => None,
    };
    let pairing = if args.no_associations {
        Pairing::Stamps
    } else {
        Pairing::Listed
    };
    let options = OpenOptions {
        max_difference: args.max_difference,
        pairing,
        calibration: sensor.map(TumSensor::calibration),
        ..OpenOptions::default()
    };
    let mut seq = Sequence::open(dir, &options).bad_input()?;
    unread_frames::warn(dir, &seq, args.max_difference);
    let flags = [args.fx, args.fy, args.cx, args.cy, args.depth_scale];
    let given = flags[..4].iter().all(Option::is_some);
    cli::check_tum_intrinsics(dir, &seq, Some(given))?;
    if dir.join("intrinsics.txt").exists() {
        if flags.iter().any(Option::is_some) {
            tracing::warn!(
                "{}: intrinsics.txt gives the intrinsics; --fx, --fy, --cx, --cy and \
                 --depth-scale are for folders without one, and are ignored",
                dir.display()
            );
        }
    } else {
        let c = seq.camera_mut();
        c.fx = args.fx.unwrap_or(c.fx);
        c.fy = args.fy.unwrap_or(c.fy);
        c.cx = args.cx.unwrap_or(c.cx);
        c.cy = args.cy.unwrap_or(c.cy);
        c.depth_scale = args.depth_scale.unwrap_or(c.depth_scale);
    }
    Ok(seq)
}

/// The ground truth's pose at the first frame when there is one (for comparable ATE plots; ATE
/// aligns anyway), else the identity.
fn start_pose(seq: &Sequence) -> Isometry3<f64> {
    let t0 = seq.first_stamp();
    seq.groundtruth()
        .and_then(|g| {
            g.stamps
                .iter()
                .position(|s| (s - t0).abs() < MAX_STAMP_DIFFERENCE)
                .map(|i| g.poses[i])
        })
        .unwrap_or_else(Isometry3::identity)
}

/// What the frame loop counts and keeps.
#[derive(Default)]
struct Tally {
    /// The tracked frames' stamps and poses.
    trajectory: Trajectory,
    /// Each tracked frame's keyframe anchor (for carrying it to the graph's solution).
    anchors: Vec<Option<usize>>,
    /// Stage times summed over the frames.
    totals: StageTimes,
    /// Frames read but not tracked, frames that could not be read, frames relocalised, frames
    /// that started a new map fragment.
    failures: usize,
    skipped: usize,
    relocalised: usize,
    new_maps: usize,
    /// Time spent waiting for the reader thread, seconds.
    read_seconds: f64,
    /// Frames taken from the stream.
    processed: usize,
    /// Why the first frame that could not be read could not be.
    first_unreadable: Option<String>,
    /// The last frame tracked.
    last_good: Option<usize>,
    /// The depth stamp of each frame the pipeline counted, in order: its frame number `n`
    /// (counted from 1, as keyframes are named) is `given[n - 1]`.
    given: Vec<f64>,
}

impl Tally {
    /// The frames taken, unreadable and tracked.
    fn counts(&self) -> cli::FrameCounts {
        cli::FrameCounts {
            taken: self.processed,
            unreadable: self.skipped,
            first_unreadable: self.first_unreadable.clone(),
            kept: self.trajectory.len(),
        }
    }

    /// Milliseconds per frame taken: read, preprocess, track, integrate, raycast.
    fn ms_per_frame(&self) -> [f64; 5] {
        let t = &self.totals;
        [
            self.read_seconds,
            t.preprocess,
            t.track,
            t.integrate,
            t.raycast,
        ]
        .map(|s| 1e3 * s / self.processed.max(1) as f64)
    }
}

/// Tracks the first `n` frames of `seq` until done or interrupted, counting into `tally`; the
/// result is the recording's (logging stops at its first error, tracking does not).
///
/// A reader thread decodes the next frames while this one is processed (as a sensor driver
/// would deliver them); "read" is the time spent waiting for a frame.
#[allow(clippy::too_many_arguments)] // the run's parts, each used by the loop
fn track_frames(
    args: &Args,
    seq: &Sequence,
    n: usize,
    slam: &mut RigidSlam,
    tally: &mut Tally,
    bar: &ProgressBar,
    rec: &Recorder,
    interrupt: &AtomicBool,
) -> Result<()> {
    let mut logged: Result<()> = Ok(());
    let mut logged_loops = 0;
    let (sender, frames) = std::sync::mpsc::sync_channel(2);
    std::thread::scope(|scope| {
        scope.spawn(move || {
            for i in 0..n {
                if sender.send((i, seq.load(i))).is_err() {
                    break;
                }
            }
        });
        let frames = frames; // dropped after the loop, so the reader stops on an interrupt
        loop {
            if interrupt.load(std::sync::atomic::Ordering::SeqCst) {
                break;
            }
            let t_read = Instant::now();
            let Ok((i, loaded)) = frames.recv() else {
                break;
            };
            tally.read_seconds += t_read.elapsed().as_secs_f64();
            tally.processed += 1;
            let frame = match loaded {
                Ok(f) => f,
                Err(e) => {
                    tally.skipped += 1;
                    tracing::warn!("frame {i} skipped: {e}");
                    tally
                        .first_unreadable
                        .get_or_insert_with(|| format!("{e:#}"));
                    bar.inc(1);
                    continue;
                }
            };
            let report = track_one(slam, tally, i, &frame);
            if rec.enabled() && logged.is_ok() {
                logged = record(rec, args, i, &frame, &report, slam, &tally.trajectory)
                    .and_then(|()| log_loops(rec, slam.keyframe_graph(), &mut logged_loops));
            }
            bar.inc(1);
        }
        drop(frames);
        if rec.enabled() && logged.is_ok() {
            // the loops of the searches still under way
            slam.finish_loops();
            logged = log_loops(rec, slam.keyframe_graph(), &mut logged_loops);
        }
    });
    logged
}

/// Tracks frame `i`, logs its outcome and counts it.
fn track_one(slam: &mut RigidSlam, tally: &mut Tally, i: usize, frame: &RgbdFrame) -> FrameReport {
    let stamps = FrameStamps {
        depth: frame.timestamp,
        color: frame.color_timestamp,
    };
    let report = slam.process_timed(&frame.depth, frame.color.as_ref(), stamps);
    if slam.frames_counted() > tally.given.len() {
        tally.given.push(frame.timestamp);
    }
    tally.totals.add(&report.times);
    if let Some(why) = report.failure() {
        tally.failures += 1;
        tracing::warn!(
            "frame {i} ({:.6}): not tracked, not fused: {why}",
            frame.timestamp
        );
        return report;
    }
    if report.outcome == FrameOutcome::Relocalised {
        tally.relocalised += 1;
        let previous = tally
            .last_good
            .map_or(String::new(), |g| format!(" (previous frame located: {g})"));
        tracing::info!(
            "frame {i} ({:.6}): relocalised: a break in the stream, a lost track or \
             a doubtful one{previous}",
            frame.timestamp,
        );
    }
    if report.outcome == FrameOutcome::NewMap {
        tally.new_maps += 1;
        tracing::info!(
            "frame {i} ({:.6}): lost for good: a new map starts here; its frames join the \
             trajectory if a loop places it in the map",
            frame.timestamp,
        );
    }
    tally.last_good = Some(i);
    tally.trajectory.push(frame.timestamp, report.pose);
    tally.anchors.push(report.anchor);
    report
}

/// Writes `--output`, `--mesh`, `--graph` and `--render`.
fn write_outputs(
    args: &Args,
    slam: &RigidSlam,
    trajectory: &Trajectory,
    solved: Option<&Optimised>,
) -> Result<()> {
    if let Some(out) = &args.output {
        trajectory.write_tum(out)?;
    }
    if let Some(m) = &args.mesh {
        ply::write(m, &slam.map_mesh(solved.map(|o| &o.poses)))?;
    }
    if let (Some(path), Some(o)) = (&args.graph, solved) {
        slam.keyframe_graph().write_g2o(path, &o.poses)?;
    }
    if let Some(png) = &args.render {
        let mut maps = RaycastMaps::new();
        slam.volume()
            .raycast(&slam.camera(), &slam.pose(), &mut maps);
        dynamap_slam::io::images::write_color(png, &preview::shade(&maps, &slam.pose()))?;
    }
    Ok(())
}

/// `--preview`: model views from three of the poses, the trajectory from above and, with a
/// ground truth, the per-frame error.
fn write_preview(
    out: &Path,
    slam: &RigidSlam,
    seq: &Sequence,
    trajectory: &Trajectory,
    ate_result: Option<&AteResult>,
) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let poses = &trajectory.poses;
    if !poses.is_empty() {
        let views = [poses[0], poses[poses.len() / 2], poses[poses.len() - 1]];
        preview::model_views(out, slam.volume(), seq.camera(), 0.5, &views)?;
    }
    let truth = seq.groundtruth().zip(ate_result);
    preview::trajectory_plot(&out.join("trajectory.png"), trajectory, truth)?;
    if let Some((gt, a)) = truth {
        preview::error_plot(&out.join("error.png"), gt, trajectory, a)?;
    }
    tracing::info!("pictures in {}", out.display());
    Ok(())
}

/// Logs the per-frame stage times, the frames not tracked and the ATE.
fn log_summary(tally: &Tally, slam: &RigidSlam, ate_rmse: Option<f64>, dir: &Path) {
    let [read, preprocess, track, integrate, raycast] = tally.ms_per_frame();
    tracing::info!(
        "per frame: read {:.2} ms, preprocess {:.2} ms, track {:.2} ms, integrate {:.2} ms, raycast {:.2} ms; {} blocks ({:.0} MiB)",
        read,
        preprocess,
        track,
        integrate,
        raycast,
        slam.volume().num_blocks(),
        slam.volume().memory_bytes() as f64 / (1 << 20) as f64
    );
    if tally.skipped + tally.failures > 0 {
        tracing::info!(
            "{} of {} frames tracked: {} skipped (unreadable), {} not tracked, {} relocalised",
            tally.trajectory.len(),
            tally.processed,
            tally.skipped,
            tally.failures,
            tally.relocalised
        );
    }
    if let Some(a) = ate_rmse {
        tracing::info!(
            "ATE (SE(3)-aligned RMSE) against {}: {a:.4} m",
            dir.join("groundtruth.txt").display()
        );
    }
}

/// Solves the keyframes' pose graph when it has a loop (or `always`, for `--graph`): `None`
/// without keyframes or loops. A solve that did not converge is kept all the same (its poses are
/// the last iterate), warned of, and reported as `graph_converged: false` in the JSON line.
fn solve_graph(
    graph: &KeyframeGraph,
    warm: Option<&Optimised>,
    always: bool,
) -> Result<Option<Optimised>> {
    if graph.graph().vertices.is_empty() {
        if always {
            bail!("no keyframe was kept: no pose graph to write");
        }
        return Ok(None);
    }
    if graph.loop_count() == 0 && !always {
        return Ok(None);
    }
    let solved = graph.optimise(warm)?;
    if !solved.converged {
        tracing::warn!(
            "the keyframe graph did not converge in {} iterations: its last iterate is used",
            solved.iterations,
        );
    }
    let off = solved.loop_weights.iter().filter(|w| w.2 < 0.5).count();
    tracing::info!(
        "keyframe graph: {} keyframes, {} loops ({off} switched off by DCS)",
        solved.poses.len(),
        solved.loop_weights.len()
    );
    Ok(Some(solved))
}

/// Leaves out of the trajectory the frames anchored to keyframes of map fragments that no
/// loop placed in the main map ([`KeyframeGraph::unplaced`]: they have no pose in it), with a
/// warning; how many.
fn leave_out_unplaced(tally: &mut Tally, graph: &KeyframeGraph) -> usize {
    let unplaced = graph.unplaced();
    if unplaced.is_empty() {
        return 0;
    }
    let trajectory = std::mem::take(&mut tally.trajectory);
    let anchors = std::mem::take(&mut tally.anchors);
    let mut left_out = 0;
    for ((stamp, pose), anchor) in trajectory
        .stamps
        .into_iter()
        .zip(trajectory.poses)
        .zip(anchors)
    {
        if anchor.is_some_and(|a| unplaced.contains(&a)) {
            left_out += 1;
            continue;
        }
        tally.trajectory.push(stamp, pose);
        tally.anchors.push(anchor);
    }
    tracing::warn!(
        "{left_out} tracked frames lie in map fragments that no loop joined to the main map \
         (of {} fragments): left out of the trajectory and the mesh",
        graph.fragment_count(),
    );
    left_out
}

/// Moves each tracked pose to the graph's solution with the correction of its anchor keyframe
/// and the next one, interpolated by its place between them in the trajectory
/// ([`KeyframeGraph::corrected_between`]); after the last keyframe, with the last one's.
fn correct(
    trajectory: &mut Trajectory,
    anchors: &[Option<usize>],
    graph: &KeyframeGraph,
    solution: &BTreeMap<usize, Isometry3<f64>>,
) {
    let mut k = 0;
    while k < anchors.len() {
        // the run of frames anchored to one keyframe, and where the next keyframe's begins
        let end = k + anchors[k..]
            .iter()
            .take_while(|&&a| a == anchors[k])
            .count();
        if let Some(a) = anchors[k] {
            let next = anchors.get(end).copied().flatten();
            for (j, pose) in trajectory.poses[k..end].iter_mut().enumerate() {
                *pose = match next {
                    Some(b) => {
                        let s = j as f64 / (end - k) as f64;
                        graph.corrected_between(solution, (a, b), s, pose)
                    }
                    None => graph.corrected(solution, a, pose),
                };
            }
        }
        k = end;
    }
}

/// The loops found, each with its keyframes (named, as in the log and the `--graph` file, by
/// their frame number counted from 1, and with their frames' depth stamps from `given`), inliers
/// and DCS weight at the solution, for the JSON line. The stamps name the frames even where the
/// reader left some out of the sequence's list (a colour beyond the stamp limit).
fn loop_events(
    graph: &KeyframeGraph,
    solved: Option<&Optimised>,
    given: &[f64],
) -> serde_json::Value {
    let stamp = |frame: usize| frame.checked_sub(1).and_then(|i| given.get(i)).copied();
    let weight = |from, to| {
        solved
            .and_then(|o| o.loop_weights.iter().find(|w| (w.0, w.1) == (from, to)))
            .map(|w| w.2)
    };
    graph
        .loops()
        .iter()
        .map(|l| {
            serde_json::json!({"from": l.from, "to": l.to, "inliers": l.inliers,
                               "from_stamp": stamp(l.from), "to_stamp": stamp(l.to),
                               "weight": weight(l.from, l.to)})
        })
        .collect()
}
