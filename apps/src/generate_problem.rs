//! Write a generated least-squares problem as a file other solvers read: a bundle adjustment in
//! BAL's format, or a pose graph in g2o's, with known ground truth and optional outliers.
//!
//! ```text
//! cargo run --release --example generate_problem -- bal OUT.txt --cameras 200 [--points-per-camera 40]
//!        [--views 3:12] [--pixel-noise 1] [--outliers 0.02] [--seed 1]
//! cargo run --release --example generate_problem -- pose-graph OUT.g2o
//!        [--shape circle|sphere|city|corridor] [--dim 2|3] [--poses N | --rings 10 --per-ring 100]
//!        [--measurements exact|noisy] [--start perturbed|odometry] [--false-loops 20] [--seed 1]
//! ```
//! The file holds the perturbed start; the JSON line last says what was written. Bundle adjustment
//! comes from `residuals::bal::synthetic`, pose graphs from `residuals::pose_graph::synthetic`
//! (wrong loop closures by `add_false_loops`).

use crate::cli;

use anyhow::Result;
use clap::{Parser, Subcommand, ValueEnum};
use cli::{InputError, Session};
use dynamap_residuals::bal::{self, synthetic as bal_synthetic};
use dynamap_residuals::pose_graph::{g2o, synthetic as pg_synthetic, Dimension, PoseGraph};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Shape {
    /// SE(2): concentric laps, each pose tied to the one a lap before.
    Circle,
    /// SE(3): rings on a sphere, each pose tied to the one a ring above.
    Sphere,
    /// A walk through a grid of streets closing loops at intersections it returns to.
    City,
    /// Passes up and down a long corridor with loops only at a few doors.
    Corridor,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum BalLayout {
    /// Cameras on a ring around a cloud of points.
    Ring,
    /// A walk through a grid of streets photographing the façades; the city grows with the
    /// number of cameras (as BAL's Venice and Final sets).
    Streets,
}

/// The `bal` subcommand's settings.
#[derive(clap::Args, Debug)]
struct BalArgs {
    /// Output file.
    out: PathBuf,
    /// Where the cameras stand.
    #[arg(long, value_enum, default_value = "ring")]
    layout: BalLayout,
    /// Number of cameras.
    #[arg(long, default_value_t = 50)]
    cameras: usize,
    /// Points per camera (the number of points is cameras × this).
    #[arg(long, default_value_t = 40)]
    points_per_camera: usize,
    /// How many cameras see each point, LO:HI: neighbours on the ring, or cameras that have
    /// the point in view in the streets [default: 3:12 on the ring, 2:20 in the streets].
    #[arg(long, value_parser = parse_range)]
    views: Option<(usize, usize)>,
    /// Standard deviation of the pixel noise.
    #[arg(long, default_value_t = 1.0)]
    pixel_noise: f64,
    /// Fraction of observations replaced by gross outliers (10 to 60 pixels off).
    #[arg(long, default_value_t = 0.02)]
    outliers: f64,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

/// The `pose-graph` subcommand's settings.
#[derive(clap::Args, Debug)]
struct PoseGraphArgs {
    /// Output file.
    out: PathBuf,
    /// Add the wrong loop closures to this g2o graph instead of generating one (the layout's
    /// settings are then ignored).
    #[arg(long)]
    from: Option<PathBuf>,
    /// Layout (circle is SE(2), sphere SE(3); city and corridor take --dim).
    #[arg(long, value_enum, default_value = "circle")]
    shape: Shape,
    /// Dimension of a city or corridor: 2 (SE(2)) or 3 (SE(3)).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(2..=3))]
    dim: u8,
    /// Number of poses (rings and poses per ring are then both about its square root).
    #[arg(long)]
    poses: Option<usize>,
    /// Laps or rings, without --poses.
    #[arg(long, default_value_t = 10)]
    rings: usize,
    /// Poses per lap or ring, without --poses.
    #[arg(long, default_value_t = 100)]
    per_ring: usize,
    /// Measurements exact (the truth is the optimum) or drawn from each edge's Gaussian [default:
    /// exact on rings, noisy in a city or corridor].
    #[arg(long, value_enum)]
    measurements: Option<Measurements>,
    /// Where the vertices in the file start.
    #[arg(long, value_enum, default_value = "perturbed")]
    start: StartKind,
    /// Wrong loop closures added between random poses.
    #[arg(long, default_value_t = 0)]
    false_loops: usize,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

#[derive(Clone, Copy, Debug, PartialEq, ValueEnum)]
enum Measurements {
    /// Exact: the ground truth is the optimum, chi2 0.
    Exact,
    /// Drawn from N(truth, Ω⁻¹).
    Noisy,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum StartKind {
    /// The truth with noise on every pose but the first.
    Perturbed,
    /// The measurements composed along the odometry chain, as published graphs start.
    Odometry,
}

#[derive(Subcommand, Debug)]
enum Kind {
    /// A bundle adjustment in BAL's format (cameras on a ring, or a walk through streets).
    Bal(BalArgs),
    /// A pose graph in g2o's format: rings, a city walk or a corridor, with optional wrong loop
    /// closures.
    PoseGraph(PoseGraphArgs),
}

/// Write a generated problem for other solvers.
#[derive(Parser, Debug)]
#[command(version, long_about = None)]
struct Args {
    #[command(subcommand)]
    kind: Kind,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

fn parse_range(s: &str) -> Result<(usize, usize), String> {
    let (lo, hi) = s
        .split_once(':')
        .ok_or_else(|| format!("'{s}': expected LO:HI"))?;
    let lo: usize = lo
        .trim()
        .parse()
        .map_err(|_| format!("'{lo}' is not a count"))?;
    let hi: usize = hi
        .trim()
        .parse()
        .map_err(|_| format!("'{hi}' is not a count"))?;
    if lo < 2 || hi < lo {
        return Err(format!("'{s}': need 2 <= LO <= HI"));
    }
    Ok((lo, hi))
}

pub fn main() -> ExitCode {
    cli::run(run)
}

fn run(args: Args, _session: &Session) -> Result<()> {
    let summary = match args.kind {
        Kind::Bal(a) => write_bal(a)?,
        Kind::PoseGraph(a) => write_pose_graph(a)?,
    };
    println!("{summary}");
    Ok(())
}

/// The most cameras or points a generated BAL problem may have: beyond the largest published
/// one (Final-13682, 4.4 million points); a problem of 10⁹ aborted on its allocation.
const MAX_SIZE: usize = 5_000_000;

/// The most poses (or wrong loops) a generated pose graph may have: four hundred times
/// sphere2500's; ten million took 10 GB to generate.
const MAX_POSES: usize = 1_000_000;

/// `bal`: generates the problem and writes it; the summary line.
fn write_bal(a: BalArgs) -> Result<serde_json::Value> {
    let (layout, views) = match a.layout {
        BalLayout::Ring => (bal_synthetic::Layout::Ring, a.views.unwrap_or((3, 12))),
        BalLayout::Streets => (bal_synthetic::Layout::Streets, a.views.unwrap_or((2, 20))),
    };
    if a.cameras < 2 || (matches!(a.layout, BalLayout::Ring) && views.1 > a.cameras) {
        return Err(cli::bad_input(format!(
            "--cameras {} must be at least 2 and, on the ring, at least the largest --views count {}",
            a.cameras, views.1
        )));
    }
    let points = a.cameras.checked_mul(a.points_per_camera);
    if a.cameras > MAX_SIZE || !points.is_some_and(|p| (1..=MAX_SIZE).contains(&p)) {
        return Err(cli::bad_input(format!(
            "--cameras and --cameras × --points-per-camera must be at most {MAX_SIZE} (and the \
             points at least 1), not {} and {} × {}",
            a.cameras, a.cameras, a.points_per_camera
        )));
    }
    if !((0.0..=1.0).contains(&a.outliers) && a.pixel_noise >= 0.0 && a.pixel_noise.is_finite()) {
        return Err(cli::bad_input(
            "--outliers must lie in [0, 1] and --pixel-noise be a finite non-negative number",
        ));
    }
    let s = bal_synthetic::generate(&bal_synthetic::SyntheticOptions {
        layout,
        cameras: a.cameras,
        points: a.cameras * a.points_per_camera,
        pixel_noise: a.pixel_noise,
        outlier_fraction: a.outliers,
        views: Some(views),
        seed: a.seed,
        ..Default::default()
    });
    bal::file::write(&a.out, &s.start)?;
    Ok(
        serde_json::json!({"kind": "bal", "out": a.out.display().to_string(), "cameras": a.cameras,
        "points": s.start.points.len(), "observations": s.start.observations.len(),
        "outliers": s.outlier.iter().filter(|&&b| b).count()}),
    )
}

/// `pose-graph`: generates (or reads) the graph, adds the wrong loops and writes it; the summary.
fn write_pose_graph(a: PoseGraphArgs) -> Result<serde_json::Value> {
    let poses = a.poses.unwrap_or(0).max(a.rings.saturating_mul(a.per_ring));
    if poses > MAX_POSES || a.false_loops > MAX_POSES {
        return Err(cli::bad_input(format!(
            "--poses (or --rings × --per-ring) and --false-loops must be at most {MAX_POSES}"
        )));
    }
    if a.poses.is_some_and(|n| n < 6) {
        return Err(cli::bad_input(format!(
            "--poses must be at least 6, not {}",
            a.poses.unwrap_or(0)
        )));
    }
    let mut graph = match &a.from {
        Some(path) => g2o::read(path).bad_input()?,
        None => generate_pose_graph(&a)?,
    };
    pg_synthetic::add_false_loops(&mut graph, a.false_loops, a.seed.wrapping_add(1));
    g2o::write(&a.out, &graph, &graph.vertices)?;
    Ok(
        serde_json::json!({"kind": "pose-graph", "out": a.out.display().to_string(),
        "shape": format!("{:?}", a.shape).to_lowercase(), "poses": graph.vertices.len(),
        "edges": graph.edges.len(), "false_loops": a.false_loops}),
    )
}

/// The generated graph of a layout.
fn generate_pose_graph(a: &PoseGraphArgs) -> Result<PoseGraph> {
    let rings = matches!(a.shape, Shape::Circle | Shape::Sphere);
    let noisy = a.measurements.unwrap_or(if rings {
        Measurements::Exact
    } else {
        Measurements::Noisy
    }) == Measurements::Noisy;
    let start = match a.start {
        StartKind::Perturbed => pg_synthetic::Start::Perturbed {
            rotation: 0.05,
            translation: 0.2,
        },
        StartKind::Odometry => pg_synthetic::Start::Odometry,
    };
    let noise = pg_synthetic::Noise {
        noisy,
        start,
        seed: a.seed,
        ..Default::default()
    };
    let dimension = if a.dim == 3 {
        Dimension::Three
    } else {
        Dimension::Two
    };
    let poses = a.poses.unwrap_or(10_000);
    let generated = match a.shape {
        Shape::Circle | Shape::Sphere => return ring_graph(a, noisy, start),
        Shape::City => pg_synthetic::city(&pg_synthetic::CityOptions {
            poses,
            dimension,
            noise,
            ..Default::default()
        }),
        Shape::Corridor => pg_synthetic::corridor(&pg_synthetic::CorridorOptions {
            poses,
            dimension,
            noise,
            ..Default::default()
        }),
    };
    Ok(generated.map_err(cli::bad_input)?.graph)
}

/// A circle or sphere of --rings × --per-ring poses, or of about --poses.
fn ring_graph(a: &PoseGraphArgs, noisy: bool, start: pg_synthetic::Start) -> Result<PoseGraph> {
    let (rings, per_ring) = match a.poses {
        Some(n) => {
            let per_ring = (n as f64).sqrt().round().max(3.0) as usize;
            (n.div_ceil(per_ring).max(2), per_ring)
        }
        None => (a.rings, a.per_ring),
    };
    if rings < 2 || per_ring < 3 {
        return Err(cli::bad_input(
            "--rings must be at least 2 and --per-ring at least 3",
        ));
    }
    let pg_synthetic::Start::Perturbed {
        rotation,
        translation,
    } = start
    else {
        return Err(cli::bad_input(
            "--start odometry is for city and corridor graphs",
        ));
    };
    let o = pg_synthetic::SyntheticOptions {
        rings,
        per_ring,
        rotation_noise: rotation,
        translation_noise: translation,
        noisy,
        seed: a.seed,
    };
    Ok(match a.shape {
        Shape::Sphere => pg_synthetic::sphere(&o).graph,
        _ => pg_synthetic::circle(&o).graph,
    })
}
