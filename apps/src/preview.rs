//! `--preview DIR`: pictures of a run without a viewer, drawn with plotters (cost per iteration,
//! trajectories from above, per-frame error) or by the TSDF raycaster (shaded model views).

use anyhow::{anyhow, Context, Result};
use dynamap_slam::camera::Camera;
use dynamap_slam::eval::AteResult;
use dynamap_slam::image::{ColorImage, Image};
use dynamap_slam::io::images::write_color;
use dynamap_slam::io::trajectory::Trajectory;
use dynamap_slam::tsdf::{RaycastMaps, TsdfVolume};
use nalgebra::{Isometry3, Vector3};
use plotters::prelude::*;
use std::path::Path;
use std::sync::OnceLock;

/// Plot size, pixels.
const SIZE: (u32, u32) = (960, 640);

/// Where plotters finds its text font: `DYNAMAP_FONT`, else common system locations of DejaVu Sans
/// or Liberation Sans.
const FONT_PATHS: [&str; 5] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/Library/Fonts/Arial.ttf",
];

/// Registers the font plotters draws text with (once per process).
fn register_font() -> Result<()> {
    static FOUND: OnceLock<Result<(), String>> = OnceLock::new();
    let found = FOUND.get_or_init(|| {
        let env = std::env::var("DYNAMAP_FONT").ok();
        let path = env
            .iter()
            .map(String::as_str)
            .chain(FONT_PATHS)
            .find(|p| Path::new(p).is_file())
            .ok_or_else(|| {
                "--preview draws text and found no TrueType font: set DYNAMAP_FONT to a .ttf file"
                    .to_string()
            })?;
        let bytes = std::fs::read(path).map_err(|e| format!("reading the font {path}: {e}"))?;
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes.leak())
            .map_err(|_| format!("{path}: not a TrueType font plotters can read"))
    });
    found.clone().map_err(|e| anyhow!(e))
}

/// Draws into an RGB buffer with `draw` and writes it as a PNG (through a temporary file).
fn plot(
    path: &Path,
    draw: impl FnOnce(DrawingArea<BitMapBackend, plotters::coord::Shift>) -> Result<()>,
) -> Result<()> {
    register_font()?;
    let (w, h) = SIZE;
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
        draw(root.clone())?;
        root.present().map_err(|e| anyhow!("{e}"))?;
    }
    let data = buf.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
    let img = Image::from_vec(w as usize, h as usize, data).expect("sized by SIZE");
    write_color(path, &img).with_context(|| format!("writing {}", path.display()))
}

/// Turns a plotters error into ours.
fn drawn<T, E: std::fmt::Display>(r: std::result::Result<T, E>) -> Result<T> {
    r.map_err(|e| anyhow!("drawing: {e}"))
}

/// A chart in the house style: the title, margins, room for the axis labels.
fn chart_builder<'a, 'b>(
    root: &'a DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>,
    title: &str,
) -> ChartBuilder<'a, 'b, BitMapBackend<'b>> {
    let mut builder = ChartBuilder::on(root);
    builder
        .caption(title, ("sans-serif", 24))
        .margin(16)
        .x_label_area_size(44)
        .y_label_area_size(80);
    builder
}

/// Draws the series' labels in a box at `at`.
fn legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    at: SeriesLabelPosition,
) -> Result<()> {
    drawn(
        chart
            .configure_series_labels()
            .position(at)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw(),
    )
}

/// Cost per iteration on a log axis, one line per named series (e.g. plain and robust fits).
pub fn cost_plot(path: &Path, title: &str, series: &[(&str, Vec<(usize, f64)>)]) -> Result<()> {
    let all = || series.iter().flat_map(|(_, s)| s.iter());
    let top = all().map(|p| p.1).fold(f64::MIN_POSITIVE, f64::max);
    // costs reach 0 on exact problems: show them at the floor of the axis
    let floor = all()
        .map(|p| p.1)
        .filter(|c| *c > 0.0)
        .fold(top, f64::min)
        .max(top * 1e-30)
        .max(f64::MIN_POSITIVE);
    let last = all().map(|p| p.0).max().unwrap_or(1).max(1);
    plot(path, |root| {
        let mut chart = drawn(
            chart_builder(&root, title)
                .build_cartesian_2d(0..last, (floor * 0.5..top * 2.0).log_scale()),
        )?;
        drawn(
            chart
                .configure_mesh()
                .x_desc("iteration")
                .y_desc("cost ½Σρ(‖r‖²)")
                .y_labels(16)
                .y_label_formatter(&|v| format!("{v:.0e}"))
                .draw(),
        )?;
        for (k, (name, s)) in series.iter().enumerate() {
            let colour = Palette99::pick(k).to_rgba();
            let pts: Vec<(usize, f64)> = s.iter().map(|&(i, c)| (i, c.max(floor))).collect();
            drawn(chart.draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2))))?
                .label(*name)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(2))
                });
            drawn(chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, colour.filled()))))?;
        }
        legend(&mut chart, SeriesLabelPosition::UpperRight)
    })
}

/// The two world axes along which the ground truth (else the estimate) spreads most: the view
/// from above for a camera moving over a floor.
fn top_axes(points: &[Vector3<f64>]) -> (usize, usize) {
    let n = points.len().max(1) as f64;
    let mean = points.iter().sum::<Vector3<f64>>() / n;
    let var = points
        .iter()
        .map(|p| (p - mean).component_mul(&(p - mean)))
        .sum::<Vector3<f64>>();
    let mut axes = [0, 1, 2];
    axes.sort_by(|&a, &b| var[b].total_cmp(&var[a]));
    (axes[0].min(axes[1]), axes[0].max(axes[1]))
}

/// The estimated trajectory (aligned onto the ground truth by `ate`'s transform) over the ground
/// truth, seen along the axis they spread least in, with equal scales.
pub fn trajectory_plot(
    path: &Path,
    estimate: &Trajectory,
    truth: Option<(&Trajectory, &AteResult)>,
) -> Result<()> {
    let est: Vec<Vector3<f64>> = estimate
        .poses
        .iter()
        .map(|p| match truth {
            Some((_, a)) => a.alignment.apply(&p.translation.vector.into()).coords,
            None => p.translation.vector,
        })
        .collect();
    let gt: Vec<Vector3<f64>> = truth
        .map(|(g, _)| g.poses.iter().map(|p| p.translation.vector).collect())
        .unwrap_or_default();
    let (a, b) = top_axes(if gt.is_empty() { &est } else { &gt });
    let all: Vec<(f64, f64)> = est.iter().chain(&gt).map(|p| (p[a], p[b])).collect();
    let (mut lo, mut hi) = ((f64::MAX, f64::MAX), (f64::MIN, f64::MIN));
    for &(x, y) in &all {
        lo = (lo.0.min(x), lo.1.min(y));
        hi = (hi.0.max(x), hi.1.max(y));
    }
    // equal scales: the plot area is 3:2, so the wider range sets both
    let span = ((hi.0 - lo.0) / 1.4).max((hi.1 - lo.1) / 0.9).max(1e-3) * 1.1;
    let (cx, cy) = ((lo.0 + hi.0) / 2.0, (lo.1 + hi.1) / 2.0);
    let names = ["x", "y", "z"];
    plot(path, |root| {
        let mut chart = drawn(
            chart_builder(&root, "trajectory from above").build_cartesian_2d(
                cx - 0.7 * span..cx + 0.7 * span,
                cy - 0.45 * span..cy + 0.45 * span,
            ),
        )?;
        drawn(
            chart
                .configure_mesh()
                .x_desc(format!("{} (m)", names[a]))
                .y_desc(format!("{} (m)", names[b]))
                .draw(),
        )?;
        let line = |v: &[Vector3<f64>]| v.iter().map(|p| (p[a], p[b])).collect::<Vec<_>>();
        if !gt.is_empty() {
            // wide and grey under the estimate, so both show where they coincide
            let grey = BLACK.mix(0.3).stroke_width(7);
            drawn(chart.draw_series(LineSeries::new(line(&gt), grey)))?
                .label("ground truth")
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], grey));
        }
        drawn(chart.draw_series(LineSeries::new(line(&est), RED.stroke_width(2))))?
            .label("estimate")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], RED.stroke_width(2)));
        if let Some(&p) = gt.first().or(est.first()) {
            drawn(chart.draw_series([Circle::new((p[a], p[b]), 6, BLACK.filled())]))?
                .label("start")
                .legend(|(x, y)| Circle::new((x + 12, y), 5, BLACK.filled()));
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft)
    })
}

/// Named series of (x, y) on linear axes from 0.
pub fn line_plot(
    path: &Path,
    title: &str,
    axes: (&str, &str),
    series: &[(&str, Vec<(f64, f64)>)],
) -> Result<()> {
    let all = || series.iter().flat_map(|(_, s)| s.iter());
    let right = all().map(|p| p.0).fold(1.0, f64::max);
    let top = all()
        .map(|p| p.1)
        .filter(|y| y.is_finite())
        .fold(1e-9, f64::max)
        * 1.15;
    plot(path, |root| {
        let mut chart =
            drawn(chart_builder(&root, title).build_cartesian_2d(0.0..right, 0.0..top))?;
        drawn(
            chart
                .configure_mesh()
                .x_desc(axes.0)
                .y_desc(axes.1)
                .x_label_formatter(&|v| format!("{v:.0}"))
                .draw(),
        )?;
        for (k, (name, s)) in series.iter().enumerate() {
            let colour = Palette99::pick(k).to_rgba().stroke_width(2);
            drawn(chart.draw_series(LineSeries::new(s.clone(), colour)))?
                .label(*name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], colour));
        }
        legend(&mut chart, SeriesLabelPosition::UpperRight)
    })
}

/// The translational error of each associated frame after alignment (what ATE averages), with
/// the RMSE as a level line.
pub fn error_plot(
    path: &Path,
    truth: &Trajectory,
    estimate: &Trajectory,
    ate: &AteResult,
) -> Result<()> {
    let errors: Vec<(f64, f64)> = ate
        .pairs
        .iter()
        .enumerate()
        .map(|(k, &(i, j))| {
            let e = ate
                .alignment
                .apply(&estimate.poses[j].translation.vector.into());
            let g = truth.poses[i].translation.vector;
            (k as f64, 1e3 * (g - e.coords).norm())
        })
        .collect();
    let rmse_mm = 1e3 * ate.stats.rmse;
    let level = vec![(0.0, rmse_mm), (errors.len() as f64, rmse_mm)];
    line_plot(
        path,
        &format!("per-frame translational error (ATE RMSE {rmse_mm:.2} mm)"),
        ("frame", "error (mm)"),
        &[("error", errors), ("RMSE", level)],
    )
}

/// A raycast's normals shaded by a light over the viewer's left shoulder (Lambert, in the camera
/// frame); pixels with no surface are black.
pub fn shade(maps: &RaycastMaps, pose: &Isometry3<f64>) -> ColorImage {
    let light = Vector3::new(0.3f32, -0.5, -1.0).normalize();
    let rot = pose
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
            let nc = rot.transpose() * Vector3::new(n[0], n[1], n[2]);
            let v = (40.0 + 215.0 * nc.dot(&light).max(0.0)) as u8;
            [v, v, v]
        })
        .collect();
    let (w, h) = (maps.normals.width, maps.normals.height);
    Image::from_vec(w, h, data).expect("one shade per normal")
}

/// The model raycast and shaded from each of `views` (the camera with its focal length scaled by
/// `zoom`, e.g. 0.5 for twice the field of view), written as `model_view_<k>.png` in `dir`.
pub fn model_views(
    dir: &Path,
    volume: &TsdfVolume,
    camera: &Camera,
    zoom: f64,
    views: &[Isometry3<f64>],
) -> Result<()> {
    let wide = Camera {
        fx: camera.fx * zoom,
        fy: camera.fy * zoom,
        ..*camera
    };
    let mut maps = RaycastMaps::new();
    for (k, pose) in views.iter().enumerate() {
        volume.raycast(&wide, pose, &mut maps);
        let path = dir.join(format!("model_view_{}.png", k + 1));
        write_color(&path, &shade(&maps, pose))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

/// Two panels side by side, each as the camera sees it: the target in grey (lighter is nearer)
/// with the source in red (left, before) and the warped source in blue (right, after); of two
/// points on one pixel the nearer is drawn. Where the blue lies on the grey and hides it, the
/// warp put the source on the target's surface.
pub fn registration_picture(
    camera: &Camera,
    target: &[Vector3<f64>],
    source: &[Vector3<f64>],
    warped: &[Vector3<f64>],
) -> ColorImage {
    let (w, h) = (camera.width, camera.height);
    let (near, far) = target
        .iter()
        .chain(source)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.z), b.max(p.z))
        });
    let span = (far - near).max(1e-9);
    let mut image = Image::filled(2 * w, h, [0u8; 3]);
    let mut depth = Image::filled(2 * w, h, f64::INFINITY);
    let mut splat = |points: &[Vector3<f64>], panel: usize, colour: &dyn Fn(f64) -> [u8; 3]| {
        for p in points {
            let Some((x, y)) = camera.project_to_pixel(&(*p).into()) else {
                continue;
            };
            let i = y * 2 * w + panel * w + x;
            if p.z < depth.data[i] {
                depth.data[i] = p.z;
                image.data[i] = colour(1.0 - ((p.z - near) / span).clamp(0.0, 1.0));
            }
        }
    };
    let grey = |t: f64| [(70.0 + 150.0 * t) as u8; 3];
    let red = |t: f64| [(120.0 + 135.0 * t) as u8, 30, 30];
    let blue = |t: f64| [30, 60, (120.0 + 135.0 * t) as u8];
    for panel in 0..2 {
        splat(target, panel, &grey);
    }
    splat(source, 0, &red);
    splat(warped, 1, &blue);
    image
}
