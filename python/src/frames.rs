//! One RGB-D frame registered onto another with the deformation graph, from numpy images, as
//! `nonrigid_register frames` does: the warped source points, the scene flow and the verdict
//! (the depth's, then the colour's).

use crate::arrays;
use crate::errors;
use crate::slam::{color_image, depth_image, pinhole};
use dynamap_slam::camera::Camera;
use dynamap_slam::image::{depth_to_metres, DepthImage, Image};
use dynamap_slam::nonrigid::{
    register_frames as register, ColourCheck, FrameRegistration, FrameSettings, FrameVerdict,
    FrameView, OutlineCheck,
};
use nalgebra::Vector3;
use numpy::{
    PyArray1, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The pinhole camera of images shaped like `depth` (height × width; see `slam::pinhole`).
fn camera_of(depth: &Bound<'_, PyAny>, intrinsics: [f64; 4], depth_scale: f64) -> PyResult<Camera> {
    let shape = depth
        .cast::<PyUntypedArray>()
        .map_err(|_| PyValueError::new_err("source_depth must be a numpy array"))?
        .shape()
        .to_vec();
    match shape[..] {
        [h, w] => pinhole(intrinsics, (w, h), depth_scale),
        _ => Err(PyValueError::new_err(format!(
            "source_depth must be height x width, not of shape {shape:?}"
        ))),
    }
}

/// A depth array in metres (frame 0 the source, 1 the target; see `slam::depth_image`).
fn metres(depth: &Bound<'_, PyAny>, camera: &Camera, frame: usize) -> PyResult<DepthImage> {
    let raw = depth_image(depth, camera, frame)?;
    let mut out = DepthImage::default();
    depth_to_metres(&raw, camera, &mut out);
    Ok(out)
}

/// The source's mask (height × width, bool).
fn mask_image(mask: &PyReadonlyArray2<'_, bool>, camera: &Camera) -> PyResult<Image<bool>> {
    let a = mask.as_array();
    if a.shape() != [camera.height, camera.width] {
        return Err(PyValueError::new_err(format!(
            "mask has shape {:?}, the depth's is ({}, {})",
            a.shape(),
            camera.height,
            camera.width
        )));
    }
    let data = a.iter().copied().collect();
    Ok(Image::from_vec(camera.width, camera.height, data).expect("the shape was checked"))
}

/// The source frame registered onto the target (`nonrigid_register frames`, its default
/// settings): depth arrays as uint16 sensor units (`depth_scale` per metre) or float metres,
/// colour as height × width × 3 uint8, the source's object as a bool mask. Gives `points` and
/// `warped` (n × 3, source and target camera frames), `pixels` (row-major source pixel of each
/// point), `flow` (height × width × 3, NaN off the object), `nodes`, `matched`, `data_points`,
/// `iterations`, `seconds`, `registered` (bool), `verdict` ("registered", "depth": too little
/// of the source ended on the target, "outline": its outline lies flush in a surface that goes
/// on, or "colour": its colour disagrees, slid along the surface), `start` ("features",
/// "outline": placed by the object's outline against the target's depth, or "none"),
/// `colour_check` (aligned, off, flat, floor, correlation, contrast; None without colour) and
/// `outline_check` (outline, seen, flush; None when the object has no outline before its
/// background in the source). An array of the wrong shape or type is a `ValueError` naming it (the source's images
/// are frame 0, the target's frame 1).
#[pyfunction]
#[pyo3(signature = (source_depth, target_depth, fx, fy, cx, cy, depth_scale = 1000.0, source_color = None, target_color = None, mask = None))]
#[allow(clippy::too_many_arguments)]
pub fn register_frames<'py>(
    py: Python<'py>,
    source_depth: &Bound<'py, PyAny>,
    target_depth: &Bound<'py, PyAny>,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    depth_scale: f64,
    source_color: Option<PyReadonlyArray3<'py, u8>>,
    target_color: Option<PyReadonlyArray3<'py, u8>>,
    mask: Option<PyReadonlyArray2<'py, bool>>,
) -> PyResult<Bound<'py, PyDict>> {
    let camera = camera_of(source_depth, [fx, fy, cx, cy], depth_scale)?;
    let depths = [
        metres(source_depth, &camera, 0)?,
        metres(target_depth, &camera, 1)?,
    ];
    let colours = [
        source_color
            .map(|c| color_image(&c, &camera, 0))
            .transpose()?,
        target_color
            .map(|c| color_image(&c, &camera, 1))
            .transpose()?,
    ];
    let mask = mask.map(|m| mask_image(&m, &camera)).transpose()?;
    let reg = py
        .detach(|| {
            let source = FrameView::new(&camera, &depths[0], colours[0].as_ref(), mask.as_ref());
            let target = FrameView::new(&camera, &depths[1], colours[1].as_ref(), None);
            register(&source, &target, &FrameSettings::default())
        })
        .map_err(|e| errors::SolveError::new_err(format!("registering the frames: {e}")))?;
    registration_dict(py, &reg, &camera)
}

/// The registration as the dictionary `register_frames` documents.
fn registration_dict<'py>(
    py: Python<'py>,
    reg: &FrameRegistration,
    camera: &Camera,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let flat = |v: &[Vector3<f64>]| v.iter().flat_map(|p| [p.x, p.y, p.z]).collect::<Vec<f64>>();
    d.set_item("points", arrays::rows(py, flat(&reg.points), 3))?;
    d.set_item("warped", arrays::rows(py, flat(&reg.warped), 3))?;
    d.set_item("pixels", reg.pixels.clone())?;
    let flow = reg.scene_flow(camera.width, camera.height);
    let values: Vec<f32> = flow.data.iter().flatten().copied().collect();
    let flow = PyArray1::from_vec(py, values).reshape([camera.height, camera.width, 3])?;
    d.set_item("flow", flow)?;
    d.set_item("nodes", reg.graph.nodes.len())?;
    d.set_item("matched", reg.summary.matched)?;
    d.set_item("data_points", reg.data_points)?;
    d.set_item("iterations", reg.summary.iterations)?;
    d.set_item("seconds", reg.summary.seconds)?;
    let verdict = reg.verdict();
    d.set_item("registered", verdict == FrameVerdict::Registered)?;
    d.set_item("verdict", verdict.name())?;
    d.set_item("start", reg.start.name())?;
    let colour = reg
        .colour
        .as_ref()
        .map(|c| colour_dict(py, c))
        .transpose()?;
    d.set_item("colour_check", colour)?;
    let outline = reg
        .outline
        .as_ref()
        .map(|o| outline_dict(py, o))
        .transpose()?;
    d.set_item("outline_check", outline)?;
    Ok(d)
}

/// The outline check's counts.
fn outline_dict<'py>(py: Python<'py>, o: &OutlineCheck) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("outline", o.outline)?;
    d.set_item("seen", o.seen)?;
    d.set_item("flush", o.flush)?;
    Ok(d)
}

/// The colour check's counts, floor, correlation and contrast.
fn colour_dict<'py>(py: Python<'py>, c: &ColourCheck) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("aligned", c.aligned)?;
    d.set_item("off", c.off)?;
    d.set_item("flat", c.flat)?;
    d.set_item("floor", c.floor)?;
    d.set_item("correlation", c.correlation)?;
    d.set_item("contrast", c.contrast)?;
    Ok(d)
}
