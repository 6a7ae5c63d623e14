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

#[path = "common/warp_flags.rs"]
mod warp_flags;

use anyhow::{bail, Context, Result};
use clap::Parser;
use dynamap::slam::eval::Stats;
use dynamap::slam::io::{meshes::read_mesh, ply};
use dynamap::slam::nonrigid::{
    bounding_diagonal, clean_surface_settings, mesh_points, register_surfaces,
};
use dynamap::slam::synthetic::plate;
use nalgebra::Vector3;
use std::path::PathBuf;
use warp_flags::WarpFlags;

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
    /// Graph and optimiser settings (defaults scale with the source's bounding-box diagonal D:
    /// spacing 0.03 D, distance gate 0.1 D).
    #[command(flatten)]
    warp: WarpFlags,
    /// Also start the rigid pre-alignment from the principal-axes alignments (for shapes far apart).
    #[arg(long)]
    principal_axes: bool,
    /// A ground-truth vertex map (line k: the index on TARGET of SOURCE's vertex k, as in the camel
    /// data's maps/i_to_j): adds the mean and 95th percentile of |warped − partner| before and after,
    /// as fractions of TARGET's bounding-box diagonal, to the JSON. Entries pointing at a vertex that
    /// over 1 % of the source points at are placeholders for "no partner" and are not scored.
    #[arg(long)]
    ground_truth: Option<PathBuf>,
}

/// Reads a vertex map of `n` lines, each an index below `targets`.
fn read_map(path: &std::path::Path, n: usize, targets: usize) -> Result<Vec<usize>> {
    let text = dynamap::slam::io::read_text(path)?;
    let map = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| match l.trim().parse::<usize>() {
            Ok(k) if k < targets => Ok(k),
            _ => bail!(
                "{}:{}: '{}' is not a vertex index below {targets}",
                path.display(),
                i + 1,
                l.trim()
            ),
        })
        .collect::<Result<Vec<_>>>()?;
    if map.len() != n {
        bail!(
            "{}: {} lines for {n} source vertices",
            path.display(),
            map.len()
        );
    }
    Ok(map)
}

/// The map entries to score: all but those pointing at a vertex that more than 1 % of the source's
/// vertices point at (the camel maps send their unmatched vertices, about 7 %, to one vertex).
fn scored_entries(map: &[usize], targets: usize) -> Vec<bool> {
    let mut count = vec![0usize; targets];
    for &k in map {
        count[k] += 1;
    }
    map.iter().map(|&k| count[k] * 100 <= map.len()).collect()
}

/// Mean and 95th percentile of the distances from the scored `points` to their partners, over
/// `scale`.
fn map_error(
    points: &[Vector3<f64>],
    partners: &[Vector3<f64>],
    map: &[usize],
    scored: &[bool],
    scale: f64,
) -> (f64, f64) {
    let mut d: Vec<f64> = points
        .iter()
        .zip(map)
        .zip(scored)
        .filter(|(_, &s)| s)
        .map(|((p, &k), _)| (p - partners[k]).norm() / scale)
        .collect();
    d.sort_by(f64::total_cmp);
    let mean = d.iter().sum::<f64>() / d.len().max(1) as f64;
    (
        mean,
        d.get((0.95 * d.len() as f64) as usize)
            .copied()
            .unwrap_or(0.0),
    )
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
        let reg = register_surfaces((&sp, &sn), (&tp, &tn), graph, params.clone(), true)?;
        let after: Vec<f64> = reg
            .points
            .iter()
            .zip(&tp)
            .map(|(a, b)| (a - b).norm())
            .collect();
        let (b, a) = (Stats::of(&before), Stats::of(&after));
        println!(
            "{:<11} {:>9.2e} {:>9.2e} {:>9.2e} | {:>9.2e} {:>9.2e} {:>9.2e} | {:>5} {:>5} {:>7.3}",
            def.name(),
            b.max,
            b.mean,
            b.std,
            a.max,
            a.mean,
            a.std,
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
    args.warp.apply(&mut graph, &mut params)?;
    let map = match &args.ground_truth {
        Some(p) => Some(read_map(p, sp.len(), tp.len())?),
        None => None,
    };
    let reg = register_surfaces((&sp, &sn), (&tp, &tn), graph, params, args.principal_axes)
        .with_context(|| format!("registering {}", source_path.display()))?;
    if let Some(out) = &args.output {
        let mut warped = source.clone();
        warped.vertices = reg.points.iter().map(|p| p.cast::<f32>().into()).collect();
        warped.normals = reg.normals.iter().map(|n| n.cast::<f32>()).collect();
        ply::write(out, &warped)?;
    }
    let mut json = serde_json::json!({
            "nodes": reg.graph.nodes.len(),
            "iterations": reg.summary.iterations,
            "seconds": reg.summary.seconds,
            "data_cost": reg.summary.data_cost,
            "regulariser_cost": reg.summary.regulariser_cost,
            "matched": reg.summary.matched,
            "points": sp.len(),
    });
    if let Some(map) = &map {
        let d = bounding_diagonal(&tp);
        let scored = scored_entries(map, tp.len());
        let (b_mean, b_p95) = map_error(&sp, &tp, map, &scored, d);
        let (a_mean, a_p95) = map_error(&reg.points, &tp, map, &scored, d);
        json["scored_vertices"] = scored.iter().filter(|&&s| s).count().into();
        json["error_before"] = serde_json::json!({"mean": b_mean, "p95": b_p95});
        json["error_after"] = serde_json::json!({"mean": a_mean, "p95": a_p95});
    }
    println!("{json}");
    Ok(())
}
