//! Registers one surface onto another with the deformation graph and the warp-field optimiser.
//!
//! ```text
//! cargo run --release --example nonrigid_register                  # the thesis' grid experiment
//! cargo run --release --example nonrigid_register -- meshes SOURCE TARGET --output WARPED.ply
//! cargo run --release --example nonrigid_register -- frames D0.png D1.png --intrinsics FX FY CX CY \
//!     --depth-scale S [--mask M.png | --mask-nodes NODES.bin] [--color C0] [--target-color C1] \
//!     [--flow F.sflow] [--picture P.png]
//! cargo run --release --example nonrigid_register -- sheets [--sizes 0.1 0.5 2] [--remeshed | --target-mesh FLAT.off]
//! ```
//! `meshes`: SOURCE and TARGET are meshes (PLY, OFF or OBJ). WARPED is the source mesh with its
//! vertices (in their order) and normals warped. Lengths default to fractions of the source's
//! bounding-box diagonal D (of the vertices its faces use; a stray vertex no face uses does not
//! count, `surface_diagonal`): node spacing 0.03 D, association gate 0.1 D, Tukey's c 0.05 D.
//! Meshes are registered in a first pass by closest point and then in passes seeded by geodesic
//! descriptors to the core and the extremities (`register_meshes`, NOTES 47, 48 and 102);
//! `--seeded-passes 0` registers by closest point alone. In every round a target point farther
//! than `--cover` source point spacings from the warped source pulls the nearest warped point
//! (NOTES 101; 0 turns it off). One JSON line last: nodes, iterations, seconds, final data and
//! regulariser costs, and whether it `registered` (`fit`: the shares of the warped source within
//! a node spacing of the target and of the target covered, at least half each, the share of the
//! former facing the target's way, at least 0.8, and the source's area at rest and warped over
//! the target's, each within 1.5× of 1; a warning says which failed), and whether the target's
//! normals were turned to point the source's way (`target_normals_turned`, NOTES 140). Where the
//! fit registered and neither mesh slides along itself (`slippage`, NOTES 179), the target is
//! registered back onto the source at the same time, and `round_trip` gives the mean distance
//! at which a source point comes back (`error`), how far it moved (`moved`) and their `ratio`:
//! over 0.35 the surfaces do not fix where the points go, and it is not registered (module
//! `round_trip`, NOTES 188); `seconds` counts both ways. Where it registered and the way back
//! lies closer to its target (data cost per point), WARPED holds the source where the way back
//! placed it (`placed_back`, NOTES 189). Where it registered, a rigid motion or else a global
//! affine map (no direction stretched more than twice; for an open mesh, only one that lays every
//! vertex within a tenth of the node spacing, NOTES 199), each fitted by point-to-plane closest
//! point, that lays the source on the target at least as closely as the warp is taken: WARPED holds
//! the source carried by it and the round trip is not run (`placed_rigid`, `placed_affine`, NOTES
//! 195 and 197). `affine_slippage` gives the share of each mesh's least-constrained affine motion
//! that moves it off itself and the answer's `departure_from_rigid` (root mean square, in the
//! meshes' unit): where a mesh slides along itself under a stretch (under 1e-3: an ellipsoid, a
//! stretched torus) and the answer departs from rigid by more than `rigid_limit` (a tenth of the
//! node spacing), the same answer stretched along the surface fits as well, and it is not
//! registered (NOTES 197). The rigid motion is fitted from five starts (the centroids, and the four
//! turns that put the source's principal axes onto the target's) and the affine map from six (the
//! centroids, and each rigid motion; where a mesh is open, from the four stretches that put the
//! source's principal axes and spreads onto the target's and, for a flat sheet, the two closest of
//! 144 turns of its whitened plane, refined point to point, judged on nine tenths of the distances,
//! and one that fits but is not exact is set against the warp like a second map); where more than
//! one of the kind taken lays the source as closely as the warp, `maps_apart` gives how far apart
//! they carry it (`apart`, root mean square) and the `limit` (a tenth of the node spacing) within
//! which they are one map: further apart, as a box or an ellipsoid turned onto itself is, a box
//! whose faces a stretch exchanges, or a flat sheet stretched, none is taken and it is not
//! registered (NOTES 198–199). A point cloud (no faces) must carry its normals. A mesh
//! without normals has them computed from its triangles after those wound against their
//! neighbours are turned over (`faces_turned`, per mesh, with a warning; NOTES 141). A
//! registration that did not register writes its outputs and JSON line, then exits 1 (NOTES
//! 173).
//!
//! `frames`: two RGB-D frames, each a depth PNG read with `--intrinsics fx fy cx cy --depth-scale
//! S`, its object selected by `--mask M.png` (source) and `--target-mask M.png`, its colour given
//! by `--color C` and `--target-color C` (with both colours, FAST/BRIEF matches give the rigid
//! start). WARPED holds the source's valid pixels in row-major order, `--flow FLOW.sflow` writes
//! their scene flow in DeepDeform's format, and `--flow-ground-truth GT.sflow` scores it (EPE 3D).
//! Without a mask, `--mask-nodes` takes the source's object from DeepDeform's graph nodes (its
//! test pairs come so). The JSON gives the median distance from the source's points to the
//! target's (inside its mask), before and after, and with `--flow-ground-truth` after the true
//! flow (`ground_truth`: the floor the depth's noise leaves); `--picture` draws both. As with
//! `meshes`, a pair that did not register exits 1 after its outputs and JSON line.
//!
//! `sheets`: plain sheets, no correspondence given, onto bent, rolled, folded, twisted and saddled
//! copies, alone and moved rigidly, at `--sizes` widths and `--columns` resolutions (issue 26):
//! one row per case with the largest and mean vertex error as % of the largest displacement.
//! The targets are the source's grid, the grid meshed apart (`--remeshed`), or a flat mesh of the
//! user's (`--target-mesh`).
//!
//! `grid`, or no subcommand: the thesis' experiment (sec. 4.5, Table 4.1), the flat 21 × 13 grid
//! registered onto five deformed copies (correspondences found by closest point, not given by
//! vertex index as in the thesis), with max, mean and σ of the vertex-to-ground-truth distance
//! before and after.

use crate::cli;
use crate::flag_checks;
use crate::preview::registration_picture;
use crate::warp_flags;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use cli::{InputError, Session};
use dynamap_slam::camera::Camera;
use dynamap_slam::eval::{flow_scores, EpeResult, FlowScores, Stats, VertexMap};
use dynamap_slam::image::{depth_to_metres, ColorImage, DepthImage, Image};
use dynamap_slam::io::deepdeform::read_graph_nodes;
use dynamap_slam::io::flow::{read_flow, write_flow};
use dynamap_slam::io::images::{read_color, read_depth, read_mask, write_color};
use dynamap_slam::io::{
    meshes::{read_mesh, read_mesh_oriented},
    ply,
};
use dynamap_slam::mesh::Mesh;
use dynamap_slam::nonrigid::{
    clean_surface_settings, frame_points, mask_near_nodes, median_distance, mesh_points,
    register_frames, register_mesh_or_cloud, register_mesh_pair, register_surfaces,
    surface_diagonal, AffineSlide, FrameError, FrameSettings, FrameVerdict, FrameView,
    RegisterSummary, RoundTrip, Seeding, Slippage, SurfaceMesh, SurfaceRegistration,
    SurfaceVerdict, MAX_AFFINE_SLIPPAGE, MAX_FLUSH_FRACTION, MAX_OFF_FRACTION, MAX_ROUND_TRIP,
    MAX_SLIPPAGE, MIN_MATCHED_FRACTION,
};
use dynamap_slam::nonrigid::{MeshRole, SurfaceError, AREA_FACTOR, MIN_FACING, MIN_SHARE};
use dynamap_slam::synthetic::plate;
use dynamap_slam::synthetic::sheet::{self, SheetDeformation, SheetScore};
use nalgebra::Vector3;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use warp_flags::WarpFlags;

mod frame_flags;
mod pairs;

/// Non-rigid registration of one surface onto another.
#[derive(Parser, Debug)]
#[command(long_about = None)]
struct Args {
    /// What to register; without a subcommand, the thesis' grid experiment.
    #[command(subcommand)]
    mode: Option<Mode>,
    #[command(flatten)]
    common: cli::Common,
}

/// The three inputs, each with its own flags.
#[derive(Subcommand, Debug)]
enum Mode {
    /// The thesis' experiment (sec. 4.5, Table 4.1): the flat 21 × 13 grid onto five deformed
    /// copies, one table row each (the default).
    Grid,
    /// One mesh onto another (PLY, OFF or OBJ); lengths scale with the source's bounding-box
    /// diagonal D.
    Meshes(MeshArgs),
    /// One RGB-D frame (a depth PNG) onto another: warped points, scene flow and its EPE.
    Frames(Box<FrameArgs>),
    /// Plain sheets (no correspondences given) onto bent, rolled, folded, twisted and saddled
    /// copies, alone and moved rigidly, at several sizes and mesh resolutions (issue 26).
    Sheets(SheetArgs),
    /// Generated frame pairs (a plate, a cylinder and a ball, bent, twisted and rippled, seen from
    /// cameras apart) registered as `frames` does: EPE 3D per pair and the mean.
    Pairs(pairs::PairArgs),
}

/// `sheets`: which sizes and meshes.
#[derive(clap::Args, Debug)]
struct SheetArgs {
    /// Sheet widths, metres.
    #[arg(long, num_args = 1.., default_values_t = [0.1, 0.5, 2.0])]
    sizes: Vec<f64>,
    /// Vertices along the sheet's width (its height gets 0.6 × as many, rounded).
    #[arg(long, num_args = 1.., default_values_t = [21, 41])]
    columns: Vec<usize>,
    /// The rigid motion's shift, metres.
    #[arg(long, default_value_t = 0.03)]
    shift: f64,
    /// The rigid motion's turn, degrees.
    #[arg(long, default_value_t = 15.0)]
    turn: f64,
    /// Each deformation's amount as a multiple of the issue's largest (1: an S of 69°, a roll of
    /// 180°, a fold of 90°, a twist of 0.8 rad, a saddle 0.15 of the width high).
    #[arg(long, default_value_t = 1.0)]
    amount: f64,
    /// Mesh each target apart from its source: 1.4 × the columns and rows, its inner vertices
    /// moved at random by up to 0.3 of their spacing (seeded), so that no vertex has a copy.
    #[arg(long)]
    remeshed: bool,
    /// Make every target from this flat mesh instead of the grid (.ply, .off or .obj): a sheet in
    /// the plane z = 0 whose outline is a W × 0.6 W rectangle, at any size and position (it is
    /// centred and scaled to each width). For meshings made elsewhere, such as a Delaunay
    /// triangulation of scattered points.
    #[arg(long, value_name = "FILE", conflicts_with = "remeshed")]
    target_mesh: Option<PathBuf>,
}

/// `meshes`: the inputs and the flags that apply to meshes.
#[derive(clap::Args, Debug)]
struct MeshArgs {
    /// The mesh to move (.ply, .off or .obj).
    source: PathBuf,
    /// The mesh to move it onto.
    target: PathBuf,
    /// Where to write the warped source (binary PLY: its vertices in their order, and normals).
    #[arg(long)]
    output: Option<PathBuf>,
    /// Graph and optimiser settings.
    #[command(flatten)]
    warp: WarpFlags,
    /// Also start the rigid pre-alignment from the principal-axes alignments (for shapes far apart).
    #[arg(long)]
    principal_axes: bool,
    /// Passes after the first that start from geodesic-descriptor correspondences (anchors on
    /// the core placed by the pass before), which keep parts that swing past each other apart
    /// (legs); 0 registers in one pass by closest point only. Point clouds (no triangles) have no
    /// surface distances and are always registered in one pass.
    #[arg(long, value_name = "N")]
    seeded_passes: Option<usize>,
    /// A ground-truth vertex map (line k: the index on TARGET of SOURCE's vertex k, as in the camel
    /// data's maps/i_to_j): adds the mean and 95th percentile of |warped − partner| before and after,
    /// as fractions of TARGET's bounding-box diagonal (of the vertices its faces use), to the JSON.
    /// Entries pointing at a vertex that over 1 % of the source points at are placeholders for "no
    /// partner" and are not scored.
    #[arg(long)]
    ground_truth: Option<PathBuf>,
}

/// `frames`: the inputs and the flags that apply to RGB-D frames.
#[derive(clap::Args, Debug)]
struct FrameArgs {
    /// The frame to move: its depth image (.png).
    source: PathBuf,
    /// The frame to move it onto: its depth image (.png).
    target: PathBuf,
    /// Intrinsics of both frames: fx fy cx cy (pixels; a negative focal length mirrors its axis).
    #[arg(long, required = true, num_args = 4, value_names = ["FX", "FY", "CX", "CY"],
          allow_negative_numbers = true)]
    intrinsics: Vec<f64>,
    /// Depth units per metre (e.g. 1000 for millimetres).
    #[arg(long, required = true)]
    depth_scale: f64,
    /// The object's pixels in the source frame (non-zero = object).
    #[arg(long)]
    mask: Option<PathBuf>,
    /// The source's object from DeepDeform's graph nodes (`graph_nodes/*.bin`, source camera
    /// frame): the pixels within one node spacing (--spacing) of a node; instead of --mask.
    #[arg(long, conflicts_with = "mask")]
    mask_nodes: Option<PathBuf>,
    /// The object's pixels in the target frame.
    #[arg(long)]
    target_mask: Option<PathBuf>,
    /// The source frame's colour image (with --target-color: feature matches start the fit).
    #[arg(long)]
    color: Option<PathBuf>,
    /// The target frame's colour image.
    #[arg(long)]
    target_color: Option<PathBuf>,
    /// Where to write the source pixels' scene flow (DeepDeform .sflow).
    #[arg(long)]
    flow: Option<PathBuf>,
    /// Ground-truth scene flow (.sflow) to score ours against: EPE 3D in the JSON.
    #[arg(long)]
    flow_ground_truth: Option<PathBuf>,
    /// Where to write the warped source: its valid pixels in row-major order (binary PLY).
    #[arg(long)]
    output: Option<PathBuf>,
    /// Where to draw the pair (PNG, two panels): the target in grey with the source (red,
    /// before) and the warped source (blue, after).
    #[arg(long)]
    picture: Option<PathBuf>,
    /// How the frames are registered.
    #[command(flatten)]
    registration: frame_flags::FrameFlags,
}

cli::has_common!(Args);

/// The thesis' experiment: prints one row per deformation.
fn grid_experiment(session: &Session) -> Result<()> {
    let source = plate::flat_grid();
    let (sp, sn) = mesh_points(&source);
    let (graph, params) = plate::registration_settings();
    let bar = session.progress(plate::PlateDeformation::ALL.len() as u64, "targets");
    let row = |line: String| bar.suspend(|| println!("{line}"));
    row(format!(
        "{:<11} {:>9} {:>9} {:>9} | {:>9} {:>9} {:>9} | {:>5} {:>5} {:>7}",
        "target", "max", "mean", "sd", "max", "mean", "sd", "nodes", "iter", "seconds"
    ));
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
        bar.inc(1);
        row(format!(
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
        ));
    }
    Ok(())
}

/// The most vertices along a sheet's width: 1001 × 601, some 600 000 vertices (401 took 27 s
/// and 0.2 GB a case); 100 000 columns were killed for memory at 23 GB.
const MAX_COLUMNS: usize = 1001;

/// Issue 26's sheets: one row per case, size and mesh, with the largest and mean vertex error
/// as a share of the largest displacement.
fn sheet_experiment(args: &SheetArgs, session: &Session) -> Result<()> {
    if args.sizes.iter().any(|s| !(s.is_finite() && *s > 0.0))
        || ![args.shift, args.turn, args.amount]
            .iter()
            .all(|v| v.is_finite())
    {
        return Err(cli::bad_input(
            "--sizes must be positive, and --shift, --turn and --amount finite",
        ));
    }
    if args
        .columns
        .iter()
        .any(|&c| !(3..=MAX_COLUMNS).contains(&c))
    {
        return Err(cli::bad_input(format!(
            "--columns must lie between 3 and {MAX_COLUMNS}"
        )));
    }
    let flat = args
        .target_mesh
        .as_deref()
        .map(flat_sheet_file)
        .transpose()?;
    let cases = SheetDeformation::cases(args.amount, args.turn, args.shift);
    let total = cases.len() * args.sizes.len() * args.columns.len();
    let bar = session.progress(total as u64, "cases");
    let row = |line: String| bar.suspend(|| println!("{line}"));
    row(format!(
        "{:<18} {:>6} {:>7} {:>9} | {:>8} {:>8} | {:>5} {:>7} {:>10}",
        "case", "width", "mesh", "max disp", "max %", "mean %", "nodes", "seconds", "registered"
    ));
    let (mut worst_max, mut worst_mean) = (0.0f64, 0.0f64);
    for &columns in &args.columns {
        let rows = ((columns - 1) as f64 * 0.6).round() as usize + 1;
        for &width in &args.sizes {
            let source = sheet::flat_sheet(columns, rows, width);
            let target_sheet = if let Some(flat) = &flat {
                scaled_sheet(flat, width)
            } else if args.remeshed {
                let (c, r) = (columns * 7 / 5, rows * 7 / 5);
                sheet::jittered(sheet::flat_sheet(c, r, width), c, r, 0.3, 7)
            } else {
                source.clone()
            };
            for case in &cases {
                let (score, reg) = register_sheet(&source, &target_sheet, case, width)?;
                worst_max = worst_max.max(score.max);
                worst_mean = worst_mean.max(score.mean);
                bar.inc(1);
                let name = format!(
                    "{}{}",
                    case.shape.name(),
                    if case.rigid.is_some() { " +rigid" } else { "" }
                );
                row(format!(
                    "{:<18} {:>6} {:>7} {:>9.4} | {:>8.2} {:>8.2} | {:>5} {:>7.3} {:>10}",
                    name,
                    width,
                    format!("{columns}x{rows}"),
                    score.displacement,
                    100.0 * score.max,
                    100.0 * score.mean,
                    reg.graph.nodes.len(),
                    reg.summary.seconds,
                    if reg.verdict() == SurfaceVerdict::Registered {
                        "yes"
                    } else {
                        "no"
                    }
                ));
            }
        }
    }
    row(format!(
        "worst: max {:.2} %, mean {:.2} % of the largest displacement",
        100.0 * worst_max,
        100.0 * worst_mean
    ));
    Ok(())
}

/// The flat sheet of `--target-mesh`, centred on the origin and scaled to width 1; an error
/// naming the file unless it is a mesh of triangles in a plane z = constant whose bounding box
/// is W × 0.6 W (that its outline fills the box is the user's to say: another outline finds no
/// rim to align by and scores far off).
fn flat_sheet_file(path: &Path) -> Result<Mesh> {
    let mut mesh = read_mesh(path).bad_input()?;
    let (lo, hi) = mesh.vertices.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), v| {
            let v = v.coords.cast::<f64>();
            (lo.inf(&v), hi.sup(&v))
        },
    );
    let extent = hi - lo;
    let flat = extent.x > 0.0 && extent.z <= 1e-6 * extent.x;
    let outline = (extent.y / extent.x - 0.6).abs() <= 0.01;
    if mesh.faces.is_empty() || !flat || !outline {
        return Err(cli::bad_input(format!(
            "{}: --target-mesh must be a flat sheet (z constant) of triangles whose outline is a \
             W × 0.6 W rectangle; its extent is {:.4} × {:.4} × {:.4}",
            path.display(),
            extent.x,
            extent.y,
            extent.z
        )));
    }
    let centre = (lo + hi) / 2.0;
    for v in &mut mesh.vertices {
        *v = ((v.cast::<f64>() - centre) / extent.x).cast::<f32>();
    }
    mesh.compute_normals();
    Ok(mesh)
}

/// The unit-width `flat` sheet at width `width`.
fn scaled_sheet(flat: &Mesh, width: f64) -> Mesh {
    let mut mesh = flat.clone();
    for v in &mut mesh.vertices {
        *v = (v.cast::<f64>() * width).cast::<f32>();
    }
    mesh
}

/// Registers the flat `source` (width `width`) onto `case` of the flat `target` with
/// [`register_mesh_pair`] and scores every vertex against where the case sends it; with the
/// registration.
fn register_sheet(
    source: &Mesh,
    target: &Mesh,
    case: &SheetDeformation,
    width: f64,
) -> Result<(SheetScore, SurfaceRegistration)> {
    let deformed = case.deformed(target, width);
    let reg = register_mesh_pair(source, &deformed, &Seeding::default())?;
    let score = case.score(source, &reg.points, width);
    Ok((score, reg))
}

/// The JSON line's common part: nodes, iterations, seconds, final costs, matched and source points.
fn summary_json(nodes: usize, summary: &RegisterSummary, points: usize) -> serde_json::Value {
    serde_json::json!({
        "nodes": nodes,
        "iterations": summary.iterations,
        "seconds": summary.seconds,
        "data_cost": summary.data_cost,
        "regulariser_cost": summary.regulariser_cost,
        "matched": summary.matched,
        "points": points,
    })
}

/// One RGB-D frame as read: its camera, depth in metres, optional colour and mask.
struct FrameFiles {
    camera: Camera,
    depth: DepthImage,
    color: Option<ColorImage>,
    mask: Option<Image<bool>>,
}

impl FrameFiles {
    fn frame(&self) -> FrameView<'_> {
        FrameView::new(
            &self.camera,
            &self.depth,
            self.color.as_ref(),
            self.mask.as_ref(),
        )
    }
}

/// Reads one RGB-D frame: depth (metres) and the camera, optional colour and mask.
fn read_frame(
    args: &FrameArgs,
    depth: &Path,
    color: Option<&PathBuf>,
    mask: Option<&PathBuf>,
) -> Result<FrameFiles> {
    let (k, scale) = (&args.intrinsics, args.depth_scale);
    let raw = read_depth(depth)?;
    let mut camera = Camera::new(k[0], k[1], k[2], k[3], raw.width, raw.height);
    camera.depth_scale = scale;
    let mut metres = Image::new(0, 0);
    depth_to_metres(&raw, &camera, &mut metres);
    let color = color.map(read_color).transpose()?;
    let mask = mask.map(read_mask).transpose()?;
    Ok(FrameFiles {
        camera,
        depth: metres,
        color,
        mask,
    })
}

/// The ground-truth flow of `--flow-ground-truth`, checked against the source frame's size.
fn read_ground_truth_flow(path: &Path, camera: &Camera) -> Result<Image<[f32; 3]>> {
    let gt: Image<[f32; 3]> = read_flow(path).bad_input()?;
    if (gt.width, gt.height) != (camera.width, camera.height) {
        return Err(cli::bad_input(format!(
            "{}: a {}×{} flow for a {}×{} source frame",
            path.display(),
            gt.width,
            gt.height,
            camera.width,
            camera.height
        )));
    }
    Ok(gt)
}

/// A frame registration's error: bad input (exit code 2) for frames of another size than their
/// camera or no depth in the mask, which are what the user gave; a runtime failure otherwise.
fn input_or_failure(e: FrameError) -> anyhow::Error {
    match e {
        FrameError::Size { .. } | FrameError::NoPoints => cli::bad_input(e),
        e => e.into(),
    }
}

impl FrameArgs {
    /// Refuses intrinsics no camera has and output paths that could not be written, before the
    /// frames are read.
    fn check(&self) -> Result<()> {
        let k = &self.intrinsics;
        flag_checks::intrinsics([
            ("--intrinsics FX", Some(k[0])),
            ("--intrinsics FY", Some(k[1])),
            ("--intrinsics CX", Some(k[2])),
            ("--intrinsics CY", Some(k[3])),
        ])?;
        flag_checks::positive("--depth-scale", self.depth_scale)?;
        let files = [
            ("--output", self.output.as_deref()),
            ("--flow", self.flow.as_deref()),
            ("--picture", self.picture.as_deref()),
        ];
        cli::check_outputs(&files, &[])
    }
}

/// Registers one RGB-D frame onto another, writes the warped points and the scene flow, scores the
/// flow against ground truth, and prints the JSON line.
fn register_frame_pair(args: &FrameArgs) -> Result<()> {
    args.check()?;
    let mut source =
        read_frame(args, &args.source, args.color.as_ref(), args.mask.as_ref()).bad_input()?;
    let target = read_frame(
        args,
        &args.target,
        args.target_color.as_ref(),
        args.target_mask.as_ref(),
    )
    .bad_input()?;
    let settings = args.registration.settings()?;
    if let Some(path) = &args.mask_nodes {
        let nodes = read_graph_nodes(path).bad_input()?;
        let (camera, radius) = (&source.camera, settings.graph.spacing);
        source.mask = Some(mask_near_nodes(camera, &source.depth, &nodes, radius));
    }
    let gt = args
        .flow_ground_truth
        .as_deref()
        .map(|p| read_ground_truth_flow(p, &source.camera))
        .transpose()?;
    let reg = register_frames(&source.frame(), &target.frame(), &settings)
        .map_err(input_or_failure)
        .with_context(|| format!("registering {}", args.source.display()))?;
    let flow = reg.scene_flow(source.camera.width, source.camera.height);
    if let Some(out) = &args.output {
        let cloud = Mesh {
            vertices: reg.warped.iter().map(|p| p.cast::<f32>().into()).collect(),
            normals: reg.normals.iter().map(|n| n.cast::<f32>()).collect(),
            ..Mesh::default()
        };
        ply::write(out, &cloud)?;
    }
    if let Some(out) = &args.flow {
        write_flow(out, &flow)?;
    }
    let surface = frame_points(&target.frame());
    if let Some(out) = &args.picture {
        let picture = registration_picture(&source.camera, &surface, &reg.points, &reg.warped);
        write_color(out, &picture)?;
    }
    let mut json = summary_json(reg.graph.nodes.len(), &reg.summary, reg.points.len());
    json["data_points"] = reg.data_points.into();
    json["feature_matches"] = serde_json::json!(reg.matches.as_ref().map(|m| serde_json::json!({
        "keypoints": [m.keypoints.0, m.keypoints.1],
        "matches": m.matches,
        "inliers": m.source.len(),
    })));
    json["start"] = reg.start.name().into();
    let verdict = reg.verdict();
    json["registered"] = verdict_json(verdict);
    json["colour_check"] = serde_json::json!(reg.colour.map(|c| serde_json::json!({
        "aligned": c.aligned,
        "off": c.off,
        "flat": c.flat,
        "floor": c.floor,
        "correlation": c.correlation,
        "contrast": c.contrast,
    })));
    json["outline_check"] = serde_json::json!(reg.outline.map(|o| serde_json::json!({
        "outline": o.outline,
        "seen": o.seen,
        "flush": o.flush,
    })));
    json["surface_distance"] = serde_json::json!({
        "before": median_distance(&reg.points, &surface),
        "after": median_distance(&reg.warped, &surface),
        "target_points": surface.len(),
    });
    if let (Some(gt), Some(path)) = (&gt, &args.flow_ground_truth) {
        let scores = flow_scores(&flow, gt, source.mask.as_ref()).ok_or_else(|| {
            cli::bad_input(format!(
                "{}: no pixel has a finite ground-truth flow",
                path.display()
            ))
        })?;
        json["epe"] = flow_json(&scores);
        json["surface_distance"]["ground_truth"] =
            median_distance(&reg.points_moved_by(gt), &surface).into();
    }
    println!("{json}");
    registered_or_failure(verdict == FrameVerdict::Registered)
}

/// A registration's exit: a run that did not register has written its outputs and JSON line
/// (with the warning saying why), and ends as a runtime failure (exit code 1) so that a script
/// cannot take the result for a registration.
fn registered_or_failure(registered: bool) -> Result<()> {
    if registered {
        Ok(())
    } else {
        bail!("the source was not registered onto the target (outputs and summary written)")
    }
}

/// Whether the registration registered, as JSON; a warning when it did not.
fn verdict_json(verdict: FrameVerdict) -> serde_json::Value {
    match verdict {
        FrameVerdict::Registered => true.into(),
        FrameVerdict::NotRegistered {
            matched,
            data_points,
        } => {
            tracing::warn!(
                "not registered: {matched} of {data_points} data points ended on the target \
                 (at least {:.0} % must)",
                100.0 * MIN_MATCHED_FRACTION
            );
            false.into()
        }
        FrameVerdict::LiesFlush(o) => {
            tracing::warn!(
                "not registered: {} of the {} outline points seen on the target lie flush in a \
                 surface that goes on (at most {:.0} % may): a plain object laid on a surface \
                 it is not",
                o.flush,
                o.seen,
                100.0 * MAX_FLUSH_FRACTION
            );
            false.into()
        }
        FrameVerdict::ColourDisagrees(c) => {
            tracing::warn!(
                "not registered: the colour disagrees on {} of {} textured patches (at most {:.0} \
                 % may): the surface slid",
                c.off,
                c.off + c.aligned,
                100.0 * MAX_OFF_FRACTION
            );
            false.into()
        }
    }
}

/// Whether a surface registration registered, as JSON; a warning saying why when it did not.
fn surface_verdict_json(verdict: SurfaceVerdict) -> serde_json::Value {
    let ratio = |r: Option<f64>| r.map_or("– (a cloud)".to_string(), |r| format!("{r:.3}"));
    match verdict {
        SurfaceVerdict::Registered => true.into(),
        SurfaceVerdict::NotRegistered(fit) => {
            tracing::warn!(
                "not registered: {:.0} % of the source ended within {:.3e} of the target and \
                 {:.0} % of the target is covered (at least {:.0} % each must be); {:.0} % of the \
                 former face the target's way (at least {:.0} % must); the source's area over \
                 the target's is {} at rest and {} warped (within {AREA_FACTOR}× of 1 must be)",
                100.0 * fit.on_target,
                fit.tolerance,
                100.0 * fit.covered,
                100.0 * MIN_SHARE,
                100.0 * fit.facing,
                100.0 * MIN_FACING,
                ratio(fit.source_area_ratio),
                ratio(fit.area_ratio)
            );
            false.into()
        }
        SurfaceVerdict::Ambiguous(slip) => {
            let v = |v: nalgebra::Vector3<f64>| format!("({:.3}, {:.3}, {:.3})", v.x, v.y, v.z);
            tracing::warn!(
                "not registered: the surfaces fit, but one slides along itself: its least \
                 constrained rigid motion (rotation {} about its centroid, translation {} in \
                 diagonals) moves it off itself by {:.1e} of its displacement (a symmetry is \
                 under {MAX_SLIPPAGE:.0e}), so where its points lie along that motion is not known",
                v(slip.rotation),
                v(slip.translation),
                slip.ratio
            );
            false.into()
        }
        SurfaceVerdict::AffineAmbiguous(slide) => {
            tracing::warn!(
                "not registered: the surfaces fit, but one slides along itself under a stretch \
                 or shear (affine slippage {:.1e} and {:.1e}, under {MAX_AFFINE_SLIPPAGE:.0e}: \
                 an ellipsoid, say) and the answer departs from rigid by {:.3e} (at most {:.3e} \
                 counts as rigid), so the same answer stretched along the surface fits as well",
                slide.ratios[0],
                slide.ratios[1],
                slide.departure,
                slide.limit
            );
            false.into()
        }
        SurfaceVerdict::MapsDisagree(maps) => {
            tracing::warn!(
                "not registered: the surfaces fit, and two rigid motions or two affine maps \
                 fitted from different starts each lay the source on the target as closely as \
                 the warp, but carry it {:.3e} apart (at most {:.3e} counts as one map): the \
                 surfaces fit both (a box turned onto itself, or its faces exchanged by a \
                 stretch), and nothing tells which is right",
                maps.apart,
                maps.limit
            );
            false.into()
        }
        SurfaceVerdict::Inconsistent(trip) => {
            tracing::warn!(
                "not registered: the surfaces fit, but the target registered back onto the \
                 source brings its points back {:.3e} from where they started on average, {:.0} \
                 % of the {:.3e} they moved (at most {:.0} % may): the surfaces do not fix where \
                 the points go",
                trip.mean,
                100.0 * trip.ratio(),
                trip.moved,
                100.0 * MAX_ROUND_TRIP
            );
            false.into()
        }
    }
}

/// The round trip's error, the displacement claimed, their ratio and its limit, as JSON (module
/// `round_trip`); null where it was not run.
fn round_trip_json(trip: Option<RoundTrip>) -> serde_json::Value {
    trip.map_or(serde_json::Value::Null, |t| {
        serde_json::json!({"error": t.mean, "moved": t.moved, "ratio": t.ratio(), "points": t.points, "limit": MAX_ROUND_TRIP})
    })
}

/// The share of each surface's least-constrained motion that leaves it (module `slippage`), as
/// JSON.
fn slippage_json(slippage: Option<[Slippage; 2]>) -> serde_json::Value {
    slippage.map_or(
        serde_json::Value::Null,
        |[s, t]| serde_json::json!({"source": s.ratio, "target": t.ratio, "limit": MAX_SLIPPAGE}),
    )
}

/// The share of each surface's least-constrained affine motion that leaves it and the answer's
/// departure from rigid with its limit (module `affine_slippage`), as JSON.
fn affine_slippage_json(slide: Option<AffineSlide>) -> serde_json::Value {
    slide.map_or(serde_json::Value::Null, |a| {
        let departure = a.departure.is_finite().then_some(a.departure);
        serde_json::json!({"source": a.ratios[0], "target": a.ratios[1], "limit": MAX_AFFINE_SLIPPAGE,
            "departure_from_rigid": departure, "rigid_limit": a.limit})
    })
}

/// The flow's scores as JSON.
fn flow_json(s: &FlowScores) -> serde_json::Value {
    let score = |e: &EpeResult| serde_json::json!({"mean": e.stats.mean, "median": e.stats.median, "within_5cm": e.within_5cm, "within_10cm": e.within_10cm});
    serde_json::json!({
        "object": s.object.as_ref().map(score),
        "object_pixels": s.object_pixels,
        "coverage": s.coverage,
        "all": score(&s.all),
        "all_pixels": s.all_pixels,
        "zero_flow": score(&s.zero_flow),
    })
}

pub fn main() -> ExitCode {
    let (graph, register) = clean_surface_settings(1.0);
    let frames = FrameSettings::default();
    cli::run_with(
        |cmd| {
            cmd.mut_subcommand("meshes", |c| {
                let c = WarpFlags::describe_relative_defaults(c, &graph, &register, "D");
                let passes = format!("[default: {}]", Seeding::default().passes);
                warp_flags::append_help(c, "seeded_passes", &passes)
            })
            .mut_subcommand("frames", |c| {
                WarpFlags::show_defaults(c, &frames.graph, &frames.register)
            })
            .mut_subcommand("pairs", |c| {
                WarpFlags::show_defaults(c, &frames.graph, &frames.register)
            })
        },
        run,
    )
}

fn run(args: Args, session: &Session) -> Result<()> {
    match &args.mode {
        None | Some(Mode::Grid) => grid_experiment(session),
        Some(Mode::Meshes(m)) => register_mesh_files(m),
        Some(Mode::Frames(f)) => register_frame_pair(f),
        Some(Mode::Sheets(a)) => sheet_experiment(a, session),
        Some(Mode::Pairs(a)) => pairs::pair_experiment(a, session),
    }
}

/// A surface's points and their normals, in double precision.
type PointsAndNormals = (Vec<Vector3<f64>>, Vec<Vector3<f64>>);

/// The points and normals of `mesh` read from `path`, the normals computed from its triangles
/// where the file gives none; a point cloud without normals is refused (it has nothing to compute
/// them from, and a normal made up would be registered as if it were true).
fn surface_points(mesh: &Mesh, path: &Path) -> Result<PointsAndNormals> {
    if mesh.faces.is_empty() && mesh.normals.len() != mesh.vertices.len() {
        return Err(cli::bad_input(format_args!(
            "{}: a point cloud needs normals (the file has neither triangles nor normals)",
            path.display()
        )));
    }
    Ok(mesh_points(mesh))
}

/// Reads a mesh, and how many of its triangles were turned to be wound like their neighbours
/// when its normals were computed from them (0 when it gave normals or has no faces), with a
/// warning naming the file when any were, and another when some cannot be.
fn read_oriented(path: &Path) -> Result<(Mesh, usize)> {
    let (mesh, winding) = read_mesh_oriented(path).bad_input()?;
    let winding = winding.unwrap_or_default();
    if winding.turned > 0 {
        tracing::warn!(
            "{}: {} of {} triangles were wound against their neighbours and were turned over \
             before the normals were computed",
            path.display(),
            winding.turned,
            mesh.faces.len()
        );
    }
    if winding.disagreeing > 0 {
        tracing::warn!(
            "{}: {} shared edge(s) join triangles that cannot be wound alike (a surface that \
             cannot be oriented, as a Möbius strip); its normals point both ways there",
            path.display(),
            winding.disagreeing
        );
    }
    Ok((mesh, winding.turned))
}

/// Says how many of the mesh's (at `path`) `points` are not finite: they are no part of the
/// surface (a source's are written back as they were).
fn warn_unplaced(points: &[Vector3<f64>], path: &Path) {
    let unplaced = points
        .iter()
        .filter(|p| !p.iter().all(|x| x.is_finite()))
        .count();
    if unplaced > 0 {
        tracing::warn!(
            "{}: {unplaced} of {} vertices are not finite (NaN or infinite): left out of the \
             surface",
            path.display(),
            points.len()
        );
    }
}

/// The diagonal of the surface `points` (the mesh at `path`), which the settings scale with; a
/// surface with no extent is bad input.
fn surface_size(points: &[Vector3<f64>], mesh: &Mesh, path: &Path) -> Result<f64> {
    let d = surface_diagonal(points, &mesh.faces);
    if d.is_finite() && d > 0.0 {
        Ok(d)
    } else {
        Err(cli::bad_input(format_args!(
            "{}: the surface has no extent (its vertices lie at one point)",
            path.display()
        )))
    }
}

/// Registers one mesh onto another, writes the warped mesh, scores it against a ground-truth
/// vertex map, and prints the JSON line.
fn register_mesh_files(args: &MeshArgs) -> Result<()> {
    cli::check_outputs(&[("--output", args.output.as_deref())], &[])?;
    let (source, source_winding) = read_oriented(&args.source)?;
    let (target, target_winding) = read_oriented(&args.target)?;
    let (sp, sn) = surface_points(&source, &args.source)?;
    let (tp, tn) = surface_points(&target, &args.target)?;
    warn_unplaced(&sp, &args.source);
    warn_unplaced(&tp, &args.target);
    let (source_size, target_size) = (
        surface_size(&sp, &source, &args.source)?,
        surface_size(&tp, &target, &args.target)?,
    );
    let (mut graph, mut params) = clean_surface_settings(source_size);
    args.warp.apply(&mut graph, &mut params).bad_input()?;
    let map = match &args.ground_truth {
        Some(p) => Some(VertexMap::read(p, sp.len(), tp.len()).bad_input()?),
        None => None,
    };
    let passes = args.seeded_passes.unwrap_or(Seeding::default().passes);
    flag_checks::iterations("--seeded-passes", &[passes], false)?;
    let seeding = Seeding {
        passes,
        ..Seeding::default()
    };
    let reg = register_mesh_or_cloud(
        SurfaceMesh::with_faces_of(&sp, &sn, &source),
        SurfaceMesh::with_faces_of(&tp, &tn, &target),
        graph,
        params,
        args.principal_axes,
        &seeding,
    )
    .map_err(|e| match e {
        // a mesh without area is the file's fault: bad input, naming it
        SurfaceError::NoArea(role) => {
            let path = [&args.source, &args.target][(role == MeshRole::Target) as usize];
            cli::bad_input(format_args!("{}: {e}", path.display()))
        }
        e => anyhow::Error::new(e).context(format!("registering {}", args.source.display())),
    })?;
    if let Some(out) = &args.output {
        let mut warped = source.clone();
        warped.vertices = reg.points.iter().map(|p| p.cast::<f32>().into()).collect();
        warped.normals = reg.normals.iter().map(|n| n.cast::<f32>()).collect();
        ply::write(out, &warped)?;
    }
    let mut json = summary_json(reg.graph.nodes.len(), &reg.summary, sp.len());
    let verdict = reg.verdict();
    json["registered"] = surface_verdict_json(verdict);
    json["target_normals_turned"] = reg.target_normals_turned.into();
    json["slippage"] = slippage_json(reg.slippage);
    json["affine_slippage"] = affine_slippage_json(reg.affine_slide());
    json["round_trip"] = round_trip_json(reg.round_trip);
    json["placed_back"] = reg.placed_back.into();
    json["placed_affine"] = reg.placed_affine.into();
    json["placed_rigid"] = reg.placed_rigid.into();
    json["maps_apart"] = reg.maps_apart.map_or(
        serde_json::Value::Null,
        |m| serde_json::json!({"apart": m.apart, "limit": m.limit}),
    );
    json["faces_turned"] = serde_json::json!({"source": source_winding, "target": target_winding});
    json["fit"] = serde_json::json!({
        "on_target": reg.fit.on_target,
        "covered": reg.fit.covered,
        "facing": reg.fit.facing,
        "median_distance": reg.fit.median_distance,
        "area_ratio": reg.fit.area_ratio,
        "source_area_ratio": reg.fit.source_area_ratio,
        "tolerance": reg.fit.tolerance,
    });
    if let Some(map) = &map {
        let d = target_size;
        let (before, after) = (map.error(&sp, &tp, d), map.error(&reg.points, &tp, d));
        json["scored_vertices"] = map.scored_count().into();
        json["error_before"] = serde_json::json!({"mean": before.mean, "p95": before.p95});
        json["error_after"] = serde_json::json!({"mean": after.mean, "p95": after.p95});
    }
    println!("{json}");
    registered_or_failure(verdict == SurfaceVerdict::Registered)
}
