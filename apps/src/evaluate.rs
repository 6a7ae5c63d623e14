//! Trajectory evaluation as evo computes it.
//!
//! ```text
//! cargo run --release --example evaluate -- ate GT.txt EST.txt [--align se3|sim3|none]
//! cargo run --release --example evaluate -- rpe GT.txt EST.txt [--delta 1 --delta-unit frames|seconds|meters]
//! cargo run --release --example evaluate -- mesh MESH.ply GT.txt EST.txt --layout room --seed 51
//! ```
//! Prints the statistics and, last, one JSON line (rmse, mean, median, max, pairs; for `mesh`,
//! the distances of the mesh's vertices to the generated scene's surface and the share off it).

use crate::cli;
use crate::flag_checks;
use crate::preview;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use cli::{InputError, Session};
use dynamap_slam::eval::{associate, ate, rpe, Alignment, DeltaUnit, MAX_STAMP_DIFFERENCE};
use dynamap_slam::io::ply;
use dynamap_slam::io::trajectory::Trajectory;
use dynamap_slam::synthetic::layouts::{self, Layout};
use dynamap_slam::synthetic::surface_error::surface_error;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Align {
    Se3,
    Sim3,
    None,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Unit {
    Frames,
    Seconds,
    Meters,
}

#[derive(Subcommand, Debug)]
enum Metric {
    /// Absolute trajectory error (translation, metres) after alignment.
    Ate {
        /// Ground truth (TUM format).
        gt: PathBuf,
        /// Estimate (TUM format).
        est: PathBuf,
        /// Alignment of the estimate onto the ground truth.
        #[arg(long, value_enum, default_value = "se3")]
        align: Align,
        /// Largest stamp difference for associating poses, seconds (evo's --t_max_diff).
        #[arg(long, visible_alias = "t-max-diff", default_value_t = MAX_STAMP_DIFFERENCE)]
        max_difference: f64,
        /// A folder for pictures: both trajectories from above, the per-frame error.
        #[arg(long, value_name = "DIR")]
        preview: Option<PathBuf>,
    },
    /// Relative pose error over intervals of --delta.
    Rpe {
        /// Ground truth (TUM format).
        gt: PathBuf,
        /// Estimate (TUM format).
        est: PathBuf,
        /// Interval length.
        #[arg(long, default_value_t = 1.0)]
        delta: f64,
        /// What --delta counts.
        #[arg(long, value_enum, default_value = "frames")]
        delta_unit: Unit,
        /// Largest stamp difference for associating poses, seconds (evo's --t_max_diff).
        #[arg(long, visible_alias = "t-max-diff", default_value_t = MAX_STAMP_DIFFERENCE)]
        max_difference: f64,
    },
    /// A mesh of a generated rigid sequence against its scene: each vertex's distance to the
    /// scene's surface along its normal, and the share farther than --tolerance (a wall fused
    /// twice shows as vertices off the surface). The mesh is taken into the scene's frame by the
    /// ground truth and the estimate at the first stamp they share.
    Mesh {
        /// The mesh (PLY), in the frame of the estimate.
        mesh: PathBuf,
        /// Ground truth of the sequence (TUM format).
        gt: PathBuf,
        /// The trajectory the mesh was made with (TUM format).
        est: PathBuf,
        /// The layout the sequence was generated with (room, bare, office, twins).
        #[arg(long)]
        layout: Layout,
        /// The seed it was generated with.
        #[arg(long)]
        seed: u64,
        /// How far along its normal a vertex looks for the surface, metres.
        #[arg(long, default_value_t = 0.05)]
        reach: f64,
        /// Farther than this from the surface, a vertex is off it, metres.
        #[arg(long, default_value_t = 0.01)]
        tolerance: f64,
        /// Largest stamp difference for associating poses, seconds.
        #[arg(long, default_value_t = MAX_STAMP_DIFFERENCE)]
        max_difference: f64,
    },
}

/// Evaluate a trajectory against ground truth.
#[derive(Parser, Debug)]
#[command(long_about = None)]
struct Args {
    #[command(subcommand)]
    metric: Metric,
    #[command(flatten)]
    common: cli::Common,
}

cli::has_common!(Args);

pub fn main() -> ExitCode {
    cli::run(run)
}

/// Both trajectories, read as bad input when they fail or hold no pose.
fn read_pair(gt: &std::path::Path, est: &std::path::Path) -> Result<(Trajectory, Trajectory)> {
    let read = |path: &std::path::Path| {
        let t = Trajectory::read_tum(path).bad_input()?;
        if t.is_empty() {
            return Err(cli::bad_input(format!("{}: no poses", path.display())));
        }
        Ok(t)
    };
    Ok((read(gt)?, read(est)?))
}

fn run(args: Args, session: &Session) -> Result<()> {
    let quiet = session.quiet;
    check_flags(&args.metric)?;
    match args.metric {
        Metric::Ate {
            gt,
            est,
            align,
            max_difference,
            preview,
        } => ate_of(&gt, &est, align, max_difference, preview.as_deref(), quiet)?,
        Metric::Rpe {
            gt,
            est,
            delta,
            delta_unit,
            max_difference,
        } => rpe_of(&gt, &est, delta, delta_unit, max_difference, quiet)?,
        Metric::Mesh {
            mesh,
            gt,
            est,
            layout,
            seed,
            reach,
            tolerance,
            max_difference,
        } => mesh_error(
            &mesh,
            (&gt, &est),
            (layout, seed),
            (reach, tolerance),
            max_difference,
            quiet,
        )?,
    }
    Ok(())
}

/// Refuses a stamp limit or an RPE interval that no pair of poses can meet (NaN, negative, or
/// an interval of zero), naming the flag, before the files are read.
fn check_flags(metric: &Metric) -> Result<()> {
    let max_difference = match metric {
        Metric::Ate { max_difference, .. }
        | Metric::Rpe { max_difference, .. }
        | Metric::Mesh { max_difference, .. } => *max_difference,
    };
    flag_checks::non_negative("--max-difference", max_difference)?;
    match metric {
        Metric::Rpe { delta, .. } => flag_checks::positive("--delta", *delta),
        _ => Ok(()),
    }
}

/// `evaluate ate`: prints the statistics (unless quiet) and the JSON line; `--preview` plots.
fn ate_of(
    gt: &Path,
    est: &Path,
    align: Align,
    max_difference: f64,
    preview: Option<&Path>,
    quiet: bool,
) -> Result<()> {
    let (g, e) = read_pair(gt, est)?;
    let a = match align {
        Align::Se3 => Alignment::Se3,
        Align::Sim3 => Alignment::Sim3,
        Align::None => Alignment::None,
    };
    let r = ate(&g, &e, a, max_difference)
        .map_err(anyhow::Error::msg)
        .bad_input()?;
    let s = r.stats;
    if !quiet {
        println!(
            "ATE (translation, m) over {} pose pairs, alignment {align:?} (scale {:.6})",
            r.pairs.len(),
            r.alignment.scale
        );
        println!(
            "  rmse {:.6}  mean {:.6}  median {:.6}  max {:.6}  min {:.6}  std {:.6}",
            s.rmse, s.mean, s.median, s.max, s.min, s.std
        );
    }
    if let Some(dir) = preview {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        preview::trajectory_plot(&dir.join("trajectory.png"), &e, Some((&g, &r)))?;
        preview::error_plot(&dir.join("error.png"), &g, &e, &r)?;
    }
    println!(
        "{}",
        serde_json::json!({"metric": "ate", "rmse": s.rmse, "mean": s.mean, "median": s.median, "max": s.max, "pairs": r.pairs.len()})
    );
    Ok(())
}

/// `evaluate rpe`: prints the statistics (unless quiet) and the JSON line.
fn rpe_of(
    gt: &Path,
    est: &Path,
    delta: f64,
    delta_unit: Unit,
    max_difference: f64,
    quiet: bool,
) -> Result<()> {
    let (g, e) = read_pair(gt, est)?;
    let u = match delta_unit {
        Unit::Frames => DeltaUnit::Frames,
        Unit::Seconds => DeltaUnit::Seconds,
        Unit::Meters => DeltaUnit::Meters,
    };
    let r = rpe(&g, &e, delta, u, max_difference)
        .map_err(anyhow::Error::msg)
        .bad_input()?;
    let (t, d) = (r.translation, r.rotation_deg);
    if !quiet {
        println!("RPE over {} intervals of {delta} {delta_unit:?}", t.count);
        println!(
            "  translation (m):  rmse {:.6}  mean {:.6}  median {:.6}  max {:.6}",
            t.rmse, t.mean, t.median, t.max
        );
        println!(
            "  rotation (deg):   rmse {:.6}  mean {:.6}  median {:.6}  max {:.6}",
            d.rmse, d.mean, d.median, d.max
        );
    }
    println!(
        "{}",
        serde_json::json!({"metric": "rpe", "rmse": t.rmse, "mean": t.mean, "median": t.median, "max": t.max, "pairs": t.count,
            "rotation_deg": {"rmse": d.rmse, "mean": d.mean, "median": d.median, "max": d.max}})
    );
    Ok(())
}

/// `evaluate mesh`: the mesh at `path` against the scene of `layout` and `seed`.
fn mesh_error(
    path: &std::path::Path,
    (gt, est): (&std::path::Path, &std::path::Path),
    (layout, seed): (Layout, u64),
    (reach, tolerance): (f64, f64),
    max_difference: f64,
    quiet: bool,
) -> Result<()> {
    if !(reach > 0.0 && tolerance > 0.0) {
        return Err(cli::bad_input("--reach and --tolerance must be positive"));
    }
    let (g, e) = read_pair(gt, est)?;
    let Some(&(i, j)) = associate(&g, &e, max_difference).first() else {
        return Err(cli::bad_input(format!(
            "{} and {} share no stamp within {max_difference} s",
            gt.display(),
            est.display()
        )));
    };
    let to_scene = g.poses[i] * e.poses[j].inverse();
    let mesh = ply::read(path).bad_input()?;
    let scene = layouts::build(layout, seed);
    let r = surface_error(&mesh, &scene.prepare(), &to_scene, reach, tolerance);
    if r.vertices == 0 {
        return Err(cli::bad_input(format!(
            "{}: no vertex with a normal to measure",
            path.display()
        )));
    }
    let d = r.distances.as_ref();
    if !quiet {
        println!(
            "{} vertices measured, {} off the surface by more than {tolerance} m ({:.2} %), {} find no surface within {reach} m",
            r.vertices,
            r.off,
            100.0 * r.off_fraction(),
            r.unmatched
        );
        if let Some(d) = d {
            println!(
                "  distance (m): rmse {:.6}  mean {:.6}  median {:.6}  max {:.6}",
                d.rmse, d.mean, d.median, d.max
            );
        }
    }
    println!(
        "{}",
        serde_json::json!({"metric": "mesh", "vertices": r.vertices, "off": r.off, "off_fraction": r.off_fraction(),
            "unmatched": r.unmatched, "rmse": d.map(|d| d.rmse), "mean": d.map(|d| d.mean),
            "median": d.map(|d| d.median), "max": d.map(|d| d.max)})
    );
    Ok(())
}
