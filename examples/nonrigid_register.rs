//! Registers one surface onto another with the deformation graph and the warp-field optimiser.
//!
//! ```text
//! cargo run --release --example nonrigid_register                  # the thesis' grid experiment
//! cargo run --release --example nonrigid_register -- SOURCE TARGET --output WARPED.ply
//! ```
//! SOURCE and TARGET are meshes (PLY, OFF or OBJ). WARPED is the source mesh with its vertices (in
//! their order) and normals warped. Lengths default to fractions of the source's bounding-box
//! diagonal D: node spacing 0.03 D, association gate 0.1 D, Tukey's c 0.05 D. One JSON line last:
//! nodes, iterations, seconds, final data and regulariser costs.
//!
//! With no arguments: the thesis' experiment (sec. 4.5, Table 4.1), the flat 21 × 13 grid
//! registered onto five deformed copies (correspondences found by closest point, not given by
//! vertex index as in the thesis), with max, mean and σ of the vertex-to-ground-truth distance
//! before and after.

use anyhow::{bail, Context, Result};
use clap::Parser;
use dynamap::slam::io::{meshes::read_mesh, ply};
use dynamap::slam::nonrigid::{
    bounding_diagonal, clean_surface_settings, mesh_points, register_surfaces,
};
use dynamap::slam::synthetic::plate;
use std::path::PathBuf;

/// Non-rigid registration of one surface onto another.
#[derive(Parser, Debug)]
#[command(about)]
struct Args {
    /// The surface to move (mesh: .ply, .off or .obj). Without it, the thesis' grid experiment runs.
    source: Option<PathBuf>,
    /// The surface to move it onto.
    target: Option<PathBuf>,
    /// Where to write the warped source (binary PLY).
    #[arg(long)]
    output: Option<PathBuf>,
    /// Node spacing (default 0.03 D).
    #[arg(long)]
    spacing: Option<f64>,
    /// Regulariser weights, one stage each, largest first.
    #[arg(long, value_delimiter = ',')]
    schedule: Option<Vec<f64>>,
    /// Association rounds per stage.
    #[arg(long)]
    rounds: Option<usize>,
    /// Levenberg-Marquardt iterations per round.
    #[arg(long)]
    iterations: Option<usize>,
    /// Association distance gate (default 0.1 D).
    #[arg(long)]
    max_distance: Option<f64>,
    /// Association normal-angle gate, degrees.
    #[arg(long)]
    max_angle: Option<f64>,
    /// Weight of the point-to-point term beside point-to-plane.
    #[arg(long)]
    point_weight: Option<f64>,
}

/// Max, mean and standard deviation.
fn stats(d: &[f64]) -> (f64, f64, f64) {
    let n = d.len().max(1) as f64;
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    (d.iter().copied().fold(0.0, f64::max), mean, var.sqrt())
}

/// The thesis' experiment: prints one row per deformation.
fn grid_experiment() -> Result<()> {
    let source = plate::flat_grid();
    let (sp, sn) = mesh_points(&source);
    let (graph, params) = plate::registration_settings();
    println!(
        "{:<11} {:>9} {:>9} {:>9} | {:>9} {:>9} {:>9} | {:>5} {:>5} {:>7}",
        "target", "max", "mean", "sd", "max", "mean", "sd", "nodes", "iter", "seconds"
    );
    for def in plate::PlateDeformation::ALL {
        let target = def.deformed(&source);
        let (tp, tn) = mesh_points(&target);
        let before: Vec<f64> = sp.iter().zip(&tp).map(|(a, b)| (a - b).norm()).collect();
        let reg = register_surfaces((&sp, &sn), (&tp, &tn), graph, params.clone())?;
        let after: Vec<f64> = reg
            .points
            .iter()
            .zip(&tp)
            .map(|(a, b)| (a - b).norm())
            .collect();
        let (b, a) = (stats(&before), stats(&after));
        println!(
            "{:<11} {:>9.2e} {:>9.2e} {:>9.2e} | {:>9.2e} {:>9.2e} {:>9.2e} | {:>5} {:>5} {:>7.3}",
            def.name(),
            b.0,
            b.1,
            b.2,
            a.0,
            a.1,
            a.2,
            reg.graph.nodes.len(),
            reg.summary.iterations,
            reg.summary.seconds
        );
    }
    Ok(())
}

fn main() -> Result<()> {
    let args = Args::parse();
    let (Some(source_path), Some(target_path)) = (&args.source, &args.target) else {
        if args.source.is_some() {
            bail!("give both SOURCE and TARGET (or neither, for the grid experiment)");
        }
        return grid_experiment();
    };
    let source = read_mesh(source_path)?;
    let target = read_mesh(target_path)?;
    let (sp, sn) = mesh_points(&source);
    let (tp, tn) = mesh_points(&target);
    let (mut graph, mut params) = clean_surface_settings(bounding_diagonal(&sp));
    if let Some(s) = args.spacing {
        graph.spacing = s;
    }
    if let Some(s) = args.schedule {
        params.schedule = s;
    }
    if let Some(r) = args.rounds {
        params.rounds = r;
    }
    if let Some(i) = args.iterations {
        params.iterations = i;
    }
    if let Some(d) = args.max_distance {
        params.max_distance = d;
    }
    if let Some(a) = args.max_angle {
        params.max_normal_angle_deg = a;
    }
    if let Some(w) = args.point_weight {
        params.point_weight = w;
    }
    let reg = register_surfaces((&sp, &sn), (&tp, &tn), graph, params)
        .with_context(|| format!("registering {}", source_path.display()))?;
    if let Some(out) = &args.output {
        let mut warped = source.clone();
        warped.vertices = reg.points.iter().map(|p| p.cast::<f32>().into()).collect();
        warped.normals = reg.normals.iter().map(|n| n.cast::<f32>()).collect();
        ply::write(out, &warped)?;
    }
    println!(
        "{}",
        serde_json::json!({
            "nodes": reg.graph.nodes.len(),
            "iterations": reg.summary.iterations,
            "seconds": reg.summary.seconds,
            "data_cost": reg.summary.data_cost,
            "regulariser_cost": reg.summary.regulariser_cost,
            "matched": reg.summary.matched,
            "points": sp.len(),
        })
    );
    Ok(())
}
