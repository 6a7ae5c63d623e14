//! Write a rendered RGB-D sequence with ground truth in the TUM layout.
//!
//! ```text
//! cargo run --release --example generate -- rigid OUT_DIR [--trajectory GT.txt | --motion orbit|shake|fast-rotation|sweep|survey|corridor|gallery]
//!                                            [--sensor kinect|ideal] [--frames N] [--width W --height H]
//!                                            [--layout room|bare|office|twins|corridor|gallery] [--seed K] [--no-noise] [--gain-drift A]
//! cargo run --release --example generate -- deforming OUT_DIR [--motion bend|twist|wave]
//!                                            [--surface plane|cylinder|sphere] [--frames N] ...
//! cargo run --release --example generate -- faulty OUT_DIR [--clean] [--width W --height H] ...
//! ```
//! `faulty` is the reliability test's orbit of 180 frames with 10 dropped frames, 5 corrupt files,
//! 3 blank depth frames, a 30 cm jump at frame 80 and 20 frames at a plain wall from frame 140
//! (`--clean`: the same orbit without them).
//!
//! Writes rgb/, depth/, rgb.txt, depth.txt, associations.txt, groundtruth.txt, intrinsics.txt
//! (fx fy cx cy depth_scale) and, for deforming scenes, meshes/ (ground-truth surface per frame) and
//! flow/ (per-pixel scene flow). Prints one JSON line last.

use crate::cli;
use crate::deform_flags::{DeformMotion, SurfaceArg};
use crate::flag_checks;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use cli::{InputError, Session};
use dynamap_slam::camera::Camera;
use dynamap_slam::io::trajectory::Trajectory;
use dynamap_slam::synthetic::deform::{self, DeformingScene, Field, SurfaceKind};
use dynamap_slam::synthetic::faults::{self, FaultPlan};
use dynamap_slam::synthetic::kinect::KinectModel;
use dynamap_slam::synthetic::layouts::{self, Layout};
use dynamap_slam::synthetic::motion::{self, Motion};
use dynamap_slam::synthetic::noise::SensorNoise;
use dynamap_slam::synthetic::sequence;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

#[derive(Clone, Copy, Debug, ValueEnum)]
enum RigidMotion {
    Orbit,
    Shake,
    FastRotation,
    Sweep,
    Survey,
    Corridor,
    Gallery,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum SensorArg {
    Kinect,
    Ideal,
}

/// What both kinds of sequence take.
#[derive(clap::Args, Debug)]
struct SequenceFlags {
    /// Output folder (created).
    out: PathBuf,
    /// Number of frames.
    #[arg(long, default_value_t = 60)]
    frames: usize,
    /// Image width.
    #[arg(long, default_value_t = 640)]
    width: usize,
    /// Image height.
    #[arg(long, default_value_t = 480)]
    height: usize,
    /// Random seed (noise and textures).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Exact depth (quantised only) and colour.
    #[arg(long)]
    no_noise: bool,
    /// Amplitude of a drifting auto-exposure gain on the colour (0.15: a consumer sensor's drift
    /// over seconds). The ideal sensor's is 1 + a sin(2π k / 150) for frame k (default 0), the
    /// Kinect's a sum of slow random sinusoids (default 0.15).
    #[arg(long)]
    gain_drift: Option<f32>,
    /// Frames per second.
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
}

#[derive(Subcommand, Debug)]
enum Kind {
    /// A furnished room seen along a camera trajectory.
    Rigid {
        #[command(flatten)]
        sequence: SequenceFlags,
        /// Follow a TUM ground-truth trajectory (poses taken as they are at about --fps).
        #[arg(long, conflicts_with = "motion")]
        trajectory: Option<PathBuf>,
        /// A procedural motion.
        #[arg(long, value_enum, default_value = "orbit")]
        motion: RigidMotion,
        /// The sensor: a structured-light Kinect (quantised disparity, shadows, flying pixels,
        /// motion blur, exposure drift, vignetting, lens distortion, colour 10-20 ms after depth
        /// with its own stamps) or the ideal render with simple axial noise.
        #[arg(long, value_enum, default_value = "kinect")]
        sensor: SensorArg,
        /// The scene: `room` (furnished), `bare` (the same room with plain floor and walls),
        /// `office` (drawn from the seed), `twins` (two identical halves), `corridor` (a ring
        /// corridor round a block, for `--motion corridor`) or `gallery` (a ring hall with
        /// pillars round its block, for `--motion gallery`).
        #[arg(long, default_value = "room")]
        layout: Layout,
    },
    /// A surface deforming in front of a static camera.
    Deforming {
        #[command(flatten)]
        sequence: SequenceFlags,
        /// The deformation field.
        #[arg(long, value_enum, default_value = "bend")]
        motion: DeformMotion,
        /// The surface.
        #[arg(long, value_enum, default_value = "plane")]
        surface: SurfaceArg,
        /// Deform this mesh (PLY, in metres, centred near its origin) instead of a built-in surface.
        #[arg(long)]
        mesh: Option<PathBuf>,
    },
    /// The room orbit with the faults of a real stream (dropped, corrupt and blank frames, a
    /// 30 cm jump, a stretch at a plain wall); --frames is ignored (the plan has 180).
    Faulty {
        #[command(flatten)]
        sequence: SequenceFlags,
        /// The same orbit without faults (the reference), --frames long.
        #[arg(long)]
        clean: bool,
    },
}

/// Render an RGB-D sequence with ground truth.
#[derive(Parser, Debug)]
#[command(long_about = None)]
struct Args {
    #[command(subcommand)]
    kind: Kind,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

impl SequenceFlags {
    /// The TUM default intrinsics scaled to the requested size.
    fn camera(&self) -> Result<Camera> {
        if self.width < 8 || self.height < 8 {
            return Err(cli::bad_input("--width and --height must be at least 8"));
        }
        flag_checks::frame_size(self.width, self.height)?;
        flag_checks::frame_count("--frames", self.frames)?;
        flag_checks::positive("--fps", self.fps)?;
        Ok(Camera::scaled_default(self.width, self.height))
    }

    /// Creates the output folder and returns the sensor model the flags ask for.
    fn prepare(&self) -> Result<SensorNoise> {
        if self.gain_drift.is_some_and(|g| !(0.0..1.0).contains(&g)) {
            return Err(cli::bad_input("--gain-drift must lie in [0, 1)"));
        }
        std::fs::create_dir_all(&self.out)
            .with_context(|| format!("creating {}", self.out.display()))?;
        Ok(SensorNoise {
            enabled: !self.no_noise,
            seed: self.seed,
            gain_drift: self.gain_drift.unwrap_or(0.0),
            ..SensorNoise::default()
        })
    }
}

pub fn main() -> ExitCode {
    cli::run(run)
}

fn run(args: Args, session: &Session) -> Result<()> {
    let start = Instant::now();
    let (common, kind, frames) = match &args.kind {
        Kind::Rigid {
            sequence: common,
            trajectory,
            motion: m,
            sensor,
            layout,
        } => {
            let frames = write_rigid(session, common, trajectory.as_deref(), *m, *sensor, *layout)?;
            (common, "rigid", frames)
        }
        Kind::Deforming {
            sequence: common,
            motion: m,
            surface,
            mesh,
        } => {
            let frames = write_deforming(session, common, *m, *surface, mesh.as_deref())?;
            (common, "deforming", frames)
        }
        Kind::Faulty {
            sequence: common,
            clean,
        } => {
            let cam = common.camera()?;
            let plan = if *clean {
                FaultPlan::clean(common.frames)
            } else {
                FaultPlan::standard()
            };
            let noise = common.prepare()?;
            let bar = session.progress(1, "sequence");
            let written = faults::write_faulty(&common.out, &plan, &cam, &noise)?;
            bar.inc(1);
            let kind = if *clean { "clean" } else { "faulty" };
            (common, kind, written.listed.len())
        }
    };
    println!(
        "{}",
        serde_json::json!({"kind": kind, "out": common.out.display().to_string(), "frames": frames,
            "width": common.width, "height": common.height, "seconds": start.elapsed().as_secs_f64()})
    );
    Ok(())
}

/// A progress bar over `frames` frames, as the writers report them.
fn progress(session: &Session, frames: usize) -> impl FnMut(usize) {
    let bar = session.progress(frames as u64, "frames");
    move |k: usize| bar.set_position(k as u64 + 1)
}

/// `generate rigid`: the camera's path (procedural, or resampled from a TUM trajectory) through
/// the layout, recorded by the sensor; gives the frames written.
fn write_rigid(
    session: &Session,
    common: &SequenceFlags,
    trajectory: Option<&Path>,
    m: RigidMotion,
    sensor: SensorArg,
    layout: Layout,
) -> Result<usize> {
    let cam = common.camera()?;
    let (traj, to_room) = match trajectory {
        Some(path) => {
            let gt = Trajectory::read_tum(path).bad_input()?;
            if gt.is_empty() {
                return Err(cli::bad_input(format!("{}: no poses", path.display())));
            }
            let t = motion::resample(&gt, common.frames, common.fps);
            (t, motion::world_to_room(&gt))
        }
        None => {
            let m = match m {
                RigidMotion::Orbit => Motion::Orbit,
                RigidMotion::Shake => Motion::Shake,
                RigidMotion::FastRotation => Motion::FastRotation,
                RigidMotion::Sweep => Motion::Sweep,
                RigidMotion::Survey => Motion::Survey,
                RigidMotion::Corridor => Motion::Corridor,
                RigidMotion::Gallery => Motion::Gallery,
            };
            (
                motion::procedural(m, common.frames, common.fps),
                nalgebra::Isometry3::identity(),
            )
        }
    };
    let noise = common.prepare()?;
    let sensor = match sensor {
        SensorArg::Kinect if common.no_noise => {
            return Err(cli::bad_input(
                "--no-noise is the ideal sensor's; add --sensor ideal",
            ))
        }
        SensorArg::Kinect => sequence::Sensor::Kinect(Box::new(KinectModel {
            seed: common.seed,
            gain_drift: common.gain_drift.unwrap_or(0.15) as f64,
            ..KinectModel::default()
        })),
        SensorArg::Ideal => sequence::Sensor::Ideal(noise),
    };
    sequence::write_rigid(
        &common.out,
        &layouts::build(layout, common.seed),
        &cam,
        &traj,
        &to_room,
        &sensor,
        progress(session, traj.len()),
    )?;
    Ok(traj.len())
}

/// `generate deforming`: a static camera on a surface (generated, or a mesh) deformed by the
/// field; gives the frames written.
fn write_deforming(
    session: &Session,
    common: &SequenceFlags,
    m: DeformMotion,
    surface: SurfaceArg,
    mesh: Option<&Path>,
) -> Result<usize> {
    let cam = common.camera()?;
    let field = Field::from(m);
    let kind = SurfaceKind::from(surface);
    let canonical = match mesh {
        Some(path) => {
            let mut m = dynamap_slam::io::ply::read(path).bad_input()?;
            if m.faces.is_empty() {
                return Err(cli::bad_input(format!(
                    "{}: the mesh has no faces",
                    path.display()
                )));
            }
            m.compute_normals();
            m
        }
        None => deform::surface(kind, 60),
    };
    let scene = DeformingScene::new(canonical, field, common.seed);
    let traj = sequence::static_camera(common.frames, common.fps);
    let noise = common.prepare()?;
    sequence::write_deforming(
        &common.out,
        &scene,
        &cam,
        &traj,
        &noise,
        progress(session, traj.len()),
    )?;
    Ok(traj.len())
}
