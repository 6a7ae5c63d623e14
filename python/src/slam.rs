//! Dense rigid SLAM from numpy images: `RigidSlam` fed depth and colour arrays, `Sequence` to
//! read recorded ones (TUM, ICL-NUIM or a plain folder), and `generate_sequence` to render new
//! ones with ground truth.

use crate::arrays;
use crate::errors;
use crate::meshes;
use dynamap_slam::camera::{usable_focal_length, Camera};
use dynamap_slam::image::{ColorImage, Image};
use dynamap_slam::io::sequence::{OpenOptions, Sequence as Core};
use dynamap_slam::io::trajectory::Trajectory;
use dynamap_slam::rigid::{
    FrameOutcome, FrameReport, FrameStamps, RigidSlam as Pipeline, SlamParams,
};
use dynamap_slam::synthetic::kinect::KinectModel;
use dynamap_slam::synthetic::layouts::{self, Layout};
use dynamap_slam::synthetic::motion::{self, Motion};
use dynamap_slam::synthetic::noise::SensorNoise;
use dynamap_slam::synthetic::sequence::{self, Sensor};
use dynamap_slam::synthetic::{MAX_FRAMES, MAX_PIXELS};
use dynamap_slam::tsdf::{usable_voxel_size, MAX_VOXEL_SIZE, MIN_VOXEL_SIZE};
use dynamap_solver::lie::se3;
use dynamap_solver::{Manifold, SE3, SO3};
use nalgebra::{Isometry3, Matrix4};
use numpy::{
    PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3,
    PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// Stamps (n,) and poses (n × 7, `[t, q]`).
type StampedPoses<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray2<f64>>);

/// A pose as `[tx, ty, tz, qx, qy, qz, qw]`.
fn pose_vec(p: &Isometry3<f64>) -> [f64; 7] {
    let mut v = [0.0; 7];
    se3::to_slice(p, &mut v);
    v
}

/// A pose as a 4 × 4 homogeneous matrix.
fn pose_matrix<'py>(py: Python<'py>, p: &Isometry3<f64>) -> Bound<'py, PyArray2<f64>> {
    let m: Matrix4<f64> = p.to_homogeneous();
    arrays::matrix(
        py,
        &nalgebra::DMatrix::from_iterator(4, 4, m.iter().copied()),
    )
}

/// A pose from `[tx, ty, tz, qx, qy, qz, qw]` or a 4 × 4 matrix, checked by the SE(3) and
/// SO(3) manifolds (a zero quaternion, or a block that is not a rotation, is refused).
fn pose_from(a: &Bound<'_, PyAny>) -> PyResult<Isometry3<f64>> {
    let invalid = |e: String| PyValueError::new_err(format!("pose: {e}"));
    if let Ok(v) = a.extract::<arrays::Vector<'_>>() {
        return Ok(se3::from_slice(
            &SE3.validate(&arrays::to_vec(&v)).map_err(invalid)?,
        ));
    }
    let m = arrays::to_square::<4>(&a.extract::<arrays::Matrix<'_>>()?, "pose")?;
    let r = SO3
        .validate(m.fixed_view::<3, 3>(0, 0).into_owned().as_slice())
        .map_err(invalid)?;
    let t = m.fixed_view::<3, 1>(0, 3);
    if !t.iter().all(|x| x.is_finite()) {
        return Err(invalid("the translation is not finite".into()));
    }
    let rot = nalgebra::UnitQuaternion::from_matrix(&nalgebra::Matrix3::from_column_slice(&r));
    Ok(Isometry3::from_parts(
        nalgebra::Translation3::new(t[0], t[1], t[2]),
        rot,
    ))
}

/// A pinhole camera of `(width, height)` images with intrinsics `[fx, fy, cx, cy]` (pixels) and
/// raw depth in `depth_scale` units per metre; anything else than finite non-zero focal lengths,
/// a positive depth scale and images of at least 8 × 8 is a `ValueError`.
pub(crate) fn pinhole(
    [fx, fy, cx, cy]: [f64; 4],
    (width, height): (usize, usize),
    depth_scale: f64,
) -> PyResult<Camera> {
    let ok = [cx, cy, depth_scale].iter().all(|v| v.is_finite())
        && usable_focal_length(fx)
        && usable_focal_length(fy);
    if !ok || depth_scale <= 0.0 || width < 8 || height < 8 {
        return Err(PyValueError::new_err(format!(
            "the camera needs finite non-zero focal lengths, a positive depth scale and images of at least 8 x 8 (got {width} x {height})"
        )));
    }
    if width.saturating_mul(height) > MAX_PIXELS {
        return Err(PyValueError::new_err(format!(
            "the camera's images must have at most {MAX_PIXELS} pixels (4096 x 4096), not \
             {width} x {height}"
        )));
    }
    let mut camera = Camera::new(fx, fy, cx, cy, width, height);
    camera.depth_scale = depth_scale;
    Ok(camera)
}

/// A depth array as raw sensor units: uint16 as given, float32/float64 metres times
/// `depth_scale` (NaN, infinite or non-positive depths are holes).
pub(crate) fn depth_image(
    depth: &Bound<'_, PyAny>,
    camera: &Camera,
    frame: usize,
) -> PyResult<Image<u16>> {
    let shape = depth
        .cast::<PyUntypedArray>()
        .map_err(|_| PyValueError::new_err(format!("frame {frame}: depth must be a numpy array")))?
        .shape()
        .to_vec();
    if shape != [camera.height, camera.width] {
        return Err(PyValueError::new_err(format!(
            "frame {frame}: depth has shape {shape:?}, the camera's images are ({}, {})",
            camera.height, camera.width
        )));
    }
    let data: Vec<u16> = if let Ok(a) = depth.extract::<PyReadonlyArray2<'_, u16>>() {
        a.as_array().iter().copied().collect()
    } else if let Ok(a) = depth.extract::<PyReadonlyArray2<'_, f32>>() {
        a.as_array()
            .iter()
            .map(|&m| to_units(m as f64, camera.depth_scale))
            .collect()
    } else if let Ok(a) = depth.extract::<PyReadonlyArray2<'_, f64>>() {
        a.as_array()
            .iter()
            .map(|&m| to_units(m, camera.depth_scale))
            .collect()
    } else {
        return Err(PyValueError::new_err(format!(
            "frame {frame}: depth must be uint16 (sensor units) or float32/float64 (metres)"
        )));
    };
    Ok(Image::from_vec(camera.width, camera.height, data).expect("the shape was checked"))
}

/// Metres to sensor units, 0 (a hole) for what is not a positive finite depth or is beyond the
/// format's range.
fn to_units(metres: f64, scale: f64) -> u16 {
    let u = (metres * scale).round();
    match u.is_finite() && u >= 1.0 && u <= u16::MAX as f64 {
        true => u as u16,
        false => 0,
    }
}

/// A colour array (height × width × 3, uint8).
pub(crate) fn color_image(
    color: &PyReadonlyArray3<'_, u8>,
    camera: &Camera,
    frame: usize,
) -> PyResult<ColorImage> {
    let a = color.as_array();
    if a.shape() != [camera.height, camera.width, 3] {
        return Err(PyValueError::new_err(format!(
            "frame {frame}: colour has shape {:?}, expected ({}, {}, 3) uint8",
            a.shape(),
            camera.height,
            camera.width
        )));
    }
    let data = a
        .as_standard_layout()
        .as_slice()
        .expect("standard layout")
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    Ok(ColorImage::from_vec(camera.width, camera.height, data).expect("the shape was checked"))
}

/// Dense rigid RGB-D SLAM (KinectFusion with voxel hashing, frame-to-model point-to-plane and
/// photometric tracking, relocalisation from keyframes): feed it frames, read each frame's
/// outcome and pose, the trajectory and the mesh.
#[pyclass(module = "dynamap", unsendable)]
pub struct RigidSlam {
    core: Pipeline,
    camera: Camera,
    trajectory: Trajectory,
    frames: usize,
}

#[pymethods]
impl RigidSlam {
    /// A pipeline for `width × height` images from a pinhole camera (fx, fy, cx, cy in pixels),
    /// raw depth in `depth_scale` units per metre, starting at `initial_pose` (camera to world,
    /// `[t, q]` or 4 × 4; default the identity). `voxel_size` (metres) overrides the default.
    #[new]
    #[pyo3(signature = (fx, fy, cx, cy, width, height, depth_scale = 5000.0, initial_pose = None, voxel_size = None))]
    #[allow(clippy::too_many_arguments)]
    fn py_new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        width: usize,
        height: usize,
        depth_scale: f64,
        initial_pose: Option<&Bound<'_, PyAny>>,
        voxel_size: Option<f32>,
    ) -> PyResult<Self> {
        let camera = pinhole([fx, fy, cx, cy], (width, height), depth_scale)?;
        let mut params = SlamParams::default();
        // frame by frame, a new map's poses would be in its own frame, and this trajectory has
        // no keyframe graph to place them: a lost track stays lost until relocalised
        params.relocalise.new_map_after = 0;
        if let Some(v) = voxel_size {
            if !usable_voxel_size(v) {
                return Err(PyValueError::new_err(format!(
                    "voxel_size must lie between {MIN_VOXEL_SIZE} and {MAX_VOXEL_SIZE} metres, got {v}"
                )));
            }
            params.tsdf.voxel_size = v;
        }
        let pose = initial_pose
            .map(pose_from)
            .transpose()?
            .unwrap_or_else(Isometry3::identity);
        Ok(Self {
            core: Pipeline::new(camera, params, pose),
            camera,
            trajectory: Trajectory::default(),
            frames: 0,
        })
    }

    /// Processes one frame: `depth` (height × width, uint16 sensor units or float metres),
    /// `color` (height × width × 3 uint8, optional), stamped `timestamp` seconds (default the
    /// frame's index) and `color_timestamp` (default the same). Returns a dict: index, outcome,
    /// tracked, fused, failure (why not tracked, or None), pose (4 × 4, camera to world; the last
    /// good pose when not tracked), inliers, inlier_fraction, agreement, proximity (the agreement
    /// without the normal test), correlation (of the texture with the model's). A frame that
    /// cannot be tracked is reported so, never fused with a wrong pose; a malformed array raises.
    #[pyo3(signature = (depth, color = None, timestamp = None, color_timestamp = None))]
    fn process<'py>(
        &mut self,
        py: Python<'py>,
        depth: &Bound<'py, PyAny>,
        color: Option<PyReadonlyArray3<'py, u8>>,
        timestamp: Option<f64>,
        color_timestamp: Option<f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let index = self.frames;
        let depth = depth_image(depth, &self.camera, index)?;
        let color = color
            .map(|c| color_image(&c, &self.camera, index))
            .transpose()?;
        let t = timestamp.unwrap_or(index as f64);
        if !t.is_finite() || color_timestamp.is_some_and(|c| !c.is_finite()) {
            return Err(PyValueError::new_err(format!(
                "frame {index}: the timestamps must be finite"
            )));
        }
        let stamps = FrameStamps {
            depth: t,
            color: color_timestamp.unwrap_or(t),
        };
        let core = &mut self.core;
        let report = py.detach(|| core.process_timed(&depth, color.as_ref(), stamps));
        self.frames += 1;
        if report.failure().is_none() {
            self.trajectory.push(t, report.pose);
        }
        report_dict(py, index, &report)
    }

    /// The current camera-to-world pose, 4 × 4.
    #[getter]
    fn pose<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        pose_matrix(py, &self.core.pose())
    }

    /// The tracked frames' (stamps, poses): stamps (n,) and poses n × 7 `[t, q]`, camera to world.
    fn trajectory<'py>(&self, py: Python<'py>) -> StampedPoses<'py> {
        let poses = self.trajectory.poses.iter().flat_map(pose_vec).collect();
        (
            PyArray1::from_slice(py, &self.trajectory.stamps),
            arrays::rows(py, poses, 7),
        )
    }

    /// Writes the tracked trajectory in TUM's format (through a temporary file).
    fn write_trajectory(&self, path: PathBuf) -> PyResult<()> {
        self.trajectory.write_tum(&path).map_err(errors::input)
    }

    /// The fused surface by marching cubes: a dict of vertices, normals, colors and faces.
    fn mesh<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        // the pipeline is not Sync (its background graph solver's channel), so the interpreter
        // stays held here
        meshes::mesh_dict(py, &self.core.map_mesh(None))
    }

    fn __repr__(&self) -> String {
        format!(
            "<dynamap.RigidSlam {}x{}, {} frames, {} tracked>",
            self.camera.width,
            self.camera.height,
            self.frames,
            self.trajectory.len()
        )
    }
}

/// "started", "new_map", "tracked", "relocalised", "not_tracked" or "skipped".
fn outcome_name(o: &FrameOutcome) -> &'static str {
    match o {
        FrameOutcome::Started => "started",
        FrameOutcome::NewMap => "new_map",
        FrameOutcome::Tracked => "tracked",
        FrameOutcome::Relocalised => "relocalised",
        FrameOutcome::NotTracked(_) => "not_tracked",
        FrameOutcome::Skipped(_) => "skipped",
    }
}

/// One frame's report as a dict.
fn report_dict<'py>(
    py: Python<'py>,
    index: usize,
    r: &FrameReport,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("index", index)?;
    d.set_item("outcome", outcome_name(&r.outcome))?;
    d.set_item("tracked", r.failure().is_none())?;
    d.set_item("fused", r.outcome.is_fused())?;
    d.set_item("failure", r.failure().map(|f| f.to_string()))?;
    d.set_item("pose", pose_matrix(py, &r.pose))?;
    d.set_item("inliers", r.inliers)?;
    d.set_item("inlier_fraction", r.inlier_fraction)?;
    d.set_item("agreement", r.agreement)?;
    d.set_item("proximity", r.proximity)?;
    d.set_item("correlation", r.correlation)?;
    Ok(d)
}

/// A recorded RGB-D sequence: a TUM folder (rgb.txt, depth.txt), an ICL-NUIM folder or a folder
/// of numbered frames, read frame by frame as numpy arrays.
#[pyclass(module = "dynamap", frozen)]
pub struct Sequence {
    core: Core,
}

#[pymethods]
impl Sequence {
    /// Opens the sequence in `path`; raises `InputError` naming the file at fault.
    #[new]
    fn py_new(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let core = py
            .detach(|| Core::open(&path, &OpenOptions::default()))
            .map_err(errors::input)?;
        Ok(Self { core })
    }

    fn __len__(&self) -> usize {
        self.core.len()
    }

    /// The intrinsics: fx, fy, cx, cy, width, height, depth_scale.
    #[getter]
    fn camera<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = self.core.camera();
        let d = PyDict::new(py);
        d.set_item("fx", c.fx)?;
        d.set_item("fy", c.fy)?;
        d.set_item("cx", c.cx)?;
        d.set_item("cy", c.cy)?;
        d.set_item("width", c.width)?;
        d.set_item("height", c.height)?;
        d.set_item("depth_scale", c.depth_scale)?;
        Ok(d)
    }

    /// Frame `i` as (depth uint16 h × w, colour uint8 h × w × 3 or None, timestamp,
    /// color_timestamp); raises `InputError` for a frame that cannot be read.
    #[allow(clippy::type_complexity)]
    fn frame<'py>(
        &self,
        py: Python<'py>,
        i: usize,
    ) -> PyResult<(
        Bound<'py, PyArray2<u16>>,
        Option<Bound<'py, PyArray3<u8>>>,
        f64,
        f64,
    )> {
        if i >= self.core.len() {
            return Err(pyo3::exceptions::PyIndexError::new_err(format!(
                "frame {i}: the sequence has {}",
                self.core.len()
            )));
        }
        let f = py.detach(|| self.core.load(i)).map_err(errors::input)?;
        let depth = arrays::rows(py, f.depth.data, f.depth.width);
        let color = f.color.map(|c| {
            let (w, h) = (c.width, c.height);
            PyArray1::from_vec(py, c.data.into_iter().flatten().collect())
                .reshape([h, w, 3])
                .expect("h × w × 3 values")
        });
        Ok((depth, color, f.timestamp, f.color_timestamp))
    }

    /// The ground truth as (stamps, poses n × 7 `[t, q]`), or None.
    fn groundtruth<'py>(&self, py: Python<'py>) -> Option<StampedPoses<'py>> {
        self.core.groundtruth().map(|g| {
            let poses = g.poses.iter().flat_map(pose_vec).collect();
            (
                PyArray1::from_slice(py, &g.stamps),
                arrays::rows(py, poses, 7),
            )
        })
    }
}

/// Renders a rigid RGB-D sequence with ground truth into `path` (TUM layout), as
/// `generate rigid` does: the camera moving by `motion` (orbit, shake, fast_rotation, sweep or
/// survey) through the furnished room drawn from `seed`, recorded by the `sensor` model
/// ("kinect": structured light with its holes, edges, lens distortion and exposure; "ideal":
/// the render with axial noise). Returns the number of frames written.
#[pyfunction]
#[pyo3(signature = (path, frames = 60, motion = "orbit", width = 640, height = 480, fps = 30.0, sensor = "kinect", seed = 1))]
#[allow(clippy::too_many_arguments)]
pub fn generate_sequence(
    py: Python<'_>,
    path: PathBuf,
    frames: usize,
    motion: &str,
    width: usize,
    height: usize,
    fps: f64,
    sensor: &str,
    seed: u64,
) -> PyResult<usize> {
    if width < 8 || height < 8 || frames == 0 || !(fps > 0.0 && fps.is_finite()) {
        return Err(PyValueError::new_err(
            "generate_sequence: width and height at least 8, frames at least 1, fps positive",
        ));
    }
    if width.saturating_mul(height) > MAX_PIXELS || frames > MAX_FRAMES {
        return Err(PyValueError::new_err(format!(
            "generate_sequence: width x height must be at most {MAX_PIXELS} pixels (4096 x 4096) \
             and frames at most {MAX_FRAMES}, not {width} x {height} and {frames}"
        )));
    }
    let m = match motion {
        "orbit" => Motion::Orbit,
        "shake" => Motion::Shake,
        "fast_rotation" => Motion::FastRotation,
        "sweep" => Motion::Sweep,
        "survey" => Motion::Survey,
        other => {
            return Err(PyValueError::new_err(format!(
                "motion='{other}': expected orbit, shake, fast_rotation, sweep or survey"
            )))
        }
    };
    let sensor = match sensor {
        "kinect" => Sensor::Kinect(Box::new(KinectModel {
            seed,
            ..KinectModel::default()
        })),
        "ideal" => Sensor::Ideal(SensorNoise {
            seed,
            ..SensorNoise::default()
        }),
        other => {
            return Err(PyValueError::new_err(format!(
                "sensor='{other}': expected kinect or ideal"
            )))
        }
    };
    let camera = Camera::scaled_default(width, height);
    let trajectory = motion::procedural(m, frames, fps);
    let scene = layouts::build(Layout::Room, seed);
    py.detach(|| {
        std::fs::create_dir_all(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        sequence::write_rigid(
            &path,
            &scene,
            &camera,
            &trajectory,
            &Isometry3::identity(),
            &sensor,
            |_| {},
        )
        .map_err(|e| e.to_string())
    })
    .map_err(errors::input)?;
    Ok(trajectory.len())
}
